//! Batch jobs: recorded before they are acknowledged, each frame stored
//! done before its client hears so, and resumed after a master restart.

use super::*;
use crate::protocol::JobSpec;

fn job(frames: u32, scene: SceneHash) -> JobSpec {
    JobSpec { key: [5; 32], name: "frames/".into(), scene, frames, settings: settings(96, 64, 0) }
}

/// A client runs a job of `frames` frames, two queued at a time, until
/// `stop` frames are done (all if `None`); returns the frames it received,
/// by index.
fn run_job(net: &mut Net, c: PeerId, frames: u32, skip: &[u32], stop: Option<usize>) -> Vec<u32> {
    let todo: Vec<u32> = (0..frames).filter(|i| !skip.contains(i)).collect();
    let mut asked: Vec<(u32, u64)> = Vec::new();
    let mut next = 0;
    loop {
        let done: Vec<u32> = asked.iter().filter(|(_, r)| net.viewer_done(c, *r)).map(|(i, _)| *i).collect();
        if done.len() == todo.len() || stop.is_some_and(|s| done.len() >= s) {
            for (_, r) in asked.iter().filter(|(_, r)| net.viewer_done(c, *r)) {
                net.assert_exact(c, *r);
            }
            return done;
        }
        while next < todo.len() && asked.len() - done.len() < 2 {
            let i = todo[next];
            let r = net.request_of(c, settings(96, 64, u64::from(i)), true, None, Some(i));
            asked.push((i, r));
            next += 1;
        }
        net.step();
    }
}

#[test]
fn a_job_survives_a_master_restart_and_no_frame_is_rendered_twice_or_skipped() {
    let mut net = Net::new(sim::config());
    net.slave(SlaveSpec::default());
    let c = net.viewer_of(Work::Batch);
    net.run_until(|n| n.core.status().slaves.len() == 1 && n.limit(c).is_some());
    let scene = net.core.scene().unwrap().hash;
    net.submit_job(c, job(12, scene));
    net.run_until(|n| n.accepted(c).is_some());
    assert_eq!(net.accepted(c), Some(vec![]));
    assert!(net.disk.jobs.contains_key(&[5; 32]), "stored before it was acknowledged");
    let first = run_job(&mut net, c, 12, &[], Some(5));
    let stored = net.disk.jobs[&[5; 32]].done.clone();
    assert!(stored.iter().all(|i| first.contains(i)) && stored.len() >= first.len().min(5));

    // kill -9 of the master: everything reconnects to a new one.
    net.restart_master();
    net.slave(SlaveSpec::default());
    let c = net.viewer_of(Work::Batch);
    net.run_until(|n| n.core.status().slaves.len() == 1 && n.limit(c).is_some());
    net.submit_job(c, job(12, scene));
    net.run_until(|n| n.accepted(c).is_some());
    let done_before = net.accepted(c).unwrap();
    assert_eq!(done_before, stored, "the restarted master knows what was done");
    let rest = run_job(&mut net, c, 12, &done_before, None);
    let mut all: Vec<u32> = done_before.iter().chain(&rest).copied().collect();
    all.sort_unstable();
    assert_eq!(all, (0..12).collect::<Vec<_>>(), "every frame once");
    assert_eq!(net.disk.jobs[&[5; 32]].done, all);
    let st = net.statuses(c).len();
    net.say(c, &Message::StatusRequest);
    net.run_until(|n| n.statuses(c).len() > st);
    let report = net.statuses(c).last().unwrap();
    assert_eq!((report.jobs[0].done, report.jobs[0].frames, report.jobs[0].eta_seconds), (12, 12, Some(0.0)));
}

#[test]
fn jobs_are_checked_before_they_are_recorded() {
    let mut net = Net::new(sim::config());
    let c = net.viewer_of(Work::Batch);
    net.run_until(|n| n.limit(c).is_some());
    net.submit_job(c, job(0, net.core.scene().unwrap().hash));
    net.submit_job(c, job(3, [1; 32]));
    net.request_of(c, settings(8, 8, 1), true, None, Some(0));
    net.run_until(|n| n.errors(c).len() == 3);
    let e = net.errors(c);
    assert!(e[0].contains("1 to 100000 frames"), "{e:?}");
    assert!(e[1].contains("upload it first"), "{e:?}");
    assert!(e[2].contains("not a frame of this client's job"), "{e:?}");
    assert!(net.disk.jobs.is_empty());
}

#[test]
fn viewers_are_pushed_the_status_with_slave_names_and_job_progress() {
    let mut net = Net::new(sim::config());
    let v = net.viewer();
    net.run_until(|n| n.limit(v).is_some());
    // About a second and a half a frame.
    net.slave(SlaveSpec { us_per_pixel: 500, ..SlaveSpec::default() });
    net.run_until(|n| n.statuses(v).last().is_some_and(|s| s.slaves.len() == 1));
    let st = net.statuses(v).last().unwrap().clone();
    assert!(st.slaves[0].name.starts_with("sim"), "{st:?}");
    assert_eq!(st.slaves[0].threads, 2);
    // While frames are open, once a second; the rate follows the tiles.
    let c = net.viewer_of(Work::Batch);
    net.run_until(|n| n.limit(c).is_some());
    net.submit_job(c, job(6, net.core.scene().unwrap().hash));
    net.run_until(|n| n.accepted(c).is_some());
    let pushed = net.statuses(v).len();
    let start = net.now;
    run_job(&mut net, c, 6, &[], Some(3));
    let took = (net.now - start).as_secs() as usize;
    assert!(took >= 3, "{took} s");
    assert!(
        net.statuses(v).len() >= pushed + took - 1,
        "{} pushed in {took} s",
        net.statuses(v).len() - pushed
    );
    let last = net.statuses(v).last().unwrap();
    assert!(last.jobs[0].done >= 2 && last.jobs[0].running, "{last:?}");
    assert!(last.jobs[0].eta_seconds.is_some_and(|s| s > 1.0), "{last:?}");
    assert!(net.statuses(v).iter().any(|s| s.slaves.iter().any(|x| x.tiles_per_second > 0.0)));
    assert!(last.clients.iter().any(|x| x.work == Work::Batch && x.frames_done >= 2), "{last:?}");
}

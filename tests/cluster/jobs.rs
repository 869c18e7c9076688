//! Batch jobs through the cluster, over real sockets: scenes clients bring,
//! and a flight that survives `kill -9` of its master.
//!
//! - `a_render_of_another_scene_during_a_flight…`: while a viewer flies the
//!   master's scene, `isin render cornell.toml --cluster` renders the Cornell
//!   box (sent to the master by the client), byte-identical to a local
//!   render, and the viewer's frames stay those of its own scene.
//! - `a_flight_survives_kill_9_of_its_master…`: `isin fly --cluster` against
//!   a master with `--state`; the master is killed mid-flight and restarted
//!   on the same address and identity; the flight reconnects by itself and
//!   finishes with every frame written exactly once, each equal to the local
//!   `isin fly`.

use super::util::{self, Cluster, Proc, Stream, Transport, assert_same_pixels, client_transport};
use isin_actors::viewer;
use isin_transport::Ticket;
use std::sync::atomic::{AtomicBool, Ordering};

cluster_test!(a_render_of_another_scene_during_a_flight_is_that_scenes_render, |t| {
    let c = Cluster::start(t, 2, &[]);
    let size = ["--width", "160", "--height", "120"];
    let cornell = util::root().join("scenes/cornell.toml");
    let local_cornell = util::render_local_of(&cornell, &size);
    let local_paper = util::render_local(&size);
    let out = c.dir.path().join("cornell.png");
    let args = ["render", cornell.to_str().unwrap(), "--connect", &c.ticket, "-o", out.to_str().unwrap()];
    let mut args: Vec<&str> = args.to_vec();
    args.extend(size);
    let mut render = Proc::spawn("render cornell --cluster", &args, "info");
    let finished = AtomicBool::new(false);
    let ticket: Ticket = c.ticket.parse().expect("ticket");
    let transport = client_transport(&c);
    let flown = std::thread::scope(|s| {
        let flight = s.spawn(|| {
            actix::System::new().block_on(async {
                let (v, scene, mut events) =
                    viewer::connect(transport.as_ref(), &ticket, "flyer").await.expect("viewer");
                let scene = scene.expect("the master serves a scene");
                let settings = isin_tracer::RenderSettings { width: 160, height: 120, ..scene.settings };
                let mut frames = Vec::new();
                // Flying (a new frame as soon as the last is done) until the
                // render is through, and a few frames at least.
                while frames.len() < 3 || !finished.load(Ordering::Acquire) {
                    let (frame, _) = viewer::collect_frame(&v, &mut events, scene.camera, settings)
                        .await
                        .expect("a frame");
                    frames.push(frame.rgb);
                }
                frames
            })
        });
        let ok = render.wait_exit().success();
        finished.store(true, Ordering::Release);
        assert!(ok, "the render failed\n{}\n{}", render.dump(), c.master.dump());
        flight.join().expect("the flight")
    });
    assert_same_pixels(&util::pixels(&out), &local_cornell, "cornell.toml through the cluster vs here");
    for rgb in &flown {
        assert_same_pixels(rgb, &local_paper, "the viewer's frame beside the other scene's render");
    }
    // Each slave fetched the other scene once.
    for s in &c.slaves {
        assert_eq!(s.matching(Stream::Err, |l| l.contains("fetching a scene")).len(), 1, "{}", s.dump());
    }
});

cluster_test!(a_flight_survives_kill_9_of_its_master_with_every_frame_once_and_identical, |t: Transport| {
    let addr = t.free_addr();
    let (identity, state) = (tempfile::tempdir().expect("temp dir"), tempfile::tempdir().expect("temp dir"));
    let (identity_args, ticket) = t.prepared_ticket(identity.path(), "tok", &addr);
    // A master with no scene of its own: the flight brings it.
    let start_master = || {
        let mut args = vec!["master", "--listen", &addr, "--token", "tok", "--state"];
        args.push(state.path().to_str().unwrap());
        args.extend(t.master_args());
        args.extend(identity_args.iter().map(String::as_str));
        let m = Proc::spawn("master", &args, "info,isin_cluster::cluster=debug");
        m.wait_for(Stream::Out, "ticket ");
        m
    };
    let mut master = start_master();
    let _slaves: Vec<Proc> = (0..2)
        .map(|i| {
            let name = format!("s{i}");
            Proc::spawn(&name, &["slave", "--connect", &ticket, "--threads", "1", "--name", &name], "info")
        })
        .collect();
    master.wait_for_n(Stream::Err, "joined with", 2);
    let (scene, path) = (util::scene(), util::root().join("scenes/paths/paper.toml"));
    let dir = tempfile::tempdir().expect("temp dir");
    let (here, there) = (dir.path().join("here"), dir.path().join("there"));
    let fly_args = |out: &std::path::Path| {
        let mut a =
            vec!["fly".to_string(), scene.display().to_string(), "--path".into(), path.display().to_string()];
        for x in [
            "--out-dir",
            out.to_str().unwrap(),
            "--width",
            "240",
            "--height",
            "180",
            "--spp",
            "2",
            "--frames",
            "0..10",
        ] {
            a.push(x.to_string());
        }
        a
    };
    let mut args = fly_args(&there);
    args.extend(["--connect".to_string(), ticket.clone(), "--timeout".into(), "120".into()]);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let mut fly = Proc::spawn("fly --cluster", &args, "info");
    fly.wait_for_n(Stream::Out, " done at ", 3);
    master.kill9();
    let master = start_master();
    assert!(fly.wait_exit().success(), "the flight failed\n{}\n{}", fly.dump(), master.dump());
    let resumed = fly.wait_for(Stream::Out, "resuming: ");
    let before: usize = resumed.split_whitespace().nth(1).and_then(|n| n.parse().ok()).expect("a count");
    assert!((3..10).contains(&before), "{resumed}");
    // The restarted master knew the job, and at least the frames written.
    let job = master.wait_for(Stream::Err, "(10 frames, ");
    let known: usize = job
        .split("(10 frames, ")
        .nth(1)
        .and_then(|r| r.split(' ').next())
        .and_then(|n| n.parse().ok())
        .expect("a count");
    assert!(known >= 3, "{job}");
    let args = fly_args(&here);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let mut local = Proc::spawn("fly", &args, "warn");
    assert!(local.wait_exit().success(), "{}", local.dump());
    for i in 0..10 {
        let done = fly.matching(Stream::Out, |l| l.starts_with(&format!("frame {i:04}  done")));
        assert_eq!(done.len(), 1, "frame {i} written {} times\n{}", done.len(), fly.dump());
        let name = format!("frame_{i:04}.png");
        assert_same_pixels(&util::pixels(&there.join(&name)), &util::pixels(&here.join(&name)), &name);
    }
    assert_eq!(std::fs::read_dir(&there).unwrap().count(), 10, "ten frames and nothing else");
});

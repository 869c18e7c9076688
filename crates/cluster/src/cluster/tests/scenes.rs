//! Scenes per client: uploads, frames naming their scene, slaves fetching
//! the scenes they lack, and what happens when a scene cannot be had.

use super::*;
use sim::fake_scene;

/// Logs in two slaves and returns them with a viewer flying the default
/// scene and a batch client.
fn two_slaves_a_flyer_and_a_batch_client(net: &mut Net) -> ([PeerId; 2], PeerId, PeerId) {
    let a = net.slave(SlaveSpec::default());
    let b = net.slave(SlaveSpec { us_per_pixel: 7, ..SlaveSpec::default() });
    let (flyer, batch) = (net.viewer(), net.viewer_of(Work::Batch));
    net.run_until(|n| {
        n.core.status().slaves.len() == 2 && n.limit(flyer).is_some() && n.limit(batch).is_some()
    });
    ([a, b], flyer, batch)
}

#[test]
fn a_batch_render_of_another_scene_during_a_flight_is_that_scenes_render_and_each_slave_fetches_it_once() {
    let mut net = Net::new(sim::config());
    let (slaves, flyer, batch) = two_slaves_a_flyer_and_a_batch_client(&mut net);
    let other = net.upload(batch, fake_scene("other.toml", 20_000));
    net.run_until(|n| n.stored(batch, other));
    let mut flights = Vec::new();
    let mut stills = Vec::new();
    for seed in 1..=4 {
        flights.push(net.request(flyer, settings(96, 64, seed), false));
        stills.push(net.request_of(batch, settings(80, 60, 100 + seed), true, Some(other), None));
        net.run_until(|n| flights.iter().all(|&r| n.viewer_done(flyer, r)));
    }
    net.run_until(|n| stills.iter().all(|&r| n.viewer_done(batch, r)));
    for &r in &flights {
        net.assert_exact(flyer, r);
    }
    for &r in &stills {
        net.assert_exact(batch, r);
    }
    // Back to the default scene and to the other again: nothing is resent.
    let back = net.request_of(batch, settings(80, 60, 7), false, None, None);
    net.run_until(|n| n.viewer_done(batch, back));
    let again = net.request_of(batch, settings(80, 60, 8), false, Some(other), None);
    net.run_until(|n| n.viewer_done(batch, again));
    net.assert_exact(batch, back);
    net.assert_exact(batch, again);
    for s in slaves {
        // The default scene at join, the other one when first handed its tiles.
        assert!(net.scene_syncs(s) <= 2, "slave {s} got {} scenes", net.scene_syncs(s));
    }
    assert_eq!(
        net.core.status().scene_sends,
        slaves.iter().map(|&s| u64::from(net.scene_syncs(s))).sum::<u64>()
    );
}

#[test]
fn a_scene_the_master_holds_is_not_uploaded_again() {
    let mut net = Net::new(sim::config());
    let (_, flyer, batch) = two_slaves_a_flyer_and_a_batch_client(&mut net);
    let h = net.upload(batch, fake_scene("other.toml", 1000));
    net.run_until(|n| n.stored(batch, h));
    assert!(net.received(batch).iter().any(|m| matches!(m, Message::SceneWanted { .. })));
    assert_eq!(net.upload(flyer, fake_scene("other.toml", 1000)), h);
    net.run_until(|n| n.stored(flyer, h));
    assert!(
        !net.received(flyer).iter().any(|m| matches!(m, Message::SceneWanted { .. })),
        "the second client was asked for the scene"
    );
    // The default scene is held too.
    let default = net.core.scene().unwrap().hash;
    let header =
        SceneHeader { hash: default, name: "x".into(), raw_bytes: 1 << 40, compressed_bytes: 1, chunks: 1 };
    net.say(flyer, &Message::SceneUpload(header));
    net.run_until(|n| n.stored(flyer, default));
}

#[test]
fn uploads_are_bounded_checked_and_announced() {
    let mut net = Net::new(sim::config());
    let (_, flyer, batch) = two_slaves_a_flyer_and_a_batch_client(&mut net);
    // Too large: refused before a byte of it is read.
    let max = net.core.budgets().scene_upload_bytes as u64;
    let packed = crate::scene_stream::pack(&fake_scene("a.toml", 100)).unwrap();
    let huge = SceneHeader { hash: [9; 32], raw_bytes: max + 1, ..packed.header.clone() };
    net.say(batch, &Message::SceneUpload(huge));
    net.run_until(|n| !n.errors(batch).is_empty());
    assert!(net.errors(batch)[0].contains("at most"), "{:?}", net.errors(batch));
    assert_eq!(net.limit(batch), Some(VIEWER_MAX_FRAME));
    // A frame of a scene nobody uploaded.
    net.request_of(batch, settings(8, 8, 1), false, Some([1; 32]), None);
    net.run_until(|n| n.errors(batch).len() == 2);
    assert!(net.errors(batch)[1].contains("unknown scene"), "{:?}", net.errors(batch));
    // A chunk of a scene never announced: the client is refused.
    let chunk = packed.chunk_frame(0).unwrap();
    net.send_raw(flyer, chunk.as_ref().clone());
    net.run_until(|n| n.is_closed(flyer));
    assert!(net.rejection(flyer).unwrap().contains("not announced"));
    // Announced as one scene, sent as another: refused, the client dropped.
    let lying = SceneHeader { hash: [1; 32], ..packed.header.clone() };
    net.say(batch, &Message::SceneUpload(lying));
    net.run_until(|n| n.limit(batch) == Some(limits::SCENE_CHUNK_FRAME));
    let Message::SceneChunk { index, bytes, .. } = protocol::decode(&chunk, usize::MAX).unwrap() else {
        panic!("a chunk")
    };
    net.say(batch, &Message::SceneChunk { hash: [1; 32], index, bytes });
    net.run_until(|n| n.is_closed(batch));
    assert!(net.rejection(batch).unwrap().contains("does not match its hash"), "{:?}", net.rejection(batch));
    assert!(!net.stored(batch, [1; 32]) && !net.core.scenes.contains(&[1; 32]));
    assert_eq!(net.core.uploading, 0, "nothing is held for it");
}

#[test]
fn uploads_in_progress_are_held_within_their_budget() {
    let mut cfg = sim::config();
    cfg.budgets.uploading_bytes = 30_000;
    let mut net = Net::new(cfg);
    let (_, flyer, batch) = two_slaves_a_flyer_and_a_batch_client(&mut net);
    // Two uploads of 20 kB announced at once: the second waits for room.
    let a = crate::scene_stream::pack(&fake_scene("a.toml", 20_000)).unwrap();
    let b = crate::scene_stream::pack(&fake_scene("b.toml", 20_000)).unwrap();
    net.say(batch, &Message::SceneUpload(a.header.clone()));
    net.say(flyer, &Message::SceneUpload(b.header.clone()));
    net.run_until(|n| !n.errors(flyer).is_empty());
    assert!(net.errors(flyer)[0].contains("receiving"), "{:?}", net.errors(flyer));
    assert_eq!(net.core.uploading, a.header.raw_bytes);
    // A's chunks in: held, and room again.
    for i in 0..a.header.chunks {
        net.send_raw(batch, a.chunk_frame(i).unwrap().as_ref().clone());
    }
    net.run_until(|n| n.stored(batch, a.header.hash));
    assert_eq!(net.core.uploading, 0);
    assert_eq!(net.limit(batch), Some(VIEWER_MAX_FRAME), "the limit drops back once the scene is in");
    let h = net.upload(flyer, fake_scene("b.toml", 20_000));
    net.run_until(|n| n.stored(flyer, h));
    // A client that leaves mid-upload takes its share with it.
    let c = crate::scene_stream::pack(&fake_scene("c.toml", 20_000)).unwrap();
    net.say(batch, &Message::SceneUpload(c.header.clone()));
    net.run_until(|n| n.limit(batch) == Some(limits::SCENE_CHUNK_FRAME));
    assert_eq!(net.core.uploading, c.header.raw_bytes);
    net.disconnect(batch);
    assert_eq!(net.core.uploading, 0);
}

#[test]
fn a_master_without_a_scene_serves_the_scenes_clients_bring() {
    let mut cfg = sim::config();
    cfg.scene = None;
    let mut net = Net::new(cfg);
    let s = net.slave(SlaveSpec::default());
    let v = net.viewer();
    net.run_until(|n| n.core.status().slaves.len() == 1 && n.limit(v).is_some());
    assert_eq!(net.scene_syncs(s), 0, "no scene at join");
    net.request(v, settings(16, 16, 1), false);
    net.run_until(|n| !n.errors(v).is_empty());
    assert!(net.errors(v)[0].contains("serves no scene"), "{:?}", net.errors(v));
    let h = net.upload(v, fake_scene("mine.toml", 3000));
    net.run_until(|n| n.stored(v, h));
    let r = net.request_of(v, settings(64, 48, 2), false, Some(h), None);
    net.run_until(|n| n.viewer_done(v, r));
    net.assert_exact(v, r);
    assert_eq!(net.scene_syncs(s), 1);
}

#[test]
fn a_scene_a_slave_cannot_load_fails_its_frames_with_the_reason_and_no_others() {
    let mut net = Net::new(sim::config());
    let weak = net.slave(SlaveSpec { behaviour: Behaviour::FailsScenes, ..SlaveSpec::default() });
    let (flyer, batch) = (net.viewer(), net.viewer_of(Work::Batch));
    net.run_until(|n| n.core.status().slaves.len() == 1 && n.limit(batch).is_some());
    let h = net.upload(batch, fake_scene("huge.toml", 1000));
    net.run_until(|n| n.stored(batch, h));
    net.request_of(batch, settings(64, 48, 1), true, Some(h), None);
    let fly = net.request(flyer, settings(64, 48, 2), false);
    net.run_until(|n| !n.errors(batch).is_empty() && n.viewer_done(flyer, fly));
    let why = &net.errors(batch)[0];
    assert!(why.contains("huge.toml") && why.contains("no memory") && why.contains("sim"), "{why}");
    net.assert_exact(flyer, fly);
    assert!(net.core.sched.open_frames().is_empty());
    assert!(!net.is_closed(weak), "the slave stays for other scenes");
}

#[test]
fn an_idle_scene_is_evicted_for_a_new_one_and_a_busy_one_never() {
    let mut cfg = sim::config();
    cfg.budgets.scene_bytes = 30_000;
    let mut net = Net::new(cfg);
    let (_, _, batch) = two_slaves_a_flyer_and_a_batch_client(&mut net);
    let a = net.upload(batch, fake_scene("a.toml", 15_000));
    net.run_until(|n| n.stored(batch, a));
    // a has an open frame: b cannot push it out.
    let r = net.request_of(batch, settings(320, 240, 1), true, Some(a), None);
    let b = net.upload(batch, fake_scene("b.toml", 15_000));
    net.run_until(|n| !n.errors(batch).is_empty());
    assert!(net.errors(batch)[0].contains("in use"), "{:?}", net.errors(batch));
    assert!(!net.stored(batch, b));
    net.run_until(|n| n.viewer_done(batch, r));
    net.assert_exact(batch, r);
    // Now a is idle: it goes, and the master says so to its state directory.
    let b = net.upload(batch, fake_scene("b.toml", 15_000));
    net.run_until(|n| n.stored(batch, b));
    assert!(net.disk.scenes.contains_key(&b) && !net.disk.scenes.contains_key(&a));
}

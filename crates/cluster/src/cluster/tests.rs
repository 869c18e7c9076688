//! Cluster tests: a virtual clock (1 ms steps) and simulated peers that speak
//! the real protocol — encoded frames into [`Cluster::handle_frame`],
//! [`Transmit`]s out — honest or hostile. A simulated transport between them
//! applies the frame limits the core asks for, as TCP and QUIC do.

mod jobs;
mod scenes;
mod sim;
mod sync;

use super::*;
use sim::{Behaviour, Net, SlaveSpec};

const MS: Duration = Duration::from_millis(1);

fn settings(w: u32, h: u32, seed: u64) -> RenderSettings {
    RenderSettings { width: w, height: h, seed, ..RenderSettings::default() }
}

#[test]
fn frames_through_two_slaves_are_exact_and_the_scene_is_sent_once_each() {
    let mut net = Net::new(sim::config());
    let a = net.slave(SlaveSpec::default());
    let b = net.slave(SlaveSpec { us_per_pixel: 7, ..SlaveSpec::default() });
    let v = net.viewer();
    net.run_until(|n| n.core.status().slaves.len() == 2);
    for seed in 1..=3 {
        let req = net.request(v, settings(96, 64, seed), false);
        net.run_until(|n| n.viewer_done(v, req));
        net.assert_exact(v, req);
    }
    assert_eq!(net.scene_syncs(a), 1);
    assert_eq!(net.scene_syncs(b), 1);
    let st = net.core.status();
    assert_eq!((st.frames_requested, st.frames_done, st.refused, st.foreign_results), (3, 3, 0, 0));
    assert!(st.slaves.iter().all(|s| s.tiles_done > 0), "{:?}", st.slaves);
}

#[test]
fn a_viewer_that_decodes_no_codec_is_sent_the_compressed_tiles_decoded() {
    let mut net = Net::new(sim::config());
    net.slave(SlaveSpec::default());
    net.slave(SlaveSpec::default());
    let old = net.raw_only_viewer();
    let new = net.viewer();
    net.run_until(|n| n.core.status().slaves.len() == 2);
    for v in [old, new] {
        let req = net.request(v, settings(96, 64, 5), false);
        net.run_until(|n| n.viewer_done(v, req));
        net.assert_exact(v, req);
    }
    // The slaves send QOI (the master's default picks it); the master checks
    // it without decoding, and decodes it only for the viewer that needs raw.
    let tiles = |v| net.codecs_seen(v).into_iter().collect::<Vec<_>>();
    assert!(matches!(tiles(old)[..], [("raw", n)] if n > 0), "{:?}", tiles(old));
    assert!(matches!(tiles(new)[..], [("qoi", n)] if n > 0), "{:?}", tiles(new));
    assert_eq!(net.core.status().refused, 0);
}

#[test]
fn a_wrong_token_is_refused_with_a_clear_message_and_no_scene() {
    let mut net = Net::new(sim::config());
    let s = net.slave(SlaveSpec { token: "wrong".into(), ..SlaveSpec::default() });
    net.run_until(|n| n.is_closed(s));
    assert!(net.rejection(s).unwrap().contains("wrong token"), "{:?}", net.rejection(s));
    assert_eq!(net.scene_syncs(s), 0);
    assert_eq!(net.core.status().refused, 1);
}

#[test]
fn a_peer_speaking_another_protocol_version_is_told_so() {
    let mut net = Net::new(sim::config());
    let p = net.raw_peer();
    let mut frame = protocol::encode(&Message::Heartbeat).unwrap();
    frame[..2].copy_from_slice(&(PROTOCOL_VERSION_OTHER).to_be_bytes());
    net.send_raw(p, frame);
    net.run_until(|n| n.is_closed(p));
    let why = net.rejection(p).unwrap();
    assert!(why.contains("protocol version"), "{why}");
}

const PROTOCOL_VERSION_OTHER: u16 = protocol::PROTOCOL_VERSION + 1;

#[test]
fn a_foreign_tile_result_is_refused_and_the_frame_stays_exact() {
    let mut cfg = sim::config();
    cfg.budgets.foreign_results = 1000;
    let mut net = Net::new(cfg);
    net.slave(SlaveSpec { threads: 2, ..SlaveSpec::default() });
    let forger = net.slave(SlaveSpec { behaviour: Behaviour::Forger, ..SlaveSpec::default() });
    let v = net.viewer();
    net.run_until(|n| n.core.status().slaves.len() == 2);
    let req = net.request(v, settings(128, 96, 5), false);
    net.run_until(|n| n.viewer_done(v, req));
    net.assert_exact(v, req);
    let st = net.core.status();
    assert!(st.foreign_results > 0, "the forger sent nothing foreign");
    assert!(!net.is_closed(forger), "under its budget the forger stays");
}

#[test]
fn a_forger_past_its_budget_is_disconnected_and_the_frame_stays_exact() {
    let mut net = Net::new(sim::config());
    net.slave(SlaveSpec::default());
    let forger = net.slave(SlaveSpec { behaviour: Behaviour::Forger, ..SlaveSpec::default() });
    let v = net.viewer();
    net.run_until(|n| n.core.status().slaves.len() == 2);
    let req = net.request(v, settings(128, 96, 9), false);
    net.run_until(|n| n.viewer_done(v, req));
    net.assert_exact(v, req);
    assert!(net.is_closed(forger));
    assert!(net.rejection(forger).unwrap().contains("never handed"), "{:?}", net.rejection(forger));
    assert_eq!(net.core.status().foreign_results, u64::from(net.core.budgets().foreign_results) + 1);
}

#[test]
fn a_slave_stalled_after_login_is_dropped_within_the_heartbeat_timeout() {
    let mut net = Net::new(sim::config());
    let s = net.slave(SlaveSpec { behaviour: Behaviour::StallBeforeReady, ..SlaveSpec::default() });
    let t0 = net.now;
    net.run_until(|n| n.is_closed(s));
    let timeout = net.core.sched.config().heartbeat_timeout;
    assert!(net.now - t0 <= timeout + 10 * MS, "took {:?}", net.now - t0);
    assert!(net.rejection(s).unwrap().contains("silent"), "{:?}", net.rejection(s));
    assert_eq!(net.core.status().peers, 0);
}

#[test]
fn a_slave_that_heartbeats_but_never_loads_the_scene_is_dropped_at_the_sync_deadline() {
    let mut cfg = sim::config();
    cfg.sync_timeout = Duration::from_secs(3);
    let mut net = Net::new(cfg);
    let s = net.slave(SlaveSpec { behaviour: Behaviour::HeartbeatNeverReady, ..SlaveSpec::default() });
    net.run_until(|n| n.is_closed(s));
    assert!(net.now >= Duration::from_secs(3) && net.now < Duration::from_secs(3) + 10 * MS, "{:?}", net.now);
    assert!(net.rejection(s).unwrap().contains("did not load the scene"), "{:?}", net.rejection(s));
}

#[test]
fn a_silent_viewer_is_dropped_and_its_frame_abandoned() {
    let mut net = Net::new(sim::config());
    let s = net.slave(SlaveSpec { us_per_pixel: 20_000, ..SlaveSpec::default() });
    let v = net.viewer();
    net.run_until(|n| n.core.status().slaves.len() == 1);
    net.request(v, settings(64, 64, 1), false);
    net.set_behaviour(v, Behaviour::Silent);
    net.run_until(|n| n.is_closed(v));
    assert!(net.rejection(v).unwrap().contains("silent"));
    assert!(net.core.sched.open_frame().is_none(), "the viewer's frame is abandoned");
    assert!(net.cancels(s) > 0, "the slave was told to drop its tiles");
}

#[test]
fn a_peer_that_never_says_hello_is_dropped_at_the_handshake_deadline() {
    let mut net = Net::new(sim::config());
    let p = net.raw_peer();
    net.run_until(|n| n.is_closed(p));
    assert_eq!(net.now, net.core.handshake_timeout);
    assert!(net.rejection(p).unwrap().contains("handshake timed out"));
}

#[test]
fn every_role_is_held_to_its_frame_limit() {
    let mut net = Net::new(sim::config());
    // Before login: the handshake limit, applied by the transport.
    let p = net.raw_peer();
    net.send_raw(p, vec![0; HANDSHAKE_MAX_FRAME + 1]);
    net.run_until(|n| n.is_closed(p));
    assert!(net.rejection(p).unwrap().contains("too large"), "{:?}", net.rejection(p));
    // A viewer may send requests, not megabytes.
    let v = net.viewer();
    net.run_until(|n| n.limit(v) == Some(VIEWER_MAX_FRAME));
    let big = Message::Error { message: "x".repeat(VIEWER_MAX_FRAME) };
    net.send_raw(v, protocol::encode(&big).unwrap());
    net.run_until(|n| n.is_closed(v));
    // A slave may send one tile's worth.
    let s = net.slave(SlaveSpec::default());
    net.run_until(|n| n.core.status().slaves.len() == 1);
    assert_eq!(net.limit(s), Some(limits::slave_max_frame(32)));
    let big = Message::Error { message: "x".repeat(limits::slave_max_frame(32)) };
    net.send_raw(s, protocol::encode(&big).unwrap());
    net.run_until(|n| n.is_closed(s));
    // The core checks again what a transport let through.
    let s2 = net.slave(SlaveSpec::default());
    net.run_until(|n| n.core.status().slaves.len() == 1);
    let now = net.now;
    net.core.handle_frame(now, s2, &protocol::encode(&big).unwrap());
    net.pump();
    assert!(net.is_closed(s2));
    assert_eq!(net.core.status().refused, 4);
}

#[test]
fn peer_caps_refuse_connections_with_the_limit_named() {
    let mut cfg = sim::config();
    cfg.budgets.max_handshaking = 2;
    cfg.budgets.max_peers = 3;
    let mut net = Net::new(cfg);
    let (p1, p2) = (net.raw_peer(), net.raw_peer());
    let p3 = net.raw_peer();
    net.pump();
    assert!(net.rejection(p3).unwrap().contains("handshake"), "{:?}", net.rejection(p3));
    assert!(!net.is_closed(p1) && !net.is_closed(p2));
    // Logged-in peers free handshake slots, but not peer slots.
    let v = net.viewer();
    assert!(net.rejection(v).is_some(), "still two in the handshake");
    net.disconnect(p1);
    let v = net.viewer();
    net.run_until(|n| n.limit(v).is_some());
    let p4 = net.raw_peer();
    let late = net.raw_peer();
    assert!(net.rejection(p4).is_none());
    assert!(net.rejection(late).unwrap().contains("3 peers"), "{:?}", net.rejection(late));
    assert_eq!(net.core.status().peers, 3);
}

#[test]
fn the_scene_goes_out_by_its_file_name_never_its_path() {
    let mut cfg = sim::config();
    cfg.scene.as_mut().unwrap().bundle.name = "/home/someone/private/scenes/room.toml".into();
    let mut net = Net::new(cfg);
    let s = net.slave(SlaveSpec::default());
    let v = net.viewer();
    net.run_until(|n| n.core.status().slaves.len() == 1 && n.limit(v).is_some());
    for id in [s, v] {
        for m in net.received(id) {
            let text = format!("{m:?}");
            assert!(!text.contains("/home/someone"), "{} leaks the path", m.kind());
        }
    }
    assert_eq!(net.core.scene().unwrap().name, "room.toml");
}

#[test]
fn a_viewers_request_supersedes_its_own_frames_and_no_one_elses() {
    let mut net = Net::new(sim::config());
    let s = net.slave(SlaveSpec { us_per_pixel: 50, ..SlaveSpec::default() });
    let (v1, v2) = (net.viewer(), net.viewer());
    net.run_until(|n| n.core.status().slaves.len() == 1);
    let r1 = net.request(v1, settings(64, 64, 1), false);
    net.run_for(5 * MS);
    let r2 = net.request(v2, settings(64, 64, 2), false);
    net.run_until(|n| n.viewer_done(v1, r1) && n.viewer_done(v2, r2));
    net.assert_exact(v1, r1);
    net.assert_exact(v2, r2);
    assert!(net.errors(v1).is_empty() && net.errors(v2).is_empty());
    // A viewer moving on drops its own frame.
    let r3 = net.request(v1, settings(64, 64, 3), false);
    net.run_for(5 * MS);
    let cancels = net.cancels(s);
    let r4 = net.request(v1, settings(64, 64, 4), false);
    net.run_until(|n| n.viewer_done(v1, r4));
    net.assert_exact(v1, r4);
    assert!(!net.viewer_done(v1, r3));
    assert!(net.cancels(s) > cancels, "the superseded frame's tiles were cancelled");
}

/// Two viewers keep two frames queued each, one of big frames and one of
/// small ones: by pixel-samples each gets close to half of the cluster (the
/// oldest frame first would give the small one a few per cent).
#[test]
fn two_viewers_moving_together_each_keep_at_least_40_percent_of_the_cluster() {
    let mut net = Net::new(sim::config());
    for _ in 0..3 {
        net.slave(SlaveSpec { threads: 2, us_per_pixel: 20, ..SlaveSpec::default() });
    }
    let (big, small) = (net.viewer(), net.viewer());
    net.run_until(|n| n.core.status().slaves.len() == 3 && n.limit(small).is_some());
    let mut seed = 0;
    let start = net.now;
    while net.now < start + Duration::from_secs(8) {
        for (v, (w, h)) in [(big, (256, 192)), (small, (64, 48))] {
            while net.open_requests(v) < 2 {
                seed += 1;
                net.request(v, settings(w, h, seed), true);
            }
        }
        net.step();
    }
    let (a, b) = (net.delivered(big) as f64, net.delivered(small) as f64);
    let (share_a, share_b) = (a / (a + b), b / (a + b));
    assert!(share_a >= 0.4 && share_b >= 0.4, "shares {share_a:.2} / {share_b:.2}");
    assert!(net.errors(big).is_empty() && net.errors(small).is_empty());
}

#[test]
fn queued_frames_are_pipelined_and_each_comes_back_exact() {
    let mut net = Net::new(sim::config());
    net.slave(SlaveSpec { threads: 3, ..SlaveSpec::default() });
    let v = net.viewer();
    net.run_until(|n| n.core.status().slaves.len() == 1);
    let reqs: Vec<u64> = (1..=3).map(|seed| net.request(v, settings(80, 48, seed), true)).collect();
    net.run_until(|n| reqs.iter().all(|&r| n.viewer_done(v, r)));
    for r in reqs {
        net.assert_exact(v, r);
    }
}

#[test]
fn a_slave_joining_mid_frame_gets_tiles_at_once() {
    let mut net = Net::new(sim::config());
    net.slave(SlaveSpec { us_per_pixel: 200, ..SlaveSpec::default() });
    let v = net.viewer();
    net.run_until(|n| n.core.status().slaves.len() == 1);
    let req = net.request(v, settings(128, 128, 3), false);
    net.run_for(20 * MS);
    let late = net.slave(SlaveSpec::default());
    net.run_until(|n| n.core.status().slaves.len() == 2);
    let joined = net.now;
    net.run_until(|n| n.assignments(late) > 0);
    assert!(net.now - joined <= MS, "waited {:?}", net.now - joined);
    net.run_until(|n| n.viewer_done(v, req));
    net.assert_exact(v, req);
}

#[test]
fn a_slave_that_reconnects_with_the_scene_cached_is_not_sent_it_again() {
    let mut net = Net::new(sim::config());
    let a = net.slave(SlaveSpec::default());
    net.run_until(|n| n.core.status().slaves.len() == 1);
    assert_eq!(net.scene_syncs(a), 1);
    let hash = net.core.scene().unwrap().hash;
    net.disconnect(a);
    let b = net.slave(SlaveSpec { cached: Some(hash), ..SlaveSpec::default() });
    net.run_until(|n| n.core.status().slaves.len() == 1);
    assert_eq!(net.scene_syncs(b), 0);
    let v = net.viewer();
    let req = net.request(v, settings(32, 32, 1), false);
    net.run_until(|n| n.viewer_done(v, req));
    net.assert_exact(v, req);
}

#[test]
fn a_slave_that_dies_mid_frame_has_its_tiles_rendered_by_the_others() {
    let mut net = Net::new(sim::config());
    let doomed = net.slave(SlaveSpec { us_per_pixel: 100, ..SlaveSpec::default() });
    net.slave(SlaveSpec::default());
    let v = net.viewer();
    net.run_until(|n| n.core.status().slaves.len() == 2);
    let req = net.request(v, settings(128, 96, 4), false);
    net.run_for(3 * MS);
    net.disconnect(doomed);
    net.run_until(|n| n.viewer_done(v, req));
    net.assert_exact(v, req);
    assert_eq!(net.core.status().deaths, 1);
}

#[test]
fn a_viewer_whose_frames_wait_for_slaves_is_told_once_and_served_when_one_joins() {
    let mut net = Net::new(sim::config());
    let v = net.viewer();
    net.run_until(|n| n.limit(v).is_some());
    let first = net.request(v, settings(32, 32, 1), false);
    let second = net.request(v, settings(32, 32, 2), true);
    net.run_for(3000 * MS);
    let told = net.notices(v);
    assert_eq!(told.len(), 1, "{told:?}");
    assert!(told[0].contains("no slaves connected") && told[0].contains("isin slave --connect"), "{told:?}");
    let s = net.slave(SlaveSpec::default());
    net.run_until(|n| n.viewer_done(v, first) && n.viewer_done(v, second));
    net.assert_exact(v, second);
    assert_eq!(net.notices(v).len(), 1, "nothing more to say while slaves work");
    // The only slave goes: the next frame waits, and the viewer is told again.
    net.disconnect(s);
    net.request(v, settings(32, 32, 3), false);
    assert_eq!(net.notices(v).len(), 2);
}

#[test]
fn absurd_requests_get_an_error_and_the_viewer_stays() {
    let mut net = Net::new(sim::config());
    let v = net.viewer();
    net.run_until(|n| n.limit(v).is_some());
    net.request(v, settings(0, 10, 1), false);
    net.request(v, RenderSettings { spp: 1 << 30, ..settings(8, 8, 1) }, false);
    net.run_for(MS);
    let errors = net.errors(v);
    assert_eq!(errors.len(), 2, "{errors:?}");
    assert!(errors[0].contains("image side 0") && errors[1].contains("samples per pixel"), "{errors:?}");
    assert!(!net.is_closed(v));
    assert_eq!(net.core.status().frames_requested, 0);
}

#[test]
fn a_viewer_sending_a_tile_or_a_slave_requesting_a_frame_is_refused() {
    let mut net = Net::new(sim::config());
    let s = net.slave(SlaveSpec::default());
    let v = net.viewer();
    net.run_until(|n| n.core.status().slaves.len() == 1 && n.limit(v).is_some());
    let request = Message::FrameRequest {
        request: 1,
        scene: None,
        camera: Camera::default(),
        settings: settings(8, 8, 1),
    };
    net.send_raw(s, protocol::encode(&request).unwrap());
    net.send_raw(v, protocol::encode(&Message::Ready { hash: Some([0; 32]) }).unwrap());
    net.run_until(|n| n.is_closed(s) && n.is_closed(v));
    assert!(net.rejection(s).unwrap().contains("unexpected FrameRequest"));
    assert!(net.rejection(v).unwrap().contains("unexpected Ready"));
}

/// Honest and hostile peers mixed, slaves dying, going silent and joining,
/// viewers superseding and queueing: every frame that completes is exact,
/// every pixel of it delivered once, and the core never speaks to a peer it
/// has closed.
#[test]
fn randomised_clusters_with_hostile_peers_never_lose_duplicate_or_corrupt_a_pixel() {
    for seed in 1..=24u64 {
        let mut rng = sim::Rng(seed.wrapping_mul(0x9e37_79b9_7f4a_7c15));
        let mut cfg = sim::config();
        cfg.scheduler.heartbeat_timeout = Duration::from_millis(1200);
        cfg.budgets.foreign_results = rng.below(4) as u32;
        let mut net = Net::new(cfg);
        for _ in 0..1 + rng.below(3) {
            let spec = SlaveSpec {
                threads: 1 + rng.below(3) as u32,
                us_per_pixel: 1 + rng.below(40),
                ..SlaveSpec::default()
            };
            net.slave(spec);
        }
        for _ in 0..rng.below(3) {
            let behaviour = match rng.below(4) {
                0 => Behaviour::Forger,
                1 => Behaviour::StallBeforeReady,
                2 => Behaviour::Oversized,
                _ => Behaviour::WrongRect,
            };
            net.slave(SlaveSpec { behaviour, ..SlaveSpec::default() });
        }
        let v = net.viewer();
        net.run_until(|n| n.limit(v).is_some());
        let mut requests = Vec::new();
        for round in 0..6 {
            let (w, h) = (16 + rng.below(100) as u32, 16 + rng.below(80) as u32);
            let queue = rng.below(2) == 0;
            requests.push(net.request(v, settings(w, h, seed * 100 + round), queue));
            net.run_for(Duration::from_millis(rng.below(30)));
            match rng.below(6) {
                0 => {
                    if let Some(s) = net.live_honest_slave(&mut rng) {
                        net.disconnect(s);
                    }
                }
                1 => {
                    if let Some(s) = net.live_honest_slave(&mut rng) {
                        net.set_behaviour(s, Behaviour::Silent);
                    }
                }
                _ => {}
            }
            if net.honest_slaves() == 0 || rng.below(3) == 0 {
                net.slave(SlaveSpec { threads: 2, ..SlaveSpec::default() });
            }
        }
        // Every request either completes or is superseded by a later one.
        let last = *requests.last().unwrap();
        net.run_until(|n| n.viewer_done(v, last));
        let mut done = 0;
        for &r in &requests {
            if net.viewer_done(v, r) {
                net.assert_exact(v, r);
                done += 1;
            }
        }
        assert!(done >= 1, "seed {seed}");
        assert_eq!(net.core.status().frames_done as usize, done, "seed {seed}");
    }
}

/// A viewer flying (a new frame the moment the last one is done), first
/// alone, then beside a batch job of ten frames: its frames take little
/// longer than alone (interactive work first), and the job still finishes,
/// on the idle ends of the viewer's frames and the share `BATCH_FLOOR`
/// keeps for it.
#[test]
fn a_batch_job_still_finishes_while_a_viewer_flies() {
    let fly = |net: &mut Net, v: PeerId, seed: &mut u64| {
        if net.open_requests(v) == 0 {
            *seed += 1;
            net.request(v, settings(128, 96, *seed), false);
        }
    };
    let mut net = Net::new(sim::config());
    for _ in 0..2 {
        net.slave(SlaveSpec { threads: 2, us_per_pixel: 10, ..SlaveSpec::default() });
    }
    let alone = net.viewer();
    net.run_until(|n| n.core.status().slaves.len() == 2 && n.limit(alone).is_some());
    let mut seed = 0;
    while net.done_requests(alone) < 5 {
        fly(&mut net, alone, &mut seed);
        net.step();
    }
    let (flyer, job) = (net.viewer(), net.viewer_of(Work::Batch));
    net.run_until(|n| n.limit(flyer).is_some() && n.limit(job).is_some());
    let mut batch = Vec::new();
    let start = net.now;
    while batch.len() < 10 || !batch.iter().all(|&r| net.viewer_done(job, r)) {
        assert!(
            net.now < start + Duration::from_secs(120),
            "the batch job starved: {} done",
            net.done_requests(job)
        );
        fly(&mut net, flyer, &mut seed);
        while batch.len() < 10 && net.open_requests(job) < 2 {
            seed += 1;
            batch.push(net.request(job, settings(128, 96, seed), true));
        }
        net.step();
    }
    for &r in &batch {
        net.assert_exact(job, r);
    }
    let (t_alone, t_beside) = (net.mean_frame_time(alone), net.mean_frame_time(flyer));
    assert!(
        t_beside.as_secs_f64() <= 1.5 * t_alone.as_secs_f64(),
        "frames took {t_beside:?} beside the job, {t_alone:?} alone"
    );
}

/// Nobody moving: a batch job keeps its frames queued and the slaves busy.
#[test]
fn a_batch_job_takes_at_least_90_percent_of_the_cluster_while_nobody_moves() {
    let mut net = Net::new(sim::config());
    for _ in 0..3 {
        net.slave(SlaveSpec { threads: 2, us_per_pixel: 10, ..SlaveSpec::default() });
    }
    let (idle, job) = (net.viewer(), net.viewer_of(Work::Batch));
    net.run_until(|n| n.core.status().slaves.len() == 3 && n.limit(job).is_some());
    let still = net.request(idle, settings(64, 48, 1), false);
    net.run_until(|n| n.viewer_done(idle, still));
    let mut seed = 1;
    let (lanes0, busy0) = net.lanes();
    let start = net.now;
    while net.now < start + Duration::from_secs(5) {
        while net.open_requests(job) < 2 {
            seed += 1;
            net.request(job, settings(160, 120, seed), true);
        }
        net.step();
    }
    let (lanes, busy) = net.lanes();
    let utilisation = (busy - busy0) as f64 / (lanes - lanes0) as f64;
    assert!(utilisation >= 0.9, "utilisation {utilisation:.3}");
    assert!(net.done_requests(job) > 5);
}

/// A batch client that vanishes mid-job takes its frames with it: slaves
/// drop its tiles, and a viewer's frame beside it completes as if it had
/// never been there.
#[test]
fn a_batch_client_that_vanishes_mid_job_leaves_nothing_behind() {
    let mut net = Net::new(sim::config());
    let s = net.slave(SlaveSpec { threads: 2, us_per_pixel: 40, ..SlaveSpec::default() });
    let (viewer, job) = (net.viewer(), net.viewer_of(Work::Batch));
    net.run_until(|n| n.core.status().slaves.len() == 1 && n.limit(job).is_some());
    for seed in 1..=3 {
        net.request(job, settings(160, 120, seed), true);
    }
    net.run_for(20 * MS);
    let cancels = net.cancels(s);
    net.disconnect(job);
    assert!(net.cancels(s) > cancels, "the slave was told to drop the job's tiles");
    let r = net.request(viewer, settings(64, 48, 9), false);
    net.run_until(|n| n.viewer_done(viewer, r));
    net.assert_exact(viewer, r);
    assert_eq!(net.core.sched.open_frames(), Vec::<FrameId>::new(), "no frame of the job is left open");
}

/// A slave joining in the middle of a batch job is handed its tiles at once.
#[test]
fn a_slave_joining_mid_job_is_used_at_once() {
    let mut net = Net::new(sim::config());
    net.slave(SlaveSpec { threads: 1, us_per_pixel: 100, ..SlaveSpec::default() });
    let job = net.viewer_of(Work::Batch);
    net.run_until(|n| n.core.status().slaves.len() == 1 && n.limit(job).is_some());
    let frames: Vec<u64> = (1..=3).map(|seed| net.request(job, settings(160, 120, seed), true)).collect();
    net.run_for(30 * MS);
    let late = net.slave(SlaveSpec { threads: 2, ..SlaveSpec::default() });
    net.run_until(|n| n.core.status().slaves.len() == 2);
    let joined = net.now;
    net.run_until(|n| n.assignments(late) > 0);
    assert!(net.now - joined <= MS, "waited {:?}", net.now - joined);
    net.run_until(|n| frames.iter().all(|&r| n.viewer_done(job, r)));
    for r in frames {
        net.assert_exact(job, r);
    }
}

#[test]
fn a_direct_viewers_tiles_come_straight_but_a_sample_and_each_slave_hears_the_offer_once() {
    let mut net = Net::new(sim::config());
    let a = net.slave(SlaveSpec::default());
    let b = net.slave(SlaveSpec::default());
    let v = net.direct_viewer();
    net.run_until(|n| n.core.status().slaves.len() == 2);
    let (mut tiles, mut direct) = (0, 0);
    for seed in 1..=3 {
        let req = net.request(v, settings(256, 192, seed), false);
        net.run_until(|n| n.viewer_done(v, req));
        net.assert_exact(v, req);
        let last = net.core.status().last_frame.expect("a frame done");
        (tiles, direct) = (tiles + last.tiles, direct + last.direct);
    }
    assert_eq!(net.direct_tiles(v), direct, "the master counts what the viewer took straight");
    assert!(direct < tiles && direct * 10 >= tiles * 8, "{direct} of {tiles} tiles straight");
    for s in [a, b] {
        let routes: Vec<&protocol::DirectRoute> = net
            .received(s)
            .iter()
            .filter_map(|m| match m {
                Message::TileAssignment(t) => t.direct.as_deref(),
                _ => None,
            })
            .collect();
        assert!(routes.len() > 1, "slave {s} was routed {} assignments", routes.len());
        assert!(routes[0].offer.is_some(), "the first route names the viewer's offer");
        assert!(routes[1..].iter().all(|r| r.offer.is_none()), "the offer is sent once");
    }
    assert_eq!(net.core.status().refused, 0);
}

#[test]
fn a_slave_that_sends_the_masters_sample_straight_is_dropped_and_the_frame_stays_exact() {
    let mut net = Net::new(sim::config());
    net.slave(SlaveSpec::default());
    let cheat = net.slave(SlaveSpec { behaviour: Behaviour::SkipsSample, ..SlaveSpec::default() });
    let v = net.direct_viewer();
    net.run_until(|n| n.core.status().slaves.len() == 2);
    let req = net.request(v, settings(256, 192, 4), false);
    net.run_until(|n| n.viewer_done(v, req));
    net.assert_exact(v, req);
    assert!(net.is_closed(cheat));
    let why = net.rejection(cheat).unwrap();
    assert!(why.contains("through the master"), "{why}");
}

#[test]
fn a_viewer_reporting_a_tile_of_a_frame_not_its_own_direct_one_is_refused() {
    let mut net = Net::new(sim::config());
    let s = net.slave(SlaveSpec { threads: 1, ..SlaveSpec::default() });
    let owner = net.viewer();
    let liar = net.direct_viewer();
    net.run_until(|n| n.core.status().slaves.len() == 1);
    let req = net.request(owner, settings(256, 192, 2), false);
    net.run_until(|n| n.assigned(s).is_some());
    let (frame, job) = net.assigned(s).expect("a tile");
    let r = protocol::TileReceived { frame, id: job.id, slave: s, tile: job.tile, render_micros: 1 };
    net.say(liar, &Message::TileReceived(r));
    net.run_until(|n| n.is_closed(liar));
    assert!(net.rejection(liar).unwrap().contains("not its own direct frame"), "{:?}", net.rejection(liar));
    assert!(!net.is_closed(s), "the slave did nothing wrong");
    net.run_until(|n| n.viewer_done(owner, req));
    net.assert_exact(owner, req);
}

/// The rosters viewer `v` was sent, oldest first.
fn rosters(net: &Net, v: PeerId) -> Vec<&[protocol::SlaveEntry]> {
    net.received(v)
        .iter()
        .filter_map(|m| match m {
            Message::Slaves { slaves } => Some(slaves.as_slice()),
            _ => None,
        })
        .collect()
}

#[test]
fn joins_and_deaths_one_after_another_reach_viewers_as_a_roster_at_most_every_interval() {
    let mut net = Net::new(sim::config());
    let v = net.viewer();
    // Forty slaves join a millisecond apart, thirty die a millisecond apart:
    // a roster (and a status) each would be seventy lists of the cluster.
    let slaves: Vec<PeerId> = (0..40)
        .map(|_| {
            net.run_for(MS);
            net.slave(SlaveSpec::default())
        })
        .collect();
    net.run_until(|n| n.core.status().slaves.len() == 40);
    net.run_for(ROSTER_INTERVAL);
    let joined = rosters(&net, v);
    let last = joined.last().expect("a roster");
    assert_eq!(last.iter().filter(|e| e.alive).count(), 40, "the last roster lists every slave");
    // One at connection, then one per interval over the joins' 40 ms.
    assert!(joined.len() <= 3, "{} rosters for 40 joins", joined.len());
    let (told, statuses) = (joined.len(), net.statuses(v).len());

    for &s in &slaves[..30] {
        net.set_behaviour(s, Behaviour::Silent);
        net.run_for(MS);
    }
    let timeout = sim::config().scheduler.heartbeat_timeout;
    net.run_until(|n| n.core.status().deaths == 30);
    // Declared dead on time, each.
    assert!(net.core.longest_silence() <= timeout + MS, "{:?}", net.core.longest_silence());
    net.run_for(ROSTER_INTERVAL);
    let all = rosters(&net, v);
    let last = all.last().expect("a roster");
    assert_eq!(last.iter().filter(|e| e.alive).count(), 10);
    assert_eq!(last.iter().filter(|e| !e.alive).count(), DEAD_SLAVES_LISTED);
    let (rosters_for_deaths, statuses_for_deaths) = (all.len() - told, net.statuses(v).len() - statuses);
    assert!((1..=2).contains(&rosters_for_deaths), "{rosters_for_deaths} rosters for 30 deaths over 30 ms");
    // The periodic status aside (a frame open), one a roster.
    assert!(statuses_for_deaths <= 2, "{statuses_for_deaths} statuses for 30 deaths");
}

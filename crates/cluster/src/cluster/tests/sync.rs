//! Scenes on their way to slaves: compressed, in chunks, a window of them in
//! flight per slave, moved on by acknowledgements; nothing sent to a slave
//! that holds the scene.

use super::*;
use crate::scene_stream;

/// A default scene of about `bytes` bytes that compresses as a mesh file
/// does (lines of random coordinates), with `window` chunks in flight per
/// slave.
fn config(bytes: usize, window: u32) -> ClusterConfig {
    let mut cfg = sim::config();
    let mut rng = sim::Rng(0x243f_6a88_85a3_08d3);
    let mut text = Vec::with_capacity(bytes + 64);
    while text.len() < bytes {
        let mut c = || rng.below(20_000) as f64 / 1000.0 - 10.0;
        let line = format!("v {:.3} {:.3} {:.3}\n", c(), c(), c());
        text.extend_from_slice(line.as_bytes());
    }
    let mut assets = BTreeMap::new();
    assets.insert("mesh.obj".to_string(), text);
    let bundle = SceneBundle { name: "big.toml".into(), source: "# big".into(), assets };
    cfg.scene = Some(DefaultScene { bundle, camera: Camera::default(), settings: RenderSettings::default() });
    cfg.scene_window = window;
    cfg
}

/// The default scene as the master packs it.
fn packed(net: &Net) -> Arc<scene_stream::Packed> {
    let hash = net.core.scene().expect("a default scene").hash;
    net.core.scenes.packed(&hash).expect("held")
}

fn chunk_bytes(p: &scene_stream::Packed, n: u32) -> u64 {
    p.begin_frame().len() as u64 + (0..n).map(|i| p.chunk_frame(i).unwrap().len() as u64).sum::<u64>()
}

#[test]
fn a_scene_streams_within_the_window_and_acknowledgements_move_it_on() {
    let mut net = Net::new(config(4 << 20, 3));
    let p = packed(&net);
    assert!(p.header.chunks > 5, "{:?}", p.header);
    assert!(p.header.compressed_bytes * 2 < p.header.raw_bytes, "{:?}", p.header);
    let s = net.slave(SlaveSpec { behaviour: Behaviour::NeverAcks, ..SlaveSpec::default() });
    net.run_for(Duration::from_millis(200));
    assert_eq!(net.scene_chunks(s), 3, "the window");
    assert_eq!(net.core.status().scene_bytes_sent, chunk_bytes(&p, 3));
    // Two acknowledged: two more go out.
    let hash = p.header.hash;
    net.say(s, &Message::SceneAck { hash, chunks_received: 2 });
    assert_eq!(net.scene_chunks(s), 5);
    assert_eq!(net.core.status().scene_bytes_sent, chunk_bytes(&p, 5));
    // Acknowledging from here on, it gets the rest, loads it and joins.
    net.set_behaviour(s, Behaviour::Honest);
    net.say(s, &Message::SceneAck { hash, chunks_received: 5 });
    net.run_until(|n| n.core.status().slaves.len() == 1);
    assert_eq!((net.scene_chunks(s), net.scene_syncs(s)), (p.header.chunks, 1));
    assert_eq!(net.core.status().scene_bytes_sent, p.wire_bytes());
}

#[test]
fn a_stalled_slave_holds_up_no_other() {
    let mut net = Net::new(config(4 << 20, 2));
    let p = packed(&net);
    let stalled = net.slave(SlaveSpec { behaviour: Behaviour::NeverAcks, ..SlaveSpec::default() });
    let honest = net.slave(SlaveSpec::default());
    let v = net.viewer();
    net.run_until(|n| n.core.status().slaves.len() == 1);
    let req = net.request(v, settings(96, 64, 3), false);
    net.run_until(|n| n.viewer_done(v, req));
    net.assert_exact(v, req);
    assert_eq!(net.scene_chunks(stalled), 2);
    assert_eq!(net.scene_chunks(honest), p.header.chunks);
    assert_eq!(net.core.status().scene_bytes_sent, chunk_bytes(&p, 2) + p.wire_bytes());
    assert!(!net.is_closed(stalled), "heartbeating: it has till the sync timeout");
}

#[test]
fn acknowledgements_of_chunks_never_sent_or_of_another_scene_drop_the_slave() {
    type Lie = fn(SceneHash) -> Message;
    let cases: [(&str, Lie); 3] = [
        ("beyond", |hash| Message::SceneAck { hash, chunks_received: 3 }),
        ("another", |_| Message::SceneAck { hash: [9; 32], chunks_received: 1 }),
        ("backwards", |hash| Message::SceneAck { hash, chunks_received: 0 }),
    ];
    for (what, ack) in cases {
        let mut net = Net::new(config(4 << 20, 2));
        let hash = packed(&net).header.hash;
        let s = net.slave(SlaveSpec { behaviour: Behaviour::NeverAcks, ..SlaveSpec::default() });
        if what == "backwards" {
            net.say(s, &Message::SceneAck { hash, chunks_received: 2 });
        }
        net.say(s, &ack(hash));
        assert!(net.is_closed(s), "{what}");
        let why = net.rejection(s).unwrap_or_default();
        assert!(why.contains("acknowledged"), "{what}: {why}");
        let before = net.core.status().scene_bytes_sent;
        net.run_for(Duration::from_millis(50));
        assert_eq!(net.core.status().scene_bytes_sent, before, "{what}: nothing more sent");
    }
}

#[test]
fn a_slave_holding_the_scene_is_sent_no_scene_bytes_and_a_new_one_the_compressed_scene() {
    let mut net = Net::new(config(2 << 20, 4));
    let p = packed(&net);
    let fresh = net.slave(SlaveSpec::default());
    net.run_until(|n| n.core.status().slaves.len() == 1);
    let sent = net.core.status().scene_bytes_sent;
    assert_eq!(sent, p.wire_bytes());
    assert!(sent < p.header.raw_bytes / 2, "{sent} bytes sent for {} raw", p.header.raw_bytes);
    // A slave that holds the scene (a rejoin) is sent nothing.
    let cached = Some(p.header.hash);
    let rejoin = net.slave(SlaveSpec { cached, ..SlaveSpec::default() });
    net.run_until(|n| n.core.status().slaves.len() == 2);
    assert_eq!(net.core.status().scene_bytes_sent, sent);
    assert_eq!((net.scene_chunks(rejoin), net.scene_syncs(rejoin)), (0, 0));
    // And the first one, disconnected and back with the scene, neither.
    net.disconnect(fresh);
    let back = net.slave(SlaveSpec { cached, ..SlaveSpec::default() });
    net.run_until(|n| n.core.status().slaves.len() == 2);
    assert_eq!(net.core.status().scene_bytes_sent, sent);
    assert_eq!(net.scene_chunks(back), 0);
    assert_eq!(net.core.status().scene_sends, 1);
}

#[test]
fn a_scene_a_slave_asks_for_follows_the_one_it_is_being_sent() {
    // Two scenes to one slave: the second waits for the first to finish,
    // so its window never holds chunks of both.
    let mut net = Net::new(config(2 << 20, 2));
    let s = net.slave(SlaveSpec { behaviour: Behaviour::NeverAcks, ..SlaveSpec::default() });
    let p = packed(&net);
    let before = net.scene_chunks(s);
    // Asking for the scene being sent again queues nothing.
    let mut t = Transfers::new(2);
    let first = t.start(net.now, s, p.clone());
    assert!(p.header.chunks > 2);
    assert_eq!(first.len(), 3, "begin and two chunks");
    assert!(t.start(net.now, s, p.clone()).is_empty());
    let other = Arc::new(scene_stream::pack(&sim::fake_scene("other.toml", 1000)).unwrap());
    assert!(t.start(net.now, s, other.clone()).is_empty(), "queued behind the first");
    let mut got = Vec::new();
    for n in 1..=p.header.chunks {
        let acked = t.ack(net.now, s, p.header.hash, n).unwrap();
        got.extend(acked.frames);
        if n == p.header.chunks {
            assert_eq!(acked.finished, Some(p.header.hash));
        }
    }
    // The first's remaining chunks, then the second's begin and its chunk.
    assert_eq!(got.len() as u32, p.header.chunks - 2 + 1 + other.header.chunks);
    assert_eq!(got[got.len() - 2], other.begin_frame());
    assert!(t.ack(net.now, s, p.header.hash, 1).is_err(), "the first is done");
    assert_eq!(net.scene_chunks(s), before);
}

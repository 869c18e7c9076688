//! The actors end to end in one process over the in-memory transport, with a
//! fake renderer (a pixel's bytes are a hash of its coordinates and the
//! camera), so these run without the ray tracer.

use isin_actors::client::JoinError;
use isin_actors::master::{GetStatus, Master, MasterConfig};
use isin_actors::slave::{self, Pattern, SlaveOptions};
use isin_actors::viewer;
use isin_cluster::codec::{Codec, Compression};
use isin_tracer::{Camera, RenderSettings, SceneBundle};
use isin_transport::Ticket;
use isin_transport::Transport;
use isin_transport::mem::MemTransport;
use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

type Fake = Pattern;

fn pixel(cam: &Camera, x: u32, y: u32) -> [u8; 3] {
    Pattern::pixel(cam, x, y)
}

fn bundle() -> SceneBundle {
    let mut assets = BTreeMap::new();
    assets.insert("mesh.bin".to_string(), vec![42u8; 5000]);
    SceneBundle { name: "fake.toml".into(), source: "fake scene".into(), assets }
}

fn settings(w: u32, h: u32) -> RenderSettings {
    RenderSettings { width: w, height: h, ..RenderSettings::default() }
}

async fn start_master(t: &MemTransport, token: &str) -> (actix::Addr<Master>, Ticket) {
    start_master_with(t, token, Compression::Auto).await
}

async fn start_master_with(
    t: &MemTransport,
    token: &str,
    compression: Compression,
) -> (actix::Addr<Master>, Ticket) {
    let mut cfg = MasterConfig::new(token.into(), bundle(), Camera::default(), settings(64, 48)).unwrap();
    cfg.cluster.compression = compression;
    let listener = t.listen("master").await.unwrap();
    let addr = Master::new(cfg).unwrap().serve(listener);
    // The kind is not read: the test hands the in-memory transport to the peer itself.
    (
        addr,
        Ticket {
            transport: isin_transport::TransportKind::TcpInsecure,
            token: token.into(),
            addr: "master".into(),
            fingerprint: None,
        },
    )
}

fn spawn_slave(t: &MemTransport, ticket: &Ticket, name: &str, fake: Arc<Fake>) {
    let opts = SlaveOptions { name: name.into(), threads: 2, ..SlaveOptions::default() };
    let t: Arc<dyn Transport> = Arc::new(t.clone());
    let ticket = ticket.clone();
    actix::spawn(async move {
        let _ = slave::run(t, ticket, opts, fake).await;
    });
}

async fn wait_slaves(master: &actix::Addr<Master>, n: usize) {
    for _ in 0..2000 {
        if master.send(GetStatus).await.unwrap().slaves.len() >= n {
            return;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    panic!("{n} slaves never joined");
}

#[actix::test]
async fn frames_through_two_slaves_are_exact_and_scene_is_sent_once_each() {
    let t = MemTransport::new();
    let (master, ticket) = start_master(&t, "s3cret").await;
    let fakes = [Arc::new(Fake::default()), Arc::new(Fake::default())];
    spawn_slave(&t, &ticket, "a", fakes[0].clone());
    spawn_slave(&t, &ticket, "b", fakes[1].clone());
    wait_slaves(&master, 2).await;

    let (v, scene, mut events) = viewer::connect(&t, &ticket, "viewer").await.unwrap();
    assert_eq!(scene.unwrap().name, "fake.toml");
    for round in 0..3 {
        let mut cam = Camera::default();
        cam.eye.z += round as f32;
        let s = settings(200, 150);
        let (frame, stats) = viewer::collect_frame(&v, &mut events, cam, s).await.unwrap();
        for y in 0..150 {
            for x in 0..200 {
                let i = ((y * 200 + x) * 3) as usize;
                assert_eq!(frame.rgb[i..i + 3], pixel(&cam, x, y), "pixel {x},{y} round {round}");
            }
        }
        assert!(stats.tiles >= 35);
    }
    for f in &fakes {
        assert_eq!(f.loads.load(Ordering::Relaxed), 1);
        assert!(f.tiles.load(Ordering::Relaxed) > 0, "both slaves rendered");
    }
    let status = master.send(GetStatus).await.unwrap();
    assert_eq!(status.frames_done, 3);
    assert!(status.wire.bytes_sent > 3 * 200 * 150 * 3, "tiles forwarded to the viewer are counted");
}

#[actix::test]
async fn a_slave_sending_a_wrong_sized_tile_is_dropped_and_its_tiles_rendered_by_others() {
    use isin_actors::client;
    use isin_cluster::protocol::{self, Message, TileResult};
    let t = MemTransport::new();
    let (master, ticket) = start_master(&t, "tok").await;
    // A hand-driven slave that lies about a tile's size.
    // It offers no codec, as a build without compression would: raw it is.
    let (mut conn, welcome) =
        client::handshake(&t, &ticket, client::Join::slave("liar", 1, &[], &[])).await.unwrap();
    assert_eq!(welcome.codec, Codec::Raw);
    let max = protocol::DEFAULT_MAX_FRAME;
    let hash = welcome.scene.as_ref().map(|s| s.hash).expect("a default scene");
    isin_actors::slave::receive_scene(&mut conn, hash).await.unwrap();
    client::send_message(&conn, &Message::Ready { hash: welcome.scene.map(|s| s.hash) }).unwrap();
    wait_slaves(&master, 1).await;
    let (v, _, mut events) = viewer::connect(&t, &ticket, "viewer").await.unwrap();
    let req = v.send(viewer::RequestFrame { camera: Camera::default(), settings: settings(64, 64) });
    req.await.unwrap();
    let assignment = loop {
        match client::recv_message(&mut conn, max, Duration::from_secs(10)).await.unwrap() {
            Message::TileAssignment(a) => break a,
            Message::Heartbeat => {}
            other => panic!("unexpected {}", other.kind()),
        }
    };
    let job = assignment.tiles[0];
    let lie = TileResult {
        frame: assignment.frame,
        id: job.id,
        tile: job.tile,
        render_micros: 1,
        codec: Codec::Raw,
        pixels: vec![0u8; 5].into(),
    };
    client::send_message(&conn, &Message::TileResult(lie)).unwrap();
    let reason = loop {
        match client::recv_message(&mut conn, max, Duration::from_secs(10)).await {
            Ok(Message::Reject { reason }) => break reason,
            Ok(_) => {}
            Err(e) => panic!("connection ended without a reason: {e}"),
        }
    };
    assert!(reason.contains("bytes"), "{reason}");
    assert!(matches!(
        client::recv_message(&mut conn, max, Duration::from_secs(10)).await,
        Err(JoinError::Closed | JoinError::Transport(_))
    ));
    // An honest slave finishes the frame, the liar's tiles included.
    spawn_slave(&t, &ticket, "honest", Arc::new(Fake::default()));
    let (mut covered, mut told) = (0, false);
    while let Some(ev) = events.recv().await {
        match ev {
            viewer::ViewerEvent::Tile { tile, pixels, .. } => {
                assert_eq!(pixels.len(), tile.pixel_count() * 3);
                covered += tile.pixel_count();
            }
            viewer::ViewerEvent::FrameDone { .. } => break,
            // The liar was the only slave: the frame waited for the next.
            viewer::ViewerEvent::Notice(m) => told |= m.contains("no slaves connected"),
            other => panic!("unexpected {other:?}"),
        }
    }
    assert_eq!(covered, 64 * 64);
    assert!(told, "the viewer was not told its frame waited");
    assert_eq!(master.send(GetStatus).await.unwrap().deaths, 1);
}

#[actix::test]
async fn a_request_under_the_callers_number_comes_back_tagged_with_it_and_the_slaves() {
    let t = MemTransport::new();
    let (master, ticket) = start_master(&t, "tok").await;
    spawn_slave(&t, &ticket, "left", Arc::default());
    spawn_slave(&t, &ticket, "right", Arc::default());
    wait_slaves(&master, 2).await;
    let slaves: BTreeMap<String, u64> =
        master.send(GetStatus).await.unwrap().slaves.iter().map(|s| (s.name.clone(), s.id)).collect();
    let (v, _, mut events) = viewer::connect(&t, &ticket, "gui").await.unwrap();
    // The caller's own numbers, as a window's frame ids; a later actor-numbered
    // request is numbered above them.
    let s = settings(256, 128);
    v.do_send(viewer::RequestFrameAs { request: 41, camera: Camera::default(), settings: s });
    let mut by_slave: BTreeMap<u64, usize> = BTreeMap::new();
    loop {
        match events.recv().await.unwrap() {
            viewer::ViewerEvent::Tile { request, slave, slave_name, .. } => {
                assert_eq!(request, 41);
                assert_eq!(slaves.get(&slave_name), Some(&slave), "{slave_name} is slave {slave}");
                *by_slave.entry(slave).or_default() += 1;
            }
            viewer::ViewerEvent::FrameDone { request, stats } => {
                assert_eq!(request, 41);
                assert_eq!(by_slave.values().sum::<usize>(), stats.tiles as usize);
                break;
            }
            other => panic!("{other:?}"),
        }
    }
    assert_eq!(by_slave.len(), 2, "both slaves rendered tiles: {by_slave:?}");
    let next = v.send(viewer::RequestFrame { camera: Camera::default(), settings: s }).await.unwrap();
    assert_eq!(next, 42);
    let _ = v.send(viewer::Disconnect).await;
    // The event stream ends after Disconnect (at most a Closed note first).
    while let Some(ev) = events.recv().await {
        assert!(matches!(ev, viewer::ViewerEvent::Closed(_)), "{ev:?} after Disconnect");
    }
}

#[actix::test]
async fn codecs_are_negotiated_at_join_and_every_one_delivers_exact_frames() {
    use isin_actors::client;
    let all = Codec::ALL;
    for (compression, best) in [
        (Compression::Auto, Codec::ALL[0]),
        (Compression::Use(Codec::Raw), Codec::Raw),
        (Compression::Use(Codec::Lz4), Codec::Lz4),
        (Compression::Use(Codec::Qoi), Codec::Qoi),
    ] {
        let t = MemTransport::new();
        let (master, ticket) = start_master_with(&t, "tok", compression).await;
        // What the master picks for a peer offering everything, one offering
        // only LZ4, and an old one offering nothing.
        for (offer, want) in [
            (&all[..], best),
            (
                &[Codec::Lz4][..],
                if matches!(best, Codec::Lz4) || compression == Compression::Auto {
                    Codec::Lz4
                } else {
                    Codec::Raw
                },
            ),
            (&[][..], Codec::Raw),
        ] {
            let (conn, welcome) = client::handshake(
                &t,
                &ticket,
                client::Join { codecs: offer, ..client::Join::viewer("probe", Default::default()) },
            )
            .await
            .unwrap();
            assert_eq!(welcome.codec, want, "{compression:?} offered {offer:?}");
            conn.sender.close();
        }
        // A new and an old slave render together; the frame is exact.
        spawn_slave(&t, &ticket, "new", Arc::new(Fake::default()));
        let old =
            SlaveOptions { name: "old".into(), threads: 1, codecs: Vec::new(), ..SlaveOptions::default() };
        let (tt, tk) = (Arc::new(t.clone()) as Arc<dyn Transport>, ticket.clone());
        actix::spawn(async move {
            let _ = slave::run(tt, tk, old, Arc::new(Fake::default())).await;
        });
        wait_slaves(&master, 2).await;
        let (v, _, mut events) = viewer::connect(&t, &ticket, "viewer").await.unwrap();
        let cam = Camera::default();
        let (frame, stats) = viewer::collect_frame(&v, &mut events, cam, settings(320, 240)).await.unwrap();
        for y in 0..240 {
            for x in 0..320 {
                let i = ((y * 320 + x) * 3) as usize;
                assert_eq!(frame.rgb[i..i + 3], pixel(&cam, x, y), "pixel {x},{y} with {compression:?}");
            }
        }
        assert_eq!(stats.per_slave.len(), 2, "both slaves rendered: {:?}", stats.per_slave);
    }
}

#[actix::test]
async fn queued_frames_are_pipelined_and_each_comes_back_exact_in_order() {
    let t = MemTransport::new();
    let (master, ticket) = start_master(&t, "tok").await;
    spawn_slave(&t, &ticket, "a", Arc::default());
    spawn_slave(&t, &ticket, "b", Arc::default());
    wait_slaves(&master, 2).await;
    let (v, _, mut events) = viewer::connect(&t, &ticket, "replay").await.unwrap();
    let (w, h) = (160u32, 96u32);
    let cams: Vec<Camera> = (0..3)
        .map(|i| {
            let mut c = Camera::default();
            c.eye.z += i as f32;
            c
        })
        .collect();
    // All three queued at once: the slaves get the tiles of frame k + 1 while
    // frame k's are still queued on them, and must render both.
    let mut requests = Vec::new();
    for &camera in &cams {
        requests.push(
            v.send(viewer::QueueFrame { camera, settings: settings(w, h), job_frame: None }).await.unwrap(),
        );
    }
    let mut frames: BTreeMap<u64, Vec<u8>> =
        requests.iter().map(|&r| (r, vec![0; (w * h * 3) as usize])).collect();
    let mut done = Vec::new();
    let collect = async {
        while done.len() < requests.len() {
            match events.recv().await.expect("viewer hears back") {
                viewer::ViewerEvent::Tile { request, tile, pixels, .. } => {
                    let f = frames.get_mut(&request).expect("a tile of a requested frame");
                    for row in 0..tile.h {
                        let src = (row * tile.w * 3) as usize;
                        let dst = (((tile.y + row) * w + tile.x) * 3) as usize;
                        f[dst..dst + (tile.w * 3) as usize]
                            .copy_from_slice(&pixels[src..src + (tile.w * 3) as usize]);
                    }
                }
                viewer::ViewerEvent::FrameDone { request, .. } => done.push(request),
                other => panic!("{other:?}"),
            }
        }
    };
    tokio::time::timeout(Duration::from_secs(30), collect).await.expect("every queued frame completes");
    let mut sorted = done.clone();
    sorted.sort_unstable();
    assert_eq!(sorted, requests, "one FrameDone per queued frame");
    for (i, r) in requests.iter().enumerate() {
        let f = &frames[r];
        for y in 0..h {
            for x in 0..w {
                let p = ((y * w + x) * 3) as usize;
                assert_eq!(f[p..p + 3], pixel(&cams[i], x, y), "frame {i} pixel {x},{y}");
            }
        }
    }
    let status = master.send(GetStatus).await.unwrap();
    assert_eq!(status.frames_done, 3);
}

//! The actors end to end in one process over the in-memory transport, with a
//! fake renderer (a pixel's bytes are a hash of its coordinates and the
//! camera), so these run without the ray tracer.

use isin_actors::auth::Ticket;
use isin_actors::client::JoinError;
use isin_actors::master::{GetStatus, Master, MasterConfig};
use isin_actors::slave::{self, Renderer, SlaveOptions};
use isin_actors::transport::Transport;
use isin_actors::transport::mem::MemTransport;
use isin_actors::viewer;
use isin_tracer::{Camera, RenderSettings, SceneBundle, Tile};
use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

/// Pixels from coordinates; counts loads and tiles.
#[derive(Default)]
struct Fake {
    loads: AtomicU64,
    tiles: AtomicU64,
}

fn pixel(cam: &Camera, x: u32, y: u32) -> [u8; 3] {
    let h = (x as u64).wrapping_mul(0x9e37_79b9)
        ^ (y as u64).wrapping_mul(0x85eb_ca6b)
        ^ cam.eye.z.to_bits() as u64;
    [h as u8, (h >> 8) as u8, (h >> 16) as u8]
}

impl Renderer for Fake {
    type Scene = String;

    fn load(&self, bundle: SceneBundle) -> Result<String, String> {
        self.loads.fetch_add(1, Ordering::Relaxed);
        Ok(bundle.source)
    }

    fn render(&self, _: &String, camera: &Camera, _: &RenderSettings, t: Tile) -> Vec<u8> {
        self.tiles.fetch_add(1, Ordering::Relaxed);
        let mut out = Vec::with_capacity(t.pixel_count() * 3);
        for y in t.y..t.y + t.h {
            for x in t.x..t.x + t.w {
                out.extend_from_slice(&pixel(camera, x, y));
            }
        }
        out
    }
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
    let cfg = MasterConfig::new(token.into(), bundle(), Camera::default(), settings(64, 48));
    let listener = t.listen("master").await.unwrap();
    let addr = Master::new(cfg).unwrap().serve(listener);
    (addr, Ticket { transport: "mem".into(), token: token.into(), addr: "master".into(), fingerprint: None })
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
    assert_eq!(scene.name, "fake.toml");
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
async fn wrong_token_is_refused_with_a_clear_message_and_no_scene() {
    let t = MemTransport::new();
    let (master, ticket) = start_master(&t, "right").await;
    let wrong = Ticket { token: "wrong".into(), ..ticket.clone() };
    match viewer::connect(&t, &wrong, "intruder").await {
        Err(JoinError::Rejected(reason)) => assert!(reason.contains("wrong token"), "{reason}"),
        other => panic!("expected a refusal, got {:?}", other.map(|_| ())),
    }
    let fake = Arc::new(Fake::default());
    let opts = SlaveOptions { name: "intruder".into(), threads: 1, ..SlaveOptions::default() };
    let err = slave::run(Arc::new(t.clone()), wrong, opts, fake.clone()).await.unwrap_err();
    assert!(matches!(err, JoinError::Rejected(_)), "{err}");
    assert_eq!(fake.loads.load(Ordering::Relaxed), 0, "no scene reached the intruder");
    let status = master.send(GetStatus).await.unwrap();
    assert_eq!(status.refused, 2);
    assert!(status.slaves.is_empty());
}

#[actix::test]
async fn slave_joining_mid_session_gets_tiles() {
    let t = MemTransport::new();
    let (master, ticket) = start_master(&t, "tok").await;
    let first = Arc::new(Fake::default());
    spawn_slave(&t, &ticket, "first", first.clone());
    wait_slaves(&master, 1).await;
    let (v, _, mut events) = viewer::connect(&t, &ticket, "viewer").await.unwrap();
    viewer::collect_frame(&v, &mut events, Camera::default(), settings(64, 64)).await.unwrap();
    let late = Arc::new(Fake::default());
    spawn_slave(&t, &ticket, "late", late.clone());
    wait_slaves(&master, 2).await;
    viewer::collect_frame(&v, &mut events, Camera::default(), settings(320, 240)).await.unwrap();
    assert!(late.tiles.load(Ordering::Relaxed) > 0, "the late slave rendered tiles");
}

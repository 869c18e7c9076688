//! The real master, slave and viewer actors over QUIC in one process, with a
//! fake renderer (a pixel's bytes are a hash of its coordinates and the
//! camera). Checks what the ordering rules must preserve for the protocol:
//! the handshake and scene sync, every tile before `FrameDone`, and a slave
//! that vanishes being noticed through the idle timeout.

mod relay;

use isin_actors::master::{GetStatus, Master, MasterConfig};
use isin_actors::slave::{self, Pattern, SlaveOptions};
use isin_actors::viewer;
use isin_tracer::{Camera, RenderSettings, SceneBundle};
use isin_transport::Ticket;
use isin_transport::Transport;
use isin_transport_quic::QuicTransport;
use isin_transport_quic::tls::Identity;
use relay::Relay;
use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

type Fake = Pattern;

fn pixel(cam: &Camera, x: u32, y: u32) -> [u8; 3] {
    Pattern::pixel(cam, x, y)
}

fn settings(w: u32, h: u32) -> RenderSettings {
    RenderSettings { width: w, height: h, ..RenderSettings::default() }
}

struct Setup {
    master: actix::Addr<Master>,
    ticket: Ticket,
    client: QuicTransport,
}

async fn start_master() -> Setup {
    let id = Identity::generate().unwrap();
    let server = QuicTransport::server(&id).unwrap();
    let mut assets = BTreeMap::new();
    // Larger than a QUIC stream window: the scene crosses the control stream in pieces.
    assets.insert("mesh.bin".to_string(), (0..3_000_000u32).map(|i| (i % 251) as u8).collect());
    let bundle = SceneBundle { name: "fake.toml".into(), source: "fake scene".into(), assets };
    let cfg = MasterConfig::new("tok".into(), bundle, Camera::default(), settings(64, 48)).unwrap();
    let listener = server.listen("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr();
    let master = Master::new(cfg).unwrap().serve(listener);
    let ticket: Ticket = format!("isin+quic://tok@{addr}?fp={}", id.fingerprint()).parse().unwrap();
    Setup { master, ticket, client: QuicTransport::client(id.fingerprint()).unwrap() }
}

fn spawn_slave(t: &QuicTransport, ticket: &Ticket, name: &str, fake: Arc<Fake>) {
    let opts =
        SlaveOptions { name: name.into(), threads: 2, max_attempts: Some(1), ..SlaveOptions::default() };
    let t: Arc<dyn Transport> = Arc::new(t.clone());
    let ticket = ticket.clone();
    actix::spawn(async move {
        let _ = slave::run(t, ticket, opts, fake).await;
    });
}

/// Polls the master until `pred` holds on its status (bounded).
async fn wait_until(
    master: &actix::Addr<Master>,
    what: &str,
    pred: impl Fn(&isin_actors::master::MasterStatus) -> bool,
) {
    let t0 = Instant::now();
    loop {
        if pred(&master.send(GetStatus).await.unwrap()) {
            return;
        }
        assert!(t0.elapsed() < Duration::from_secs(30), "timed out waiting for {what}");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

fn check(frame: &isin_tracer::Frame, cam: &Camera, w: u32, h: u32) {
    for y in 0..h {
        for x in 0..w {
            let i = ((y * w + x) * 3) as usize;
            assert_eq!(frame.rgb[i..i + 3], pixel(cam, x, y), "pixel {x},{y}");
        }
    }
}

#[actix::test]
async fn frames_through_two_slaves_over_quic_are_exact() {
    let s = start_master().await;
    let fakes = [Arc::new(Fake::default()), Arc::new(Fake::default())];
    spawn_slave(&s.client, &s.ticket, "a", fakes[0].clone());
    spawn_slave(&s.client, &s.ticket, "b", fakes[1].clone());
    wait_until(&s.master, "2 slaves", |st| st.slaves.len() == 2).await;
    let (v, scene, mut events) = viewer::connect(&s.client, &s.ticket, "viewer").await.unwrap();
    assert_eq!(scene.unwrap().name, "fake.toml");
    for round in 0..3 {
        let mut cam = Camera::default();
        cam.eye.z += round as f32;
        let (frame, stats) = viewer::collect_frame(&v, &mut events, cam, settings(320, 240)).await.unwrap();
        check(&frame, &cam, 320, 240);
        assert!(stats.tiles > 10);
    }
    for f in &fakes {
        assert_eq!(f.loads.load(Ordering::Relaxed), 1, "the scene arrived once, whole");
        assert!(f.tiles.load(Ordering::Relaxed) > 0, "both slaves rendered");
    }
    let st = s.master.send(GetStatus).await.unwrap();
    assert_eq!((st.frames_done, st.refused, st.deaths), (3, 0, 0));
}

#[actix::test]
async fn a_slave_that_vanishes_is_dropped_and_frames_go_on() {
    let s = start_master().await;
    let steady = Arc::new(Fake::default());
    spawn_slave(&s.client, &s.ticket, "steady", steady.clone());
    // The second slave reaches the master through a relay that will go silent.
    let relay = Relay::start(s.ticket.addr.parse().unwrap(), 0, 3).await;
    let via = Ticket { addr: relay.addr.to_string(), ..s.ticket.clone() };
    let doomed = Arc::new(Fake::default());
    spawn_slave(&s.client, &via, "doomed", doomed.clone());
    wait_until(&s.master, "2 slaves", |st| st.slaves.len() == 2).await;
    let (v, _, mut events) = viewer::connect(&s.client, &s.ticket, "viewer").await.unwrap();
    let cam = Camera::default();
    let (frame, _) = viewer::collect_frame(&v, &mut events, cam, settings(160, 120)).await.unwrap();
    check(&frame, &cam, 160, 120);
    relay.go_silent();
    let t0 = Instant::now();
    wait_until(&s.master, "the vanished slave dropped", |st| st.slaves.len() == 1 && st.deaths == 1).await;
    // Noticed by the transport's idle timeout or the heartbeat timeout, both seconds.
    assert!(t0.elapsed() < Duration::from_secs(10), "{:?}", t0.elapsed());
    let (frame, _) = viewer::collect_frame(&v, &mut events, cam, settings(160, 120)).await.unwrap();
    check(&frame, &cam, 160, 120);
    // A vanished peer is a closed connection, not a misbehaving one.
    assert_eq!(s.master.send(GetStatus).await.unwrap().refused, 0);
}

#[actix::test]
async fn a_slave_joining_mid_session_over_quic_gets_tiles() {
    let s = start_master().await;
    let first = Arc::new(Fake::default());
    spawn_slave(&s.client, &s.ticket, "first", first.clone());
    wait_until(&s.master, "1 slave", |st| st.slaves.len() == 1).await;
    let (v, _, mut events) = viewer::connect(&s.client, &s.ticket, "viewer").await.unwrap();
    let cam = Camera::default();
    viewer::collect_frame(&v, &mut events, cam, settings(64, 64)).await.unwrap();
    let late = Arc::new(Fake::default());
    spawn_slave(&s.client, &s.ticket, "late", late.clone());
    wait_until(&s.master, "2 slaves", |st| st.slaves.len() == 2).await;
    let (frame, _) = viewer::collect_frame(&v, &mut events, cam, settings(320, 240)).await.unwrap();
    check(&frame, &cam, 320, 240);
    assert_eq!(late.loads.load(Ordering::Relaxed), 1, "the late slave received the scene");
    assert!(late.tiles.load(Ordering::Relaxed) > 0, "the late slave rendered tiles");
}

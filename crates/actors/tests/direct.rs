//! Tiles that skip the master, end to end in one process over the in-memory
//! transport: slaves deliver a direct viewer's tiles to it, the master sees
//! a sample and the viewer's small `TileReceived`s, and the frames are exact; a slave
//! that cannot reach the viewer, and a peer without the key, change nothing
//! the viewer shows.

use isin_actors::master::{GetStatus, Master, MasterConfig};
use isin_actors::slave::{self, Dialer, Pattern, SlaveOptions};
use isin_actors::viewer::{self, DirectListener, Setup, ViewerEvent};
use isin_cluster::protocol::{self, DirectTile, FrameTile, Message};
use isin_cluster::scheduler::Work;
use isin_tracer::{Camera, Frame, RenderSettings, SceneBundle, Tile};
use isin_transport::mem::MemTransport;
use isin_transport::{Ticket, Transport, TransportKind};
use serde_bytes::ByteBuf;
use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;

const TOKEN: &str = "direct";

async fn start_master(t: &MemTransport) -> (actix::Addr<Master>, Ticket) {
    let mut assets = BTreeMap::new();
    assets.insert("mesh.bin".to_string(), vec![42u8; 5000]);
    let bundle = SceneBundle { name: "fake.toml".into(), source: "fake scene".into(), assets };
    let settings = RenderSettings { width: 64, height: 48, ..RenderSettings::default() };
    let cfg = MasterConfig::new(TOKEN.into(), bundle, Camera::default(), settings).unwrap();
    let addr = Master::new(cfg).unwrap().serve(t.listen("master").await.unwrap());
    let ticket = Ticket {
        transport: TransportKind::TcpInsecure,
        token: TOKEN.into(),
        addr: "master".into(),
        fingerprint: None,
    };
    (addr, ticket)
}

/// A slave whose dialer reaches viewers over `t` (or fails, `reach` false).
fn spawn_slave(t: &MemTransport, ticket: &Ticket, name: &str, reach: bool) {
    let mem = t.clone();
    let dialer = Dialer::new(move |fingerprint| {
        assert!(fingerprint.is_none(), "a plaintext offer has no fingerprint");
        if reach {
            Ok(Arc::new(mem.clone()) as Arc<dyn Transport>)
        } else {
            Err("no route to the viewer".into())
        }
    });
    let opts =
        SlaveOptions { name: name.into(), threads: 2, direct: Some(dialer), ..SlaveOptions::default() };
    let (t, ticket): (Arc<dyn Transport>, _) = (Arc::new(t.clone()), ticket.clone());
    actix::spawn(async move {
        let _ = slave::run(t, ticket, opts, Arc::new(Pattern::default())).await;
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

fn assert_exact(frame: &Frame, cam: &Camera) {
    for y in 0..frame.height {
        for x in 0..frame.width {
            let i = ((y * frame.width + x) * 3) as usize;
            assert_eq!(frame.rgb[i..i + 3], Pattern::pixel(cam, x, y), "pixel {x},{y}");
        }
    }
}

fn setup(name: &str) -> Setup<'_> {
    Setup { name, work: Work::Interactive, scene: None, job: None }
}

#[actix::test]
async fn a_direct_viewers_tiles_skip_the_master_but_a_sample_and_every_frame_is_exact() {
    let t = MemTransport::new();
    let (master, ticket) = start_master(&t).await;
    spawn_slave(&t, &ticket, "a", true);
    spawn_slave(&t, &ticket, "b", true);
    wait_slaves(&master, 2).await;
    let direct = DirectListener::bind(&t, "viewer", None).await.unwrap();
    let c = viewer::connect_direct(&t, &ticket, setup("gui"), direct).await.unwrap();
    let (v, mut events) = (c.addr, c.events);
    let s = RenderSettings { width: 640, height: 480, ..RenderSettings::default() };
    let (mut tiles, mut direct, mut bytes_in) = (0, 0, 0);
    for round in 0..4 {
        let mut cam = Camera::default();
        cam.eye.x += round as f32;
        let (frame, stats) = viewer::collect_frame(&v, &mut events, cam, s).await.unwrap();
        assert_exact(&frame, &cam);
        (tiles, direct, bytes_in) = (tiles + stats.tiles, direct + stats.direct, bytes_in + stats.bytes_in);
    }
    // The first tiles go through the master while the links are dialled;
    // after that all but about one in sixteen go straight.
    assert!(direct > 0 && direct < tiles, "{direct} of {tiles} tiles direct");
    assert!(direct * 10 >= tiles * 7, "only {direct} of {tiles} tiles direct");
    let pixel_bytes = 4 * 640 * 480 * 3;
    assert!(bytes_in * 4 < pixel_bytes, "the master received {bytes_in} bytes for {pixel_bytes} of pixels");
}

#[actix::test]
async fn a_slave_that_cannot_reach_the_viewer_sends_its_tiles_through_the_master() {
    let t = MemTransport::new();
    let (master, ticket) = start_master(&t).await;
    spawn_slave(&t, &ticket, "walled", false);
    wait_slaves(&master, 1).await;
    let direct = DirectListener::bind(&t, "viewer", None).await.unwrap();
    let c = viewer::connect_direct(&t, &ticket, setup("gui"), direct).await.unwrap();
    let (v, mut events) = (c.addr, c.events);
    let s = RenderSettings { width: 200, height: 150, ..RenderSettings::default() };
    for round in 0..2 {
        let mut cam = Camera::default();
        cam.eye.z += round as f32;
        let (frame, stats) = viewer::collect_frame(&v, &mut events, cam, s).await.unwrap();
        assert_exact(&frame, &cam);
        assert_eq!(stats.direct, 0);
        assert!(stats.bytes_in > 200 * 150, "the pixels came through the master");
    }
}

#[actix::test]
async fn the_viewer_lets_in_only_the_key_and_only_tiles_of_its_own_frames() {
    let t = MemTransport::new();
    let (master, ticket) = start_master(&t).await;
    let direct = DirectListener::bind(&t, "viewer", None).await.unwrap();
    let key = direct.offer().key;
    let c = viewer::connect_direct(&t, &ticket, setup("gui"), direct).await.unwrap();
    let (v, mut events) = (c.addr, c.events);
    let send =
        |conn: &isin_transport::Connection, m: &Message| conn.sender.send(protocol::encode(m).unwrap());
    let tile = |request| {
        Message::DirectTile(DirectTile {
            frame: 1,
            id: 0,
            tile: FrameTile {
                request,
                slave: 7,
                slave_name: "forger".into(),
                tile: Tile { x: 0, y: 0, w: 2, h: 1 },
                codec: isin_cluster::codec::Codec::Raw,
                pixels: ByteBuf::from(vec![255u8; 6]),
            },
            render_micros: 1,
        })
    };
    // The wrong key: closed before any tile is read.
    let mut wrong = t.connect("viewer").await.unwrap();
    send(&wrong, &Message::DirectHello { key: [0; 32], slave: 7 }).unwrap();
    let _ = send(&wrong, &tile(1));
    assert!(matches!(wrong.receiver.recv().await, None | Some(Err(_))), "a wrong key is let in");
    // The right key but a request the viewer never made: closed, unacknowledged.
    let mut right = t.connect("viewer").await.unwrap();
    send(&right, &Message::DirectHello { key, slave: 7 }).unwrap();
    send(&right, &tile(5)).unwrap();
    assert!(matches!(right.receiver.recv().await, None | Some(Err(_))), "a tile of no request is taken");
    // Its own frame (no slave yet: its tiles wait) takes a tile in it, once.
    let s = RenderSettings { width: 16, height: 8, ..RenderSettings::default() };
    let request = v.send(viewer::RequestFrame { camera: Camera::default(), settings: s }).await.unwrap();
    let mut ok = t.connect("viewer").await.unwrap();
    send(&ok, &Message::DirectHello { key, slave: 7 }).unwrap();
    for _ in 0..2 {
        send(&ok, &tile(request)).unwrap();
        let ack = ok.receiver.recv().await.expect("acknowledged").unwrap();
        assert_eq!(protocol::decode(&ack, 1 << 10).unwrap(), Message::DirectAck { frame: 1, id: 0 });
    }
    // A tile is passed on before it is acknowledged: both acks are in, so
    // whatever the viewer showed of them is in its event stream already.
    let mut shown = 0;
    while let Ok(e) = events.try_recv() {
        match e {
            ViewerEvent::Tile { request: r, slave, .. } => {
                assert_eq!((r, slave), (request, 7));
                shown += 1;
            }
            ViewerEvent::Notice(_) => {}
            other => panic!("unexpected {other:?}"),
        }
    }
    assert_eq!(shown, 1, "a tile that came twice is shown once");
    drop(master);
}

//! A tile of a frame far older than the frames a slave renders now is still
//! rendered: a batch frame stays open while viewers run through many frames
//! (frame numbers are the master's, over all clients), so when its tile is
//! handed out again — its first slave died — the slave that gets it has seen
//! far newer frames. (Found by `isin bench chaos`: such a slave skipped the
//! tile as "long gone", never answered for it, and the batch job stalled
//! until the master restarted.)

use isin_actors::client;
use isin_actors::master::{GetStatus, Master, MasterConfig};
use isin_actors::slave::{self, Pattern, SlaveOptions};
use isin_actors::viewer::{self, ViewerEvent};
use isin_cluster::codec::Codec;
use isin_cluster::protocol::Message;
use isin_cluster::scheduler::Work;
use isin_tracer::{Camera, RenderSettings, SceneBundle};
use isin_transport::Transport;
use isin_transport::mem::MemTransport;
use isin_transport::{Ticket, TransportKind};
use std::sync::Arc;
use std::time::Duration;

/// The next message but heartbeats.
async fn next(conn: &mut isin_transport::Connection) -> Message {
    loop {
        match client::recv_message(conn, 1 << 20, Duration::from_secs(10)).await.unwrap() {
            Message::Heartbeat => {}
            m => return m,
        }
    }
}

fn settings(w: u32, h: u32) -> RenderSettings {
    RenderSettings { width: w, height: h, ..RenderSettings::default() }
}

#[actix::test]
async fn a_requeued_tile_of_an_old_batch_frame_is_rendered_by_a_slave_far_ahead() {
    let t = MemTransport::new();
    let bundle = SceneBundle { name: "fake.toml".into(), source: "fake".into(), ..Default::default() };
    let mut cfg = MasterConfig::new("tok".into(), bundle, Camera::default(), settings(16, 16)).unwrap();
    // No copies of A's tile to B: it reaches B only when A dies.
    cfg.cluster.scheduler.duplicate_stragglers = false;
    let master = Master::new(cfg).unwrap().serve(t.listen("master").await.unwrap());
    // The kind is not read: the test hands the in-memory transport to the peers itself.
    let ticket = Ticket {
        transport: TransportKind::TcpInsecure,
        token: "tok".into(),
        addr: "master".into(),
        fingerprint: None,
    };

    // Slave A, by hand: takes the batch frame's only tile and sits on it.
    let (mut a, welcome) =
        client::handshake(&t, &ticket, client::Join::slave("a", 1, &[], &[Codec::Raw])).await.unwrap();
    let hash = welcome.scene.expect("the master has a default scene").hash;
    slave::receive_scene(&mut a, hash).await.unwrap();
    client::send_message(&a, &Message::Ready { hash: Some(hash) }).unwrap();

    let mut batch_camera = Camera::default();
    batch_camera.advance(1.0);
    let (batch, _, mut batch_events) = viewer::connect_as(&t, &ticket, "batch", Work::Batch).await.unwrap();
    let request = batch
        .send(viewer::QueueFrame { camera: batch_camera, settings: settings(16, 16), job_frame: None })
        .await
        .unwrap();
    let old = loop {
        match next(&mut a).await {
            Message::TileAssignment(asg) => break asg.frame,
            Message::Slaves { .. } | Message::Status(_) => {}
            m => panic!("slave a got {} before its tile", m.kind()),
        }
    };

    // Slave B joins and renders a viewer's frames, far newer than the batch frame.
    let transport: Arc<dyn Transport> = Arc::new(t.clone());
    let opts = SlaveOptions { name: "b".into(), threads: 1, ..SlaveOptions::default() };
    let tk = ticket.clone();
    actix::spawn(async move {
        let _ = slave::run(transport, tk, opts, Arc::new(Pattern::default())).await;
    });
    for _ in 0..2000 {
        if master.send(GetStatus).await.unwrap().slaves.len() == 2 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    let (v, _, mut events) = viewer::connect(&t, &ticket, "gui").await.unwrap();
    for i in 0..40 {
        let mut camera = Camera::default();
        camera.advance(-(i as f32) * 0.01);
        tokio::time::timeout(
            Duration::from_secs(10),
            viewer::collect_frame(&v, &mut events, camera, settings(16, 16)),
        )
        .await
        .expect("a viewer frame took too long")
        .unwrap();
    }

    // A dies: its tile of the old frame goes to B, which must render it.
    drop(a);
    let done = tokio::time::timeout(Duration::from_secs(10), async {
        let mut pixels = None;
        while let Some(ev) = batch_events.recv().await {
            match ev {
                ViewerEvent::Tile { request: r, pixels: p, .. } if r == request => pixels = Some(p),
                ViewerEvent::FrameDone { request: r, .. } if r == request => return pixels,
                ViewerEvent::Error(e) | ViewerEvent::Closed(e) => panic!("batch client: {e}"),
                _ => {}
            }
        }
        None
    })
    .await
    .unwrap_or_else(|_| panic!("the batch frame {old} never completed after its slave died"));
    let pixels = done.expect("no tile of the batch frame");
    assert_eq!(pixels[..3], Pattern::pixel(&batch_camera, 0, 0));
}

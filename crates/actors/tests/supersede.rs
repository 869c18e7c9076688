//! Superseding a frame stops the slaves' work on it: tiles already being
//! rendered stop between bands of rows, not at their end; and the tracer's
//! banded rendering gives the bytes of one whole-tile render.

use isin_actors::master::{GetStatus, Master, MasterConfig};
use isin_actors::slave::{self, Pattern, Renderer, SlaveOptions, Tracer};
use isin_actors::viewer;
use isin_tracer::{Camera, RenderSettings, SceneBundle, Tile};
use isin_transport::Ticket;
use isin_transport::Transport;
use isin_transport::mem::MemTransport;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};
use tokio::sync::mpsc;

/// The camera whose tiles [`Stuck`] renders only once cancelled.
fn stuck_camera() -> Camera {
    let mut c = Camera::default();
    c.advance(1.0);
    c
}

/// A renderer whose tiles of [`stuck_camera`] never finish on their own
/// within the test (up to a minute): they poll the cancel check and stop when
/// it answers true. Other cameras render at once (as [`Pattern`]).
#[derive(Default)]
struct Stuck {
    started: std::sync::Mutex<Option<mpsc::UnboundedSender<()>>>,
    /// Tiles that were rendering (the cancel check had said no) and stopped.
    stopped: AtomicU64,
    finished: AtomicU64,
}

impl Renderer for Stuck {
    type Scene = String;

    fn load(&self, bundle: &SceneBundle) -> Result<String, String> {
        Ok(bundle.source.clone())
    }

    fn render(&self, scene: &String, camera: &Camera, settings: &RenderSettings, tile: Tile) -> Vec<u8> {
        Pattern::default().render(scene, camera, settings, tile)
    }

    fn render_cancellable(
        &self,
        scene: &String,
        camera: &Camera,
        settings: &RenderSettings,
        tile: Tile,
        cancelled: &dyn Fn() -> bool,
    ) -> Option<Vec<u8>> {
        if *camera != stuck_camera() {
            return Some(self.render(scene, camera, settings, tile));
        }
        if cancelled() {
            return None; // skipped before it started
        }
        if let Some(tx) = self.started.lock().unwrap().as_ref() {
            let _ = tx.send(());
        }
        let t0 = Instant::now();
        while t0.elapsed() < Duration::from_secs(60) {
            if cancelled() {
                self.stopped.fetch_add(1, Ordering::SeqCst);
                return None;
            }
            std::thread::yield_now();
        }
        self.finished.fetch_add(1, Ordering::SeqCst);
        Some(self.render(scene, camera, settings, tile))
    }
}

fn settings(w: u32, h: u32) -> RenderSettings {
    RenderSettings { width: w, height: h, ..RenderSettings::default() }
}

#[actix::test]
async fn a_newer_frame_stops_the_tile_in_flight_of_the_superseded_one() {
    let t = MemTransport::new();
    let bundle = SceneBundle { name: "fake.toml".into(), source: "fake".into(), ..Default::default() };
    let cfg = MasterConfig::new("tok".into(), bundle, Camera::default(), settings(32, 32)).unwrap();
    let master = Master::new(cfg).unwrap().serve(t.listen("master").await.unwrap());
    let ticket =
        // The kind is not read: the test hands the in-memory transport to the peer itself.
        Ticket { transport: isin_transport::TransportKind::TcpInsecure, token: "tok".into(), addr: "master".into(), fingerprint: None };
    let (started_tx, mut started) = mpsc::unbounded_channel();
    let stuck = Arc::new(Stuck { started: std::sync::Mutex::new(Some(started_tx)), ..Default::default() });
    // One render thread: the new frame's tile can only run once the stuck one stopped.
    let opts = SlaveOptions { name: "one".into(), threads: 1, ..SlaveOptions::default() };
    let transport: Arc<dyn Transport> = Arc::new(t.clone());
    let renderer = stuck.clone();
    let tk = ticket.clone();
    actix::spawn(async move {
        let _ = slave::run(transport, tk, opts, renderer).await;
    });
    for _ in 0..2000 {
        if !master.send(GetStatus).await.unwrap().slaves.is_empty() {
            break;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    let (v, _, mut events) = viewer::connect(&t, &ticket, "gui").await.unwrap();
    // A one-tile frame that gets stuck in the renderer…
    v.do_send(viewer::RequestFrameAs { request: 1, camera: stuck_camera(), settings: settings(16, 16) });
    tokio::time::timeout(Duration::from_secs(20), started.recv())
        .await
        .expect("the stuck tile never started")
        .unwrap();
    // …is superseded by the next request, which completes.
    let t0 = Instant::now();
    let (frame, _) = tokio::time::timeout(
        Duration::from_secs(30),
        viewer::collect_frame(&v, &mut events, Camera::default(), settings(16, 16)),
    )
    .await
    .expect("the new frame waited for the superseded tile")
    .unwrap();
    assert_eq!(frame.rgb[..3], Pattern::pixel(&Camera::default(), 0, 0));
    assert_eq!(stuck.stopped.load(Ordering::SeqCst), 1, "the superseded tile stopped part-way");
    assert_eq!(stuck.finished.load(Ordering::SeqCst), 0);
    assert!(t0.elapsed() < Duration::from_secs(30));
}

/// A small scene of the tracer: a checkered floor, a box, a mirror ball,
/// a point light and an area light (soft shadows need several shadow rays).
fn small_scene() -> isin_tracer::Scene {
    let source = r#"
        [settings]
        width = 48
        height = 40
        light_samples = 4
        [textures.tiles]
        kind = "checker"
        even = [0.9, 0.9, 0.9]
        odd = [0.1, 0.1, 0.1]
        [materials.floor]
        kind = "phong"
        texture = "tiles"
        [materials.red]
        kind = "phong"
        color = [0.7, 0.1, 0.1]
        [materials.mirror]
        kind = "mirror"
        [[lights]]
        kind = "point"
        position = [-3.0, 5.0, 2.0]
        intensity = [1.0, 1.0, 1.0]
        power = 30
        [[lights]]
        kind = "area"
        corner = [0.5, 5.0, -2.0]
        edge1 = [2.0, 0.0, 0.0]
        edge2 = [0.0, 0.0, 2.0]
        radiance = [1.0, 1.0, 1.0]
        power = 5
        [[objects]]
        kind = "quad"
        material = "floor"
        scale = [14, 1, 24]
        [[objects]]
        kind = "box"
        material = "red"
        translate = [-1.5, 0.5, -1.0]
        [[objects]]
        kind = "box"
        material = "mirror"
        scale = 1.5
        translate = [1.5, 0.75, -2.0]
    "#;
    let bundle = SceneBundle { name: "small.toml".into(), source: source.into(), ..Default::default() };
    bundle.load().expect("the test scene loads")
}

#[test]
fn the_tracer_renders_a_tile_in_bands_with_the_bytes_of_one_call_and_stops_when_asked() {
    let scene = small_scene();
    let camera = scene.camera;
    let settings = RenderSettings { spp: 4, ..scene.settings };
    // Odd sizes: the last band is short.
    let tile = Tile { x: 5, y: 3, w: 23, h: 19 };
    let whole = isin_tracer::render_tile(&scene, &camera, &settings, tile);
    let checks = AtomicU64::new(0);
    let banded = Tracer
        .render_cancellable(&scene, &camera, &settings, tile, &|| {
            checks.fetch_add(1, Ordering::SeqCst);
            false
        })
        .expect("never cancelled");
    assert_eq!(banded, whole, "banded rendering changed pixels");
    assert!(whole.iter().any(|&b| b > 0), "a black test image proves nothing");
    let bands = tile.h.div_ceil(slave::ROWS_PER_CANCEL_CHECK) as u64;
    assert_eq!(checks.load(Ordering::SeqCst), bands, "one check per band");
    // Cancelled after two bands: nothing more is asked, nothing returned.
    let checks = AtomicU64::new(0);
    let out = Tracer
        .render_cancellable(&scene, &camera, &settings, tile, &|| checks.fetch_add(1, Ordering::SeqCst) >= 2);
    assert_eq!(out, None);
    assert_eq!(checks.load(Ordering::SeqCst), 3);
}

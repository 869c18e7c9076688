//! Opens the viewer on a procedural [`FrameSource`] (a checkered floor under a
//! sky, ray-cast with the paper's camera), to try the window, navigation and
//! overlays without a scene or the tracer: `cargo run -p isin-viewer --example pattern`.

use isin_tracer::{Camera, RenderSettings, Tile, Vec3};
use isin_viewer::{
    Controls, FrameRequest, FrameSource, Quality, Session, SessionConfig, SourceEvent, SourceStatus,
    TileUpdate, ViewerOptions, Waker,
};
use std::sync::mpsc::{Receiver, Sender, channel};
use std::time::Instant;

struct Pattern {
    tx: Sender<SourceEvent>,
    rx: Receiver<SourceEvent>,
    waker: Waker,
}

fn shade(camera: &Camera, fx: f32, fy: f32) -> [u8; 3] {
    let ray = camera.ray(fx, fy);
    if ray.dir.y < -1e-3 {
        let t = (-2.0 - ray.origin.y) / ray.dir.y;
        let p = ray.origin + ray.dir * t;
        let check = ((p.x.floor() + p.z.floor()) as i64).rem_euclid(2) == 0;
        let fade = (1.0 / (1.0 + t * 0.05)).clamp(0.0, 1.0);
        let v = if check { 230.0 } else { 40.0 } * fade;
        [v as u8, (v * 0.8) as u8, (v * 0.6) as u8]
    } else {
        let up = ray.dir.dot(Vec3::Y).clamp(0.0, 1.0);
        [(120.0 - 80.0 * up) as u8, (160.0 - 60.0 * up) as u8, 230]
    }
}

impl FrameSource for Pattern {
    fn set_waker(&mut self, waker: Waker) {
        self.waker = waker;
    }

    fn request(&mut self, r: FrameRequest) {
        let (tx, waker) = (self.tx.clone(), self.waker.clone());
        std::thread::spawn(move || {
            let start = Instant::now();
            let s = r.settings;
            for tile in Tile::grid(s.width, s.height, 32) {
                let mut rgb = Vec::with_capacity(tile.pixel_count() * 3);
                for y in tile.y..tile.y + tile.h {
                    for x in tile.x..tile.x + tile.w {
                        let fx = (x as f32 + 0.5) / s.width as f32;
                        let fy = (y as f32 + 0.5) / s.height as f32;
                        rgb.extend(shade(&r.camera, fx, fy));
                    }
                }
                let owner = (tile.x / 32 + tile.y / 32) % 3;
                let _ = tx.send(SourceEvent::Tile(TileUpdate { frame_id: r.frame_id, tile, rgb, owner }));
                waker.wake();
            }
            let _ = tx.send(SourceEvent::FrameComplete { frame_id: r.frame_id, elapsed: start.elapsed() });
            waker.wake();
        });
    }

    fn try_next(&mut self) -> Option<SourceEvent> {
        self.rx.try_recv().ok()
    }

    fn status(&self) -> SourceStatus {
        SourceStatus { live_slaves: 3, transport: "pattern".into(), ..Default::default() }
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (tx, rx) = channel();
    let settings = RenderSettings { width: 320, height: 240, ..Default::default() };
    let config = SessionConfig {
        settings,
        quality: Quality { max_spp: 4, ..Quality::for_settings(&settings) },
        controls: Controls::default(),
        camera: Camera::default(),
    };
    let mut session = Session::new(Box::new(Pattern { tx, rx, waker: Waker::noop() }), config);
    isin_viewer::run(&mut session, ViewerOptions { title: "isin pattern".into(), ..Default::default() })?;
    Ok(())
}

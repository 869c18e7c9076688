//! [`LocalSource`]: renders frames in-process on a rayon pool, so `isin view`
//! works without a cluster.

use crate::error::ViewerError;
use crate::source::{FrameId, FrameRequest, FrameSource, SourceEvent, SourceStatus, TileUpdate, Waker};
use isin_tracer::{Scene, Tile, render_tile};
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, Sender, channel};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// Counters shared between the render threads and the status line.
#[derive(Default)]
struct Counters {
    tiles: Mutex<BTreeMap<u32, u64>>,
    bytes: AtomicU64,
}

/// A [`FrameSource`] rendering tiles with [`isin_tracer::render_tile`] on its
/// own rayon pool.
///
/// Tiles are rendered centre-out (the middle of the image appears first). Each
/// tile checks, before it starts and between bands of rows
/// ([`render_tile_until`]), whether its frame is still the latest request:
/// tiles of superseded frames are skipped or stopped, so a new camera waits at
/// most for a few rows of the tiles being rendered. Tile owners are rayon
/// thread indices.
pub struct LocalSource {
    scene: Arc<Scene>,
    pool: Arc<rayon::ThreadPool>,
    tile_size: u32,
    latest: Arc<AtomicU64>,
    tx: Sender<SourceEvent>,
    rx: Receiver<SourceEvent>,
    waker: Waker,
    counters: Arc<Counters>,
}

impl LocalSource {
    /// A source rendering `scene` on `threads` threads (0: one per core) in
    /// tiles of `tile_size × tile_size` pixels.
    pub fn new(scene: Arc<Scene>, threads: usize, tile_size: u32) -> Result<Self, ViewerError> {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("isin-view-render-{i}"))
            .panic_handler(|_| tracing::error!("a render thread panicked"))
            .build()?;
        let (tx, rx) = channel();
        Ok(Self {
            scene,
            pool: Arc::new(pool),
            tile_size: tile_size.max(1),
            latest: Arc::new(AtomicU64::new(0)),
            tx,
            rx,
            waker: Waker::noop(),
            counters: Arc::default(),
        })
    }

    /// Number of render threads.
    pub fn threads(&self) -> usize {
        self.pool.current_num_threads()
    }
}

/// Rows rendered between two checks of [`render_tile_until`].
pub const ROWS_PER_CHECK: u32 = 4;

/// [`render_tile`] in bands of [`ROWS_PER_CHECK`] rows, giving up (`None`) as
/// soon as `stop()` answers true before a band: a tile of a superseded frame
/// stops within a few rows. The bytes are those of one `render_tile` call (a
/// pixel's value does not depend on the tiling).
pub fn render_tile_until(
    scene: &Scene,
    camera: &isin_tracer::Camera,
    settings: &isin_tracer::RenderSettings,
    tile: Tile,
    stop: &dyn Fn() -> bool,
) -> Option<Vec<u8>> {
    let mut out = Vec::with_capacity(tile.pixel_count() * 3);
    let mut y = tile.y;
    while y < tile.y + tile.h {
        if stop() {
            return None;
        }
        let h = ROWS_PER_CHECK.min(tile.y + tile.h - y);
        out.extend_from_slice(&render_tile(scene, camera, settings, Tile { y, h, ..tile }));
        y += h;
    }
    Some(out)
}

/// The tiles of a `width × height` image, nearest to the centre first.
pub fn centre_out_tiles(width: u32, height: u32, size: u32) -> Vec<Tile> {
    let mut tiles = Tile::grid(width, height, size);
    let (cx, cy) = (width as i64, height as i64);
    // Twice the tile centre minus the image size: integer distance from the centre.
    tiles.sort_by_key(|t| {
        let dx = (2 * t.x as i64 + t.w as i64) - cx;
        let dy = (2 * t.y as i64 + t.h as i64) - cy;
        (dx * dx + dy * dy, t.y, t.x)
    });
    tiles
}

impl FrameSource for LocalSource {
    fn set_waker(&mut self, waker: Waker) {
        self.waker = waker;
    }

    fn request(&mut self, request: FrameRequest) {
        let id: FrameId = request.frame_id;
        self.latest.fetch_max(id, Ordering::AcqRel);
        let tiles = centre_out_tiles(request.settings.width, request.settings.height, self.tile_size);
        let total = tiles.len();
        let scene = self.scene.clone();
        let latest = self.latest.clone();
        let tx = self.tx.clone();
        let waker = self.waker.clone();
        let counters = self.counters.clone();
        let started = Instant::now();
        let done = Arc::new(AtomicUsize::new(0));
        self.pool.spawn(move || {
            tiles.par_iter().for_each(|&tile| {
                if latest.load(Ordering::Acquire) != id {
                    return;
                }
                let superseded = || latest.load(Ordering::Acquire) != id;
                let rendered = catch_unwind(AssertUnwindSafe(|| {
                    render_tile_until(&scene, &request.camera, &request.settings, tile, &superseded)
                }));
                let rgb = match rendered {
                    Ok(Some(rgb)) => rgb,
                    Ok(None) => return, // superseded part-way
                    Err(panic) => {
                        let what = panic
                            .downcast_ref::<&str>()
                            .map(|s| s.to_string())
                            .or_else(|| panic.downcast_ref::<String>().cloned())
                            .unwrap_or_else(|| "unknown panic".into());
                        let _ = tx.send(SourceEvent::Failed(format!("render_tile panicked: {what}")));
                        waker.wake();
                        return;
                    }
                };
                let owner = rayon::current_thread_index().unwrap_or(0) as u32;
                counters.bytes.fetch_add(rgb.len() as u64, Ordering::Relaxed);
                *counters.tiles.lock().unwrap_or_else(|e| e.into_inner()).entry(owner).or_default() += 1;
                let _ = tx.send(SourceEvent::Tile(TileUpdate { frame_id: id, tile, rgb, owner }));
                if done.fetch_add(1, Ordering::AcqRel) + 1 == total {
                    let _ = tx.send(SourceEvent::FrameComplete { frame_id: id, elapsed: started.elapsed() });
                }
                waker.wake();
            });
        });
    }

    fn try_next(&mut self) -> Option<SourceEvent> {
        self.rx.try_recv().ok()
    }

    fn status(&self) -> SourceStatus {
        let tiles = self.counters.tiles.lock().unwrap_or_else(|e| e.into_inner());
        SourceStatus {
            live_slaves: self.pool.current_num_threads(),
            tiles_per_slave: tiles.iter().map(|(&k, &v)| (k, v)).collect(),
            bytes_received: self.counters.bytes.load(Ordering::Relaxed),
            transport: "in-process".into(),
            workers: Vec::new(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use isin_tracer::lights::Light;
    use isin_tracer::materials::Material;
    use isin_tracer::scene::{SceneParts, TriangleShading};
    use isin_tracer::shapes::Triangle;
    use isin_tracer::{Camera, Frame, RenderSettings, Vec2, Vec3};
    use std::time::Duration;

    /// A floor, an upright triangle casting a shadow, a point and an area light.
    fn scene() -> Scene {
        let tri = |a: [f32; 3], b: [f32; 3], c: [f32; 3]| Triangle { v: [a.into(), b.into(), c.into()] };
        let triangles = vec![
            tri([-8.0, -3.0, 6.0], [8.0, -3.0, 6.0], [8.0, -3.0, -8.0]),
            tri([-8.0, -3.0, 6.0], [8.0, -3.0, -8.0], [-8.0, -3.0, -8.0]),
            tri([-2.0, -3.0, -2.0], [2.0, -3.0, -2.0], [0.0, 2.0, -2.0]),
        ];
        let shading = triangles
            .iter()
            .enumerate()
            .map(|(i, t)| {
                let n = (t.v[1] - t.v[0]).cross(t.v[2] - t.v[0]).normalize();
                TriangleShading { normals: [n; 3], uvs: [Vec2::ZERO; 3], material: (i / 2) as u32 }
            })
            .collect();
        Scene::new(SceneParts {
            triangles,
            shading,
            materials: vec![Material::default(), Material::default()],
            lights: vec![
                Light::Point { position: Vec3::new(3.0, 6.0, 4.0), intensity: Vec3::splat(40.0) },
                Light::Area {
                    vertices: vec![
                        Vec3::new(-1.0, 7.0, -1.0),
                        Vec3::new(1.0, 7.0, -1.0),
                        Vec3::new(1.0, 7.0, 1.0),
                        Vec3::new(-1.0, 7.0, 1.0),
                    ],
                    radiance: Vec3::splat(5.0),
                },
            ],
            ambient: Vec3::splat(0.05),
            background: Vec3::new(0.2, 0.3, 0.5),
            camera: Camera::default(),
            settings: RenderSettings::default(),
            ..Default::default()
        })
    }

    /// A source whose waker signals `rx`.
    fn source(threads: usize, tile: u32) -> (LocalSource, std::sync::mpsc::Receiver<()>) {
        let mut s = LocalSource::new(Arc::new(scene()), threads, tile).unwrap();
        let (tx, rx) = channel();
        let tx = Mutex::new(tx);
        s.set_waker(Waker::new(move || {
            let _ = tx.lock().unwrap().send(());
        }));
        (s, rx)
    }

    /// Collects events until `frame_id` completes.
    fn until_complete(
        s: &mut LocalSource,
        wake: &std::sync::mpsc::Receiver<()>,
        waker: &Waker,
        frame_id: FrameId,
    ) -> Vec<SourceEvent> {
        let mut events = Vec::new();
        loop {
            wake.recv_timeout(Duration::from_secs(60)).expect("the source went quiet");
            waker.rearm();
            while let Some(e) = s.try_next() {
                let done = matches!(e, SourceEvent::FrameComplete { frame_id: f, .. } if f == frame_id);
                assert!(!matches!(e, SourceEvent::Failed(_)), "{e:?}");
                events.push(e);
                if done {
                    return events;
                }
            }
        }
    }

    #[test]
    fn local_tiles_assemble_into_the_same_frame_as_render_frame() {
        let (mut s, wake) = source(2, 16);
        let waker = s.waker.clone();
        let settings =
            RenderSettings { width: 72, height: 40, spp: 2, light_samples: 2, ..Default::default() };
        let camera = Camera::default();
        s.request(FrameRequest { frame_id: 1, camera, settings });
        let events = until_complete(&mut s, &wake, &waker, 1);
        let mut frame = Frame::new(72, 40);
        let mut bytes = 0;
        let mut tiles = 0;
        for e in &events {
            if let SourceEvent::Tile(t) = e {
                assert_eq!(t.frame_id, 1);
                assert!(t.owner < 2, "owner {} is not a thread of a 2-thread pool", t.owner);
                frame.blit(t.tile, &t.rgb);
                bytes += t.rgb.len() as u64;
                tiles += 1;
            }
        }
        assert!(matches!(events.last(), Some(SourceEvent::FrameComplete { frame_id: 1, .. })));
        assert_eq!(tiles, Tile::grid(72, 40, 16).len(), "every tile exactly once");
        let expect = isin_tracer::render_frame(&scene(), &camera, &settings, 32, &|_| {});
        assert!(frame == expect, "tiles rendered by the source differ from render_frame");
        let status = s.status();
        assert_eq!(status.bytes_received, bytes);
        assert_eq!(status.tiles_per_slave.iter().map(|(_, n)| n).sum::<u64>(), tiles as u64);
        assert_eq!(status.live_slaves, 2);
        assert_eq!(status.transport, "in-process");
    }

    #[test]
    fn a_newer_request_supersedes_the_one_in_flight() {
        let (mut s, wake) = source(2, 16);
        let waker = s.waker.clone();
        // Seconds of work that the second request must cut short.
        let slow =
            RenderSettings { width: 512, height: 512, spp: 64, light_samples: 16, ..Default::default() };
        let fast = RenderSettings { width: 32, height: 32, spp: 1, light_samples: 1, ..Default::default() };
        s.request(FrameRequest { frame_id: 1, camera: Camera::default(), settings: slow });
        s.request(FrameRequest { frame_id: 2, camera: Camera::default(), settings: fast });
        let events = until_complete(&mut s, &wake, &waker, 2);
        let old_tiles =
            events.iter().filter(|e| matches!(e, SourceEvent::Tile(t) if t.frame_id == 1)).count();
        assert!(old_tiles < Tile::grid(512, 512, 16).len() / 4, "{old_tiles} tiles of the superseded frame");
        assert!(!events.iter().any(|e| matches!(e, SourceEvent::FrameComplete { frame_id: 1, .. })));
        let new_tiles =
            events.iter().filter(|e| matches!(e, SourceEvent::Tile(t) if t.frame_id == 2)).count();
        assert_eq!(new_tiles, 4);
    }

    #[test]
    fn banded_rendering_stops_at_the_first_band_after_the_stop_signal() {
        let scene = scene();
        let settings =
            RenderSettings { width: 40, height: 30, spp: 2, light_samples: 2, ..Default::default() };
        let tile = Tile { x: 3, y: 2, w: 17, h: 13 };
        let camera = Camera::default();
        let asked = AtomicUsize::new(0);
        let whole = render_tile_until(&scene, &camera, &settings, tile, &|| {
            asked.fetch_add(1, Ordering::SeqCst);
            false
        });
        assert_eq!(whole, Some(render_tile(&scene, &camera, &settings, tile)));
        assert_eq!(asked.load(Ordering::SeqCst), 13usize.div_ceil(ROWS_PER_CHECK as usize));
        let asked = AtomicUsize::new(0);
        let stopped = render_tile_until(&scene, &camera, &settings, tile, &|| {
            asked.fetch_add(1, Ordering::SeqCst) == 1
        });
        assert_eq!((stopped, asked.load(Ordering::SeqCst)), (None, 2), "one band, then the stop");
    }

    #[test]
    fn centre_out_covers_every_pixel_once_and_starts_in_the_middle() {
        let tiles = centre_out_tiles(100, 70, 16);
        let mut seen = vec![0u8; 100 * 70];
        for t in &tiles {
            for y in t.y..t.y + t.h {
                for x in t.x..t.x + t.w {
                    seen[(y * 100 + x) as usize] += 1;
                }
            }
        }
        assert!(seen.iter().all(|&n| n == 1));
        let first = tiles[0];
        assert!(first.x <= 50 && 50 <= first.x + first.w, "{first:?}");
        assert!(first.y <= 35 && 35 <= first.y + first.h, "{first:?}");
        let last = tiles[tiles.len() - 1];
        assert!(last.x == 0 || last.x + last.w == 100, "a corner tile comes last: {last:?}");
    }
}

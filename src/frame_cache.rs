//! `isin slave --cache-tiles DIR`: a memoising [`Renderer`] for measuring the
//! network with real pixels but without the tracer's cost.
//!
//! The first time a tile of some (scene, camera, settings) is asked for, the
//! whole frame is rendered once (by the wrapped renderer, as one big tile) and
//! kept in memory and in `DIR`; every tile of that frame — whatever its
//! rectangle, so the master's end-of-frame splitting is fine — is then cut out
//! of it. Slaves on one machine can share `DIR`, so a camera path is rendered
//! once and then replayed at the speed of the transport. The tracer is
//! deterministic, so the bytes are exactly those a fresh render would give.
//!
//! Files are named by a SHA-256 of the scene's hash, the camera and the
//! settings; a file of the wrong size is ignored and rendered again.

use isin_actors::slave::Renderer;
use isin_cluster::protocol::{SceneHash, scene_hash};
use isin_tracer::{Camera, RenderSettings, SceneBundle, Tile};
use sha2::{Digest, Sha256};
use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex, OnceLock};

/// Frames kept in memory, at most (bytes); beyond it frames are read from disk again.
pub const MAX_MEMORY_BYTES: usize = 1 << 30;

type Slot = Arc<OnceLock<Arc<Vec<u8>>>>;

/// A renderer that renders each frame once (see the [module docs](self)).
pub struct FrameCache<R> {
    inner: R,
    dir: Option<PathBuf>,
    frames: Mutex<HashMap<[u8; 32], Slot>>,
    memory: Mutex<usize>,
}

impl<R: Renderer> FrameCache<R> {
    /// Caches frames of `inner` in memory, and in `dir` when given (created if needed).
    pub fn new(inner: R, dir: Option<PathBuf>) -> std::io::Result<Self> {
        if let Some(d) = &dir {
            std::fs::create_dir_all(d)?;
        }
        Ok(Self { inner, dir, frames: Mutex::new(HashMap::new()), memory: Mutex::new(0) })
    }

    fn key(scene: &SceneHash, camera: &Camera, settings: &RenderSettings) -> [u8; 32] {
        // Debug formatting of f32 round-trips exactly, so equal strings mean equal cameras.
        let mut h = Sha256::new();
        h.update(scene);
        h.update(format!("{camera:?}\n{settings:?}").as_bytes());
        h.finalize().into()
    }

    /// The whole frame for `camera` and `settings`: from memory, disk, or rendered now.
    fn frame(
        &self,
        scene: &(SceneHash, R::Scene),
        camera: &Camera,
        settings: &RenderSettings,
    ) -> Arc<Vec<u8>> {
        let key = Self::key(&scene.0, camera, settings);
        let slot: Slot = {
            let mut frames = self.frames.lock().unwrap_or_else(|e| e.into_inner());
            frames.entry(key).or_default().clone()
        };
        // Concurrent tiles of a new frame wait here for one render, not one each.
        let mut fresh = false;
        let frame = slot
            .get_or_init(|| {
                fresh = true;
                let len = settings.width as usize * settings.height as usize * 3;
                let file = self.dir.as_ref().map(|d| d.join(format!("{}.rgb", hex(&key))));
                if let Some(bytes) =
                    file.as_ref().and_then(|f| std::fs::read(f).ok()).filter(|b| b.len() == len)
                {
                    return Arc::new(bytes);
                }
                let whole = Tile { x: 0, y: 0, w: settings.width, h: settings.height };
                let bytes = self.inner.render(&scene.1, camera, settings, whole);
                if let Some(f) = file.filter(|_| bytes.len() == len) {
                    let tmp = f.with_extension(format!("tmp{}", std::process::id()));
                    if std::fs::write(&tmp, &bytes).and_then(|_| std::fs::rename(&tmp, &f)).is_err() {
                        tracing::warn!("cannot write {}", f.display());
                        let _ = std::fs::remove_file(&tmp);
                    }
                }
                Arc::new(bytes)
            })
            .clone();
        if fresh {
            // Over the memory budget: forget it (the disk copy stays).
            let mut used = self.memory.lock().unwrap_or_else(|e| e.into_inner());
            if *used + frame.len() > MAX_MEMORY_BYTES {
                self.frames.lock().unwrap_or_else(|e| e.into_inner()).remove(&key);
            } else {
                *used += frame.len();
            }
        }
        frame
    }
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

impl<R: Renderer> Renderer for FrameCache<R> {
    type Scene = (SceneHash, R::Scene);

    fn load(&self, bundle: &SceneBundle) -> Result<Self::Scene, String> {
        let hash = scene_hash(bundle);
        Ok((hash, self.inner.load(bundle)?))
    }

    fn render(&self, scene: &Self::Scene, camera: &Camera, settings: &RenderSettings, tile: Tile) -> Vec<u8> {
        let frame = self.frame(scene, camera, settings);
        let (fw, fh) = (settings.width as usize, settings.height as usize);
        let (x, y, w, h) = (tile.x as usize, tile.y as usize, tile.w as usize, tile.h as usize);
        if frame.len() != fw * fh * 3 || x + w > fw || y + h > fh {
            // Not ours to judge: the wrapped renderer answers odd requests itself.
            return self.inner.render(&scene.1, camera, settings, tile);
        }
        let mut out = Vec::with_capacity(w * h * 3);
        for row in y..y + h {
            let start = (row * fw + x) * 3;
            out.extend_from_slice(&frame[start..start + w * 3]);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use isin_actors::slave::Pattern;
    use std::sync::atomic::Ordering;

    fn bundle() -> SceneBundle {
        SceneBundle { name: "t".into(), source: "x".into(), ..Default::default() }
    }

    #[test]
    fn tiles_match_the_renderer_and_the_frame_is_rendered_once() {
        let cache = FrameCache::new(Pattern::default(), None).unwrap();
        let scene = cache.load(&bundle()).unwrap();
        let camera = Camera::default();
        let settings = RenderSettings { width: 40, height: 30, ..Default::default() };
        let reference = Pattern::default();
        for tile in [
            Tile { x: 0, y: 0, w: 32, h: 30 },
            Tile { x: 32, y: 8, w: 8, h: 8 },
            Tile { x: 5, y: 7, w: 1, h: 1 },
        ] {
            let got = cache.render(&scene, &camera, &settings, tile);
            assert_eq!(got, reference.render(&String::new(), &camera, &settings, tile), "{tile:?}");
        }
        // One whole-frame render for three tiles.
        assert_eq!(cache.inner.tiles.load(Ordering::Relaxed), 1);
        let other = RenderSettings { width: 41, ..settings };
        cache.render(&scene, &camera, &other, Tile { x: 0, y: 0, w: 8, h: 8 });
        assert_eq!(cache.inner.tiles.load(Ordering::Relaxed), 2, "other settings are another frame");
    }

    #[test]
    fn a_second_cache_on_the_same_directory_renders_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let settings = RenderSettings { width: 16, height: 16, ..Default::default() };
        let tile = Tile { x: 8, y: 0, w: 8, h: 16 };
        let first = FrameCache::new(Pattern::default(), Some(dir.path().to_path_buf())).unwrap();
        let s1 = first.load(&bundle()).unwrap();
        let a = first.render(&s1, &Camera::default(), &settings, tile);
        let second = FrameCache::new(Pattern::default(), Some(dir.path().to_path_buf())).unwrap();
        let s2 = second.load(&bundle()).unwrap();
        let b = second.render(&s2, &Camera::default(), &settings, tile);
        assert_eq!(a, b);
        assert_eq!(second.inner.tiles.load(Ordering::Relaxed), 0, "read from disk, not rendered");
    }

    #[test]
    fn a_truncated_file_is_rendered_again() {
        let dir = tempfile::tempdir().unwrap();
        let settings = RenderSettings { width: 8, height: 8, ..Default::default() };
        let cache = FrameCache::new(Pattern::default(), Some(dir.path().to_path_buf())).unwrap();
        let scene = cache.load(&bundle()).unwrap();
        let key = FrameCache::<Pattern>::key(&scene.0, &Camera::default(), &settings);
        std::fs::write(dir.path().join(format!("{}.rgb", hex(&key))), [1u8; 5]).unwrap();
        let t = Tile { x: 0, y: 0, w: 8, h: 8 };
        let got = cache.render(&scene, &Camera::default(), &settings, t);
        assert_eq!(got, Pattern::default().render(&String::new(), &Camera::default(), &settings, t));
        assert_eq!(cache.inner.tiles.load(Ordering::Relaxed), 1);
    }
}

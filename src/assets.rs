//! Reading scene files and their assets from disk.

use anyhow::Context;
use isin_tracer::{AssetSource, Scene, SceneBundle};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// An [`AssetSource`] that reads files relative to the scene's directory and
/// remembers every file it read, so the scene can be shipped as a bundle.
pub struct DiskAssets {
    base: PathBuf,
    read: BTreeMap<String, Vec<u8>>,
}

impl DiskAssets {
    /// Assets resolved relative to `base`.
    pub fn new(base: impl Into<PathBuf>) -> Self {
        Self { base: base.into(), read: BTreeMap::new() }
    }
}

impl AssetSource for DiskAssets {
    fn read(&mut self, path: &str) -> Result<Vec<u8>, String> {
        if let Some(bytes) = self.read.get(path) {
            return Ok(bytes.clone());
        }
        let full = self.base.join(path);
        let bytes = std::fs::read(&full).map_err(|e| format!("cannot read {}: {e}", full.display()))?;
        self.read.insert(path.to_owned(), bytes.clone());
        Ok(bytes)
    }
}

/// Loads a scene file from disk: the built scene and the self-contained bundle
/// (text + every asset read) that reproduces it elsewhere.
pub fn load_scene_file(path: &Path) -> anyhow::Result<(Scene, SceneBundle)> {
    load_scene_file_timed(path).map(|(scene, bundle, _)| (scene, bundle))
}

/// How long loading a scene took.
#[derive(Clone, Copy, Debug)]
pub struct LoadTimes {
    /// Reading and parsing the scene and its assets, building the triangles.
    pub parse: Duration,
    /// Building the BVH.
    pub bvh: Duration,
}

/// [`load_scene_file`], also reporting how long parsing and the BVH build took.
///
/// `path` is a scene file (`.toml`) or a mesh file (`.gltf`, `.glb`, `.obj`);
/// around a mesh file a scene is made ([`isin_tracer::scenefile::mesh_scene`])
/// whose text refers to the mesh by its file name, so the bundle is a scene
/// like any other.
pub fn load_scene_file_timed(path: &Path) -> anyhow::Result<(Scene, SceneBundle, LoadTimes)> {
    let t0 = Instant::now();
    let (parts, bundle) = parse_file(path)?;
    let t1 = Instant::now();
    let scene = Scene::new(parts);
    let times = LoadTimes { parse: t1 - t0, bvh: t1.elapsed() };
    Ok((scene, bundle, times))
}

/// What a cluster client renders with: the scene's own camera and settings,
/// and its bundle (parsed, so every asset is read, but not built).
pub fn load_view(
    path: &Path,
) -> anyhow::Result<(isin_tracer::Camera, isin_tracer::RenderSettings, SceneBundle)> {
    parse_file(path).map(|(parts, bundle)| (parts.camera, parts.settings, bundle))
}

/// Reads and parses `path` and every asset it refers to.
fn parse_file(path: &Path) -> anyhow::Result<(isin_tracer::scene::SceneParts, SceneBundle)> {
    let base = path.parent().unwrap_or(Path::new("."));
    let mut assets = DiskAssets::new(base);
    let (name, source) = match mesh_file_name(path) {
        Some(file) => {
            let source = isin_tracer::scenefile::mesh_scene(&file, &mut assets)?;
            (format!("{} (scene made around it)", path.display()), source)
        }
        None => {
            let source = std::fs::read_to_string(path)
                .with_context(|| format!("cannot read scene file {}", path.display()))?;
            (path.display().to_string(), source)
        }
    };
    let parts = isin_tracer::parse_scene(&name, &source, &mut assets)?;
    Ok((parts, SceneBundle { name, source, assets: assets.read }))
}

/// The file name of `path` when it names a mesh file rather than a scene.
fn mesh_file_name(path: &Path) -> Option<String> {
    let file = path.file_name()?.to_str()?;
    isin_tracer::scenefile::MeshFormat::from_path(file).map(|_| file.to_owned())
}

/// The scene text `isin scene PATH` prints: a mesh file's made scene, with
/// the mesh referred to by `path` as given (so the text works from the
/// current directory), or a scene file's own text.
pub fn scene_text(path: &Path) -> anyhow::Result<String> {
    if mesh_file_name(path).is_none() {
        return std::fs::read_to_string(path)
            .with_context(|| format!("cannot read scene file {}", path.display()));
    }
    let rel = path.to_str().with_context(|| format!("{} is not valid UTF-8", path.display()))?;
    let mut assets = DiskAssets::new(".");
    Ok(isin_tracer::scenefile::mesh_scene(rel, &mut assets)?)
}

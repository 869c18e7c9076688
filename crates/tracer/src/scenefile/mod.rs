//! The human-editable scene description (TOML) and its loaders (built-in
//! primitives, Wavefront OBJ + MTL, glTF 2.0).
//!
//! The format is described in [`format`](mod@format); `scenes/paper.toml` opens with a
//! commented example of every section. A mesh file alone (`.gltf`, `.glb`,
//! `.obj`) becomes a scene through [`mesh_scene`](mod@mesh_scene), which writes
//! the scene file's text around it; meshes without normals can be smoothed
//! ([`smooth`]).
//!
//! Loading never touches the file system: files a scene refers to (meshes,
//! textures, MTL libraries, glTF buffers) are requested from an [`AssetSource`].
//! The binary passes one that reads from disk and records what it read; the
//! recording becomes a [`SceneBundle`] — the scene text plus every asset's bytes —
//! which serialises with serde and is what the master ships to slaves.

mod build;
mod errors;
pub mod format;
mod gltf;
pub mod mesh_scene;
mod obj;
pub mod smooth;
pub mod subdivide;

pub use build::{MAX_IMAGE_SIDE, MAX_TRIANGLES};
pub use errors::{Location, SceneError};
pub use mesh_scene::{MeshFormat, mesh_bounds, mesh_scene};

use crate::scene::{Scene, SceneParts};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Supplies the bytes of files a scene refers to, by path relative to the
/// scene file's directory.
///
/// Paths written in the scene are passed as written (with `./` segments
/// dropped); paths written inside other files — an OBJ's `mtllib`, an MTL's
/// `map_Kd`, a glTF buffer or image URI — are first resolved against the
/// referring file's directory, so `meshes/knot.obj` naming `knot.mtl` asks for
/// `meshes/knot.mtl`. `..` segments are collapsed where possible.
pub trait AssetSource {
    /// The bytes of `path`, or a message saying why they cannot be had.
    fn read(&mut self, path: &str) -> Result<Vec<u8>, String>;
}

/// A scene file together with the bytes of every asset it refers to:
/// self-contained, serialisable, and what the cluster ships to slaves.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SceneBundle {
    /// Name of the scene file, for error messages.
    pub name: String,
    /// The scene file's text.
    pub source: String,
    /// Asset bytes by the path the scene (or a file it loads) uses.
    pub assets: BTreeMap<String, Vec<u8>>,
}

impl AssetSource for SceneBundle {
    fn read(&mut self, path: &str) -> Result<Vec<u8>, String> {
        self.assets.get(path).cloned().ok_or_else(|| format!("asset `{path}` is not in the scene bundle"))
    }
}

impl SceneBundle {
    /// Builds the scene from the bundle's own text and assets.
    pub fn load(&self) -> Result<Scene, SceneError> {
        let mut assets = self.clone();
        load_scene(&self.name, &self.source, &mut assets)
    }
}

/// Parses a scene file's text (`name` is used in error messages) and loads every
/// asset through `assets`, producing everything but the BVH.
pub fn parse_scene(name: &str, source: &str, assets: &mut dyn AssetSource) -> Result<SceneParts, SceneError> {
    build::Builder::new(name, source, assets).build()
}

/// [`parse_scene`], then builds the scene (BVH included).
pub fn load_scene(name: &str, source: &str, assets: &mut dyn AssetSource) -> Result<Scene, SceneError> {
    Ok(Scene::new(parse_scene(name, source, assets)?))
}

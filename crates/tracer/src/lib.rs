//! # isin-tracer — the pure ray tracer
//!
//! Everything that turns a scene and a camera into pixels, and nothing else: no
//! files, no sockets, no async runtime. Loading a scene takes its text and an
//! [`scenefile::AssetSource`] that hands over referenced files as bytes, so the
//! same code runs on the master (reading from disk) and on a slave (reading from
//! the [`scenefile::SceneBundle`] the master shipped).
//!
//! The design follows the paper (Çakır & Köse, *Interactive Ray Tracing*) — a
//! Whitted ray tracer over triangles with Möller–Trumbore intersection, mirror
//! reflection, shadow rays to point and polygonal lights, barycentric texture
//! mapping and a camera given by its image plane's four corners — with a
//! binned-SAH BVH, dielectrics, mip-mapped textures and anti-aliasing added.
//!
//! **Determinism.** A pixel's value depends only on the scene, the camera, the
//! [`RenderSettings`] and the pixel's coordinates: every random number is a hash
//! of (pixel, sample index, dimension, scene seed), transcendental functions
//! come from the pure-Rust `libm` rather than the platform's, and no code path
//! uses fused multiply-add. Any tiling, any thread count, any machine gives the
//! same bytes, which is what lets the cluster re-render a lost tile anywhere.
//!
//! Modules are named for what they hold: [`geometry`] (rays, boxes),
//! [`shapes`] (triangle intersection), [`bvh`] (the acceleration structure),
//! [`cameras`], [`keyframes`] (the cameras between a path's keyed ones),
//! [`materials`], [`lights`], [`textures`], [`sampling`],
//! [`meshes`] (built-in primitives), [`shadows`] (what can block shadow rays,
//! per region of space), [`scene`] (the built, renderable scene),
//! [`scenefile`] (the human-editable description and its loaders),
//! [`integrator`] (Whitted shading), [`render`] (tiles and frames) and
//! [`memory`] (huge pages for large scenes, for binaries that opt in).

pub mod bvh;
pub mod cameras;
pub mod geometry;
pub mod integrator;
pub mod keyframes;
pub mod lights;
pub mod limits;
pub mod materials;
pub mod math;
pub mod memory;
pub mod meshes;
pub mod render;
pub mod sampling;
pub mod scene;
pub mod scenefile;
pub mod shadows;
pub mod shapes;
pub mod textures;

pub use cameras::Camera;
pub use render::{
    Frame, FrameBuffers, Passes, RenderSettings, Tile, render_frame, render_frame_hdr, render_tile,
    render_tile_hdr,
};
pub use scene::Scene;
pub use scenefile::{AssetSource, SceneBundle, SceneError, load_scene, parse_scene};

/// Re-export of the vector types used throughout the public API.
pub use glam::{Vec2, Vec3};

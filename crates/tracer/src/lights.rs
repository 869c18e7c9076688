//! Light sources: point lights (hard shadows) and polygonal area lights (soft
//! shadows from many stratified shadow rays).
//!
//! OWNER: shading helper (sampling); the types are shared with the scene loader.

use glam::Vec3;

/// A light source.
#[derive(Clone, Debug, PartialEq)]
pub enum Light {
    /// A point light; irradiance falls off with the squared distance.
    Point {
        /// Position.
        position: Vec3,
        /// Radiant intensity (linear RGB, W/sr-like units).
        intensity: Vec3,
    },
    /// A one-sided polygonal emitter: a triangle or a planar convex quad,
    /// vertices counter-clockwise seen from the lit side.
    Area {
        /// 3 or 4 vertices.
        vertices: Vec<Vec3>,
        /// Emitted radiance (linear RGB).
        radiance: Vec3,
    },
}

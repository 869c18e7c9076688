//! Bounding volume hierarchy over all triangles of a scene, built with the binned
//! surface-area heuristic.
//!
//! OWNER: bvh helper.

use crate::geometry::Ray;
use crate::shapes::{Hit, Triangle};

/// A BVH over a triangle list. It keeps its own, traversal-friendly copy of the
/// triangle data; [`Hit::prim`] refers to the index in the list it was built from.
#[derive(Clone, Debug, Default)]
pub struct Bvh {}

impl Bvh {
    /// Builds the hierarchy over `triangles`.
    pub fn build(triangles: &[Triangle]) -> Self {
        let _ = triangles;
        todo!("bvh helper")
    }

    /// Nearest hit with `t_min < t < t_max`.
    pub fn intersect(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<Hit> {
        let _ = (ray, t_min, t_max);
        todo!("bvh helper")
    }

    /// True when anything lies on the ray with `t_min < t < t_max` (shadow rays).
    pub fn occluded(&self, ray: &Ray, t_min: f32, t_max: f32) -> bool {
        let _ = (ray, t_min, t_max);
        todo!("bvh helper")
    }
}

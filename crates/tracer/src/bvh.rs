//! Bounding volume hierarchy over all triangles of a scene, built with the binned
//! surface-area heuristic.
//!
//! OWNER: bvh helper.

use crate::geometry::Ray;
use crate::shapes::{Hit, Triangle};

/// A BVH over a triangle list. It keeps its own, traversal-friendly copy of the
/// triangle data; [`Hit::prim`] refers to the index in the list it was built from.
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    // Placeholder: a linear scan until the real BVH lands.
    triangles: Vec<Triangle>,
}

impl Bvh {
    /// Builds the hierarchy over `triangles`.
    pub fn build(triangles: &[Triangle]) -> Self {
        Bvh { triangles: triangles.to_vec() }
    }

    /// Nearest hit with `t_min < t < t_max`.
    pub fn intersect(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        for (i, tri) in self.triangles.iter().enumerate() {
            let tmax = best.map_or(t_max, |h| h.t);
            if let Some((t, u, v)) = tri.intersect(ray, t_min, tmax) {
                best = Some(Hit { t, u, v, prim: i as u32 });
            }
        }
        best
    }

    /// True when anything lies on the ray with `t_min < t < t_max` (shadow rays).
    pub fn occluded(&self, ray: &Ray, t_min: f32, t_max: f32) -> bool {
        self.triangles.iter().any(|t| t.intersect(ray, t_min, t_max).is_some())
    }
}

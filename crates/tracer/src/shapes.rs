//! Triangles — the only primitive, as in the paper — and their intersection.
//!
//! Intersection is Möller–Trumbore ("Fast, minimum storage ray/triangle
//! intersection", 1997): it returns the ray parameter `t` and the barycentric
//! coordinates `(u, v)` of the hit. The arithmetic lives in [`moller_trumbore`],
//! which works on the precomputed form `(v0, e1 = v1 - v0, e2 = v2 - v0)`; both
//! [`Triangle::intersect`] and the BVH's leaf tests call it, so a hit found
//! through the BVH is bit-for-bit the hit a brute-force scan finds.
//!
//! The test is two-sided (no back-face culling) and uses no fused multiply-add,
//! so every machine computes the same bits.

use crate::geometry::{Aabb, Ray};
use glam::Vec3;

/// A triangle given by its three vertices in world space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Triangle {
    /// Vertices, counter-clockwise when seen from the front.
    pub v: [Vec3; 3],
}

/// A ray–triangle hit: distance and barycentric coordinates. The hit point is
/// `(1 - u - v) * v0 + u * v1 + v * v2`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Ray parameter of the hit.
    pub t: f32,
    /// Barycentric weight of `v1`.
    pub u: f32,
    /// Barycentric weight of `v2`.
    pub v: f32,
    /// Index of the triangle in the scene's triangle list.
    pub prim: u32,
}

impl Triangle {
    /// Bounding box.
    pub fn bounds(&self) -> Aabb {
        let mut b = Aabb::from_point(self.v[0]);
        b.grow(self.v[1]);
        b.grow(self.v[2]);
        b
    }

    /// Unnormalised geometric normal `(v1 - v0) × (v2 - v0)`.
    pub fn normal(&self) -> Vec3 {
        (self.v[1] - self.v[0]).cross(self.v[2] - self.v[0])
    }

    /// Area.
    pub fn area(&self) -> f32 {
        0.5 * self.normal().length()
    }

    /// The precomputed form `(v0, e1, e2)` used by [`moller_trumbore`].
    #[inline]
    pub fn edges(&self) -> (Vec3, Vec3, Vec3) {
        (self.v[0], self.v[1] - self.v[0], self.v[2] - self.v[0])
    }

    /// Möller–Trumbore: `Some((t, u, v))` when the ray hits the triangle with
    /// `t_min < t < t_max`. Two-sided; degenerate (zero-area) triangles never hit.
    #[inline]
    pub fn intersect(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<(f32, f32, f32)> {
        let (v0, e1, e2) = self.edges();
        moller_trumbore(v0, e1, e2, ray, t_min, t_max)
    }

    /// Any-hit query for shadow rays: true when the ray hits the triangle with
    /// `t_min < t < t_max`. Same arithmetic as [`Triangle::intersect`], so the
    /// two always agree.
    #[inline]
    pub fn occludes(&self, ray: &Ray, t_min: f32, t_max: f32) -> bool {
        let (v0, e1, e2) = self.edges();
        moller_trumbore_any(v0, e1, e2, ray, t_min, t_max)
    }
}

/// Möller–Trumbore on the precomputed triangle `(v0, e1 = v1 - v0, e2 = v2 - v0)`.
///
/// Returns `(t, u, v)` for a hit with `t_min < t < t_max`, `u >= 0`, `v >= 0`,
/// `u + v <= 1`. A ray parallel to the triangle's plane (determinant exactly 0)
/// misses; NaNs anywhere make every comparison fail, so they miss too.
#[inline(always)]
pub fn moller_trumbore(
    v0: Vec3,
    e1: Vec3,
    e2: Vec3,
    ray: &Ray,
    t_min: f32,
    t_max: f32,
) -> Option<(f32, f32, f32)> {
    let p = ray.dir.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 {
        return None;
    }
    let inv = 1.0 / det;
    let s = ray.origin - v0;
    let u = s.dot(p) * inv;
    // `contains` is false for NaN, so a NaN `u` misses.
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = ray.dir.dot(q) * inv;
    if !(v >= 0.0 && u + v <= 1.0) {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t > t_min && t < t_max).then_some((t, u, v))
}

/// Any-hit form of [`moller_trumbore`]: the same operations in the same order
/// (so it agrees bit for bit), without building the result tuple.
#[inline(always)]
pub fn moller_trumbore_any(v0: Vec3, e1: Vec3, e2: Vec3, ray: &Ray, t_min: f32, t_max: f32) -> bool {
    moller_trumbore(v0, e1, e2, ray, t_min, t_max).is_some()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri() -> Triangle {
        Triangle { v: [Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.0, 1.0, 0.0)] }
    }

    #[test]
    fn hit_reports_t_and_barycentrics() {
        let ray = Ray::new(Vec3::new(0.25, 0.5, 2.0), Vec3::new(0.0, 0.0, -1.0));
        let (t, u, v) = tri().intersect(&ray, 0.0, f32::INFINITY).expect("hit");
        assert_eq!(t, 2.0);
        // Hit point = (1-u-v) v0 + u v1 + v v2 = (u, v, 0).
        assert_eq!((u, v), (0.25, 0.5));
        let p = ray.at(t);
        assert_eq!(p, Vec3::new(u, v, 0.0));
    }

    #[test]
    fn two_sided_and_interval_is_open() {
        let from_below = Ray::new(Vec3::new(0.2, 0.2, -1.0), Vec3::new(0.0, 0.0, 1.0));
        assert_eq!(tri().intersect(&from_below, 0.0, 10.0).map(|h| h.0), Some(1.0));
        assert!(tri().intersect(&from_below, 1.0, 10.0).is_none(), "t_min is exclusive");
        assert!(tri().intersect(&from_below, 0.0, 1.0).is_none(), "t_max is exclusive");
        assert!(tri().occludes(&from_below, 0.0, 1.5));
        assert!(!tri().occludes(&from_below, 0.0, 0.5));
    }

    #[test]
    fn misses_outside_parallel_and_degenerate() {
        let outside = Ray::new(Vec3::new(0.8, 0.8, 1.0), Vec3::new(0.0, 0.0, -1.0));
        assert!(tri().intersect(&outside, 0.0, f32::INFINITY).is_none());
        let parallel = Ray::new(Vec3::new(-1.0, 0.2, 0.0), Vec3::new(1.0, 0.0, 0.0));
        assert!(tri().intersect(&parallel, 0.0, f32::INFINITY).is_none());
        let flat = Triangle { v: [Vec3::ZERO, Vec3::X, Vec3::X * 2.0] };
        let down = Ray::new(Vec3::new(0.5, 0.0, 1.0), Vec3::new(0.0, 0.0, -1.0));
        assert!(flat.intersect(&down, 0.0, f32::INFINITY).is_none());
        let nan = Ray::new(Vec3::splat(f32::NAN), Vec3::new(0.0, 0.0, -1.0));
        assert!(tri().intersect(&nan, 0.0, f32::INFINITY).is_none());
    }
}

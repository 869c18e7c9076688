//! Triangles — the only primitive, as in the paper — and their intersection.
//!
//! OWNER: bvh helper. Möller–Trumbore nearest hit returning (t, u, v), plus a
//! cheaper any-hit query for shadow rays.

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

    /// Möller–Trumbore: `Some((t, u, v))` when the ray hits the triangle with
    /// `t_min < t < t_max`.
    pub fn intersect(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<(f32, f32, f32)> {
        // Placeholder (scalar Möller–Trumbore); the bvh helper owns the final version.
        let e1 = self.v[1] - self.v[0];
        let e2 = self.v[2] - self.v[0];
        let p = ray.dir.cross(e2);
        let det = e1.dot(p);
        if det.abs() < 1e-12 {
            return None;
        }
        let inv = 1.0 / det;
        let s = ray.origin - self.v[0];
        let u = s.dot(p) * inv;
        if !(0.0..=1.0).contains(&u) {
            return None;
        }
        let q = s.cross(e1);
        let v = ray.dir.dot(q) * inv;
        if v < 0.0 || u + v > 1.0 {
            return None;
        }
        let t = e2.dot(q) * inv;
        (t > t_min && t < t_max).then_some((t, u, v))
    }
}

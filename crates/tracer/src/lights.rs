//! Light sources: point lights (hard shadows) and polygonal area lights (soft
//! shadows from many stratified shadow rays).
//!
//! **Which side of an area light emits.** Its vertices are counter-clockwise
//! seen from the lit side, so the emitting normal is the right-handed
//! `(v1 − v0) × (v2 − v0)` (for a quad the equivalent, more robust
//! `(v2 − v0) × (v3 − v1)`), the same convention as a triangle's front face.
//! Points behind that plane receive nothing.
//!
//! Sampling ([`Light::sample`]) returns the direction and distance to a point on
//! the light and the irradiance that point delivers to a surface facing it:
//! `I / d²` for a point light, and for an area light the one-sample estimate
//! `L · cos θ_light · A / d²`, where `A` is the area density of the sample (for a
//! quad, the Jacobian of the bilinear map from the unit square, so non-
//! parallelogram quads are sampled without bias).

use crate::sampling::square_to_triangle;
use glam::{Vec2, Vec3, Vec4};

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

/// One sample of a light as seen from a shading point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightSample {
    /// Unit direction from the shading point towards the light.
    pub dir: Vec3,
    /// Distance to the sampled point (the shadow ray's length).
    pub dist: f32,
    /// Irradiance on a surface facing the light (before the receiver's cosine).
    pub irradiance: Vec3,
}

impl Light {
    /// True for lights that need several shadow rays (area lights).
    pub fn is_area(&self) -> bool {
        matches!(self, Light::Area { .. })
    }

    /// The emitting unit normal of an area light (`None` for a point light or a
    /// degenerate polygon).
    pub fn normal(&self) -> Option<Vec3> {
        match self {
            Light::Point { .. } => None,
            Light::Area { vertices: v, .. } => {
                let n = match v.len() {
                    3 => (v[1] - v[0]).cross(v[2] - v[0]),
                    4 => (v[2] - v[0]).cross(v[3] - v[1]),
                    _ => return None,
                };
                let len = n.length();
                (len > 0.0 && len.is_finite()).then(|| n / len)
            }
        }
    }

    /// Area of an area light (0 for a point light or an unsupported polygon).
    pub fn area(&self) -> f32 {
        match self {
            Light::Point { .. } => 0.0,
            Light::Area { vertices: v, .. } => match v.len() {
                3 => 0.5 * (v[1] - v[0]).cross(v[2] - v[0]).length(),
                4 => 0.5 * (v[2] - v[0]).cross(v[3] - v[1]).length(),
                _ => 0.0,
            },
        }
    }

    /// A point on the light for the unit-square sample `u`, with the area
    /// density (area per unit of `u`) at that point. Triangles use the
    /// low-distortion square-to-triangle map (density = area); quads the
    /// bilinear map `v0 → v1` along `u.x`, `v0 → v3` along `u.y` (density = the
    /// map's Jacobian). `None` for a point light or a polygon that is neither a
    /// triangle nor a quad.
    pub fn point_on(&self, u: Vec2) -> Option<(Vec3, f32)> {
        let Light::Area { vertices: v, .. } = self else { return None };
        match v.len() {
            3 => {
                let (b1, b2) = square_to_triangle(u);
                let p = v[0] * (1.0 - b1 - b2) + v[1] * b1 + v[2] * b2;
                Some((p, self.area()))
            }
            4 => {
                let (s, t) = (u.x, u.y);
                let top = v[0] * (1.0 - s) + v[1] * s;
                let bottom = v[3] * (1.0 - s) + v[2] * s;
                let p = top * (1.0 - t) + bottom * t;
                let dpds = (v[1] - v[0]) * (1.0 - t) + (v[2] - v[3]) * t;
                let dpdt = bottom - top;
                Some((p, dpds.cross(dpdt).length()))
            }
            _ => None,
        }
    }

    /// Samples the light from shading point `p`; `u` is a stratified point of
    /// the unit square (ignored by point lights). `None` when the light cannot
    /// reach `p` (behind a one-sided emitter, degenerate, or at `p` itself).
    #[inline]
    pub fn sample(&self, p: Vec3, u: Vec2) -> Option<LightSample> {
        match self {
            Light::Point { position, intensity } => {
                let d = *position - p;
                let d2 = d.length_squared();
                if d2.is_nan() || d2 <= 0.0 {
                    return None;
                }
                let dist = d2.sqrt();
                Some(LightSample { dir: d / dist, dist, irradiance: *intensity / d2 })
            }
            Light::Area { .. } => self.sample_area(p, u, self.normal()?),
        }
    }

    /// The emitting normal of an area light if `p` lies strictly on its
    /// emitting side; `None` otherwise (and for point lights). Lets a caller
    /// skip every sample of a light that cannot reach a point, and compute the
    /// normal once for all of them.
    #[inline]
    pub fn area_normal_towards(&self, p: Vec3) -> Option<Vec3> {
        let Light::Area { vertices, .. } = self else { return None };
        let n = self.normal()?;
        ((p - vertices[0]).dot(n) > 0.0).then_some(n)
    }

    /// [`Light::sample`] for an area light whose unit emitting normal `n` the
    /// caller already has (see [`Light::area_normal_towards`]).
    #[inline]
    pub fn sample_area(&self, p: Vec3, u: Vec2, n: Vec3) -> Option<LightSample> {
        let Light::Area { radiance, .. } = self else { return None };
        let (q, density) = self.point_on(u)?;
        let d = q - p;
        let d2 = d.length_squared();
        if d2.is_nan() || d2 <= 0.0 {
            return None;
        }
        let dist = d2.sqrt();
        let dir = d / dist;
        let cos_light = -dir.dot(n);
        if cos_light <= 0.0 {
            return None;
        }
        Some(LightSample { dir, dist, irradiance: *radiance * (cos_light * density / d2) })
    }
}

/// An area light prepared for many samples from one shading point: its
/// emitting normal, and for triangles and parallelograms (the common shapes)
/// the corner and edge vectors with the constant area density, so that each
/// sample costs a few multiply-adds instead of [`Light::point_on`]'s bilinear
/// map and Jacobian. Other quads use `point_on`.
#[derive(Clone, Copy, Debug)]
pub struct AreaSampler<'l> {
    light: &'l Light,
    /// Unit emitting normal.
    pub normal: Vec3,
    /// The polygon's first vertex (a point of its plane).
    origin: Vec3,
    radiance: Vec3,
    shape: Shape,
    /// Centre and radius of a sphere around the polygon.
    centre: Vec3,
    radius: f32,
}

#[derive(Clone, Copy, Debug)]
enum Shape {
    /// `v0 + e1·b1 + e2·b2` over the square-to-triangle map; density = area.
    Triangle { v0: Vec3, e1: Vec3, e2: Vec3, density: f32 },
    /// `v0 + es·s + et·t`; density = `|es × et|`.
    Parallelogram { v0: Vec3, es: Vec3, et: Vec3, density: f32 },
    /// Anything else: [`Light::point_on`].
    General,
}

impl Light {
    /// The light prepared for sampling from `p`, when it is an area light and
    /// `p` lies strictly on its emitting side (see [`Light::area_normal_towards`]).
    #[inline]
    pub fn area_sampler(&self, p: Vec3) -> Option<AreaSampler<'_>> {
        self.prepare_area().filter(|s| s.faces(p))
    }

    /// The area light prepared for sampling from any point (its normal and
    /// shape do not depend on the point); `None` for a point light or a
    /// degenerate polygon. [`AreaSampler::faces`] then tells which points it
    /// reaches; together they are [`Light::area_sampler`], with the work done
    /// once per light instead of once per shading point.
    #[inline]
    pub fn prepare_area(&self) -> Option<AreaSampler<'_>> {
        let Light::Area { vertices: v, radiance } = self else { return None };
        let normal = self.normal()?;
        let shape = match v.len() {
            3 => Shape::Triangle { v0: v[0], e1: v[1] - v[0], e2: v[2] - v[0], density: self.area() },
            4 if v[1] - v[0] == v[2] - v[3] => {
                let (es, et) = (v[1] - v[0], v[3] - v[0]);
                Shape::Parallelogram { v0: v[0], es, et, density: es.cross(et).length() }
            }
            _ => Shape::General,
        };
        let centre = v.iter().copied().sum::<Vec3>() / v.len() as f32;
        let radius = v.iter().map(|&p| (p - centre).length()).fold(0.0, f32::max);
        Some(AreaSampler { light: self, normal, origin: v[0], radiance: *radiance, shape, centre, radius })
    }
}

impl AreaSampler<'_> {
    /// True when `p` lies strictly on the emitting side of the light's plane
    /// (the test of [`Light::area_normal_towards`]).
    #[inline]
    pub fn faces(&self, p: Vec3) -> bool {
        (p - self.origin).dot(self.normal) > 0.0
    }

    /// Emitted radiance.
    #[inline]
    pub fn radiance(&self) -> Vec3 {
        self.radiance
    }

    /// Centre and radius of a sphere around the light.
    #[inline]
    pub fn bounding_sphere(&self) -> (Vec3, f32) {
        (self.centre, self.radius)
    }

    /// The light's projected solid angle seen from `p` on a surface with unit
    /// normal `n`, `∫ cos θ dω` over the polygon — its irradiance on that
    /// surface per unit of radiance, exactly (Lambert's formula:
    /// `½ Σᵢ Θᵢ (Γᵢ · n)` over the polygon's edges, `Θᵢ` the angle an edge
    /// subtends and `Γᵢ` the unit normal of the plane through `p` and the
    /// edge). `None` unless every vertex lies strictly above the planes
    /// through `p` normal to `n` and to `ng` (then so does the whole convex
    /// polygon, and no part of it needs clipping at the horizon).
    ///
    /// The four vertices and edges are worked on side by side, one SIMD lane
    /// each (structure of arrays: all `x`, all `y`, all `z`), with the same
    /// IEEE operations in the same order as on one `Vec3` at a time, so the
    /// result is the same bits as the plain loop (a test compares them).
    pub fn projected_solid_angle(&self, p: Vec3, n: Vec3, ng: Vec3) -> Option<f32> {
        let Light::Area { vertices, .. } = self.light else { return None };
        let k = vertices.len();
        if !(3..=4).contains(&k) {
            return None;
        }
        // Lane i: vertex i (a triangle repeats its first vertex in lane 3).
        let lane = |i: usize| vertices[if i < k { i } else { 0 }];
        let [v0, v1, v2, v3] = [lane(0), lane(1), lane(2), lane(3)];
        let dx = Vec4::new(v0.x, v1.x, v2.x, v3.x) - Vec4::splat(p.x);
        let dy = Vec4::new(v0.y, v1.y, v2.y, v3.y) - Vec4::splat(p.y);
        let dz = Vec4::new(v0.z, v1.z, v2.z, v3.z) - Vec4::splat(p.z);
        let dot = |ax: Vec4, ay: Vec4, az: Vec4, b: Vec3| ax * b.x + ay * b.y + az * b.z;
        let len = (dx * dx + dy * dy + dz * dz).sqrt();
        let ok = dot(dx, dy, dz, n).cmpgt(Vec4::ZERO)
            & dot(dx, dy, dz, ng).cmpgt(Vec4::ZERO)
            & len.cmpgt(Vec4::ZERO)
            & len.cmplt(Vec4::INFINITY);
        if ok.bitmask() & 15 != 15 {
            return None;
        }
        let (ux, uy, uz) = (dx / len, dy / len, dz / len);
        // Edge i runs from vertex i to vertex i + 1 (mod k).
        let next = |v: Vec4| match k {
            3 => Vec4::new(v.y, v.z, v.x, v.x),
            _ => Vec4::new(v.y, v.z, v.w, v.x),
        };
        let (bx, by, bz) = (next(ux), next(uy), next(uz));
        let (cx, cy, cz) = (uy * bz - by * uz, uz * bx - bz * ux, ux * by - bx * uy);
        let s = (cx * cx + cy * cy + cz * cz).sqrt();
        let cos = ux * bx + uy * by + uz * bz;
        // Θ / |a × b|: by asin's series where the edge subtends a small angle
        // (|a × b| < 0.14; where a · b loses the angle's digits), else the
        // polynomial arc-cosine.
        let s2 = s * s;
        let series = Vec4::ONE + s2 * (Vec4::splat(1.0 / 6.0) + s2 * Vec4::splat(3.0 / 40.0));
        let theta_over_s =
            Vec4::select(cos.cmpgt(Vec4::splat(0.99)), series, crate::math::acos_poly4(cos) / s);
        let terms = theta_over_s * dot(cx, cy, cz, n);
        let (terms, s) = (terms.to_array(), s.to_array());
        let mut sum = 0.0f32;
        for i in 0..k {
            if s[i] > 0.0 {
                sum += terms[i];
            }
        }
        let e = 0.5 * sum.abs();
        e.is_finite().then_some(e)
    }

    /// The point of the light for the unit-square sample `u`, and the area
    /// density there ([`Light::point_on`], the same point up to rounding).
    #[inline]
    pub fn point(&self, u: Vec2) -> Option<(Vec3, f32)> {
        Some(match self.shape {
            Shape::Triangle { v0, e1, e2, density } => {
                let (b1, b2) = square_to_triangle(u);
                (v0 + e1 * b1 + e2 * b2, density)
            }
            Shape::Parallelogram { v0, es, et, density } => (v0 + es * u.x + et * u.y, density),
            Shape::General => self.light.point_on(u)?,
        })
    }

    /// [`Light::sample_area`] from `p` for the unit-square sample `u` (the
    /// same point of the light up to rounding).
    #[inline]
    pub fn sample(&self, p: Vec3, u: Vec2) -> Option<LightSample> {
        let (q, density) = self.point(u)?;
        let d = q - p;
        let d2 = d.length_squared();
        if d2.is_nan() || d2 <= 0.0 {
            return None;
        }
        let dist = d2.sqrt();
        let dir = d * (1.0 / dist);
        let cos_light = -dir.dot(self.normal);
        if cos_light <= 0.0 {
            return None;
        }
        Some(LightSample { dir, dist, irradiance: self.radiance * (cos_light * density / d2) })
    }

    /// [`AreaSampler::sample`] for four unit-square points at once (lane `i`:
    /// `(ux[i], uy[i])`), one SIMD lane each. Every lane goes through the same
    /// IEEE operations in the same order as `sample` does on one point, so it
    /// holds the same bits; a lane whose `sample` is `None` has its bit clear
    /// in [`LightSamples4::valid`]. `None` for a quad that is not a
    /// parallelogram (rare: its samples go through [`Light::point_on`] one by one).
    #[inline]
    pub fn sample4(&self, p: Vec3, ux: Vec4, uy: Vec4) -> Option<LightSamples4> {
        let mul_add = |v0: Vec3, e1: Vec3, a: Vec4, e2: Vec3, b: Vec4, axis: usize| {
            Vec4::splat(v0[axis]) + Vec4::splat(e1[axis]) * a + Vec4::splat(e2[axis]) * b
        };
        let (q, density) = match self.shape {
            Shape::Triangle { v0, e1, e2, density } => {
                // `square_to_triangle` in every lane.
                let upper = uy.cmpgt(ux);
                let (hx, hy) = (ux * 0.5, uy * 0.5);
                let b1 = Vec4::select(upper, hx, ux - hy);
                let b2 = Vec4::select(upper, uy - hx, hy);
                ([0, 1, 2].map(|a| mul_add(v0, e1, b1, e2, b2, a)), density)
            }
            Shape::Parallelogram { v0, es, et, density } => {
                ([0, 1, 2].map(|a| mul_add(v0, es, ux, et, uy, a)), density)
            }
            Shape::General => return None,
        };
        let d = [q[0] - Vec4::splat(p.x), q[1] - Vec4::splat(p.y), q[2] - Vec4::splat(p.z)];
        let d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        let dist = d2.sqrt();
        let inv = Vec4::ONE / dist;
        let dir = d.map(|c| c * inv);
        let n = self.normal;
        let cos_light = -(dir[0] * n.x + dir[1] * n.y + dir[2] * n.z);
        // As in `sample`: no sample where `d2` is NaN or not positive, or
        // where `cos_light` is not positive (a NaN one passes).
        let valid = (d2.cmpgt(Vec4::ZERO) & !cos_light.cmple(Vec4::ZERO)).bitmask();
        Some(LightSamples4 { dir, dist, scale: cos_light * density / d2, valid })
    }
}

/// Four samples of an area light from one shading point, by lane
/// ([`AreaSampler::sample4`]): what [`LightSample`] holds for one.
#[derive(Clone, Copy, Debug)]
pub struct LightSamples4 {
    /// Unit direction towards the light: `x`, `y` and `z` of the four lanes.
    pub dir: [Vec4; 3],
    /// Distance to the sampled point.
    pub dist: Vec4,
    /// The irradiance divided by the radiance ([`LightSample::irradiance`]
    /// is the radiance times this).
    pub scale: Vec4,
    /// Bit `i` set where lane `i` holds a sample.
    pub valid: u32,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::{Sampler, stratified_square};

    fn quad(size: f32, height: f32) -> Light {
        let h = size * 0.5;
        // Counter-clockwise seen from below (−Y): this lamp shines downwards.
        Light::Area {
            vertices: vec![
                Vec3::new(-h, height, -h),
                Vec3::new(h, height, -h),
                Vec3::new(h, height, h),
                Vec3::new(-h, height, h),
            ],
            radiance: Vec3::ONE,
        }
    }

    #[test]
    fn point_light_falls_off_with_distance_squared() {
        let l = Light::Point { position: Vec3::new(0.0, 4.0, 0.0), intensity: Vec3::splat(16.0) };
        let s = l.sample(Vec3::ZERO, Vec2::ZERO).unwrap();
        assert_eq!(s.dir, Vec3::Y);
        assert_eq!(s.dist, 4.0);
        assert_eq!(s.irradiance, Vec3::ONE);
        let s = l.sample(Vec3::new(0.0, 2.0, 0.0), Vec2::ZERO).unwrap();
        assert_eq!(s.irradiance, Vec3::splat(4.0));
    }

    #[test]
    fn area_light_emits_from_its_counter_clockwise_side_only() {
        let l = quad(1.0, 2.0);
        assert_eq!(l.normal().unwrap(), Vec3::NEG_Y);
        assert!((l.area() - 1.0).abs() < 1e-6);
        assert!(l.sample(Vec3::ZERO, Vec2::splat(0.5)).is_some());
        assert!(l.sample(Vec3::new(0.0, 3.0, 0.0), Vec2::splat(0.5)).is_none());
        assert_eq!(l.area_normal_towards(Vec3::ZERO), Some(Vec3::NEG_Y));
        assert_eq!(l.area_normal_towards(Vec3::new(0.0, 3.0, 0.0)), None);
        let tri = Light::Area { vertices: vec![Vec3::ZERO, Vec3::X, Vec3::Y], radiance: Vec3::ONE };
        assert_eq!(tri.normal().unwrap(), Vec3::Z);
        assert!(tri.sample(Vec3::new(0.2, 0.2, 1.0), Vec2::splat(0.3)).is_some());
        assert!(tri.sample(Vec3::new(0.2, 0.2, -1.0), Vec2::splat(0.3)).is_none());
    }

    #[test]
    fn small_area_light_matches_the_point_light_limit() {
        // A tiny lamp of radiance L and area A at distance d straight above
        // delivers E ≈ L·A/d².
        let l = quad(0.01, 3.0);
        let s = l.sample(Vec3::ZERO, Vec2::splat(0.25)).unwrap();
        let expect = 1e-4 / 9.0;
        assert!((s.irradiance.x - expect).abs() < expect * 1e-3, "{:?}", s.irradiance);
    }

    #[test]
    fn stratified_estimate_of_a_large_quad_matches_the_analytic_irradiance() {
        // Irradiance under the centre of a square lamp of half-side a at height
        // h (radiance 1): E = 4·[a/√(a²+h²)·atan(a/√(a²+h²))] (two-sided
        // form-factor formula for a square centred above the point).
        let (a, h) = (1.0f64, 1.0f64);
        let l = quad(2.0 * a as f32, h as f32);
        let n = 1024;
        let s = Sampler::new(0, 0, 0, 3);
        let mut e = 0.0f64;
        for i in 0..n {
            if let Some(ls) = l.sample(Vec3::ZERO, stratified_square(i, n, &s)) {
                e += (ls.irradiance.x * ls.dir.y) as f64;
            }
        }
        e /= n as f64;
        let r = (a * a + h * h).sqrt();
        let exact = 4.0 * (a / r) * (a / r).atan();
        assert!((e - exact).abs() < 0.01 * exact, "{e} vs {exact}");
    }

    #[test]
    fn prepared_samplers_match_sample_area() {
        let tri = Light::Area {
            vertices: vec![Vec3::new(-1.0, 4.0, 0.0), Vec3::new(1.0, 4.0, 0.5), Vec3::new(0.0, 4.5, 2.0)],
            radiance: Vec3::splat(2.0),
        };
        let trapezoid = Light::Area {
            vertices: vec![
                Vec3::new(0.0, 3.0, 0.0),
                Vec3::new(0.0, 3.0, 2.0),
                Vec3::new(1.0, 3.0, 1.5),
                Vec3::new(1.0, 3.0, 0.5),
            ],
            radiance: Vec3::ONE,
        };
        let p = Vec3::new(0.3, 0.0, 0.2);
        let s = Sampler::new(1, 2, 3, 4);
        for light in [quad(2.0, 3.0), tri, trapezoid] {
            // The point below, or for a lamp shining upwards one above it.
            let Some((from, normal)) = [p, p + Vec3::new(0.0, 10.0, 0.0)]
                .into_iter()
                .find_map(|q| light.area_normal_towards(q).map(|n| (q, n)))
            else {
                panic!("{light:?} faces neither point")
            };
            let prepared = light.area_sampler(from).expect("faces the point");
            assert_eq!(prepared.normal, normal);
            for i in 0..64 {
                let u = stratified_square(i, 64, &s);
                let (a, b) = (prepared.sample(from, u), light.sample_area(from, u, normal));
                let (Some(a), Some(b)) = (a, b) else {
                    assert_eq!(a.is_some(), b.is_some(), "{light:?} at {u:?}");
                    continue;
                };
                assert!((a.dir - b.dir).length() < 1e-5, "{a:?} vs {b:?}");
                assert!((a.dist - b.dist).abs() < 1e-4 * b.dist);
                assert!(
                    (a.irradiance - b.irradiance).abs().max_element() < 1e-4 * b.irradiance.max_element()
                );
            }
        }
        assert!(quad(1.0, 2.0).area_sampler(Vec3::new(0.0, 3.0, 0.0)).is_none(), "behind the lamp");
    }

    #[test]
    fn four_lane_samples_are_the_single_samples_bit_for_bit() {
        let tri = Light::Area {
            vertices: vec![Vec3::new(-1.0, 4.0, 0.0), Vec3::new(0.0, 4.5, 2.0), Vec3::new(1.0, 4.0, 0.5)],
            radiance: Vec3::ONE,
        };
        let mut next = Sampler::new(5, 6, 7, 8).stream();
        let mut compared = 0;
        for light in [quad(2.0, 3.0), tri] {
            for _ in 0..2_000 {
                let p = Vec3::new(next() * 8.0 - 4.0, next() * 6.0 - 1.0, next() * 8.0 - 4.0);
                let Some(prepared) = light.area_sampler(p) else { continue };
                let u: [Vec2; 4] = std::array::from_fn(|_| Vec2::new(next(), next()));
                let ux = Vec4::from_array(u.map(|u| u.x));
                let uy = Vec4::from_array(u.map(|u| u.y));
                let four = prepared.sample4(p, ux, uy).expect("triangle or parallelogram");
                for (i, &u) in u.iter().enumerate() {
                    let one = prepared.sample(p, u);
                    assert_eq!(four.valid & (1 << i) != 0, one.is_some(), "{light:?} from {p} at {u}");
                    let Some(one) = one else { continue };
                    compared += 1;
                    let dir = Vec3::new(four.dir[0][i], four.dir[1][i], four.dir[2][i]);
                    assert_eq!(dir.to_array().map(f32::to_bits), one.dir.to_array().map(f32::to_bits));
                    assert_eq!(four.dist[i].to_bits(), one.dist.to_bits());
                    let irradiance = prepared.radiance() * four.scale[i];
                    assert_eq!(
                        irradiance.to_array().map(f32::to_bits),
                        one.irradiance.to_array().map(f32::to_bits)
                    );
                }
            }
        }
        assert!(compared > 4_000, "only {compared} samples compared");
    }

    #[test]
    fn projected_solid_angle_matches_the_square_lamp_formula_and_sampling() {
        // Under the centre of a square lamp of half-side a at height h:
        // E = 4·[a/√(a²+h²)·atan(a/√(a²+h²))] (see the test above).
        let (a, h) = (1.0f64, 1.5f64);
        let l = quad(2.0 * a as f32, h as f32);
        let s = l.area_sampler(Vec3::ZERO).expect("faces the origin");
        let e = s.projected_solid_angle(Vec3::ZERO, Vec3::Y, Vec3::Y).unwrap() as f64;
        let r = (a * a + h * h).sqrt();
        let exact = 4.0 * (a / r) * (a / r).atan();
        assert!((e - exact).abs() < 1e-5 * exact, "{e} vs {exact}");
        // A small, far lamp (edges subtend ~10⁻³ rad): the point-light limit L·A·cos/d².
        let far = quad(0.1, 100.0);
        let e = far
            .area_sampler(Vec3::ZERO)
            .unwrap()
            .projected_solid_angle(Vec3::ZERO, Vec3::Y, Vec3::Y)
            .unwrap();
        assert!((e - 1e-6).abs() < 1e-4 * 1e-6, "{e}");
        // Off-centre, tilted receiver: against a dense stratified estimate.
        let p = Vec3::new(0.7, 0.2, -0.4);
        let n = Vec3::new(0.3, 1.0, 0.2).normalize();
        let s = l.area_sampler(p).unwrap();
        let exact = s.projected_solid_angle(p, n, Vec3::Y).unwrap() as f64;
        let m = 4096;
        let sampler = Sampler::new(3, 1, 4, 1);
        let mut est = 0.0f64;
        for i in 0..m {
            let ls = s.sample(p, stratified_square(i, m, &sampler)).unwrap();
            est += (ls.irradiance.x * ls.dir.dot(n)) as f64;
        }
        est /= m as f64;
        assert!((est - exact).abs() < 2e-3 * exact, "{est} vs {exact}");
        // A lamp crossing the receiver's horizon is left to sampling.
        assert!(s.projected_solid_angle(p, Vec3::X, Vec3::Y).is_none());
        assert!(s.projected_solid_angle(p, Vec3::Y, Vec3::NEG_Y).is_none());
    }

    /// Lambert's formula one vertex and one edge at a time, as `Vec3`s: what
    /// the SIMD [`AreaSampler::projected_solid_angle`] must equal bit for bit.
    fn projected_solid_angle_one_by_one(vertices: &[Vec3], p: Vec3, n: Vec3, ng: Vec3) -> Option<f32> {
        let k = vertices.len();
        let mut u = [Vec3::ZERO; 4];
        for (u, &v) in u.iter_mut().zip(vertices) {
            let d = v - p;
            let len = d.length();
            if !(d.dot(n) > 0.0 && d.dot(ng) > 0.0 && len > 0.0 && len.is_finite()) {
                return None;
            }
            *u = d / len;
        }
        let mut sum = 0.0f32;
        for i in 0..k {
            let (a, b) = (u[i], u[(i + 1) % k]);
            let c = a.cross(b);
            let s = c.length();
            if s > 0.0 {
                let dot = a.dot(b);
                let theta_over_s = if dot > 0.99 {
                    let s2 = s * s;
                    1.0 + s2 * (1.0 / 6.0 + s2 * (3.0 / 40.0))
                } else {
                    crate::math::acos_poly(dot) / s
                };
                sum += theta_over_s * c.dot(n);
            }
        }
        let e = 0.5 * sum.abs();
        e.is_finite().then_some(e)
    }

    #[test]
    fn projected_solid_angle_is_the_one_by_one_formula_bit_for_bit() {
        let sampler = Sampler::pixel(3, 5, 7);
        let lamps = [
            quad(3.0, 6.0),
            Light::Area {
                vertices: vec![Vec3::new(-1.0, 4.0, 0.0), Vec3::new(1.0, 4.5, 0.5), Vec3::new(0.0, 4.0, 2.0)],
                radiance: Vec3::ONE,
            },
        ];
        let (mut some, mut none) = (0, 0);
        for lamp in &lamps {
            let Light::Area { vertices, .. } = lamp else { unreachable!() };
            let s = lamp.prepare_area().unwrap();
            for i in 0..20_000u32 {
                let r = |d: u32| sampler.child(i).pair(d);
                let ((a, b), (c, d), (e, f)) = (r(0), r(1), r(2));
                // Points below the lamp, some far (small edges: the series), some close.
                let scale = if i % 3 == 0 { 40.0 } else { 4.0 };
                let p = Vec3::new((a - 0.5) * scale, (b - 0.5) * 4.0, (c - 0.5) * scale);
                let n = Vec3::new(d - 0.5, 1.0, e - 0.5).normalize();
                let ng = if f < 0.1 { -n } else { n };
                let want = projected_solid_angle_one_by_one(vertices, p, n, ng);
                let got = s.projected_solid_angle(p, n, ng);
                assert_eq!(got.map(f32::to_bits), want.map(f32::to_bits), "p {p}, n {n}");
                if got.is_some() { some += 1 } else { none += 1 }
            }
        }
        assert!(some > 10_000 && none > 1_000, "{some} computed, {none} rejected");
    }

    #[test]
    fn non_parallelogram_quad_area_is_unbiased() {
        // Integrating the sample density over the unit square gives the area.
        let l = Light::Area {
            vertices: vec![
                Vec3::ZERO,
                Vec3::new(2.0, 0.0, 0.0),
                Vec3::new(1.0, 1.0, 0.0),
                Vec3::new(0.0, 1.0, 0.0),
            ],
            radiance: Vec3::ONE,
        };
        let n = 64u32;
        let mut sum = 0.0;
        for j in 0..n {
            for i in 0..n {
                let u = Vec2::new((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
                sum += l.point_on(u).unwrap().1;
            }
        }
        let area = sum / (n * n) as f32;
        assert!((area - 1.5).abs() < 1e-3, "{area}");
        assert!((l.area() - 1.5).abs() < 1e-6);
    }
}

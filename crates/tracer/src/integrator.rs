//! Whitted-style shading: direct light with shadow rays (hard for point lights,
//! soft for area lights), Phong highlights, recursive mirror reflection and
//! refraction, ambient term.
//!
//! **Per hit.** Only the nearest hit builds shading data ([`SurfacePoint`]):
//! the smooth shading normal interpolated from the vertex normals with the
//! barycentric `(u, v)`, the interpolated UV, and the geometric normal. Both
//! normals are turned to face the incoming ray (surfaces are two-sided);
//! whether the ray hit the front (counter-clockwise) face decides whether it is
//! entering or leaving a dielectric. Secondary rays start a small distance
//! along the geometric normal — on the side they travel to — with the distance
//! scaled to the magnitude of the hit position and distance, which avoids
//! self-intersection ("acne") at any scene scale.
//!
//! **Materials.**
//! * Phong: `ambient·albedo + Σ_lights (albedo/π + specular·(s+2)/(2π)·max(0, R·L)^s)·E·cos θ`
//!   (normalised Phong lobe with shininess `s`, `R` the mirrored view
//!   direction), plus `reflectivity ×` the mirror reflection. `E` comes from
//!   one shadow ray for a point light and `light_samples` stratified shadow
//!   rays for an area light, whose length is shortened by a factor `1 − 10⁻³`
//!   so that a lamp's own visible polygon does not shadow its samples.
//! * Mirror: `tint ×` the radiance along `R = I − 2 (I·N) N`.
//! * Dielectric: Snell refraction and Schlick-weighted reflection, total
//!   internal reflection, `tint` applied to light transmitted into the medium.
//! * Emissive: its radiance, seen from both sides (the lamp is visible).
//!
//! Recursion stops at `max_depth` secondary bounces (a mirror then returns
//! black) or when a branch's throughput falls below [`MIN_THROUGHPUT`].
//!
//! **Texture footprints (ray cones).** A primary ray carries a cone whose
//! spread is the angle of a pixel (`Camera::pixel_spread`); its width grows
//! linearly with the distance travelled, through mirror bounces and refraction
//! alike (surface curvature is ignored). At a hit the UV footprint is
//! `width / |cos θ| × √(uv area / world area)` of the triangle.

use crate::geometry::Ray;
use crate::materials::{Albedo, Material, reflect, refract, schlick};
use crate::math;
use crate::render::RenderSettings;
use crate::sampling::{Sampler, stratified_square};
use crate::scene::Scene;
use crate::shapes::Hit;
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

/// Branches whose contribution to the pixel falls below this are not traced.
pub const MIN_THROUGHPUT: f32 = 1e-3;

/// Shadow rays stop this fraction short of the light sample.
const SHADOW_SHORTEN: f32 = 1.0 - 1e-3;

/// The material of triangles whose material index is out of range.
const FALLBACK_MATERIAL: Material = Material::Phong {
    albedo: Albedo::Constant(Vec3::splat(0.7)),
    specular: Vec3::ZERO,
    shininess: 1.0,
    reflectivity: 0.0,
};

/// A ray cone for texture filtering: `width` at the ray's origin, growing by
/// `spread` per unit distance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayCone {
    /// Cone width at the ray origin (world units).
    pub width: f32,
    /// Growth of the width per unit distance (radians, small-angle).
    pub spread: f32,
}

impl RayCone {
    /// The cone of a primary ray: zero width at the eye.
    pub fn primary(spread: f32) -> Self {
        Self { width: 0.0, spread }
    }

    /// The width after travelling `t`.
    #[inline]
    pub fn width_at(&self, t: f32) -> f32 {
        (self.width + self.spread * t).abs()
    }

    /// The cone of a secondary ray leaving a hit at distance `t`.
    #[inline]
    pub fn after(&self, t: f32) -> Self {
        Self { width: self.width_at(t), spread: self.spread }
    }
}

/// How many rays of each kind were traced.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RayCounts {
    /// Camera rays.
    pub primary: u64,
    /// Reflection and refraction rays.
    pub secondary: u64,
    /// Shadow rays (any-hit queries).
    pub shadow: u64,
}

impl RayCounts {
    /// All rays.
    pub fn total(&self) -> u64 {
        self.primary + self.secondary + self.shadow
    }

    /// Adds another count.
    pub fn add(&mut self, o: &RayCounts) {
        self.primary += o.primary;
        self.secondary += o.secondary;
        self.shadow += o.shadow;
    }
}

/// Shading data of the nearest hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfacePoint {
    /// Hit position.
    pub p: Vec3,
    /// Unit geometric normal, facing the incoming ray.
    pub ng: Vec3,
    /// Unit shading normal (interpolated vertex normals), on the side of `ng`.
    pub ns: Vec3,
    /// Interpolated texture coordinates.
    pub uv: Vec2,
    /// True when the ray hit the triangle's front (counter-clockwise) face.
    pub front: bool,
    /// Index into the scene's materials.
    pub material: u32,
    /// Distance to move secondary ray origins off the surface.
    pub eps: f32,
    /// UV units per world unit on this triangle (`√(uv area / world area)`).
    pub uv_per_world: f32,
    /// `|cos θ|` between the ray and the geometric normal.
    pub cos_view: f32,
}

impl SurfacePoint {
    /// Builds the shading data of `hit` on `ray`.
    #[inline]
    pub fn new(scene: &Scene, ray: &Ray, hit: &Hit) -> Self {
        let tri = &scene.triangles[hit.prim as usize];
        let sh = &scene.shading[hit.prim as usize];
        let (u, v) = (hit.u, hit.v);
        let w = 1.0 - u - v;
        let p = ray.at(hit.t);
        let n = tri.normal();
        let world2 = n.length();
        let mut ng = if world2 > 0.0 { n / world2 } else { -ray.dir };
        let ns = sh.normals[0] * w + sh.normals[1] * u + sh.normals[2] * v;
        let ns_len = ns.length();
        let mut ns = if ns_len > 0.0 && ns_len.is_finite() { ns / ns_len } else { ng };
        let front = ng.dot(ray.dir) < 0.0;
        if !front {
            ng = -ng;
            ns = -ns;
        }
        // Shading normals facing away from the viewer (smooth-shaded
        // silhouettes) would send reflections into the surface.
        if ns.dot(ray.dir) >= 0.0 {
            ns = ng;
        }
        let uv = sh.uvs[0] * w + sh.uvs[1] * u + sh.uvs[2] * v;
        let e1 = sh.uvs[1] - sh.uvs[0];
        let e2 = sh.uvs[2] - sh.uvs[0];
        let uv2 = (e1.x * e2.y - e1.y * e2.x).abs();
        let uv_per_world = if world2 > 0.0 { (uv2 / world2).sqrt() } else { 0.0 };
        let eps = 2e-5 * (1.0 + p.abs().max_element() + hit.t.abs());
        SurfacePoint {
            p,
            ng,
            ns,
            uv,
            front,
            material: sh.material,
            eps,
            uv_per_world,
            cos_view: ng.dot(ray.dir).abs(),
        }
    }

    /// The UV footprint of a ray cone of width `cone_width` at this point.
    #[inline]
    pub fn uv_width(&self, cone_width: f32) -> f32 {
        cone_width / self.cos_view.max(1e-4) * self.uv_per_world
    }

    /// Origin for a ray leaving on the side the incoming ray came from.
    #[inline]
    fn above(&self) -> Vec3 {
        self.p + self.ng * self.eps
    }

    /// Origin for a ray passing through the surface.
    #[inline]
    fn below(&self) -> Vec3 {
        self.p - self.ng * self.eps
    }

    /// The mirror direction of `dir`, kept on the incoming side.
    #[inline]
    fn reflect(&self, dir: Vec3) -> Vec3 {
        let r = reflect(dir, self.ns);
        if r.dot(self.ng) > 0.0 { r } else { reflect(dir, self.ng) }
    }
}

/// A Whitted ray tracer over one scene.
#[derive(Clone, Copy, Debug)]
pub struct Integrator<'a> {
    scene: &'a Scene,
    max_depth: u32,
    light_samples: u32,
}

impl<'a> Integrator<'a> {
    /// An integrator with the recursion depth and light sample count of
    /// `settings`.
    pub fn new(scene: &'a Scene, settings: &RenderSettings) -> Self {
        Self { scene, max_depth: settings.max_depth, light_samples: settings.light_samples.max(1) }
    }

    /// Radiance (linear RGB) arriving along the camera ray `ray`, whose cone
    /// and random numbers are given.
    #[inline]
    pub fn trace(&self, ray: &Ray, cone: RayCone, sampler: &Sampler, counts: &mut RayCounts) -> Vec3 {
        counts.primary += 1;
        self.radiance(ray, cone, 0, Vec3::ONE, sampler, counts)
    }

    /// Radiance along `ray` at recursion depth `depth`; `weight` is the
    /// branch's throughput to the pixel.
    fn radiance(
        &self,
        ray: &Ray,
        cone: RayCone,
        depth: u32,
        weight: Vec3,
        sampler: &Sampler,
        counts: &mut RayCounts,
    ) -> Vec3 {
        let scene = self.scene;
        let Some(hit) = scene.intersect(ray, 0.0, f32::INFINITY) else {
            return scene.background;
        };
        let sp = SurfacePoint::new(scene, ray, &hit);
        let cone_width = cone.width_at(hit.t);
        let material = scene.materials.get(sp.material as usize).unwrap_or(&FALLBACK_MATERIAL);
        match material {
            Material::Phong { albedo, specular, shininess, reflectivity } => {
                let albedo = match *albedo {
                    Albedo::Constant(c) => c,
                    Albedo::Texture { texture, tint } => match scene.textures.get(texture as usize) {
                        Some(t) => tint * t.eval(sp.uv, sp.uv_width(cone_width)),
                        None => tint,
                    },
                };
                let mut c = scene.ambient * albedo;
                c += self.direct(&sp, ray.dir, albedo, *specular, *shininess, depth, sampler, counts);
                let r = reflectivity.clamp(0.0, 1.0);
                if r > 0.0 {
                    let dir = sp.reflect(ray.dir);
                    c += self.secondary(
                        Ray::new(sp.above(), dir),
                        cone.after(hit.t),
                        depth,
                        weight,
                        r,
                        sampler,
                        counts,
                    ) * r;
                }
                c
            }
            Material::Mirror { tint } => {
                let dir = sp.reflect(ray.dir);
                self.secondary_tinted(
                    Ray::new(sp.above(), dir),
                    cone.after(hit.t),
                    depth,
                    weight,
                    *tint,
                    sampler,
                    counts,
                )
            }
            Material::Dielectric { ior, tint } => {
                let ior = if *ior > 0.0 && ior.is_finite() { *ior } else { 1.0 };
                let (n1, n2) = if sp.front { (1.0, ior) } else { (ior, 1.0) };
                let next = cone.after(hit.t);
                let refl = Ray::new(sp.above(), sp.reflect(ray.dir));
                match refract(ray.dir, sp.ns, n1 / n2) {
                    None => self.secondary(refl, next, depth, weight, 1.0, sampler, counts),
                    Some(t) => {
                        let cos = if n1 <= n2 { -ray.dir.dot(sp.ns) } else { -t.dot(sp.ns) };
                        let f = schlick(cos, n1, n2);
                        let tint = if sp.front { *tint } else { Vec3::ONE };
                        let reflected = self.secondary(refl, next, depth, weight, f, sampler, counts) * f;
                        let transmitted = self.secondary_tinted(
                            Ray::new(sp.below(), t),
                            next,
                            depth,
                            weight,
                            tint * (1.0 - f),
                            sampler,
                            counts,
                        );
                        reflected + transmitted
                    }
                }
            }
            Material::Emissive { radiance } => *radiance,
        }
    }

    /// Traces a secondary ray whose result will be scaled by `factor`.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    fn secondary(
        &self,
        ray: Ray,
        cone: RayCone,
        depth: u32,
        weight: Vec3,
        factor: f32,
        sampler: &Sampler,
        counts: &mut RayCounts,
    ) -> Vec3 {
        let w = weight * factor;
        if depth >= self.max_depth || w.max_element() < MIN_THROUGHPUT {
            return Vec3::ZERO;
        }
        counts.secondary += 1;
        self.radiance(&ray, cone, depth + 1, w, sampler, counts)
    }

    /// Traces a secondary ray and multiplies the result by `tint`.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    fn secondary_tinted(
        &self,
        ray: Ray,
        cone: RayCone,
        depth: u32,
        weight: Vec3,
        tint: Vec3,
        sampler: &Sampler,
        counts: &mut RayCounts,
    ) -> Vec3 {
        let w = weight * tint;
        if depth >= self.max_depth || w.max_element() < MIN_THROUGHPUT {
            return Vec3::ZERO;
        }
        counts.secondary += 1;
        tint * self.radiance(&ray, cone, depth + 1, w, sampler, counts)
    }

    /// Direct light from every light source at a Phong surface.
    #[allow(clippy::too_many_arguments)]
    fn direct(
        &self,
        sp: &SurfacePoint,
        view_dir: Vec3,
        albedo: Vec3,
        specular: Vec3,
        shininess: f32,
        depth: u32,
        sampler: &Sampler,
        counts: &mut RayCounts,
    ) -> Vec3 {
        let scene = self.scene;
        let diffuse = albedo * (1.0 / PI);
        let shininess = if shininess.is_finite() { shininess.max(0.0) } else { 0.0 };
        let has_spec = specular.max_element() > 0.0;
        let spec = specular * ((shininess + 2.0) / (2.0 * PI));
        let mirrored_view = reflect(view_dir, sp.ns);
        let origin = sp.above();
        let depth_sampler = sampler.child(depth);
        let mut total = Vec3::ZERO;
        for (index, light) in scene.lights.iter().enumerate() {
            let (n, light_sampler) = if light.is_area() {
                (self.light_samples, depth_sampler.child(index as u32))
            } else {
                (1, depth_sampler)
            };
            let mut sum = Vec3::ZERO;
            for j in 0..n {
                let u = if n > 1 { stratified_square(j, n, &light_sampler) } else { Vec2::splat(0.5) };
                let Some(ls) = light.sample(sp.p, u) else { continue };
                let cos = sp.ns.dot(ls.dir);
                if cos <= 0.0 || sp.ng.dot(ls.dir) <= 0.0 {
                    continue;
                }
                let mut f = diffuse;
                if has_spec {
                    let rv = mirrored_view.dot(ls.dir);
                    if rv > 0.0 {
                        f += spec * math::powf(rv, shininess);
                    }
                }
                counts.shadow += 1;
                if scene.occluded(&Ray::new(origin, ls.dir), 0.0, ls.dist * SHADOW_SHORTEN) {
                    continue;
                }
                sum += f * ls.irradiance * cos;
            }
            total += sum / n as f32;
        }
        total
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{SceneParts, TriangleShading};
    use crate::shapes::Triangle;

    fn one_triangle(normals: [Vec3; 3]) -> Scene {
        let tri =
            Triangle { v: [Vec3::new(-1.0, -1.0, 0.0), Vec3::new(1.0, -1.0, 0.0), Vec3::new(0.0, 1.0, 0.0)] };
        Scene::new(SceneParts {
            triangles: vec![tri],
            shading: vec![TriangleShading {
                normals,
                uvs: [Vec2::ZERO, Vec2::new(2.0, 0.0), Vec2::new(0.0, 2.0)],
                material: 0,
            }],
            materials: vec![Material::default()],
            ..Default::default()
        })
    }

    #[test]
    fn smooth_shading_interpolates_vertex_normals() {
        let n0 = Vec3::new(-0.5, 0.0, 1.0).normalize();
        let n1 = Vec3::new(0.5, 0.0, 1.0).normalize();
        let n2 = Vec3::new(0.0, 0.5, 1.0).normalize();
        let scene = one_triangle([n0, n1, n2]);
        let ray = Ray::new(Vec3::new(0.0, -0.5, 5.0), Vec3::NEG_Z);
        let hit = scene.intersect(&ray, 0.0, f32::INFINITY).unwrap();
        let sp = SurfacePoint::new(&scene, &ray, &hit);
        let w = 1.0 - hit.u - hit.v;
        let expect = (n0 * w + n1 * hit.u + n2 * hit.v).normalize();
        assert!((sp.ns - expect).length() < 1e-6);
        assert!((sp.ns - Vec3::Z).length() > 0.01, "not the face normal");
        assert_eq!(sp.ng, Vec3::Z);
        assert!(sp.front);
        // At a vertex the normal is that vertex's normal.
        let ray = Ray::new(Vec3::new(0.999, -0.9995, 5.0), Vec3::NEG_Z);
        let hit = scene.intersect(&ray, 0.0, f32::INFINITY).unwrap();
        assert!((SurfacePoint::new(&scene, &ray, &hit).ns - n1).length() < 2e-3);
        // UV interpolation: (u, v) barycentrics scale the edge UVs.
        let ray = Ray::new(Vec3::new(0.0, -0.5, 5.0), Vec3::NEG_Z);
        let hit = scene.intersect(&ray, 0.0, f32::INFINITY).unwrap();
        let sp = SurfacePoint::new(&scene, &ray, &hit);
        assert!((sp.uv - Vec2::new(2.0 * hit.u, 2.0 * hit.v)).length() < 1e-6);
        // uv area 2, world area 2.
        assert!((sp.uv_per_world - 1.0).abs() < 1e-6);
    }

    #[test]
    fn back_faces_are_face_forwarded() {
        let scene = one_triangle([Vec3::Z; 3]);
        let ray = Ray::new(Vec3::new(0.0, -0.5, -5.0), Vec3::Z);
        let hit = scene.intersect(&ray, 0.0, f32::INFINITY).unwrap();
        let sp = SurfacePoint::new(&scene, &ray, &hit);
        assert!(!sp.front);
        assert_eq!(sp.ng, Vec3::NEG_Z);
        assert_eq!(sp.ns, Vec3::NEG_Z);
        assert!(sp.above().z < sp.p.z && sp.below().z > sp.p.z);
    }

    #[test]
    fn ray_cones_grow_with_distance() {
        let c = RayCone::primary(0.01);
        assert_eq!(c.width_at(0.0), 0.0);
        assert!((c.width_at(10.0) - 0.1).abs() < 1e-7);
        let d = c.after(10.0);
        assert!((d.width_at(5.0) - 0.15).abs() < 1e-7, "keeps growing after a bounce");
    }
}

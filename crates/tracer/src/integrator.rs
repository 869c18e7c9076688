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
//!   so that a lamp's own visible polygon does not shadow its samples. Behind
//!   a reflection or refraction that passes only a fraction `w` of the light
//!   on to the pixel, an area light takes `⌈light_samples · w⌉` samples (at
//!   least one): the estimate stays unbiased, and the noise it adds to the
//!   pixel is scaled by `w` anyway (`Integrator::light_samples_for`).
//!   Area-light samples are traced adaptively (with more than
//!   [`ADAPTIVE_TESTS`] of them): the samples nearest the light's four corners
//!   first, and the rest only when those disagree (a penumbra); where they
//!   agree the remaining samples count as lit or shadowed like them
//!   (`Integrator::area_adaptive`). [`Integrator::with_adaptive_shadows`]
//!   switches this off for reference images. With more than
//!   [`ADAPTIVE_TESTS`] and at most [`RATIO_MAX`] samples, and the whole light
//!   above the horizon, the diffuse part is not averaged but computed exactly
//!   (the polygon's projected solid angle) and scaled by the fraction the
//!   samples find unblocked — the ratio estimator (`Integrator::area_ratio`):
//!   lit surfaces carry no sampling noise. Its adaptive tests go to the
//!   centres of the corner strata of the light-sample grid rather than to
//!   samples. Where the scene's shadow cells
//!   ([`crate::shadows`]) know a light to be unblocked, its shadow rays are
//!   not traced.
//! * Mirror: `tint ×` the radiance along `R = I − 2 (I·N) N`.
//! * Dielectric: Snell refraction and Schlick-weighted reflection, total
//!   internal reflection, `tint` applied to light transmitted into the medium.
//! * Emissive: its radiance, seen from both sides (the lamp is visible).
//!
//! Recursion stops at `max_depth` secondary bounces (a mirror then returns
//! black) or when a branch's throughput falls below [`MIN_THROUGHPUT`].
//!
//! **Packets.** Camera rays arrive in packets of eight
//! ([`Integrator::trace_packet`]), and the reflections and refractions their
//! hits spawn are traced as packets as well, branch by branch and depth by
//! depth, while enough of them go on (`Integrator::radiance_packet`): the
//! reflections off a 4×2 block of floor are nearly as coherent as the camera
//! rays. A hit's shading is split for this into the rays it spawns
//! (`Integrator::bounce`) and the light it returns once those rays' radiance
//! is known (`Integrator::finish`); the sums are the recursive ones, in the
//! same order, so the pixels are the same bytes as with single rays.
//!
//! **Texture footprints (ray cones).** A primary ray carries a cone whose
//! spread is the angle of a pixel (`Camera::pixel_spread`); its width grows
//! linearly with the distance travelled, through mirror bounces and refraction
//! alike; mirror reflection off a curved surface (curvature estimated from the
//! vertex normals) widens it further. At a hit the cone cuts an ellipse out of
//! the surface, `width` across and `width / |cos θ|` along the view direction;
//! the bounding box of that ellipse in UV space (through the gradients of `u`
//! and `v` over the triangle) is the footprint the texture is filtered over —
//! exactly, per axis, for the checker; by its larger side for mip-mapped
//! images. (For an isotropic UV mapping the larger side is
//! `width / |cos θ| × √(uv area / world area)`.) So a receding checker floor
//! stays sharp across the view while blurring to its mean colour with depth.

use crate::bvh::PACKET_LANES;
use crate::geometry::Ray;
use crate::lights::{AreaSampler, LightSample, LightSamples4};
use crate::materials::{Albedo, Material, Pbr, PbrShading, TextureMap, reflect, refract, schlick};
use crate::math;
use crate::render::RenderSettings;
use crate::sampling::{Divisor, Sampler, Strata, ceil_sqrt};
use crate::scene::Scene;
use crate::shadows::{CellAnswer, CellIndex};
use crate::shapes::Hit;
use glam::{Vec2, Vec3, Vec4};
use std::f32::consts::PI;

/// Branches whose contribution to the pixel falls below this are not traced
/// (adaptive tree-depth control, Hall & Greenberg 1983). At 0.4 % what is
/// cut is mostly a glass ball's third internal reflection and the floor's
/// reflection of the ball's outer one: on the paper frame 1,732 of 76,800
/// pixels change, by one level in most and at most 13 (a glint of the lamp
/// in the ball), and the frame's distance to a converged one grows by
/// 0.04 dB PSNR, for about 8 % of its time (docs/performance-notes.md, "Shading").
pub const MIN_THROUGHPUT: f32 = 4e-3;

/// Recursion depth is capped here whatever the settings say, so a scene file
/// cannot overflow the stack.
pub const MAX_DEPTH_LIMIT: u32 = 64;

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

    /// The cone of a mirror-reflected ray leaving a hit at distance `t` on a
    /// surface of curvature `k`: across a footprint of width `w` the normal
    /// turns by about `k·w`, so reflected directions fan out by `2·k·w` more.
    /// (Concave and convex surfaces are treated alike, erring on the side of
    /// blur rather than aliasing.)
    #[inline]
    pub fn reflected(&self, t: f32, k: f32) -> Self {
        let w = self.width_at(t);
        Self { width: w, spread: self.spread + 2.0 * k * w }
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
    /// `|cos θ|` between the ray and the geometric normal.
    pub cos_view: f32,
}

impl SurfacePoint {
    /// Builds the shading data of `hit` on `ray`.
    #[inline(always)]
    pub fn new(scene: &Scene, ray: &Ray, hit: &Hit) -> Self {
        let sh = &scene.shading[hit.prim as usize];
        let (u, v) = (hit.u, hit.v);
        let w = 1.0 - u - v;
        let p = ray.at(hit.t);
        let unit_normal = scene.unit_normals.get(hit.prim as usize).copied().flatten();
        let mut ng = unit_normal.unwrap_or(-ray.dir);
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
        let eps = 2e-5 * (1.0 + p.abs().max_element() + hit.t.abs());
        SurfacePoint { p, ng, ns, uv, front, material: sh.material, eps, cos_view: ng.dot(ray.dir).abs() }
    }

    /// The larger side of the UV footprint of a ray cone of width
    /// `cone_width` at this point of the triangle `v` with texture
    /// coordinates `uvs`, for an isotropic UV mapping (see [`uv_per_world`]).
    pub fn uv_width(&self, v: &[Vec3; 3], uvs: &[Vec2; 3], cone_width: f32) -> f32 {
        cone_width / self.cos_view.max(1e-4) * uv_per_world(v, uvs)
    }

    /// The UV footprint of a ray cone of width `cone_width` arriving along
    /// unit direction `dir`, as the `(u, v)` extents of the bounding box of
    /// the ellipse the cone cuts out of the triangle's plane: its minor axis
    /// (perpendicular to the ray) is `cone_width` long, its major axis (along
    /// the ray's projection) `cone_width / |cos θ|`. Both are mapped to UV
    /// through the gradients of `u` and `v` over the triangle `v` with
    /// texture coordinates `uvs`. For isotropic UV mappings the larger extent
    /// equals [`SurfacePoint::uv_width`].
    pub fn uv_footprint(&self, v: &[Vec3; 3], uvs: &[Vec2; 3], dir: Vec3, cone_width: f32) -> Vec2 {
        self.uv_footprint_from(uv_gradients(v, uvs), v, dir, cone_width)
    }

    /// [`SurfacePoint::uv_footprint`] from the triangle's [`uv_gradients`].
    #[inline]
    fn uv_footprint_from(&self, grads: Option<[Vec3; 2]>, v: &[Vec3; 3], dir: Vec3, cone_width: f32) -> Vec2 {
        let Some([grad_u, grad_v]) = grads else { return Vec2::ZERO };
        // In-plane ellipse axes: minor ⟂ ray, major along its projection.
        let minor = dir.cross(self.ng);
        let minor =
            if minor.length_squared() > 1e-12 { minor.normalize() } else { (v[1] - v[0]).normalize() };
        let major = self.ng.cross(minor);
        let stretch = 1.0 / self.cos_view.max(1e-4);
        let extent = |g: Vec3| {
            let (ga, gb) = (g.dot(major) * stretch, g.dot(minor));
            cone_width * (ga * ga + gb * gb).sqrt()
        };
        Vec2::new(extent(grad_u), extent(grad_v))
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

/// The world-space gradients of `u` and of `v` over the plane of the
/// triangle `v` with texture coordinates `uvs`, `None` for a degenerate
/// triangle. Fixed per triangle, so the scene works them out once.
pub fn uv_gradients(v: &[Vec3; 3], uvs: &[Vec2; 3]) -> Option<[Vec3; 2]> {
    let (e1, e2) = (v[1] - v[0], v[2] - v[0]);
    let n = e1.cross(e2);
    let n2 = n.length_squared();
    if n2 <= 0.0 || !n2.is_finite() {
        return None;
    }
    let (d1, d2) = (uvs[1] - uvs[0], uvs[2] - uvs[0]);
    // Gradient of a linear function with increments f1, f2 along e1, e2.
    let (a, b) = (e2.cross(n), n.cross(e1));
    Some([(a * d1.x + b * d2.x) / n2, (a * d1.y + b * d2.y) / n2])
}

/// UV units per world unit on the triangle `v` with texture coordinates
/// `uvs`: `√(uv area / world area)` (0 for a degenerate triangle).
pub fn uv_per_world(v: &[Vec3; 3], uvs: &[Vec2; 3]) -> f32 {
    let world2 = (v[1] - v[0]).cross(v[2] - v[0]).length();
    let (e1, e2) = (uvs[1] - uvs[0], uvs[2] - uvs[0]);
    let uv2 = (e1.x * e2.y - e1.y * e2.x).abs();
    if world2 > 0.0 { (uv2 / world2).sqrt() } else { 0.0 }
}

/// The surface a camera ray hits first, as the albedo, normal and depth
/// passes record it ([`Integrator::first_hit`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FirstHit {
    /// The surface's colour, clamped to `[0, 1]`: a Phong surface's diffuse
    /// albedo (texture included), a glTF surface's base colour (texture and
    /// vertex colour included), the tint of a mirror or of glass, an
    /// emitter's radiance; zero where the ray escapes.
    pub albedo: Vec3,
    /// The unit shading normal in world space (interpolated, normal-mapped,
    /// turned to face the camera); zero where the ray escapes.
    pub normal: Vec3,
    /// Distance from the camera's eye along the (unit) ray; `+∞` where the
    /// ray escapes.
    pub depth: f32,
}

impl FirstHit {
    /// What a ray that hits nothing records.
    pub const NOTHING: FirstHit = FirstHit { albedo: Vec3::ZERO, normal: Vec3::ZERO, depth: f32::INFINITY };
}

/// Which camera sample of which pixel a ray serves: the key of its random
/// numbers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SampleId {
    /// The pixel's sampler ([`Sampler::pixel`]).
    pub pixel: Sampler,
    /// Camera sample index within the pixel, `0..spp`.
    pub index: u32,
}

/// A Whitted ray tracer over one scene.
///
/// Area-light samples are stratified over the whole pixel: camera sample `s`
/// takes samples `s·N .. s·N + N` of one stratified set of `spp·N` points per
/// (pixel, depth, light), so supersampling refines the penumbra as a single,
/// larger stratified pattern rather than `spp` independent ones.
#[derive(Clone, Copy, Debug)]
pub struct Integrator<'a> {
    scene: &'a Scene,
    max_depth: u32,
    light_samples: u32,
    /// Division by the number of strata of one pixel's light-sample grid.
    light_strata: Divisor,
    /// That grid (`⌈√(spp · light_samples)⌉` strata a side), to be keyed per
    /// pixel ([`Integrator::light_set`]).
    light_grid_strata: Strata,
    /// Strata per side of that grid.
    light_grid: u32,
    /// One camera sample per pixel.
    one_camera_sample: bool,
    /// Trace area-light shadow rays adaptively ([`Integrator::area_adaptive`]).
    adaptive_shadows: bool,
    /// Ask the scene's shadow cells before tracing shadow rays ([`Integrator::with_shadow_cells`]).
    shadow_cells: bool,
    /// The first [`PREPARED_LIGHTS`] lights, prepared once
    /// ([`crate::lights::Light::prepare_area`]; `None` for point lights and degenerate ones).
    prepared: [Option<AreaSampler<'a>>; PREPARED_LIGHTS],
}

/// How many of a scene's lights an [`Integrator`] prepares up front; further
/// ones are prepared at each shading point (same numbers, more work).
const PREPARED_LIGHTS: usize = 8;

impl<'a> Integrator<'a> {
    /// An integrator with the recursion depth (at most [`MAX_DEPTH_LIMIT`])
    /// and light sample count of `settings`.
    pub fn new(scene: &'a Scene, settings: &RenderSettings) -> Self {
        let light_samples = settings.light_samples.max(1);
        let per_pixel = light_samples.saturating_mul(settings.spp.max(1)).min(1 << 24);
        let max_depth = settings.max_depth.min(MAX_DEPTH_LIMIT);
        let mut prepared = [None; PREPARED_LIGHTS];
        for (slot, light) in prepared.iter_mut().zip(&scene.lights) {
            *slot = light.prepare_area();
        }
        let light_grid = ceil_sqrt(per_pixel);
        Self {
            scene,
            max_depth,
            light_samples,
            light_strata: Divisor::new(light_grid * light_grid),
            light_grid_strata: Strata::new(light_grid, 0),
            light_grid,
            one_camera_sample: settings.spp <= 1,
            adaptive_shadows: true,
            shadow_cells: true,
            prepared,
        }
    }

    /// Switches adaptive area-light sampling on (the default) or off (every
    /// sample traced; for reference images and tests).
    pub fn with_adaptive_shadows(mut self, on: bool) -> Self {
        self.adaptive_shadows = on;
        self
    }

    /// Answers shadow rays from the scene's shadow cells where they can (the
    /// default; see [`crate::shadows`]) or traces every one through the BVH.
    /// The answers, and so the pixels, are the same.
    pub fn with_shadow_cells(mut self, on: bool) -> Self {
        self.shadow_cells = on;
        self
    }

    /// What the shadow cells know about shadow rays from `origin` (in cell
    /// `cell`) to light `index` ([`CellAnswer::Unknown`] with the cells off).
    #[inline]
    fn shadow_cell(&self, index: usize, cell: CellIndex, origin: Vec3) -> CellAnswer<'a> {
        if self.shadow_cells { self.scene.shadow_cell_in(index, cell, origin) } else { CellAnswer::Unknown }
    }

    /// Area-light samples at a hit whose contribution reaches the pixel
    /// scaled by `weight`: `⌈light_samples × max(weight)⌉`, at least one (all
    /// of them at the camera hit, where the weight is 1). Samples go where
    /// they show: behind a 10 % floor reflection one sample adds less noise
    /// to the pixel than eight do at the floor itself.
    #[inline]
    fn light_samples_for(&self, weight: Vec3) -> u32 {
        let w = weight.max_element();
        if w >= 1.0 {
            return self.light_samples;
        }
        // NaN weights take one sample (`max` ignores NaN).
        // ⌈x⌉ as −⌊−x⌋: `f32::ceil` is a call into the runtime's `ceilf`
        // without SSE4.1 (see `floor_f32`).
        let n = -crate::textures::floor_f32(-(self.light_samples as f32 * w.max(0.0)));
        (n as u32).clamp(1, self.light_samples)
    }

    /// Curvature estimate of triangle `prim` (see [`triangle_curvature`]).
    #[inline]
    fn curvature(&self, prim: u32) -> f32 {
        let i = prim as usize;
        triangle_curvature(&self.scene.triangles[i].v, &self.scene.shading[i].normals)
    }

    /// Point `j` of the pixel's stratified set of area-light samples.
    #[inline]
    #[cfg(test)]
    fn light_sample(&self, j: u32, sampler: &Sampler) -> Vec2 {
        self.light_sample_in(&self.light_set(sampler), j, sampler)
    }

    /// The pixel's stratified set of area-light samples drawn from `sampler`,
    /// prepared once for all the samples a shading point takes from it.
    #[inline]
    fn light_set(&self, sampler: &Sampler) -> Strata {
        self.light_grid_strata.with_key(sampler.bits(0))
    }

    /// Point `j` of the set `set` drawn from `sampler` (see [`Integrator::light_set`]).
    #[inline]
    fn light_sample_in(&self, set: &Strata, j: u32, sampler: &Sampler) -> Vec2 {
        set.point(self.light_strata.rem(j), sampler)
    }

    /// Radiance (linear RGB) arriving along the camera ray `ray`, whose cone
    /// and random numbers are given.
    #[inline]
    pub fn trace(&self, ray: &Ray, cone: RayCone, sample: &SampleId, counts: &mut RayCounts) -> Vec3 {
        self.trace_hit(ray, self.scene.intersect_visible(ray, 0.0, f32::INFINITY), cone, sample, counts)
    }

    /// [`Integrator::trace`] for a camera ray whose nearest hit the caller
    /// already found (e.g. with a packet query that gives exactly
    /// `scene.intersect(ray, 0.0, f32::INFINITY)`).
    #[inline]
    pub fn trace_hit(
        &self,
        ray: &Ray,
        hit: Option<Hit>,
        cone: RayCone,
        sample: &SampleId,
        counts: &mut RayCounts,
    ) -> Vec3 {
        counts.primary += 1;
        match self.scene.beyond_cutouts(ray, hit, f32::INFINITY) {
            Some(hit) => self.shade(ray, &hit, cone, 0, Vec3::ONE, sample, counts),
            None => self.scene.background(ray.dir),
        }
    }

    /// [`Integrator::trace_hit`] for up to [`PACKET_LANES`] camera rays at
    /// once (those selected by `active`), whose nearest hits the caller
    /// found (e.g. with [`crate::bvh::Bvh::intersect8`]); the same values bit
    /// for bit, with secondary rays traced in packets where they can be
    /// (see the module docs, "Packets").
    pub fn trace_packet(
        &self,
        rays: &[Ray; PACKET_LANES],
        hits: &[Option<Hit>; PACKET_LANES],
        cone: RayCone,
        samples: &[SampleId; PACKET_LANES],
        active: u8,
        counts: &mut RayCounts,
    ) -> [Vec3; PACKET_LANES] {
        counts.primary += u64::from(active.count_ones());
        let (cones, weights) = ([cone; PACKET_LANES], [Vec3::ONE; PACKET_LANES]);
        self.radiance_packet(rays, hits, &cones, 0, &weights, samples, active, counts)
    }

    /// Radiance along `ray` at recursion depth `depth`; `weight` is the
    /// branch's throughput to the pixel.
    fn radiance(
        &self,
        ray: &Ray,
        cone: RayCone,
        depth: u32,
        weight: Vec3,
        sample: &SampleId,
        counts: &mut RayCounts,
    ) -> Vec3 {
        match self.scene.intersect_visible(ray, 0.0, f32::INFINITY) {
            Some(hit) => self.shade(ray, &hit, cone, depth, weight, sample, counts),
            None => self.scene.background(ray.dir),
        }
    }

    /// Radiance leaving `hit`, the nearest hit of `ray`, towards the ray's origin.
    #[allow(clippy::too_many_arguments)]
    fn shade(
        &self,
        ray: &Ray,
        hit: &Hit,
        cone: RayCone,
        depth: u32,
        weight: Vec3,
        sample: &SampleId,
        counts: &mut RayCounts,
    ) -> Vec3 {
        let sp = self.surface(ray, hit, cone);
        let bounce = self.bounce(ray, hit, &sp, cone, depth, weight);
        let mut found = [Vec3::ZERO; 2];
        for (k, branch) in bounce.branches.iter().enumerate() {
            if let Some(b) = branch {
                counts.secondary += 1;
                found[k] = self.radiance(&b.ray, b.cone, depth + 1, b.weight, sample, counts);
            }
        }
        self.finish(ray, hit, &sp, cone, depth, weight, &bounce, found, sample, counts)
    }

    /// The secondary rays the material at `hit` spawns (see [`Bounce`]),
    /// leaving out those past the depth limit or below [`MIN_THROUGHPUT`].
    #[inline(always)]
    fn bounce(
        &self,
        ray: &Ray,
        hit: &Hit,
        sp: &SurfacePoint,
        cone: RayCone,
        depth: u32,
        weight: Vec3,
    ) -> Bounce {
        let branch = |ray: Ray, cone: RayCone, factor: Vec3| {
            let w = weight * factor;
            if depth >= self.max_depth || w.max_element() < MIN_THROUGHPUT {
                return None;
            }
            Some(Branch { ray, cone, factor, weight: w })
        };
        // The mirror direction and its ray cone, which every branching material has.
        let mirror =
            || (Ray::new(sp.above(), sp.reflect(ray.dir)), cone.reflected(hit.t, self.curvature(hit.prim)));
        let material = self.scene.materials.get(sp.material as usize).unwrap_or(&FALLBACK_MATERIAL);
        let mut bounce = Bounce::default();
        match material {
            Material::Phong { reflectivity, .. } => {
                let r = reflectivity.clamp(0.0, 1.0);
                if r > 0.0 {
                    let (refl, mirrored) = mirror();
                    bounce.branches[0] = branch(refl, mirrored, Vec3::splat(r));
                }
            }
            Material::Mirror { tint } => {
                let (refl, mirrored) = mirror();
                bounce.branches[0] = branch(refl, mirrored, *tint);
            }
            Material::Dielectric { ior, tint } => {
                let ior = if *ior > 0.0 && ior.is_finite() { *ior } else { 1.0 };
                let (n1, n2) = if sp.front { (1.0, ior) } else { (ior, 1.0) };
                let next = cone.after(hit.t);
                let (refl, mirrored) = mirror();
                match refract(ray.dir, sp.ns, n1 / n2) {
                    None => bounce.branches[0] = branch(refl, mirrored, Vec3::ONE),
                    Some(t) => {
                        let cos = if n1 <= n2 { -ray.dir.dot(sp.ns) } else { -t.dot(sp.ns) };
                        let f = schlick(cos, n1, n2);
                        let tint = if sp.front { *tint } else { Vec3::ONE };
                        bounce.branches[0] = branch(refl, mirrored, Vec3::splat(f));
                        bounce.branches[1] = branch(Ray::new(sp.below(), t), next, tint * (1.0 - f));
                        bounce.two = true;
                    }
                }
            }
            Material::Emissive { .. } => {}
            Material::Pbr(p) => {
                let shading = self.pbr_shading(p, ray, hit, sp, cone);
                let r = shading.reflection((-ray.dir.dot(sp.ns)).max(0.0));
                if r.max_element() > 0.0 {
                    let (refl, mirrored) = mirror();
                    bounce.branches[0] = branch(refl, mirrored, r);
                }
                bounce.pbr = Some(shading);
            }
        }
        bounce
    }

    /// The shading data of `hit` on `ray` ([`SurfacePoint::new`]), its
    /// shading normal bent by the material's normal map if it has one.
    #[inline]
    fn surface(&self, ray: &Ray, hit: &Hit, cone: RayCone) -> SurfacePoint {
        let mut sp = SurfacePoint::new(self.scene, ray, hit);
        if let Some(Material::Pbr(p)) = self.scene.materials.get(sp.material as usize)
            && let Some(map) = &p.normal_texture
        {
            self.bend_normal(&mut sp, map, p.normal_scale, ray, hit, cone);
        }
        sp
    }

    /// Bends `sp`'s shading normal by the tangent-space normal map `map`
    /// (glTF: red along +u, green along −v, blue along the normal; `scale`
    /// multiplies red and green). The tangent frame comes from the
    /// triangle's texture-coordinate gradients, made orthogonal to the
    /// shading normal. A bent normal that would face away from the viewer
    /// or below the surface is not used.
    fn bend_normal(
        &self,
        sp: &mut SurfacePoint,
        map: &TextureMap,
        scale: f32,
        ray: &Ray,
        hit: &Hit,
        cone: RayCone,
    ) {
        let scene = self.scene;
        let (Some([gu, gv]), Some(texture)) =
            (scene.uv_gradients(hit.prim), scene.textures.get(map.texture as usize))
        else {
            return;
        };
        let n = sp.ns;
        let t = (gu - n * n.dot(gu)).normalize_or_zero();
        let b = -gv;
        let b = (b - n * n.dot(b) - t * t.dot(b)).normalize_or_zero();
        if t == Vec3::ZERO || b == Vec3::ZERO {
            return;
        }
        let v = &scene.triangles[hit.prim as usize].v;
        let fp = sp.uv_footprint_from(Some([gu, gv]), v, ray.dir, cone.width_at(hit.t));
        let uv = scene.uv_of_set(map.set, hit.prim, hit.u, hit.v, sp.uv);
        let (uv, fp) = map.apply(uv, fp);
        let c = texture.eval_rect_clamped(uv, fp, map.clamped()) * 2.0 - Vec3::ONE;
        let bent = (t * (c.x * scale) + b * (c.y * scale) + n * c.z).normalize_or_zero();
        if bent.dot(ray.dir) < 0.0 && bent.dot(sp.ng) > 0.0 {
            sp.ns = bent;
        }
    }

    /// A glTF material at `hit`: its textures looked up over the hit's ray
    /// cone footprint, the vertex colour interpolated, mapped to Phong terms.
    #[inline]
    fn pbr_shading(&self, p: &Pbr, ray: &Ray, hit: &Hit, sp: &SurfacePoint, cone: RayCone) -> PbrShading {
        let scene = self.scene;
        let fp = if p.textures().next().is_some() {
            let v = &scene.triangles[hit.prim as usize].v;
            sp.uv_footprint_from(scene.uv_gradients(hit.prim), v, ray.dir, cone.width_at(hit.t))
        } else {
            Vec2::ZERO
        };
        let look = |map: &Option<TextureMap>| match map
            .as_ref()
            .and_then(|m| Some((m, scene.textures.get(m.texture as usize)?)))
        {
            Some((m, t)) => {
                let uv = scene.uv_of_set(m.set, hit.prim, hit.u, hit.v, sp.uv);
                let (uv, fp) = m.apply(uv, fp);
                t.eval_rect_clamped(uv, fp, m.clamped())
            }
            None => Vec3::ONE,
        };
        let colour = scene.vertex_colour(hit.prim, hit.u, hit.v);
        p.shade(look(&p.base_texture), look(&p.metallic_roughness), look(&p.emissive_texture), colour)
    }

    /// A Phong surface's diffuse albedo at `hit`: the constant, or the
    /// texture filtered over the ray cone's footprint times its tint.
    #[inline]
    fn phong_albedo(&self, albedo: &Albedo, ray: &Ray, hit: &Hit, sp: &SurfacePoint, cone: RayCone) -> Vec3 {
        let scene = self.scene;
        match *albedo {
            Albedo::Constant(c) => c,
            Albedo::Texture { texture, tint } => match scene.textures.get(texture as usize) {
                Some(t) => {
                    let i = hit.prim as usize;
                    let fp = sp.uv_footprint_from(
                        scene.uv_gradients(hit.prim),
                        &scene.triangles[i].v,
                        ray.dir,
                        cone.width_at(hit.t),
                    );
                    tint * t.eval_rect(sp.uv, fp)
                }
                None => tint,
            },
        }
    }

    /// What a camera ray sees at its first hit, for the albedo, normal and
    /// depth passes ([`FirstHit`]); `hit` is its nearest hit as
    /// [`Integrator::trace_hit`] takes it (cut-out surfaces are looked
    /// through here too). Traces no ray besides those of cut-outs.
    pub fn first_hit(&self, ray: &Ray, hit: Option<Hit>, cone: RayCone) -> FirstHit {
        let Some(hit) = self.scene.beyond_cutouts(ray, hit, f32::INFINITY) else {
            return FirstHit::NOTHING;
        };
        let sp = self.surface(ray, &hit, cone);
        let material = self.scene.materials.get(sp.material as usize).unwrap_or(&FALLBACK_MATERIAL);
        let albedo = match material {
            Material::Phong { albedo, .. } => self.phong_albedo(albedo, ray, &hit, &sp, cone),
            Material::Mirror { tint } | Material::Dielectric { tint, .. } => *tint,
            Material::Emissive { radiance } => *radiance,
            Material::Pbr(p) => self.pbr_shading(p, ray, &hit, &sp, cone).base_colour,
        };
        FirstHit { albedo: albedo.clamp(Vec3::ZERO, Vec3::ONE), normal: sp.ns, depth: hit.t }
    }

    /// Radiance leaving `hit` towards the ray's origin, given the radiance
    /// `found` along each branch of its [`Bounce`] (unused where there is
    /// no branch).
    #[allow(clippy::too_many_arguments)]
    #[inline]
    fn finish(
        &self,
        ray: &Ray,
        hit: &Hit,
        sp: &SurfacePoint,
        cone: RayCone,
        depth: u32,
        weight: Vec3,
        bounce: &Bounce,
        found: [Vec3; 2],
        sample: &SampleId,
        counts: &mut RayCounts,
    ) -> Vec3 {
        let scene = self.scene;
        let returned = |k: usize| match &bounce.branches[k] {
            Some(b) => b.factor * found[k],
            None => Vec3::ZERO,
        };
        let material = scene.materials.get(sp.material as usize).unwrap_or(&FALLBACK_MATERIAL);
        match material {
            Material::Phong { albedo, specular, shininess, reflectivity } => {
                let albedo = self.phong_albedo(albedo, ray, hit, sp, cone);
                let mut c = scene.ambient * albedo;
                c += self.direct(sp, ray.dir, albedo, *specular, *shininess, depth, weight, sample, counts);
                if *reflectivity > 0.0 {
                    c += returned(0);
                }
                c
            }
            Material::Mirror { .. } => returned(0),
            Material::Dielectric { .. } => match bounce.two {
                false => returned(0),
                true => returned(0) + returned(1),
            },
            Material::Emissive { radiance } => *radiance,
            Material::Pbr(p) => {
                let s = match bounce.pbr {
                    Some(s) => s,
                    None => self.pbr_shading(p, ray, hit, sp, cone),
                };
                let mut c = scene.ambient * s.albedo + s.emission;
                c += self.direct(
                    sp,
                    ray.dir,
                    s.albedo,
                    s.specular,
                    s.shininess,
                    depth,
                    weight,
                    sample,
                    counts,
                );
                c + returned(0)
            }
        }
    }

    /// Radiance along up to [`PACKET_LANES`] rays at once (those selected by
    /// `active`) whose nearest hits are `hits`: exactly what
    /// [`Integrator::radiance`] gives for each, bit for bit. The branches the
    /// hits spawn are traced as packets too ([`crate::bvh::Bvh::intersect8`],
    /// which finds the single-ray hits), branch by branch — a floor's
    /// reflections, a glass ball's refractions — as long as at least
    /// [`PACKET_MIN`] rays go on; sparser ones are traced one by one.
    #[allow(clippy::too_many_arguments)]
    fn radiance_packet(
        &self,
        rays: &[Ray; PACKET_LANES],
        hits: &[Option<Hit>; PACKET_LANES],
        cones: &[RayCone; PACKET_LANES],
        depth: u32,
        weights: &[Vec3; PACKET_LANES],
        samples: &[SampleId; PACKET_LANES],
        active: u8,
        counts: &mut RayCounts,
    ) -> [Vec3; PACKET_LANES] {
        let lanes = |mask: u8| (0..PACKET_LANES).filter(move |&l| mask & (1 << l) != 0);
        let looked_through;
        let hits = if self.scene.cutouts {
            looked_through =
                std::array::from_fn(|l| self.scene.beyond_cutouts(&rays[l], hits[l], f32::INFINITY));
            &looked_through
        } else {
            hits
        };
        let mut out: [Vec3; PACKET_LANES] = std::array::from_fn(|l| self.scene.background(rays[l].dir));
        let mut sps = [None; PACKET_LANES];
        let mut bounces = [Bounce::default(); PACKET_LANES];
        for hit in lanes(active).filter_map(|l| hits[l].as_ref()) {
            self.scene.prefetch_shading(hit.prim);
        }
        for l in lanes(active) {
            if let Some(hit) = &hits[l] {
                let sp = self.surface(&rays[l], hit, cones[l]);
                bounces[l] = self.bounce(&rays[l], hit, &sp, cones[l], depth, weights[l]);
                sps[l] = Some(sp);
            }
        }
        // Radiance along each lane's branch k, branch by branch.
        let mut found = [[Vec3::ZERO; PACKET_LANES]; 2];
        for (k, found) in found.iter_mut().enumerate() {
            let going =
                lanes(active).filter(|&l| bounces[l].branches[k].is_some()).fold(0u8, |m, l| m | 1 << l);
            if going == 0 {
                continue;
            }
            let mut next = [Ray::new(Vec3::ZERO, Vec3::Z); PACKET_LANES];
            let mut next_cones = [RayCone::primary(0.0); PACKET_LANES];
            let mut next_weights = [Vec3::ZERO; PACKET_LANES];
            for l in lanes(going) {
                if let Some(b) = &bounces[l].branches[k] {
                    (next[l], next_cones[l], next_weights[l]) = (b.ray, b.cone, b.weight);
                }
            }
            counts.secondary += u64::from(going.count_ones());
            if going.count_ones() < PACKET_MIN {
                for l in lanes(going) {
                    found[l] = self.radiance(
                        &next[l],
                        next_cones[l],
                        depth + 1,
                        next_weights[l],
                        &samples[l],
                        counts,
                    );
                }
                continue;
            }
            let next_hits =
                self.scene.bvh.intersect8(&next, [0.0; PACKET_LANES], [f32::INFINITY; PACKET_LANES], going);
            let radiance = self.radiance_packet(
                &next,
                &next_hits,
                &next_cones,
                depth + 1,
                &next_weights,
                samples,
                going,
                counts,
            );
            for l in lanes(going) {
                found[l] = radiance[l];
            }
        }
        for l in lanes(active) {
            if let (Some(hit), Some(sp)) = (&hits[l], &sps[l]) {
                out[l] = self.finish(
                    &rays[l],
                    hit,
                    sp,
                    cones[l],
                    depth,
                    weights[l],
                    &bounces[l],
                    [found[0][l], found[1][l]],
                    &samples[l],
                    counts,
                );
            }
        }
        out
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
        weight: Vec3,
        sample: &SampleId,
        counts: &mut RayCounts,
    ) -> Vec3 {
        let scene = self.scene;
        let shininess = if shininess.is_finite() { shininess.max(0.0) } else { 0.0 };
        let lobe = Lobe {
            diffuse: albedo * (1.0 / PI),
            spec: specular * ((shininess + 2.0) / (2.0 * PI)),
            has_spec: specular.max_element() > 0.0,
            shininess,
            mirrored_view: reflect(view_dir, sp.ns),
            origin: sp.above(),
        };
        let depth_sampler = sample.pixel.child(depth);
        let first = sample.index.wrapping_mul(self.light_samples);
        let mut total = Vec3::ZERO;
        // The shadow cell around the point, shared by the lights' grids.
        let at = if self.shadow_cells { scene.shadow_cell_index(lobe.origin) } else { CellIndex::default() };
        for (index, light) in scene.lights.iter().enumerate() {
            if !light.is_area() {
                if let Some(c) = light.sample(sp.p, Vec2::splat(0.5)).and_then(|ls| lobe.eval(sp, &ls)) {
                    let cell = self.shadow_cell(index, at, lobe.origin);
                    if cell.is_clear() {
                        total += c.0;
                        continue;
                    }
                    counts.shadow += 1;
                    if !ShadowRay::new(lobe.origin, c.1.dir, c.1.dist).blocked(scene, &cell) {
                        total += c.0;
                    }
                }
                continue;
            }
            // Area lights: skip them when the point is behind the emitter, and
            // give each its own stratified, jittered set of samples.
            let beyond_prepared;
            let prepared = match self.prepared.get(index) {
                Some(Some(p)) if p.faces(sp.p) => p,
                Some(_) => continue,
                None => {
                    beyond_prepared = light.area_sampler(sp.p);
                    let Some(p) = &beyond_prepared else { continue };
                    p
                }
            };
            let light_sampler = depth_sampler.child(index as u32);
            let n = self.light_samples_for(weight);
            let area = AreaSamples { light: prepared, sampler: light_sampler, first, n };
            let cell = self.shadow_cell(index, at, lobe.origin);
            let clear = cell.is_clear();
            // With more than a handful of samples: the diffuse part exactly,
            // scaled by the fraction of it the samples find unblocked.
            if n > ADAPTIVE_TESTS as u32
                && n <= RATIO_MAX as u32
                && let Some(omega) = prepared.projected_solid_angle(sp.p, sp.ns, sp.ng)
            {
                total += self.area_ratio(sp, &lobe, &area, omega, &cell, counts);
                continue;
            }
            let sum =
                if !clear && self.adaptive_shadows && (ADAPTIVE_TESTS as u32) < n && n <= ADAPTIVE_MAX as u32
                {
                    self.area_adaptive(sp, &lobe, &area, &cell, counts)
                } else {
                    // Every sample traced (or, with nothing in the way, none
                    // needs to be): the same sum.
                    let mut sum = Vec3::ZERO;
                    // A pixel's only sample of this light (one camera sample,
                    // one light sample, as behind a faint reflection) has no
                    // other to be stratified against: it is drawn uniformly,
                    // without building the pixel's permutation of strata.
                    let set = (n > 1 || !self.one_camera_sample).then(|| self.light_set(&light_sampler));
                    for j in 0..n {
                        let u = match &set {
                            Some(set) => self.light_sample_in(set, first.wrapping_add(j), &light_sampler),
                            None => Vec2::from(light_sampler.pair(1)),
                        };
                        let Some((c, ls)) = prepared.sample(sp.p, u).and_then(|ls| lobe.eval(sp, &ls)) else {
                            continue;
                        };
                        if clear {
                            sum += c;
                            continue;
                        }
                        counts.shadow += 1;
                        if !ShadowRay::new(lobe.origin, ls.dir, ls.dist).blocked(scene, &cell) {
                            sum += c;
                        }
                    }
                    sum
                };
            total += sum / n as f32;
        }
        total
    }

    /// The points of `light` at the centres of the four corner strata of a
    /// pixel's light-sample grid (its unit-square corners first along `u`,
    /// then along `v`), where [`Integrator::area_ratio`] tests whether a
    /// point sees all of the light, none or part of it.
    fn corner_points(&self, light: &AreaSampler) -> Option<[Vec3; 4]> {
        let h = 0.5 / self.light_grid as f32;
        let mut points = [Vec3::ZERO; 4];
        for (k, q) in points.iter_mut().enumerate() {
            let u = Vec2::new(if k & 1 == 0 { h } else { 1.0 - h }, if k & 2 == 0 { h } else { 1.0 - h });
            *q = light.point(u)?.0;
        }
        Some(points)
    }

    /// Which corner-stratum centres of `light` (bit `k`:
    /// [`Integrator::corner_points`]`[k]`) are hidden from `origin`, one
    /// shadow ray each (all four hidden if the light has no such points).
    fn corners_blocked(
        &self,
        origin: Vec3,
        light: &AreaSampler,
        cell: &CellAnswer,
        counts: &mut RayCounts,
    ) -> u8 {
        let Some(points) = self.corner_points(light) else { return 15 };
        let mut hidden = 0u8;
        for (k, ray) in ShadowRay::towards4(origin, &points).iter().enumerate() {
            counts.shadow += 1;
            if ray.blocked(self.scene, cell) {
                hidden |= 1 << k;
            }
        }
        hidden
    }

    /// The corner index (as in [`Integrator::corner_points`]) of stratum
    /// `(column, row)` of the light-sample grid, if it is a corner one.
    #[inline]
    fn corner_stratum(&self, (sx, sy): (u32, u32)) -> Option<usize> {
        let last = self.light_grid - 1;
        let side = |c: u32| match c {
            0 => Some(0),
            c if c == last => Some(1),
            _ => None,
        };
        Some(side(sx)? | side(sy)? << 1)
    }

    /// The sum of an area light's sample contributions, traced adaptively:
    /// first the [`ADAPTIVE_TESTS`] samples nearest the corners of the light's
    /// sample square ([`spread_tests`]); when all of them reach the light, or
    /// all are blocked, the point is taken to be fully lit (every remaining
    /// sample counts, without a shadow ray) or fully shadowed (none counts);
    /// otherwise — a penumbra — every remaining sample is traced too.
    ///
    /// The result is bit-for-bit the exhaustive sum wherever the tests
    /// disagree or the point really is fully lit or fully shadowed (the same
    /// samples, summed in the same order); only where an occluder hides part
    /// of the light yet none of its corners can the two differ.
    fn area_adaptive(
        &self,
        sp: &SurfacePoint,
        lobe: &Lobe,
        area: &AreaSamples,
        cell: &CellAnswer,
        counts: &mut RayCounts,
    ) -> Vec3 {
        let scene = self.scene;
        let n = area.n as usize;
        let mut us = [Vec2::ZERO; ADAPTIVE_MAX];
        let set = self.light_set(&area.sampler);
        for (j, u) in us[..n].iter_mut().enumerate() {
            *u = self.light_sample_in(&set, area.first.wrapping_add(j as u32), &area.sampler);
        }
        let tests = spread_tests(&us[..n]);
        let mut tested = [Vec3::ZERO; ADAPTIVE_TESTS];
        let (mut visible, mut blocked, mut untraced) = (0, 0, 0);
        for (k, &j) in tests.iter().enumerate() {
            if tests[..k].contains(&j) {
                continue;
            }
            let Some((c, ls)) = area.light.sample(sp.p, us[j]).and_then(|ls| lobe.eval(sp, &ls)) else {
                untraced += 1;
                continue;
            };
            counts.shadow += 1;
            if ShadowRay::new(lobe.origin, ls.dir, ls.dist).blocked(scene, cell) {
                blocked += 1;
            } else {
                visible += 1;
                tested[k] = c;
            }
        }
        let uniform = untraced == 0 && visible + blocked >= 2 && (visible == 0 || blocked == 0);
        if uniform && visible == 0 {
            return Vec3::ZERO;
        }
        let mut sum = Vec3::ZERO;
        for (j, &u) in us[..n].iter().enumerate() {
            if let Some(k) = tests.iter().position(|&t| t == j) {
                // Adding +0 for a blocked test sample leaves the (non-negative-
                // zero) sum's bits unchanged, as skipping it would.
                sum += tested[k];
                continue;
            }
            let Some((c, ls)) = area.light.sample(sp.p, u).and_then(|ls| lobe.eval(sp, &ls)) else {
                continue;
            };
            if uniform {
                sum += c;
            } else {
                counts.shadow += 1;
                if !ShadowRay::new(lobe.origin, ls.dir, ls.dist).blocked(scene, cell) {
                    sum += c;
                }
            }
        }
        sum
    }
}

impl Integrator<'_> {
    /// An area light's contribution at `sp` by the ratio estimator (Heitz,
    /// Hill & McGuire 2018, "Combining Analytic Direct Illumination and
    /// Stochastic Shadows"): the diffuse part is the exact unshadowed
    /// integral (`omega`, the light's projected solid angle, times the
    /// radiance and the diffuse lobe) times the fraction of it that reaches
    /// the point among the samples, `Σ visible wⱼ / Σ wⱼ` with `wⱼ` each
    /// sample's unshadowed diffuse contribution; the Phong highlight is the
    /// samples' plain average. Unshadowed surfaces are thus free of sampling
    /// noise, and penumbrae keep the shading's shape.
    ///
    /// Where the light is known to be fully visible the diffuse part needs no
    /// sample at all, and the highlight none either where it cannot reach
    /// 10⁻³ of the diffuse part ([`Lobe::highlight_negligible`]): in a clear
    /// shadow cell, and where the shadow rays to the centres of the four
    /// corner strata of the pixel's light-sample grid
    /// ([`Integrator::corner_points`]) all reach them. Where all four are
    /// blocked the point is taken to be in the umbra. Only where they
    /// disagree (a penumbra) are the samples traced, and those that fall in
    /// a corner stratum take its centre's answer instead (the midpoint rule
    /// on that stratum). As in [`Integrator::area_adaptive`], an occluder
    /// that hides part of the light but none of the four centres goes unseen.
    ///
    /// The caller guarantees the whole light above both horizons at `sp`.
    fn area_ratio(
        &self,
        sp: &SurfacePoint,
        lobe: &Lobe,
        area: &AreaSamples,
        omega: f32,
        cell: &CellAnswer,
        counts: &mut RayCounts,
    ) -> Vec3 {
        let light = area.light;
        let radiance = light.radiance();
        let unshadowed = lobe.diffuse * radiance * omega;
        let highlight = lobe.has_spec && !lobe.highlight_negligible(sp, light);
        let clear = cell.is_clear();
        if clear && !highlight {
            return unshadowed;
        }
        // Which samples reach the light: all of them in a clear cell, all or
        // none where the corner tests agree, else each traced — but those in
        // a corner stratum take the answer of its centre.
        let n = area.n as usize;
        let all = (1u64 << n) - 1;
        let mut visible = all;
        let mut hidden = 0u8;
        if !clear && self.adaptive_shadows {
            hidden = self.corners_blocked(lobe.origin, light, cell, counts);
            if hidden == 0 {
                if !highlight {
                    return unshadowed;
                }
            } else if hidden == 15 {
                return Vec3::ZERO;
            }
        }
        let set = self.light_set(&area.sampler);
        let mut us = [Vec2::ZERO; RATIO_MAX];
        for (j, u) in us[..n].iter_mut().enumerate() {
            *u = self.light_sample_in(&set, area.first.wrapping_add(j as u32), &area.sampler);
        }
        let mut samples = RatioSamples::default();
        samples.fill(&us[..n], light, sp, lobe);
        if !clear && (hidden != 0 || !self.adaptive_shadows) {
            for j in 0..n {
                if samples.valid & (1 << j) == 0 {
                    continue;
                }
                let i = self.light_strata.rem(area.first.wrapping_add(j as u32));
                let blocked =
                    match self.adaptive_shadows.then(|| self.corner_stratum(set.stratum(i))).flatten() {
                        Some(k) => hidden & (1 << k) != 0,
                        None => {
                            counts.shadow += 1;
                            ShadowRay::new(lobe.origin, samples.dirs[j], samples.dists[j])
                                .blocked(self.scene, cell)
                        }
                    };
                if blocked {
                    visible &= !(1 << j);
                }
            }
        }
        let (valid, w, phong) = (samples.valid, &samples.w, &samples.phong);
        visible &= valid;
        let (mut sum_w, mut sum_vis, mut spec) = (Vec3::ZERO, Vec3::ZERO, Vec3::ZERO);
        for j in 0..n {
            if valid & (1 << j) == 0 {
                continue;
            }
            sum_w += w[j];
            if visible & (1 << j) != 0 {
                sum_vis += w[j];
                spec += w[j] * phong[j];
            }
        }
        let diffuse = if visible == valid {
            unshadowed
        } else {
            let ratio = Vec3::select(sum_w.cmpgt(Vec3::ZERO), sum_vis / sum_w, Vec3::ZERO);
            unshadowed * ratio
        };
        if highlight { diffuse + lobe.spec * spec / n as f32 } else { diffuse }
    }
}

/// The samples of [`Integrator::area_ratio`], evaluated four at a time.
#[derive(Default)]
struct RatioSamples {
    /// Unshadowed irradiance times the receiver's cosine.
    w: [Vec3; RATIO_MAX],
    /// The Phong factor.
    phong: [f32; RATIO_MAX],
    /// Shadow ray direction and length.
    dirs: [Vec3; RATIO_MAX],
    dists: [f32; RATIO_MAX],
    /// Samples above both horizons.
    valid: u64,
}

impl RatioSamples {
    /// Evaluates the light at the points `us` of the unit square (at most
    /// [`RATIO_MAX`]), four lanes at a time ([`AreaSampler::sample4`]) with
    /// the operations of [`Lobe::eval`], so each sample has the same bits as
    /// when evaluated alone.
    #[inline(always)]
    fn fill(&mut self, us: &[Vec2], light: &AreaSampler, sp: &SurfacePoint, lobe: &Lobe) {
        for (c, chunk) in us.chunks(4).enumerate() {
            let (mut ux, mut uy) = ([0.0; 4], [0.0; 4]);
            for (i, u) in chunk.iter().enumerate() {
                (ux[i], uy[i]) = (u.x, u.y);
            }
            let live = (1u32 << chunk.len()) - 1;
            match light.sample4(sp.p, Vec4::from_array(ux), Vec4::from_array(uy)) {
                Some(ls) => self.put4(c * 4, &ls, live, light.radiance(), sp, lobe),
                None => {
                    for (i, &u) in chunk.iter().enumerate() {
                        if let Some(ls) = light.sample(sp.p, u) {
                            self.put1(c * 4 + i, &ls, sp, lobe);
                        }
                    }
                }
            }
        }
    }

    /// Stores lanes `live` of `ls` as samples `first..first + 4`.
    #[inline(always)]
    fn put4(
        &mut self,
        first: usize,
        ls: &LightSamples4,
        live: u32,
        radiance: Vec3,
        sp: &SurfacePoint,
        lobe: &Lobe,
    ) {
        let dot = |v: Vec3| ls.dir[0] * v.x + ls.dir[1] * v.y + ls.dir[2] * v.z;
        let cos = dot(sp.ns);
        let valid = ls.valid & live & (cos.cmpgt(Vec4::ZERO) & dot(sp.ng).cmpgt(Vec4::ZERO)).bitmask();
        let w = [0, 1, 2].map(|a| (Vec4::splat(radiance[a]) * ls.scale * cos).to_array());
        let phong = if lobe.has_spec {
            let rv = dot(lobe.mirrored_view);
            Vec4::select(rv.cmpgt(Vec4::ZERO), phong_lobe4(rv, lobe.shininess), Vec4::ZERO).to_array()
        } else {
            [0.0; 4]
        };
        let (dir, dist) = (ls.dir.map(|v| v.to_array()), ls.dist.to_array());
        for i in 0..4 {
            if valid & (1 << i) != 0 {
                let j = first + i;
                self.valid |= 1 << j;
                self.w[j] = Vec3::new(w[0][i], w[1][i], w[2][i]);
                self.phong[j] = phong[i];
                self.dirs[j] = Vec3::new(dir[0][i], dir[1][i], dir[2][i]);
                self.dists[j] = dist[i];
            }
        }
    }

    /// Stores `ls` as sample `j` if it lies above both horizons.
    #[inline]
    fn put1(&mut self, j: usize, ls: &LightSample, sp: &SurfacePoint, lobe: &Lobe) {
        let cos = sp.ns.dot(ls.dir);
        if cos > 0.0 && sp.ng.dot(ls.dir) > 0.0 {
            self.valid |= 1 << j;
            self.w[j] = ls.irradiance * cos;
            self.phong[j] = lobe.phong(ls.dir);
            self.dirs[j] = ls.dir;
            self.dists[j] = ls.dist;
        }
    }
}

/// The secondary rays a hit spawns: mirror reflection (branch 0) and, for
/// a dielectric that does not reflect totally, refraction (branch 1); each
/// brings back `factor ×` the radiance it finds.
#[derive(Clone, Copy, Default)]
struct Bounce {
    branches: [Option<Branch>; 2],
    /// A dielectric's reflection and refraction both (its radiance is their sum).
    two: bool,
    /// A glTF material's terms at the hit, worked out once for both halves.
    pbr: Option<PbrShading>,
}

/// One secondary ray of a [`Bounce`].
#[derive(Clone, Copy)]
struct Branch {
    ray: Ray,
    cone: RayCone,
    /// The share of the radiance along `ray` that comes back.
    factor: Vec3,
    /// The branch's throughput to the pixel.
    weight: Vec3,
}

/// The integrator traces a branch as a packet when at
/// least this many of its rays go on.
pub const PACKET_MIN: u32 = 4;

/// Area lights with more samples per shading point than this are traced
/// adaptively (see the module docs): this many test samples first.
pub const ADAPTIVE_TESTS: usize = 4;

/// Area lights with more samples per shading point than this are always
/// traced exhaustively (the adaptive path keeps its samples on the stack).
pub const ADAPTIVE_MAX: usize = 64;

/// Area lights with at most this many samples per shading point (and more
/// than [`ADAPTIVE_TESTS`]) use the ratio estimator
/// (`Integrator::area_ratio`, which keeps its samples on the stack).
pub const RATIO_MAX: usize = 16;

/// The indices of the samples nearest the four corners of the unit square
/// (smallest and largest `x + y` and `x − y`; the first on ties), which the
/// light maps to its extremities. Indices may repeat for very few samples.
pub fn spread_tests(us: &[Vec2]) -> [usize; ADAPTIVE_TESTS] {
    let mut best = [0usize; 4];
    let key = |u: Vec2| [u.x + u.y, -(u.x + u.y), u.x - u.y, u.y - u.x];
    let mut lo = key(us[0]);
    for (j, &u) in us.iter().enumerate().skip(1) {
        let k = key(u);
        for c in 0..4 {
            if k[c] < lo[c] {
                lo[c] = k[c];
                best[c] = j;
            }
        }
    }
    best
}

/// The Phong lobe at one shading point, ready for light samples.
struct Lobe {
    diffuse: Vec3,
    spec: Vec3,
    has_spec: bool,
    shininess: f32,
    mirrored_view: Vec3,
    /// Origin of the shadow rays.
    origin: Vec3,
}

impl Lobe {
    /// The Phong factor `max(0, R·L)^s` for light arriving along unit `dir`
    /// (0 without a highlight).
    #[inline(always)]
    fn phong(&self, dir: Vec3) -> f32 {
        if !self.has_spec {
            return 0.0;
        }
        let rv = self.mirrored_view.dot(dir);
        if rv > 0.0 { phong_lobe(rv, self.shininess) } else { 0.0 }
    }

    /// True when the highlight `spec · max(0, R·L)^s` cannot reach 10⁻³ of
    /// the diffuse lobe (plus 10⁻⁵) for any direction `L` towards `light`
    /// from `sp`: the mirrored view direction `R` lies outside the cone
    /// around the light's bounding sphere by an angle whose cosine, raised to
    /// `s`, is that small.
    fn highlight_negligible(&self, sp: &SurfacePoint, light: &AreaSampler) -> bool {
        let (centre, radius) = light.bounding_sphere();
        let d = centre - sp.p;
        let dist = d.length();
        if !(dist > radius && dist.is_finite()) {
            return false;
        }
        let cos_t = self.mirrored_view.dot(d / dist);
        let sin_a = radius / dist;
        let cos_a = (1.0 - sin_a * sin_a).max(0.0).sqrt();
        if cos_t >= cos_a {
            return false;
        }
        let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
        // cos(θ − α), the largest cosine between R and the cone.
        let bound = (cos_t * cos_a + sin_t * sin_a).max(0.0);
        self.spec.max_element() * phong_lobe(bound, self.shininess)
            <= 1e-3 * self.diffuse.max_element() + 1e-5
    }

    /// The contribution of light sample `ls` if it is not shadowed, or `None`
    /// when it lies below the shading or geometric horizon.
    #[inline(always)]
    fn eval(&self, sp: &SurfacePoint, ls: &LightSample) -> Option<(Vec3, LightSample)> {
        let cos = sp.ns.dot(ls.dir);
        if cos <= 0.0 || sp.ng.dot(ls.dir) <= 0.0 {
            return None;
        }
        let mut f = self.diffuse;
        if self.has_spec {
            // Adding +0 where the lobe is 0 leaves `f`'s bits as they are.
            f += self.spec * self.phong(ls.dir);
        }
        Some((f * ls.irradiance * cos, *ls))
    }
}

/// One area light's samples at one shading point.
struct AreaSamples<'a, 'l> {
    light: &'a AreaSampler<'l>,
    sampler: Sampler,
    first: u32,
    n: u32,
}

/// A shadow ray from `origin` along unit `dir` that stops
/// [`SHADOW_SHORTEN`] of the way to a light point at distance `dist`.
#[derive(Clone, Copy)]
struct ShadowRay {
    ray: Ray,
    t_max: f32,
}

impl ShadowRay {
    #[inline(always)]
    fn new(origin: Vec3, dir: Vec3, dist: f32) -> Self {
        Self { ray: Ray::new(origin, dir), t_max: dist * SHADOW_SHORTEN }
    }

    /// The shadow rays from `origin` to the four light points `to`, worked
    /// out side by side in SIMD lanes with the operations of
    /// `Self::new(origin, d / |d|, |d|)` (`d = to − origin`), so each ray has
    /// the same bits as when made alone.
    #[inline]
    fn towards4(origin: Vec3, to: &[Vec3; 4]) -> [Self; 4] {
        let axis = |a: usize| Vec4::from_array(to.map(|q| q[a])) - Vec4::splat(origin[a]);
        let (dx, dy, dz) = (axis(0), axis(1), axis(2));
        let dist = (dx * dx + dy * dy + dz * dz).sqrt();
        let (dx, dy, dz, dist) =
            ((dx / dist).to_array(), (dy / dist).to_array(), (dz / dist).to_array(), dist.to_array());
        std::array::from_fn(|k| Self::new(origin, Vec3::new(dx[k], dy[k], dz[k]), dist[k]))
    }

    /// Whether anything blocks the ray; `cell` is what the shadow cells
    /// know about rays from its origin to its light.
    #[inline(always)]
    fn blocked(&self, scene: &Scene, cell: &CellAnswer) -> bool {
        if scene.cutouts {
            // Cut-out surfaces let light through: the nearest hit that is not.
            return scene.occluded_visible(&self.ray, 0.0, self.t_max);
        }
        cell.occluded(&scene.bvh, &self.ray, 0.0, self.t_max)
    }
}

/// Curvature of a smooth-shaded triangle estimated from its vertex normals:
/// the largest change of normal per unit length along an edge (0 for flat
/// shading, `1/r` on a sphere of radius `r`).
#[inline]
pub fn triangle_curvature(v: &[Vec3; 3], normals: &[Vec3; 3]) -> f32 {
    if normals[0] == normals[1] && normals[1] == normals[2] {
        return 0.0; // flat shading (also what the loop below finds)
    }
    let mut k = 0.0f32;
    for (a, b) in [(0, 1), (1, 2), (2, 0)] {
        let len = (v[a] - v[b]).length();
        if len > 0.0 {
            k = k.max((normals[a] - normals[b]).length() / len);
        }
    }
    if k.is_finite() { k } else { 0.0 }
}

/// `x^s` for the Phong lobe: exponentiation by squaring for integer exponents
/// up to 4096 (the common case, a handful of multiplications), `powf`
/// otherwise. Both are deterministic.
#[inline]
pub fn phong_lobe(x: f32, s: f32) -> f32 {
    match integer_exponent(s) {
        Some(n) => power(x, 1.0, n),
        None => math::powf(x, s),
    }
}

/// `s` as an integer exponent for [`power`], when it is one of 0..=4096.
#[inline]
fn integer_exponent(s: f32) -> Option<u32> {
    ((0.0..=4096.0).contains(&s) && s == crate::textures::floor_f32(s)).then_some(s as u32)
}

/// `x^n` by squaring (`one` is the multiplicative identity): the same
/// multiplications in the same order for a float and for each SIMD lane.
#[inline(always)]
fn power<T: Copy + std::ops::MulAssign>(x: T, one: T, mut n: u32) -> T {
    let (mut base, mut acc) = (x, one);
    while n > 0 {
        if n & 1 == 1 {
            acc *= base;
        }
        base *= base;
        n >>= 1;
    }
    acc
}

/// [`phong_lobe`] in four lanes, with the same operations in each.
#[inline]
pub fn phong_lobe4(x: Vec4, s: f32) -> Vec4 {
    match integer_exponent(s) {
        Some(n) => power(x, Vec4::ONE, n),
        None => Vec4::from_array(x.to_array().map(|x| math::powf(x, s))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lights::Light;
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
    fn highlight_is_negligible_only_far_from_the_mirror_direction() {
        use crate::lights::Light;
        // A 1 × 1 lamp 4 above the origin, shining down; a floor point at the origin.
        let lamp = Light::Area {
            vertices: vec![
                Vec3::new(-0.5, 4.0, -0.5),
                Vec3::new(0.5, 4.0, -0.5),
                Vec3::new(0.5, 4.0, 0.5),
                Vec3::new(-0.5, 4.0, 0.5),
            ],
            radiance: Vec3::ONE,
        };
        let light = lamp.area_sampler(Vec3::ZERO).expect("faces the floor");
        let sp = SurfacePoint {
            p: Vec3::ZERO,
            ng: Vec3::Y,
            ns: Vec3::Y,
            uv: Vec2::ZERO,
            front: true,
            material: 0,
            eps: 1e-5,
            cos_view: 1.0,
        };
        let lobe = |view: Vec3, shininess: f32| Lobe {
            diffuse: Vec3::splat(0.5 / PI),
            spec: Vec3::splat(0.3 * (shininess + 2.0) / (2.0 * PI)),
            has_spec: true,
            shininess,
            mirrored_view: reflect(view.normalize(), Vec3::Y),
            origin: Vec3::ZERO,
        };
        // Seen from straight above, the lamp sits in the mirror direction.
        assert!(!lobe(Vec3::NEG_Y, 40.0).highlight_negligible(&sp, &light));
        // At a grazing view the mirror direction is ~80° off the lamp: negligible for
        // s = 40 (cos⁴⁰ 80° ≈ 10⁻³⁰), not for s = 1.
        let grazing = Vec3::new(1.0, -0.18, 0.0);
        assert!(lobe(grazing, 40.0).highlight_negligible(&sp, &light));
        assert!(!lobe(grazing, 1.0).highlight_negligible(&sp, &light));
        // And where it says so, no direction towards the lamp gets 10⁻³ of the diffuse lobe.
        for (view, s) in [(Vec3::new(1.0, -0.6, 0.3), 40.0), (Vec3::new(1.0, -1.2, 0.0), 400.0)] {
            let l = lobe(view, s);
            assert!(l.highlight_negligible(&sp, &light), "{view:?}, s = {s}");
            for k in 0..100 {
                let u = Vec2::new((k % 10) as f32 / 9.0, (k / 10) as f32 / 9.0);
                let ls = light.sample(Vec3::ZERO, u).unwrap();
                assert!(l.spec.x * l.phong(ls.dir) <= 1e-3 * l.diffuse.x + 1e-5);
            }
        }
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
        assert!((uv_per_world(&scene.triangles[0].v, &scene.shading[0].uvs) - 1.0).abs() < 1e-6);
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
    fn light_samples_are_stratified_over_the_whole_pixel() {
        let scene = one_triangle([Vec3::Z; 3]);
        let settings = RenderSettings { spp: 4, light_samples: 4, ..Default::default() };
        let integrator = Integrator::new(&scene, &settings);
        let sampler = Sampler::pixel(5, 6, 7).child(0).child(0);
        // The 4 camera samples × 4 shadow rays fill the 4 × 4 strata once each.
        let mut seen = [false; 16];
        for camera_sample in 0..4 {
            for j in 0..4 {
                let u = integrator.light_sample(camera_sample * 4 + j, &sampler);
                let cell = (u.y * 4.0) as usize * 4 + (u.x * 4.0) as usize;
                assert!(!seen[cell], "stratum {cell} twice");
                seen[cell] = true;
            }
        }
    }

    #[test]
    fn phong_lobe_matches_powf() {
        for s in [0.0f32, 1.0, 2.0, 7.0, 32.0, 100.0, 12.5, 4097.0] {
            for x in [0.0f32, 0.3, 0.9, 0.999, 1.0] {
                let (a, b) = (phong_lobe(x, s), math::powf(x, s));
                assert!((a - b).abs() <= 1e-5 * b.max(1e-30) + 1e-30, "{x}^{s}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn ratio_samples_four_at_a_time_are_the_single_samples_bit_for_bit() {
        // A parallelogram lamp (the four-lane path) and a trapezoid (one by one).
        let parallelogram = vec![
            Vec3::new(-1.0, 5.0, -1.0),
            Vec3::new(1.0, 5.0, -1.0),
            Vec3::new(1.5, 5.0, 1.0),
            Vec3::new(-0.5, 5.0, 1.0),
        ];
        let trapezoid = vec![
            Vec3::new(-1.0, 5.0, -1.0),
            Vec3::new(1.0, 5.0, -1.0),
            Vec3::new(0.5, 5.0, 1.0),
            Vec3::new(-0.5, 5.0, 1.0),
        ];
        let mut next = Sampler::new(4, 3, 2, 1).stream();
        let mut compared = 0;
        for vertices in [parallelogram, trapezoid] {
            let light = Light::Area { vertices, radiance: Vec3::new(1.0, 0.9, 0.8) };
            for i in 0..500 {
                let p = Vec3::new(next() * 6.0 - 3.0, next() * 2.0, next() * 6.0 - 3.0);
                let Some(prepared) = light.area_sampler(p) else { continue };
                let ng = Vec3::new(next() - 0.5, 1.0, next() - 0.5).normalize();
                let ns = (ng + Vec3::new(next() - 0.5, 0.0, next() - 0.5) * 0.4).normalize();
                let sp = SurfacePoint {
                    p,
                    ng,
                    ns,
                    uv: Vec2::ZERO,
                    front: true,
                    material: 0,
                    eps: 1e-4,
                    cos_view: 1.0,
                };
                let view = Vec3::new(next() - 0.5, -1.0, next() - 0.5).normalize();
                let lobe = Lobe {
                    diffuse: Vec3::splat(0.2),
                    spec: Vec3::splat(0.5),
                    has_spec: i % 4 != 0,
                    shininess: [32.0, 7.5, 1.0][i % 3],
                    mirrored_view: reflect(view, sp.ns),
                    origin: sp.p,
                };
                let us: Vec<Vec2> = (0..1 + i % RATIO_MAX).map(|_| Vec2::new(next(), next())).collect();
                let (mut four, mut one) = (RatioSamples::default(), RatioSamples::default());
                four.fill(&us, &prepared, &sp, &lobe);
                for (j, &u) in us.iter().enumerate() {
                    if let Some(ls) = prepared.sample(sp.p, u) {
                        one.put1(j, &ls, &sp, &lobe);
                    }
                }
                assert_eq!(four.valid, one.valid);
                for j in (0..us.len()).filter(|&j| one.valid & (1 << j) != 0) {
                    compared += 1;
                    let bits = |r: &RatioSamples| {
                        let v = |v: Vec3| v.to_array().map(f32::to_bits);
                        (v(r.w[j]), r.phong[j].to_bits(), v(r.dirs[j]), r.dists[j].to_bits())
                    };
                    assert_eq!(bits(&four), bits(&one), "sample {j} from {p}");
                }
            }
        }
        assert!(compared > 1_000, "only {compared} samples compared");
    }

    #[test]
    fn four_shadow_rays_at_once_are_the_single_rays_bit_for_bit() {
        let mut uniform = Sampler::new(9, 8, 7, 6).stream();
        let mut next = || uniform() * 20.0 - 10.0;
        for _ in 0..1_000 {
            let origin = Vec3::new(next(), next(), next());
            let to: [Vec3; 4] = std::array::from_fn(|_| Vec3::new(next(), next(), next()));
            for (ray, q) in ShadowRay::towards4(origin, &to).iter().zip(to) {
                let d = q - origin;
                let one = ShadowRay::new(origin, d / d.length(), d.length());
                let bits = |r: &ShadowRay| {
                    let [x, y, z] = r.ray.dir.to_array().map(f32::to_bits);
                    (r.ray.origin, [x, y, z, r.t_max.to_bits()])
                };
                assert_eq!(bits(ray), bits(&one), "{origin} to {q}");
            }
        }
    }

    #[test]
    fn four_lane_phong_lobe_is_phong_lobe_in_every_lane() {
        let xs = [-0.5f32, 0.0, 0.3, 0.9, 0.999, 1.0, 1.5, f32::NAN];
        for s in [0.0f32, 1.0, 2.0, 7.0, 32.0, 40.0, 100.0, 12.5, 4097.0] {
            for x in xs.chunks(4) {
                let four = phong_lobe4(Vec4::from_slice(x), s).to_array();
                for (i, &x) in x.iter().enumerate() {
                    let one = phong_lobe(x, s);
                    assert!(
                        four[i].to_bits() == one.to_bits() || (four[i].is_nan() && one.is_nan()),
                        "{x}^{s}"
                    );
                }
            }
        }
    }

    #[test]
    fn uv_footprints_stretch_along_the_view_direction() {
        // A triangle in the z = 0 plane whose UVs are its x and y coordinates.
        let v = [Vec3::ZERO, Vec3::X, Vec3::Y];
        let uvs = [Vec2::ZERO, Vec2::X, Vec2::Y];
        let scene = Scene::new(SceneParts {
            triangles: vec![Triangle { v }],
            shading: vec![TriangleShading { normals: [Vec3::Z; 3], uvs, material: 0 }],
            ..Default::default()
        });
        // Seen at a grazing angle while looking along +y: stretched in v only.
        let dir = Vec3::new(0.0, 1.0, -0.25).normalize();
        let ray = Ray::new(Vec3::new(0.2, 0.2, 0.0) - dir * 3.0, dir);
        let hit = scene.intersect(&ray, 0.0, f32::INFINITY).unwrap();
        let sp = SurfacePoint::new(&scene, &ray, &hit);
        let cos = 0.25 / (1.0f32 + 0.0625).sqrt();
        assert!((sp.cos_view - cos).abs() < 1e-5);
        let fp = sp.uv_footprint(&v, &uvs, dir, 0.01);
        assert!((fp.x - 0.01).abs() < 1e-6, "{fp:?}");
        assert!((fp.y - 0.01 / cos).abs() < 1e-4, "{fp:?}");
        assert!((fp.y - sp.uv_width(&v, &uvs, 0.01)).abs() < 1e-4, "the major extent is the isotropic width");
        // Looking straight down: a circle.
        let ray = Ray::new(Vec3::new(0.2, 0.2, 1.0), Vec3::NEG_Z);
        let hit = scene.intersect(&ray, 0.0, f32::INFINITY).unwrap();
        let sp = SurfacePoint::new(&scene, &ray, &hit);
        let fp = sp.uv_footprint(&v, &uvs, ray.dir, 0.01);
        assert!((fp - Vec2::splat(0.01)).abs().max_element() < 1e-6, "{fp:?}");
        // UVs twice as dense in u: twice the u extent.
        let fp = sp.uv_footprint(&v, &[Vec2::ZERO, Vec2::new(2.0, 0.0), Vec2::Y], ray.dir, 0.01);
        assert!((fp - Vec2::new(0.02, 0.01)).abs().max_element() < 1e-6, "{fp:?}");
    }

    #[test]
    fn curved_mirrors_widen_the_reflected_cone() {
        // A small triangle on a sphere of radius 2.
        let n = [
            Vec3::new(0.0, 0.0, 1.0),
            Vec3::new(0.1, 0.0, 1.0).normalize(),
            Vec3::new(0.0, 0.1, 1.0).normalize(),
        ];
        let v = n.map(|d| d * 2.0);
        let k = triangle_curvature(&v, &n);
        assert!((k - 0.5).abs() < 0.01, "curvature {k}");
        assert_eq!(triangle_curvature(&v, &[Vec3::Z; 3]), 0.0, "flat shading");
        let c = RayCone::primary(0.01);
        let flat = c.reflected(10.0, 0.0);
        assert_eq!(flat, c.after(10.0));
        let curved = c.reflected(10.0, k);
        assert!((curved.spread - (0.01 + 2.0 * 0.5 * 0.1)).abs() < 1e-3);
    }

    #[test]
    fn ray_cones_grow_with_distance() {
        let c = RayCone::primary(0.01);
        assert_eq!(c.width_at(0.0), 0.0);
        assert!((c.width_at(10.0) - 0.1).abs() < 1e-7);
        let d = c.after(10.0);
        assert!((d.width_at(5.0) - 0.15).abs() < 1e-7, "keeps growing after a bounce");
    }

    #[test]
    fn area_light_samples_follow_the_path_weight() {
        let scene = one_triangle([Vec3::Z; 3]);
        let settings = RenderSettings { light_samples: 8, ..Default::default() };
        let integrator = Integrator::new(&scene, &settings);
        let n = |w: Vec3| integrator.light_samples_for(w);
        assert_eq!(n(Vec3::ONE), 8, "camera hits take them all");
        assert_eq!(n(Vec3::splat(0.9)), 8, "a mirror barely dims: ⌈7.2⌉");
        assert_eq!(n(Vec3::new(0.5, 0.1, 0.2)), 4, "the brightest channel counts");
        assert_eq!(n(Vec3::splat(0.1)), 1, "a 10 % reflection");
        assert_eq!(n(Vec3::ZERO), 1);
        assert_eq!(n(Vec3::splat(f32::NAN)), 1);
        assert_eq!(n(Vec3::splat(3.0)), 8, "never more than the setting");
    }
}

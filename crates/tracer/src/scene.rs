//! The built, renderable scene: triangles with their shading data, materials,
//! textures, lights and the BVH over everything.
//!
//! A [`Scene`] is made once per scene (by [`crate::load_scene`]) and then shared
//! read-only by every render thread.

use crate::bvh::Bvh;
use crate::cameras::Camera;
use crate::geometry::{Aabb, Ray};
use crate::integrator::uv_gradients;
use crate::lights::Light;
use crate::materials::Material;
use crate::math;
use crate::render::RenderSettings;
use crate::shadows::{CellAnswer, CellIndex, ShadowCells};
use crate::shapes::{Hit, Triangle};
use crate::textures::{MipMap, Texture};
use glam::{Vec2, Vec3};
use rayon::prelude::*;

/// An equirectangular environment image seen by rays that leave the scene.
///
/// Straight up (+Y) is the image's top row, straight down its bottom; the
/// image's centre column is seen looking along −Z (turned by `rotation`
/// about +Y), and `u` grows towards +X.
#[derive(Clone, Debug, PartialEq)]
pub struct Environment {
    /// The image (linear RGB).
    pub map: MipMap,
    /// Multiplier of the image's radiance.
    pub strength: f32,
    /// Turn about +Y, radians (counter-clockwise seen from above).
    pub rotation: f32,
}

impl Environment {
    /// The radiance arriving from unit direction `dir` (bilinear, unfiltered).
    pub fn radiance(&self, dir: Vec3) -> Vec3 {
        let phi = math::atan2(dir.x, -dir.z) - self.rotation;
        let u = 0.5 + phi * (0.5 / std::f32::consts::PI);
        let v = math::acos(dir.y.clamp(-1.0, 1.0)) * (1.0 / std::f32::consts::PI);
        // Around the horizon the image wraps; at the poles it stops.
        self.map.eval_clamped(Vec2::new(u, v), 0.0, [false, true]) * self.strength
    }
}

/// Per-triangle data needed only once a hit has been found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleShading {
    /// Vertex normals (unit length). Flat-shaded triangles carry their face
    /// normal three times.
    pub normals: [Vec3; 3],
    /// Vertex texture coordinates (zero where the mesh has none).
    pub uvs: [Vec2; 3],
    /// Index into [`Scene::materials`].
    pub material: u32,
}

/// Everything [`Scene::new`] needs; the loader fills it.
#[derive(Clone, Debug, Default)]
pub struct SceneParts {
    /// All triangles, in world space.
    pub triangles: Vec<Triangle>,
    /// Shading data, one per triangle.
    pub shading: Vec<TriangleShading>,
    /// Materials referenced by [`TriangleShading::material`].
    pub materials: Vec<Material>,
    /// Textures referenced by materials.
    pub textures: Vec<Texture>,
    /// Light sources.
    pub lights: Vec<Light>,
    /// Ambient light added to every diffuse surface (linear RGB).
    pub ambient: Vec3,
    /// Colour of rays that leave the scene (linear RGB); with a sky
    /// (`zenith`), its colour at and below the horizon.
    pub background: Vec3,
    /// A sky's colour straight up (+Y): rays that leave the scene see
    /// `background` blended towards it by the height of their direction.
    pub zenith: Option<Vec3>,
    /// An environment image, seen by rays that leave the scene (instead of
    /// `background` and `zenith`).
    pub environment: Option<Environment>,
    /// The camera the scene file defines.
    pub camera: Camera,
    /// The render settings the scene file defines.
    pub settings: RenderSettings,
    /// What the loader found worth telling the user (each was also logged
    /// with `tracing::warn!`): no light at all, huge textures, huge meshes.
    pub warnings: Vec<String>,
    /// Second texture coordinates (glTF `TEXCOORD_1`) per triangle: empty
    /// when no mesh has them, else parallel to `triangles` (zero where a mesh
    /// has none).
    pub uvs1: Vec<[Vec2; 3]>,
    /// Vertex colours (linear RGB, glTF `COLOR_0`) per triangle, multiplying
    /// the base colour of [`Material::Pbr`] surfaces: empty when no mesh has
    /// any, else parallel to `triangles` (white where a mesh has none).
    pub colours: Vec<[Vec3; 3]>,
}

/// A renderable scene.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Triangles, in world space.
    pub triangles: Vec<Triangle>,
    /// Shading data, parallel to `triangles`.
    pub shading: Vec<TriangleShading>,
    /// Materials.
    pub materials: Vec<Material>,
    /// Textures.
    pub textures: Vec<Texture>,
    /// Lights.
    pub lights: Vec<Light>,
    /// Ambient term (linear RGB).
    pub ambient: Vec3,
    /// Background colour (linear RGB); a sky's horizon.
    pub background: Vec3,
    /// A sky's zenith colour, see [`SceneParts::zenith`].
    pub zenith: Option<Vec3>,
    /// An environment image, see [`SceneParts::environment`].
    pub environment: Option<Environment>,
    /// The scene file's camera.
    pub camera: Camera,
    /// The scene file's render settings.
    pub settings: RenderSettings,
    /// Vertex colours, see [`SceneParts::colours`].
    pub colours: Vec<[Vec3; 3]>,
    /// Second texture coordinates, see [`SceneParts::uvs1`].
    pub uvs1: Vec<[Vec2; 3]>,
    /// True when some material is alpha-masked ([`crate::materials::Pbr::alpha_cutoff`]):
    /// ray queries then look through its cut-out parts.
    pub(crate) cutouts: bool,
    /// Bounds of all triangles.
    pub bounds: Aabb,
    /// Acceleration structure over `triangles`.
    pub bvh: Bvh,
    /// What can block shadow rays to each light, per cell of space, filled
    /// on demand (made from `triangles` and `lights` by [`Scene::new`]).
    shadow_cells: ShadowCells,
    /// Per triangle: its unit geometric normal, `None` where degenerate
    /// ([`unit_normal`]); the shading of every hit needs it.
    pub(crate) unit_normals: Vec<Option<Vec3>>,
    /// The world-space gradients of the `u` and `v` texture coordinates
    /// ([`crate::integrator::uv_gradients`]) of the triangles with a textured
    /// material, for the filter footprints of their texture lookups; see
    /// [`Scene::uv_gradients`].
    uv_gradients: Vec<Option<[Vec3; 2]>>,
    /// Per triangle, its entry in `uv_gradients` (`u32::MAX` for the others);
    /// empty when no material has a texture, so that a large untextured mesh
    /// beside a textured floor costs 4 bytes a triangle, not 28.
    uv_gradient_slots: Vec<u32>,
}

/// Most cut-out surfaces a ray looks through before it counts as lost.
const MAX_CUTOUT_LAYERS: usize = 64;

/// The unit geometric normal `(v1 − v0) × (v2 − v0) / |…|` of `tri`, `None`
/// when that length is not positive.
fn unit_normal(tri: &Triangle) -> Option<Vec3> {
    let n = tri.normal();
    let len = n.length();
    (len > 0.0).then(|| n / len)
}

impl Scene {
    /// Builds the BVH and assembles the scene. `parts.shading` must be parallel
    /// to `parts.triangles`.
    pub fn new(parts: SceneParts) -> Self {
        assert_eq!(parts.triangles.len(), parts.shading.len(), "one shading record per triangle");
        assert!(
            parts.colours.is_empty() || parts.colours.len() == parts.triangles.len(),
            "vertex colours for every triangle or none"
        );
        assert!(
            parts.uvs1.is_empty() || parts.uvs1.len() == parts.triangles.len(),
            "TEXCOORD_1 for all or none"
        );
        let cutouts =
            parts.materials.iter().any(|m| matches!(m, Material::Pbr(p) if p.alpha_cutoff.is_some()));
        let bvh = Bvh::build(&parts.triangles);
        let bounds = parts.triangles.iter().fold(Aabb::EMPTY, |b, t| b.union(&t.bounds()));
        let shadow_cells = ShadowCells::new(&bounds, &parts.lights);
        let unit_normals = parts.triangles.par_iter().map(unit_normal).collect();
        let textured = |sh: &TriangleShading| {
            parts.materials.get(sh.material as usize).is_some_and(Material::has_texture)
        };
        let mut textured_ids = Vec::new();
        let uv_gradient_slots = if parts.materials.iter().any(Material::has_texture) {
            let slot = |(i, sh): (usize, &TriangleShading)| {
                if !textured(sh) {
                    return u32::MAX;
                }
                textured_ids.push(i);
                (textured_ids.len() - 1) as u32
            };
            parts.shading.iter().enumerate().map(slot).collect()
        } else {
            Vec::new()
        };
        let uv_gradients = textured_ids
            .par_iter()
            .map(|&i| uv_gradients(&parts.triangles[i].v, &parts.shading[i].uvs))
            .collect();
        Scene {
            unit_normals,
            uv_gradients,
            uv_gradient_slots,
            triangles: parts.triangles,
            shading: parts.shading,
            materials: parts.materials,
            textures: parts.textures,
            lights: parts.lights,
            ambient: parts.ambient,
            background: parts.background,
            zenith: parts.zenith,
            environment: parts.environment,
            camera: parts.camera,
            settings: parts.settings,
            colours: parts.colours,
            uvs1: parts.uvs1,
            cutouts,
            bounds,
            bvh,
            shadow_cells,
        }
    }

    /// What a ray leaving the scene along unit `dir` sees.
    #[inline]
    pub fn background(&self, dir: Vec3) -> Vec3 {
        if let Some(env) = &self.environment {
            return env.radiance(dir);
        }
        match self.zenith {
            None => self.background,
            Some(zenith) => {
                let t = if dir.y > 0.0 { dir.y.min(1.0) } else { 0.0 };
                self.background + (zenith - self.background) * t
            }
        }
    }

    /// The vertex colour of triangle `prim` at barycentric `(u, v)`; white
    /// when the scene has none.
    #[inline]
    pub fn vertex_colour(&self, prim: u32, u: f32, v: f32) -> Vec3 {
        match self.colours.get(prim as usize) {
            Some(c) => c[0] * (1.0 - u - v) + c[1] * u + c[2] * v,
            None => Vec3::ONE,
        }
    }

    /// Texture coordinates of set `set` (0, or 1 for `TEXCOORD_1`) of
    /// triangle `prim` at barycentric `(u, v)`, given set 0's `uv0` there.
    #[inline]
    pub fn uv_of_set(&self, set: u8, prim: u32, u: f32, v: f32, uv0: Vec2) -> Vec2 {
        match (set, self.uvs1.get(prim as usize)) {
            (1, Some(t)) => t[0] * (1.0 - u - v) + t[1] * u + t[2] * v,
            (1, None) => Vec2::ZERO,
            _ => uv0,
        }
    }

    /// The gradients of triangle `prim`'s texture coordinates, if its
    /// material has a texture and the triangle is not degenerate.
    #[inline]
    pub(crate) fn uv_gradients(&self, prim: u32) -> Option<[Vec3; 2]> {
        let slot = *self.uv_gradient_slots.get(prim as usize)?;
        self.uv_gradients.get(slot as usize).copied().flatten()
    }

    /// Asks the CPU to start loading what the shading of a hit on triangle
    /// `prim` reads first (its shading record and unit normal). A hint that
    /// changes no result: in a large mesh those are cache misses, and a
    /// packet's lanes then wait for theirs together instead of one by one.
    #[inline(always)]
    pub(crate) fn prefetch_shading(&self, prim: u32) {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
            let i = prim as usize;
            if let (Some(sh), Some(n)) = (self.shading.get(i), self.unit_normals.get(i)) {
                let sh: *const i8 = std::ptr::from_ref(sh).cast();
                let last = sh.wrapping_add(std::mem::size_of::<TriangleShading>() - 1);
                // SAFETY: SSE is part of the x86_64 baseline; a prefetch never
                // faults, and the addresses lie inside the records.
                unsafe {
                    _mm_prefetch::<_MM_HINT_T0>(sh);
                    _mm_prefetch::<_MM_HINT_T0>(last);
                    _mm_prefetch::<_MM_HINT_T0>(std::ptr::from_ref(n).cast());
                }
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = prim;
    }

    /// Nearest hit with `t_min < t < t_max`.
    #[inline]
    pub fn intersect(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<Hit> {
        self.bvh.intersect(ray, t_min, t_max)
    }

    /// True when `hit` lies on a cut-out part of an alpha-masked surface:
    /// its alpha (factor × the base texture's alpha, looked up unfiltered)
    /// is below the material's cutoff.
    pub fn is_cut_out(&self, hit: &Hit) -> bool {
        let Some(sh) = self.shading.get(hit.prim as usize) else { return false };
        let Some(Material::Pbr(p)) = self.materials.get(sh.material as usize) else { return false };
        let Some(cutoff) = p.alpha_cutoff else { return false };
        let mut alpha = p.alpha;
        if let Some(m) = &p.alpha_texture
            && let Some(t) = self.textures.get(m.texture as usize)
        {
            let w = 1.0 - hit.u - hit.v;
            let uv = sh.uvs[0] * w + sh.uvs[1] * hit.u + sh.uvs[2] * hit.v;
            let uv = self.uv_of_set(m.set, hit.prim, hit.u, hit.v, uv);
            let (uv, _) = m.apply(uv, Vec2::ZERO);
            alpha *= t.eval_rect_clamped(uv, Vec2::ZERO, m.clamped()).x;
        }
        alpha < cutoff
    }

    /// [`Scene::intersect`], looking through cut-out surfaces
    /// ([`Scene::is_cut_out`]): the nearest hit that is not cut out.
    #[inline]
    pub fn intersect_visible(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<Hit> {
        let hit = self.intersect(ray, t_min, t_max);
        if self.cutouts { self.beyond_cutouts(ray, hit, t_max) } else { hit }
    }

    /// `hit`, the nearest hit of `ray` before `t_max`, or when it is cut out
    /// the nearest one beyond it that is not.
    #[inline]
    pub fn beyond_cutouts(&self, ray: &Ray, mut hit: Option<Hit>, t_max: f32) -> Option<Hit> {
        if !self.cutouts {
            return hit;
        }
        for _ in 0..MAX_CUTOUT_LAYERS {
            match hit {
                Some(h) if self.is_cut_out(&h) => {
                    // Just past this hit: the same triangle is not found again.
                    let t = f32::from_bits(h.t.max(0.0).to_bits() + 1);
                    hit = self.intersect(ray, t, t_max);
                }
                _ => return hit,
            }
        }
        None
    }

    /// Whether something that is not cut out blocks the ray between `t_min`
    /// and `t_max`.
    pub fn occluded_visible(&self, ray: &Ray, t_min: f32, t_max: f32) -> bool {
        if self.cutouts {
            self.intersect_visible(ray, t_min, t_max).is_some()
        } else {
            self.occluded(ray, t_min, t_max)
        }
    }

    /// True when something blocks the ray between `t_min` and `t_max`.
    #[inline]
    pub fn occluded(&self, ray: &Ray, t_min: f32, t_max: f32) -> bool {
        self.bvh.occluded(ray, t_min, t_max)
    }

    /// True when no shadow ray from `origin` to light `light` (an index into
    /// `lights`) can hit anything, provided it stops short of the light (as
    /// the integrator's shadow rays do); false when that is not known. See
    /// [`crate::shadows`].
    #[inline(always)]
    pub fn shadow_clear(&self, light: usize, origin: Vec3) -> bool {
        self.shadow_cells.clear(&self.bvh, light, origin)
    }

    /// What the shadow cells know about shadow rays from `origin` to light
    /// `light` that stop short of it: nothing can block them, only the
    /// triangles below a few subtrees can, or not known.
    /// [`CellAnswer::occluded`] answers each such ray (pass it
    /// [`Scene::bvh`]). See [`crate::shadows`].
    #[inline(always)]
    pub fn shadow_cell(&self, light: usize, origin: Vec3) -> CellAnswer<'_> {
        self.shadow_cells.lookup(&self.bvh, light, origin)
    }

    /// The shadow cell around `origin`, the same for every light: for
    /// [`Scene::shadow_cell_in`] when one point asks about several lights.
    #[inline(always)]
    pub fn shadow_cell_index(&self, origin: Vec3) -> CellIndex {
        self.shadow_cells.cell(origin)
    }

    /// [`Scene::shadow_cell`] where `cell` is [`Scene::shadow_cell_index`]`(origin)`.
    #[inline(always)]
    pub fn shadow_cell_in(&self, light: usize, cell: CellIndex, origin: Vec3) -> CellAnswer<'_> {
        self.shadow_cells.lookup_in(&self.bvh, light, cell, origin)
    }

    /// Fills the shadow cells around every surface now, in parallel, rather
    /// than as frames first need them (see [`ShadowCells::fill_surface_cells`]):
    /// for renderers that keep a scene for many frames, such as a cluster's slaves.
    pub fn fill_shadow_cells(&self) {
        self.shadow_cells.fill_surface_cells(&self.bvh, &self.triangles);
    }

    /// Shadow cells filled so far, over all lights.
    pub fn shadow_cells_filled(&self) -> usize {
        self.shadow_cells.filled()
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }
}

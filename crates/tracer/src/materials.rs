//! Surface materials of a Whitted ray tracer.

use glam::{Vec2, Vec3};

/// Where a surface's diffuse colour comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum Albedo {
    /// One colour everywhere (linear RGB).
    Constant(Vec3),
    /// A texture from [`crate::Scene::textures`], looked up at the hit's
    /// interpolated UV and multiplied by `tint`.
    Texture {
        /// Index into the scene's textures.
        texture: u32,
        /// Linear RGB multiplier.
        tint: Vec3,
    },
}

/// A surface material.
#[derive(Clone, Debug, PartialEq)]
pub enum Material {
    /// Lambert diffuse plus a Phong specular highlight, optionally with a
    /// mirror reflection blended in (`reflectivity` in 0..=1).
    Phong {
        /// Diffuse colour.
        albedo: Albedo,
        /// Specular highlight colour (linear RGB); zero for none.
        specular: Vec3,
        /// Phong exponent.
        shininess: f32,
        /// Weight of the mirror reflection, 0 for a matte surface.
        reflectivity: f32,
    },
    /// A perfect mirror: `R = I − 2 (I·N) N`, traced recursively.
    Mirror {
        /// Colour of the reflection (linear RGB).
        tint: Vec3,
    },
    /// Glass-like: refraction by Snell's law, reflection weighted by Fresnel
    /// (Schlick), total internal reflection.
    Dielectric {
        /// Index of refraction.
        ior: f32,
        /// Transmission colour (linear RGB).
        tint: Vec3,
    },
    /// A light-emitting surface (the visible face of an area light).
    Emissive {
        /// Emitted radiance (linear RGB).
        radiance: Vec3,
    },
    /// A glTF metallic-roughness material, turned into Phong terms at every
    /// hit from its textures ([`Pbr::shade`]).
    Pbr(Pbr),
}

/// How texture coordinates outside `0..1` are brought back (glTF sampler
/// wrap modes).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Wrap {
    /// The texture tiles.
    #[default]
    Repeat,
    /// Coordinates are clamped to the edge.
    Clamp,
    /// The texture tiles, every other tile mirrored.
    Mirror,
}

impl Wrap {
    #[inline]
    fn apply(self, x: f32) -> f32 {
        match self {
            Wrap::Repeat => x,
            Wrap::Clamp => x,
            Wrap::Mirror => {
                let t = x - 2.0 * crate::textures::floor_f32(x * 0.5);
                if t > 1.0 { 2.0 - t } else { t }
            }
        }
    }
}

/// A texture as a [`Pbr`] material uses it: the texture, the affine map its
/// texture coordinates go through first (`KHR_texture_transform`) and how
/// they wrap.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TextureMap {
    /// Index into the scene's textures.
    pub texture: u32,
    /// `uv' = transform[0] · u + transform[1] · v + transform[2]`.
    pub transform: [Vec2; 3],
    /// Wrap modes along `u` and `v`.
    pub wrap: [Wrap; 2],
    /// The texture coordinate set it reads: 0 (`TEXCOORD_0`) or 1.
    pub set: u8,
}

impl TextureMap {
    /// The identity map onto `texture`, repeating.
    pub fn plain(texture: u32) -> Self {
        TextureMap { texture, transform: [Vec2::X, Vec2::Y, Vec2::ZERO], wrap: [Wrap::Repeat; 2], set: 0 }
    }

    /// The axes that do not wrap around (clamped, or mirrored into `0..=1`).
    #[inline]
    pub fn clamped(&self) -> [bool; 2] {
        self.wrap.map(|w| w != Wrap::Repeat)
    }

    /// Texture coordinates `uv` and their filter footprint (the `(u, v)`
    /// extents of a box) as this map turns them: the footprint becomes the
    /// bounding box of the transformed box. Mirrored axes are folded into
    /// `0..=1`; look the result up with [`crate::textures::Texture::eval_rect_clamped`]
    /// and [`TextureMap::clamped`], so clamped axes stop at the edge texels.
    #[inline]
    pub fn apply(&self, uv: Vec2, footprint: Vec2) -> (Vec2, Vec2) {
        let [a, b, c] = self.transform;
        let uv = a * uv.x + b * uv.y + c;
        let fp = a.abs() * footprint.x + b.abs() * footprint.y;
        (Vec2::new(self.wrap[0].apply(uv.x), self.wrap[1].apply(uv.y)), fp)
    }
}

/// A glTF 2.0 metallic-roughness material (see the glTF loader's docs for
/// how it maps onto Whitted shading).
#[derive(Clone, Debug, PartialEq)]
pub struct Pbr {
    /// `baseColorFactor` (linear RGB).
    pub base_color: Vec3,
    /// `baseColorTexture` (sRGB), multiplied by `base_color`.
    pub base_texture: Option<TextureMap>,
    /// `metallicFactor`, 0..=1.
    pub metallic: f32,
    /// `roughnessFactor`, 0..=1.
    pub roughness: f32,
    /// `metallicRoughnessTexture` (linear): blue scales metallic, green roughness.
    pub metallic_roughness: Option<TextureMap>,
    /// `emissiveFactor` × `KHR_materials_emissive_strength` (linear RGB).
    pub emissive: Vec3,
    /// `emissiveTexture` (sRGB), multiplied by `emissive`.
    pub emissive_texture: Option<TextureMap>,
    /// `normalTexture` (linear, tangent space), with its `scale`.
    pub normal_texture: Option<TextureMap>,
    /// `normalTexture.scale`: multiplies the map's red and green.
    pub normal_scale: f32,
    /// `alphaMode` `MASK`: the `alphaCutoff` below which the surface is cut
    /// out — camera, reflected and shadow rays pass through it. `None` for
    /// opaque surfaces.
    pub alpha_cutoff: Option<f32>,
    /// The base colour's alpha (`baseColorFactor[3]`).
    pub alpha: f32,
    /// The base-colour texture's alpha channel (linear, in red), for `MASK`.
    pub alpha_texture: Option<TextureMap>,
}

impl Default for Pbr {
    /// The glTF defaults: white, fully metallic, fully rough, no emission.
    fn default() -> Self {
        Pbr {
            base_color: Vec3::ONE,
            base_texture: None,
            metallic: 1.0,
            roughness: 1.0,
            metallic_roughness: None,
            emissive: Vec3::ZERO,
            emissive_texture: None,
            normal_texture: None,
            normal_scale: 1.0,
            alpha_cutoff: None,
            alpha: 1.0,
            alpha_texture: None,
        }
    }
}

/// Reflectance at normal incidence of glTF dielectrics (index 1.5).
pub const DIELECTRIC_F0: f32 = 0.04;

/// Highest Phong exponent a [`Pbr`] material's highlight gets.
pub const MAX_PBR_SHININESS: f32 = 4096.0;

/// What a [`Pbr`] material is at one point, in Phong terms.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PbrShading {
    /// Base colour: factor × texture × vertex colour (for metals, their
    /// reflectance at normal incidence); the albedo pass of a glTF surface.
    pub base_colour: Vec3,
    /// Diffuse albedo (also lit by the ambient term).
    pub albedo: Vec3,
    /// Colour of the Phong highlight.
    pub specular: Vec3,
    /// Phong exponent of the highlight.
    pub shininess: f32,
    /// Specular reflectance at normal incidence (`F0`).
    pub f0: Vec3,
    /// Share of the specular reflectance seen as a mirror reflection, `(1 − roughness)²`.
    pub gloss: f32,
    /// Emitted radiance.
    pub emission: Vec3,
}

impl PbrShading {
    /// Weight of the mirror reflection where the view makes cosine `cos`
    /// with the normal: Schlick's Fresnel term from `f0`, times `gloss`.
    #[inline]
    pub fn reflection(&self, cos: f32) -> Vec3 {
        if self.gloss <= 0.0 {
            return Vec3::ZERO;
        }
        let m = (1.0 - cos).clamp(0.0, 1.0);
        let m2 = m * m;
        (self.f0 + (Vec3::ONE - self.f0) * (m2 * m2 * m)) * self.gloss
    }
}

impl Pbr {
    /// The material at a point where the base-colour texture reads `base`,
    /// the metallic-roughness texture `mr`, the emissive texture `emission`
    /// (white where a texture is absent) and the vertex colour is `colour`:
    ///
    /// - base colour `c = base_color × base × colour`, metallic `m` and
    ///   roughness `r` the factors times `mr`'s blue and green;
    /// - `F0 = lerp(0.04, c, m)`, and a very rough specular acts as a diffuse
    ///   reflector: a share `r²` of a metal's `F0` is diffuse;
    /// - diffuse albedo `c (1 − m)(1 − 0.04) + F0 m r²`, highlight
    ///   `F0 (1 − m r²)` with exponent `2/r⁴ − 2` (Blinn–Phong's match of a
    ///   microfacet width `r²`), clamped to 1..=4096;
    /// - a mirror reflection `Fresnel(F0, θ) (1 − r)²` ([`PbrShading::reflection`]).
    pub fn shade(&self, base: Vec3, mr: Vec3, emission: Vec3, colour: Vec3) -> PbrShading {
        let c = (self.base_color * base * colour).max(Vec3::ZERO);
        let m = (self.metallic * mr.z).clamp(0.0, 1.0);
        let r = (self.roughness * mr.y).clamp(0.0, 1.0);
        let f0 = Vec3::splat(DIELECTRIC_F0).lerp(c, m);
        let r2 = r * r;
        let albedo = c * ((1.0 - m) * (1.0 - DIELECTRIC_F0)) + f0 * (m * r2);
        let shininess = if r2 * r2 > 2.0 / (MAX_PBR_SHININESS + 2.0) {
            crate::textures::floor_f32(2.0 / (r2 * r2) - 2.0).max(1.0)
        } else {
            MAX_PBR_SHININESS
        };
        PbrShading {
            base_colour: c,
            albedo,
            specular: f0 * (1.0 - m * r2),
            shininess,
            f0,
            gloss: (1.0 - r) * (1.0 - r),
            emission: (self.emissive * emission).max(Vec3::ZERO),
        }
    }

    /// The material's textures.
    pub fn textures(&self) -> impl Iterator<Item = &TextureMap> {
        [&self.base_texture, &self.metallic_roughness, &self.emissive_texture, &self.normal_texture]
            .into_iter()
            .flatten()
    }
}

impl Default for Material {
    fn default() -> Self {
        Material::Phong {
            albedo: Albedo::Constant(Vec3::splat(0.7)),
            specular: Vec3::ZERO,
            shininess: 1.0,
            reflectivity: 0.0,
        }
    }
}

impl Material {
    /// True when the material's colour comes from a texture.
    pub fn has_texture(&self) -> bool {
        match self {
            Material::Phong { albedo: Albedo::Texture { .. }, .. } => true,
            Material::Pbr(p) => p.textures().next().is_some(),
            _ => false,
        }
    }

    /// True when the material emits light (an emissive surface, or a glTF
    /// material with an emissive factor).
    pub fn emits(&self) -> bool {
        match self {
            Material::Emissive { radiance } => radiance.max_element() > 0.0,
            Material::Pbr(p) => p.emissive.max_element() > 0.0,
            _ => false,
        }
    }
}

/// Mirror reflection of direction `i` about unit normal `n`: `R = I − 2 (I·N) N`.
#[inline]
pub fn reflect(i: Vec3, n: Vec3) -> Vec3 {
    i - n * (2.0 * i.dot(n))
}

/// Refraction of unit direction `i` through a surface with unit normal `n`
/// facing the incoming ray (`i·n < 0`), with `eta = n1 / n2` (incoming over
/// transmitting index). Returns the unit transmitted direction obeying Snell's
/// law `n1 sin θ1 = n2 sin θ2`, or `None` on total internal reflection.
#[inline]
pub fn refract(i: Vec3, n: Vec3, eta: f32) -> Option<Vec3> {
    let cos_i = -i.dot(n);
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i).max(0.0);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    Some(i * eta + n * (eta * cos_i - cos_t))
}

/// Schlick's approximation of the Fresnel reflectance between media of indices
/// `n1` and `n2`; `cos` is the cosine of the angle on the optically thinner
/// side (the incident angle when entering a denser medium, the transmitted
/// angle when leaving it).
#[inline]
pub fn schlick(cos: f32, n1: f32, n2: f32) -> f32 {
    let r0 = (n1 - n2) / (n1 + n2);
    let r0 = r0 * r0;
    let m = (1.0 - cos).clamp(0.0, 1.0);
    let m2 = m * m;
    r0 + (1.0 - r0) * (m2 * m2 * m)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sin_from(d: Vec3, n: Vec3) -> f32 {
        d.cross(n).length()
    }

    #[test]
    fn reflection_mirrors_about_the_normal() {
        let i = Vec3::new(1.0, -1.0, 0.0).normalize();
        let r = reflect(i, Vec3::Y);
        assert!((r - Vec3::new(1.0, 1.0, 0.0).normalize()).length() < 1e-6);
    }

    #[test]
    fn refraction_obeys_snell() {
        let n = Vec3::Y;
        for deg in [0.0f32, 10.0, 30.0, 60.0, 85.0] {
            let a = deg.to_radians();
            let i = Vec3::new(a.sin(), -a.cos(), 0.0);
            let t = refract(i, n, 1.0 / 1.5).expect("entering glass never reflects totally");
            assert!((t.length() - 1.0).abs() < 1e-5);
            assert!(t.y < 0.0, "goes into the surface");
            let (s1, s2) = (sin_from(i, n), sin_from(t, n));
            assert!((1.0 * s1 - 1.5 * s2).abs() < 1e-5, "{deg}°: {s1} vs {s2}");
            // Stays in the plane of incidence, on the far side of the normal.
            assert!(t.z.abs() < 1e-6 && t.x >= 0.0);
        }
    }

    #[test]
    fn total_internal_reflection_past_the_critical_angle() {
        let ior = 1.5f32;
        let critical = (1.0 / ior).asin();
        let n = Vec3::Y; // facing the ray, which travels inside the glass
        for (a, tir) in [(critical - 0.01, false), (critical + 0.01, true), (1.4, true), (0.2, false)] {
            let i = Vec3::new(a.sin(), -a.cos(), 0.0);
            assert_eq!(refract(i, n, ior).is_none(), tir, "angle {a} (critical {critical})");
        }
        // Just below the critical angle the transmitted ray grazes the surface.
        let a = critical - 1e-3;
        let t = refract(Vec3::new(a.sin(), -a.cos(), 0.0), n, ior).unwrap();
        assert!(t.y.abs() < 0.1);
    }

    #[test]
    fn gltf_defaults_are_a_rough_metal_that_is_not_black() {
        let s = Pbr { base_color: Vec3::new(0.8, 0.1, 0.1), ..Pbr::default() }.shade(
            Vec3::ONE,
            Vec3::ONE,
            Vec3::ONE,
            Vec3::ONE,
        );
        assert!(s.albedo.x > 0.5 && s.albedo.x > 4.0 * s.albedo.y, "a red diffuse-like metal: {s:?}");
        assert_eq!(s.reflection(1.0), Vec3::ZERO, "no mirror when fully rough");
    }

    #[test]
    fn smooth_metals_are_mirrors_tinted_by_their_base_colour() {
        let gold = Vec3::new(1.0, 0.76, 0.33);
        let p = Pbr { base_color: gold, metallic: 1.0, roughness: 0.0, ..Pbr::default() };
        let s = p.shade(Vec3::ONE, Vec3::ONE, Vec3::ONE, Vec3::ONE);
        assert_eq!(s.albedo, Vec3::ZERO);
        assert!((s.reflection(1.0) - gold).length() < 1e-6);
        assert!(s.reflection(0.0).min_element() > 0.999, "Fresnel: white at grazing");
        assert_eq!(s.shininess, MAX_PBR_SHININESS);
    }

    #[test]
    fn dielectrics_are_diffuse_with_a_fresnel_weighted_reflection() {
        let p = Pbr { base_color: Vec3::splat(0.5), metallic: 0.0, roughness: 0.2, ..Pbr::default() };
        let s = p.shade(Vec3::ONE, Vec3::ONE, Vec3::ONE, Vec3::ONE);
        assert!((s.albedo - Vec3::splat(0.48)).length() < 1e-6);
        assert!((s.specular - Vec3::splat(DIELECTRIC_F0)).length() < 1e-6);
        let (head_on, grazing) = (s.reflection(1.0), s.reflection(0.05));
        assert!((head_on.x - 0.04 * 0.64).abs() < 1e-6, "{head_on}");
        assert!(grazing.x > 10.0 * head_on.x);
        // The metallic-roughness texture scales the factors: blue metal, green rough.
        let metal = Pbr { metallic: 1.0, roughness: 1.0, ..p }.shade(
            Vec3::ONE,
            Vec3::new(0.0, 0.2, 0.0),
            Vec3::ONE,
            Vec3::ONE,
        );
        assert_eq!(metal, s, "blue 0 makes it a dielectric, green 0.2 its roughness");
    }

    #[test]
    fn texture_maps_transform_and_wrap() {
        let mut t = TextureMap::plain(0);
        t.transform = [Vec2::new(2.0, 0.0), Vec2::new(0.0, 0.5), Vec2::new(0.25, 0.0)];
        let (uv, fp) = t.apply(Vec2::new(0.1, 0.4), Vec2::new(0.01, 0.02));
        assert!((uv - Vec2::new(0.45, 0.2)).length() < 1e-6);
        assert!((fp - Vec2::new(0.02, 0.01)).length() < 1e-6);
        t.wrap = [Wrap::Clamp, Wrap::Mirror];
        let (uv, _) = t.apply(Vec2::new(1.0, 3.0), Vec2::ZERO);
        assert_eq!(t.clamped(), [true, true]);
        assert_eq!(uv.x, 2.25, "clamped in the lookup, not here");
        assert!((uv.y - 0.5).abs() < 1e-6, "1.5 mirrored: {uv}");
    }

    #[test]
    fn schlick_at_normal_and_grazing_incidence() {
        for n in [1.33f32, 1.5, 2.4] {
            let r0 = ((n - 1.0) / (n + 1.0)).powi(2);
            assert!((schlick(1.0, 1.0, n) - r0).abs() < 1e-7);
            assert!((schlick(1.0, n, 1.0) - r0).abs() < 1e-7, "symmetric");
            assert!((schlick(0.0, 1.0, n) - 1.0).abs() < 1e-6, "grazing reflects everything");
            assert!(schlick(0.5, 1.0, n) > r0 && schlick(0.5, 1.0, n) < 1.0);
        }
    }
}

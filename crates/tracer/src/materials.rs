//! Surface materials of a Whitted ray tracer.

use glam::Vec3;

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
        matches!(self, Material::Phong { albedo: Albedo::Texture { .. }, .. })
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

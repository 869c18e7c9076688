//! Surface materials of a Whitted ray tracer.
//!
//! OWNER: shading helper (evaluation); the types are shared with the scene loader.

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

//! Textures: procedural checker and mip-mapped image textures with bilinear
//! filtering, so distant textured floors do not alias.
//!
//! OWNER: shading helper. The constructors are what the scene loader calls.

use glam::{Vec2, Vec3};

/// A texture, evaluated at a UV coordinate with a filter footprint.
#[derive(Clone, Debug, PartialEq)]
pub enum Texture {
    /// Alternating squares of `even` and `odd`; `scale` squares per UV unit.
    Checker {
        /// Colour of squares where `floor(u*s) + floor(v*s)` is even (linear RGB).
        even: Vec3,
        /// Colour of the other squares (linear RGB).
        odd: Vec3,
        /// Squares per UV unit.
        scale: f32,
    },
    /// An image with its mip-map pyramid.
    Image(MipMap),
}

/// An image and its successively halved, box-filtered levels, in linear RGB.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct MipMap {
    levels: Vec<Level>,
}

#[derive(Clone, Debug, PartialEq, Default)]
struct Level {
    width: u32,
    height: u32,
    texels: Vec<Vec3>,
}

impl MipMap {
    /// Builds the pyramid from an sRGB-encoded RGBA8 image (alpha ignored),
    /// `rgba.len() == width * height * 4`.
    pub fn from_srgb8(width: u32, height: u32, rgba: &[u8]) -> Self {
        let _ = (width, height, rgba);
        todo!("shading helper")
    }
}

impl Texture {
    /// The texture's colour at `uv`, filtered over a square footprint `width`
    /// UV units wide (0 for a point sample).
    pub fn eval(&self, uv: Vec2, width: f32) -> Vec3 {
        let _ = (uv, width);
        todo!("shading helper")
    }
}

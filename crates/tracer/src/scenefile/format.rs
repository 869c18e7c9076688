//! The scene file format: TOML, read with serde into these types.
//!
//! A scene file has these parts (all optional except that the scene must end up
//! with at least one triangle); `scenes/paper.toml` starts with a commented
//! example of every section.
//!
//! ```toml
//! ambient = [0.05, 0.05, 0.05]     # linear RGB added to every diffuse surface
//! background = [0.0, 0.0, 0.0]     # colour of rays that leave the scene, or a sky:
//! # background = { zenith = [0.2, 0.35, 0.7], horizon = [0.7, 0.75, 0.8] }
//! # background = { image = "sky.hdr", strength = 1, rotate = 0 }   # equirectangular
//!
//! [settings]                       # crate::RenderSettings; every key optional
//! width = 640
//! height = 480
//!
//! [camera]                         # the paper's form: eye + image-plane corners
//! eye = [0, 0, 12.5]
//! p0 = [-4, 3, 0]                  # top-left, then clockwise seen by the viewer
//! p1 = [4, 3, 0]
//! p2 = [4, -3, 0]
//! p3 = [-4, -3, 0]
//! # … or the look-at form: eye, target, up = [0,1,0], fov (horizontal degrees),
//! # aspect (default settings.width / settings.height)
//!
//! [textures.tiles]
//! kind = "checker"                 # or kind = "image", path = "textures/wood.png"
//! even = [0.9, 0.9, 0.9]
//! odd = [0.1, 0.1, 0.1]
//! scale = 8                        # squares per UV unit
//!
//! [materials.floor]
//! kind = "phong"                   # phong | mirror | dielectric | emissive
//! texture = "tiles"                # or color = [r, g, b]
//!
//! [[lights]]
//! kind = "point"
//! position = [0, 4, 0]
//! intensity = [1, 1, 1]
//! power = 30
//!
//! [[objects]]
//! kind = "quad"                    # quad | plane | box | sphere | cylinder | obj | gltf
//! material = "floor"
//! scale = [10, 1, 10]
//! ```
//!
//! **Numbers** may be written as integers or floats; NaN and infinities are
//! rejected everywhere. **Colours** are linear RGB triples `[r, g, b]`; a single
//! number means grey. Unknown keys are errors, so typos do not go unnoticed.
//!
//! **Built-in primitives** are centred on the origin and fit in the unit cube
//! `[-½, ½]³`, so `scale` is their size: a `quad` (alias `plane`) is the unit
//! square in the XZ plane facing +Y, a `box` the unit cube, a `sphere` has
//! diameter 1, a `cylinder` diameter 1 and height 1 along Y. Transforms apply
//! scale, then rotation (Euler degrees about X, then Y, then Z), then
//! translation. Any object may say `subdivide = N` (0 to 6): every triangle is
//! split 1 → 4 at its edge midpoints N times, the shape unchanged (this makes
//! the 1.6M-triangle dragon of `scenes/dragon.toml` from the 100k one).
//!
//! **Texture coordinates** follow glTF: (0, 0) is the top-left of an image, `v`
//! grows downwards. OBJ files count `v` upwards, so the loader flips them. On a
//! `quad`, `u` runs along +X and `v` along +Z.

use crate::render::RenderSettings;
use glam::{Vec2, Vec3};
use serde::Deserialize;
use serde::de::{self, Deserializer, SeqAccess, Visitor};
use std::collections::BTreeMap;
use std::fmt;
use toml::Spanned;

/// A finite number. Deserialising NaN, an infinity, or a value outside the
/// `f32` range is an error pointing at the number.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Num(pub f32);

impl Num {
    fn check<E: de::Error>(x: f64) -> Result<Num, E> {
        if x.is_nan() {
            Err(E::custom("NaN is not allowed: numbers must be finite"))
        } else if !x.is_finite() {
            Err(E::custom(format!("{x} is not allowed: numbers must be finite")))
        } else if x.abs() > f32::MAX as f64 {
            Err(E::custom(format!("{x:e} is too large: numbers are at most {:e} in magnitude", f32::MAX)))
        } else {
            Ok(Num(x as f32))
        }
    }
}

struct NumVisitor;

impl<'de> Visitor<'de> for NumVisitor {
    type Value = Num;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a finite number")
    }
    fn visit_i64<E: de::Error>(self, v: i64) -> Result<Num, E> {
        Num::check(v as f64)
    }
    fn visit_u64<E: de::Error>(self, v: u64) -> Result<Num, E> {
        Num::check(v as f64)
    }
    fn visit_f64<E: de::Error>(self, v: f64) -> Result<Num, E> {
        Num::check(v)
    }
}

impl<'de> Deserialize<'de> for Num {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(NumVisitor)
    }
}

/// A point or direction `[x, y, z]`.
pub type Point = [Num; 3];

/// Converts a [`Point`].
pub fn vec3(p: Point) -> Vec3 {
    Vec3::new(p[0].0, p[1].0, p[2].0)
}

/// One number for every component, or one per component: `2` or `[1, 2, 3]`
/// (scales and colours), `2` or `[1, 2]` (UV scales).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Splat<const N: usize> {
    /// The same value for every component.
    Uniform(Num),
    /// One value per component.
    Each([Num; N]),
}

/// A colour (`[r, g, b]` linear RGB, or one number for grey), a per-axis
/// scale or a point-light intensity.
pub type Triple = Splat<3>;

impl Splat<3> {
    /// As a vector.
    pub fn vec3(self) -> Vec3 {
        match self {
            Splat::Uniform(n) => Vec3::splat(n.0),
            Splat::Each(a) => vec3(a),
        }
    }
}

impl Splat<2> {
    /// As a vector.
    pub fn vec2(self) -> Vec2 {
        match self {
            Splat::Uniform(n) => Vec2::splat(n.0),
            Splat::Each(a) => Vec2::new(a[0].0, a[1].0),
        }
    }
}

struct SplatVisitor<const N: usize>;

impl<'de, const N: usize> Visitor<'de> for SplatVisitor<N> {
    type Value = Splat<N>;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        write!(f, "a number or an array of {N} numbers")
    }
    fn visit_i64<E: de::Error>(self, v: i64) -> Result<Self::Value, E> {
        NumVisitor.visit_i64(v).map(Splat::Uniform)
    }
    fn visit_u64<E: de::Error>(self, v: u64) -> Result<Self::Value, E> {
        NumVisitor.visit_u64(v).map(Splat::Uniform)
    }
    fn visit_f64<E: de::Error>(self, v: f64) -> Result<Self::Value, E> {
        NumVisitor.visit_f64(v).map(Splat::Uniform)
    }
    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
        let mut out = [Num(0.0); N];
        for (i, slot) in out.iter_mut().enumerate() {
            *slot = seq.next_element()?.ok_or_else(|| de::Error::invalid_length(i, &self))?;
        }
        if seq.next_element::<de::IgnoredAny>()?.is_some() {
            return Err(de::Error::invalid_length(N + 1, &self));
        }
        Ok(Splat::Each(out))
    }
}

impl<'de, const N: usize> Deserialize<'de> for Splat<N> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(SplatVisitor::<N>)
    }
}

/// The whole scene file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    /// Ambient light added to every diffuse surface (linear RGB); default black.
    pub ambient: Option<Triple>,
    /// What rays that leave the scene see: a colour (linear RGB), or a sky
    /// `{ zenith = [r, g, b], horizon = [r, g, b] }` blended by the height
    /// of the ray's direction (+Y up; below the horizon, the horizon's
    /// colour); default black.
    pub background: Option<BackgroundDef>,
    /// Resolution, samples and recursion depth; see [`RenderSettings`] for the
    /// keys (`width`, `height`, `spp`, `light_samples`, `max_depth`, `seed`).
    pub settings: Option<Spanned<RenderSettings>>,
    /// The camera; the paper's default camera when absent.
    pub camera: Option<Spanned<CameraDef>>,
    /// Named textures, referenced by materials.
    #[serde(default)]
    pub textures: BTreeMap<String, Spanned<TextureDef>>,
    /// Named materials, referenced by objects.
    #[serde(default)]
    pub materials: BTreeMap<String, Spanned<MaterialDef>>,
    /// Light sources (`[[lights]]`).
    #[serde(default)]
    pub lights: Vec<Spanned<LightDef>>,
    /// Geometry (`[[objects]]`).
    #[serde(default)]
    pub objects: Vec<Spanned<ObjectDef>>,
}

/// `background`: a colour, or a two-colour sky gradient.
#[derive(Clone, Debug, Deserialize)]
#[serde(
    untagged,
    expecting = "a colour [r, g, b], a sky { zenith = [r, g, b], horizon = [r, g, b] } or an image { image = \"sky.hdr\" }"
)]
pub enum BackgroundDef {
    /// The same colour in every direction.
    Colour(Triple),
    /// A gradient from the horizon to the zenith.
    Sky(SkyDef),
    /// An equirectangular image.
    Image(EnvironmentDef),
}

/// An environment image: `{ image = "sky.hdr", strength = 1, rotate = 0 }`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EnvironmentDef {
    /// Equirectangular image, relative to the scene file: Radiance `.hdr`
    /// (linear), or PNG / JPEG (sRGB).
    pub image: String,
    /// Multiplier of its radiance; default 1.
    pub strength: Option<Num>,
    /// Turn about +Y in degrees; default 0 (the image's centre seen along −Z).
    pub rotate: Option<Num>,
}

/// A two-colour sky: `zenith` straight up (+Y), `horizon` at and below the horizon.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SkyDef {
    /// Colour straight up (linear RGB).
    pub zenith: Triple,
    /// Colour at the horizon and below (linear RGB).
    pub horizon: Triple,
}

/// `[camera]`: either the paper's form (`eye` and the image plane's corners
/// `p0` top-left, `p1` top-right, `p2` bottom-right, `p3` bottom-left) or the
/// look-at form (`eye`, `target`, optional `up`, `fov`, `aspect`).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraDef {
    /// The eye point (both forms).
    pub eye: Point,
    /// Top-left corner of the image plane (paper form).
    pub p0: Option<Point>,
    /// Top-right corner (paper form).
    pub p1: Option<Point>,
    /// Bottom-right corner (paper form).
    pub p2: Option<Point>,
    /// Bottom-left corner (paper form).
    pub p3: Option<Point>,
    /// The point looked at (look-at form).
    pub target: Option<Point>,
    /// Approximate up direction (look-at form); default `[0, 1, 0]`.
    pub up: Option<Point>,
    /// Horizontal field of view in degrees (look-at form); default the paper's
    /// 35.5°.
    pub fov: Option<Num>,
    /// Image-plane width / height (look-at form); default the settings' width / height.
    pub aspect: Option<Num>,
}

/// Texture kinds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TextureKind {
    /// Procedural checkerboard: `even`, `odd`, `scale`.
    Checker,
    /// PNG or JPEG image: `path` (relative to the scene file).
    Image,
}

/// `[textures.NAME]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TextureDef {
    /// `checker` or `image`.
    pub kind: TextureKind,
    /// Checker: colour of the even squares; default white.
    pub even: Option<Triple>,
    /// Checker: colour of the odd squares; default black.
    pub odd: Option<Triple>,
    /// Checker: squares per UV unit; default 8.
    pub scale: Option<Num>,
    /// Image: file path relative to the scene file (PNG or JPEG, sRGB).
    pub path: Option<String>,
}

/// Material kinds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MaterialKind {
    /// Lambert + Phong highlight + optional mirror blend: `color` or `texture`
    /// (+ `tint`), `specular`, `shininess`, `reflectivity`.
    Phong,
    /// Perfect mirror: `tint`.
    Mirror,
    /// Glass: `ior`, `tint`.
    Dielectric,
    /// Light-emitting surface: `radiance`.
    Emissive,
}

/// `[materials.NAME]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialDef {
    /// `phong`, `mirror`, `dielectric` or `emissive`.
    pub kind: MaterialKind,
    /// Phong: diffuse colour; default 0.7 grey.
    pub color: Option<Triple>,
    /// Phong: name of a texture giving the diffuse colour (instead of `color`).
    pub texture: Option<String>,
    /// Phong with a texture: multiplier of the texture colour; mirror: colour
    /// of the reflection; dielectric: transmission colour. Default white.
    pub tint: Option<Triple>,
    /// Phong: colour of the specular highlight; default none.
    pub specular: Option<Triple>,
    /// Phong: highlight exponent; default 32.
    pub shininess: Option<Num>,
    /// Phong: weight 0..=1 of a mirror reflection blended in; default 0.
    pub reflectivity: Option<Num>,
    /// Dielectric: index of refraction; default 1.5.
    pub ior: Option<Num>,
    /// Emissive: emitted radiance (linear RGB).
    pub radiance: Option<Triple>,
}

/// Light kinds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LightKind {
    /// Point light: `position`, `intensity`, `power`.
    Point,
    /// Polygonal area light: `vertices` (3 or 4) or `corner` + `edge1` +
    /// `edge2` (a parallelogram), `radiance`, `power`, `visible`.
    Area,
}

/// `[[lights]]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightDef {
    /// `point` or `area`.
    pub kind: LightKind,
    /// Point: position.
    pub position: Option<Point>,
    /// Point: colour of the intensity (linear RGB); default white.
    pub intensity: Option<Triple>,
    /// Scalar multiplier of `intensity` / `radiance`; default 1.
    pub power: Option<Num>,
    /// Area: the polygon's 3 or 4 vertices, counter-clockwise seen from the
    /// lit side (a quad must be planar and convex).
    pub vertices: Option<Vec<Point>>,
    /// Area: one corner of a parallelogram light…
    pub corner: Option<Point>,
    /// …its first edge from `corner`…
    pub edge1: Option<Point>,
    /// …and its second edge; the light shines towards `edge1 × edge2`.
    pub edge2: Option<Point>,
    /// Area: emitted radiance (linear RGB); default white.
    pub radiance: Option<Triple>,
    /// Area: whether the camera (and mirrors) see the lamp itself, as an
    /// emissive polygon; default true.
    pub visible: Option<bool>,
}

/// Object kinds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObjectKind {
    /// Unit square in the XZ plane, facing +Y.
    Quad,
    /// Same as `quad`.
    Plane,
    /// Unit cube.
    Box,
    /// UV sphere of diameter 1: `segments` (around, default 32), `rings`
    /// (pole to pole, default 16).
    Sphere,
    /// Cylinder of diameter 1 and height 1 along Y: `segments` (default 32),
    /// `caps` (default true).
    Cylinder,
    /// Wavefront OBJ mesh (+ its MTL libraries): `path`.
    Obj,
    /// glTF 2.0 scene (`.gltf` or `.glb`): `path`.
    Gltf,
}

impl ObjectKind {
    /// The kind's name as written in scene files.
    pub fn name(self) -> &'static str {
        match self {
            ObjectKind::Quad => "quad",
            ObjectKind::Plane => "plane",
            ObjectKind::Box => "box",
            ObjectKind::Sphere => "sphere",
            ObjectKind::Cylinder => "cylinder",
            ObjectKind::Obj => "obj",
            ObjectKind::Gltf => "gltf",
        }
    }
}

/// `[[objects]]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectDef {
    /// What to build.
    pub kind: ObjectKind,
    /// Optional label used in error messages.
    pub name: Option<String>,
    /// Material name. Required for built-in primitives unless the default grey
    /// is wanted; for meshes it overrides the file's own materials.
    pub material: Option<String>,
    /// Translation; default none.
    pub translate: Option<Point>,
    /// Rotation: Euler angles in degrees about X, then Y, then Z.
    pub rotate: Option<Point>,
    /// Scale: one number or one per axis; default 1. Must not be zero.
    pub scale: Option<Triple>,
    /// Multiplier of texture coordinates, to tile textures: one number or `[u, v]`.
    pub uv_scale: Option<Splat<2>>,
    /// Sphere and cylinder: subdivisions around the axis.
    pub segments: Option<u32>,
    /// Sphere: subdivisions from pole to pole.
    pub rings: Option<u32>,
    /// Cylinder: whether to close the ends.
    pub caps: Option<bool>,
    /// OBJ and glTF: file path relative to the scene file.
    pub path: Option<String>,
    /// OBJ and glTF: give a mesh without vertex normals smooth ones
    /// ([`super::smooth`]), across edges whose faces bend by at most
    /// `smooth_angle`; `false` also turns off an OBJ's `s` smoothing groups.
    /// Meshes with normals keep theirs.
    pub smooth: Option<bool>,
    /// OBJ and glTF: the crease angle of `smooth`, in degrees (0 to 180,
    /// default 30); setting it implies `smooth = true`.
    pub smooth_angle: Option<Num>,
    /// Midpoint subdivision levels (each splits every triangle 1 → 4, the
    /// shape unchanged); default 0, at most
    /// [`MAX_SUBDIVIDE`](super::subdivide::MAX_SUBDIVIDE).
    pub subdivide: Option<u32>,
}

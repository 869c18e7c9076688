//! Turns a parsed [`SceneFile`] into [`SceneParts`]: validates every entry,
//! resolves names, loads assets and emits world-space triangles.

use super::errors::{Location, SceneError, SourceMap};
use super::format::*;
use super::smooth::{DEFAULT_SMOOTH_ANGLE, smooth_normals};
use super::subdivide::{self, MAX_SUBDIVIDE};
use super::{AssetSource, gltf, obj};
use crate::cameras::Camera;
use crate::lights::Light;
use crate::limits;
use crate::materials::{Albedo, Material};
use crate::meshes::{self, Mesh, Transform};
use crate::scene::{Environment, SceneParts, TriangleShading};
use crate::shapes::Triangle;
use crate::textures::{MipMap, Texture};
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use std::collections::{BTreeMap, HashMap};
use std::ops::Range;
use toml::Spanned;

/// Most triangles a scene may have (about 100 bytes each once built).
pub const MAX_TRIANGLES: usize = 20_000_000;
/// Largest image texture side accepted.
pub const MAX_IMAGE_SIDE: u32 = 16_384;
/// Scenes with more triangles than this get a warning with their memory estimate.
pub const LARGE_TRIANGLES: usize = 10_000_000;
/// Bytes a triangle takes once the scene is built, roughly: the triangle (36),
/// its shading record (64), its unit normal (16) and its share of the BVH (~68).
pub const BYTES_PER_TRIANGLE: usize = 184;
/// Textures with more texels than this (8192²) get a warning.
pub const LARGE_TEXTURE_TEXELS: u64 = 8192 * 8192;

/// Who needs something: a scene-file entry (for error messages).
#[derive(Clone, Debug)]
pub(crate) struct Origin {
    /// File and line of the entry.
    pub at: Location,
    /// The entry, e.g. `objects[2] (obj)` or `materials.red`.
    pub what: String,
}

impl Origin {
    /// An [`SceneError::Invalid`] about this entry.
    pub fn invalid(&self, message: impl Into<String>) -> SceneError {
        SceneError::Invalid { at: self.at.clone(), what: self.what.clone(), message: message.into() }
    }

    /// An [`SceneError::BadAsset`] about an asset this entry needs.
    pub fn bad_asset(&self, path: &str, message: impl Into<String>) -> SceneError {
        SceneError::BadAsset {
            at: self.at.clone(),
            what: self.what.clone(),
            path: path.to_owned(),
            message: message.into(),
        }
    }
}

/// Per-object placement applied to every mesh the object produces.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Placement {
    /// Object to world.
    pub transform: Transform,
    /// Multiplier of texture coordinates.
    pub uv_scale: Vec2,
    /// Material overriding the mesh file's own, if the object names one.
    pub material: Option<u32>,
    /// Midpoint subdivision levels applied to every mesh (see [`super::subdivide`]).
    pub subdivide: u32,
    /// Whether meshes without normals get smooth ones.
    pub smooth: Smoothing,
}

/// What an object says about smoothing meshes that have no normals.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Smoothing {
    /// Nothing: OBJ smoothing groups (`s`) are followed, other meshes are flat.
    Default,
    /// `smooth = false`: flat, whatever the file says.
    Off,
    /// `smooth = true` / `smooth_angle`: smooth, with this crease angle (degrees).
    On(f32),
}

/// Accumulates the scene while entries are processed.
pub(crate) struct Builder<'a> {
    pub map: SourceMap<'a>,
    pub assets: &'a mut dyn AssetSource,
    pub parts: SceneParts,
    material_names: BTreeMap<String, u32>,
    texture_names: BTreeMap<String, u32>,
    images: HashMap<String, u32>,
    default_material: Option<u32>,
    degenerate: usize,
    quiet: bool,
}

/// Joins `rel` (as written inside `base`, a path relative to the scene file)
/// onto `base`'s directory, normalising `.` and `..` segments and backslashes.
pub(crate) fn join(base: &str, rel: &str) -> String {
    let rel = rel.replace('\\', "/");
    let mut parts: Vec<&str> = Vec::new();
    let combined = if rel.starts_with('/') {
        rel.clone()
    } else {
        match base.rfind('/') {
            Some(i) => format!("{}/{}", &base[..i], rel),
            None => rel.clone(),
        }
    };
    let absolute = combined.starts_with('/');
    for seg in combined.split('/') {
        match seg {
            "" | "." => {}
            ".." if parts.last().is_some_and(|p| *p != "..") => {
                parts.pop();
            }
            s => parts.push(s),
        }
    }
    let joined = parts.join("/");
    if absolute { format!("/{joined}") } else { joined }
}

/// Decodes a PNG or JPEG image into a mip-mapped texture.
pub(crate) fn decode_image(bytes: &[u8]) -> Result<MipMap, String> {
    let img = decode_rgba8(bytes)?;
    let (w, h) = img.dimensions();
    Ok(MipMap::from_srgb8(w, h, img.as_raw()))
}

/// Decodes a PNG or JPEG image to 8-bit RGBA, within [`MAX_IMAGE_SIDE`].
fn decode_rgba8(bytes: &[u8]) -> Result<image::RgbaImage, String> {
    use image::ImageFormat::{Jpeg, Png};
    Ok(decode_any(bytes, &[Png, Jpeg], "not a PNG or JPEG image")?.to_rgba8())
}

/// Decodes an image in one of the `formats`, within [`MAX_IMAGE_SIDE`].
fn decode_any(
    bytes: &[u8],
    formats: &[image::ImageFormat],
    other: &str,
) -> Result<image::DynamicImage, String> {
    let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| e.to_string())?;
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_IMAGE_SIDE);
    limits.max_image_height = Some(MAX_IMAGE_SIDE);
    reader.limits(limits);
    if !reader.format().is_some_and(|f| formats.contains(&f)) {
        return Err(other.into());
    }
    let img = reader.decode().map_err(|e| e.to_string())?;
    if img.width() == 0 || img.height() == 0 {
        return Err("image has no pixels".into());
    }
    Ok(img)
}

/// Decodes a PNG or JPEG image holding data rather than colour (a glTF
/// metallic-roughness map): channels scaled to 0..1, no sRGB decoding.
pub(crate) fn decode_image_linear(bytes: &[u8]) -> Result<MipMap, String> {
    let img = decode_rgba8(bytes)?;
    let (w, h) = img.dimensions();
    let texels = img.pixels().map(|p| Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32) / 255.0).collect();
    Ok(MipMap::from_linear(w, h, texels))
}

/// The warning for a scene of `triangles` triangles, when it is large.
fn large_scene_warning(triangles: usize) -> Option<String> {
    (triangles > LARGE_TRIANGLES).then(|| {
        let gb = (triangles * BYTES_PER_TRIANGLE) as f64 / 1e9;
        format!("{triangles} triangles: the built scene needs about {gb:.1} GB of memory")
    })
}

/// The warning for a `w × h` texture taking `bytes`, when it is large.
fn large_texture_warning(name: &str, w: u32, h: u32, bytes: usize) -> Option<String> {
    (w as u64 * h as u64 > LARGE_TEXTURE_TEXELS).then(|| {
        format!("texture {name} is {w}×{h}, larger than 8192²: it takes {:.0} MB", bytes as f64 / 1e6)
    })
}

/// Decodes an environment image: Radiance HDR as linear radiance, PNG and
/// JPEG as sRGB colour.
fn decode_environment(bytes: &[u8]) -> Result<MipMap, String> {
    use image::ImageFormat::{Hdr, Jpeg, Png};
    let img = decode_any(bytes, &[Hdr, Png, Jpeg], "not a Radiance HDR, PNG or JPEG image")?;
    if !matches!(img, image::DynamicImage::ImageRgb32F(_) | image::DynamicImage::ImageRgba32F(_)) {
        return decode_image(bytes);
    }
    let img = img.to_rgb32f();
    let finite = |c: Vec3| if c.is_finite() { c.max(Vec3::ZERO) } else { Vec3::ZERO };
    Ok(MipMap::from_linear(
        img.width(),
        img.height(),
        img.pixels().map(|p| finite(Vec3::from(p.0))).collect(),
    ))
}

/// Decodes the alpha channel of a PNG or JPEG image (0..1, in every
/// channel), for alpha-masked glTF materials.
pub(crate) fn decode_image_alpha(bytes: &[u8]) -> Result<MipMap, String> {
    let img = decode_rgba8(bytes)?;
    let (w, h) = img.dimensions();
    Ok(MipMap::from_linear(w, h, img.pixels().map(|p| Vec3::splat(p[3] as f32 / 255.0)).collect()))
}

/// Checks that each `(field, is_set)` is among `allowed` for the kind.
fn check_fields(
    map: &SourceMap,
    span: &Range<usize>,
    what: &str,
    kind: &str,
    set: &[(&str, bool)],
    allowed: &[&str],
) -> Result<(), SceneError> {
    for &(field, is_set) in set {
        if is_set && !allowed.contains(&field) {
            return Err(SceneError::Invalid {
                at: map.field(span, field),
                what: format!("{what}.{field}"),
                message: format!(
                    "`{field}` does not apply to kind = \"{kind}\" (its keys: {})",
                    if allowed.is_empty() { "none".to_owned() } else { allowed.join(", ") }
                ),
            });
        }
    }
    Ok(())
}

impl<'a> Builder<'a> {
    /// A builder for the scene file `name` with text `text`.
    pub fn new(name: &'a str, text: &'a str, assets: &'a mut dyn AssetSource) -> Self {
        Builder {
            map: SourceMap { file: name, text },
            assets,
            parts: SceneParts::default(),
            material_names: BTreeMap::new(),
            texture_names: BTreeMap::new(),
            images: HashMap::new(),
            default_material: None,
            degenerate: 0,
            quiet: false,
        }
    }

    /// Builds everything.
    pub fn build(mut self) -> Result<SceneParts, SceneError> {
        let file: SceneFile = toml::from_str(self.map.text).map_err(|e| self.map.syntax(&e))?;
        let whole = 0..self.map.text.len();
        self.parts.ambient = self.colour(file.ambient, Vec3::ZERO, &whole, "ambient", "ambient")?;
        match &file.background {
            None => {}
            Some(BackgroundDef::Image(env)) => {
                let origin = Origin { at: self.map.field(&whole, "background"), what: "background".into() };
                let strength = env.strength.map_or(1.0, |n| n.0);
                if strength < 0.0 {
                    return Err(origin.invalid(format!("strength must not be negative, got {strength}")));
                }
                let path = join("", &env.image);
                let bytes = self.read_asset(&path, &origin)?;
                let map = decode_environment(&bytes).map_err(|e| origin.bad_asset(&path, e))?;
                let (w, h) = map.level_size(0);
                if let Some(warning) = large_texture_warning(&path, w, h, map.memory_bytes()) {
                    self.warn(warning);
                }
                let rotation = env.rotate.map_or(0.0, |n| n.0).to_radians();
                self.parts.environment = Some(Environment { map, strength, rotation });
            }
            Some(BackgroundDef::Colour(c)) => {
                self.parts.background =
                    self.colour(Some(*c), Vec3::ZERO, &whole, "background", "background")?;
            }
            Some(BackgroundDef::Sky(sky)) => {
                let zenith = self.colour(Some(sky.zenith), Vec3::ZERO, &whole, "background", "background")?;
                self.parts.background =
                    self.colour(Some(sky.horizon), Vec3::ZERO, &whole, "background", "background")?;
                self.parts.zenith = Some(zenith);
            }
        }
        if let Some(settings) = &file.settings {
            self.settings(settings)?;
        }
        for (name, def) in &file.textures {
            let index = self.texture(name, def)?;
            self.texture_names.insert(name.clone(), index);
        }
        for (name, def) in &file.materials {
            let material = self.material(name, def)?;
            self.material_names.insert(name.clone(), self.parts.materials.len() as u32);
            self.parts.materials.push(material);
        }
        for (i, light) in file.lights.iter().enumerate() {
            self.light(i, light)?;
        }
        for (i, object) in file.objects.iter().enumerate() {
            self.object(i, object)?;
        }
        self.parts.camera = match &file.camera {
            Some(c) => self.camera(c)?,
            None => Camera::default(),
        };
        if self.degenerate > 0 {
            tracing::debug!(file = self.map.file, count = self.degenerate, "skipped degenerate triangles");
        }
        if self.parts.triangles.is_empty() {
            return Err(SceneError::Empty { file: self.map.file.to_owned() });
        }
        self.warn_about_the_whole();
        tracing::debug!(
            file = self.map.file,
            triangles = self.parts.triangles.len(),
            materials = self.parts.materials.len(),
            textures = self.parts.textures.len(),
            lights = self.parts.lights.len(),
            "scene parsed"
        );
        Ok(self.parts)
    }

    /// Records a warning for the user, and logs it unless the builder is
    /// [`Builder::quiet`].
    pub fn warn(&mut self, message: String) {
        if !self.quiet {
            tracing::warn!(file = self.map.file, "{message}");
        }
        self.parts.warnings.push(message);
    }

    /// A builder that keeps its warnings to itself (in
    /// [`SceneParts::warnings`]): for a look at a mesh before the scene
    /// around it is loaded, and warns, for real.
    pub fn quiet(mut self) -> Self {
        self.quiet = true;
        self
    }

    /// Warnings about the finished scene: nothing to light it, its size.
    fn warn_about_the_whole(&mut self) {
        let materials = &self.parts.materials;
        let emissive = self
            .parts
            .shading
            .iter()
            .any(|s| materials.get(s.material as usize).is_some_and(Material::emits));
        if self.parts.lights.is_empty() && !emissive {
            let lit =
                if self.parts.ambient.max_element() > 0.0 { "only by the ambient term" } else { "black" };
            self.warn(format!(
                "the scene has no lights and no emissive surface: it will render {lit} (add [[lights]])"
            ));
        }
        if let Some(w) = large_scene_warning(self.parts.triangles.len()) {
            self.warn(w);
        }
        if self.camera_sees_nothing_from_inside() {
            self.warn(
                "the camera is inside the scene's bounding box and sees nothing: move its `eye` \
                 (or check the model's scale)"
                    .into(),
            );
        }
    }

    /// True when the camera's eye is inside the bounding box of the scene's
    /// triangles and none of the rays through the image's centre and four
    /// points near its corners hits one (brute force: the BVH is not built yet).
    fn camera_sees_nothing_from_inside(&self) -> bool {
        let tris = &self.parts.triangles;
        let bounds = tris.iter().fold(crate::geometry::Aabb::EMPTY, |b, t| b.union(&t.bounds()));
        let eye = self.parts.camera.eye;
        if !(eye.cmpge(bounds.min).all() && eye.cmple(bounds.max).all()) {
            return false;
        }
        let points = [(0.5, 0.5), (0.1, 0.1), (0.9, 0.1), (0.1, 0.9), (0.9, 0.9)];
        !points.iter().any(|&(fx, fy)| {
            let ray = self.parts.camera.ray(fx, fy);
            tris.par_iter().any(|t| t.occludes(&ray, 0.0, f32::INFINITY))
        })
    }

    fn origin(&self, span: &Range<usize>, what: String) -> Origin {
        Origin { at: self.map.at(span.start), what }
    }

    fn invalid_field(&self, span: &Range<usize>, what: &str, key: &str, message: String) -> SceneError {
        SceneError::Invalid { at: self.map.field(span, key), what: format!("{what}.{key}"), message }
    }

    /// A colour: components must be non-negative.
    fn colour(
        &self,
        value: Option<Triple>,
        default: Vec3,
        span: &Range<usize>,
        what: &str,
        key: &str,
    ) -> Result<Vec3, SceneError> {
        let c = value.map_or(default, Triple::vec3);
        if c.min_element() < 0.0 {
            return Err(SceneError::Invalid {
                at: self.map.field(span, key),
                what: if what == key { key.to_owned() } else { format!("{what}.{key}") },
                message: format!("colour components must not be negative, got {c}"),
            });
        }
        Ok(c)
    }

    /// Reads an asset for `origin`.
    pub fn read_asset(&mut self, path: &str, origin: &Origin) -> Result<Vec<u8>, SceneError> {
        self.assets.read(path).map_err(|reason| SceneError::MissingAsset {
            at: origin.at.clone(),
            what: origin.what.clone(),
            path: path.to_owned(),
            reason,
        })
    }

    /// The index of the image texture at `path` (relative to the scene file),
    /// loading it the first time.
    pub fn image_texture(&mut self, path: &str, origin: &Origin) -> Result<u32, SceneError> {
        if let Some(&i) = self.images.get(path) {
            return Ok(i);
        }
        let bytes = self.read_asset(path, origin)?;
        let mip = decode_image(&bytes).map_err(|e| origin.bad_asset(path, e))?;
        self.add_image(path.to_owned(), mip)
    }

    /// Adds a decoded image texture under a cache key, returning its index.
    pub fn add_image(&mut self, key: String, mip: MipMap) -> Result<u32, SceneError> {
        let (w, h) = mip.level_size(0);
        let name = key.split('#').next().unwrap_or(&key);
        if let Some(warning) = large_texture_warning(name, w, h, mip.memory_bytes()) {
            self.warn(warning);
        }
        let i = self.parts.textures.len() as u32;
        self.parts.textures.push(Texture::Image(mip));
        self.images.insert(key, i);
        Ok(i)
    }

    /// A cached image texture, if `key` was loaded before.
    pub fn cached_image(&self, key: &str) -> Option<u32> {
        self.images.get(key).copied()
    }

    /// Adds a material, returning its index.
    pub fn add_material(&mut self, m: Material) -> u32 {
        self.parts.materials.push(m);
        (self.parts.materials.len() - 1) as u32
    }

    /// The grey material used where nothing else is given.
    pub fn default_material(&mut self) -> u32 {
        match self.default_material {
            Some(i) => i,
            None => {
                let i = self.add_material(Material::default());
                self.default_material = Some(i);
                i
            }
        }
    }

    fn settings(&mut self, s: &Spanned<crate::render::RenderSettings>) -> Result<(), SceneError> {
        let span = s.span();
        let v = *s.get_ref();
        let mut v = v;
        if u64::from(v.max_depth) > limits::DEPTH.max {
            // What the integrator does anyway: said once, and the same for a
            // cluster, which is sent the clamped settings.
            let max = limits::DEPTH.max as u32;
            self.warn(format!("settings.max_depth {} is above {max}: rendering with {max}", v.max_depth));
            v.max_depth = max;
        }
        if let Err(e) = limits::check_settings(&v) {
            let key = match e.name {
                "samples per pixel" => "spp",
                "light samples" => "light_samples",
                "image pixels" => "width × height",
                _ if u64::from(v.width) == e.value => "width",
                _ => "height",
            };
            return Err(self.invalid_field(&span, "settings", key, e.to_string()));
        }
        self.parts.settings = v;
        Ok(())
    }

    /// Adds a named texture, returning its index (image files already loaded
    /// are shared).
    fn texture(&mut self, name: &str, def: &Spanned<TextureDef>) -> Result<u32, SceneError> {
        let span = def.span();
        let what = format!("textures.{name}");
        let d = def.get_ref();
        let set = [
            ("even", d.even.is_some()),
            ("odd", d.odd.is_some()),
            ("scale", d.scale.is_some()),
            ("path", d.path.is_some()),
        ];
        match d.kind {
            TextureKind::Checker => {
                check_fields(&self.map, &span, &what, "checker", &set, &["even", "odd", "scale"])?;
                let scale = d.scale.map_or(8.0, |n| n.0);
                if scale <= 0.0 {
                    return Err(self.invalid_field(
                        &span,
                        &what,
                        "scale",
                        format!("must be positive, got {scale}"),
                    ));
                }
                let checker = Texture::Checker {
                    even: self.colour(d.even, Vec3::ONE, &span, &what, "even")?,
                    odd: self.colour(d.odd, Vec3::ZERO, &span, &what, "odd")?,
                    scale,
                };
                self.parts.textures.push(checker);
                Ok((self.parts.textures.len() - 1) as u32)
            }
            TextureKind::Image => {
                check_fields(&self.map, &span, &what, "image", &set, &["path"])?;
                let Some(path) = &d.path else {
                    return Err(self.origin(&span, what).invalid("an image texture needs `path`"));
                };
                let origin = Origin { at: self.map.field(&span, "path"), what };
                self.image_texture(&join("", path), &origin)
            }
        }
    }

    fn material(&mut self, name: &str, def: &Spanned<MaterialDef>) -> Result<Material, SceneError> {
        let span = def.span();
        let what = format!("materials.{name}");
        let d = def.get_ref();
        let set = [
            ("color", d.color.is_some()),
            ("texture", d.texture.is_some()),
            ("tint", d.tint.is_some()),
            ("specular", d.specular.is_some()),
            ("shininess", d.shininess.is_some()),
            ("reflectivity", d.reflectivity.is_some()),
            ("ior", d.ior.is_some()),
            ("radiance", d.radiance.is_some()),
        ];
        let tint = self.colour(d.tint, Vec3::ONE, &span, &what, "tint")?;
        match d.kind {
            MaterialKind::Phong => {
                let allowed = ["color", "texture", "tint", "specular", "shininess", "reflectivity"];
                check_fields(&self.map, &span, &what, "phong", &set, &allowed)?;
                let albedo = match (&d.texture, d.color) {
                    (Some(_), Some(_)) => {
                        return Err(self.invalid_field(
                            &span,
                            &what,
                            "texture",
                            "give either `color` or `texture`, not both (use `tint` to colour a texture)"
                                .into(),
                        ));
                    }
                    (Some(t), None) => match self.texture_names.get(t) {
                        Some(&texture) => Albedo::Texture { texture, tint },
                        None => {
                            return Err(SceneError::UnknownName {
                                at: self.map.field(&span, "texture"),
                                what: format!("{what}.texture"),
                                kind: "texture",
                                name: t.clone(),
                                defined: names(&self.texture_names),
                            });
                        }
                    },
                    (None, color) => {
                        if d.tint.is_some() {
                            return Err(self.invalid_field(
                                &span,
                                &what,
                                "tint",
                                "`tint` multiplies a texture; without one use `color`".into(),
                            ));
                        }
                        Albedo::Constant(self.colour(color, Vec3::splat(0.7), &span, &what, "color")?)
                    }
                };
                let shininess = d.shininess.map_or(32.0, |n| n.0);
                if shininess < 0.0 {
                    return Err(self.invalid_field(
                        &span,
                        &what,
                        "shininess",
                        format!("must not be negative, got {shininess}"),
                    ));
                }
                let reflectivity = d.reflectivity.map_or(0.0, |n| n.0);
                if !(0.0..=1.0).contains(&reflectivity) {
                    return Err(self.invalid_field(
                        &span,
                        &what,
                        "reflectivity",
                        format!("must be between 0 and 1, got {reflectivity}"),
                    ));
                }
                Ok(Material::Phong {
                    albedo,
                    specular: self.colour(d.specular, Vec3::ZERO, &span, &what, "specular")?,
                    shininess,
                    reflectivity,
                })
            }
            MaterialKind::Mirror => {
                check_fields(&self.map, &span, &what, "mirror", &set, &["tint"])?;
                Ok(Material::Mirror { tint })
            }
            MaterialKind::Dielectric => {
                check_fields(&self.map, &span, &what, "dielectric", &set, &["ior", "tint"])?;
                let ior = d.ior.map_or(1.5, |n| n.0);
                if ior <= 0.0 {
                    return Err(self.invalid_field(
                        &span,
                        &what,
                        "ior",
                        format!("must be positive, got {ior}"),
                    ));
                }
                Ok(Material::Dielectric { ior, tint })
            }
            MaterialKind::Emissive => {
                check_fields(&self.map, &span, &what, "emissive", &set, &["radiance"])?;
                if d.radiance.is_none() {
                    return Err(self.origin(&span, what).invalid("an emissive material needs `radiance`"));
                }
                Ok(Material::Emissive {
                    radiance: self.colour(d.radiance, Vec3::ONE, &span, &what, "radiance")?,
                })
            }
        }
    }

    fn light(&mut self, index: usize, def: &Spanned<LightDef>) -> Result<(), SceneError> {
        let span = def.span();
        let d = def.get_ref();
        let what = format!("lights[{index}]");
        let set = [
            ("position", d.position.is_some()),
            ("intensity", d.intensity.is_some()),
            ("power", d.power.is_some()),
            ("vertices", d.vertices.is_some()),
            ("corner", d.corner.is_some()),
            ("edge1", d.edge1.is_some()),
            ("edge2", d.edge2.is_some()),
            ("radiance", d.radiance.is_some()),
            ("visible", d.visible.is_some()),
        ];
        let power = d.power.map_or(1.0, |n| n.0);
        if power < 0.0 {
            return Err(self.invalid_field(
                &span,
                &what,
                "power",
                format!("must not be negative, got {power}"),
            ));
        }
        match d.kind {
            LightKind::Point => {
                check_fields(&self.map, &span, &what, "point", &set, &["position", "intensity", "power"])?;
                let Some(position) = d.position else {
                    return Err(self.origin(&span, what).invalid("a point light needs `position`"));
                };
                let intensity = self.colour(d.intensity, Vec3::ONE, &span, &what, "intensity")? * power;
                self.parts.lights.push(Light::Point { position: vec3(position), intensity });
            }
            LightKind::Area => {
                let allowed = ["vertices", "corner", "edge1", "edge2", "radiance", "power", "visible"];
                check_fields(&self.map, &span, &what, "area", &set, &allowed)?;
                let vertices: Vec<Vec3> = match (&d.vertices, d.corner, d.edge1, d.edge2) {
                    (Some(v), None, None, None) => {
                        if !(3..=4).contains(&v.len()) {
                            return Err(self.invalid_field(
                                &span,
                                &what,
                                "vertices",
                                format!("an area light needs 3 or 4 vertices, got {}", v.len()),
                            ));
                        }
                        v.iter().map(|&p| vec3(p)).collect()
                    }
                    (None, Some(c), Some(e1), Some(e2)) => {
                        let (c, e1, e2) = (vec3(c), vec3(e1), vec3(e2));
                        vec![c, c + e1, c + e1 + e2, c + e2]
                    }
                    _ => {
                        return Err(self.origin(&span, what).invalid(
                            "an area light needs either `vertices` (3 or 4 points) or all of `corner`, \
                             `edge1` and `edge2`",
                        ));
                    }
                };
                let normal = (vertices[1] - vertices[0]).cross(vertices[2] - vertices[0]);
                let size = (vertices[1] - vertices[0]).length().max((vertices[2] - vertices[0]).length());
                if !normal.is_finite() || normal.length() <= 1e-9 * size * size {
                    return Err(self.origin(&span, what).invalid("the area light's polygon has zero area"));
                }
                if let Some(&p3) = vertices.get(3) {
                    let off_plane = (p3 - vertices[0]).dot(normal.normalize()).abs();
                    let convex = (vertices[2] - vertices[0]).cross(p3 - vertices[0]).dot(normal) > 0.0
                        && (vertices[2] - vertices[1]).cross(p3 - vertices[1]).dot(normal) > 0.0
                        && (p3 - vertices[2]).cross(vertices[0] - vertices[2]).dot(normal) > 0.0;
                    if off_plane > 1e-4 * size || !convex {
                        return Err(self.origin(&span, what).invalid(
                            "a 4-vertex area light must be a planar, convex quad with its vertices in order",
                        ));
                    }
                }
                let radiance = self.colour(d.radiance, Vec3::ONE, &span, &what, "radiance")? * power;
                if d.visible.unwrap_or(true) {
                    let material = self.add_material(Material::Emissive { radiance });
                    let mut mesh = Mesh { positions: vertices.clone(), ..Mesh::default() };
                    mesh.indices.push([0, 1, 2]);
                    if vertices.len() == 4 {
                        mesh.indices.push([0, 2, 3]);
                    }
                    let origin = self.origin(&span, what);
                    let placement = Placement {
                        transform: Transform::IDENTITY,
                        uv_scale: Vec2::ONE,
                        material: None,
                        subdivide: 0,
                        smooth: Smoothing::Default,
                    };
                    self.emit(&mesh, &placement, material, &origin)?;
                }
                self.parts.lights.push(Light::Area { vertices, radiance });
            }
        }
        Ok(())
    }

    fn object(&mut self, index: usize, def: &Spanned<ObjectDef>) -> Result<(), SceneError> {
        let span = def.span();
        let d = def.get_ref();
        let kind = d.kind.name();
        let what = match &d.name {
            Some(n) => format!("objects[{index}] ({kind} \"{n}\")"),
            None => format!("objects[{index}] ({kind})"),
        };
        let set = [
            ("segments", d.segments.is_some()),
            ("rings", d.rings.is_some()),
            ("caps", d.caps.is_some()),
            ("path", d.path.is_some()),
            ("smooth", d.smooth.is_some()),
            ("smooth_angle", d.smooth_angle.is_some()),
        ];
        let allowed: &[&str] = match d.kind {
            ObjectKind::Quad | ObjectKind::Plane | ObjectKind::Box => &[],
            ObjectKind::Sphere => &["segments", "rings"],
            ObjectKind::Cylinder => &["segments", "caps"],
            ObjectKind::Obj | ObjectKind::Gltf => &["path", "smooth", "smooth_angle"],
        };
        check_fields(&self.map, &span, &what, kind, &set, allowed)?;

        let material = match &d.material {
            None => None,
            Some(name) => match self.material_names.get(name) {
                Some(&m) => Some(m),
                None => {
                    return Err(SceneError::UnknownName {
                        at: self.map.field(&span, "material"),
                        what: format!("{what}.material"),
                        kind: "material",
                        name: name.clone(),
                        defined: names(&self.material_names),
                    });
                }
            },
        };
        let scale = d.scale.map_or(Vec3::ONE, Triple::vec3);
        if scale.to_array().contains(&0.0) {
            return Err(self.invalid_field(&span, &what, "scale", format!("must not be zero, got {scale}")));
        }
        let transform = Transform::from_srt(
            scale,
            d.rotate.map_or(Vec3::ZERO, vec3),
            d.translate.map_or(Vec3::ZERO, vec3),
        );
        let subdivide = d.subdivide.unwrap_or(0);
        if subdivide > MAX_SUBDIVIDE {
            return Err(self.invalid_field(
                &span,
                &what,
                "subdivide",
                format!("must be between 0 and {MAX_SUBDIVIDE}, got {subdivide}"),
            ));
        }
        let smooth = match (d.smooth, d.smooth_angle) {
            (Some(false), Some(_)) => {
                return Err(self.invalid_field(
                    &span,
                    &what,
                    "smooth_angle",
                    "`smooth_angle` needs smoothing, but `smooth = false`".into(),
                ));
            }
            (Some(false), None) => Smoothing::Off,
            (None, None) => Smoothing::Default,
            (_, angle) => {
                let angle = angle.map_or(DEFAULT_SMOOTH_ANGLE, |n| n.0);
                if !(0.0..=180.0).contains(&angle) {
                    return Err(self.invalid_field(
                        &span,
                        &what,
                        "smooth_angle",
                        format!("must be between 0 and 180 degrees, got {angle}"),
                    ));
                }
                Smoothing::On(angle)
            }
        };
        let placement = Placement {
            transform,
            uv_scale: d.uv_scale.map_or(Vec2::ONE, Splat::vec2),
            material,
            subdivide,
            smooth,
        };
        let origin = self.origin(&span, what.clone());
        let count = |key: &str, value: Option<u32>, default: u32, min: u32| -> Result<u32, SceneError> {
            let n = value.unwrap_or(default);
            if !(min..=4096).contains(&n) {
                return Err(self.invalid_field(
                    &span,
                    &what,
                    key,
                    format!("must be between {min} and 4096, got {n}"),
                ));
            }
            Ok(n)
        };
        let mesh = match d.kind {
            ObjectKind::Quad | ObjectKind::Plane => meshes::quad(),
            ObjectKind::Box => meshes::cuboid(),
            ObjectKind::Sphere => {
                meshes::uv_sphere(count("segments", d.segments, 32, 3)?, count("rings", d.rings, 16, 2)?)
            }
            ObjectKind::Cylinder => {
                meshes::cylinder(count("segments", d.segments, 32, 3)?, d.caps.unwrap_or(true))
            }
            ObjectKind::Obj | ObjectKind::Gltf => {
                let Some(path) = &d.path else {
                    return Err(origin.invalid(format!("a {kind} object needs `path`")));
                };
                let path = join("", path);
                let origin = Origin { at: self.map.field(&span, "path"), what: what.clone() };
                let before = self.parts.triangles.len();
                if d.kind == ObjectKind::Obj {
                    obj::load(self, &path, &origin, &placement)?;
                } else {
                    gltf::load(self, &path, &origin, &placement)?;
                }
                if self.parts.triangles.len() == before {
                    return Err(origin.bad_asset(&path, "the file contains no triangles"));
                }
                return Ok(());
            }
        };
        let material = match material {
            Some(m) => m,
            None => self.default_material(),
        };
        self.emit(&mesh, &placement, material, &origin)
    }

    /// Adds `mesh`, placed by `placement`, with `material` to the scene.
    /// Indices are checked, vertices must stay finite, zero-area triangles are
    /// skipped; missing normals give flat shading.
    pub fn emit(
        &mut self,
        mesh: &Mesh,
        placement: &Placement,
        material: u32,
        origin: &Origin,
    ) -> Result<(), SceneError> {
        let n = mesh.positions.len();
        let split = 4usize.pow(placement.subdivide.min(MAX_SUBDIVIDE));
        if self.parts.triangles.len() + mesh.indices.len().saturating_mul(split) > MAX_TRIANGLES {
            return Err(origin.invalid(format!("the scene would exceed {MAX_TRIANGLES} triangles")));
        }
        if let Some(&bad) = mesh.indices.iter().flatten().find(|&&i| i as usize >= n) {
            return Err(origin.invalid(format!("mesh index {bad} is out of range ({n} vertices)")));
        }
        let smoothed;
        let mesh = match placement.smooth {
            Smoothing::On(angle) if mesh.normals.len() != n => {
                smoothed = smooth_normals(mesh, None, angle);
                &smoothed
            }
            _ => mesh,
        };
        let subdivided;
        let mesh = if placement.subdivide > 0 {
            subdivided = subdivide::subdivide(mesh, placement.subdivide);
            &subdivided
        } else {
            mesh
        };
        let n = mesh.positions.len();
        let t = &placement.transform;
        let normal_matrix = t.normal_matrix();
        let flip = t.flips_winding();
        let has_normals = mesh.normals.len() == n;
        let has_uvs = mesh.uvs.len() == n;
        let has_colours = mesh.colours.len() == n;
        if has_colours && self.parts.colours.is_empty() {
            // The first mesh with vertex colours: the triangles before it are white.
            self.parts.colours = vec![[Vec3::ONE; 3]; self.parts.triangles.len()];
        }
        let colours = has_colours || !self.parts.colours.is_empty();
        let has_uvs1 = mesh.uvs1.len() == n;
        if has_uvs1 && self.parts.uvs1.is_empty() {
            self.parts.uvs1 = vec![[Vec2::ZERO; 3]; self.parts.triangles.len()];
        }
        let uvs1 = has_uvs1 || !self.parts.uvs1.is_empty();
        for &idx in &mesh.indices {
            if let Some(&bad) = idx.iter().find(|&&i| i as usize >= n) {
                return Err(origin.invalid(format!("mesh index {bad} is out of range ({n} vertices)")));
            }
            let idx = if flip { [idx[0], idx[2], idx[1]] } else { idx };
            let v = idx.map(|i| t.point(mesh.positions[i as usize]));
            if !v.iter().all(|p| p.is_finite()) {
                return Err(origin.invalid(format!(
                    "a vertex is not finite once placed in the world: {:?}",
                    idx.map(|i| mesh.positions[i as usize])
                )));
            }
            let tri = Triangle { v };
            let face = tri.normal().normalize_or_zero();
            if face == Vec3::ZERO || !face.is_finite() {
                self.degenerate += 1;
                continue;
            }
            let normals = if has_normals {
                idx.map(|i| {
                    let n = (normal_matrix * mesh.normals[i as usize]).normalize_or_zero();
                    if n == Vec3::ZERO || !n.is_finite() { face } else { n }
                })
            } else {
                [face; 3]
            };
            let uvs = if has_uvs {
                idx.map(|i| {
                    let uv = mesh.uvs[i as usize] * placement.uv_scale;
                    if uv.is_finite() { uv } else { Vec2::ZERO }
                })
            } else {
                [Vec2::ZERO; 3]
            };
            self.parts.triangles.push(tri);
            self.parts.shading.push(TriangleShading { normals, uvs, material });
            if colours {
                let c = if has_colours { idx.map(|i| mesh.colours[i as usize]) } else { [Vec3::ONE; 3] };
                self.parts.colours.push(c);
            }
            if uvs1 {
                let t = if has_uvs1 { idx.map(|i| mesh.uvs1[i as usize]) } else { [Vec2::ZERO; 3] };
                self.parts
                    .uvs1
                    .push(t.map(|uv| if uv.is_finite() { uv * placement.uv_scale } else { Vec2::ZERO }));
            }
        }
        Ok(())
    }

    fn camera(&self, def: &Spanned<CameraDef>) -> Result<Camera, SceneError> {
        let span = def.span();
        let d = def.get_ref();
        let at = self.map.at(span.start);
        let corners = [d.p0, d.p1, d.p2, d.p3];
        let look = [
            ("target", d.target.is_some()),
            ("up", d.up.is_some()),
            ("fov", d.fov.is_some()),
            ("aspect", d.aspect.is_some()),
        ];
        let eye = vec3(d.eye);
        let camera = if corners.iter().any(Option::is_some) {
            if let Some(&(key, _)) = look.iter().find(|(_, set)| *set) {
                return Err(self.invalid_field(
                    &span,
                    "camera",
                    key,
                    "give either the corners p0..p3 or the look-at keys (target, up, fov, aspect), not both"
                        .into(),
                ));
            }
            let mut c = [Vec3::ZERO; 4];
            for (i, p) in corners.iter().enumerate() {
                match p {
                    Some(p) => c[i] = vec3(*p),
                    None => {
                        return Err(SceneError::Invalid {
                            at: at.clone(),
                            what: format!("camera.p{i}"),
                            message: "the paper's camera form needs all four corners p0, p1, p2, p3".into(),
                        });
                    }
                }
            }
            Camera::from_corners(eye, c)
        } else {
            let Some(target) = d.target else {
                return Err(SceneError::Invalid {
                    at: at.clone(),
                    what: "camera".into(),
                    message: "give either the corners p0..p3 or a `target` to look at".into(),
                });
            };
            let target = vec3(target);
            let up = d.up.map_or(Vec3::Y, vec3);
            let forward = target - eye;
            if forward.length() == 0.0 {
                return Err(self.invalid_field(
                    &span,
                    "camera",
                    "target",
                    "the target equals the eye".into(),
                ));
            }
            if forward.normalize().cross(up.normalize_or_zero()).length() < 1e-6 {
                return Err(self.invalid_field(
                    &span,
                    "camera",
                    "up",
                    "`up` must not be zero or parallel to the viewing direction".into(),
                ));
            }
            let default_fov = Camera::default().hfov_degrees();
            let fov = d.fov.map_or(default_fov, |n| n.0);
            if !(fov > 0.0 && fov < 180.0) {
                return Err(self.invalid_field(
                    &span,
                    "camera",
                    "fov",
                    format!("must be between 0 and 180 degrees, got {fov}"),
                ));
            }
            let s = &self.parts.settings;
            let aspect = d.aspect.map_or(s.width as f32 / s.height as f32, |n| n.0);
            if aspect <= 0.0 {
                return Err(self.invalid_field(
                    &span,
                    "camera",
                    "aspect",
                    format!("must be positive, got {aspect}"),
                ));
            }
            Camera::look_at(eye, target, up, fov, aspect)
        };
        camera.validate().map_err(|source| SceneError::Camera { at, source })?;
        Ok(camera)
    }
}

fn names(map: &BTreeMap<String, u32>) -> String {
    if map.is_empty() {
        "none".to_owned()
    } else {
        map.keys().map(String::as_str).collect::<Vec<_>>().join(", ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn joins_paths_relative_to_the_referring_file() {
        assert_eq!(join("", "meshes/a.obj"), "meshes/a.obj");
        assert_eq!(join("", "./meshes/./a.obj"), "meshes/a.obj");
        assert_eq!(join("meshes/a.obj", "a.mtl"), "meshes/a.mtl");
        assert_eq!(join("meshes/a.obj", "../textures/t.png"), "textures/t.png");
        assert_eq!(join("a.obj", "../shared/x.png"), "../shared/x.png");
        assert_eq!(join("../../shared/m/c.obj", "c.mtl"), "../../shared/m/c.mtl");
        assert_eq!(join("m/c.obj", "tex\\wood.png"), "m/tex/wood.png");
        assert_eq!(join("m/c.obj", "/abs/wood.png"), "/abs/wood.png");
    }

    #[test]
    fn size_warnings_start_past_their_limits_and_give_the_memory() {
        assert_eq!(large_scene_warning(LARGE_TRIANGLES), None);
        let w = large_scene_warning(12_000_000).unwrap();
        assert!(w.contains("12000000 triangles") && w.contains("2.2 GB"), "{w}");
        assert_eq!(large_texture_warning("a.png", 8192, 8192, 1), None);
        let w = large_texture_warning("a.png", 16384, 8192, 3_000_000_000).unwrap();
        assert!(w.contains("a.png") && w.contains("16384×8192") && w.contains("3000 MB"), "{w}");
    }

    #[test]
    fn image_decoding_errors_are_reported() {
        assert!(decode_image(b"definitely not an image").is_err());
        // A PNG signature followed by garbage.
        let mut bytes = b"\x89PNG\r\n\x1a\n".to_vec();
        bytes.extend_from_slice(&[0xff; 40]);
        assert!(decode_image(&bytes).is_err());
    }
}

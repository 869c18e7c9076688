//! glTF 2.0 scenes (`.gltf` JSON or binary `.glb`) through the `gltf` crate.
//!
//! Buffers come from the GLB binary chunk, `data:` URIs (base64) or files read
//! through the scene's [`super::AssetSource`] (URIs relative to the glTF file).
//! Accessors are read by this module with every offset and length checked, so a
//! malformed file is an error, never a panic. All nodes of the default scene
//! are instanced with their full parent-to-child transform chain.
//!
//! **Extensions.** Supported: `KHR_materials_emissive_strength`,
//! `KHR_materials_ior`, `KHR_materials_transmission`, `KHR_texture_transform`,
//! `KHR_mesh_quantization` and `KHR_lights_punctual` (lights and cameras are
//! read by [`super::mesh_scene`] for scenes made around a file; a glTF object
//! in a scene file contributes its meshes only). A file that lists another
//! extension in `extensionsRequired` is refused with an error naming it; one
//! only in `extensionsUsed` is a warning, and the file renders without it.
//!
//! **Geometry.** Triangle lists, strips and fans, indexed or not; points and
//! lines are skipped. Attributes may be floats, normalised integers, or — with
//! `KHR_mesh_quantization` — plain integers; sparse accessors are applied
//! over their base view (or zeros). `COLOR_0` (RGB or RGBA, alpha ignored)
//! multiplies the base colour. Nodes with a negative scale keep their
//! triangles facing out (the winding is reversed). Surfaces are two-sided
//! whatever `doubleSided` says: a Whitted tracer shades both faces.
//!
//! **Materials** map onto Whitted shading ([`crate::materials::Pbr`]), with
//! the specification's defaults (white, `metallicFactor` = `roughnessFactor`
//! = 1). At every hit, with `c` the base colour (`baseColorFactor` ×
//! `baseColorTexture` × `COLOR_0`), `m` and `r` metallic and roughness (the
//! factors × the blue and green of `metallicRoughnessTexture`):
//!
//! - the specular reflectance at normal incidence is `F0 = lerp(0.04, c, m)`
//!   — 4 % for dielectrics, the base colour for metals;
//! - the diffuse albedo is `c (1 − m)(1 − 0.04)` plus, since a very rough
//!   specular reflects much as a diffuse surface does, a share `r²` of a
//!   metal's `F0`: a fully rough metal is matte and coloured, never black;
//! - the rest of `F0`, `F0 (1 − m r²)`, is a normalised Phong highlight of
//!   exponent `2/r⁴ − 2` (1..=4096), which is what point and area lights
//!   show on it;
//! - a mirror reflection weighted by Schlick's Fresnel term from `F0` and by
//!   `(1 − r)²`: smooth metals are mirrors tinted by their base colour,
//!   smooth dielectrics reflect a little head-on and much at grazing angles,
//!   rough surfaces not at all (their sharp reflection would be wrong);
//! - `emissiveFactor` × `emissiveTexture` × `KHR_materials_emissive_strength`
//!   is added as emitted light.
//!
//! The highlight and the mirror reflection both carry `F0`: mirrors in a
//! Whitted tracer see no point lights, so the highlight is what shows them.
//! `KHR_materials_transmission` above ½, or `alphaMode` `BLEND` with alpha
//! below 1, makes a dielectric instead (index from `KHR_materials_ior`, else
//! 1.5; tinted by the base colour). Textures honour `KHR_texture_transform`
//! and their sampler's wrap modes (repeat, clamp, mirrored repeat); filtering
//! is always isin's mip-mapped one (a texture on `TEXCOORD_1` is filtered
//! over `TEXCOORD_0`'s footprint); `TEXCOORD_0` and `TEXCOORD_1` are read (a
//! texture on another set warns and uses the first). `alphaMode` `MASK` cuts the
//! surface out where alpha (`baseColorFactor`'s × the base texture's,
//! unfiltered) is below `alphaCutoff` (default ½): camera, reflected,
//! refracted and shadow rays pass through there. `normalTexture` bends the
//! shading normal in a tangent frame made per triangle from its texture
//! coordinates (not from a `TANGENT` attribute, not MikkTSpace: seams of
//! curved, normal-mapped meshes may show). Not supported:
//! `occlusionTexture`, `COLOR_0`'s alpha.

use super::SceneError;
use super::build::{Builder, Origin, Placement, decode_image, decode_image_alpha, decode_image_linear, join};
use super::mesh_scene::{FileCamera, FileLight};
use crate::materials::{Material, Pbr, TextureMap, Wrap};
use crate::math;
use crate::meshes::{Mesh, Transform};
use glam::{Mat4, Vec2, Vec3};
use gltf::accessor::{DataType, Dimensions};
use std::collections::HashMap;

/// Deepest node hierarchy followed (guards against cyclic files).
const MAX_DEPTH: usize = 64;
/// Most node instances expanded from one file.
const MAX_INSTANCES: usize = 100_000;

/// Loads the glTF/GLB file at `path` (relative to the scene file) into the scene.
pub(crate) fn load(
    b: &mut Builder,
    path: &str,
    origin: &Origin,
    placement: &Placement,
) -> Result<(), SceneError> {
    let bytes = b.read_asset(path, origin)?;
    let bad = |m: String| origin.bad_asset(path, m);
    let (file, warnings) = parse(&bytes).map_err(bad)?;
    for w in warnings {
        b.warn(format!("{path}: {w}"));
    }
    let doc = &file.document;
    let quantized = doc.extensions_used().any(|e| e == "KHR_mesh_quantization");

    let mut buffers: Vec<Vec<u8>> = Vec::new();
    for buffer in doc.buffers() {
        let data = match buffer.source() {
            gltf::buffer::Source::Bin => {
                file.blob.clone().ok_or_else(|| bad("buffer refers to a missing GLB binary chunk".into()))?
            }
            gltf::buffer::Source::Uri(uri) => uri_bytes(b, path, uri, origin)?,
        };
        if data.len() < buffer.length() {
            return Err(bad(format!(
                "buffer {} holds {} bytes but declares {}",
                buffer.index(),
                data.len(),
                buffer.length()
            )));
        }
        buffers.push(data);
    }

    let scene = doc.default_scene().or_else(|| doc.scenes().next()).ok_or_else(|| bad("no scene".into()))?;
    let mut materials: HashMap<usize, u32> = HashMap::new();
    let mut stack: Vec<(gltf::Node, Transform, usize)> =
        scene.nodes().map(|n| (n, placement.transform, 0)).collect();
    let mut instances = 0;
    while let Some((node, parent, depth)) = stack.pop() {
        instances += 1;
        if depth > MAX_DEPTH || instances > MAX_INSTANCES {
            return Err(bad("node hierarchy is too deep or cyclic".into()));
        }
        let local = Transform::from_mat4(Mat4::from_cols_array_2d(&node.transform().matrix()));
        let world = local.then(&parent);
        for child in node.children() {
            stack.push((child, world, depth + 1));
        }
        let Some(mesh) = node.mesh() else { continue };
        for prim in mesh.primitives() {
            let name = format!("mesh {} primitive {}", mesh.index(), prim.index());
            let tris = read_primitive(&prim, &buffers, quantized).map_err(|e| bad(format!("{name}: {e}")))?;
            let Some(tris) = tris else {
                tracing::debug!(path, %name, "skipping a non-triangle primitive");
                continue;
            };
            let material = match (placement.material, prim.material().index()) {
                (Some(m), _) => m,
                (None, Some(i)) => match materials.get(&i) {
                    Some(&m) => m,
                    None => {
                        let m = convert(b, &prim.material(), path, &buffers, origin)?;
                        let m = b.add_material(m);
                        materials.insert(i, m);
                        m
                    }
                },
                (None, None) => b.default_material(),
            };
            let placed = Placement { transform: world, ..*placement };
            b.emit(&tris, &placed, material, origin)?;
        }
    }
    Ok(())
}

/// Extensions this loader understands; files that require others are refused.
pub(crate) const SUPPORTED_EXTENSIONS: &[&str] = &[
    "KHR_lights_punctual",
    "KHR_materials_emissive_strength",
    "KHR_materials_ior",
    "KHR_materials_transmission",
    "KHR_mesh_quantization",
    "KHR_texture_transform",
];

/// Parses and validates a glTF or GLB file. Unsupported extensions in
/// `extensionsRequired` are an error naming them all; unsupported ones in
/// `extensionsUsed` are a warning each (the file still renders, without
/// them), returned with the file.
fn parse(bytes: &[u8]) -> Result<(gltf::Gltf, Vec<String>), String> {
    check_glb_header(bytes)?;
    let file = gltf::Gltf::from_slice_without_validation(bytes).map_err(|e| format!("glTF: {e}"))?;
    let root = file.document.as_json();
    let unsupported: Vec<&str> = root
        .extensions_required
        .iter()
        .map(String::as_str)
        .filter(|e| !SUPPORTED_EXTENSIONS.contains(e))
        .collect();
    if !unsupported.is_empty() {
        return Err(format!(
            "the file requires glTF extensions isin does not support: {} (supported: {})",
            unsupported.join(", "),
            SUPPORTED_EXTENSIONS.join(", ")
        ));
    }
    let warnings = root
        .extensions_used
        .iter()
        .filter(|e| !SUPPORTED_EXTENSIONS.contains(&e.as_str()))
        .map(|e| format!("glTF extension {e} is not supported: rendering without it"))
        .collect();
    check_unchecked(root)?;
    let mut errors = Vec::new();
    use gltf::json::validation::Validate;
    root.validate(root, gltf::json::Path::new, &mut |at: &dyn Fn() -> gltf::json::Path, e| {
        let at = at().to_string();
        // Required extensions were checked above, against what isin supports.
        if !at.starts_with("extensionsRequired") {
            errors.push(format!("{at}: {e}"));
        }
    });
    if !errors.is_empty() {
        return Err(format!("glTF: invalid file: {}", errors.join("; ")));
    }
    Ok((file, warnings))
}

/// The first perspective camera and every punctual light of the default
/// scene of a glTF or GLB file, in world space.
pub(crate) fn cameras_and_lights(bytes: &[u8]) -> Result<(Option<FileCamera>, Vec<FileLight>), String> {
    // The file's warnings are the loader's to give: it reads the file too.
    let (file, _) = parse(bytes)?;
    let doc = &file.document;
    let Some(scene) = doc.default_scene().or_else(|| doc.scenes().next()) else {
        return Ok((None, Vec::new()));
    };
    let mut camera = None;
    let mut lights = Vec::new();
    // Depth first, in document order: the first camera is the one a viewer shows.
    let mut stack: Vec<(gltf::Node, Mat4, usize)> = scene.nodes().map(|n| (n, Mat4::IDENTITY, 0)).collect();
    stack.reverse();
    let mut visited = 0;
    while let Some((node, parent, depth)) = stack.pop() {
        visited += 1;
        if depth > MAX_DEPTH || visited > MAX_INSTANCES {
            return Err("node hierarchy is too deep or cyclic".into());
        }
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        let children: Vec<_> = node.children().collect();
        stack.extend(children.into_iter().rev().map(|child| (child, world, depth + 1)));
        let origin = world.transform_point3(Vec3::ZERO);
        let forward = world.transform_vector3(-Vec3::Z).normalize_or_zero();
        if let Some(cam) = node.camera() {
            match cam.projection() {
                gltf::camera::Projection::Perspective(p) if camera.is_none() => {
                    let up = world.transform_vector3(Vec3::Y).normalize_or_zero();
                    let ok = origin.is_finite() && forward != Vec3::ZERO && forward.cross(up).length() > 1e-3;
                    if ok && p.yfov() > 0.0 && p.yfov() < 3.1 {
                        camera = Some(FileCamera {
                            eye: origin,
                            forward,
                            up,
                            yfov: p.yfov(),
                            aspect: p.aspect_ratio(),
                        });
                    }
                }
                gltf::camera::Projection::Orthographic(_) => {
                    tracing::warn!(
                        camera = cam.index(),
                        "orthographic glTF cameras are not supported; framing the model instead"
                    );
                }
                _ => {}
            }
        }
        if let Some(light) = node.light() {
            let colour = Vec3::from(light.color()).max(Vec3::ZERO) * light.intensity().max(0.0);
            if !colour.is_finite() || !origin.is_finite() {
                continue;
            }
            use gltf::khr_lights_punctual::Kind;
            lights.push(match light.kind() {
                Kind::Directional => FileLight::Directional { direction: forward, illuminance: colour },
                Kind::Point => FileLight::Point { position: origin, intensity: colour },
                Kind::Spot { .. } => {
                    tracing::warn!(
                        light = light.index(),
                        "spot light cones are not supported: a point light"
                    );
                    FileLight::Point { position: origin, intensity: colour }
                }
            });
        }
    }
    Ok((camera, lights))
}

/// Refuses what the `gltf` crates (1.4) index or unwrap unchecked, and would
/// panic on (found by fuzzing: `fuzz/regressions/gltf`, `glb`): a
/// primitive attribute naming an accessor that does not exist (indexed by
/// the validation itself), an image in a buffer view without a `mimeType`,
/// an image with neither a `uri` nor a `bufferView`.
fn check_unchecked(root: &gltf::json::Root) -> Result<(), String> {
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            if let Some(index) = prim.attributes.values().find(|i| i.value() >= root.accessors.len()) {
                return Err(format!(
                    "glTF: meshes[{m}].primitives[{p}] names accessor {}, but the file has {}",
                    index.value(),
                    root.accessors.len()
                ));
            }
        }
    }
    for (i, image) in root.images.iter().enumerate() {
        match (&image.buffer_view, &image.mime_type, &image.uri) {
            (Some(_), None, _) => {
                return Err(format!("glTF: images[{i}] is in a buffer view but has no mimeType"));
            }
            (None, _, None) => return Err(format!("glTF: images[{i}] has neither a uri nor a bufferView")),
            _ => {}
        }
    }
    Ok(())
}

/// Rejects GLB headers whose declared length would make the `gltf` crate's
/// arithmetic overflow.
fn check_glb_header(bytes: &[u8]) -> Result<(), String> {
    if !bytes.starts_with(b"glTF") {
        return Ok(());
    }
    let word = |i: usize| bytes.get(i..i + 4).map(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]]));
    match word(8) {
        Some(len) if len >= 12 && len as usize <= bytes.len() => Ok(()),
        _ => Err("GLB header declares an impossible length".into()),
    }
}

/// The bytes behind a buffer or image URI: a `data:` URI or a file relative to
/// the glTF file.
fn uri_bytes(b: &mut Builder, gltf_path: &str, uri: &str, origin: &Origin) -> Result<Vec<u8>, SceneError> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let (meta, data) = rest.split_once(',').unwrap_or((rest, ""));
        if !meta.ends_with(";base64") {
            return Err(origin.bad_asset(gltf_path, "only base64 `data:` URIs are supported"));
        }
        return base64_decode(data).map_err(|e| origin.bad_asset(gltf_path, format!("data URI: {e}")));
    }
    let rel = join(gltf_path, &percent_decode(uri));
    let what = Origin { at: origin.at.clone(), what: format!("{} (uri in {gltf_path})", origin.what) };
    b.read_asset(&rel, &what)
}

/// Decodes standard base64 (padding optional, whitespace ignored).
pub(crate) fn base64_decode(text: &str) -> Result<Vec<u8>, String> {
    let mut out = Vec::with_capacity(text.len() / 4 * 3);
    let (mut acc, mut bits) = (0u32, 0u32);
    let mut padded = false;
    for c in text.bytes() {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            b'=' => {
                padded = true;
                continue;
            }
            b' ' | b'\n' | b'\r' | b'\t' => continue,
            _ => return Err(format!("invalid base64 character {:?}", c as char)),
        };
        if padded {
            return Err("base64 data continues after padding".into());
        }
        acc = (acc << 6) | v as u32;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    if bits >= 6 {
        return Err("truncated base64 data".into());
    }
    Ok(out)
}

/// Decodes `%XX` escapes in a URI.
fn percent_decode(uri: &str) -> String {
    let bytes = uri.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        let hex = |j: usize| bytes.get(j).and_then(|&c| (c as char).to_digit(16));
        match (bytes[i], hex(i + 1), hex(i + 2)) {
            (b'%', Some(h), Some(l)) => {
                out.push((h * 16 + l) as u8);
                i += 3;
            }
            (c, _, _) => {
                out.push(c);
                i += 1;
            }
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// An accessor's elements as `f32` components (normalised integers scaled to
/// 0..1 or −1..1; with `quantized` — the file uses `KHR_mesh_quantization` —
/// plain integers too), bounds-checked against its buffer view and buffer.
fn read_floats(
    acc: &gltf::Accessor,
    buffers: &[Vec<u8>],
    dims: usize,
    quantized: bool,
) -> Result<Vec<f32>, String> {
    let normalize = acc.normalized();
    read_components(acc, buffers, dims, |ty, b| match ty {
        DataType::F32 => Some(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        DataType::U8 if normalize => Some(b[0] as f32 / 255.0),
        DataType::U16 if normalize => Some(u16::from_le_bytes([b[0], b[1]]) as f32 / 65535.0),
        DataType::I8 if normalize => Some((b[0] as i8 as f32 / 127.0).max(-1.0)),
        DataType::I16 if normalize => Some((i16::from_le_bytes([b[0], b[1]]) as f32 / 32767.0).max(-1.0)),
        DataType::U8 if quantized => Some(b[0] as f32),
        DataType::U16 if quantized => Some(u16::from_le_bytes([b[0], b[1]]) as f32),
        DataType::I8 if quantized => Some(b[0] as i8 as f32),
        DataType::I16 if quantized => Some(i16::from_le_bytes([b[0], b[1]]) as f32),
        _ => None,
    })
}

/// An index accessor's elements.
fn read_indices(acc: &gltf::Accessor, buffers: &[Vec<u8>]) -> Result<Vec<u32>, String> {
    read_components(acc, buffers, 1, |ty, b| match ty {
        DataType::U8 => Some(b[0] as u32),
        DataType::U16 => Some(u16::from_le_bytes([b[0], b[1]]) as u32),
        DataType::U32 => Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        _ => None,
    })
}

/// The bytes of a buffer view, checked against its buffer.
fn view_bytes<'b>(view: &gltf::buffer::View, buffers: &'b [Vec<u8>], name: &str) -> Result<&'b [u8], String> {
    let buffer = buffers.get(view.buffer().index()).ok_or_else(|| format!("{name}: no such buffer"))?;
    view.offset()
        .checked_add(view.length())
        .and_then(|end| buffer.get(view.offset()..end))
        .ok_or_else(|| format!("{name}: buffer view {} exceeds its buffer", view.index()))
}

/// `count` elements of `elem` bytes each, `stride` apart from `offset` in
/// `data`, or `None` when they do not fit.
fn elements(data: &[u8], offset: usize, count: usize, stride: usize, elem: usize) -> Option<&[u8]> {
    if count == 0 {
        return Some(&[]);
    }
    let end = (count - 1).checked_mul(stride)?.checked_add(elem)?.checked_add(offset)?;
    data.get(offset..end)
}

fn read_components<T: Copy>(
    acc: &gltf::Accessor,
    buffers: &[Vec<u8>],
    dims: usize,
    decode: impl Fn(DataType, &[u8]) -> Option<T>,
) -> Result<Vec<T>, String> {
    let name = format!("accessors[{}]", acc.index());
    let want = match dims {
        1 => Dimensions::Scalar,
        2 => Dimensions::Vec2,
        3 => Dimensions::Vec3,
        _ => Dimensions::Vec4,
    };
    if acc.dimensions() != want {
        return Err(format!("{name} has type {:?}, expected {want:?}", acc.dimensions()));
    }
    let ty = acc.data_type();
    let size = ty.size();
    let Some(zero) = decode(ty, &[0; 4]) else {
        return Err(format!(
            "{name}: component type {ty:?} (normalized: {}) is not allowed here",
            acc.normalized()
        ));
    };
    let count = acc.count();
    let elem = size * dims;
    let mut out = match acc.view() {
        Some(view) => {
            let data = view_bytes(&view, buffers, &name)?;
            let stride = view.stride().unwrap_or(elem);
            if stride < elem {
                return Err(format!(
                    "{name}: byte stride {stride} is smaller than an element ({elem} bytes)"
                ));
            }
            let data = elements(data, acc.offset(), count, stride, elem)
                .ok_or_else(|| format!("{name}: {count} elements exceed buffer view {}", view.index()))?;
            let mut out = Vec::with_capacity(count * dims);
            for i in 0..count {
                for c in 0..dims {
                    let at = i * stride + c * size;
                    out.extend(decode(ty, &data[at..at + size]));
                }
            }
            out
        }
        // Without a view every element is zero (sparse accessors then set some).
        None if acc.sparse().is_some() => {
            if count > super::MAX_TRIANGLES * 3 {
                return Err(format!("{name}: {count} elements is too many"));
            }
            vec![zero; count * dims]
        }
        None => return Err(format!("{name} has no buffer view")),
    };
    if let Some(sparse) = acc.sparse() {
        let n = sparse.count();
        let (indices, values) = (sparse.indices(), sparse.values());
        let isize = match indices.index_type() {
            gltf::accessor::sparse::IndexType::U8 => 1,
            gltf::accessor::sparse::IndexType::U16 => 2,
            gltf::accessor::sparse::IndexType::U32 => 4,
        };
        let what = format!("{name}.sparse");
        let ib = elements(view_bytes(&indices.view(), buffers, &what)?, indices.offset(), n, isize, isize)
            .ok_or_else(|| format!("{what}: {n} indices exceed their buffer view"))?;
        let vb = elements(view_bytes(&values.view(), buffers, &what)?, values.offset(), n, elem, elem)
            .ok_or_else(|| format!("{what}: {n} values exceed their buffer view"))?;
        for k in 0..n {
            let b = &ib[k * isize..k * isize + isize];
            let i = match isize {
                1 => b[0] as usize,
                2 => u16::from_le_bytes([b[0], b[1]]) as usize,
                _ => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize,
            };
            if i >= count {
                return Err(format!("{what}: index {i} is out of range ({count} elements)"));
            }
            for c in 0..dims {
                let at = k * elem + c * size;
                if let Some(v) = decode(ty, &vb[at..at + size]) {
                    out[i * dims + c] = v;
                }
            }
        }
    }
    Ok(out)
}

/// A triangle primitive as a [`Mesh`] (in the node's space); `None` for points
/// and lines.
fn read_primitive(
    prim: &gltf::Primitive,
    buffers: &[Vec<u8>],
    quantized: bool,
) -> Result<Option<Mesh>, String> {
    use gltf::mesh::Mode;
    let mode = prim.mode();
    if !matches!(mode, Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) {
        return Ok(None);
    }
    let positions = prim.get(&gltf::Semantic::Positions).ok_or("no POSITION attribute")?;
    let positions: Vec<Vec3> =
        read_floats(&positions, buffers, 3, quantized)?.chunks_exact(3).map(Vec3::from_slice).collect();
    let n = positions.len();
    let normals = match prim.get(&gltf::Semantic::Normals) {
        Some(a) => read_floats(&a, buffers, 3, quantized)?
            .chunks_exact(3)
            .map(|c| Vec3::from_slice(c).normalize_or_zero())
            .collect(),
        None => Vec::new(),
    };
    let uvs = match prim.get(&gltf::Semantic::TexCoords(0)) {
        Some(a) => read_floats(&a, buffers, 2, quantized)?.chunks_exact(2).map(Vec2::from_slice).collect(),
        None => Vec::new(),
    };
    let uvs1: Vec<Vec2> = match prim.get(&gltf::Semantic::TexCoords(1)) {
        Some(a) => read_floats(&a, buffers, 2, quantized)?.chunks_exact(2).map(Vec2::from_slice).collect(),
        None => Vec::new(),
    };
    let colours: Vec<Vec3> = match prim.get(&gltf::Semantic::Colors(0)) {
        Some(a) => {
            let dims = if a.dimensions() == Dimensions::Vec4 { 4 } else { 3 };
            read_floats(&a, buffers, dims, quantized)?
                .chunks_exact(dims)
                .map(|c| Vec3::from_slice(c).max(Vec3::ZERO))
                .collect()
        }
        None => Vec::new(),
    };
    if normals.len() != n && !normals.is_empty()
        || uvs.len() != n && !uvs.is_empty()
        || colours.len() != n && !colours.is_empty()
        || uvs1.len() != n && !uvs1.is_empty()
    {
        return Err("attribute counts differ".into());
    }
    let order: Vec<u32> = match prim.indices() {
        Some(a) => read_indices(&a, buffers)?,
        None => (0..n as u32).collect(),
    };
    let indices: Vec<[u32; 3]> = match mode {
        Mode::Triangles => order.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        Mode::TriangleStrip => (2..order.len())
            .map(|i| {
                if i % 2 == 0 {
                    [order[i - 2], order[i - 1], order[i]]
                } else {
                    [order[i - 1], order[i - 2], order[i]]
                }
            })
            .collect(),
        _ => (2..order.len()).map(|i| [order[0], order[i - 1], order[i]]).collect(),
    };
    if let Some(bad) = order.iter().find(|&&i| i as usize >= n) {
        return Err(format!("index {bad} out of range ({n} vertices)"));
    }
    Ok(Some(Mesh { positions, normals, uvs, indices, colours, uvs1 }))
}

/// Maps a glTF material to an isin material (see the module docs).
fn convert(
    b: &mut Builder,
    m: &gltf::Material,
    path: &str,
    buffers: &[Vec<u8>],
    origin: &Origin,
) -> Result<Material, SceneError> {
    let pbr = m.pbr_metallic_roughness();
    let base = pbr.base_color_factor();
    let colour = Vec3::new(base[0], base[1], base[2]).max(Vec3::ZERO);
    let metallic = pbr.metallic_factor().clamp(0.0, 1.0);
    let roughness = pbr.roughness_factor().clamp(0.0, 1.0);
    let strength = m.emissive_strength().unwrap_or(1.0).max(0.0);
    let emissive = Vec3::from(m.emissive_factor()).max(Vec3::ZERO) * strength;
    let values = [colour.max_element(), base[3], metallic, roughness, emissive.max_element()];
    let name = match m.index() {
        Some(i) => format!("materials[{i}]"),
        None => "the default material".to_owned(),
    };
    if !values.iter().all(|v| v.is_finite()) {
        return Err(origin.bad_asset(path, format!("{name} has non-finite factors")));
    }
    let transmission = m.transmission().map_or(0.0, |t| t.transmission_factor());
    let blended = m.alpha_mode() == gltf::material::AlphaMode::Blend && base[3] < 1.0;
    if transmission > 0.5 || blended {
        let ior = m.ior().filter(|i| i.is_finite() && *i > 0.0).unwrap_or(1.5);
        return Ok(Material::Dielectric { ior, tint: colour });
    }
    let mut map = |info: Option<gltf::texture::Info>, decode: Decode, slot: &str| -> Result<_, SceneError> {
        let Some(info) = info else { return Ok(None) };
        let what = format!("{name}.{slot}");
        texture_map(b, &info, decode, path, buffers, origin, &what).map(Some)
    };
    let base_texture = map(pbr.base_color_texture(), Decode::Srgb, "baseColorTexture")?;
    let metallic_roughness =
        map(pbr.metallic_roughness_texture(), Decode::Linear, "metallicRoughnessTexture")?;
    let emissive_texture = map(m.emissive_texture(), Decode::Srgb, "emissiveTexture")?;
    let masked = m.alpha_mode() == gltf::material::AlphaMode::Mask;
    let alpha_texture = match masked {
        true => map(pbr.base_color_texture(), Decode::Alpha, "baseColorTexture")?,
        false => None,
    };
    let normal_texture = match m.normal_texture() {
        Some(n) => {
            let texture = n.texture();
            let index = image_texture(b, &texture.source(), Decode::Linear, path, buffers, origin)?;
            let sampler = texture.sampler();
            Some(TextureMap {
                wrap: [wrap_mode(sampler.wrap_s()), wrap_mode(sampler.wrap_t())],
                set: u8::from(n.tex_coord() == 1),
                ..TextureMap::plain(index)
            })
        }
        None => None,
    };
    let normal_scale = m.normal_texture().map_or(1.0, |n| n.scale()).clamp(-100.0, 100.0);
    let alpha_cutoff = masked.then(|| m.alpha_cutoff().unwrap_or(0.5)).filter(|c| c.is_finite());
    Ok(Material::Pbr(Pbr {
        base_color: colour,
        base_texture,
        metallic,
        roughness,
        metallic_roughness,
        emissive,
        emissive_texture,
        normal_texture,
        normal_scale: if normal_scale.is_finite() { normal_scale } else { 1.0 },
        alpha_cutoff,
        alpha: base[3],
        alpha_texture,
    }))
}

/// How an image becomes a texture.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Decode {
    /// Colour, sRGB-encoded.
    Srgb,
    /// Data (metallic-roughness), its bytes scaled to 0..1.
    Linear,
    /// Its alpha channel, scaled to 0..1.
    Alpha,
}

/// A material's texture reference: the image (decoded as `decode` says),
/// its `KHR_texture_transform` and its sampler's wrap modes.
fn texture_map(
    b: &mut Builder,
    info: &gltf::texture::Info,
    decode: Decode,
    path: &str,
    buffers: &[Vec<u8>],
    origin: &Origin,
    what: &str,
) -> Result<TextureMap, SceneError> {
    let texture = info.texture();
    let index = image_texture(b, &texture.source(), decode, path, buffers, origin)?;
    let mut map = TextureMap::plain(index);
    let mut set = info.tex_coord();
    if let Some(t) = info.texture_transform() {
        let ([ox, oy], r, [sx, sy]) = (t.offset(), t.rotation(), t.scale());
        if ![ox, oy, r, sx, sy].iter().all(|v| v.is_finite()) {
            return Err(
                origin.bad_asset(path, format!("{what}: KHR_texture_transform has non-finite values"))
            );
        }
        let (sin, cos) = (math::sin(r), math::cos(r));
        map.transform = [Vec2::new(cos * sx, -sin * sx), Vec2::new(sin * sy, cos * sy), Vec2::new(ox, oy)];
        set = t.tex_coord().unwrap_or(set);
    }
    if set > 1 {
        b.warn(format!("{path}: {what} reads TEXCOORD_{set}: only TEXCOORD_0 and _1 are read; using _0"));
    }
    map.set = u8::from(set == 1);
    let sampler = texture.sampler();
    map.wrap = [wrap_mode(sampler.wrap_s()), wrap_mode(sampler.wrap_t())];
    Ok(map)
}

/// A glTF sampler wrap mode.
fn wrap_mode(mode: gltf::texture::WrappingMode) -> Wrap {
    match mode {
        gltf::texture::WrappingMode::ClampToEdge => Wrap::Clamp,
        gltf::texture::WrappingMode::MirroredRepeat => Wrap::Mirror,
        gltf::texture::WrappingMode::Repeat => Wrap::Repeat,
    }
}

/// The scene texture for a glTF image (embedded in a buffer view, a data URI
/// or a file), decoded once per file and image.
fn image_texture(
    b: &mut Builder,
    image: &gltf::Image,
    decode: Decode,
    path: &str,
    buffers: &[Vec<u8>],
    origin: &Origin,
) -> Result<u32, SceneError> {
    let suffix = match decode {
        Decode::Srgb => "",
        Decode::Linear => "#linear",
        Decode::Alpha => "#alpha",
    };
    let key = format!("{path}#image{}{suffix}", image.index());
    if let Some(i) = b.cached_image(&key) {
        return Ok(i);
    }
    let bytes = match image.source() {
        gltf::image::Source::Uri { uri, .. } if !uri.starts_with("data:") && decode == Decode::Srgb => {
            let rel = join(path, &percent_decode(uri));
            let what = Origin { at: origin.at.clone(), what: format!("{} (image in {path})", origin.what) };
            return b.image_texture(&rel, &what);
        }
        gltf::image::Source::Uri { uri, .. } if !uri.starts_with("data:") => {
            let rel = join(path, &percent_decode(uri));
            let what = Origin { at: origin.at.clone(), what: format!("{} (image in {path})", origin.what) };
            b.read_asset(&rel, &what)?
        }
        gltf::image::Source::Uri { uri, .. } => uri_bytes(b, path, uri, origin)?,
        gltf::image::Source::View { view, .. } => {
            let buffer = &buffers[view.buffer().index()];
            let range = view.offset()..view.offset().saturating_add(view.length());
            buffer
                .get(range)
                .ok_or_else(|| origin.bad_asset(path, format!("image {} exceeds its buffer", image.index())))?
                .to_vec()
        }
    };
    let decoded = match decode {
        Decode::Srgb => decode_image(&bytes),
        Decode::Linear => decode_image_linear(&bytes),
        Decode::Alpha => decode_image_alpha(&bytes),
    };
    let mip = decoded.map_err(|e| origin.bad_asset(path, format!("images[{}]: {e}", image.index())))?;
    b.add_image(key, mip)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What the `gltf` crates panic on is refused, named (found by fuzzing:
    /// `fuzz/regressions/gltf`, `glb`).
    #[test]
    fn images_without_a_source_and_missing_accessors_are_refused_not_panicked_on() {
        let doc = |images: &str, accessors: &str| {
            format!(
                r#"{{"asset":{{"version":"2.0"}},"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
                "images":{images},"accessors":{accessors}}}"#
            )
        };
        let accessor = r#"[{"componentType":5126,"count":1,"type":"VEC3","min":[0,0,0],"max":[0,0,0]}]"#;
        let err = |text: String| match parse(text.as_bytes()) {
            Err(e) => e,
            Ok(_) => panic!("not refused: {text}"),
        };
        assert!(
            err(doc(r#"[{"name":"x"}]"#, accessor)).contains("images[0] has neither a uri nor a bufferView")
        );
        let in_view = r#"[{"bufferView":0}]"#;
        assert!(err(doc(in_view, accessor)).contains("images[0] is in a buffer view but has no mimeType"));
        assert!(
            err(doc("[]", "[]")).contains("meshes[0].primitives[0] names accessor 0, but the file has 0")
        );
        let whole = gltf::Gltf::from_slice_without_validation(doc("[]", accessor).as_bytes()).unwrap();
        assert_eq!(check_unchecked(whole.document.as_json()), Ok(()));
    }

    #[test]
    fn base64_round_trips_known_vectors() {
        assert_eq!(base64_decode("").unwrap(), b"");
        assert_eq!(base64_decode("Zg==").unwrap(), b"f");
        assert_eq!(base64_decode("Zm8=").unwrap(), b"fo");
        assert_eq!(base64_decode("Zm9v").unwrap(), b"foo");
        assert_eq!(base64_decode("Zm9vYmFy").unwrap(), b"foobar");
        assert_eq!(base64_decode("Zm9vYg").unwrap(), b"foob");
        assert_eq!(base64_decode("AAEC/w==").unwrap(), [0, 1, 2, 255]);
        assert!(base64_decode("Zm9v!").is_err());
        assert!(base64_decode("Z").is_err());
        assert!(base64_decode("Zg==Zg").is_err());
    }

    #[test]
    fn percent_escapes_decode() {
        assert_eq!(percent_decode("my%20mesh.bin"), "my mesh.bin");
        assert_eq!(percent_decode("100%"), "100%");
    }

    #[test]
    fn impossible_glb_lengths_are_rejected() {
        assert!(check_glb_header(b"glTF\x02\0\0\0\x04\0\0\0").is_err());
        assert!(check_glb_header(b"glTF\x02\0").is_err());
        assert!(check_glb_header(b"{\"asset\":{}}").is_ok());
    }
}

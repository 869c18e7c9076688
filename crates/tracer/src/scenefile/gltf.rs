//! glTF 2.0 scenes (`.gltf` JSON or binary `.glb`) through the `gltf` crate.
//!
//! Buffers come from the GLB binary chunk, `data:` URIs (base64) or files read
//! through the scene's [`super::AssetSource`] (URIs relative to the glTF file).
//! Accessors are read by this module with every offset and length checked, so a
//! malformed file is an error, never a panic. All nodes of the default scene
//! are instanced with their full parent-to-child transform chain.
//!
//! Materials map to the nearest Whitted material: an emissive factor (without
//! an emissive texture) → emissive; `KHR_materials_transmission` above ½ or
//! blended alpha < 1 → dielectric (IOR from
//! `KHR_materials_ior` if present, else 1.5); metallic ≥ 0.9 with roughness ≤ 0.2
//! and no texture → mirror tinted by the base colour; otherwise Phong with the
//! base colour (or base-colour texture tinted by the factor) scaled by
//! `1 − metallic`, a specular colour between 4 % grey and the base colour by
//! metallic and dimmed by roughness, a Phong exponent `2/r⁴ − 2` from roughness
//! `r`, and a mirror reflection of weight `metallic · (1 − r)²`.

use super::SceneError;
use super::build::{Builder, Origin, Placement, decode_image, join};
use super::mesh_scene::{FileCamera, FileLight};
use crate::materials::{Albedo, Material};
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
    let file = parse(&bytes, path).map_err(bad)?;
    let doc = &file.document;

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
            let tris = read_primitive(&prim, &buffers).map_err(|e| bad(format!("{name}: {e}")))?;
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
/// `extensionsUsed` are a warning each (the file still renders, without them).
fn parse(bytes: &[u8], path: &str) -> Result<gltf::Gltf, String> {
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
    for ext in root.extensions_used.iter().filter(|e| !SUPPORTED_EXTENSIONS.contains(&e.as_str())) {
        tracing::warn!(file = path, extension = %ext, "glTF extension not supported; rendering without it");
    }
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
    Ok(file)
}

/// The first perspective camera and every punctual light of the default
/// scene of a glTF or GLB file, in world space.
pub(crate) fn cameras_and_lights(bytes: &[u8]) -> Result<(Option<FileCamera>, Vec<FileLight>), String> {
    let file = parse(bytes, "")?;
    let doc = &file.document;
    let Some(scene) = doc.default_scene().or_else(|| doc.scenes().next()) else {
        return Ok((None, Vec::new()));
    };
    let mut camera = None;
    let mut lights = Vec::new();
    let mut stack: Vec<(gltf::Node, Mat4, usize)> = scene.nodes().map(|n| (n, Mat4::IDENTITY, 0)).collect();
    let mut visited = 0;
    while let Some((node, parent, depth)) = stack.pop() {
        visited += 1;
        if depth > MAX_DEPTH || visited > MAX_INSTANCES {
            return Err("node hierarchy is too deep or cyclic".into());
        }
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        for child in node.children() {
            stack.push((child, world, depth + 1));
        }
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
/// 0..1 or −1..1), bounds-checked against its buffer view and buffer.
fn read_floats(acc: &gltf::Accessor, buffers: &[Vec<u8>], dims: usize) -> Result<Vec<f32>, String> {
    let normalize = acc.normalized();
    read_components(acc, buffers, dims, |ty, b| match ty {
        DataType::F32 => Some(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        DataType::U8 if normalize => Some(b[0] as f32 / 255.0),
        DataType::U16 if normalize => Some(u16::from_le_bytes([b[0], b[1]]) as f32 / 65535.0),
        DataType::I8 if normalize => Some((b[0] as i8 as f32 / 127.0).max(-1.0)),
        DataType::I16 if normalize => Some((i16::from_le_bytes([b[0], b[1]]) as f32 / 32767.0).max(-1.0)),
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

fn read_components<T>(
    acc: &gltf::Accessor,
    buffers: &[Vec<u8>],
    dims: usize,
    decode: impl Fn(DataType, &[u8]) -> Option<T>,
) -> Result<Vec<T>, String> {
    let name = format!("accessor {}", acc.index());
    let want = match dims {
        1 => Dimensions::Scalar,
        2 => Dimensions::Vec2,
        3 => Dimensions::Vec3,
        _ => Dimensions::Vec4,
    };
    if acc.dimensions() != want {
        return Err(format!("{name} has type {:?}, expected {want:?}", acc.dimensions()));
    }
    if acc.sparse().is_some() {
        return Err(format!("{name}: sparse accessors are not supported"));
    }
    let ty = acc.data_type();
    let size = ty.size();
    if decode(ty, &[0; 4]).is_none() {
        return Err(format!(
            "{name}: component type {ty:?} (normalized: {}) is not allowed here",
            acc.normalized()
        ));
    }
    let count = acc.count();
    if count == 0 {
        return Ok(Vec::new());
    }
    let view = acc.view().ok_or_else(|| format!("{name} has no buffer view"))?;
    let buffer = buffers.get(view.buffer().index()).ok_or_else(|| format!("{name}: no such buffer"))?;
    let view_start = view.offset();
    let view_end = view_start.checked_add(view.length()).filter(|&e| e <= buffer.len());
    let view_end =
        view_end.ok_or_else(|| format!("{name}: buffer view {} exceeds its buffer", view.index()))?;
    let elem = size * dims;
    let stride = view.stride().unwrap_or(elem);
    if stride < elem {
        return Err(format!("{name}: byte stride {stride} is smaller than an element ({elem} bytes)"));
    }
    let end = (count - 1)
        .checked_mul(stride)
        .and_then(|x| x.checked_add(elem))
        .and_then(|x| x.checked_add(acc.offset()))
        .and_then(|x| x.checked_add(view_start))
        .filter(|&e| e <= view_end)
        .ok_or_else(|| format!("{name}: {count} elements exceed buffer view {}", view.index()))?;
    let data = &buffer[view_start + acc.offset()..end];
    let mut out = Vec::with_capacity(count * dims);
    for i in 0..count {
        for c in 0..dims {
            let at = i * stride + c * size;
            out.extend(decode(ty, &data[at..at + size]));
        }
    }
    Ok(out)
}

/// A triangle primitive as a [`Mesh`] (in the node's space); `None` for points
/// and lines.
fn read_primitive(prim: &gltf::Primitive, buffers: &[Vec<u8>]) -> Result<Option<Mesh>, String> {
    use gltf::mesh::Mode;
    let mode = prim.mode();
    if !matches!(mode, Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) {
        return Ok(None);
    }
    let positions = prim.get(&gltf::Semantic::Positions).ok_or("no POSITION attribute")?;
    let positions: Vec<Vec3> =
        read_floats(&positions, buffers, 3)?.chunks_exact(3).map(Vec3::from_slice).collect();
    let n = positions.len();
    let normals = match prim.get(&gltf::Semantic::Normals) {
        Some(a) => read_floats(&a, buffers, 3)?
            .chunks_exact(3)
            .map(|c| Vec3::from_slice(c).normalize_or_zero())
            .collect(),
        None => Vec::new(),
    };
    let uvs = match prim.get(&gltf::Semantic::TexCoords(0)) {
        Some(a) => read_floats(&a, buffers, 2)?.chunks_exact(2).map(Vec2::from_slice).collect(),
        None => Vec::new(),
    };
    if normals.len() != n && !normals.is_empty() || uvs.len() != n && !uvs.is_empty() {
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
    Ok(Some(Mesh { positions, normals, uvs, indices }))
}

/// Maps a glTF PBR material to the nearest Whitted material.
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
    let emissive = Vec3::from(m.emissive_factor()).max(Vec3::ZERO);
    let values = [colour.max_element(), base[3], metallic, roughness, emissive.max_element()];
    if !values.iter().all(|v| v.is_finite()) {
        return Err(origin.bad_asset(path, format!("material {:?} has non-finite factors", m.index())));
    }
    if emissive.max_element() > 0.0 && m.emissive_texture().is_none() {
        return Ok(Material::Emissive { radiance: emissive * m.emissive_strength().unwrap_or(1.0) });
    }
    let transmission = m.transmission().map_or(0.0, |t| t.transmission_factor());
    let blended = m.alpha_mode() == gltf::material::AlphaMode::Blend && base[3] < 1.0;
    if transmission > 0.5 || blended {
        let ior = m.ior().filter(|i| i.is_finite() && *i > 0.0).unwrap_or(1.5);
        return Ok(Material::Dielectric { ior, tint: colour });
    }
    let texture = match pbr.base_color_texture() {
        Some(info) => Some(image_texture(b, &info.texture().source(), path, buffers, origin)?),
        None => None,
    };
    if metallic >= 0.9 && roughness <= 0.2 && texture.is_none() {
        return Ok(Material::Mirror { tint: colour });
    }
    let diffuse = colour * (1.0 - metallic);
    let albedo = match texture {
        Some(texture) => Albedo::Texture { texture, tint: diffuse },
        None => Albedo::Constant(diffuse),
    };
    let r = roughness.max(0.05);
    let shininess = (2.0 / math::powf(r, 4.0) - 2.0).clamp(1.0, 1000.0);
    let specular = Vec3::splat(0.04).lerp(colour, metallic) * (1.0 - roughness);
    let reflectivity = metallic * (1.0 - roughness) * (1.0 - roughness);
    Ok(Material::Phong { albedo, specular, shininess, reflectivity })
}

/// The scene texture for a glTF image (embedded in a buffer view, a data URI
/// or a file), decoded once per file and image.
fn image_texture(
    b: &mut Builder,
    image: &gltf::Image,
    path: &str,
    buffers: &[Vec<u8>],
    origin: &Origin,
) -> Result<u32, SceneError> {
    let bytes = match image.source() {
        gltf::image::Source::Uri { uri, .. } if !uri.starts_with("data:") => {
            let rel = join(path, &percent_decode(uri));
            let what = Origin { at: origin.at.clone(), what: format!("{} (image in {path})", origin.what) };
            return b.image_texture(&rel, &what);
        }
        gltf::image::Source::Uri { uri, .. } => uri_bytes(b, path, uri, origin)?,
        gltf::image::Source::View { view, .. } => {
            let key = format!("{path}#image{}", image.index());
            if let Some(i) = b.cached_image(&key) {
                return Ok(i);
            }
            let buffer = &buffers[view.buffer().index()];
            let range = view.offset()..view.offset().saturating_add(view.length());
            buffer
                .get(range)
                .ok_or_else(|| origin.bad_asset(path, format!("image {} exceeds its buffer", image.index())))?
                .to_vec()
        }
    };
    let key = format!("{path}#image{}", image.index());
    if let Some(i) = b.cached_image(&key) {
        return Ok(i);
    }
    let mip =
        decode_image(&bytes).map_err(|e| origin.bad_asset(path, format!("image {}: {e}", image.index())))?;
    b.add_image(key, mip)
}

#[cfg(test)]
mod tests {
    use super::*;

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

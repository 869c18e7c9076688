//! Wavefront OBJ meshes and their MTL material libraries (through `tobj`).
//!
//! `mtllib` paths are relative to the OBJ file and texture paths (`map_Kd`)
//! relative to the MTL file; everything is read through the scene's
//! [`super::AssetSource`]. A missing MTL library is only a warning (many OBJ
//! files name one that was never shipped): its materials become the default
//! grey. A missing texture is a warning too (the material keeps its `Kd`
//! colour); a malformed library or texture is an error. OBJ counts texture `v` upwards from the bottom of the
//! image, the tracer downwards from the top, so `v` is flipped.
//!
//! MTL materials map to the nearest Whitted material: `Ke` → emissive;
//! `illum` 4, 6, 7 or `d` < 1 (or `Tr` > 0) with `Ni` → dielectric (`Ni` as the index,
//! `Tf` as the tint); `illum` 3 with a black `Kd` → mirror tinted by `Ks`;
//! otherwise Phong with `Kd` (or `map_Kd` tinted by `Kd`), `Ks`, `Ns` and, for
//! `illum` 3, a mirror reflection weighted by `Ks`.

use super::SceneError;
use super::build::{Builder, Origin, Placement, Smoothing, join};
use super::smooth::smooth_normals;
use crate::materials::{Albedo, Material};
use crate::meshes::Mesh;
use glam::{Vec2, Vec3};
use std::cell::RefCell;
use std::collections::HashMap;
use std::path::Path;

/// Loads the OBJ file at `path` (relative to the scene file) into the scene.
pub(crate) fn load(
    b: &mut Builder,
    path: &str,
    origin: &Origin,
    placement: &Placement,
) -> Result<(), SceneError> {
    let bytes = b.read_asset(path, origin)?;
    vertex_references(&bytes).map_err(|e| origin.bad_asset(path, format!("OBJ: {e}")))?;
    // tobj's material loader is a `Fn`: route reads through a RefCell and
    // remember which library each material came from and why a read failed.
    let assets = RefCell::new(&mut *b.assets);
    let libraries: RefCell<Vec<(String, usize)>> = RefCell::new(Vec::new());
    let failure: RefCell<Option<SceneError>> = RefCell::new(None);
    let missing: RefCell<Vec<String>> = RefCell::new(Vec::new());
    let loader = |mtl: &Path| {
        let rel = join(path, &mtl.to_string_lossy());
        let result = match assets.borrow_mut().read(&rel) {
            Ok(data) => match grey_colours(&data) {
                Ok(data) => tobj::load_mtl_buf(&mut &data[..]).inspect_err(|e| {
                    failure.borrow_mut().get_or_insert(origin.bad_asset(&rel, format!("MTL library: {e}")));
                }),
                Err(e) => {
                    failure.borrow_mut().get_or_insert(origin.bad_asset(&rel, format!("MTL library: {e}")));
                    Err(tobj::LoadError::MaterialParseError)
                }
            },
            Err(reason) => {
                missing.borrow_mut().push(format!(
                    "{path}: MTL library {rel} cannot be read ({reason}); using default materials"
                ));
                Err(tobj::LoadError::OpenFileFailed)
            }
        };
        if let Ok((mats, _)) = &result {
            libraries.borrow_mut().push((rel, mats.len()));
        }
        result
    };
    let options =
        tobj::LoadOptions { triangulate: true, single_index: true, ignore_points: true, ignore_lines: true };
    let loaded = tobj::load_obj_buf(&mut bytes.as_slice(), &options, loader);
    if let Some(e) = failure.into_inner() {
        return Err(e);
    }
    // Real-world OBJ files often name a library that was never shipped (the
    // shared dragon does): a warning, and the default materials.
    let missing = missing.into_inner();
    for w in &missing {
        b.warn(w.clone());
    }
    let (models, materials) = loaded.map_err(|e| origin.bad_asset(path, format!("OBJ: {e}")))?;
    let materials = match materials {
        Ok(m) => m,
        Err(_) if !missing.is_empty() => Vec::new(),
        Err(e) => return Err(origin.bad_asset(path, format!("MTL: {e}"))),
    };
    // Which library each material index came from, to resolve its textures.
    let mut library_of = Vec::with_capacity(materials.len());
    for (lib, count) in libraries.into_inner() {
        library_of.extend(std::iter::repeat_n(lib, count));
    }

    // Smoothing groups, one per triangle in file order (the models' order).
    let total: usize = models.iter().map(|m| m.mesh.indices.len() / 3).sum();
    let groups = smoothing_groups(&bytes, total);
    if groups.is_none() && bytes.split(|&c| c == b'\n').any(|l| l.starts_with(b"s ")) {
        b.warn(format!("{path}: could not match the smoothing groups (s) to the faces; ignoring them"));
    }
    let mut first = 0;
    let mut mapped: HashMap<usize, u32> = HashMap::new();
    for model in &models {
        let m = &model.mesh;
        let mut mesh =
            to_mesh(m).map_err(|e| origin.bad_asset(path, format!("object `{}`: {e}", model.name)))?;
        let range = first..first + mesh.indices.len();
        first = range.end;
        if mesh.normals.is_empty() && !mesh.indices.is_empty() {
            let own = groups.as_ref().map(|g| &g[range]);
            let angle = match placement.smooth {
                Smoothing::On(angle) => Some(angle),
                Smoothing::Default if own.is_some_and(|g| g.iter().any(|&k| k != 0)) => Some(180.0),
                _ => None,
            };
            if let Some(angle) = angle {
                // An explicit `smooth` smooths faces the file left flat too.
                let own = own.filter(|g| g.iter().any(|&k| k != 0));
                mesh = smooth_normals(&mesh, own, angle);
            }
        }
        let material = match (placement.material, m.material_id) {
            (Some(over), _) => over,
            (None, Some(id)) if id < materials.len() => match mapped.get(&id) {
                Some(&i) => i,
                None => {
                    let lib = library_of.get(id).map_or(path, String::as_str).to_owned();
                    let mat = convert(b, &materials[id], &lib, origin)?;
                    let i = b.add_material(mat);
                    mapped.insert(id, i);
                    i
                }
            },
            _ => b.default_material(),
        };
        let placed = Placement { smooth: Smoothing::Off, ..*placement };
        b.emit(&mesh, &placed, material, origin)?;
    }
    Ok(())
}

/// The smoothing group (`s N`; `s off` and `s 0` are 0) of every triangle
/// the OBJ text's faces make, in file order, when the file has any `s`
/// statement and its faces make `triangles` triangles (as `tobj` fans them).
fn smoothing_groups(text: &[u8], triangles: usize) -> Option<Vec<u32>> {
    let text = String::from_utf8_lossy(text);
    if !text.lines().any(|l| l.trim_start().starts_with("s ")) {
        return None;
    }
    let mut group = 0;
    let mut out = Vec::with_capacity(triangles);
    for line in text.lines() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("s") => {
                group = match words.next() {
                    Some("off") | None => 0,
                    Some(g) => g.parse().unwrap_or(1),
                };
            }
            Some("f") => {
                let corners = words.count();
                out.extend(std::iter::repeat_n(group, corners.saturating_sub(2)));
            }
            _ => {}
        }
    }
    (out.len() == triangles).then_some(out)
}

/// A `tobj` mesh (single-indexed) as a [`Mesh`], `v` flipped.
fn to_mesh(m: &tobj::Mesh) -> Result<Mesh, String> {
    if m.positions.len() % 3 != 0 || m.indices.len() % 3 != 0 {
        return Err("malformed vertex or index arrays".into());
    }
    let positions: Vec<Vec3> = m.positions.chunks_exact(3).map(|p| Vec3::new(p[0], p[1], p[2])).collect();
    let n = positions.len();
    let normals = if m.normals.len() == 3 * n {
        m.normals.chunks_exact(3).map(|p| Vec3::new(p[0], p[1], p[2]).normalize_or_zero()).collect()
    } else {
        Vec::new()
    };
    let uvs = if m.texcoords.len() == 2 * n {
        m.texcoords.chunks_exact(2).map(|t| Vec2::new(t[0], 1.0 - t[1])).collect()
    } else {
        Vec::new()
    };
    let indices: Vec<[u32; 3]> = m.indices.chunks_exact(3).map(|i| [i[0], i[1], i[2]]).collect();
    if let Some(bad) = m.indices.iter().find(|&&i| i as usize >= n) {
        return Err(format!("vertex index {bad} out of range ({n} vertices)"));
    }
    Ok(Mesh { positions, normals, uvs, indices, ..Mesh::default() })
}

fn rgb(c: Option<[f32; 3]>) -> Option<Vec3> {
    c.map(Vec3::from)
}

fn parse_rgb(s: &str) -> Option<Vec3> {
    let v: Vec<f32> = s.split_whitespace().map(str::parse).collect::<Result<_, _>>().ok()?;
    match v.as_slice() {
        [g] => Some(Vec3::splat(*g)),
        [r, g, b] => Some(Vec3::new(*r, *g, *b)),
        _ => None,
    }
}

/// The texture file of a `map_Kd` statement, skipping options like `-s 1 1 1`.
fn texture_file(spec: &str) -> &str {
    let spec = spec.trim();
    if spec.starts_with('-') { spec.split_whitespace().last().unwrap_or(spec) } else { spec }
}

/// Maps an MTL material to the nearest Whitted material; `library` is the MTL
/// file's path (relative to the scene file), against which textures resolve.
fn convert(
    b: &mut Builder,
    m: &tobj::Material,
    library: &str,
    origin: &Origin,
) -> Result<Material, SceneError> {
    let bad = |what: &str| origin.bad_asset(library, format!("material `{}`: {what}", m.name));
    let finite = |v: Vec3| v.is_finite() && v.min_element() >= 0.0;
    let kd = rgb(m.diffuse).unwrap_or(Vec3::splat(0.7));
    let ks = rgb(m.specular).unwrap_or(Vec3::ZERO);
    let ke = rgb(m.emissive).unwrap_or(Vec3::ZERO);
    let tf = m.unknown_param.get("Tf").and_then(|s| parse_rgb(s)).unwrap_or(Vec3::ONE);
    if ![kd, ks, ke, tf].into_iter().all(finite) {
        return Err(bad("colours must be finite and non-negative"));
    }
    let ns = m.shininess.unwrap_or(1.0);
    let ni = m.optical_density.unwrap_or(1.5);
    // `Tr` (transparency) is the complement of `d`, which wins when both are given.
    let tr = m.unknown_param.get("Tr").and_then(|t| t.trim().parse::<f32>().ok());
    let d = m.dissolve.or(tr.map(|t| 1.0 - t)).unwrap_or(1.0);
    if !(ns.is_finite() && ni.is_finite() && d.is_finite()) {
        return Err(bad("Ns, Ni and d must be finite"));
    }
    let illum = m.illumination_model.unwrap_or(2);
    if ke.max_element() > 0.0 {
        return Ok(Material::Emissive { radiance: ke });
    }
    if matches!(illum, 4 | 6 | 7) || (d < 1.0 && m.optical_density.is_some()) {
        return Ok(Material::Dielectric { ior: if ni > 0.0 { ni } else { 1.5 }, tint: tf });
    }
    let texture = match &m.diffuse_texture {
        Some(spec) if !spec.trim().is_empty() => {
            let tex_path = join(library, texture_file(spec));
            let tex_origin =
                Origin { at: origin.at.clone(), what: format!("{} (map_Kd of `{}`)", origin.what, m.name) };
            match b.image_texture(&tex_path, &tex_origin) {
                Ok(t) => Some(t),
                // Exporters often reference textures that were never shipped:
                // the material keeps its Kd colour.
                Err(SceneError::MissingAsset { reason, .. }) => {
                    b.warn(format!(
                        "{}: texture {tex_path} (map_Kd of `{}`) cannot be read ({reason}); using Kd",
                        origin.what, m.name
                    ));
                    None
                }
                Err(e) => return Err(e),
            }
        }
        _ => None,
    };
    if illum == 3 && texture.is_none() && kd.max_element() < 0.05 {
        let tint = if ks.max_element() > 0.0 { ks } else { Vec3::ONE };
        return Ok(Material::Mirror { tint });
    }
    let albedo = match texture {
        Some(texture) => Albedo::Texture { texture, tint: rgb(m.diffuse).unwrap_or(Vec3::ONE) },
        None => Albedo::Constant(kd),
    };
    let reflectivity = if illum == 3 { ks.max_element().clamp(0.0, 1.0) } else { 0.0 };
    Ok(Material::Phong { albedo, specular: ks, shininess: ns.max(1.0), reflectivity })
}

/// The element kinds a face's `v/vt/vn` reference counts, as OBJ names them.
const ELEMENTS: [&str; 3] = ["v", "vt", "vn"];

/// Refuses face, line and point references (`f 1/2/3`, `f -1 -2 -3`) to an
/// element that does not exist: 0, a relative index reaching before the
/// first element, an absolute one past the file's last. tobj 4.0 turns such
/// an index into an offset with arithmetic that overflows (a panic where
/// overflow checks are on, a wrapped offset where not). A kind the file has
/// none of is left to tobj, which ignores references to it. One pass over
/// the bytes: the earliest bad reference is named, with its line.
fn vertex_references(obj: &[u8]) -> Result<(), String> {
    /// A reference to element `x` of a kind, on `line`, where `n` of the
    /// kind came before it.
    struct Bad<'a> {
        line: usize,
        word: &'a [u8],
        x: i64,
        n: u64,
    }
    let mut seen = [0u64; 3];
    // Per kind: the first reference that is bad whatever the file's count
    // (0, or before the first element), and the largest absolute one.
    let mut bad: [Option<Bad>; 3] = [None, None, None];
    let mut largest: [Option<Bad>; 3] = [None, None, None];
    for (line, raw) in obj.split(|&c| c == b'\n').enumerate() {
        let mut words = raw.split(u8::is_ascii_whitespace).filter(|w| !w.is_empty());
        match words.next() {
            Some(b"v") => seen[0] += 1,
            Some(b"vt") => seen[1] += 1,
            Some(b"vn") => seen[2] += 1,
            Some(b"f" | b"l" | b"p") => {
                for word in words {
                    for (k, part) in word.split(|&c| c == b'/').enumerate().take(3) {
                        // Malformed numbers are tobj's to refuse.
                        let Some(x) = std::str::from_utf8(part).ok().and_then(|p| p.parse::<i64>().ok())
                        else {
                            continue;
                        };
                        let here = Bad { line, word, x, n: seen[k] };
                        if x == 0 || (x < 0 && x.unsigned_abs() > seen[k]) {
                            bad[k].get_or_insert(here);
                        } else if x > 0 && largest[k].as_ref().is_none_or(|l| x > l.x) {
                            largest[k] = Some(here);
                        }
                    }
                }
            }
            _ => {}
        }
    }
    let total = seen;
    let past_the_last = largest.into_iter().zip(total).map(|(l, n)| l.filter(|l| l.x.unsigned_abs() > n));
    let earliest = (0..3)
        .zip(bad.into_iter().zip(past_the_last))
        .filter(|&(k, _)| total[k] > 0)
        .flat_map(|(k, (b, p))| [b, p].into_iter().flatten().map(move |b| (k, b)))
        .min_by_key(|(_, b)| b.line);
    let Some((k, b)) = earliest else { return Ok(()) };
    let (name, word) = (ELEMENTS[k], super::errors::excerpt(&String::from_utf8_lossy(b.word)));
    let (n, place) = if b.x < 0 { (b.n, " before it") } else { (total[k], "") };
    let plural = if n == 1 { "" } else { "s" };
    Err(format!(
        "line {}: `{word}` refers to {name} {}, but the file has {n} `{name}` line{plural}{place}",
        b.line + 1,
        b.x
    ))
}

/// The colour keys tobj reads as exactly three numbers.
const COLOUR_KEYS: [&str; 4] = ["Ka", "Kd", "Ks", "Ke"];

/// An MTL library as tobj can take it: a colour given as one number (grey,
/// as the format allows) is written out as three. A colour with no number or
/// two is refused, naming its line — tobj 4.0 panics on anything but three.
fn grey_colours(mtl: &[u8]) -> Result<std::borrow::Cow<'_, [u8]>, String> {
    let mut out: Option<Vec<u8>> = None;
    let mut at = 0;
    for (i, raw) in mtl.split(|&c| c == b'\n').enumerate() {
        let start = at;
        at += raw.len() + 1;
        // tobj refuses lines that are not UTF-8 itself.
        let Ok(line) = std::str::from_utf8(raw) else { continue };
        let mut words = line.split_whitespace();
        let Some(key) = words.next().filter(|k| COLOUR_KEYS.contains(k)) else { continue };
        let values: Vec<&str> = words.collect();
        match values[..] {
            [] | [_, _] => {
                return Err(format!(
                    "line {}: `{key}` takes one number (grey) or three, got {}",
                    i + 1,
                    values.len()
                ));
            }
            [grey] if grey.parse::<f32>().is_ok() => {
                let out = out.get_or_insert_with(|| mtl[..start].to_vec());
                out.extend_from_slice(format!("{key} {grey} {grey} {grey}\n").as_bytes());
                continue;
            }
            _ => {}
        }
        if let Some(out) = &mut out {
            out.extend_from_slice(&mtl[start..(start + raw.len() + 1).min(mtl.len())]);
        }
    }
    Ok(out.map_or(std::borrow::Cow::Borrowed(mtl), std::borrow::Cow::Owned))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grey_colours_are_written_out_and_malformed_ones_refused_by_line() {
        let mtl = b"newmtl a\nKd 0.5\nKs 1 0 0\n";
        assert_eq!(&grey_colours(mtl).unwrap()[..], b"newmtl a\nKd 0.5 0.5 0.5\nKs 1 0 0\n");
        assert!(matches!(grey_colours(b"Kd 1 2 3"), Ok(std::borrow::Cow::Borrowed(_))));
        // What tobj 4.0 panics on (found by fuzzing: fuzz/regressions/mtl).
        assert_eq!(
            grey_colours(b"newmtl a\nKa 1 0\n").unwrap_err(),
            "line 2: `Ka` takes one number (grey) or three, got 2"
        );
        assert!(grey_colours(b"Ke\n").unwrap_err().starts_with("line 1: `Ke`"));
        let (materials, _) =
            tobj::load_mtl_buf(&mut &grey_colours(b"newmtl g\nKd 0.25\n").unwrap()[..]).unwrap();
        assert_eq!(materials[0].diffuse, Some([0.25; 3]));
    }

    #[test]
    fn faces_referring_to_elements_that_do_not_exist_are_refused_by_line() {
        let head = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\n";
        let ok = |face: &str| vertex_references(format!("{head}{face}\n").as_bytes());
        assert_eq!(ok("f 1 2 3"), Ok(()));
        assert_eq!(ok("f -3/-1/-1 -2/1/1 -1//1"), Ok(()));
        // A kind the file has none of is tobj's to ignore.
        assert_eq!(vertex_references(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/5 2/5 3/5\n"), Ok(()));
        let e = ok("f 1/1/1 2/1/1 3/-3/0").unwrap_err();
        assert_eq!(e, "line 6: `3/-3/0` refers to vt -3, but the file has 1 `vt` line before it");
        assert!(ok("f 1 2 0").unwrap_err().contains("refers to v 0"));
        assert!(ok("f 1 2 4").unwrap_err().contains("refers to v 4, but the file has 3 `v` lines"), "{e}");
        assert!(ok("f 1//9223372036854775807 2 3").unwrap_err().contains("vn 9223372036854775807"));
        assert!(ok("l 1 -4").unwrap_err().starts_with("line 6:"));
        // Relative indices count what came before the face, not the file's total.
        let later = vertex_references(b"v 0 0 0\nf -1 -2 -3\nv 1 0 0\nv 0 1 0\n").unwrap_err();
        assert!(later.contains("refers to v -2, but the file has 1 `v` line before it"), "{later}");
    }

    #[test]
    fn smoothing_groups_follow_the_faces() {
        let obj = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\ns 1\nf 1 2 3 4\ns off\nf 1 2 3\ns 2\nf 1 3 4\n";
        assert_eq!(smoothing_groups(obj, 4), Some(vec![1, 1, 0, 2]));
        assert_eq!(smoothing_groups(obj, 5), None, "a count that does not match is not guessed at");
        assert_eq!(smoothing_groups(b"v 0 0 0\nf 1 1 1\n", 1), None, "no groups");
    }

    #[test]
    fn map_kd_options_are_skipped() {
        assert_eq!(texture_file("wood.png"), "wood.png");
        assert_eq!(texture_file(" -s 2 2 1 -bm 0.5 tex/wood.png "), "tex/wood.png");
    }

    #[test]
    fn colours_parse_as_grey_or_rgb() {
        assert_eq!(parse_rgb("0.5"), Some(Vec3::splat(0.5)));
        assert_eq!(parse_rgb("1 0.5 0"), Some(Vec3::new(1.0, 0.5, 0.0)));
        assert_eq!(parse_rgb("1 x 0"), None);
    }
}

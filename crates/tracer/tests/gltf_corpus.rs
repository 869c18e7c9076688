//! A corpus of small glTF files made here (JSON with the buffer and images in
//! `data:` URIs), each opened as a user would — a scene made around the file
//! ([`isin_tracer::scenefile::mesh_scene`]) — and rendered, with a check of
//! what must hold in the picture.

use isin_tracer::render::render_tile;
use isin_tracer::scenefile::{mesh_bounds, mesh_scene};
use isin_tracer::{AssetSource, Frame, RenderSettings, Scene, Tile, Vec3, load_scene};
use std::collections::HashMap;

/// Assets held in memory.
#[derive(Default, Clone)]
struct Mem(HashMap<String, Vec<u8>>);

impl AssetSource for Mem {
    fn read(&mut self, path: &str) -> Result<Vec<u8>, String> {
        self.0.get(path).cloned().ok_or_else(|| format!("no such file: {path}"))
    }
}

fn b64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for c in bytes.chunks(3) {
        let n = (c[0] as u32) << 16 | (*c.get(1).unwrap_or(&0) as u32) << 8 | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            out.push(if k <= c.len() { A[(n >> (18 - 6 * k) & 63) as usize] as char } else { '=' });
        }
    }
    out
}

fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// A PNG of `w × h` pixels from a function of the pixel, as a data URI.
fn png_uri(w: u32, h: u32, f: impl Fn(u32, u32) -> [u8; 4]) -> String {
    let img = image::RgbaImage::from_fn(w, h, |x, y| image::Rgba(f(x, y)));
    let mut out = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png).unwrap();
    format!("data:image/png;base64,{}", b64(&out))
}

/// Builds a glTF file: one buffer (a data URI), its views and accessors.
#[derive(Default)]
struct Builder {
    buffer: Vec<u8>,
    views: Vec<String>,
    accessors: Vec<String>,
}

impl Builder {
    /// Adds `bytes` as a buffer view and an accessor over it; returns the accessor's index.
    fn accessor(&mut self, bytes: &[u8], component: u32, count: usize, ty: &str, extra: &str) -> usize {
        while self.buffer.len() % 4 != 0 {
            self.buffer.push(0);
        }
        let offset = self.buffer.len();
        self.buffer.extend_from_slice(bytes);
        self.views.push(format!(r#"{{"buffer": 0, "byteOffset": {offset}, "byteLength": {}}}"#, bytes.len()));
        self.accessors.push(format!(
            r#"{{"bufferView": {}, "componentType": {component}, "count": {count}, "type": "{ty}"{extra}}}"#,
            self.views.len() - 1
        ));
        self.accessors.len() - 1
    }

    fn floats(&mut self, v: &[f32], dims: usize) -> usize {
        let ty = ["", "SCALAR", "VEC2", "VEC3", "VEC4"][dims];
        let extra = if dims == 3 {
            let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
            for p in v.chunks_exact(3) {
                for k in 0..3 {
                    lo[k] = lo[k].min(p[k]);
                    hi[k] = hi[k].max(p[k]);
                }
            }
            format!(r#", "min": {lo:?}, "max": {hi:?}"#)
        } else {
            String::new()
        };
        self.accessor(&f32_bytes(v), 5126, v.len() / dims, ty, &extra)
    }

    /// The file: `body` holds the rest of the top-level members (scenes,
    /// nodes, meshes, materials…), each followed by a comma.
    fn json(&self, body: &str) -> String {
        format!(
            r#"{{"asset": {{"version": "2.0"}}, {body}
  "accessors": [{}],
  "bufferViews": [{}],
  "buffers": [{{"byteLength": {}, "uri": "data:application/octet-stream;base64,{}"}}]}}"#,
            self.accessors.join(", "),
            self.views.join(", "),
            self.buffer.len(),
            b64(&self.buffer)
        )
    }
}

/// A unit cube centred on the origin: 24 vertices (4 per face, in the order
/// +X, −X, +Y, −Y, +Z, −Z) with normals and UVs, 36 u16 indices.
struct Cube {
    positions: Vec<f32>,
    normals: Vec<f32>,
    uvs: Vec<f32>,
    indices: Vec<u16>,
}

fn cube() -> Cube {
    let mut c = Cube { positions: Vec::new(), normals: Vec::new(), uvs: Vec::new(), indices: Vec::new() };
    let axes = [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z];
    for n in axes {
        let up = if n.y.abs() > 0.5 { Vec3::Z } else { Vec3::Y };
        let right = up.cross(n);
        let base = (c.positions.len() / 3) as u16;
        for (s, t) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)] {
            let p = n * 0.5 + right * (s - 0.5) + up * (0.5 - t);
            c.positions.extend_from_slice(&p.to_array());
            c.normals.extend_from_slice(&n.to_array());
            c.uvs.extend_from_slice(&[s, t]);
        }
        // (0,0) top-left, (1,0) top-right, (1,1) bottom-right: counter-clockwise seen from outside.
        c.indices.extend_from_slice(&[base, base + 2, base + 1, base, base + 3, base + 2]);
    }
    c
}

/// A cube glTF with `material` (JSON) and the top-level members `extra`
/// (e.g. `"textures": […], "images": […],`); `colours` are per-vertex RGBA.
fn cube_gltf(material: &str, extra: &str, colours: Option<&[f32]>) -> String {
    let c = cube();
    let mut b = Builder::default();
    let pos = b.floats(&c.positions, 3);
    let nor = b.floats(&c.normals, 3);
    let uv = b.floats(&c.uvs, 2);
    let idx_bytes: Vec<u8> = c.indices.iter().flat_map(|i| i.to_le_bytes()).collect();
    let idx = b.accessor(&idx_bytes, 5123, c.indices.len(), "SCALAR", "");
    let colour = colours.map(|v| format!(r#", "COLOR_0": {}"#, b.floats(v, 4))).unwrap_or_default();
    b.json(&format!(
        r#""scene": 0, "scenes": [{{"nodes": [0]}}], "nodes": [{{"mesh": 0}}],
  "meshes": [{{"primitives": [{{"attributes": {{"POSITION": {pos}, "NORMAL": {nor}, "TEXCOORD_0": {uv}{colour}}}, "indices": {idx}, "material": 0}}]}}],
  "materials": [{material}], {extra}"#
    ))
}

const SIZE: (u32, u32) = (64, 48);

/// Loads the scene made around `json` (as `model.gltf`).
fn scene_of(json: &str) -> Scene {
    let mut assets = Mem::default();
    assets.0.insert("model.gltf".into(), json.as_bytes().to_vec());
    let text = mesh_scene("model.gltf", &mut assets).unwrap_or_else(|e| panic!("{e}"));
    load_scene("made.toml", &text, &mut assets).unwrap_or_else(|e| panic!("{e}\n{text}"))
}

fn settings(scene: &Scene) -> RenderSettings {
    RenderSettings { width: SIZE.0, height: SIZE.1, spp: 1, light_samples: 4, ..scene.settings }
}

fn render(json: &str) -> Frame {
    let scene = scene_of(json);
    let s = settings(&scene);
    let rgb = render_tile(&scene, &scene.camera, &s, Tile { x: 0, y: 0, w: s.width, h: s.height });
    Frame { width: s.width, height: s.height, rgb }
}

fn pixel(f: &Frame, x: u32, y: u32) -> [u8; 3] {
    let i = ((y * f.width + x) * 3) as usize;
    [f.rgb[i], f.rgb[i + 1], f.rgb[i + 2]]
}

fn pixels(f: &Frame) -> impl Iterator<Item = [u8; 3]> + '_ {
    f.rgb.chunks_exact(3).map(|p| [p[0], p[1], p[2]])
}

/// True when channel `k` is bright and at least twice each other channel.
fn dominant(p: [u8; 3], k: usize) -> bool {
    p[k] > 50 && (0..3).all(|j| j == k || p[k] as u32 >= 2 * p[j] as u32)
}

fn centre(f: &Frame) -> [u8; 3] {
    pixel(f, f.width / 2, f.height / 2)
}

#[test]
fn a_base_colour_alone_gives_a_lit_rough_metal_of_that_colour() {
    // By the specification metallicFactor = roughnessFactor = 1 here.
    let f = render(&cube_gltf(
        r#"{"pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.05, 0.05, 1]}}"#,
        "",
        None,
    ));
    assert!(dominant(centre(&f), 0), "the rough metal cube is red, not black: {:?}", centre(&f));
    let dielectric = render(&cube_gltf(
        r#"{"pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.05, 0.05, 1], "metallicFactor": 0}}"#,
        "",
        None,
    ));
    assert!(dominant(centre(&dielectric), 0), "{:?}", centre(&dielectric));
}

#[test]
fn a_textured_cube_with_default_factors_shows_its_texture() {
    let extra = format!(
        r#""textures": [{{"source": 0}}], "images": [{{"uri": "{}"}}],"#,
        png_uri(4, 4, |_, _| [20, 200, 20, 255])
    );
    let material = r#"{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}"#;
    let f = render(&cube_gltf(material, &extra, None));
    assert!(dominant(centre(&f), 1), "green texture: {:?}", centre(&f));
}

#[test]
fn vertex_colours_multiply_the_base_colour() {
    // +X faces red, +Y green, +Z blue, the hidden faces white.
    let face = [[1.0, 0.05, 0.05], [1.0; 3], [0.05, 1.0, 0.05], [1.0; 3], [0.05, 0.05, 1.0], [1.0; 3]];
    let colours: Vec<f32> = face.iter().flat_map(|c| [c[0], c[1], c[2], 1.0].repeat(4)).collect();
    let f = render(&cube_gltf(r#"{"pbrMetallicRoughness": {"metallicFactor": 0}}"#, "", Some(&colours)));
    for (k, name) in ["red", "green", "blue"].iter().enumerate() {
        let n = pixels(&f).filter(|&p| dominant(p, k)).count();
        assert!(n > 30, "{n} {name} pixels: the COLOR_0 of a visible face shows");
    }
    let plain = render(&cube_gltf(r#"{"pbrMetallicRoughness": {"metallicFactor": 0}}"#, "", None));
    assert!(pixels(&plain).all(|p| !dominant(p, 2)), "without COLOR_0 nothing is blue");
}

/// A texture red on its left half, blue on its right.
fn halves_texture() -> String {
    let uri = png_uri(8, 8, |x, _| if x < 4 { [220, 20, 20, 255] } else { [20, 20, 220, 255] });
    format!(r#""textures": [{{"source": 0}}], "images": [{{"uri": "{uri}"}}],"#)
}

#[test]
fn a_texture_transform_moves_the_texture() {
    let material = |transform: &str| {
        format!(
            r#"{{"pbrMetallicRoughness": {{"metallicFactor": 0, "baseColorTexture": {{"index": 0{transform}}}}}}}"#
        )
    };
    let extra = format!(r#"{} "extensionsUsed": ["KHR_texture_transform"],"#, halves_texture());
    let plain = render(&cube_gltf(&material(""), &extra, None));
    let moved = render(&cube_gltf(
        &material(r#", "extensions": {"KHR_texture_transform": {"offset": [0.5, 0]}}"#),
        &extra,
        None,
    ));
    let (mut red_to_blue, mut blue_to_red) = (0, 0);
    for (a, b) in pixels(&plain).zip(pixels(&moved)) {
        red_to_blue += (dominant(a, 0) && dominant(b, 2)) as u32;
        blue_to_red += (dominant(a, 2) && dominant(b, 0)) as u32;
    }
    assert!(
        red_to_blue > 30 && blue_to_red > 30,
        "half a tile along u swaps the halves: {red_to_blue}, {blue_to_red}"
    );
}

#[test]
fn sampler_wrap_modes_are_honoured() {
    // UVs scaled by 2 about the origin: with clamping, the right half of
    // every face reads the texture's (blue) right edge; repeating shows red there again.
    let material = r#"{"pbrMetallicRoughness": {"metallicFactor": 0, "baseColorTexture": {"index": 0, "extensions": {"KHR_texture_transform": {"scale": [2, 1]}}}}}"#;
    let count = |sampler: &str| {
        let extra = halves_texture().replace(r#"{"source": 0}"#, r#"{"source": 0, "sampler": 0}"#);
        let extra =
            format!(r#"{extra} "samplers": [{sampler}], "extensionsUsed": ["KHR_texture_transform"],"#);
        let f = render(&cube_gltf(material, &extra, None));
        (pixels(&f).filter(|&p| dominant(p, 0)).count(), pixels(&f).filter(|&p| dominant(p, 2)).count())
    };
    let (red_repeat, _) = count(r#"{"wrapS": 10497}"#);
    let (red_clamp, blue_clamp) = count(r#"{"wrapS": 33071}"#);
    assert!(blue_clamp > 2 * red_clamp, "clamped: mostly the blue edge ({red_clamp} red, {blue_clamp} blue)");
    assert!(red_repeat > red_clamp + 30, "repeated: red again ({red_repeat} vs {red_clamp})");
}

#[test]
fn a_metallic_roughness_texture_scales_the_factors_blue_metal_green_rough() {
    // Blue = 1 (metal), green = 0 (smooth) over factors 1, 1: the same as
    // factors 1, 0 without a texture — a red mirror, not red paint.
    let extra = format!(
        r#""textures": [{{"source": 0}}], "images": [{{"uri": "{}"}}],"#,
        png_uri(2, 2, |_, _| [0, 0, 255, 255])
    );
    let paint = r#"{"pbrMetallicRoughness": {"baseColorFactor": [0.9, 0.1, 0.1, 1], "metallicFactor": 0}}"#;
    let mirror = r#"{"pbrMetallicRoughness": {"baseColorFactor": [0.9, 0.1, 0.1, 1], "roughnessFactor": 0}}"#;
    let mapped = r#"{"pbrMetallicRoughness": {"baseColorFactor": [0.9, 0.1, 0.1, 1], "metallicRoughnessTexture": {"index": 0}}}"#;
    let paint = render(&cube_gltf(paint, "", None));
    let mirror = render(&cube_gltf(mirror, "", None));
    let mapped = render(&cube_gltf(mapped, &extra, None));
    let differing =
        |a: &Frame, b: &Frame| a.rgb.iter().zip(&b.rgb).filter(|(x, y)| x.abs_diff(**y) > 1).count();
    assert!(differing(&paint, &mirror) > 300, "paint and mirror look different");
    assert!(differing(&mapped, &mirror) < 10, "the texture made it the mirror");
}

#[test]
fn a_smooth_metal_mirrors_its_surroundings_tinted_by_its_base_colour() {
    let red_metal =
        r#"{"pbrMetallicRoughness": {"baseColorFactor": [0.9, 0.1, 0.05, 1], "roughnessFactor": 0}}"#;
    let f = render(&cube_gltf(red_metal, "", None));
    let tinted: Vec<[u8; 3]> = pixels(&f).filter(|&p| dominant(p, 0)).collect();
    assert!(tinted.len() > 150, "{} red pixels", tinted.len());
    // What the faces mirror (sky, ground, the cube's shadow) varies: not one flat patch.
    let mut distinct = tinted.clone();
    distinct.sort();
    distinct.dedup();
    assert!(distinct.len() > 20, "{} distinct reds", distinct.len());
}

#[test]
fn emissive_factor_and_strength_light_up_a_surface() {
    let dark = r#"{"pbrMetallicRoughness": {"baseColorFactor": [0, 0, 0, 1], "metallicFactor": 0}}"#;
    let glowing = r#"{"pbrMetallicRoughness": {"baseColorFactor": [0, 0, 0, 1], "metallicFactor": 0}, "emissiveFactor": [0, 0.2, 0], "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 4}}}"#;
    let a = centre(&render(&cube_gltf(dark, "", None)));
    let b = centre(&render(&cube_gltf(glowing, "", None)));
    assert!(a[1] < 40, "{a:?}");
    assert!(dominant(b, 1) && b[1] > 200, "0.2 × 4 green emission: {b:?}");
}

/// A unit square in the XY plane centred on the origin, facing +Z, `u`
/// along +X, with `material` and the top-level members `extra`.
fn square_gltf(material: &str, extra: &str) -> String {
    let mut b = Builder::default();
    let pos = b.floats(&[-0.5, -0.5, 0.0, 0.5, -0.5, 0.0, 0.5, 0.5, 0.0, -0.5, 0.5, 0.0], 3);
    let nor = b.floats(&[0.0, 0.0, 1.0].repeat(4), 3);
    let uv = b.floats(&[0.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0], 2);
    let idx: Vec<u8> = [0u16, 1, 2, 0, 2, 3].iter().flat_map(|i| i.to_le_bytes()).collect();
    let idx = b.accessor(&idx, 5123, 6, "SCALAR", "");
    b.json(&format!(
        r#""scenes": [{{"nodes": [0]}}], "nodes": [{{"mesh": 0, "translation": [0, 0.6, 0]}}],
  "meshes": [{{"primitives": [{{"attributes": {{"POSITION": {pos}, "NORMAL": {nor}, "TEXCOORD_0": {uv}}}, "indices": {idx}, "material": 0}}]}}],
  "materials": [{material}], {extra}"#
    ))
}

#[test]
fn an_alpha_mask_cuts_out_what_camera_and_shadow_rays_pass_through() {
    // Red; transparent on the left half (u < ½), opaque on the right.
    let uri = png_uri(8, 8, |x, _| [230, 20, 20, if x < 4 { 0 } else { 255 }]);
    let extra = format!(r#""textures": [{{"source": 0}}], "images": [{{"uri": "{uri}"}}],"#);
    let material = |mode: &str| {
        format!(
            r#"{{"alphaMode": "{mode}", "pbrMetallicRoughness": {{"metallicFactor": 0, "baseColorTexture": {{"index": 0}}}}}}"#
        )
    };
    let red = |f: &Frame| pixels(f).filter(|&p| dominant(p, 0)).count();
    let opaque = red(&render(&square_gltf(&material("OPAQUE"), &extra)));
    let masked = red(&render(&square_gltf(&material("MASK"), &extra)));
    assert!(opaque > 200, "{opaque}");
    assert!(
        masked * 10 > opaque * 3 && masked * 10 < opaque * 7,
        "about half is cut out: {masked} of {opaque}"
    );
    // Rays through the left half pass; through the right half they stop, shadow rays too.
    let scene = scene_of(&square_gltf(&material("MASK"), &extra));
    let towards = |x: f32| isin_tracer::geometry::Ray::new(Vec3::new(x, 0.6, 2.0), -Vec3::Z);
    assert!(!scene.occluded_visible(&towards(-0.25), 0.0, 3.0), "the cut-out lets light through");
    assert!(scene.occluded_visible(&towards(0.25), 0.0, 3.0));
    assert!(scene.intersect_visible(&towards(-0.25), 0.0, 3.0).is_none(), "nothing else on that line");
    let hit = scene.intersect_visible(&towards(0.25), 0.0, 3.0).unwrap();
    assert!((hit.t - 2.0).abs() < 1e-4);
    let opaque_scene = scene_of(&square_gltf(&material("OPAQUE"), &extra));
    assert!(opaque_scene.occluded_visible(&towards(-0.25), 0.0, 3.0), "OPAQUE ignores alpha");
    // A constant alpha below the cutoff cuts out everything, textures or not.
    let gone = r#"{"alphaMode": "MASK", "alphaCutoff": 0.6, "pbrMetallicRoughness": {"baseColorFactor": [1, 0, 0, 0.5]}}"#;
    assert_eq!(red(&render(&square_gltf(gone, ""))), 0);
}

#[test]
fn a_normal_map_changes_the_shading() {
    let with_map = |rgb: [u8; 3]| {
        let extra = format!(
            r#""textures": [{{"source": 0}}], "images": [{{"uri": "{}"}}],"#,
            png_uri(4, 4, |_, _| [rgb[0], rgb[1], rgb[2], 255])
        );
        let material = r#"{"pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.8, 0.8, 1], "metallicFactor": 0}, "normalTexture": {"index": 0}}"#;
        render(&square_gltf(material, &extra))
    };
    let plain = render(&square_gltf(
        r#"{"pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.8, 0.8, 1], "metallicFactor": 0}}"#,
        "",
    ));
    let diff =
        |a: &Frame, b: &Frame| a.rgb.iter().zip(&b.rgb).map(|(x, y)| x.abs_diff(*y) as u32).max().unwrap();
    let flat = with_map([128, 128, 255]);
    assert!(diff(&flat, &plain) <= 3, "a flat normal map is (nearly) no map: {}", diff(&flat, &plain));
    let (left, right) = (with_map([38, 128, 217]), with_map([217, 128, 217]));
    let (up, down) = (with_map([128, 217, 217]), with_map([128, 38, 217]));
    for (name, f) in [("left", &left), ("right", &right), ("up", &up), ("down", &down)] {
        assert!(diff(f, &plain) > 20, "tilted {name}: the shading changes ({})", diff(f, &plain));
    }
    assert!(diff(&left, &right) > 20 && diff(&up, &down) > 20, "opposite tilts differ");
    // The key light stands above and to the left: normals tilted towards it
    // (red low: −u, to the left; green high: −v, up) catch more of it.
    let light = |f: &Frame| f.rgb.iter().map(|&c| c as u64).sum::<u64>();
    assert!(light(&left) > light(&right), "left {} vs right {}", light(&left), light(&right));
    assert!(light(&up) > light(&down), "up {} vs down {}", light(&up), light(&down));
}

#[test]
fn textures_may_read_the_second_texture_coordinates() {
    // TEXCOORD_0 pins the square to the texture's red left edge; TEXCOORD_1 spans it.
    let mut b = Builder::default();
    let pos = b.floats(&[-0.5, -0.5, 0.0, 0.5, -0.5, 0.0, 0.5, 0.5, 0.0, -0.5, 0.5, 0.0], 3);
    let uv0 = b.floats(&[0.1, 0.5].repeat(4), 2);
    let uv1 = b.floats(&[0.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0], 2);
    let idx: Vec<u8> = [0u16, 1, 2, 0, 2, 3].iter().flat_map(|i| i.to_le_bytes()).collect();
    let idx = b.accessor(&idx, 5123, 6, "SCALAR", "");
    let json = |set: u32| {
        b.json(&format!(
            r#""scenes": [{{"nodes": [0]}}], "nodes": [{{"mesh": 0, "translation": [0, 0.6, 0]}}],
  "meshes": [{{"primitives": [{{"attributes": {{"POSITION": {pos}, "TEXCOORD_0": {uv0}, "TEXCOORD_1": {uv1}}}, "indices": {idx}, "material": 0}}]}}],
  "materials": [{{"pbrMetallicRoughness": {{"metallicFactor": 0, "baseColorTexture": {{"index": 0, "texCoord": {set}}}}}}}], {}"#,
            halves_texture()
        ))
    };
    let blue = |f: &Frame| pixels(f).filter(|&p| dominant(p, 2)).count();
    let red = |f: &Frame| pixels(f).filter(|&p| dominant(p, 0)).count();
    let (first, second) = (render(&json(0)), render(&json(1)));
    assert!(red(&first) > 200 && blue(&first) == 0, "set 0: all red");
    assert!(
        red(&second) > 100 && blue(&second) > 100,
        "set 1: both halves ({}, {})",
        red(&second),
        blue(&second)
    );
}

#[test]
fn unsupported_required_extensions_are_refused_by_name() {
    let json = cube_gltf(
        "{}",
        r#""extensionsUsed": ["KHR_draco_mesh_compression", "EXT_foo"], "extensionsRequired": ["KHR_draco_mesh_compression"],"#,
        None,
    );
    let mut assets = Mem::default();
    assets.0.insert("model.gltf".into(), json.into_bytes());
    let e = mesh_scene("model.gltf", &mut assets).unwrap_err().to_string();
    for part in ["model.gltf", "KHR_draco_mesh_compression", "requires"] {
        assert!(e.contains(part), "{part} missing from: {e}");
    }
    assert!(!e.contains("EXT_foo"), "only the required ones: {e}");
    // Only used, not required: the file loads, with one warning naming it.
    let json = cube_gltf("{}", r#""extensionsUsed": ["EXT_foo"],"#, None);
    assets.0.insert("model.gltf".into(), json.into_bytes());
    let text = mesh_scene("model.gltf", &mut assets).unwrap();
    let parts = isin_tracer::parse_scene("made.toml", &text, &mut assets).unwrap();
    let named: Vec<_> = parts.warnings.iter().filter(|w| w.contains("EXT_foo")).collect();
    assert_eq!(named.len(), 1, "{:?}", parts.warnings);
    assert_eq!(parts.warnings.len(), 1, "the made scene has lights: {:?}", parts.warnings);
}

/// The bounds of the mesh in `json`.
fn bounds(json: &str) -> (Vec3, Vec3) {
    let mut assets = Mem::default();
    assets.0.insert("m.gltf".into(), json.as_bytes().to_vec());
    let b = mesh_bounds("m.gltf", &mut assets).unwrap_or_else(|e| panic!("{e}"));
    (b.min, b.max)
}

/// A one-triangle mesh whose positions are accessor `pos`, with top-level `extra`.
fn triangle_gltf(b: &Builder, pos: usize, node: &str, mode: u32, extra: &str) -> String {
    b.json(&format!(
        r#""scenes": [{{"nodes": [0]}}], "nodes": [{{"mesh": 0{node}}}],
  "meshes": [{{"primitives": [{{"attributes": {{"POSITION": {pos}}}, "mode": {mode}}}]}}], {extra}"#
    ))
}

#[test]
fn sparse_accessors_replace_elements_of_their_base() {
    let mut b = Builder::default();
    let pos = b.floats(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0], 3);
    let idx = b.accessor(&1u16.to_le_bytes(), 5123, 1, "SCALAR", "");
    let val = b.floats(&[4.0, 0.0, 0.0], 3);
    // Point the sparse block at the index and value views just added.
    let (iv, vv) = (idx, val); // one view per accessor, in order
    let sparse = format!(
        r#", "sparse": {{"count": 1, "indices": {{"bufferView": {iv}, "componentType": 5123}}, "values": {{"bufferView": {vv}}}}}"#
    );
    b.accessors[pos] = b.accessors[pos].replacen('}', &format!("{sparse}}}"), 1);
    let b_json = triangle_gltf(&b, pos, "", 4, "");
    let (lo, hi) = bounds(&b_json);
    assert_eq!((lo, hi), (Vec3::ZERO, Vec3::new(4.0, 1.0, 0.0)), "vertex 1 moved to x = 4");
    // Indices beyond the accessor are an error naming it.
    let bad = b_json.replace(r#""count": 3, "type": "VEC3""#, r#""count": 1, "type": "VEC3""#);
    let mut assets = Mem::default();
    assets.0.insert("m.gltf".into(), bad.into_bytes());
    let e = mesh_bounds("m.gltf", &mut assets).unwrap_err().to_string();
    assert!(e.contains("accessors[0].sparse") && e.contains("out of range"), "{e}");
}

#[test]
fn quantized_integer_positions_load_with_mesh_quantization() {
    let mut b = Builder::default();
    let q: Vec<u8> = [0u16, 0, 0, 100, 0, 0, 0, 200, 0, 0].iter().flat_map(|v| v.to_le_bytes()).collect();
    let pos = b.accessor(&q[..18], 5123, 3, "VEC3", r#", "min": [0, 0, 0], "max": [100, 200, 0]"#);
    let node = r#", "scale": [0.01, 0.01, 0.01]"#;
    let used =
        r#""extensionsUsed": ["KHR_mesh_quantization"], "extensionsRequired": ["KHR_mesh_quantization"],"#;
    let (lo, hi) = bounds(&triangle_gltf(&b, pos, node, 4, used));
    assert!(
        (lo - Vec3::ZERO).length() < 1e-6 && (hi - Vec3::new(1.0, 2.0, 0.0)).length() < 1e-6,
        "{lo} {hi}"
    );
    // Without the extension plain integers are not positions.
    let mut assets = Mem::default();
    assets.0.insert("m.gltf".into(), triangle_gltf(&b, pos, node, 4, "").into_bytes());
    let e = mesh_bounds("m.gltf", &mut assets).unwrap_err().to_string();
    assert!(e.contains("accessors[0]") && e.contains("not allowed"), "{e}");
}

#[test]
fn strips_fans_and_unindexed_lists_make_triangles() {
    let mut b = Builder::default();
    let quad = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 0.0];
    let pos = b.floats(&quad, 3);
    for (mode, want) in [(5, 2), (6, 2), (4, 1)] {
        let json = triangle_gltf(&b, pos, "", mode, "");
        let mut assets = Mem::default();
        assets.0.insert("m.gltf".into(), json.into_bytes());
        let text = mesh_scene("m.gltf", &mut assets).unwrap();
        let scene = load_scene("made.toml", &text, &mut assets).unwrap();
        // The made scene adds a ground quad (2 triangles).
        assert_eq!(scene.triangles.len() - 2, want, "mode {mode}");
    }
}

#[test]
fn negative_scale_nodes_keep_triangles_facing_out() {
    let c = cube();
    let mut b = Builder::default();
    let pos = b.floats(&c.positions, 3);
    let idx_bytes: Vec<u8> = c.indices.iter().flat_map(|i| i.to_le_bytes()).collect();
    let idx = b.accessor(&idx_bytes, 5123, c.indices.len(), "SCALAR", "");
    let json = b.json(&format!(
        r#""scenes": [{{"nodes": [0]}}], "nodes": [{{"mesh": 0, "scale": [-1, 1, 1], "translation": [5, 0, 0]}}],
  "meshes": [{{"primitives": [{{"attributes": {{"POSITION": {pos}}}, "indices": {idx}}}]}}],"#
    ));
    let mut assets = Mem::default();
    assets.0.insert("m.gltf".into(), json.into_bytes());
    let scene =
        load_scene("s.toml", "[[objects]]\nkind = \"gltf\"\npath = \"m.gltf\"\n", &mut assets).unwrap();
    assert_eq!(scene.triangles.len(), 12);
    for t in &scene.triangles {
        let outward = (t.v[0] + t.v[1] + t.v[2]) / 3.0 - Vec3::new(5.0, 0.0, 0.0);
        assert!(t.normal().dot(outward) > 0.0, "a mirrored cube's triangles still face out");
    }
}

#[test]
fn the_files_own_camera_and_lights_make_the_scene() {
    let c = cube();
    let mut b = Builder::default();
    let pos = b.floats(&c.positions, 3);
    // A camera 10 units up +Z looking down −Z; a red point light and a directional light.
    let json = b.json(&format!(
        r#""scenes": [{{"nodes": [0, 1, 2, 3]}}],
  "nodes": [{{"mesh": 0}}, {{"camera": 0, "translation": [0, 0, 10]}},
            {{"translation": [0, 3, 0], "extensions": {{"KHR_lights_punctual": {{"light": 0}}}}}},
            {{"rotation": [-0.70710678, 0, 0, 0.70710678], "extensions": {{"KHR_lights_punctual": {{"light": 1}}}}}}],
  "cameras": [{{"type": "perspective", "perspective": {{"yfov": 0.5, "aspectRatio": 2.0, "znear": 0.1}}}}],
  "extensionsUsed": ["KHR_lights_punctual"],
  "extensions": {{"KHR_lights_punctual": {{"lights": [{{"type": "point", "color": [1, 0, 0], "intensity": 20}}, {{"type": "directional", "intensity": 3}}]}}}},
  "meshes": [{{"primitives": [{{"attributes": {{"POSITION": {pos}}}, "mode": 4}}]}}],"#
    ));
    let mut assets = Mem::default();
    assets.0.insert("m.gltf".into(), json.into_bytes());
    let text = mesh_scene("m.gltf", &mut assets).unwrap();
    let scene = load_scene("made.toml", &text, &mut assets).unwrap();
    assert!((scene.camera.eye - Vec3::new(0.0, 0.0, 10.0)).length() < 1e-5, "{text}");
    assert!((scene.camera.forward() - -Vec3::Z).length() < 1e-5);
    assert_eq!((scene.settings.width, scene.settings.height), (640, 320), "the camera's aspect ratio");
    let vfov = 2.0 * (scene.camera.plane_y().length() * 0.5).atan2(scene.camera.eye_distance());
    assert!((vfov - 0.5).abs() < 1e-4, "yfov kept: {vfov}");
    use isin_tracer::lights::Light;
    let points: Vec<_> = scene
        .lights
        .iter()
        .filter_map(|l| match l {
            Light::Point { position, intensity } => Some((*position, *intensity)),
            _ => None,
        })
        .collect();
    assert_eq!(points.len(), 2, "{text}");
    assert!(
        (points[0].0 - Vec3::new(0.0, 3.0, 0.0)).length() < 1e-5 && points[0].1 == Vec3::new(20.0, 0.0, 0.0)
    );
    // The directional light shines down (−Z turned to −Y): it stands far above.
    assert!(points[1].0.y > 100.0 && points[1].0.x.abs() < 1e-3, "{:?}", points[1]);
    assert!(!text.contains("name = \"ground\""), "a composed scene gets no ground plane");
}

#[test]
fn a_mesh_without_camera_or_lights_is_framed_and_lit() {
    let scene = scene_of(&cube_gltf("{}", "", None));
    assert!(!scene.lights.is_empty());
    let to_centre = (Vec3::ZERO - scene.camera.eye).normalize();
    assert!(to_centre.dot(scene.camera.forward()) > 0.999, "looks at the cube's centre");
    assert!(
        scene.camera.eye.x > 0.0 && scene.camera.eye.y > 0.0 && scene.camera.eye.z > 0.0,
        "three-quarter view"
    );
}

#[test]
fn corpus_renders_are_identical_across_tilings_and_threads() {
    let face = [[1.0, 0.2, 0.2], [1.0; 3], [0.2, 1.0, 0.2], [1.0; 3], [0.2, 0.2, 1.0], [1.0; 3]];
    let colours: Vec<f32> = face.iter().flat_map(|c| [c[0], c[1], c[2], 1.0].repeat(4)).collect();
    let extra = format!(r#"{} "extensionsUsed": ["KHR_texture_transform"],"#, halves_texture());
    let material = r#"{"pbrMetallicRoughness": {"metallicFactor": 0.5, "roughnessFactor": 0.3, "baseColorTexture": {"index": 0, "extensions": {"KHR_texture_transform": {"rotation": 0.3, "scale": [2, 2]}}}}, "emissiveFactor": [0.02, 0, 0]}"#;
    let textured = scene_of(&cube_gltf(material, &extra, Some(&colours)));
    let uri = png_uri(8, 8, |x, y| [230, 20, 20, if (x + y) % 3 == 0 { 0 } else { 255 }]);
    let extra = format!(
        r#""textures": [{{"source": 0, "sampler": 0}}], "images": [{{"uri": "{uri}"}}], "samplers": [{{"wrapS": 33648}}],"#
    );
    let masked = r#"{"alphaMode": "MASK", "pbrMetallicRoughness": {"roughnessFactor": 0.2, "baseColorTexture": {"index": 0}}, "normalTexture": {"index": 0, "scale": 0.5}}"#;
    let masked = scene_of(&square_gltf(masked, &extra));
    for (name, scene) in [("textured cube", textured), ("cut-out, normal-mapped square", masked)] {
        let s = RenderSettings { spp: 2, ..settings(&scene) };
        let (w, h) = (s.width, s.height);
        let whole = render_tile(&scene, &scene.camera, &s, Tile { x: 0, y: 0, w, h });
        let mut tiled = Frame::new(w, h);
        for y in (0..h).step_by(5) {
            for x in (0..w).step_by(7) {
                let tile = Tile { x, y, w: 7.min(w - x), h: 5.min(h - y) };
                tiled.blit(tile, &render_tile(&scene, &scene.camera, &s, tile));
            }
        }
        assert_eq!(tiled.rgb, whole, "{name}: 7×5 tiles");
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let f = pool.install(|| isin_tracer::render_frame(&scene, &scene.camera, &s, 16, &|_| {}));
            assert_eq!(f.rgb, whole, "{name}: {threads} threads");
        }
        let options = isin_tracer::render::TraceOptions { packets: false, ..Default::default() };
        let (single, _) =
            isin_tracer::render::render_frame_with(&scene, &scene.camera, &s, 16, &options, &|_| {});
        assert_eq!(single.rgb, whole, "{name}: single rays as packets");
        assert!(whole.iter().any(|&b| b != whole[0]));
    }
}

#[test]
fn a_scene_made_around_a_mesh_travels_as_a_bundle_and_renders_the_same_bytes() {
    let json = cube_gltf(r#"{"pbrMetallicRoughness": {"baseColorFactor": [0.2, 0.6, 0.9, 1]}}"#, "", None);
    let mut assets = Mem::default();
    assets.0.insert("m/model.gltf".into(), json.into_bytes());
    let text = mesh_scene("m/model.gltf", &mut assets).unwrap();
    let local = load_scene("made", &text, &mut assets.clone()).unwrap();
    // What a slave gets: the text and the bytes, serialised.
    let bundle = isin_tracer::SceneBundle {
        name: "made".into(),
        source: text,
        assets: assets.0.into_iter().collect(),
    };
    let shipped: isin_tracer::SceneBundle =
        rmp_serde::from_slice(&rmp_serde::to_vec(&bundle).unwrap()).unwrap();
    let remote = shipped.load().unwrap();
    let s = settings(&local);
    let tile = Tile { x: 0, y: 0, w: s.width, h: s.height };
    let a = render_tile(&local, &local.camera, &s, tile);
    assert_eq!(a, render_tile(&remote, &remote.camera, &s, tile));
    assert!(a.iter().any(|&b| b != a[0]));
}

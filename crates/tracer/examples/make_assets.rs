//! Generates the procedural assets that the scenes in `scenes/` use:
//!
//! - `scenes/textures/wood.png` and `scenes/textures/bricks.png` (256 × 256, sRGB),
//! - `scenes/meshes/knot.obj` + `knot.mtl`: a (2, 3) torus knot tube with smooth
//!   normals and texture coordinates,
//! - `scenes/meshes/gem.gltf`: a subdivided icosahedron under a two-level node
//!   hierarchy, its buffer embedded as a base64 `data:` URI;
//! - `scenes/meshes/materials.gltf`: five spheres in a row, one per kind of glTF
//!   material — a base colour alone (by the specification's defaults a rough
//!   metal), polished gold, blue plastic, vertex colours (`COLOR_0`) and a
//!   checker texture (a PNG in the buffer) under a `KHR_texture_transform` —
//!   for `isin render scenes/meshes/materials.gltf` (README, "Bring your own scene").
//!
//! Run from the repository root: `cargo run -p isin-tracer --example make_assets`.
//! The output is deterministic; the files are committed.

use std::f32::consts::PI;
use std::fmt::Write as _;
use std::path::Path;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    std::fs::create_dir_all(root.join("textures"))?;
    std::fs::create_dir_all(root.join("meshes"))?;
    write_png(&root.join("textures/wood.png"), 256, 256, wood)?;
    write_png(&root.join("textures/bricks.png"), 256, 256, bricks)?;
    let (obj, mtl) = torus_knot(160, 10);
    std::fs::write(root.join("meshes/knot.obj"), obj)?;
    std::fs::write(root.join("meshes/knot.mtl"), mtl)?;
    std::fs::write(root.join("meshes/gem.gltf"), gem_gltf(2))?;
    std::fs::write(root.join("meshes/materials.gltf"), materials_gltf(48, 24)?)?;
    println!("wrote assets under {}", root.display());
    Ok(())
}

/// A hash of integer coordinates to 0..1.
fn hash(x: i32, y: i32, seed: u32) -> f32 {
    let mut h = (x as u32).wrapping_mul(0x8da6_b343)
        ^ (y as u32).wrapping_mul(0xd816_3841)
        ^ seed.wrapping_mul(0xcb1a_b31f);
    h ^= h >> 13;
    h = h.wrapping_mul(0x5bd1_e995);
    h ^= h >> 15;
    (h & 0x00ff_ffff) as f32 / 16_777_216.0
}

/// Smooth value noise, tileable with period `p`.
fn noise(x: f32, y: f32, p: i32, seed: u32) -> f32 {
    let (xi, yi) = (x.floor() as i32, y.floor() as i32);
    let (fx, fy) = (x - xi as f32, y - yi as f32);
    let s = |t: f32| t * t * (3.0 - 2.0 * t);
    let h = |i: i32, j: i32| hash(i.rem_euclid(p), j.rem_euclid(p), seed);
    let a = h(xi, yi) + (h(xi + 1, yi) - h(xi, yi)) * s(fx);
    let b = h(xi, yi + 1) + (h(xi + 1, yi + 1) - h(xi, yi + 1)) * s(fx);
    a + (b - a) * s(fy)
}

fn mix(a: [f32; 3], b: [f32; 3], t: f32) -> [f32; 3] {
    [a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t, a[2] + (b[2] - a[2]) * t]
}

/// Wood planks: grain along x, growth rings disturbed by noise, darker seams.
fn wood(x: u32, y: u32) -> [f32; 3] {
    let (u, v) = (x as f32 / 256.0, y as f32 / 256.0);
    let plank = (v * 4.0).floor();
    let within = v * 4.0 - plank;
    let n = noise(u * 8.0, v * 32.0, 8, 7) * 0.6 + noise(u * 16.0, v * 64.0, 16, 9) * 0.3;
    let rings = ((within * 6.0 + n * 3.0 + plank * 1.7) * PI).sin() * 0.5 + 0.5;
    let light = [0.80, 0.55, 0.32];
    let dark = [0.50, 0.30, 0.15];
    let mut c = mix(light, dark, rings.powf(3.0));
    let shade = 0.85 + 0.3 * hash(plank as i32, ((u + plank * 0.5) * 2.0).floor() as i32, 3);
    c = c.map(|k| k * shade);
    if !(0.02..=0.98).contains(&within) || ((u * 2.0 + plank * 0.5).fract() < 0.008) {
        c = c.map(|k| k * 0.35);
    }
    c
}

/// Running-bond red bricks with grey mortar.
fn bricks(x: u32, y: u32) -> [f32; 3] {
    let (u, v) = (x as f32 / 256.0 * 4.0, y as f32 / 256.0 * 8.0);
    let row = v.floor();
    let u = u + if row as i32 % 2 == 1 { 0.5 } else { 0.0 };
    let col = u.floor();
    let (fu, fv) = (u - col, v - row);
    let mortar = fu < 0.04 || fv < 0.08;
    let n = noise(x as f32 / 8.0, y as f32 / 8.0, 32, 5);
    if mortar {
        let g = 0.55 + 0.15 * n;
        return [g, g, g * 0.95];
    }
    let tone = hash(col as i32, row as i32, 11);
    let base = mix([0.62, 0.20, 0.12], [0.45, 0.14, 0.09], tone);
    base.map(|k| k * (0.85 + 0.3 * n))
}

/// Writes an sRGB PNG from a linear-colour function of the pixel.
fn write_png(path: &Path, w: u32, h: u32, f: fn(u32, u32) -> [f32; 3]) -> Result<(), image::ImageError> {
    let encode = |c: f32| {
        let c = c.clamp(0.0, 1.0);
        let s = if c <= 0.003_130_8 { c * 12.92 } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 };
        (s * 255.0 + 0.5) as u8
    };
    let img = image::RgbImage::from_fn(w, h, |x, y| image::Rgb(f(x, y).map(encode)));
    img.save(path)
}

/// A (2, 3) torus knot tube as OBJ text (with normals and UVs) and its MTL.
fn torus_knot(segments: usize, sides: usize) -> (String, String) {
    let curve = |t: f32| {
        let (p, q) = (2.0, 3.0);
        let r = 2.0 + (q * t).cos();
        [r * (p * t).cos(), (q * t).sin(), r * (p * t).sin()].map(|c| c * 0.5)
    };
    let sub = |a: [f32; 3], b: [f32; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let cross = |a: [f32; 3], b: [f32; 3]| {
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    };
    let norm = |a: [f32; 3]| {
        let l = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
        a.map(|c| c / l)
    };
    let radius = 0.18;
    let mut obj = String::from(
        "# (2,3) torus knot, generated by crates/tracer/examples/make_assets.rs\nmtllib knot.mtl\no knot\n",
    );
    let mut normals = String::new();
    let mut uvs = String::new();
    for i in 0..=segments {
        let t = 2.0 * PI * i as f32 / segments as f32;
        let c = curve(t);
        let tangent = norm(sub(curve(t + 1e-3), curve(t - 1e-3)));
        // A frame that does not twist: the ring's "out" direction is the
        // radial direction (away from the Y axis) made perpendicular to the tangent.
        let out = norm(cross(cross(tangent, [c[0], 0.0, c[2]]), tangent));
        let b = cross(tangent, out);
        for j in 0..=sides {
            let a = 2.0 * PI * j as f32 / sides as f32;
            let n = [0, 1, 2].map(|k| out[k] * a.cos() + b[k] * a.sin());
            let p = [0, 1, 2].map(|k| c[k] + n[k] * radius);
            let _ = writeln!(obj, "v {:.4} {:.4} {:.4}", p[0], p[1], p[2]);
            let _ = writeln!(normals, "vn {:.4} {:.4} {:.4}", n[0], n[1], n[2]);
            let _ =
                writeln!(uvs, "vt {:.4} {:.4}", i as f32 / segments as f32 * 8.0, j as f32 / sides as f32);
        }
    }
    obj.push_str(&normals);
    obj.push_str(&uvs);
    obj.push_str("usemtl copper\n");
    let ring = sides + 1;
    for i in 0..segments {
        for j in 0..sides {
            let a = i * ring + j + 1;
            let (b, c, d) = (a + ring, a + ring + 1, a + 1);
            // Counter-clockwise seen from outside the tube.
            let _ = writeln!(obj, "f {a}/{a}/{a} {d}/{d}/{d} {c}/{c}/{c} {b}/{b}/{b}");
        }
    }
    let mtl = "# generated by crates/tracer/examples/make_assets.rs\nnewmtl copper\nKd 0.55 0.25 0.12\nKs 0.6 0.45 0.35\nNs 60\nillum 3\n".to_owned();
    (obj, mtl)
}

fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for chunk in bytes.chunks(3) {
        let b = [chunk[0], *chunk.get(1).unwrap_or(&0), *chunk.get(2).unwrap_or(&0)];
        let n = (b[0] as u32) << 16 | (b[1] as u32) << 8 | b[2] as u32;
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// A subdivided icosahedron (flat-shaded facets: each face has its own
/// vertices) as a glTF with an embedded buffer, under a translated parent node
/// and a rotated, scaled child node.
fn gem_gltf(levels: usize) -> String {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let mut verts: Vec<[f32; 3]> = vec![
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ];
    let mut faces: Vec<[usize; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    let unit = |v: [f32; 3]| {
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        v.map(|c| c / l * 0.5)
    };
    for v in &mut verts {
        *v = unit(*v);
    }
    for _ in 0..levels {
        let mut next = Vec::new();
        for f in &faces {
            let mid = |a: usize, b: usize, verts: &mut Vec<[f32; 3]>| {
                verts.push(unit([0, 1, 2].map(|k| verts[a][k] + verts[b][k])));
                verts.len() - 1
            };
            let (a, b, c) =
                (mid(f[0], f[1], &mut verts), mid(f[1], f[2], &mut verts), mid(f[2], f[0], &mut verts));
            next.extend([[f[0], a, c], [f[1], b, a], [f[2], c, b], [a, b, c]]);
        }
        faces = next;
    }
    // Flat facets: three own vertices per face, each with the face normal.
    let mut data: Vec<u8> = Vec::new();
    let mut min = [f32::MAX; 3];
    let mut max = [f32::MIN; 3];
    for f in &faces {
        for &i in f {
            for k in 0..3 {
                min[k] = min[k].min(verts[i][k]);
                max[k] = max[k].max(verts[i][k]);
            }
            data.extend(verts[i].iter().flat_map(|c| c.to_le_bytes()));
        }
    }
    let positions_len = data.len();
    for f in &faces {
        let [a, b, c] = f.map(|i| verts[i]);
        let e1 = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let e2 = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let n = [e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]];
        let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        for _ in 0..3 {
            data.extend(n.iter().flat_map(|c| (c / l).to_le_bytes()));
        }
    }
    let count = faces.len() * 3;
    format!(
        r#"{{
  "asset": {{ "version": "2.0", "generator": "isin make_assets" }},
  "scene": 0,
  "scenes": [ {{ "nodes": [0] }} ],
  "nodes": [
    {{ "name": "stand", "translation": [0.0, 0.5, 0.0], "children": [1] }},
    {{ "name": "gem", "mesh": 0, "rotation": [0.0, 0.3826834, 0.0, 0.9238795], "scale": [1.0, 1.0, 1.0] }}
  ],
  "meshes": [ {{ "primitives": [ {{ "attributes": {{ "POSITION": 0, "NORMAL": 1 }}, "material": 0 }} ] }} ],
  "materials": [ {{ "name": "gold", "pbrMetallicRoughness": {{ "baseColorFactor": [1.0, 0.76, 0.33, 1.0], "metallicFactor": 1.0, "roughnessFactor": 0.1 }} }} ],
  "accessors": [
    {{ "bufferView": 0, "componentType": 5126, "count": {count}, "type": "VEC3", "min": [{:.6}, {:.6}, {:.6}], "max": [{:.6}, {:.6}, {:.6}] }},
    {{ "bufferView": 1, "componentType": 5126, "count": {count}, "type": "VEC3" }}
  ],
  "bufferViews": [
    {{ "buffer": 0, "byteOffset": 0, "byteLength": {positions_len} }},
    {{ "buffer": 0, "byteOffset": {positions_len}, "byteLength": {} }}
  ],
  "buffers": [ {{ "byteLength": {}, "uri": "data:application/octet-stream;base64,{}" }} ]
}}
"#,
        min[0],
        min[1],
        min[2],
        max[0],
        max[1],
        max[2],
        data.len() - positions_len,
        data.len(),
        base64(&data)
    )
}

/// Five UV spheres (diameter 1, `segments` × `rings`) in a row along X, each
/// its own mesh over the same accessors, with one glTF material each; the
/// fourth adds vertex colours, the fifth a checker texture stored in the buffer.
fn materials_gltf(segments: usize, rings: usize) -> Result<String, image::ImageError> {
    let (mut pos, mut nor, mut uv, mut col) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for r in 0..=rings {
        let theta = PI * r as f32 / rings as f32;
        for s in 0..=segments {
            let phi = 2.0 * PI * s as f32 / segments as f32;
            let n = [theta.sin() * phi.cos(), theta.cos(), -theta.sin() * phi.sin()];
            pos.extend(n.map(|c| c * 0.5));
            nor.extend(n);
            uv.extend([s as f32 / segments as f32, r as f32 / rings as f32]);
            // A hue wheel around the sphere, paler towards the poles.
            let h = s as f32 / segments as f32 * 6.0;
            let rgb = [0.0f32, 4.0, 2.0].map(|o| ((h + o) % 6.0 - 3.0).abs().clamp(1.0, 2.0) - 1.0);
            let pale = theta.sin();
            col.extend(rgb.map(|c| 1.0 - pale + pale * c));
            col.push(1.0);
        }
    }
    let mut idx: Vec<u16> = Vec::new();
    let row = segments as u16 + 1;
    for r in 0..rings as u16 {
        for s in 0..segments as u16 {
            let (a, b) = (r * row + s, (r + 1) * row + s);
            idx.extend([a, b, a + 1, a + 1, b, b + 1]);
        }
    }
    let checker = image::RgbaImage::from_fn(64, 64, |x, y| {
        if (x / 8 + y / 8) % 2 == 0 {
            image::Rgba([235, 225, 200, 255])
        } else {
            image::Rgba([40, 90, 60, 255])
        }
    });
    let mut png = Vec::new();
    checker.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)?;

    let mut data: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    let mut push = |bytes: Vec<u8>, data: &mut Vec<u8>| {
        while data.len() % 4 != 0 {
            data.push(0);
        }
        views.push(format!(
            r#"{{ "buffer": 0, "byteOffset": {}, "byteLength": {} }}"#,
            data.len(),
            bytes.len()
        ));
        data.extend(bytes);
    };
    let floats = |v: &[f32]| v.iter().flat_map(|c| c.to_le_bytes()).collect::<Vec<u8>>();
    push(floats(&pos), &mut data);
    push(floats(&nor), &mut data);
    push(floats(&uv), &mut data);
    push(floats(&col), &mut data);
    push(idx.iter().flat_map(|i| i.to_le_bytes()).collect(), &mut data);
    push(png, &mut data);
    let n = pos.len() / 3;
    let materials = [
        r#"{ "name": "base colour alone: a rough metal", "pbrMetallicRoughness": { "baseColorFactor": [0.8, 0.12, 0.1, 1.0] } }"#,
        r#"{ "name": "polished gold", "pbrMetallicRoughness": { "baseColorFactor": [1.0, 0.76, 0.33, 1.0], "metallicFactor": 1.0, "roughnessFactor": 0.05 } }"#,
        r#"{ "name": "blue plastic", "pbrMetallicRoughness": { "baseColorFactor": [0.1, 0.25, 0.8, 1.0], "metallicFactor": 0.0, "roughnessFactor": 0.25 } }"#,
        r#"{ "name": "vertex colours", "pbrMetallicRoughness": { "metallicFactor": 0.0, "roughnessFactor": 0.6 } }"#,
        r#"{ "name": "checker", "pbrMetallicRoughness": { "metallicFactor": 0.0, "roughnessFactor": 0.5, "baseColorTexture": { "index": 0, "extensions": { "KHR_texture_transform": { "scale": [2.0, 1.0] } } } } }"#,
    ];
    let meshes: Vec<String> = (0..materials.len())
        .map(|m| {
            let colour = if m == 3 { r#", "COLOR_0": 3"# } else { "" };
            format!(
                r#"{{ "primitives": [ {{ "attributes": {{ "POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2{colour} }}, "indices": 4, "material": {m} }} ] }}"#
            )
        })
        .collect();
    let nodes: Vec<String> = (0..materials.len())
        .map(|m| format!(r#"{{ "mesh": {m}, "translation": [{:.1}, 0.5, 0.0] }}"#, 1.25 * (m as f32 - 2.0)))
        .collect();
    Ok(format!(
        r#"{{
  "asset": {{ "version": "2.0", "generator": "isin make_assets" }},
  "extensionsUsed": [ "KHR_texture_transform" ],
  "scene": 0,
  "scenes": [ {{ "nodes": [0, 1, 2, 3, 4] }} ],
  "nodes": [
    {}
  ],
  "meshes": [
    {}
  ],
  "materials": [
    {}
  ],
  "textures": [ {{ "source": 0 }} ],
  "images": [ {{ "bufferView": 5, "mimeType": "image/png" }} ],
  "accessors": [
    {{ "bufferView": 0, "componentType": 5126, "count": {n}, "type": "VEC3", "min": [-0.5, -0.5, -0.5], "max": [0.5, 0.5, 0.5] }},
    {{ "bufferView": 1, "componentType": 5126, "count": {n}, "type": "VEC3" }},
    {{ "bufferView": 2, "componentType": 5126, "count": {n}, "type": "VEC2" }},
    {{ "bufferView": 3, "componentType": 5126, "count": {n}, "type": "VEC4" }},
    {{ "bufferView": 4, "componentType": 5123, "count": {}, "type": "SCALAR" }}
  ],
  "bufferViews": [
    {}
  ],
  "buffers": [ {{ "byteLength": {}, "uri": "data:application/octet-stream;base64,{}" }} ]
}}
"#,
        nodes.join(",\n    "),
        meshes.join(",\n    "),
        materials.join(",\n    "),
        idx.len(),
        views.join(",\n    "),
        data.len(),
        base64(&data)
    ))
}

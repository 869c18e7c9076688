//! Targets for what scene files hold: the scene TOML and every file format
//! it loads (OBJ, MTL, glTF, GLB, PNG/JPEG textures, Radiance HDR
//! environments), and the scene bundle a slave receives and loads.
//!
//! Each feeds the fuzzer's bytes to the real loader (`isin_tracer::load_scene`
//! with a [`SceneBundle`] as the asset source, as a slave loads) as one file of
//! a small scene whose other files are valid ([`fixtures`]). A scene that
//! loads is built (its BVH) and rendered for a few pixels, so what the loader
//! lets through is used, not only parsed.

use isin_cluster::protocol::DEFAULT_MAX_FRAME;
use isin_tracer::{Camera, RenderSettings, Scene, SceneBundle, SceneError, Tile, parse_scene};
use std::collections::BTreeMap;
use std::sync::{Once, OnceLock};

/// The scene's name in error messages.
const NAME: &str = "fuzz.toml";

/// Most triangles a scene built by a target may have: more are legitimate
/// (up to the loader's own limit) but only slow the fuzzer down.
const BUILD_TRIANGLES: usize = 200_000;

/// A 4×4 RGBA PNG.
fn png() -> Vec<u8> {
    let img = image::RgbaImage::from_fn(4, 4, |x, y| image::Rgba([x as u8 * 60, y as u8 * 60, 128, 200]));
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).expect("a PNG encodes");
    out.into_inner()
}

/// A 4×2 Radiance HDR image.
fn hdr() -> Vec<u8> {
    let img = image::Rgb32FImage::from_fn(4, 2, |x, y| image::Rgb([x as f32, y as f32 * 2.0, 0.5]));
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Hdr).expect("an HDR encodes");
    out.into_inner()
}

/// One triangle for glTF files: positions, texture coordinates and indices.
pub fn triangle_buffer() -> Vec<u8> {
    let mut b = Vec::new();
    for v in [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    for i in [0u16, 1, 2, 0] {
        b.extend_from_slice(&i.to_le_bytes());
    }
    b
}

/// A glTF document around [`triangle_buffer`] (as `buffer`: a URI, or
/// `None` for a GLB's binary chunk), its material textured by `image`.
pub fn triangle_gltf(buffer: Option<&str>, image: &str) -> String {
    let uri = buffer.map_or(String::new(), |u| format!(r#""uri":"{u}","#));
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0,"translation":[0,0,-1]}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,"TEXCOORD_0":1}},"indices":2,"material":0}}]}}],
"materials":[{{"alphaMode":"MASK","pbrMetallicRoughness":{{"baseColorFactor":[1,0.5,0.2,1],"baseColorTexture":{{"index":0}},"metallicRoughnessTexture":{{"index":0}}}}}}],
"textures":[{{"source":0}}],"images":[{{"uri":"{image}"}}],
"buffers":[{{{uri}"byteLength":68}}],
"bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":24}},{{"buffer":0,"byteOffset":60,"byteLength":6}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
{{"bufferView":1,"componentType":5126,"count":3,"type":"VEC2"}},{{"bufferView":2,"componentType":5123,"count":3,"type":"SCALAR"}}]}}"#
    )
}

/// An OBJ quad that uses the materials `a` and `b` of `mtllib`.
pub fn quad_obj(mtllib: &str) -> String {
    format!(
        "mtllib {mtllib}\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\n\
         usemtl a\nf 1/1/1 2/2/1 3/3/1\nusemtl b\ns 1\nf 1/1 3/3 4/4\n"
    )
}

/// An MTL library for [`quad_obj`], textured by `tex.png`.
pub const MTL: &str = "newmtl a\nKd 0.8 0.2 0.2\nKs 0.5 0.5 0.5\nNs 20\nmap_Kd tex.png\n\
                       newmtl b\nKe 1 1 1\nd 0.5\nNi 1.4\nillum 7\n";

/// The valid files every target's scene may refer to: `tex.png`, `env.hdr`,
/// `mesh.obj` (+ `mesh.mtl`), `mesh.gltf` (+ `buffer.bin`).
pub fn fixtures() -> &'static BTreeMap<String, Vec<u8>> {
    static FIXTURES: OnceLock<BTreeMap<String, Vec<u8>>> = OnceLock::new();
    FIXTURES.get_or_init(|| {
        let mut a = BTreeMap::new();
        a.insert("tex.png".to_string(), png());
        a.insert("env.hdr".to_string(), hdr());
        a.insert("mesh.obj".to_string(), quad_obj("mesh.mtl").into_bytes());
        a.insert("mesh.mtl".to_string(), MTL.as_bytes().to_vec());
        a.insert("mesh.gltf".to_string(), triangle_gltf(Some("buffer.bin"), "tex.png").into_bytes());
        a.insert("buffer.bin".to_string(), triangle_buffer());
        a
    })
}

/// A light and one object of `kind` loading `path` (smoothed: meshes
/// without normals get them).
fn scene_of(kind: &str, path: &str) -> String {
    format!(
        "[[lights]]\nkind = \"point\"\nposition = [0, 2, 4]\n\n\
         [[objects]]\nkind = \"{kind}\"\npath = \"{path}\"\nsmooth = true\n"
    )
}

/// Makes the calling thread rayon's only worker, once: the loader and the
/// BVH build run their parallel loops inline. A pool of other threads costs a
/// one-file scene most of its time handing work over and waking and parking
/// workers (three quarters of the MTL target's, in the kernel), and the work
/// is the same code either way.
fn one_thread() {
    static POOL: Once = Once::new();
    POOL.call_once(|| {
        // Fails only if the global pool exists already (a test binary's
        // other tests): the targets then run on that pool, as before.
        let _ = rayon::ThreadPoolBuilder::new().num_threads(1).use_current_thread().build_global();
    });
}

/// Loads `source` with the fixtures and `extra` files; a scene that loads is
/// built and a few of its pixels rendered.
fn load(source: &str, extra: &[(&str, &[u8])]) -> Result<(), SceneError> {
    one_thread();
    let mut assets = fixtures().clone();
    for (path, bytes) in extra {
        assets.insert(path.to_string(), bytes.to_vec());
    }
    let mut bundle = SceneBundle { name: NAME.into(), source: source.into(), assets };
    let parts = parse_scene(NAME, source, &mut bundle)?;
    if parts.triangles.len() <= BUILD_TRIANGLES {
        use_scene(&Scene::new(parts));
    }
    Ok(())
}

/// What a slave does with a loaded scene: renders with it. (A slave also
/// fills every surface's shadow cells first; rendering fills those its
/// pixels meet, the same code, and the eager fill of a whole quad's cells
/// cost the file targets nine tenths of their time.)
fn use_scene(scene: &Scene) {
    let settings = RenderSettings {
        width: 4,
        height: 4,
        spp: 1,
        light_samples: scene.settings.light_samples.min(4),
        max_depth: scene.settings.max_depth.min(6),
        seed: 1,
    };
    // Viewers' cameras are validated before any slave renders with them.
    let cameras = [Some(scene.camera).filter(|c| c.validate().is_ok()), Some(Camera::default())];
    for camera in cameras.into_iter().flatten() {
        let rgb = isin_tracer::render_tile(scene, &camera, &settings, Tile { x: 0, y: 0, w: 4, h: 4 });
        assert_eq!(rgb.len(), 4 * 4 * 3);
    }
}

/// The scene TOML (`scenefile::format`, what the master reads and every
/// slave loads from its bundle), with the [`fixtures`] to refer to.
pub fn scene_toml(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let _ = load(text, &[]);
}

/// A Wavefront OBJ mesh (`fuzz.obj`; `mesh.mtl` and `tex.png` are there to be used).
pub fn obj(data: &[u8]) {
    let _ = load(&scene_of("obj", "fuzz.obj"), &[("fuzz.obj", data)]);
}

/// An MTL library (`fuzz.mtl`) used by an OBJ quad ([`quad_obj`]).
pub fn mtl(data: &[u8]) {
    let obj = quad_obj("fuzz.mtl");
    let _ = load(&scene_of("obj", "q.obj"), &[("q.obj", obj.as_bytes()), ("fuzz.mtl", data)]);
}

/// A glTF JSON file (`fuzz.gltf`; `buffer.bin` and `tex.png` are there to be used).
pub fn gltf(data: &[u8]) {
    let _ = load(&scene_of("gltf", "fuzz.gltf"), &[("fuzz.gltf", data)]);
}

/// A binary glTF file (`fuzz.glb`).
pub fn glb(data: &[u8]) {
    let _ = load(&scene_of("gltf", "fuzz.glb"), &[("fuzz.glb", data)]);
}

/// An image (`fuzz.img`) as each loader decodes one: `[use: u8][bytes…]`,
/// where `use` % 3 is 0 for a scene texture (PNG/JPEG, sRGB), 1 for the
/// background environment (Radiance HDR, PNG, JPEG), 2 for a glTF
/// material's base colour with alpha mask and its metallic-roughness map.
pub fn image(data: &[u8]) {
    let [kind, bytes @ ..] = data else { return };
    let _ = load_image(*kind, bytes);
}

fn load_image(kind: u8, bytes: &[u8]) -> Result<(), SceneError> {
    let quad = "[[objects]]\nkind = \"quad\"\nmaterial = \"m\"\n";
    match kind % 3 {
        0 => {
            let source = format!(
                "[textures.t]\nkind = \"image\"\npath = \"fuzz.img\"\n\n\
                 [materials.m]\nkind = \"phong\"\ntexture = \"t\"\n\n{quad}"
            );
            load(&source, &[("fuzz.img", bytes)])
        }
        1 => {
            let source =
                format!("[background]\nimage = \"fuzz.img\"\n\n[materials.m]\nkind = \"mirror\"\n\n{quad}");
            load(&source, &[("fuzz.img", bytes)])
        }
        _ => {
            let gltf = triangle_gltf(Some("buffer.bin"), "fuzz.img");
            load(&scene_of("gltf", "t.gltf"), &[("t.gltf", gltf.as_bytes()), ("fuzz.img", bytes)])
        }
    }
}

/// A scene bundle as a slave (or the master, from a client) unpacks it: the
/// decompressed bytes of a scene stream, at most [`DEFAULT_MAX_FRAME`]
/// (`isin_cluster::scene_stream::decode_bundle`, which
/// `decode_bundle_owned` agrees with), whose bundle is loaded,
/// built and a few pixels rendered. The slave's check of the bundle against
/// its hash is left out (a master with the token can send any bundle with its right
/// hash), so that mutated bundles reach the loader.
pub fn scene_bundle(data: &[u8]) {
    if data.len() > DEFAULT_MAX_FRAME {
        return;
    }
    one_thread();
    let decoded = isin_cluster::scene_stream::decode_bundle(data);
    assert_eq!(
        decoded,
        isin_cluster::scene_stream::decode_bundle_owned(data.to_vec()),
        "the decoders disagree"
    );
    let Ok(bundle) = decoded else { return };
    let mut assets = bundle.clone();
    let Ok(parts) = parse_scene(&bundle.name, &bundle.source, &mut assets) else { return };
    if parts.triangles.len() <= BUILD_TRIANGLES {
        use_scene(&Scene::new(parts));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The scenes around each target's input load with valid files: the
    /// targets reach the loaders' insides, not only their first error.
    #[test]
    fn each_targets_scene_loads_with_a_valid_file() {
        let f = fixtures();
        load(&scene_of("obj", "fuzz.obj"), &[("fuzz.obj", &f["mesh.obj"])]).unwrap();
        let obj = quad_obj("fuzz.mtl");
        load(&scene_of("obj", "q.obj"), &[("q.obj", obj.as_bytes()), ("fuzz.mtl", MTL.as_bytes())]).unwrap();
        load(&scene_of("gltf", "fuzz.gltf"), &[("fuzz.gltf", &f["mesh.gltf"])]).unwrap();
        for kind in 0..3 {
            load_image(kind, &f["tex.png"]).unwrap();
        }
        load_image(1, &f["env.hdr"]).unwrap();
    }
}

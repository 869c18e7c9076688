//! Scene files: the shipped scenes, the format's errors, OBJ and glTF loading,
//! and scene bundles.

use glam::{Vec2, Vec3};
use isin_tracer::lights::Light;
use isin_tracer::materials::{Albedo, Material};
use isin_tracer::scene::SceneParts;
use isin_tracer::textures::Texture;
use isin_tracer::{AssetSource, SceneBundle, SceneError, parse_scene};
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

/// Assets held in memory.
#[derive(Default)]
struct Mem(HashMap<String, Vec<u8>>);

impl Mem {
    fn with(mut self, path: &str, bytes: impl Into<Vec<u8>>) -> Self {
        self.0.insert(path.to_owned(), bytes.into());
        self
    }
}

impl AssetSource for Mem {
    fn read(&mut self, path: &str) -> Result<Vec<u8>, String> {
        self.0.get(path).cloned().ok_or_else(|| format!("no such file: {path}"))
    }
}

/// Assets read from a directory, recording what was read (like the binary's DiskAssets).
struct Dir {
    base: PathBuf,
    read: BTreeMap<String, Vec<u8>>,
}

impl AssetSource for Dir {
    fn read(&mut self, path: &str) -> Result<Vec<u8>, String> {
        let bytes = std::fs::read(self.base.join(path)).map_err(|e| e.to_string())?;
        self.read.insert(path.to_owned(), bytes.clone());
        Ok(bytes)
    }
}

fn scenes_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes")
}

fn load(src: &str, assets: &mut Mem) -> Result<SceneParts, SceneError> {
    parse_scene("test.toml", src, assets)
}

fn load_ok(src: &str) -> SceneParts {
    load(src, &mut Mem::default()).unwrap_or_else(|e| panic!("{e}"))
}

fn err(src: &str, assets: &mut Mem) -> String {
    match load(src, assets) {
        Ok(_) => panic!("scene loaded but should not have:\n{src}"),
        Err(e) => e.to_string(),
    }
}

/// 1-based line of the first line containing `needle`.
fn line_of(src: &str, needle: &str) -> usize {
    src.lines().position(|l| l.contains(needle)).expect("needle in source") + 1
}

fn assert_mentions(message: &str, parts: &[&str]) {
    for p in parts {
        assert!(message.contains(p), "error message lacks {p:?}:\n{message}");
    }
}

fn close(a: Vec3, b: Vec3) -> bool {
    (a - b).length() < 1e-4
}

const QUAD: &str = "[[objects]]\nkind = \"quad\"\n";

// ───────────────────────── shipped scenes ─────────────────────────

fn load_shipped(file: &str) -> (SceneParts, BTreeMap<String, Vec<u8>>) {
    let path = scenes_dir().join(file);
    let source = std::fs::read_to_string(&path).unwrap();
    let mut assets = Dir { base: scenes_dir(), read: BTreeMap::new() };
    let parts = parse_scene(file, &source, &mut assets).unwrap_or_else(|e| panic!("{e}"));
    (parts, assets.read)
}

fn count_lights(p: &SceneParts) -> (usize, usize) {
    let points = p.lights.iter().filter(|l| matches!(l, Light::Point { .. })).count();
    (points, p.lights.len() - points)
}

fn has_material(p: &SceneParts, f: impl Fn(&Material) -> bool) -> bool {
    p.shading.iter().any(|s| f(&p.materials[s.material as usize]))
}

/// Common sanity checks: shading parallel to triangles, valid material
/// indices, unit normals, camera that validates, every triangle in front of
/// the camera somewhere (the scene is not behind the eye).
fn check_scene(p: &SceneParts, name: &str) {
    assert!(!p.triangles.is_empty(), "{name}");
    assert_eq!(p.triangles.len(), p.shading.len(), "{name}");
    p.camera.validate().unwrap_or_else(|e| panic!("{name}: {e}"));
    let fwd = p.camera.forward();
    let in_front = p.triangles.iter().filter(|t| (t.v[0] - p.camera.eye).dot(fwd) > 0.0).count();
    assert!(in_front * 2 > p.triangles.len(), "{name}: most geometry must be in front of the camera");
    for s in &p.shading {
        assert!((s.material as usize) < p.materials.len(), "{name}");
        for n in s.normals {
            assert!((n.length() - 1.0).abs() < 1e-3, "{name}: normal {n:?}");
        }
    }
    for l in &p.lights {
        if let Light::Area { vertices, .. } = l {
            assert!(vertices.len() == 3 || vertices.len() == 4, "{name}");
        }
    }
}

/// Shipped scenes are read from `scenes/`; image textures need the shading
/// branch's MipMap.
#[test]
fn every_shipped_scene_loads() {
    let mut names: Vec<String> = std::fs::read_dir(scenes_dir())
        .unwrap()
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| n.ends_with(".toml"))
        .collect();
    names.sort();
    assert!(names.len() >= 3, "{names:?}");
    for name in &names {
        let text = std::fs::read_to_string(scenes_dir().join(name)).unwrap();
        if let Some(shared) = missing_shared_mesh(&text) {
            eprintln!("skipping {name}: {} is absent", shared.display());
            continue;
        }
        let (p, _) = load_shipped(name);
        check_scene(&p, name);
    }
}

/// The first `../../shared/meshes/…` file a shipped scene names that is not
/// on disk (the mesh scenes read the shared test meshes, which may be absent).
fn missing_shared_mesh(scene_text: &str) -> Option<PathBuf> {
    scene_text
        .lines()
        .filter_map(|l| l.trim().strip_prefix("path = \"")?.strip_suffix('"'))
        .filter(|p| p.starts_with("../../shared/"))
        .map(|p| scenes_dir().join(p))
        .find(|p| !p.exists())
}

/// The mesh scenes of issue 6: a real mesh on a reflective floor, lit by a
/// point light and an area light, seen by the camera; the dragon subdivided
/// to 1.6M triangles.
#[test]
fn shared_mesh_scenes_have_the_issues_ingredients() {
    for (name, min_tris) in [("bunny.toml", 69_000), ("dragon.toml", 1_600_000)] {
        let text = std::fs::read_to_string(scenes_dir().join(name)).unwrap();
        if let Some(shared) = missing_shared_mesh(&text) {
            eprintln!("skipping {name}: {} is absent", shared.display());
            continue;
        }
        let (p, read) = load_shipped(name);
        check_scene(&p, name);
        assert!(read.keys().all(|k| k.starts_with("../../shared/meshes/")), "{:?}", read.keys());
        assert!(p.triangles.len() >= min_tris, "{name}: {}", p.triangles.len());
        assert_eq!(count_lights(&p), (1, 1), "{name}");
        assert!(
            has_material(&p, |m| matches!(m, Material::Phong { reflectivity, .. } if *reflectivity >= 0.5)),
            "{name}: a mirror floor"
        );
        // The mesh stands on the floor (y = 0) and the camera looks at it.
        let mesh_min_y = p.triangles.iter().flat_map(|t| t.v).map(|v| v.y).fold(f32::MAX, f32::min);
        assert!(mesh_min_y > -1e-3, "{name}: {mesh_min_y}");
        let fwd = p.camera.forward();
        let to_mesh = (Vec3::new(0.0, 1.0, 0.0) - p.camera.eye).normalize();
        assert!(fwd.dot(to_mesh) > 0.9, "{name}: the camera looks at the mesh");
    }
}

#[test]
fn subdivide_splits_every_triangle_one_to_four_per_level() {
    let plain = load_ok("[[objects]]\nkind = \"sphere\"\nsegments = 8\nrings = 4\n");
    for levels in 1..=2u32 {
        let src = format!("[[objects]]\nkind = \"sphere\"\nsegments = 8\nrings = 4\nsubdivide = {levels}\n");
        let p = load_ok(&src);
        assert_eq!(p.triangles.len(), plain.triangles.len() * 4usize.pow(levels));
        let area = |q: &SceneParts| q.triangles.iter().map(|t| t.normal().length() * 0.5).sum::<f32>();
        assert!((area(&p) - area(&plain)).abs() < 1e-4 * area(&plain), "the surface is unchanged");
    }
    // OBJ meshes too (5 triangles in the test file).
    let src = "[[objects]]\nkind = \"obj\"\npath = \"meshes/sub/thing.obj\"\nsubdivide = 1\n";
    assert_eq!(load(src, &mut obj_assets()).unwrap().triangles.len(), 20);
}

#[test]
fn absurd_subdivision_is_rejected_with_its_line() {
    let src = "[[objects]]\nkind = \"box\"\nsubdivide = 7\n";
    assert_mentions(
        &err(src, &mut Mem::default()),
        &["test.toml:3", "objects[0] (box).subdivide", "between 0 and 6"],
    );
    let src = "[[objects]]\nkind = \"box\"\nsubdivide = -1\n";
    assert_mentions(&err(src, &mut Mem::default()), &["test.toml:3"]);
    // Within the level limit but past the scene's triangle limit: an error, not
    // an allocation of billions of triangles.
    let src = "[[objects]]\nkind = \"sphere\"\nsegments = 256\nrings = 128\nsubdivide = 6\n";
    assert_mentions(&err(src, &mut Mem::default()), &["objects[0] (sphere)", "exceed"]);
}

#[test]
fn paper_scene_has_the_papers_ingredients() {
    let (p, read) = load_shipped("paper.toml");
    check_scene(&p, "paper");
    assert_eq!(count_lights(&p), (1, 1), "one point light and one area light");
    assert!(has_material(&p, |m| matches!(m, Material::Mirror { .. })));
    assert!(has_material(&p, |m| matches!(m, Material::Dielectric { .. })));
    assert!(has_material(&p, |m| matches!(m, Material::Emissive { .. })), "the area light is visible");
    assert!(has_material(&p, |m| matches!(m, Material::Phong { albedo: Albedo::Texture { .. }, .. })));
    assert!(p.textures.iter().any(|t| matches!(t, Texture::Image(_))));
    assert!(p.textures.iter().any(|t| matches!(t, Texture::Checker { .. })));
    assert!(read.contains_key("textures/wood.png"));
    let c = &p.camera;
    assert!((c.plane_x().length() - 8.0).abs() < 1e-2 && (c.plane_y().length() - 6.0).abs() < 1e-2);
    assert!((c.eye_distance() - 12.5).abs() < 1e-2, "the paper's camera");
    assert_eq!((p.settings.width, p.settings.height), (640, 480));
}

#[test]
fn mesh_scene_loads_its_obj_and_gltf() {
    let (p, read) = load_shipped("mesh.toml");
    check_scene(&p, "mesh");
    for f in ["meshes/knot.obj", "meshes/knot.mtl", "meshes/gem.gltf", "textures/wood.png"] {
        assert!(read.contains_key(f), "{f} read through the AssetSource: {:?}", read.keys());
    }
    assert!(p.triangles.len() > 5000);
    // The gem's gold is metallic and smooth: a glTF material, gold-coloured.
    assert!(has_material(
        &p,
        |m| matches!(m, Material::Pbr(g) if g.base_color.x > g.base_color.z && g.metallic == 1.0)
    ));
}

#[test]
fn the_shipped_materials_gltf_opens_alone() {
    let mut assets = Dir { base: scenes_dir(), read: BTreeMap::new() };
    let text = isin_tracer::scenefile::mesh_scene("meshes/materials.gltf", &mut assets).unwrap();
    let p = parse_scene("made.toml", &text, &mut assets).unwrap();
    check_scene(&p, "materials.gltf");
    assert_eq!(p.materials.iter().filter(|m| matches!(m, Material::Pbr(_))).count(), 5);
    assert!(p.materials.iter().any(|m| matches!(m, Material::Pbr(g) if g.base_texture.is_some())));
    assert_eq!(p.colours.len(), p.triangles.len(), "the vertex-coloured sphere");
    assert!(p.warnings.is_empty(), "{:?}", p.warnings);
}

#[test]
fn shipped_cameras_are_left_alone_at_their_own_aspect() {
    // Corners written to three decimals are not exactly 4:3; the image must not change for that.
    for name in ["paper.toml", "cornell.toml", "mesh.toml"] {
        let (p, _) = load_shipped(name);
        let aspect = p.settings.width as f32 / p.settings.height as f32;
        assert_eq!(p.camera.fit_aspect(aspect), p.camera, "{name}");
    }
}

/// The shipped scenes' geometry, lights and cameras.
#[test]
fn shipped_scene_layouts() {
    for name in ["paper.toml", "cornell.toml", "mesh.toml"] {
        let text = std::fs::read_to_string(scenes_dir().join(name)).unwrap();
        let mut assets = Dir { base: scenes_dir(), read: BTreeMap::new() };
        let p = parse_scene(name, &text, &mut assets).unwrap_or_else(|e| panic!("{e}"));
        check_scene(&p, name);
        match name {
            "paper.toml" => {
                assert_eq!(count_lights(&p), (1, 1));
                assert!(has_material(&p, |m| matches!(m, Material::Mirror { .. })));
                assert!(has_material(&p, |m| matches!(m, Material::Dielectric { .. })));
                // Every object rests on or above the floor (y = 0) and stays in the room.
                for t in &p.triangles {
                    for v in t.v {
                        assert!(v.y > -1e-3 && v.y < 7.0 + 1e-3 && v.x.abs() < 7.0 + 1e-3, "{v:?}");
                    }
                }
                for l in &p.lights {
                    let pos = match l {
                        Light::Point { position, .. } => *position,
                        Light::Area { vertices, .. } => vertices[0],
                    };
                    assert!(pos.y > 0.0 && pos.y < 7.0 && pos.x.abs() < 7.0 && pos.z > -10.0, "{pos:?}");
                }
            }
            "cornell.toml" => {
                assert_eq!(count_lights(&p), (0, 1));
                assert!(has_material(&p, |m| matches!(m, Material::Mirror { .. })));
                assert!(has_material(&p, |m| matches!(m, Material::Dielectric { .. })));
                // Area light faces down into the box.
                let Light::Area { vertices, .. } = &p.lights[0] else { unreachable!() };
                assert!((vertices[1] - vertices[0]).cross(vertices[2] - vertices[0]).y < 0.0);
            }
            _ => assert!(p.triangles.len() > 5000),
        }
    }
}

#[test]
fn cornell_scene_loads_from_disk() {
    let (p, read) = load_shipped("cornell.toml");
    check_scene(&p, "cornell");
    assert!(read.is_empty(), "the Cornell box needs no asset files");
    let colours: Vec<Vec3> = p
        .materials
        .iter()
        .filter_map(|m| match m {
            Material::Phong { albedo: Albedo::Constant(c), .. } => Some(*c),
            _ => None,
        })
        .collect();
    assert!(colours.iter().any(|c| c.x > 0.5 && c.y < 0.1), "a red wall");
    assert!(colours.iter().any(|c| c.y > 0.4 && c.x < 0.2), "a green wall");
}

// ───────────────────────── format and primitives ─────────────────────────

#[test]
fn minimal_scene_uses_the_papers_defaults() {
    let p = load_ok(QUAD);
    assert_eq!(p.triangles.len(), 2);
    assert_eq!(p.camera, isin_tracer::Camera::default());
    assert_eq!(p.settings, isin_tracer::RenderSettings::default());
    assert_eq!(p.materials.len(), 1, "the default grey material");
    assert_eq!(p.ambient, Vec3::ZERO);
}

#[test]
fn placement_scales_rotates_and_translates() {
    let p = load_ok(
        "[materials.m]\nkind = \"phong\"\ncolor = 0.5\n\n[[objects]]\nkind = \"box\"\nmaterial = \"m\"\n\
         scale = [2, 1, 4]\nrotate = [0, 90, 0]\ntranslate = [10, 0.5, 0]\n",
    );
    assert_eq!(p.triangles.len(), 12);
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for t in &p.triangles {
        for v in t.v {
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    // 2 × 1 × 4, turned 90° about Y (x ↔ z), resting on y = 0 around x = 10.
    assert!(close(lo, Vec3::new(8.0, 0.0, -1.0)) && close(hi, Vec3::new(12.0, 1.0, 1.0)), "{lo} {hi}");
    assert!(
        matches!(p.materials[0], Material::Phong { albedo: Albedo::Constant(c), .. } if c == Vec3::splat(0.5))
    );
    // Flat box: each triangle's three normals equal its face normal.
    for (t, s) in p.triangles.iter().zip(&p.shading) {
        let n = t.normal().normalize();
        assert!(s.normals.iter().all(|&m| close(m, n)));
    }
}

#[test]
fn spheres_are_smooth_and_uv_scale_tiles() {
    let p =
        load_ok("[[objects]]\nkind = \"sphere\"\nsegments = 8\nrings = 4\nscale = 2\nuv_scale = [3, 2]\n");
    assert_eq!(p.triangles.len(), 8 * 4 * 2 - 2 * 8);
    let mut max_uv = Vec2::ZERO;
    for (t, s) in p.triangles.iter().zip(&p.shading) {
        for (v, n) in t.v.iter().zip(s.normals) {
            assert!(close(*v, n), "radius 1: the normal is the position");
        }
        for uv in s.uvs {
            max_uv = max_uv.max(uv);
        }
    }
    assert!(close(max_uv.extend(0.0), Vec3::new(3.0, 2.0, 0.0)), "{max_uv}");
}

#[test]
fn lights_and_visible_area_lamps() {
    let src = "[[lights]]\nkind = \"point\"\nposition = [1, 2, 3]\nintensity = [1, 0.5, 0]\npower = 10\n\n\
               [[lights]]\nkind = \"area\"\ncorner = [0, 5, 0]\nedge1 = [1, 0, 0]\nedge2 = [0, 0, 2]\nradiance = 2\n\n\
               [[lights]]\nkind = \"area\"\nvertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]\nvisible = false\n";
    let p = load_ok(src);
    assert_eq!(p.lights.len(), 3);
    assert_eq!(
        p.lights[0],
        Light::Point { position: Vec3::new(1.0, 2.0, 3.0), intensity: Vec3::new(10.0, 5.0, 0.0) }
    );
    let Light::Area { vertices, radiance } = &p.lights[1] else { panic!() };
    assert_eq!(vertices.len(), 4);
    assert!(close(vertices[2], Vec3::new(1.0, 5.0, 2.0)));
    assert_eq!(*radiance, Vec3::splat(2.0));
    // Only the visible lamp became geometry: two emissive triangles facing down.
    assert_eq!(p.triangles.len(), 2);
    for (t, s) in p.triangles.iter().zip(&p.shading) {
        assert!(t.normal().y < 0.0, "faces the lit side");
        assert_eq!(p.materials[s.material as usize], Material::Emissive { radiance: Vec3::splat(2.0) });
    }
}

#[test]
fn camera_forms() {
    let src = format!(
        "[camera]\neye = [0, 0, 10]\np0 = [-4, 3, 0]\np1 = [4, 3, 0]\np2 = [4, -3, 0]\np3 = [-4, -3, 0]\n{QUAD}"
    );
    let p = load_ok(&src);
    assert!(close(p.camera.eye, Vec3::new(0.0, 0.0, 10.0)));
    assert!(close(p.camera.corners[2], Vec3::new(4.0, -3.0, 0.0)));
    let src = format!(
        "[settings]\nwidth = 200\nheight = 100\n[camera]\neye = [0, 1, 5]\ntarget = [0, 1, 0]\nfov = 90\n{QUAD}"
    );
    let p = load_ok(&src);
    assert!(close(p.camera.forward(), Vec3::NEG_Z));
    assert!((p.camera.hfov_degrees() - 90.0).abs() < 1e-3);
    assert!(
        (p.camera.plane_x().length() / p.camera.plane_y().length() - 2.0).abs() < 1e-4,
        "aspect from settings"
    );
    assert_eq!(p.settings.width, 200);
}

// ───────────────────────── errors ─────────────────────────

#[test]
fn syntax_errors_name_file_line_and_column() {
    let src = format!("{QUAD}translate = [1 2 3]\nrotate = [0, 0, 0]\n");
    let e = err(&src, &mut Mem::default());
    assert_mentions(&e, &[&format!("test.toml:{}:16:", line_of(&src, "translate")), "translate = [1 2 3]"]);
    let src = format!("{QUAD}\n[materials.a]\nkind = \"phong\"\n[materials.a]\nkind = \"mirror\"\n");
    let e = err(&src, &mut Mem::default());
    assert_mentions(&e, &[&format!("test.toml:{}:", line_of(&src, "[materials.a]") + 2), "duplicate"]);
}

#[test]
fn unknown_keys_are_rejected_with_their_line() {
    let src = format!("ambient = 0.1\n\n{QUAD}materail = \"x\"\n");
    let e = err(&src, &mut Mem::default());
    assert_mentions(&e, &[&format!("test.toml:{}:", line_of(&src, "materail")), "materail"]);
    let src = "[materials.m]\nkind = \"mirror\"\ncolour = 1\n";
    let e = err(src, &mut Mem::default());
    assert_mentions(&e, &["test.toml:3:", "colour"]);
}

#[test]
fn nan_and_infinity_are_rejected_everywhere() {
    let cases = [
        format!("{QUAD}translate = [0, nan, 0]\n"),
        format!("{QUAD}scale = inf\n"),
        format!("{QUAD}rotate = [0, 0, -inf]\n"),
        "[materials.m]\nkind = \"phong\"\ncolor = [1, nan, 0]\n".to_owned(),
        format!("ambient = nan\n{QUAD}"),
        format!("[camera]\neye = [0, 0, inf]\ntarget = [0, 0, 0]\n{QUAD}"),
        format!("[[lights]]\nkind = \"point\"\nposition = [1e39, 0, 0]\n{QUAD}"),
    ];
    for src in &cases {
        let bad_line =
            src.lines().position(|l| l.contains("nan") || l.contains("inf") || l.contains("e39")).unwrap()
                + 1;
        let e = err(src, &mut Mem::default());
        // A finite number beyond f32 says it is too large, not that it is infinite.
        let says = if src.contains("e39") { "too large" } else { "finite" };
        assert_mentions(&e, &[&format!("test.toml:{bad_line}:"), says]);
        let field = src.lines().nth(bad_line - 1).unwrap().split('=').next().unwrap().trim();
        assert_mentions(&e, &[field]);
    }
}

#[test]
fn unknown_material_names_the_object_and_line() {
    let src = "[materials.red]\nkind = \"phong\"\n\n[[objects]]\nkind = \"box\"\n\n[[objects]]\nkind = \"sphere\"\nname = \"ball\"\nmaterial = \"blue\"\n";
    let e = err(src, &mut Mem::default());
    assert_mentions(
        &e,
        &[&format!("test.toml:{}", line_of(src, "blue")), "objects[1]", "ball", "`blue`", "red"],
    );
}

#[test]
fn unknown_texture_names_the_material_and_line() {
    let src = format!("[materials.floor]\nkind = \"phong\"\ntexture = \"tiles\"\n{QUAD}");
    let e = err(&src, &mut Mem::default());
    assert_mentions(&e, &["test.toml:3", "materials.floor", "`tiles`"]);
}

#[test]
fn missing_asset_files_are_named_with_the_referring_line() {
    let src = format!("{QUAD}\n[[objects]]\nkind = \"obj\"\npath = \"meshes/gone.obj\"\n");
    let e = err(&src, &mut Mem::default());
    assert_mentions(
        &e,
        &[&format!("test.toml:{}", line_of(&src, "gone.obj")), "meshes/gone.obj", "objects[1]"],
    );

    let src = "[textures.t]\nkind = \"image\"\npath = \"textures/gone.png\"\n";
    let e = err(src, &mut Mem::default());
    assert_mentions(&e, &["test.toml:3", "textures/gone.png", "textures.t"]);

    // A texture named by an MTL library, resolved against the library's
    // directory: missing, it is a warning naming that path (exporters often
    // leave textures out), and the material keeps its Kd.
    let obj = "mtllib lib.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n";
    let src = "[[objects]]\nkind = \"obj\"\npath = \"m/tri.obj\"\n";
    let mut assets = Mem::default()
        .with("m/tri.obj", obj)
        .with("m/lib.mtl", "newmtl a\nKd 0.2 0.4 0.6\nmap_Kd tex/a.png\n");
    let p = load(src, &mut assets).unwrap();
    assert!(p.warnings.iter().any(|w| w.contains("m/tex/a.png") && w.contains("map_Kd")), "{:?}", p.warnings);
    assert!(
        matches!(p.materials[0], Material::Phong { albedo: Albedo::Constant(c), .. } if c == Vec3::new(0.2, 0.4, 0.6))
    );
    // `Tr` is 1 − d: with an index of refraction, a mostly transparent material is glass.
    let mut glass = Mem::default().with("m/tri.obj", obj).with("m/lib.mtl", "newmtl a\nNi 1.4\nTr 0.9\n");
    assert!(matches!(load(src, &mut glass).unwrap().materials[0], Material::Dielectric { .. }));
    // An undecodable one is still an error.
    let mut assets = assets.with("m/tex/a.png", b"not a png".to_vec());
    assert_mentions(&err(src, &mut assets), &["test.toml:3", "m/tex/a.png"]);

    let gltf = r#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":12,"uri":"data/buf.bin"}]}"#;
    let src = "[[objects]]\nkind = \"gltf\"\npath = \"g/a.gltf\"\n";
    let e = err(src, &mut Mem::default().with("g/a.gltf", gltf));
    assert_mentions(&e, &["test.toml:3", "g/data/buf.bin"]);
}

#[test]
fn bad_mesh_content_is_reported() {
    let src = "[[objects]]\nkind = \"obj\"\npath = \"bad.obj\"\n";
    let e = err(src, &mut Mem::default().with("bad.obj", "v 0 0 0\nf 1 2 3\n"));
    assert_mentions(&e, &["test.toml:3", "bad.obj", "objects[0]"]);
    let e = err(src, &mut Mem::default().with("bad.obj", "# nothing here\n"));
    assert_mentions(&e, &["test.toml:3", "bad.obj", "no triangles"]);
    let e = err(src, &mut Mem::default().with("bad.obj", "v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n"));
    assert_mentions(&e, &["test.toml:3", "not finite"]);

    let src = "[[objects]]\nkind = \"gltf\"\npath = \"bad.gltf\"\n";
    let e = err(src, &mut Mem::default().with("bad.gltf", "{ not json"));
    assert_mentions(&e, &["test.toml:3", "bad.gltf"]);
    let e = err(src, &mut Mem::default().with("bad.gltf", b"glTF\x02\0\0\0\x04\0\0\0".to_vec()));
    assert_mentions(&e, &["test.toml:3", "bad.gltf"]);
}

#[test]
fn invalid_cameras_are_rejected_with_the_camera_line() {
    let corners = |p1: &str| {
        format!(
            "{QUAD}\n[camera]\neye = [0, 0, 10]\np0 = [-4, 3, 0]\np1 = {p1}\np2 = [4, -3, 0]\np3 = [-4, -3, 0]\n"
        )
    };
    let src = corners("[-4, 3, 0]");
    let e = err(&src, &mut Mem::default());
    assert_mentions(&e, &[&format!("test.toml:{}", line_of(&src, "[camera]")), "zero area"]);
    let src = format!(
        "{QUAD}\n[camera]\neye = [0, 0, 0]\np0 = [-4, 3, 0]\np1 = [4, 3, 0]\np2 = [4, -3, 0]\np3 = [-4, -3, 0]\n"
    );
    let e = err(&src, &mut Mem::default());
    assert_mentions(&e, &[&format!("test.toml:{}", line_of(&src, "[camera]")), "eye"]);
    let src = format!("{QUAD}\n[camera]\neye = [0, 0, 0]\ntarget = [0, 0, 0]\n");
    let e = err(&src, &mut Mem::default());
    assert_mentions(&e, &[&format!("test.toml:{}", line_of(&src, "target")), "camera.target"]);
    let src = format!("{QUAD}\n[camera]\neye = [0, 0, 5]\np0 = [-4, 3, 0]\n");
    let e = err(&src, &mut Mem::default());
    assert_mentions(&e, &["camera.p1", "four corners"]);
    let src = format!("{QUAD}\n[camera]\neye = [0, 5, 0]\ntarget = [0, 0, 0]\n");
    let e = err(&src, &mut Mem::default());
    assert_mentions(&e, &["camera.up", "parallel"]);
}

#[test]
fn empty_scenes_are_rejected() {
    let e = err("ambient = 0.1\n[[lights]]\nkind = \"point\"\nposition = [0, 1, 0]\n", &mut Mem::default());
    assert_mentions(&e, &["test.toml", "empty"]);
    let e = err("", &mut Mem::default());
    assert_mentions(&e, &["test.toml", "empty"]);
}

#[test]
fn area_lights_need_three_or_four_vertices() {
    let src = format!("{QUAD}\n[[lights]]\nkind = \"area\"\nvertices = [[0, 0, 0], [1, 0, 0]]\n");
    let e = err(&src, &mut Mem::default());
    assert_mentions(
        &e,
        &[&format!("test.toml:{}", line_of(&src, "vertices")), "lights[0].vertices", "got 2"],
    );
    let src = format!(
        "{QUAD}\n[[lights]]\nkind = \"area\"\nvertices = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0.5, 0]]\n"
    );
    assert_mentions(&err(&src, &mut Mem::default()), &["got 5"]);
    let src = format!("{QUAD}\n[[lights]]\nkind = \"area\"\nvertices = [[0, 0, 0], [1, 0, 0], [2, 0, 0]]\n");
    assert_mentions(&err(&src, &mut Mem::default()), &["lights[0]", "zero area"]);
    let src = format!(
        "{QUAD}\n[[lights]]\nkind = \"area\"\nvertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]\n"
    );
    assert_mentions(&err(&src, &mut Mem::default()), &["lights[0]", "convex"]);
}

#[test]
fn fields_must_fit_the_kind() {
    let src = "[[objects]]\nkind = \"box\"\nsegments = 12\n";
    assert_mentions(
        &err(src, &mut Mem::default()),
        &["test.toml:3", "objects[0] (box).segments", "does not apply"],
    );
    let src = "[materials.m]\nkind = \"mirror\"\nior = 1.3\n";
    assert_mentions(&err(src, &mut Mem::default()), &["test.toml:3", "materials.m.ior"]);
    let src = "[textures.t]\nkind = \"checker\"\nscale = 4\n\n[materials.m]\nkind = \"phong\"\ntexture = \"t\"\ncolor = 1\n";
    assert_mentions(&err(src, &mut Mem::default()), &["test.toml:7", "not both"]);
    let src = "[[objects]]\nkind = \"box\"\nscale = [1, 0, 1]\n";
    assert_mentions(&err(src, &mut Mem::default()), &["test.toml:3", "scale", "zero"]);
    let src = "[[objects]]\nkind = \"sphere\"\nrings = 1\n";
    assert_mentions(&err(src, &mut Mem::default()), &["test.toml:3", "rings"]);
    let src = "[settings]\nwidth = 0\n";
    assert_mentions(&err(src, &mut Mem::default()), &["test.toml:2", "settings.width"]);
    let src = format!("{QUAD}\n[materials.m]\nkind = \"phong\"\ncolor = [1, -0.5, 0]\n");
    assert_mentions(
        &err(&src, &mut Mem::default()),
        &[&format!("test.toml:{}", line_of(&src, "color")), "negative"],
    );
}

// ───────────────────────── OBJ ─────────────────────────

const OBJ: &str = "mtllib ../mat/lib.mtl
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vn 0 0 1
o plain
usemtl matte
f 1/1/1 2/2/1 3/3/1 4/4/1
o shiny
usemtl chrome
f 1 2 3
o light
usemtl lamp
f 1 3 4
o glass
usemtl glass
f 1 2 4
";

const MTL: &str = "newmtl matte
Kd 0.5 0.25 0.125
Ks 0.1 0.1 0.1
Ns 20
newmtl chrome
Kd 0 0 0
Ks 0.9 0.9 0.9
illum 3
newmtl lamp
Kd 0 0 0
Ke 5 4 3
newmtl glass
Kd 0 0 0
Ni 1.33
d 0.1
";

fn obj_assets() -> Mem {
    Mem::default().with("meshes/sub/thing.obj", OBJ).with("meshes/mat/lib.mtl", MTL)
}

#[test]
fn obj_meshes_and_mtl_materials() {
    let src = "[[objects]]\nkind = \"obj\"\npath = \"meshes/sub/thing.obj\"\ntranslate = [0, 0, -5]\n";
    let p = load(src, &mut obj_assets()).unwrap();
    assert_eq!(p.triangles.len(), 5, "a quad triangulated into two + three triangles");
    // The quad: translated, normals from the file, v flipped (OBJ v=0 is the bottom).
    let quad: Vec<_> = (0..2).map(|i| (p.triangles[i], p.shading[i])).collect();
    for (t, s) in &quad {
        for ((v, n), uv) in t.v.iter().zip(s.normals).zip(s.uvs) {
            assert_eq!(v.z, -5.0);
            assert_eq!(n, Vec3::Z);
            assert_eq!(uv, Vec2::new(v.x, 1.0 - v.y), "uv of {v}");
        }
    }
    let material = |i: usize| &p.materials[p.shading[i].material as usize];
    assert!(
        matches!(material(0), Material::Phong { albedo: Albedo::Constant(c), specular, shininess, .. }
            if *c == Vec3::new(0.5, 0.25, 0.125) && *specular == Vec3::splat(0.1) && *shininess == 20.0),
        "{:?}",
        material(0)
    );
    assert_eq!(*material(2), Material::Mirror { tint: Vec3::splat(0.9) });
    assert_eq!(*material(3), Material::Emissive { radiance: Vec3::new(5.0, 4.0, 3.0) });
    assert!(matches!(material(4), Material::Dielectric { ior, .. } if (*ior - 1.33).abs() < 1e-6));
    // Flat triangles without normals in the file get their face normal.
    assert!(close(p.shading[2].normals[0], p.triangles[2].normal().normalize()));
}

#[test]
fn a_missing_mtl_library_falls_back_to_the_default_material() {
    let src = "[[objects]]\nkind = \"obj\"\npath = \"meshes/sub/thing.obj\"\n";
    let p = load(src, &mut Mem::default().with("meshes/sub/thing.obj", OBJ)).unwrap();
    assert_eq!(p.triangles.len(), 5);
    assert_eq!(p.materials, vec![Material::default()]);
    // A library that exists but does not parse is an error.
    let mut assets =
        Mem::default().with("meshes/sub/thing.obj", OBJ).with("meshes/mat/lib.mtl", "newmtl a\nKd 1 x\n");
    assert_mentions(&err(src, &mut assets), &["test.toml:3", "MTL"]);
}

/// A pyramid without normals: four slanted faces over a square (no base).
const PYRAMID: &str =
    "v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nv 0 1 0\nSMOOTH\nf 1 5 2\nf 2 5 3\nf 3 5 4\nf 4 5 1\n";

/// Whether any triangle's vertex normals differ from its face normal.
fn smooth_shaded(p: &SceneParts) -> bool {
    p.triangles
        .iter()
        .zip(&p.shading)
        .any(|(t, s)| s.normals.iter().any(|n| !close(*n, t.normal().normalize())))
}

#[test]
fn obj_smoothing_groups_and_the_smooth_keys_smooth_meshes_without_normals() {
    let obj = |s: &str| Mem::default().with("p.obj", PYRAMID.replace("SMOOTH", s));
    let src = |keys: &str| format!("[[objects]]\nkind = \"obj\"\npath = \"p.obj\"\n{keys}");
    assert!(!smooth_shaded(&load(&src(""), &mut obj("s off")).unwrap()), "s off: flat");
    let grouped = load(&src(""), &mut obj("s 1")).unwrap();
    assert!(smooth_shaded(&grouped), "s 1: smooth");
    // The apex normal of a smooth pyramid averages the four faces: straight up.
    let apex = grouped.triangles[0].v.iter().position(|v| v.y == 1.0).unwrap();
    assert!(close(grouped.shading[0].normals[apex], Vec3::Y), "{:?}", grouped.shading[0].normals);
    assert!(!smooth_shaded(&load(&src("smooth = false\n"), &mut obj("s 1")).unwrap()), "smooth = false wins");
    // Neighbouring faces bend by 60°: under a 30° crease angle they stay flat, under 90° they round.
    assert!(!smooth_shaded(&load(&src("smooth = true\n"), &mut obj("s off")).unwrap()), "30° default");
    assert!(smooth_shaded(&load(&src("smooth_angle = 90\n"), &mut obj("s off")).unwrap()));
    let e = err(&src("\nsmooth_angle = 200\n"), &mut obj(""));
    assert_mentions(&e, &["test.toml:5", "smooth_angle", "200"]);
    let e = err("[[objects]]\nkind = \"box\"\nsmooth = true\n", &mut Mem::default());
    assert_mentions(&e, &["test.toml:3", "smooth", "does not apply"]);
}

#[test]
fn a_sky_background_blends_from_the_horizon_to_the_zenith() {
    let src = "background = { zenith = [0, 0, 1], horizon = [1, 1, 0] }\n\n[camera]\neye = [0, 0, 0]\n\
               target = [0, 0, -1]\nfov = 90\n\n[[objects]]\nkind = \"quad\"\ntranslate = [0, -100, 0]\n";
    let scene = isin_tracer::load_scene("sky.toml", src, &mut Mem::default()).unwrap();
    assert_eq!(scene.background(Vec3::new(1.0, 0.0, 0.0)), Vec3::new(1.0, 1.0, 0.0), "horizon");
    assert_eq!(scene.background(Vec3::new(0.0, -1.0, 0.0)), Vec3::new(1.0, 1.0, 0.0), "below: horizon");
    assert_eq!(scene.background(Vec3::Y), Vec3::new(0.0, 0.0, 1.0), "zenith");
    let s = isin_tracer::RenderSettings { width: 8, height: 8, ..scene.settings };
    let rgb =
        isin_tracer::render_tile(&scene, &scene.camera, &s, isin_tracer::Tile { x: 0, y: 0, w: 8, h: 8 });
    let (top, middle) = (&rgb[3 * 4..3 * 4 + 3], &rgb[3 * (8 * 4 + 4)..3 * (8 * 4 + 4) + 3]);
    assert!(top[2] > middle[2] && top[0] < middle[0], "bluer up, yellower level: {top:?} {middle:?}");
    let e = err("background = { zenith = [0, 0, 1] }\n", &mut Mem::default());
    assert_mentions(&e, &["test.toml:1", "a sky { zenith"]);
    let e = err("background = { zenith = [0, 0, 1], horizon = [-1, 0, 0] }\n", &mut Mem::default());
    assert_mentions(&e, &["background", "negative"]);
}

#[test]
fn a_scene_without_any_light_is_warned_about() {
    let dark = load_ok(QUAD);
    assert!(
        dark.warnings.iter().any(|w| w.contains("no lights") && w.contains("black")),
        "{:?}",
        dark.warnings
    );
    let ambient = load_ok(&format!("ambient = 0.1\n{QUAD}"));
    assert!(ambient.warnings.iter().any(|w| w.contains("only by the ambient")), "{:?}", ambient.warnings);
    let lit = load_ok(&format!("[[lights]]\nkind = \"point\"\nposition = [0, 1, 0]\n\n{QUAD}"));
    assert_eq!(lit.warnings, Vec::<String>::new());
    let glowing = load_ok(&format!(
        "[materials.lamp]\nkind = \"emissive\"\nradiance = 2\n\n{QUAD}material = \"lamp\"\n"
    ));
    assert_eq!(glowing.warnings, Vec::<String>::new(), "an emissive surface lights the scene");
}

/// A 16 × 8 Radiance HDR: the top half bright green (3), the bottom half
/// red on the left (u < ½) and blue on the right.
fn hdr_sky() -> Vec<u8> {
    let img = image::Rgb32FImage::from_fn(16, 8, |x, y| match (x < 8, y < 4) {
        (_, true) => image::Rgb([0.0, 3.0, 0.0]),
        (true, false) => image::Rgb([1.0, 0.0, 0.0]),
        (false, false) => image::Rgb([0.0, 0.0, 1.0]),
    });
    let mut out = Vec::new();
    image::DynamicImage::ImageRgb32F(img)
        .write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Hdr)
        .unwrap();
    out
}

#[test]
fn an_equirectangular_hdr_background_is_seen_by_escaping_rays() {
    let src = |extra: &str| {
        format!("background = {{ image = \"sky/env.hdr\"{extra} }}\n{QUAD}translate = [0, -50, 0]\n")
    };
    let mut assets = Mem::default().with("sky/env.hdr", hdr_sky());
    let scene = isin_tracer::load_scene("env.toml", &src(""), &mut assets).unwrap();
    assert!(
        close(scene.background(Vec3::Y), Vec3::new(0.0, 3.0, 0.0)),
        "up: the top rows, radiance above 1 kept"
    );
    // Looking along −Z the centre column; a little towards +X is the right half.
    let down_right = Vec3::new(0.3, -0.5, -1.0).normalize();
    let down_left = Vec3::new(-0.3, -0.5, -1.0).normalize();
    assert!(close(scene.background(down_right), Vec3::Z), "{}", scene.background(down_right));
    assert!(close(scene.background(down_left), Vec3::X), "{}", scene.background(down_left));
    // Turned half a turn and twice as strong: the halves swap.
    let turned =
        isin_tracer::load_scene("env.toml", &src(", rotate = 180, strength = 2"), &mut assets).unwrap();
    assert!(close(turned.background(down_right), Vec3::X * 2.0), "{}", turned.background(down_right));
    let e = err(&src(""), &mut Mem::default().with("sky/env.hdr", b"#?RADIANCE\nbroken".to_vec()));
    assert_mentions(&e, &["test.toml:1", "background", "sky/env.hdr"]);
    let e = err(&src(""), &mut Mem::default());
    assert_mentions(&e, &["test.toml:1", "sky/env.hdr"]);
}

#[test]
fn a_camera_inside_the_scene_that_sees_nothing_is_warned_about() {
    // Two far-apart quads make a large box; the default camera (at z = 12.5,
    // looking along −Z) stands inside it, looking at empty space.
    let light = "[[lights]]\nkind = \"point\"\nposition = [0, 1, 0]\n\n";
    let far = format!("{light}{QUAD}translate = [0, -50, 40]\n\n{QUAD}translate = [0, 50, -40]\n");
    let p = load_ok(&far);
    assert!(p.warnings.iter().any(|w| w.contains("inside the scene's bounding box")), "{:?}", p.warnings);
    // Facing a wall in the same box: no warning.
    let wall = format!("{far}\n[[objects]]\nkind = \"box\"\nscale = [20, 20, 1]\ntranslate = [0, 0, -10]\n");
    assert_eq!(load_ok(&wall).warnings, Vec::<String>::new());
}

#[test]
fn an_objects_material_overrides_the_mtl() {
    let src = "[materials.gold]\nkind = \"mirror\"\ntint = [1, 0.8, 0.3]\n\n[[objects]]\nkind = \"obj\"\n\
               path = \"meshes/sub/thing.obj\"\nmaterial = \"gold\"\n";
    let p = load(src, &mut obj_assets()).unwrap();
    assert_eq!(p.materials.len(), 1, "MTL materials are not added");
    assert!(p.shading.iter().all(|s| s.material == 0));
}

#[test]
fn shared_cornell_box_obj_loads_with_its_mtl() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/meshes/cornell_box");
    if !dir.join("CornellBox-Original.obj").exists() {
        eprintln!("skipping: {} is absent", dir.display());
        return;
    }
    let src = "[[objects]]\nkind = \"obj\"\npath = \"CornellBox-Original.obj\"\n";
    let mut assets = Dir { base: dir, read: BTreeMap::new() };
    let p = parse_scene("cornell-obj.toml", src, &mut assets).unwrap_or_else(|e| panic!("{e}"));
    assert!(assets.read.contains_key("CornellBox-Original.mtl"));
    assert!(p.triangles.len() >= 30, "{}", p.triangles.len());
    assert!(has_material(&p, |m| matches!(m, Material::Emissive { .. })), "the ceiling light (Ke)");
    assert!(has_material(
        &p,
        |m| matches!(m, Material::Phong { albedo: Albedo::Constant(c), .. } if c.x > 0.6 && c.y < 0.1)
    ));
}

#[test]
fn shared_meshes_load_through_scene_files() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/meshes");
    for (file, min_tris, has_uvs) in
        [("dragon/dragon_100k.obj", 99_000, false), ("spot/spot_triangulated.obj", 5_800, true)]
    {
        if !dir.join(file).exists() {
            eprintln!("skipping: {} is absent", dir.join(file).display());
            continue;
        }
        let src = format!("[[objects]]\nkind = \"obj\"\npath = \"{file}\"\n");
        let mut assets = Dir { base: dir.clone(), read: BTreeMap::new() };
        let p = parse_scene("shared.toml", &src, &mut assets).unwrap_or_else(|e| panic!("{e}"));
        assert!(p.triangles.len() >= min_tris, "{file}: {}", p.triangles.len());
        let any_uv = p.shading.iter().any(|s| s.uvs.iter().any(|uv| *uv != Vec2::ZERO));
        assert_eq!(any_uv, has_uvs, "{file}");
        for s in &p.shading {
            assert!(s.normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-3), "{file}");
        }
    }
}

// ───────────────────────── glTF ─────────────────────────

fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
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

/// A unit quad in the XY plane (two triangles, indexed) with normals and UVs:
/// positions, normals, uvs, u16 indices (padded to 4 bytes).
fn quad_buffer() -> (Vec<u8>, [usize; 4]) {
    let mut data = f32_bytes(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 0.0]);
    let p = data.len();
    data.extend(f32_bytes(&[0.0, 0.0, 1.0].repeat(4)));
    let n = data.len();
    data.extend(f32_bytes(&[0.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0]));
    let t = data.len();
    for i in [0u16, 1, 2, 0, 2, 3] {
        data.extend(i.to_le_bytes());
    }
    let i = data.len();
    (data, [p, n, t, i])
}

/// glTF JSON for the quad under a parent node translated by (10, 0, 0) and a
/// child rotated 90° about Y and scaled by 2, with `material` and `buffer`
/// (a JSON object for buffers[0]).
fn quad_gltf(material: &str, buffer: &str, extra: &str) -> String {
    let (_, [p, n, t, i]) = quad_buffer();
    format!(
        r#"{{
  "asset": {{"version": "2.0"}},
  "scene": 0,
  "scenes": [{{"nodes": [0]}}],
  "nodes": [
    {{"translation": [10, 0, 0], "children": [1]}},
    {{"mesh": 0, "rotation": [0, 0.70710678, 0, 0.70710678], "scale": [2, 2, 2]}}
  ],
  "meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2}}, "indices": 3, "material": 0}}]}}],
  "materials": [{material}],
  "accessors": [
    {{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0,0,0], "max": [1,1,0]}},
    {{"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"}},
    {{"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC2"}},
    {{"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"}}
  ],
  "bufferViews": [
    {{"buffer": 0, "byteOffset": 0, "byteLength": {p}}},
    {{"buffer": 0, "byteOffset": {p}, "byteLength": {}}},
    {{"buffer": 0, "byteOffset": {n}, "byteLength": {}}},
    {{"buffer": 0, "byteOffset": {t}, "byteLength": {}}}
  ],
  "buffers": [{buffer}]{extra}
}}"#,
        n - p,
        t - n,
        i - t
    )
}

const PLAIN: &str = r#"{"pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.2, 0.1, 1], "metallicFactor": 0, "roughnessFactor": 0.5}}"#;
const GLTF_SCENE: &str =
    "[[objects]]\nkind = \"gltf\"\npath = \"models/quad.gltf\"\ntranslate = [0, 0, -3]\n";

fn check_quad_world_positions(p: &SceneParts) {
    assert_eq!(p.triangles.len(), 2);
    // Local (x, y, 0): scaled by 2, rotated 90° about Y (x → -z), moved by
    // (10, 0, 0) in the parent, then by (0, 0, -3) from the scene file.
    let world = |x: f32, y: f32| Vec3::new(10.0, 2.0 * y, -3.0 - 2.0 * x);
    let t = &p.triangles[0];
    for (got, want) in t.v.iter().zip([world(0.0, 0.0), world(1.0, 0.0), world(1.0, 1.0)]) {
        assert!(close(*got, want), "{got} vs {want}");
    }
    for s in &p.shading {
        for n in s.normals {
            assert!(close(n, Vec3::X), "normal +Z rotated to +X: {n}");
        }
    }
    assert_eq!(
        p.shading[0].uvs,
        [Vec2::new(0.0, 1.0), Vec2::new(1.0, 1.0), Vec2::new(1.0, 0.0)],
        "glTF UVs as stored"
    );
}

#[test]
fn gltf_node_hierarchy_places_the_mesh_in_world_space() {
    let (data, _) = quad_buffer();
    let buffer = format!(
        r#"{{"byteLength": {}, "uri": "data:application/octet-stream;base64,{}"}}"#,
        data.len(),
        b64(&data)
    );
    let mut assets = Mem::default().with("models/quad.gltf", quad_gltf(PLAIN, &buffer, ""));
    let p = load(GLTF_SCENE, &mut assets).unwrap();
    check_quad_world_positions(&p);
    let Material::Pbr(m) = &p.materials[0] else { panic!("{:?}", p.materials[0]) };
    assert!(close(m.base_color, Vec3::new(0.8, 0.2, 0.1)));
    assert_eq!((m.metallic, m.roughness), (0.0, 0.5));
}

#[test]
fn gltf_external_buffers_resolve_relative_to_the_gltf_file() {
    let (data, _) = quad_buffer();
    let buffer = format!(r#"{{"byteLength": {}, "uri": "bin/quad%20data.bin"}}"#, data.len());
    let mut assets = Mem::default()
        .with("models/quad.gltf", quad_gltf(PLAIN, &buffer, ""))
        .with("models/bin/quad data.bin", data);
    check_quad_world_positions(&load(GLTF_SCENE, &mut assets).unwrap());
}

#[test]
fn glb_binary_chunk_is_used() {
    let (data, _) = quad_buffer();
    let buffer = format!(r#"{{"byteLength": {}}}"#, data.len());
    let json = quad_gltf(PLAIN, &buffer, "");
    let glb = gltf::binary::Glb {
        header: gltf::binary::Header { magic: *b"glTF", version: 2, length: 0 },
        json: json.into_bytes().into(),
        bin: Some(data.into()),
    };
    let bytes = glb.to_vec().unwrap();
    let src = GLTF_SCENE.replace("quad.gltf", "quad.glb");
    check_quad_world_positions(&load(&src, &mut Mem::default().with("models/quad.glb", bytes)).unwrap());
}

#[test]
fn gltf_materials_map_to_whitted_materials() {
    let (data, _) = quad_buffer();
    let buffer = format!(
        r#"{{"byteLength": {}, "uri": "data:application/octet-stream;base64,{}"}}"#,
        data.len(),
        b64(&data)
    );
    type Check = fn(&Material) -> bool;
    let cases: [(&str, Check); 5] = [
        (
            r#"{"pbrMetallicRoughness": {"baseColorFactor": [1, 0.8, 0.4, 1], "metallicFactor": 1, "roughnessFactor": 0.05}}"#,
            |m| matches!(m, Material::Pbr(p) if p.base_color == Vec3::new(1.0, 0.8, 0.4) && p.roughness == 0.05),
        ),
        (
            r#"{"emissiveFactor": [2, 2, 1], "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 3}}}"#,
            |m| matches!(m, Material::Pbr(p) if p.emissive == Vec3::new(6.0, 6.0, 3.0)),
        ),
        (r#"{"alphaMode": "BLEND", "pbrMetallicRoughness": {"baseColorFactor": [0.9, 1, 0.9, 0.2]}}"#, |m| {
            matches!(m, Material::Dielectric { .. })
        }),
        (
            r#"{"extensions": {"KHR_materials_transmission": {"transmissionFactor": 1}, "KHR_materials_ior": {"ior": 1.33}}}"#,
            |m| matches!(m, Material::Dielectric { ior, .. } if *ior == 1.33),
        ),
        (
            r#"{}"#,
            |m| matches!(m, Material::Pbr(p) if p.metallic == 1.0 && p.roughness == 1.0 && p.base_color == Vec3::ONE),
        ),
    ];
    for (json, check) in cases {
        let mut assets = Mem::default().with("models/quad.gltf", quad_gltf(json, &buffer, ""));
        let p = load(GLTF_SCENE, &mut assets).unwrap();
        assert!(check(&p.materials[0]), "{json} → {:?}", p.materials[0]);
    }
}

#[test]
fn malformed_gltf_accessors_are_errors_not_panics() {
    let (data, _) = quad_buffer();
    let short = &data[..40];
    let buffer = format!(
        r#"{{"byteLength": {}, "uri": "data:application/octet-stream;base64,{}"}}"#,
        short.len(),
        b64(short)
    );
    let mut assets = Mem::default().with("models/quad.gltf", quad_gltf(PLAIN, &buffer, ""));
    let e = err(GLTF_SCENE, &mut assets);
    assert_mentions(&e, &["test.toml:3", "models/quad.gltf"]);

    let (data, _) = quad_buffer();
    let buffer = format!(
        r#"{{"byteLength": {}, "uri": "data:application/octet-stream;base64,{}"}}"#,
        data.len(),
        b64(&data)
    );
    let good = quad_gltf(PLAIN, &buffer, "");
    let mutations = [
        (r#""count": 4, "type": "VEC3", "min""#, r#""count": 4, "type": "VEC2", "min""#),
        (
            r#""componentType": 5126, "count": 4, "type": "VEC3", "min""#,
            r#""componentType": 5121, "count": 4, "type": "VEC3", "min""#,
        ),
        (r#""componentType": 5123, "count": 6"#, r#""componentType": 5123, "count": 600"#),
        (r#""componentType": 5123, "count": 6"#, r#""componentType": 5123, "count": 18446744073709551615"#),
        (r#""byteOffset": 0, "byteLength""#, r#""byteOffset": 0, "byteStride": 4, "byteLength""#),
        (r#""nodes": [0]}"#, r#""nodes": [7]}"#),
    ];
    for (from, to) in mutations {
        assert!(good.contains(from), "{from}");
        let mut assets = Mem::default().with("models/quad.gltf", good.replacen(from, to, 1));
        let e = err(GLTF_SCENE, &mut assets);
        assert_mentions(&e, &["test.toml:3", "models/quad.gltf"]);
    }
    // Indices beyond the vertex count.
    let mut data = data;
    let n = data.len();
    data[n - 2..].copy_from_slice(&9u16.to_le_bytes());
    let buffer = format!(
        r#"{{"byteLength": {}, "uri": "data:application/octet-stream;base64,{}"}}"#,
        data.len(),
        b64(&data)
    );
    let mut assets = Mem::default().with("models/quad.gltf", quad_gltf(PLAIN, &buffer, ""));
    assert_mentions(&err(GLTF_SCENE, &mut assets), &["out of range"]);
}

fn png_2x2() -> Vec<u8> {
    let img = image::RgbaImage::from_fn(2, 2, |x, y| image::Rgba([(x * 255) as u8, (y * 255) as u8, 0, 255]));
    let mut out = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png).unwrap();
    out
}

#[test]
fn gltf_base_colour_textures_load() {
    let (data, _) = quad_buffer();
    let buffer = format!(
        r#"{{"byteLength": {}, "uri": "data:application/octet-stream;base64,{}"}}"#,
        data.len(),
        b64(&data)
    );
    let material = r#"{"pbrMetallicRoughness": {"baseColorFactor": [1, 0.5, 1, 1], "baseColorTexture": {"index": 0}, "metallicFactor": 0}}"#;
    let extra = r#", "textures": [{"source": 0}], "images": [{"uri": "tex/checker.png"}]"#;
    let mut assets = Mem::default()
        .with("models/quad.gltf", quad_gltf(material, &buffer, extra))
        .with("models/tex/checker.png", png_2x2());
    let p = load(GLTF_SCENE, &mut assets).unwrap();
    assert_eq!(p.textures.len(), 1);
    assert!(matches!(p.textures[0], Texture::Image(_)));
    assert!(
        matches!(&p.materials[0], Material::Pbr(m) if m.base_texture.is_some_and(|t| t.texture == 0) && m.base_color.y == 0.5)
    );
}

#[test]
fn image_textures_are_shared_between_references() {
    let src = "[textures.a]\nkind = \"image\"\npath = \"t.png\"\n\n[textures.b]\nkind = \"image\"\npath = \"./t.png\"\n\n\
               [materials.m]\nkind = \"phong\"\ntexture = \"b\"\n\n[[objects]]\nkind = \"quad\"\nmaterial = \"m\"\n";
    let p = load(src, &mut Mem::default().with("t.png", png_2x2())).unwrap();
    assert_eq!(p.textures.len(), 1);
    assert_eq!(
        p.textures[0],
        Texture::Image(isin_tracer::textures::MipMap::from_srgb8(
            2,
            2,
            &image::load_from_memory(&png_2x2()).unwrap().to_rgba8()
        ))
    );
}

#[test]
fn undecodable_images_are_reported() {
    let src = "[textures.a]\nkind = \"image\"\npath = \"t.png\"\n";
    let e = err(src, &mut Mem::default().with("t.png", b"not a png".to_vec()));
    assert_mentions(&e, &["test.toml:3", "textures.a", "t.png"]);
}

// ───────────────────────── bundles ─────────────────────────

#[test]
fn scene_bundles_round_trip_through_messagepack() {
    let src = "[[objects]]\nkind = \"obj\"\npath = \"meshes/sub/thing.obj\"\n\n[[objects]]\nkind = \"sphere\"\n\
               translate = [3, 0, 0]\n";
    // Record what loading reads, as the binary does.
    struct Recording(Mem, BTreeMap<String, Vec<u8>>);
    impl AssetSource for Recording {
        fn read(&mut self, path: &str) -> Result<Vec<u8>, String> {
            let bytes = self.0.read(path)?;
            self.1.insert(path.to_owned(), bytes.clone());
            Ok(bytes)
        }
    }
    let mut rec = Recording(obj_assets(), BTreeMap::new());
    let direct = parse_scene("bundle.toml", src, &mut rec).unwrap();
    let bundle = SceneBundle { name: "bundle.toml".into(), source: src.into(), assets: rec.1 };
    assert_eq!(bundle.assets.len(), 2, "the OBJ and its MTL");
    let bytes = rmp_serde::to_vec(&bundle).unwrap();
    let back: SceneBundle = rmp_serde::from_slice(&bytes).unwrap();
    assert_eq!(back, bundle);
    let scene = back.load().unwrap();
    assert_eq!(scene.triangles, direct.triangles);
    assert_eq!(scene.shading, direct.shading);
    assert_eq!(scene.materials, direct.materials);
    // A bundle missing an asset fails with the asset's name.
    let mut broken = back.clone();
    broken.assets.remove("meshes/sub/thing.obj");
    let e = broken.load().expect_err("missing OBJ").to_string();
    assert_mentions(&e, &["bundle.toml:3", "meshes/sub/thing.obj", "not in the scene bundle"]);
}

#[test]
fn settings_beyond_the_limits_are_refused_or_clamped_as_everywhere_else() {
    // Refused before any work, naming the limit.
    let e = err("[settings]\nlight_samples = 1000000000\n", &mut Mem::default());
    assert_mentions(&e, &["test.toml", "light_samples", "above the limit of 4096"]);
    let e = err("[settings]\nwidth = 100000\n", &mut Mem::default());
    assert_mentions(&e, &["settings.width", "above the limit of 16384"]);
    // Deeper than any frame is rendered: clamped, with one warning, so a
    // cluster (sent the clamped settings) renders it as a local render does.
    let src = "[settings]\nmax_depth = 1000000\n[[objects]]\nkind = \"sphere\"\n";
    let parts = parse_scene("deep.toml", src, &mut Mem::default()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(parts.settings.max_depth, 64);
    assert_eq!(parts.warnings.iter().filter(|w| w.contains("max_depth")).count(), 1, "{:?}", parts.warnings);
}

#[test]
fn a_number_too_large_for_the_tracer_says_so() {
    let e = err("[[lights]]\nkind = \"point\"\nposition = [0, 1, 0]\npower = 1e308\n", &mut Mem::default());
    assert_mentions(&e, &["test.toml:4", "too large"]);
}

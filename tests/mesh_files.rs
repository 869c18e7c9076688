//! Mesh files opened directly: `isin render FILE.gltf|.obj` makes a scene
//! around the mesh, and `isin scene FILE` prints that scene as TOML that
//! renders to the same bytes.

use std::path::{Path, PathBuf};
use std::process::Command;

fn scenes_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes")
}

fn isin(dir: &Path, args: &[&str]) -> Vec<u8> {
    let out = Command::new(env!("CARGO_BIN_EXE_isin")).args(args).current_dir(dir).output().unwrap();
    assert!(out.status.success(), "isin {args:?} failed:\n{}", String::from_utf8_lossy(&out.stderr));
    out.stdout
}

/// Renders `target` (in `dir`) small and returns the PNG's bytes.
fn render(dir: &Path, target: &str, out: &str) -> Vec<u8> {
    isin(dir, &["render", target, "-o", out, "--width", "80", "--height", "60", "--spp", "1", "--quiet"]);
    std::fs::read(dir.join(out)).unwrap()
}

#[test]
fn mesh_files_render_directly_and_their_printed_scene_renders_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir(dir.path().join("models")).unwrap();
    for (mesh, extra) in [("gem.gltf", None), ("knot.obj", Some("knot.mtl"))] {
        for f in std::iter::once(mesh).chain(extra) {
            std::fs::copy(scenes_dir().join("meshes").join(f), dir.path().join("models").join(f)).unwrap();
        }
        let direct = render(dir.path(), &format!("models/{mesh}"), "direct.png");
        let text = isin(dir.path(), &["scene", &format!("models/{mesh}")]);
        let text = String::from_utf8(text).unwrap();
        assert!(text.contains(&format!("path = \"models/{mesh}\"")), "{text}");
        std::fs::write(dir.path().join("made.toml"), &text).unwrap();
        let saved = render(dir.path(), "made.toml", "saved.png");
        assert_eq!(direct, saved, "{mesh}: the printed scene renders to other pixels");
        let img = image::load_from_memory(&direct).unwrap().to_rgb8();
        // The model is lit and framed: the centre pixel is neither black nor the background.
        let centre = img.get_pixel(40, 30).0;
        assert!(centre.iter().any(|&c| c > 40), "{mesh}: the centre is dark: {centre:?}");
    }
}

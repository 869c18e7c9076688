//! The `isin` binary needs nothing beside it: copied alone into an empty
//! folder and run there with no arguments and no display, it renders its
//! built-in default scene through its in-process cluster and writes
//! `paper.png` into that folder — the same pixels as `isin render
//! scenes/paper.toml` in the checkout — and nothing else.

use std::path::Path;
use std::process::{Command, Stdio};

#[test]
fn the_binary_alone_in_an_empty_folder_writes_paper_png() {
    let dir = tempfile::tempdir().expect("temp dir");
    let exe = dir.path().join("isin");
    std::fs::copy(env!("CARGO_BIN_EXE_isin"), &exe).expect("copy the binary");
    // The home folder is that one too: no configuration or cache elsewhere is read.
    let run = Command::new(&exe)
        .current_dir(dir.path())
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .env_remove("ISIN_TICKET")
        .env("HOME", dir.path())
        .env("RUST_LOG", "warn")
        .env("RUST_BACKTRACE", "0")
        .stdin(Stdio::null())
        .output()
        .expect("the copied binary runs");
    let said = format!("{}\n{}", String::from_utf8_lossy(&run.stdout), String::from_utf8_lossy(&run.stderr));
    assert!(run.status.success(), "isin alone failed:\n{said}");

    let mut left: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    left.sort();
    assert_eq!(left, ["isin", "paper.png"], "isin alone left other files than paper.png:\n{said}");

    // The checkout's `isin render` of the same scene, for comparison.
    let reference = dir.path().join("reference.png");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let render = Command::new(env!("CARGO_BIN_EXE_isin"))
        .current_dir(root)
        .args(["render", "scenes/paper.toml", "--quiet", "-o"])
        .arg(&reference)
        .env_remove("ISIN_TICKET")
        .env("RUST_LOG", "warn")
        .stdin(Stdio::null())
        .output()
        .expect("isin render runs");
    assert!(render.status.success(), "{}", String::from_utf8_lossy(&render.stderr));
    let pixels = |p: &Path| image::open(p).unwrap_or_else(|e| panic!("{}: {e}", p.display())).to_rgb8();
    let (ours, theirs) = (pixels(&dir.path().join("paper.png")), pixels(&reference));
    assert_eq!(ours.dimensions(), theirs.dimensions());
    assert!(ours.as_raw() == theirs.as_raw(), "paper.png differs from isin render scenes/paper.toml");
}

//! `isin render --width/--height`: a size given on one side keeps the scene's
//! aspect ratio, and another shape widens the view instead of stretching it.

use std::path::Path;
use std::process::Command;

fn render(args: &[&str], out: &Path) -> image::RgbImage {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell.toml");
    let status = Command::new(env!("CARGO_BIN_EXE_isin"))
        .arg("render")
        .arg(&scene)
        .args(["--quiet", "--spp", "1", "-o"])
        .arg(out)
        .args(args)
        .output()
        .unwrap();
    assert!(status.status.success(), "{}", String::from_utf8_lossy(&status.stderr));
    image::open(out).unwrap().to_rgb8()
}

#[test]
fn width_alone_keeps_the_scenes_aspect_and_other_shapes_are_not_stretched() {
    let dir = tempfile::tempdir().unwrap();
    // cornell.toml is square.
    let square = render(&["--width", "40"], &dir.path().join("a.png"));
    assert_eq!(square.dimensions(), (40, 40));
    assert_eq!(render(&["--height", "30"], &dir.path().join("b.png")).dimensions(), (30, 30));
    // Twice as wide: the square view sits unchanged in the middle, with more at the sides.
    let wide = render(&["--width", "80", "--height", "40"], &dir.path().join("c.png"));
    assert_eq!(wide.dimensions(), (80, 40));
    let differing = (0..40)
        .flat_map(|y| (0..40).map(move |x| (x, y)))
        .filter(|&(x, y)| {
            let (a, b) = (square.get_pixel(x, y).0, wide.get_pixel(x + 20, y).0);
            a.iter().zip(b).any(|(p, q)| p.abs_diff(q) > 2)
        })
        .count();
    assert!(differing < 40 * 40 / 20, "{differing} of the centre's pixels changed: the view was stretched");
}

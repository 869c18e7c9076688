//! End to end: `isin fly` of keyframed camera paths — real files, the real
//! binary.
//!
//! - `fly_writes_one_frame_per_sample…`: keys from 1.0 s to 2.25 s at 10 fps
//!   make frames at 1.0, 1.1, … 2.2 s: `fly` writes exactly those, each a
//!   different view; a single key makes one frame.
//! - `the_shipped_orbit…`: `scenes/paths/orbit.toml`, the README's full example,
//!   loads, samples a frame every 1/fps from its first key to its last, and
//!   flies.
//! - `a_bad_key…`: `fly` refuses a key that looks at its own eye, naming the
//!   file, the line and the key, and writes nothing.
//! - `the_readme_example…`: the README's example path makes as many frames as
//!   the README says.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `isin fly scenes/paper.toml --path PATH --out OUT EXTRA…` at 32 × 24, fast.
fn fly(path: &Path, out: &Path, extra: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_isin"))
        .arg("fly")
        .arg(repo().join("scenes/paper.toml"))
        .arg("--path")
        .arg(path)
        .arg("--out-dir")
        .arg(out)
        .args(["--width", "32", "--height", "24", "--fast"])
        .args(extra)
        .env("RUST_BACKTRACE", "0")
        .output()
        .unwrap()
}

/// The `frame_NNNN.png` files in `dir`, sorted.
fn frames_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = match std::fs::read_dir(dir) {
        Ok(entries) => entries.map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect(),
        Err(_) => Vec::new(),
    };
    names.sort();
    names
}

/// A version-2 path of look-at keys at times `times`, sampled at `fps`.
fn keyed(fps: f64, times: &[f64]) -> String {
    let mut text = format!("version = 2\nfps = {fps}\ninterpolation = \"linear\"\n");
    for (i, t) in times.iter().enumerate() {
        let x = i as f64 * 1.5 - 1.5;
        text += &format!("\n[[key]]\nt = {t:?}\neye = [{x:?}, 2.5, 9.0]\nlook_at = [0.0, 1.2, -4.5]\n");
    }
    text
}

#[test]
fn fly_writes_one_frame_per_sample_of_a_keyframed_path() {
    let dir = tempfile::tempdir().unwrap();
    let (fps, times) = (10.0, [1.0, 1.6, 2.25]);
    let path = dir.path().join("keys.toml");
    std::fs::write(&path, keyed(fps, &times)).unwrap();
    let out = dir.path().join("out");
    let run = fly(&path, &out, &[]);
    assert!(run.status.success(), "isin fly failed: {}", String::from_utf8_lossy(&run.stderr));
    // Frame i at 1.0 + i/10 s while that is not past 2.25 s.
    let expected = (0..).take_while(|&i| times[0] + i as f64 / fps <= times[2]).count();
    assert_eq!(expected, 13);
    let names = frames_in(&out);
    assert_eq!(names, (0..expected).map(|i| format!("frame_{i:04}.png")).collect::<Vec<_>>());
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(stdout.contains(&format!("flying {expected} frames")), "{stdout}");
    let images: Vec<_> =
        names.iter().map(|n| image::open(out.join(n)).unwrap().to_rgb8().into_raw()).collect();
    assert!(images.windows(2).all(|w| w[0] != w[1]), "every sampled frame is a new view");

    // One key: one frame.
    std::fs::write(&path, keyed(fps, &[3.0])).unwrap();
    let one = dir.path().join("one");
    let run = fly(&path, &one, &[]);
    assert!(run.status.success(), "isin fly failed: {}", String::from_utf8_lossy(&run.stderr));
    assert_eq!(frames_in(&one), ["frame_0000.png"]);
}

#[test]
fn the_shipped_orbit_samples_every_frame_from_its_first_key_to_its_last_and_flies() {
    let file = repo().join("scenes/paths/orbit.toml");
    let path = isin_viewer::CameraPath::load(&file).unwrap();
    let sampling = path.sampling.expect("orbit.toml is keyframed");
    assert!(sampling.keys >= 6, "an orbit needs keys all round: {} keys", sampling.keys);
    let text = std::fs::read_to_string(&file).unwrap();
    // The keys' times as written, read without the path module.
    let times: Vec<f64> = text
        .lines()
        .filter_map(|l| l.strip_prefix("t = "))
        .map(|v| v.split('#').next().unwrap().trim().parse().unwrap())
        .collect();
    assert_eq!(times.len(), sampling.keys);
    let (first, last) = (times[0], times[times.len() - 1]);
    let expected = ((last - first) * sampling.fps + 1e-9).floor() as usize + 1;
    assert_eq!(path.frames.len(), expected);
    assert_eq!(path.frames[0].t, first);
    assert_eq!(path.frames[expected - 1].t, last, "the last frame lands on the last key");
    for (i, f) in path.frames.iter().enumerate() {
        assert!((f.t - (first + i as f64 / sampling.fps)).abs() < 1e-9, "frame {i} at {} s", f.t);
    }
    let out = tempfile::tempdir().unwrap();
    let run = fly(&file, out.path(), &["--frames", "100..103"]);
    assert!(run.status.success(), "isin fly failed: {}", String::from_utf8_lossy(&run.stderr));
    assert_eq!(frames_in(out.path()), ["frame_0100.png", "frame_0101.png", "frame_0102.png"]);
}

#[test]
fn a_bad_key_is_refused_naming_the_file_line_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let text = keyed(24.0, &[0.0, 1.0, 2.0]).replace("eye = [0.0, 2.5, 9.0]", "eye = [0.0, 1.2, -4.5]");
    // Key 1's `look_at` line (1-based).
    let line = text.lines().enumerate().filter(|(_, l)| l.starts_with("look_at")).nth(1).unwrap().0 + 1;
    let path = dir.path().join("bad.toml");
    std::fs::write(&path, &text).unwrap();
    let out = dir.path().join("out");
    let run = fly(&path, &out, &[]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success(), "a key looking at its own eye was flown");
    let want = format!("camera path {}:{line}: key 1: `look_at`", path.display());
    assert!(stderr.contains(&want), "{stderr:?} should contain {want:?}");
    assert!(frames_in(&out).is_empty(), "frames were written");
}

#[test]
fn the_readme_example_makes_the_frames_the_readme_says() {
    let readme = std::fs::read_to_string(repo().join("README.md")).unwrap();
    let section = &readme[readme.find("## Camera paths").expect("a Camera paths section")..];
    let start = section.find("```toml\n").expect("an example") + "```toml\n".len();
    let example = &section[start..start + section[start..].find("```").unwrap()];
    let path = isin_viewer::CameraPath::parse(Path::new("README.md"), example).unwrap();
    let said = section.split("makes ").nth(1).and_then(|s| s.split(' ').next()).expect("makes N frames");
    assert_eq!(said.parse::<usize>().unwrap(), path.frames.len(), "the README's count is wrong");
}

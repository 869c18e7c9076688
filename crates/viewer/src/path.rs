//! Camera paths: a recorded navigation, or keyframes, replayed headless by
//! `isin fly`.
//!
//! # Format (TOML)
//!
//! A recorded path (version 1, as `isin view --record` writes it) lists every
//! camera the viewer asked to render (every move, not every refinement pass),
//! in order, with non-decreasing `t`:
//!
//! ```toml
//! version = 1
//! width = 640                  # optional: the resolution it was recorded at
//! height = 480
//!
//! [[frame]]
//! t = 0.0                      # seconds since the recording started
//! eye = [0.0, 0.0, 12.5]       # the paper's camera: eye point …
//! corners = [                  # … and image-plane corners P0..P3
//!     [-4.0, 3.0, 0.0],        # P0 top-left
//!     [4.0, 3.0, 0.0],         # P1 top-right
//!     [4.0, -3.0, 0.0],        # P2 bottom-right
//!     [-4.0, -3.0, 0.0],       # P3 bottom-left
//! ]
//! ```
//!
//! A keyframed path (version 2) gives a few cameras at times of its choosing;
//! the frames are sampled from them at `fps` — frame `i` at `t₀ + i / fps`,
//! up to the last key's time, that time included when a frame lands on it —
//! by [`isin_tracer::keyframes`]:
//!
//! ```toml
//! version = 2
//! fps = 24                         # default 24
//! interpolation = "catmull-rom"    # or "linear"; default "catmull-rom"
//!
//! [[key]]
//! t = 0.0                          # seconds, increasing from key to key
//! eye = [0.0, 3.0, 12.0]
//! look_at = [0.0, 1.5, -4.0]
//! up = [0.0, 1.0, 0.0]             # optional, default +Y
//! fov = 50                         # optional: horizontal degrees, default the paper's 35.5
//!
//! [[key]]
//! t = 2.5
//! eye = [0.0, 0.0, 12.5]           # or the paper's form: eye and corners
//! corners = [[-4.0, 3.0, 0.0], [4.0, 3.0, 0.0], [4.0, -3.0, 0.0], [-4.0, -3.0, 0.0]]
//! ```
//!
//! A look-at key's plane has the path's `width : height` when both are
//! given, else 4 : 3; `fov` is its horizontal field of view. A version-2 file
//! may hold `[[frame]]`s instead of `[[key]]`s, never both.

use crate::error::ViewerError;
use isin_tracer::keyframes::{Interpolation, KeyframeError, Keyframes};
use isin_tracer::{Camera, Vec3};
use serde::Deserialize;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::time::Instant;
use toml::Spanned;

/// The format version of recorded paths, which the recorder writes.
pub const PATH_VERSION: u32 = 1;

/// The format version that adds keyframes (`[[key]]`, `fps`, `interpolation`).
pub const KEYFRAME_VERSION: u32 = 2;

/// Frames per second keyframes are sampled at when the file names none.
pub const DEFAULT_FPS: f64 = 24.0;

/// Largest camera path file read, in bytes (a million frames fit easily).
pub const MAX_PATH_FILE_BYTES: u64 = 256 << 20;

/// One camera of a path.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PathFrame {
    /// Seconds since the start of the recording.
    pub t: f64,
    /// The eye point.
    pub eye: Vec3,
    /// Image-plane corners `[P0, P1, P2, P3]`.
    pub corners: [Vec3; 4],
}

impl PathFrame {
    /// The frame's camera.
    pub fn camera(&self) -> Camera {
        Camera::from_corners(self.eye, self.corners)
    }
}

/// How a keyframed path's frames were made.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sampling {
    /// Keys in the file.
    pub keys: usize,
    /// Frames per second.
    pub fps: f64,
    /// How cameras between keys were computed.
    pub interpolation: Interpolation,
}

/// A camera path: its cameras, recorded or sampled from keyframes.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraPath {
    /// Format version, [`PATH_VERSION`] or [`KEYFRAME_VERSION`].
    pub version: u32,
    /// Width the path was recorded at, if known.
    pub width: Option<u32>,
    /// Height the path was recorded at, if known.
    pub height: Option<u32>,
    /// The cameras, in order.
    pub frames: Vec<PathFrame>,
    /// For a keyframed path, how `frames` were sampled from its keys.
    pub sampling: Option<Sampling>,
}

/// The file as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PathFile {
    version: u32,
    width: Option<u32>,
    height: Option<u32>,
    fps: Option<Spanned<f64>>,
    interpolation: Option<Spanned<Interpolation>>,
    #[serde(rename = "frame", default)]
    frames: Vec<Spanned<PathFrame>>,
    #[serde(rename = "key", default)]
    keys: Vec<Spanned<KeyDef>>,
}

/// A `[[key]]` as written: a time and a camera in look-at or corners form.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct KeyDef {
    t: f64,
    eye: Vec3,
    look_at: Option<Vec3>,
    up: Option<Vec3>,
    fov: Option<f32>,
    corners: Option<[Vec3; 4]>,
}

/// A complaint about one field of a key (`None`: the key as a whole).
type FieldError = (Option<&'static str>, String);

impl KeyDef {
    /// The key's camera; a look-at plane gets aspect `aspect`.
    fn camera(&self, aspect: f32) -> Result<Camera, FieldError> {
        let finite = |name: &'static str, v: Vec3| {
            if v.is_finite() { Ok(v) } else { Err((Some(name), format!("`{name}` {v} is not finite"))) }
        };
        let eye = finite("eye", self.eye)?;
        match (self.look_at, self.corners) {
            (Some(_), Some(_)) | (None, None) => {
                Err((None, "give the camera as either `look_at` or `corners`, not both nor neither".into()))
            }
            (None, Some(corners)) => {
                if let Some(name) = [("up", self.up.is_some()), ("fov", self.fov.is_some())]
                    .into_iter()
                    .find_map(|(name, set)| set.then_some(name))
                {
                    return Err((
                        Some(name),
                        format!("`{name}` goes with `look_at`; `corners` fix the plane"),
                    ));
                }
                Ok(Camera::from_corners(eye, corners))
            }
            (Some(target), None) => {
                let target = finite("look_at", target)?;
                let up = finite("up", self.up.unwrap_or(Vec3::Y))?;
                let view = target - eye;
                if view.length() <= 1e-6 * eye.length().max(1.0) {
                    return Err((Some("look_at"), format!("`look_at` {target} is the eye: look somewhere")));
                }
                let Some(unit_up) = up.try_normalize() else {
                    return Err((Some("up"), "`up` has zero length".into()));
                };
                if view.normalize().cross(unit_up).length() <= 1e-6 {
                    return Err((Some("up"), format!("`up` {up} is parallel to the viewing direction")));
                }
                let fov = self.fov.unwrap_or_else(|| Camera::default().hfov_degrees());
                if !(fov > 0.0 && fov < 180.0) {
                    return Err((Some("fov"), format!("`fov` {fov} is not between 0 and 180 degrees")));
                }
                Ok(Camera::look_at(eye, target, up, fov, aspect))
            }
        }
    }
}

/// Where things are in a path file's text, for error messages.
struct Source<'a> {
    name: &'a Path,
    text: &'a str,
}

impl Source<'_> {
    /// 1-based line of byte `offset`.
    fn line(&self, offset: usize) -> usize {
        let offset = offset.min(self.text.len());
        self.text.as_bytes()[..offset].iter().filter(|&&b| b == b'\n').count() + 1
    }

    /// The line of `field = …` within `span`, else of the span's start.
    fn field_line(&self, span: &Range<usize>, field: Option<&str>) -> usize {
        let table = self.text.get(span.clone()).unwrap_or("");
        let mut offset = 0;
        for line in table.split_inclusive('\n') {
            let trimmed = line.trim_start();
            if let Some(rest) = field.and_then(|f| trimmed.strip_prefix(f)) {
                if rest.trim_start().starts_with('=') {
                    return self.line(span.start + offset);
                }
            }
            offset += line.len();
        }
        self.line(span.start)
    }

    fn at(&self, line: usize, message: String) -> ViewerError {
        ViewerError::PathAt { path: self.name.to_path_buf(), line, message }
    }

    fn whole(&self, message: String) -> ViewerError {
        ViewerError::Path { path: self.name.to_path_buf(), message }
    }
}

impl CameraPath {
    /// An empty path recorded at `width × height`.
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            version: PATH_VERSION,
            width: Some(width),
            height: Some(height),
            frames: Vec::new(),
            sampling: None,
        }
    }

    /// Parses and validates a path (`name` is used in error messages); a
    /// keyframed one is sampled into its frames.
    pub fn parse(name: &Path, text: &str) -> Result<Self, ViewerError> {
        let src = Source { name, text };
        let file: PathFile = toml::from_str(text).map_err(|e| src.whole(e.to_string()))?;
        if file.version != PATH_VERSION && file.version != KEYFRAME_VERSION {
            return Err(src.whole(format!(
                "version {} is not supported (expected {PATH_VERSION}, or {KEYFRAME_VERSION} for keyframes)",
                file.version
            )));
        }
        let mut last = f64::NEG_INFINITY;
        for (i, f) in file.frames.iter().enumerate() {
            let line = || src.field_line(&f.span(), Some("t"));
            let f = f.get_ref();
            if !(f.t.is_finite() && f.t >= last) {
                return Err(
                    src.at(line(), format!("frame {i}: time {} is not finite and non-decreasing", f.t))
                );
            }
            last = f.t;
            f.camera().validate().map_err(|e| src.at(line(), format!("frame {i}: {e}")))?;
        }
        let mut path = CameraPath {
            version: file.version,
            width: file.width,
            height: file.height,
            frames: file.frames.iter().map(|f| *f.get_ref()).collect(),
            sampling: None,
        };
        if let Some(first) = file.keys.first() {
            if file.version != KEYFRAME_VERSION {
                return Err(src.at(
                    src.line(first.span().start),
                    format!("[[key]] needs version = {KEYFRAME_VERSION}"),
                ));
            }
            if !file.frames.is_empty() {
                return Err(src.at(
                    src.line(first.span().start),
                    "a path holds [[frame]]s (recorded) or [[key]]s, not both".into(),
                ));
            }
            let sampling = Sampling {
                keys: file.keys.len(),
                fps: file.fps.as_ref().map_or(DEFAULT_FPS, |f| *f.get_ref()),
                interpolation: file.interpolation.as_ref().map(|i| *i.get_ref()).unwrap_or_default(),
            };
            path.frames = sample(&src, &file, sampling)?;
            path.sampling = Some(sampling);
        } else if let Some((what, span)) = file
            .fps
            .as_ref()
            .map(|f| ("fps", f.span()))
            .or_else(|| file.interpolation.as_ref().map(|i| ("interpolation", i.span())))
        {
            return Err(
                src.at(src.line(span.start), format!("`{what}` applies to [[key]]s; this path has none"))
            );
        }
        Ok(path)
    }

    /// Reads and validates a path file.
    pub fn load(path: &Path) -> Result<Self, ViewerError> {
        let io = |source| ViewerError::Io { path: path.to_path_buf(), source };
        let len = std::fs::metadata(path).map_err(io)?.len();
        if len > MAX_PATH_FILE_BYTES {
            return Err(ViewerError::Path {
                path: path.to_path_buf(),
                message: format!("{len} bytes is more than the {MAX_PATH_FILE_BYTES}-byte limit"),
            });
        }
        let text = std::fs::read_to_string(path).map_err(io)?;
        Self::parse(path, &text)
    }

    /// The path's frames as TOML text (a keyframed path is written as the
    /// frames sampled from it). Numbers are written in their shortest form
    /// that reads back to the same `f32`, so the file is both exact and
    /// readable.
    pub fn to_toml(&self) -> String {
        use std::fmt::Write;
        let v = |p: Vec3| format!("[{:?}, {:?}, {:?}]", p.x, p.y, p.z);
        let mut out = String::from("# isin camera path (the format: README.md, \"Camera paths\")\n");
        let _ = writeln!(out, "version = {PATH_VERSION}");
        if let Some(w) = self.width {
            let _ = writeln!(out, "width = {w}");
        }
        if let Some(h) = self.height {
            let _ = writeln!(out, "height = {h}");
        }
        for f in &self.frames {
            let [a, b, c, d] = f.corners.map(v);
            let _ = write!(
                out,
                "\n[[frame]]\nt = {:?}\neye = {}\ncorners = [{a}, {b}, {c}, {d}]\n",
                f.t,
                v(f.eye)
            );
        }
        out
    }

    /// Writes the path as TOML.
    pub fn save(&self, path: &Path) -> Result<(), ViewerError> {
        std::fs::write(path, self.to_toml())
            .map_err(|source| ViewerError::Io { path: path.to_path_buf(), source })
    }
}

/// The frames of a keyframed file, sampled as `sampling` says.
fn sample(src: &Source, file: &PathFile, sampling: Sampling) -> Result<Vec<PathFrame>, ViewerError> {
    let aspect = match (file.width, file.height) {
        (Some(w), Some(h)) if w > 0 && h > 0 => w as f32 / h as f32,
        _ => 4.0 / 3.0,
    };
    let mut keys = Vec::with_capacity(file.keys.len());
    for (i, k) in file.keys.iter().enumerate() {
        let def = k.get_ref();
        let camera = def
            .camera(aspect)
            .map_err(|(field, why)| src.at(src.field_line(&k.span(), field), format!("key {i}: {why}")))?;
        keys.push(isin_tracer::keyframes::Keyframe { t: def.t, camera });
    }
    let fps_line = file.fps.as_ref().map(|f| src.line(f.span().start));
    let error = |e: KeyframeError| match (e.key(), &e) {
        (Some(i), KeyframeError::TimeNotFinite { .. } | KeyframeError::TimeNotIncreasing { .. }) => {
            src.at(src.field_line(&file.keys[i].span(), Some("t")), e.to_string())
        }
        (Some(i), _) => src.at(src.line(file.keys[i].span().start), e.to_string()),
        (None, _) => match fps_line {
            Some(line) => src.at(line, e.to_string()),
            None => src.whole(e.to_string()),
        },
    };
    let frames =
        Keyframes::new(&keys, sampling.interpolation).and_then(|k| k.sample(sampling.fps)).map_err(error)?;
    Ok(frames
        .into_iter()
        .map(|k| PathFrame { t: k.t, eye: k.camera.eye, corners: k.camera.corners })
        .collect())
}

/// Records cameras as the viewer requests them.
#[derive(Debug)]
pub struct Recorder {
    file: PathBuf,
    start: Instant,
    path: CameraPath,
}

impl Recorder {
    /// A recorder that will write to `file`, for a `width × height` view.
    pub fn new(file: PathBuf, width: u32, height: u32) -> Self {
        Self { file, start: Instant::now(), path: CameraPath::new(width, height) }
    }

    /// Appends `camera`, unless it equals the last one recorded.
    pub fn record(&mut self, camera: &Camera) {
        if self.path.frames.last().is_some_and(|f| f.camera() == *camera) {
            return;
        }
        // Microseconds are plenty, and keep the file readable.
        let t = (self.start.elapsed().as_secs_f64() * 1e6).round() / 1e6;
        self.path.frames.push(PathFrame { t, eye: camera.eye, corners: camera.corners });
    }

    /// What has been recorded so far.
    pub fn path(&self) -> &CameraPath {
        &self.path
    }

    /// Writes the recording to its file.
    pub fn save(&self) -> Result<&Path, ViewerError> {
        self.path.save(&self.file)?;
        Ok(&self.file)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_recorded_path_survives_a_round_trip_through_its_file() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("p.path.toml");
        let mut rec = Recorder::new(file.clone(), 320, 240);
        let mut cam = Camera::default();
        rec.record(&cam);
        rec.record(&cam); // unchanged: not recorded twice
        cam.yaw(0.3);
        cam.advance(1.25);
        rec.record(&cam);
        cam.pitch(1e-7); // tiny and huge numbers survive too
        cam.strafe(3e7, 0.0);
        rec.record(&cam);
        assert_eq!(rec.path().frames.len(), 3);
        rec.save().unwrap();
        let back = CameraPath::load(&file).unwrap();
        assert_eq!(back, *rec.path());
        assert_eq!(back.frames[2].camera(), cam);
        assert_eq!(back.width, Some(320));
        assert!(back.frames[1].t >= back.frames[0].t);
    }

    #[test]
    fn the_documented_example_parses() {
        let doc = r#"
            version = 1
            width = 640
            height = 480
            [[frame]]
            t = 0.0
            eye = [0.0, 0.0, 12.5]
            corners = [[-4.0, 3.0, 0.0], [4.0, 3.0, 0.0], [4.0, -3.0, 0.0], [-4.0, -3.0, 0.0]]
        "#;
        let p = CameraPath::parse(Path::new("doc"), doc).unwrap();
        assert_eq!(p.frames.len(), 1);
        assert_eq!(p.frames[0].camera(), Camera::default());
    }

    const KEYED: &str = r#"version = 2
fps = 24
interpolation = "catmull-rom"

[[key]]
t = 0.0
eye = [0.0, 3.0, 12.0]
look_at = [0.0, 1.5, -4.0]
up = [0.0, 1.0, 0.0]
fov = 50

[[key]]
t = 2.5
eye = [0.0, 0.0, 12.5]
corners = [[-4.0, 3.0, 0.0], [4.0, 3.0, 0.0], [4.0, -3.0, 0.0], [-4.0, -3.0, 0.0]]
"#;

    #[test]
    fn the_documented_keyframes_are_sampled_at_their_rate() {
        let p = CameraPath::parse(Path::new("doc"), KEYED).unwrap();
        // 2.5 s at 24 fps: frames at 0, 1/24, … 60/24 = 2.5, the last on the key.
        assert_eq!(p.frames.len(), 61);
        assert_eq!(
            p.sampling,
            Some(Sampling { keys: 2, fps: 24.0, interpolation: Interpolation::CatmullRom })
        );
        let first =
            Camera::look_at(Vec3::new(0.0, 3.0, 12.0), Vec3::new(0.0, 1.5, -4.0), Vec3::Y, 50.0, 4.0 / 3.0);
        assert_eq!(p.frames[0].camera(), first);
        assert_eq!(p.frames[60].camera(), Camera::default());
        assert_eq!(p.frames[60].t, 2.5);
        assert!((p.frames[12].t - 0.5).abs() < 1e-12);
        assert!(p.frames.windows(2).all(|w| w[0].camera() != w[1].camera()), "every frame moves");
        // Written out, it is the recorded form of the same frames.
        let back = CameraPath::parse(Path::new("back"), &p.to_toml()).unwrap();
        assert_eq!(back.version, PATH_VERSION);
        assert_eq!(back.frames, p.frames);
        assert_eq!(back.sampling, None);
    }

    #[test]
    fn defaults_are_24_fps_catmull_rom_and_the_paths_aspect() {
        let text = "version = 2\nwidth = 200\nheight = 100\n[[key]]\nt = 1\neye = [0, 0, 5]\nlook_at = [0, 0, 0]\n\
                    [[key]]\nt = 2\neye = [1, 0, 5]\nlook_at = [0, 0, 0]\n";
        let p = CameraPath::parse(Path::new("d"), text).unwrap();
        assert_eq!(
            p.sampling,
            Some(Sampling { keys: 2, fps: 24.0, interpolation: Interpolation::CatmullRom })
        );
        assert_eq!(p.frames.len(), 25);
        let c = p.frames[0].camera();
        assert!((c.aspect() - 2.0).abs() < 1e-5, "the plane has the path's shape: {}", c.aspect());
        assert!((c.hfov_degrees() - Camera::default().hfov_degrees()).abs() < 1e-3);
        assert_eq!(p.frames[0].t, 1.0);
    }

    const CORNERS: &str = "[[-4.0, 3.0, 0.0], [4.0, 3.0, 0.0], [4.0, -3.0, 0.0], [-4.0, -3.0, 0.0]]";

    #[test]
    fn bad_keys_are_refused_naming_the_key_and_its_line() {
        // Each case: the text; the line the error must name, as the `n`-th
        // line containing a needle; and what the error must say. A key's
        // errors name its [[key]] line, a field's errors the field's line.
        let mixed = format!("{KEYED}\n[[frame]]\nt = 0.0\neye = [0.0, 0.0, 12.5]\ncorners = {CORNERS}\n");
        let cases: Vec<(String, (&str, usize), &str)> = vec![
            (
                KEYED.replace("t = 2.5", "t = -1.0"),
                ("t = -1.0", 0),
                "key 1: time -1 s is not after key 0's time 0 s",
            ),
            (KEYED.replace("t = 2.5", "t = nan"), ("t = nan", 0), "key 1: time NaN is not a finite"),
            (
                KEYED.replace("up = [0.0, 1.0, 0.0]", "up = [0.0, 0.0, 0.0]"),
                ("up =", 0),
                "key 0: `up` has zero length",
            ),
            (
                KEYED.replace("up = [0.0, 1.0, 0.0]", "up = [0.0, -1.5, -16.0]"),
                ("up =", 0),
                "parallel to the viewing",
            ),
            (
                KEYED.replace("look_at = [0.0, 1.5, -4.0]", "look_at = [0.0, 3.0, 12.0]"),
                ("look_at =", 0),
                "key 0: `look_at` [0, 3, 12] is the eye",
            ),
            (KEYED.replace("eye = [0.0, 3.0, 12.0]", "eye = [nan, 3.0, 12.0]"), ("eye =", 0), "key 0: `eye`"),
            (KEYED.replace("fov = 50", "fov = 180"), ("fov =", 0), "`fov` 180 is not between 0 and 180"),
            (KEYED.replace("t = 2.5\n", "t = 2.5\nfov = 40\n"), ("fov = 40", 0), "key 1: `fov` goes with"),
            (
                KEYED.replace("look_at = [0.0, 1.5, -4.0]\n", ""),
                ("[[key]]", 0),
                "key 0: give the camera as either",
            ),
            (
                KEYED.replace("[-4.0, -3.0, 0.0]]", "[-4.0, -3.0, 5.0]]"),
                ("[[key]]", 1),
                "key 1: the image plane is not a rectangle",
            ),
            (KEYED.replace("version = 2", "version = 1"), ("[[key]]", 0), "[[key]] needs version = 2"),
            (KEYED.replace("fps = 24", "fps = 0"), ("fps =", 0), "fps 0 is not a frame rate"),
            (
                KEYED.replace("t = 2.5", "t = 25000.0"),
                ("fps =", 0),
                "600001 frames: more than the limit of 100000",
            ),
            (mixed, ("[[key]]", 0), "[[frame]]s (recorded) or [[key]]s, not both"),
        ];
        for (text, (needle, nth), says) in cases {
            let e = CameraPath::parse(Path::new("p.toml"), &text).unwrap_err().to_string();
            let line = text.lines().enumerate().filter(|(_, l)| l.contains(needle)).nth(nth).unwrap().0 + 1;
            assert!(e.contains(says), "{e:?} should say {says:?}");
            assert!(e.starts_with(&format!("camera path p.toml:{line}: ")), "{e:?} should name line {line}");
        }
        let e = CameraPath::parse(Path::new("p.toml"), &KEYED.replace("catmull-rom", "smooth")).unwrap_err();
        assert!(
            e.to_string().contains("`linear` or `catmull-rom`") && e.to_string().contains("line 3"),
            "{e}"
        );
        let e = CameraPath::parse(Path::new("p.toml"), "version = 1\nfps = 30\n").unwrap_err();
        assert_eq!(e.to_string(), "camera path p.toml:2: `fps` applies to [[key]]s; this path has none");
    }

    #[test]
    fn malformed_paths_are_refused_with_a_reason() {
        let bad = [
            ("version = 3\n", "version 3 is not supported"),
            ("version = 1\n[[frame]]\nt = 0.0\neye = [0.0, 0.0]\ncorners = []\n", ""),
            (
                "version = 1\n[[frame]]\nt = 1.0\neye = [0.0, 0.0, 12.5]\ncorners = [[-4.0, 3.0, 0.0], \
                 [4.0, 3.0, 0.0], [4.0, -3.0, 0.0], [-4.0, -3.0, 0.0]]\n[[frame]]\nt = 0.5\neye = [0.0, \
                 0.0, 12.5]\ncorners = [[-4.0, 3.0, 0.0], [4.0, 3.0, 0.0], [4.0, -3.0, 0.0], [-4.0, -3.0, \
                 0.0]]\n",
                "x:7: frame 1: time 0.5 is not finite and non-decreasing",
            ),
            (
                "version = 1\n[[frame]]\nt = 0.0\neye = [0.0, 0.0, 0.0]\ncorners = [[0.0, 0.0, 0.0], \
                 [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]\n",
                "x:3: frame 0: camera image plane has zero area",
            ),
        ];
        for (text, why) in bad {
            let e = CameraPath::parse(Path::new("x"), text).unwrap_err().to_string();
            assert!(e.contains(why), "{e:?} should mention {why:?}");
        }
    }
}

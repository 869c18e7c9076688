//! Camera paths: a recorded navigation, replayed headless by `isin fly`.
//!
//! # Format (TOML, version 1)
//!
//! ```toml
//! # Optional: the resolution the path was recorded at (informational).
//! version = 1
//! width = 640
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
//! One `[[frame]]` per camera the viewer asked to render (every move, not every
//! refinement pass), in order, with non-decreasing `t`.

use crate::error::ViewerError;
use isin_tracer::{Camera, Vec3};
use serde::Deserialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The only format version this code reads and writes.
pub const PATH_VERSION: u32 = 1;

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

/// A recorded navigation.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraPath {
    /// Format version, [`PATH_VERSION`].
    pub version: u32,
    /// Width the path was recorded at, if known.
    #[serde(default)]
    pub width: Option<u32>,
    /// Height the path was recorded at, if known.
    #[serde(default)]
    pub height: Option<u32>,
    /// The cameras, in order.
    #[serde(rename = "frame", default)]
    pub frames: Vec<PathFrame>,
}

impl CameraPath {
    /// An empty path recorded at `width × height`.
    pub fn new(width: u32, height: u32) -> Self {
        Self { version: PATH_VERSION, width: Some(width), height: Some(height), frames: Vec::new() }
    }

    /// Parses and validates a path (`name` is used in error messages).
    pub fn parse(name: &Path, text: &str) -> Result<Self, ViewerError> {
        let err = |message: String| ViewerError::Path { path: name.to_path_buf(), message };
        let path: CameraPath = toml::from_str(text).map_err(|e| err(e.to_string()))?;
        if path.version != PATH_VERSION {
            return Err(err(format!("version {} is not supported (expected {PATH_VERSION})", path.version)));
        }
        let mut last = f64::NEG_INFINITY;
        for (i, f) in path.frames.iter().enumerate() {
            if !(f.t.is_finite() && f.t >= last) {
                return Err(err(format!("frame {i}: time {} is not finite and non-decreasing", f.t)));
            }
            last = f.t;
            f.camera().validate().map_err(|e| err(format!("frame {i}: {e}")))?;
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

    /// The path as TOML text. Numbers are written in their shortest form that
    /// reads back to the same `f32`, so the file is both exact and readable.
    pub fn to_toml(&self) -> String {
        use std::fmt::Write;
        let v = |p: Vec3| format!("[{:?}, {:?}, {:?}]", p.x, p.y, p.z);
        let mut out = String::from("# isin camera path (format: see the isin_viewer::path docs)\n");
        let _ = writeln!(out, "version = {}", self.version);
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

    #[test]
    fn malformed_paths_are_refused_with_a_reason() {
        let bad = [
            ("version = 2\n", "version"),
            ("version = 1\n[[frame]]\nt = 0.0\neye = [0.0, 0.0]\ncorners = []\n", ""),
            (
                "version = 1\n[[frame]]\nt = 1.0\neye = [0.0, 0.0, 12.5]\ncorners = [[-4.0, 3.0, 0.0], \
                 [4.0, 3.0, 0.0], [4.0, -3.0, 0.0], [-4.0, -3.0, 0.0]]\n[[frame]]\nt = 0.5\neye = [0.0, \
                 0.0, 12.5]\ncorners = [[-4.0, 3.0, 0.0], [4.0, 3.0, 0.0], [4.0, -3.0, 0.0], [-4.0, -3.0, \
                 0.0]]\n",
                "non-decreasing",
            ),
            (
                "version = 1\n[[frame]]\nt = 0.0\neye = [0.0, 0.0, 0.0]\ncorners = [[0.0, 0.0, 0.0], \
                 [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]\n",
                "zero area",
            ),
        ];
        for (text, why) in bad {
            let e = CameraPath::parse(Path::new("x"), text).unwrap_err().to_string();
            assert!(e.contains(why), "{e:?} should mention {why:?}");
        }
    }
}

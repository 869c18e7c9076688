//! Camera keyframes and the cameras between them.
//!
//! A keyframe is a time and a [`Camera`]. Between two keys the camera is
//! taken apart into what a person moving a camera changes — where the eye
//! is, which way the camera faces, and the image plane's size and place in
//! front of the eye — and each part is interpolated on its own:
//!
//! - the **eye** along a straight line ([`Interpolation::Linear`]) or a
//!   centripetal Catmull-Rom spline through the eyes of all keys
//!   ([`Interpolation::CatmullRom`]), which passes through every key, turns
//!   smoothly, and forms no cusp or loop between two keys;
//! - the **orientation** as a unit quaternion built from the plane's right,
//!   up and back axes: spherical linear interpolation (slerp), or for
//!   Catmull-Rom the same spline drawn with slerps in place of straight
//!   lines (Barry and Goldman's construction), timed by the keys' times. A
//!   quaternion turns the whole frame rigidly, so the plane stays a
//!   rectangle and never flips; between neighbouring keys it turns the short
//!   way, so a turn of 180° or more needs keys in between;
//! - the **plane**: its width, height, distance from the eye and offset from
//!   the viewing axis, linearly.
//!
//! A key whose eye (or orientation) equals its neighbour's is a stop: the
//! spline treats it as an end, so the camera does not swing out and back
//! between two keys that stand still.
//!
//! Everything is computed in `f64` with the platform-independent functions
//! of [`crate::math`], so a path gives the same cameras on every machine.
//! A camera at a key's exact time is that key's camera, bit for bit.

use crate::cameras::{Camera, CameraError};
use crate::limits;
use crate::math;
use glam::{DMat3, DQuat, DVec3};
use serde::Deserialize;

/// Most frames per second a path may be sampled at.
pub const MAX_FPS: f64 = 1000.0;

/// Largest turn between two neighbouring keys, in degrees: near 180° the
/// short way round is no longer well defined.
pub const MAX_TURN_DEGREES: f64 = 179.0;

/// How cameras between keys are computed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Interpolation {
    /// Straight lines between eyes, slerp between orientations: the camera
    /// moves at constant speed from key to key and changes course at keys.
    Linear,
    /// A centripetal Catmull-Rom spline through the eyes and a spherical
    /// one through the orientations: the camera rounds the keys smoothly.
    #[default]
    CatmullRom,
}

/// A camera at a time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Keyframe {
    /// Seconds.
    pub t: f64,
    /// The camera at `t`.
    pub camera: Camera,
}

/// Why keys cannot be interpolated or sampled. Errors about one key carry
/// its index (0-based, in the order given).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum KeyframeError {
    /// No keys at all.
    #[error("a keyframed path needs at least one key")]
    NoKeys,
    /// A key's time is NaN or infinite.
    #[error("key {key}: time {t} is not a finite number of seconds")]
    TimeNotFinite {
        /// The key.
        key: usize,
        /// Its time.
        t: f64,
    },
    /// A key's time is not after the previous key's.
    #[error("key {key}: time {t} s is not after key {}'s time {previous} s", key - 1)]
    TimeNotIncreasing {
        /// The key.
        key: usize,
        /// Its time.
        t: f64,
        /// The previous key's time.
        previous: f64,
    },
    /// A key's camera cannot produce rays.
    #[error("key {key}: {source}")]
    Camera {
        /// The key.
        key: usize,
        /// The camera's complaint.
        source: CameraError,
    },
    /// A key's image plane is not a rectangle, so no rotation of it is
    /// another key's plane.
    #[error(
        "key {key}: the image plane is not a rectangle (P1 − P0 and P3 − P0 must be at right angles \
         and P2 = P1 + P3 − P0)"
    )]
    NotRectangular {
        /// The key.
        key: usize,
    },
    /// A key's image plane is seen from behind: P0 → P1 runs right to left.
    #[error("key {key}: the image plane is mirrored (seen from the eye, P0 → P1 runs right to left)")]
    Mirrored {
        /// The key.
        key: usize,
    },
    /// Two neighbouring keys face (nearly) opposite ways, so the short way
    /// from one to the other is not defined.
    #[error(
        "key {key}: the camera turns {degrees:.1}° from key {}; keys turn the short way, so a turn of \
         more than {MAX_TURN_DEGREES}° is ambiguous: add a key in between",
        key - 1
    )]
    HalfTurn {
        /// The later of the two keys.
        key: usize,
        /// The turn, in degrees.
        degrees: f64,
    },
    /// The frame rate is not a positive number up to [`MAX_FPS`].
    #[error("fps {0} is not a frame rate between 0 and {MAX_FPS} frames per second")]
    Fps(f64),
    /// The keys span more frames than the limit.
    #[error(
        "the keys span {span} s, which at {fps} fps is {frames} frames: more than the limit of {} ({})",
        limits::PATH_FRAMES.max,
        limits::PATH_FRAMES.why
    )]
    TooManyFrames {
        /// Seconds from the first key to the last.
        span: f64,
        /// The frame rate.
        fps: f64,
        /// Frames that would be sampled.
        frames: f64,
    },
}

impl KeyframeError {
    /// The index of the key the error is about, if it is about one.
    pub fn key(&self) -> Option<usize> {
        match self {
            KeyframeError::TimeNotFinite { key, .. }
            | KeyframeError::TimeNotIncreasing { key, .. }
            | KeyframeError::Camera { key, .. }
            | KeyframeError::NotRectangular { key }
            | KeyframeError::Mirrored { key }
            | KeyframeError::HalfTurn { key, .. } => Some(*key),
            KeyframeError::NoKeys | KeyframeError::Fps(_) | KeyframeError::TooManyFrames { .. } => None,
        }
    }
}

/// A camera taken apart into the pieces that are interpolated.
#[derive(Clone, Copy, Debug)]
struct Pose {
    eye: DVec3,
    /// Turns camera axes (x right, y up, z back) into world axes.
    rotation: DQuat,
    /// The plane's centre in camera axes: right, up, and distance ahead.
    offset: DVec3,
    /// The plane's width and height.
    size: [f64; 2],
}

/// Relative tolerance of the right angle and the fourth corner of a key's
/// plane: cameras written with three or four decimals pass.
const RECTANGLE_TOLERANCE: f64 = 1e-3;

impl Pose {
    fn of(key: usize, camera: &Camera) -> Result<Pose, KeyframeError> {
        camera.validate().map_err(|source| KeyframeError::Camera { key, source })?;
        let v = |p: glam::Vec3| p.as_dvec3();
        let [p0, p1, p2, p3] = camera.corners.map(v);
        let (x, y) = (p1 - p0, p3 - p0);
        let (w, h) = (x.length(), y.length());
        let diagonal = (w * w + h * h).sqrt();
        if x.dot(y).abs() > RECTANGLE_TOLERANCE * w * h
            || (p2 - (p1 + y)).length() > RECTANGLE_TOLERANCE * diagonal
        {
            return Err(KeyframeError::NotRectangular { key });
        }
        let eye = v(camera.eye);
        let center = (p0 + p1 + p2 + p3) * 0.25;
        let forward = v(camera.forward()).normalize();
        let right = (x - forward * x.dot(forward)).normalize();
        let back = -forward;
        let up = back.cross(right);
        if up.dot(-y) <= 0.0 {
            return Err(KeyframeError::Mirrored { key });
        }
        let rotation = DQuat::from_mat3(&DMat3::from_cols(right, up, back)).normalize();
        let rel = center - eye;
        let offset = DVec3::new(rel.dot(right), rel.dot(up), rel.dot(forward));
        Ok(Pose { eye, rotation, offset, size: [w, h] })
    }

    fn camera(&self) -> Camera {
        let q = self.rotation;
        let center = self.eye + q * DVec3::new(self.offset.x, self.offset.y, -self.offset.z);
        let half_x = q * DVec3::new(self.size[0] * 0.5, 0.0, 0.0);
        let half_y = q * DVec3::new(0.0, self.size[1] * 0.5, 0.0);
        let f = |p: DVec3| p.as_vec3();
        Camera::from_corners(
            f(self.eye),
            [
                f(center - half_x + half_y),
                f(center + half_x + half_y),
                f(center + half_x - half_y),
                f(center - half_x - half_y),
            ],
        )
    }
}

/// Keys ready to be sampled: validated, in time order.
#[derive(Clone, Debug)]
pub struct Keyframes {
    keys: Vec<Keyframe>,
    poses: Vec<Pose>,
    interpolation: Interpolation,
}

impl Keyframes {
    /// Checks `keys` — at least one, finite and increasing times, cameras
    /// that produce rays with rectangular, unmirrored planes, less than
    /// [`MAX_TURN_DEGREES`] between neighbours — and prepares them.
    pub fn new(keys: &[Keyframe], interpolation: Interpolation) -> Result<Keyframes, KeyframeError> {
        if keys.is_empty() {
            return Err(KeyframeError::NoKeys);
        }
        let mut poses: Vec<Pose> = Vec::with_capacity(keys.len());
        for (i, k) in keys.iter().enumerate() {
            if !k.t.is_finite() {
                return Err(KeyframeError::TimeNotFinite { key: i, t: k.t });
            }
            let mut pose = Pose::of(i, &k.camera)?;
            if let Some(prev) = poses.last() {
                let previous = keys[i - 1].t;
                if k.t <= previous {
                    return Err(KeyframeError::TimeNotIncreasing { key: i, t: k.t, previous });
                }
                // q and −q are the same turn; keep neighbours on the same side.
                if pose.rotation.dot(prev.rotation) < 0.0 {
                    pose.rotation = -pose.rotation;
                }
                let degrees = turn_angle(prev.rotation, pose.rotation).to_degrees();
                if degrees > MAX_TURN_DEGREES {
                    return Err(KeyframeError::HalfTurn { key: i, degrees });
                }
            }
            poses.push(pose);
        }
        Ok(Keyframes { keys: keys.to_vec(), poses, interpolation })
    }

    /// The first key's time.
    pub fn start(&self) -> f64 {
        self.keys[0].t
    }

    /// The last key's time.
    pub fn end(&self) -> f64 {
        self.keys[self.keys.len() - 1].t
    }

    /// The camera at time `t`, clamped to the keys' span.
    pub fn camera_at(&self, t: f64) -> Camera {
        let n = self.keys.len();
        if n == 1 || t <= self.start() {
            return self.keys[0].camera;
        }
        if t >= self.end() {
            return self.keys[n - 1].camera;
        }
        // The segment from key i to key i + 1 holds t.
        let i = self.keys.partition_point(|k| k.t <= t) - 1;
        if t == self.keys[i].t {
            return self.keys[i].camera;
        }
        let (t1, t2) = (self.keys[i].t, self.keys[i + 1].t);
        let s = (t - t1) / (t2 - t1);
        let (a, b) = (&self.poses[i], &self.poses[i + 1]);
        let lerp = |x: f64, y: f64| x + (y - x) * s;
        let (eye, rotation) = match self.interpolation {
            Interpolation::Linear => (a.eye.lerp(b.eye, s), slerp(a.rotation, b.rotation, s)),
            Interpolation::CatmullRom => (self.spline_eye(i, s), self.spline_rotation(i, t)),
        };
        Pose {
            eye,
            rotation,
            offset: a.offset.lerp(b.offset, s),
            size: [lerp(a.size[0], b.size[0]), lerp(a.size[1], b.size[1])],
        }
        .camera()
    }

    /// Frames from the first key to the last at `fps`: frame `i` at
    /// `start + i / fps`, the last key's time included when a frame lands on
    /// it (within 10⁻⁹ of a frame). Refused beyond [`limits::PATH_FRAMES`].
    pub fn frame_count(&self, fps: f64) -> Result<usize, KeyframeError> {
        if !(fps > 0.0 && fps <= MAX_FPS) {
            return Err(KeyframeError::Fps(fps));
        }
        let span = self.end() - self.start();
        // Finite times and rate: never NaN, at most infinite.
        let frames = (span * fps + 1e-9).floor() + 1.0;
        if frames > limits::PATH_FRAMES.max as f64 {
            return Err(KeyframeError::TooManyFrames { span, fps, frames });
        }
        Ok(frames as usize)
    }

    /// The cameras of [`Keyframes::frame_count`] frames, with their times.
    pub fn sample(&self, fps: f64) -> Result<Vec<Keyframe>, KeyframeError> {
        let n = self.frame_count(fps)?;
        Ok((0..n)
            .map(|i| {
                let t = (self.start() + i as f64 / fps).min(self.end());
                Keyframe { t, camera: self.camera_at(t) }
            })
            .collect())
    }

    /// The eye on the centripetal Catmull-Rom spline, fraction `s` of the
    /// way from key `i` to key `i + 1`.
    fn spline_eye(&self, i: usize, s: f64) -> DVec3 {
        let eye = |k: usize| self.poses[k].eye;
        let (p1, p2) = (eye(i), eye(i + 1));
        if p1 == p2 {
            return p1;
        }
        // A missing or standing neighbour: mirror the segment's other end.
        let p0 = match i.checked_sub(1).map(eye) {
            Some(p) if p != p1 => p,
            _ => p1 * 2.0 - p2,
        };
        let p3 = match (i + 2 < self.keys.len()).then(|| eye(i + 2)) {
            Some(p) if p != p2 => p,
            _ => p2 * 2.0 - p1,
        };
        let step = |a: DVec3, b: DVec3| (b - a).length().sqrt();
        let k1 = step(p0, p1);
        let k2 = k1 + step(p1, p2);
        let k3 = k2 + step(p2, p3);
        barry_goldman([p0, p1, p2, p3], [0.0, k1, k2, k3], k1 + (k2 - k1) * s, |a, b, w| a.lerp(b, w))
    }

    /// The orientation on the spherical Catmull-Rom spline at time `t`,
    /// between keys `i` and `i + 1`.
    fn spline_rotation(&self, i: usize, t: f64) -> DQuat {
        let rot = |k: usize| self.poses[k].rotation;
        let time = |k: usize| self.keys[k].t;
        let (q1, q2) = (rot(i), rot(i + 1));
        if same_turn(q1, q2) {
            return q1;
        }
        let (q0, t0) = match i.checked_sub(1) {
            Some(k) if !same_turn(rot(k), q1) => (rot(k), time(k)),
            _ => (slerp(q2, q1, 2.0), 2.0 * time(i) - time(i + 1)),
        };
        let (q3, t3) = match i + 2 < self.keys.len() {
            true if !same_turn(rot(i + 2), q2) => (rot(i + 2), time(i + 2)),
            _ => (slerp(q1, q2, 2.0), 2.0 * time(i + 1) - time(i)),
        };
        barry_goldman([q0, q1, q2, q3], [t0, time(i), time(i + 1), t3], t, slerp)
    }
}

/// Barry and Goldman's pyramid for the Catmull-Rom segment from `p[1]` to
/// `p[2]` with knots `k`, at parameter `u` in `[k[1], k[2]]`, drawn with
/// `lerp` (straight lines for points, slerp for rotations).
fn barry_goldman<T: Copy>(p: [T; 4], k: [f64; 4], u: f64, lerp: impl Fn(T, T, f64) -> T) -> T {
    let w = |a: usize, b: usize| (u - k[a]) / (k[b] - k[a]);
    let a1 = lerp(p[0], p[1], w(0, 1));
    let a2 = lerp(p[1], p[2], w(1, 2));
    let a3 = lerp(p[2], p[3], w(2, 3));
    let b1 = lerp(a1, a2, w(0, 2));
    let b2 = lerp(a2, a3, w(1, 3));
    lerp(b1, b2, w(1, 2))
}

/// Whether two unit quaternions are the same turn.
fn same_turn(a: DQuat, b: DQuat) -> bool {
    a.dot(b).abs() >= 1.0 - 1e-15
}

/// The angle of the turn from `a` to `b`, in radians (0 to π).
fn turn_angle(a: DQuat, b: DQuat) -> f64 {
    2.0 * math::acos_f64(a.dot(b).abs().min(1.0))
}

/// Spherical linear interpolation the short way from `a` (`s = 0`) to `b`
/// (`s = 1`); other `s` extrapolate along the same great circle.
fn slerp(a: DQuat, b: DQuat, s: f64) -> DQuat {
    let mut dot = a.dot(b);
    let b = if dot < 0.0 {
        dot = -dot;
        -b
    } else {
        b
    };
    if dot > 1.0 - 1e-12 {
        // Too close for the sines to be accurate: the chord is the arc.
        return (a + (b - a) * s).normalize();
    }
    let theta = math::acos_f64(dot);
    let sin = math::sin_f64(theta);
    let wa = math::sin_f64((1.0 - s) * theta) / sin;
    let wb = math::sin_f64(s * theta) / sin;
    (a * wa + b * wb).normalize()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    fn look(eye: [f32; 3], at: [f32; 3]) -> Camera {
        Camera::look_at(Vec3::from(eye), Vec3::from(at), Vec3::Y, 40.0, 4.0 / 3.0)
    }

    fn key(t: f64, camera: Camera) -> Keyframe {
        Keyframe { t, camera }
    }

    fn close(a: Vec3, b: Vec3, tol: f32) -> bool {
        (a - b).length() <= tol
    }

    /// A camera orbiting the origin at radius 10, `degrees` round from +Z.
    fn orbit(degrees: f32) -> Camera {
        let a = degrees.to_radians();
        look([10.0 * a.sin(), 2.0, 10.0 * a.cos()], [0.0, 0.0, 0.0])
    }

    /// The camera's turn about +Y, in degrees (0 looking along −Z).
    fn heading(c: &Camera) -> f32 {
        let f = c.forward();
        (-f.x).atan2(-f.z).to_degrees()
    }

    fn assert_rectangle_of(c: &Camera, w: f32, h: f32) {
        let (x, y) = (c.plane_x(), c.plane_y());
        assert!((x.length() - w).abs() < 1e-4 * w, "width {} vs {w}", x.length());
        assert!((y.length() - h).abs() < 1e-4 * h, "height {} vs {h}", y.length());
        assert!(x.dot(y).abs() < 1e-4 * w * h, "corner angle off by {}", x.dot(y));
        let p2 = c.corners[1] + y;
        assert!(close(c.corners[2], p2, 1e-4 * w), "P2 {:?} vs {p2:?}", c.corners[2]);
        c.validate().unwrap();
    }

    #[test]
    fn the_curve_passes_through_every_key_at_its_time_exactly() {
        let keys = [
            key(0.0, orbit(0.0)),
            key(1.0, look([3.0, 4.0, 5.0], [0.0, 1.0, 0.0])),
            key(1.7, orbit(100.0)),
            key(4.0, Camera::default()),
        ];
        for interpolation in [Interpolation::Linear, Interpolation::CatmullRom] {
            let path = Keyframes::new(&keys, interpolation).unwrap();
            for k in &keys {
                assert_eq!(path.camera_at(k.t), k.camera, "{interpolation:?} at t = {}", k.t);
            }
            // And continuously: a hair before each key is a hair away from it.
            for k in &keys[1..] {
                let near = path.camera_at(k.t - 1e-7);
                assert!(close(near.eye, k.camera.eye, 1e-4), "{interpolation:?} {:?}", near.eye);
                assert!(close(near.forward(), k.camera.forward(), 1e-4));
            }
        }
    }

    #[test]
    fn linear_halfway_is_the_midpoint_and_the_halfway_turn() {
        let (a, b) = (orbit(0.0), orbit(60.0));
        let path = Keyframes::new(&[key(2.0, a), key(4.0, b)], Interpolation::Linear).unwrap();
        let mid = path.camera_at(3.0);
        assert!(close(mid.eye, (a.eye + b.eye) * 0.5, 1e-5), "{:?}", mid.eye);
        // b is a turned 60° about +Y; halfway is the turn of 30°.
        let half = glam::Quat::from_rotation_y(30f32.to_radians());
        assert!(close(mid.forward(), half * a.forward(), 1e-5), "{:?}", mid.forward());
        assert!(close(mid.up(), half * a.up(), 1e-5), "{:?}", mid.up());
        assert!((heading(&mid) - 30.0).abs() < 1e-3, "heading {}", heading(&mid));
        // A quarter of the way is a quarter of the turn.
        let q = path.camera_at(2.5);
        let quarter = glam::Quat::from_rotation_y(15f32.to_radians());
        assert!(close(q.forward(), quarter * a.forward(), 1e-5), "{:?}", q.forward());
    }

    #[test]
    fn the_plane_stays_a_rectangle_of_the_same_size() {
        let mut rolled = orbit(80.0);
        rolled.roll(0.9);
        rolled.pitch(-0.4);
        let keys =
            [key(0.0, orbit(0.0)), key(1.0, rolled), key(2.0, look([1.0, 9.0, 1.0], [0.0, 0.0, -2.0]))];
        let (w, h) = (keys[0].camera.plane_x().length(), keys[0].camera.plane_y().length());
        for interpolation in [Interpolation::Linear, Interpolation::CatmullRom] {
            let path = Keyframes::new(&keys, interpolation).unwrap();
            for i in 0..=200 {
                let c = path.camera_at(i as f64 / 100.0);
                assert_rectangle_of(&c, w, h);
                assert!((c.eye_distance() - 12.5).abs() < 1e-4, "{}", c.eye_distance());
            }
        }
    }

    #[test]
    fn plane_size_and_distance_change_linearly() {
        let a = Camera::default();
        let mut b = Camera::look_at(Vec3::new(0.0, 0.0, 12.5), Vec3::ZERO, Vec3::Y, 80.0, 2.0);
        b.eye.z += 5.0; // the eye further back: a longer lens
        let path = Keyframes::new(&[key(0.0, a), key(1.0, b)], Interpolation::CatmullRom).unwrap();
        let mid = path.camera_at(0.5);
        let half = |f: fn(&Camera) -> f32| (f(&a) + f(&b)) * 0.5;
        assert!((mid.plane_x().length() - half(|c| c.plane_x().length())).abs() < 1e-4);
        assert!((mid.plane_y().length() - half(|c| c.plane_y().length())).abs() < 1e-4);
        assert!((mid.eye_distance() - half(Camera::eye_distance)).abs() < 1e-4);
        assert_rectangle_of(&mid, mid.plane_x().length(), mid.plane_y().length());
    }

    #[test]
    fn an_off_axis_plane_keeps_its_offset() {
        let mut shifted = Camera::default();
        for p in &mut shifted.corners {
            *p += Vec3::new(1.0, -0.5, 0.0);
        }
        // Turned about the eye, plane and all (Camera::rotate would re-centre the eye).
        let turn = |c: Camera, a: f32| {
            let q = glam::Quat::from_rotation_y(a);
            Camera::from_corners(c.eye, c.corners.map(|p| c.eye + q * (p - c.eye)))
        };
        let turned = turn(shifted, 0.5);
        let path = Keyframes::new(&[key(0.0, shifted), key(1.0, turned)], Interpolation::Linear).unwrap();
        let mid = path.camera_at(0.5);
        let expect = turn(shifted, 0.25);
        for (got, want) in mid.corners.iter().zip(expect.corners) {
            assert!(close(*got, want, 1e-4), "{got:?} vs {want:?}");
        }
    }

    #[test]
    fn a_full_orbit_over_several_keys_turns_smoothly_one_way_without_a_flip() {
        // 0°, 90°, … 360°: each step is a quarter turn, the whole a full one.
        let keys: Vec<_> = (0..=4).map(|i| key(i as f64, orbit(90.0 * i as f32))).collect();
        for interpolation in [Interpolation::Linear, Interpolation::CatmullRom] {
            let path = Keyframes::new(&keys, interpolation).unwrap();
            let frames = path.sample(60.0).unwrap();
            assert_eq!(frames.len(), 241);
            let mut turned = 0.0f32;
            for pair in frames.windows(2) {
                let (a, b) = (&pair[0].camera, &pair[1].camera);
                let mut step = heading(b) - heading(a);
                if step > 180.0 {
                    step -= 360.0;
                } else if step < -180.0 {
                    step += 360.0;
                }
                // One way, no frame-to-frame jump, and up stays up.
                assert!(step > 0.5 && step < 3.0, "{interpolation:?}: a step of {step}°");
                assert!(b.up().y > 0.9, "{interpolation:?}: up {:?}", b.up());
                turned += step;
            }
            assert!((turned - 360.0).abs() < 0.01, "{interpolation:?} turned {turned}°");
        }
    }

    #[test]
    fn catmull_rom_rounds_the_keys_without_overshooting_a_stop() {
        let p = |x: f32, z: f32| look([x, 1.0, z], [x, 1.0, z - 10.0]);
        // Move right, stand still for a second, move on.
        let keys =
            [key(0.0, p(0.0, 0.0)), key(1.0, p(4.0, 0.0)), key(2.0, p(4.0, 0.0)), key(3.0, p(4.0, -4.0))];
        let path = Keyframes::new(&keys, Interpolation::CatmullRom).unwrap();
        for i in 0..=10 {
            let c = path.camera_at(1.0 + i as f64 / 10.0);
            assert_eq!(c.eye, keys[1].camera.eye, "it stands still between two equal keys");
        }
        for i in 0..=100 {
            let e = path.camera_at(i as f64 / 100.0).eye;
            assert!(e.x >= -1e-5 && e.x <= 4.0 + 1e-5, "overshoots the stop: {e:?}");
        }
        // A smooth corner: the eye's velocity just before and after key 1 of
        // a path through it agrees in direction.
        let keys = [key(0.0, p(0.0, 0.0)), key(1.0, p(4.0, 0.0)), key(2.0, p(4.0, -4.0))];
        let path = Keyframes::new(&keys, Interpolation::CatmullRom).unwrap();
        let at = |t: f64| path.camera_at(t).eye;
        let (before, after) = ((at(1.0) - at(0.999)).normalize(), (at(1.001) - at(1.0)).normalize());
        assert!(before.dot(after) > 0.999, "{before:?} vs {after:?}");
    }

    #[test]
    fn a_single_key_is_one_frame_and_counts_include_the_last_key_when_it_lands() {
        let one = Keyframes::new(&[key(5.0, orbit(10.0))], Interpolation::CatmullRom).unwrap();
        let frames = one.sample(24.0).unwrap();
        assert_eq!(frames, vec![key(5.0, orbit(10.0))]);
        let keys = [key(0.0, orbit(0.0)), key(1.0, orbit(30.0)), key(2.9, orbit(60.0))];
        let path = Keyframes::new(&keys, Interpolation::Linear).unwrap();
        // 2.9 s at 10 fps: frames at 0.0, 0.1, … 2.9 — the last lands on the key.
        let frames = path.sample(10.0).unwrap();
        assert_eq!(frames.len(), 30);
        assert_eq!(frames[29], keys[2]);
        assert!((frames[7].t - 0.7).abs() < 1e-12);
        // At 4 fps the last frame is at 2.75 s, short of the key.
        assert_eq!(path.frame_count(4.0), Ok(12));
    }

    #[test]
    fn too_many_frames_and_bad_rates_are_refused_naming_the_limit() {
        let keys = [key(0.0, orbit(0.0)), key(3600.0 * 24.0, orbit(30.0))];
        let path = Keyframes::new(&keys, Interpolation::Linear).unwrap();
        let e = path.sample(24.0).unwrap_err();
        assert!(matches!(e, KeyframeError::TooManyFrames { .. }), "{e:?}");
        assert!(e.to_string().contains(&format!("limit of {}", limits::PATH_FRAMES.max)), "{e}");
        for fps in [0.0, -1.0, f64::NAN, f64::INFINITY, 1e6] {
            let e = path.frame_count(fps).unwrap_err();
            assert!(matches!(e, KeyframeError::Fps(_)), "{fps}: {e:?}");
            assert!(e.to_string().contains("between 0 and 1000"), "{e}");
        }
    }

    #[test]
    fn bad_keys_are_refused_naming_the_key() {
        let good = orbit(0.0);
        let refused = |keys: &[Keyframe]| Keyframes::new(keys, Interpolation::CatmullRom).unwrap_err();
        assert_eq!(refused(&[]), KeyframeError::NoKeys);
        for t in [f64::NAN, f64::INFINITY] {
            let e = refused(&[key(0.0, good), key(t, good)]);
            assert!(matches!(e, KeyframeError::TimeNotFinite { key: 1, .. }), "{e:?}");
            assert_eq!(e.key(), Some(1));
        }
        let e = refused(&[key(1.0, good), key(1.0, good)]);
        assert_eq!(e, KeyframeError::TimeNotIncreasing { key: 1, t: 1.0, previous: 1.0 });
        assert!(e.to_string().contains("key 1: time 1 s is not after key 0's time 1 s"), "{e}");
        let mut nan = good;
        nan.eye.y = f32::NAN;
        let e = refused(&[key(0.0, good), key(1.0, good), key(2.0, nan)]);
        assert_eq!(e, KeyframeError::Camera { key: 2, source: CameraError::NonFinite });
        assert_eq!(e.key(), Some(2));
        let mut skew = good;
        skew.corners[3] += skew.plane_x() * 0.1;
        assert_eq!(refused(&[key(0.0, skew)]), KeyframeError::NotRectangular { key: 0 });
        let mut mirrored = good;
        mirrored.corners.swap(0, 1);
        mirrored.corners.swap(2, 3);
        assert_eq!(refused(&[key(0.0, good), key(1.0, mirrored)]), KeyframeError::Mirrored { key: 1 });
        let e = refused(&[key(0.0, orbit(0.0)), key(1.0, orbit(180.0))]);
        assert!(matches!(e, KeyframeError::HalfTurn { key: 1, degrees } if degrees > 179.0), "{e:?}");
        assert!(e.to_string().contains("add a key in between"), "{e}");
        // Half a turn in two steps is fine.
        Keyframes::new(
            &[key(0.0, orbit(0.0)), key(1.0, orbit(90.0)), key(2.0, orbit(180.0))],
            Interpolation::Linear,
        )
        .unwrap();
    }
}

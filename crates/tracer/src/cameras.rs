//! The paper's camera: an image plane given by its four corners and an eye point.
//!
//! `P0` is the top-left corner, `P1` top-right, `P2` bottom-right and `P3`
//! bottom-left. Pixel `(x, y)` of a `W × H` image lies at
//! `P0 + (P1 − P0)·(x + ½)/W + (P3 − P0)·(y + ½)/H`, and its primary ray runs from
//! the eye through that point. The default plane is 8 × 6 units with the eye
//! 12.5 units in front of its centre (about 35° horizontal field of view).
//!
//! Moving the camera moves the plane — rotating it about the eye or advancing it
//! along its normal — and then recomputes the eye from the new plane, at the same
//! distance behind its centre, as the paper describes.

use crate::geometry::Ray;
use crate::math;
use glam::{Vec3, Vec4};
use serde::{Deserialize, Serialize};

/// Distance of the eye behind the image plane's centre in the paper's setup.
pub const PAPER_EYE_DISTANCE: f32 = 12.5;

/// Why a camera cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CameraError {
    /// A corner or the eye has a NaN or infinite coordinate.
    #[error("camera has a non-finite coordinate")]
    NonFinite,
    /// The image plane's corners do not span an area.
    #[error("camera image plane has zero area (its corners P0, P1, P3 are collinear or equal)")]
    ZeroArea,
    /// The eye lies in the image plane, so it cannot look through it.
    #[error("camera eye lies in the image plane")]
    EyeInPlane,
}

/// A pinhole camera defined by its image plane's corners and an eye point.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    /// The eye (centre of projection).
    pub eye: Vec3,
    /// Image-plane corners `[P0, P1, P2, P3]`: top-left, top-right,
    /// bottom-right, bottom-left.
    pub corners: [Vec3; 4],
}

impl Default for Camera {
    /// The paper's camera: an 8 × 6 plane centred on the origin facing −Z, the eye
    /// 12.5 units in front of it at (0, 0, 12.5).
    fn default() -> Self {
        let (hw, hh) = (4.0, 3.0);
        Camera::from_corners(
            Vec3::new(0.0, 0.0, PAPER_EYE_DISTANCE),
            [
                Vec3::new(-hw, hh, 0.0),
                Vec3::new(hw, hh, 0.0),
                Vec3::new(hw, -hh, 0.0),
                Vec3::new(-hw, -hh, 0.0),
            ],
        )
    }
}

impl Camera {
    /// A camera from an explicit eye and plane corners (not validated; see
    /// [`Camera::validate`]).
    pub fn from_corners(eye: Vec3, corners: [Vec3; 4]) -> Self {
        Self { eye, corners }
    }

    /// A camera at `eye` looking at `target`, with `up` as the approximate up
    /// direction, a horizontal field of view of `hfov_degrees` and an image plane
    /// of aspect `aspect` (width / height), placed [`PAPER_EYE_DISTANCE`] in
    /// front of the eye.
    pub fn look_at(eye: Vec3, target: Vec3, up: Vec3, hfov_degrees: f32, aspect: f32) -> Self {
        let forward = (target - eye).normalize();
        let right = forward.cross(up).normalize();
        let true_up = right.cross(forward);
        let d = PAPER_EYE_DISTANCE;
        let half_w = d * math::tan(hfov_degrees.to_radians() * 0.5);
        let half_h = half_w / aspect;
        let c = eye + forward * d;
        let (r, u) = (right * half_w, true_up * half_h);
        Self::from_corners(eye, [c - r + u, c + r + u, c + r - u, c - r - u])
    }

    /// Width / height of the image plane.
    pub fn aspect(&self) -> f32 {
        self.plane_x().length() / self.plane_y().length()
    }

    /// The camera for an image of aspect ratio `aspect` (width / height):
    /// the image plane is widened — or heightened, for a narrower image —
    /// about its centre until it has that aspect, the eye where it was. So
    /// an image of another shape than the scene's shows everything the
    /// scene's framing does, plus more at two sides, and nothing is
    /// stretched. Aspects within 10⁻³ of the plane's return the camera as it
    /// is: a plane written with rounded corners (the paper room's 8 × 6.00007)
    /// is the image's shape, not a reason to move every ray by a hair, which
    /// would make the same scene render differently by a client that fits
    /// and one that does not.
    pub fn fit_aspect(&self, aspect: f32) -> Camera {
        let current = self.aspect();
        if !(aspect > 0.0 && aspect.is_finite() && current.is_finite())
            || (aspect / current - 1.0).abs() <= 1e-3
        {
            return *self;
        }
        let (mut x, mut y) = (self.plane_x(), self.plane_y());
        if aspect > current {
            x *= aspect / current;
        } else {
            y *= current / aspect;
        }
        let c = self.center();
        let (hx, hy) = (x * 0.5, y * 0.5);
        Camera::from_corners(self.eye, [c - hx - hy, c + hx - hy, c + hx + hy, c - hx + hy])
    }

    /// Checks that the camera can produce rays.
    pub fn validate(&self) -> Result<(), CameraError> {
        if !self.eye.is_finite() || self.corners.iter().any(|c| !c.is_finite()) {
            return Err(CameraError::NonFinite);
        }
        let n = self.plane_x().cross(self.plane_y());
        let scale = self.plane_x().length() * self.plane_y().length();
        if n.length() <= 1e-6 * scale || scale == 0.0 || scale.is_nan() {
            return Err(CameraError::ZeroArea);
        }
        if (self.center() - self.eye).dot(n.normalize()).abs() <= 1e-6 * scale.sqrt() {
            return Err(CameraError::EyeInPlane);
        }
        Ok(())
    }

    /// `P1 − P0`: the plane's horizontal edge (left to right).
    #[inline]
    pub fn plane_x(&self) -> Vec3 {
        self.corners[1] - self.corners[0]
    }

    /// `P3 − P0`: the plane's vertical edge (top to bottom).
    #[inline]
    pub fn plane_y(&self) -> Vec3 {
        self.corners[3] - self.corners[0]
    }

    /// Centre of the image plane.
    pub fn center(&self) -> Vec3 {
        (self.corners[0] + self.corners[1] + self.corners[2] + self.corners[3]) * 0.25
    }

    /// Unit normal of the image plane pointing away from the eye (the viewing
    /// direction): `(P1 − P0) × (P3 − P0)`, oriented towards the plane.
    pub fn forward(&self) -> Vec3 {
        let n = self.plane_x().cross(self.plane_y()).normalize();
        if (self.center() - self.eye).dot(n) < 0.0 { -n } else { n }
    }

    /// Unit vector along the plane's top edge, left to right.
    pub fn right(&self) -> Vec3 {
        self.plane_x().normalize()
    }

    /// Unit vector up the plane's side, bottom to top.
    pub fn up(&self) -> Vec3 {
        -self.plane_y().normalize()
    }

    /// Distance from the eye to the image plane along its normal.
    pub fn eye_distance(&self) -> f32 {
        (self.center() - self.eye).dot(self.forward())
    }

    /// Horizontal field of view in degrees.
    pub fn hfov_degrees(&self) -> f32 {
        2.0 * math::atan2(self.plane_x().length() * 0.5, self.eye_distance()).to_degrees()
    }

    /// The point on the image plane at fractional image coordinates
    /// `(fx, fy)`, where (0, 0) is `P0` and (1, 1) is `P2`.
    #[inline]
    pub fn plane_point(&self, fx: f32, fy: f32) -> Vec3 {
        self.corners[0] + self.plane_x() * fx + self.plane_y() * fy
    }

    /// The primary ray from the eye through fractional image coordinates
    /// `(fx, fy)`; for the centre of pixel `(x, y)` of a `W × H` image use
    /// `fx = (x + ½)/W`, `fy = (y + ½)/H`. The direction is unit length.
    #[inline]
    pub fn ray(&self, fx: f32, fy: f32) -> Ray {
        Ray::new(self.eye, (self.plane_point(fx, fy) - self.eye).normalize())
    }

    /// [`Camera::ray`] for four image points at once (lane `j`: `fx[j]`,
    /// `fy[j]`), the same operations in SIMD lanes, so the same rays bit for bit.
    #[inline]
    pub fn ray4(&self, fx: Vec4, fy: Vec4) -> [Ray; 4] {
        let (px, py) = (self.plane_x(), self.plane_y());
        let axis = |a: usize| {
            let p = Vec4::splat(self.corners[0][a]) + Vec4::splat(px[a]) * fx + Vec4::splat(py[a]) * fy;
            p - Vec4::splat(self.eye[a])
        };
        let (dx, dy, dz) = (axis(0), axis(1), axis(2));
        let r = Vec4::ONE / (dx * dx + dy * dy + dz * dz).sqrt();
        let (dx, dy, dz) = ((dx * r).to_array(), (dy * r).to_array(), (dz * r).to_array());
        std::array::from_fn(|j| Ray::new(self.eye, Vec3::new(dx[j], dy[j], dz[j])))
    }

    /// Angle subtended by one pixel at the centre of a `width`-pixel-wide image,
    /// in radians: the spread of a primary ray cone, used to filter textures.
    pub fn pixel_spread(&self, width: u32) -> f32 {
        self.plane_x().length() / (width.max(1) as f32 * self.eye_distance())
    }

    /// Rotates the image plane about the eye by `angle` radians around `axis`
    /// (right-handed), then recomputes the eye from the new plane.
    pub fn rotate(&mut self, axis: Vec3, angle: f32) {
        let d = self.eye_distance();
        let axis = axis.normalize();
        let (s, c) = (math::sin(angle), math::cos(angle));
        let eye = self.eye;
        for p in &mut self.corners {
            *p = eye + rotate_vector(*p - eye, axis, s, c);
        }
        self.recompute_eye(d);
    }

    /// Turns left (positive) or right around the view's up axis.
    pub fn yaw(&mut self, angle: f32) {
        self.rotate(self.up(), angle);
    }

    /// Tilts up (positive) or down around the view's right axis.
    pub fn pitch(&mut self, angle: f32) {
        self.rotate(self.right(), angle);
    }

    /// Rolls counter-clockwise (positive, as seen by the viewer) around the
    /// viewing direction.
    pub fn roll(&mut self, angle: f32) {
        self.rotate(-self.forward(), angle);
    }

    /// Moves the plane `k` units along its normal (forward for positive `k`),
    /// then recomputes the eye from the new plane.
    pub fn advance(&mut self, k: f32) {
        let d = self.eye_distance();
        let step = self.forward() * k;
        for p in &mut self.corners {
            *p += step;
        }
        self.recompute_eye(d);
    }

    /// Moves the whole camera sideways (`dx` along right) and vertically (`dy`
    /// along up) without turning it.
    pub fn strafe(&mut self, dx: f32, dy: f32) {
        let step = self.right() * dx + self.up() * dy;
        self.eye += step;
        for p in &mut self.corners {
            *p += step;
        }
    }

    /// Places the eye `d` units behind the plane's centre along its normal.
    fn recompute_eye(&mut self, d: f32) {
        let n = self.plane_x().cross(self.plane_y()).normalize();
        // (P1 − P0) × (P3 − P0) points away from the eye for a right-handed
        // plane; keep whichever side the eye was on.
        let n = if (self.center() - self.eye).dot(n) < 0.0 { -n } else { n };
        self.eye = self.center() - n * d;
    }
}

/// Rodrigues' rotation of `v` around unit `axis`, given sin and cos of the angle.
fn rotate_vector(v: Vec3, axis: Vec3, s: f32, c: f32) -> Vec3 {
    v * c + axis.cross(v) * s + axis * (axis.dot(v) * (1.0 - c))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fitting_an_aspect_widens_or_heightens_the_plane_about_its_centre() {
        let cam = Camera::look_at(Vec3::new(1.0, 2.0, 3.0), Vec3::ZERO, Vec3::Y, 40.0, 4.0 / 3.0);
        assert_eq!(cam.fit_aspect(4.0 / 3.0), cam, "the same aspect changes nothing");
        for aspect in [2.0f32, 1.0, 0.5] {
            let fitted = cam.fit_aspect(aspect);
            assert!((fitted.aspect() - aspect).abs() < 1e-5, "{aspect}");
            assert!((fitted.center() - cam.center()).length() < 1e-5);
            assert_eq!(fitted.eye, cam.eye);
            assert!((fitted.eye_distance() - cam.eye_distance()).abs() < 1e-4);
            assert!((fitted.forward() - cam.forward()).length() < 1e-5);
            // Never cropped: each side at least as long as before.
            assert!(fitted.plane_x().length() >= cam.plane_x().length() * 0.99999);
            assert!(fitted.plane_y().length() >= cam.plane_y().length() * 0.99999);
        }
    }
    use std::f32::consts::FRAC_PI_2;

    fn close(a: Vec3, b: Vec3) -> bool {
        (a - b).length() < 1e-4
    }

    #[test]
    fn default_is_the_papers_camera() {
        let c = Camera::default();
        assert_eq!(c.plane_x().length(), 8.0);
        assert_eq!(c.plane_y().length(), 6.0);
        assert!((c.eye_distance() - 12.5).abs() < 1e-6);
        assert!(close(c.forward(), Vec3::NEG_Z));
        let fov = c.hfov_degrees();
        assert!((fov - 35.49).abs() < 0.05, "fov {fov}");
        c.validate().unwrap();
    }

    #[test]
    fn pixel_mapping_follows_the_paper() {
        let c = Camera::default();
        let (w, h) = (4.0, 3.0);
        // Pixel (0, 0): P0 + (P1-P0)/8 + (P3-P0)/6.
        let expect = c.corners[0] + c.plane_x() * (0.5 / w) + c.plane_y() * (0.5 / h);
        assert!(close(c.plane_point(0.5 / w, 0.5 / h), expect));
        assert!(close(expect, Vec3::new(-3.0, 2.0, 0.0)));
        let r = c.ray(0.5, 0.5);
        assert!(close(r.origin, c.eye));
        assert!(close(r.dir, Vec3::NEG_Z));
    }

    #[test]
    fn yaw_turns_left_about_the_eye() {
        let mut c = Camera::default();
        let eye = c.eye;
        c.yaw(FRAC_PI_2);
        assert!(close(c.eye, eye), "eye stays put when rotating about it");
        assert!(close(c.forward(), Vec3::NEG_X), "forward {:?}", c.forward());
        assert!(close(c.up(), Vec3::Y));
        assert!((c.eye_distance() - 12.5).abs() < 1e-4);
    }

    #[test]
    fn pitch_tilts_up() {
        let mut c = Camera::default();
        c.pitch(FRAC_PI_2);
        assert!(close(c.forward(), Vec3::Y), "forward {:?}", c.forward());
        assert!(close(c.right(), Vec3::X));
        assert!(close(c.eye, Vec3::new(0.0, 0.0, 12.5)));
    }

    #[test]
    fn roll_turns_counter_clockwise() {
        let mut c = Camera::default();
        c.roll(FRAC_PI_2);
        assert!(close(c.forward(), Vec3::NEG_Z));
        // Counter-clockwise as seen by the viewer: right now points up.
        assert!(close(c.right(), Vec3::Y), "right {:?}", c.right());
        assert!((c.plane_x().length() - 8.0).abs() < 1e-4, "the plane keeps its size");
    }

    #[test]
    fn rotation_about_an_arbitrary_axis_keeps_the_eye_and_plane_shape() {
        let mut c = Camera::default();
        c.rotate(Vec3::new(1.0, 2.0, 3.0), 0.7);
        assert!(close(c.eye, Vec3::new(0.0, 0.0, 12.5)));
        assert!((c.eye_distance() - 12.5).abs() < 1e-4);
        assert!((c.plane_x().length() - 8.0).abs() < 1e-4);
        assert!(c.plane_x().dot(c.plane_y()).abs() < 1e-4);
    }

    #[test]
    fn four_rays_at_once_are_the_single_rays_bit_for_bit() {
        let mut cam = Camera::default();
        cam.rotate(Vec3::new(0.3, 1.0, 0.2).normalize(), 0.7);
        for i in 0..500 {
            let f = |k: u32| ((i * 4 + k) as f32 * 0.618_034).fract() * 1.2 - 0.1;
            let (fx, fy) = ([f(0), f(1), f(2), f(3)], [f(3), f(0), f(1), f(2)].map(|v| 1.0 - v));
            let four = cam.ray4(Vec4::from_array(fx), Vec4::from_array(fy));
            for j in 0..4 {
                let one = cam.ray(fx[j], fy[j]);
                assert_eq!(four[j].origin, one.origin);
                assert_eq!(four[j].dir.to_array().map(f32::to_bits), one.dir.to_array().map(f32::to_bits));
            }
        }
    }

    #[test]
    fn advance_moves_plane_and_eye_along_the_normal() {
        let mut c = Camera::default();
        c.advance(2.0);
        assert!(close(c.eye, Vec3::new(0.0, 0.0, 10.5)));
        assert!(close(c.center(), Vec3::new(0.0, 0.0, -2.0)));
        c.advance(-5.0);
        assert!(close(c.eye, Vec3::new(0.0, 0.0, 15.5)));
        // After a turn, advancing follows the new normal.
        c.yaw(FRAC_PI_2);
        let before = c.eye;
        c.advance(1.0);
        assert!(close(c.eye - before, Vec3::NEG_X));
    }

    #[test]
    fn strafe_moves_without_turning() {
        let mut c = Camera::default();
        c.strafe(1.0, 2.0);
        assert!(close(c.eye, Vec3::new(1.0, 2.0, 12.5)));
        assert!(close(c.forward(), Vec3::NEG_Z));
    }

    #[test]
    fn look_at_matches_the_default_camera() {
        let c = Camera::look_at(
            Vec3::new(0.0, 0.0, 12.5),
            Vec3::ZERO,
            Vec3::Y,
            Camera::default().hfov_degrees(),
            4.0 / 3.0,
        );
        let d = Camera::default();
        for i in 0..4 {
            assert!(
                close(c.corners[i], d.corners[i]),
                "corner {i}: {:?} vs {:?}",
                c.corners[i],
                d.corners[i]
            );
        }
        let c = Camera::look_at(Vec3::new(5.0, 1.0, 0.0), Vec3::new(5.0, 1.0, -10.0), Vec3::Y, 90.0, 2.0);
        assert!(close(c.forward(), Vec3::NEG_Z));
        assert!((c.hfov_degrees() - 90.0).abs() < 1e-3);
        assert!((c.plane_x().length() / c.plane_y().length() - 2.0).abs() < 1e-4);
    }

    #[test]
    fn validation_rejects_broken_planes() {
        let mut c = Camera::default();
        c.corners[1] = c.corners[0];
        assert_eq!(c.validate(), Err(CameraError::ZeroArea));
        let mut c = Camera::default();
        c.eye.x = f32::NAN;
        assert_eq!(c.validate(), Err(CameraError::NonFinite));
        let mut c = Camera::default();
        c.eye = c.center();
        assert_eq!(c.validate(), Err(CameraError::EyeInPlane));
    }
}

//! Keyboard and mouse → camera moves, as in the paper: rotate the image plane
//! about the eye (yaw around the view's up axis, pitch around its right axis,
//! roll around the viewing direction) and move it `k` units along its normal;
//! plus strafing and mouse-drag look.
//!
//! Pure: no window involved. Keys are winit's *physical* key codes, so the
//! WASD block works on any keyboard layout.
//!
//! | keys | action |
//! | --- | --- |
//! | `W` / `↑` | advance `k` units along the image-plane normal |
//! | `S` / `↓` | move back `k` units |
//! | `A` / `←` | turn left (yaw) |
//! | `D` / `→` | turn right |
//! | `R` / `PageUp` | tilt up (pitch) |
//! | `F` / `PageDown` | tilt down |
//! | `Q` / `E` | roll counter-clockwise / clockwise |
//! | `Z` / `C`, `Shift`+`A`/`D`, `Shift`+`←`/`→` | strafe left / right |
//! | `Shift`+`W`/`S`, `Shift`+`↑`/`↓` | strafe up / down |
//! | mouse drag (left button) | look around |
//! | `Home` | back to the scene's camera |
//! | `F12` / `P` | save a screenshot PNG |
//! | `O` / `Tab` | toggle the tile-ownership overlay |
//! | `H` | toggle the status text |
//! | `Escape` | quit |

use isin_tracer::Camera;
use winit::keyboard::KeyCode;

/// A camera move.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Move {
    /// Move the image plane forward along its normal.
    Forward,
    /// Move the image plane backward along its normal.
    Back,
    /// Rotate left about the eye, around the view's up axis.
    YawLeft,
    /// Rotate right about the eye, around the view's up axis.
    YawRight,
    /// Rotate up about the eye, around the view's right axis.
    PitchUp,
    /// Rotate down about the eye, around the view's right axis.
    PitchDown,
    /// Roll counter-clockwise (as seen by the viewer) around the viewing direction.
    RollCcw,
    /// Roll clockwise around the viewing direction.
    RollCw,
    /// Slide left without turning.
    StrafeLeft,
    /// Slide right without turning.
    StrafeRight,
    /// Slide up without turning.
    StrafeUp,
    /// Slide down without turning.
    StrafeDown,
}

/// What a key asks the viewer to do.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Command {
    /// Move the camera.
    Move(Move),
    /// Go back to the scene's own camera.
    ResetCamera,
    /// Save the displayed image as a PNG.
    Screenshot,
    /// Show or hide the tile-ownership overlay.
    ToggleOverlay,
    /// Show or hide the status text.
    ToggleStatus,
    /// Close the window.
    Quit,
}

/// Maps a physical key (with the Shift state) to a command; `None` for keys the
/// viewer does not use.
pub fn command_for_key(key: KeyCode, shift: bool) -> Option<Command> {
    use Command as C;
    use KeyCode as K;
    use Move as M;
    let command = match (key, shift) {
        (K::KeyW | K::ArrowUp, false) => C::Move(M::Forward),
        (K::KeyS | K::ArrowDown, false) => C::Move(M::Back),
        (K::KeyW | K::ArrowUp, true) => C::Move(M::StrafeUp),
        (K::KeyS | K::ArrowDown, true) => C::Move(M::StrafeDown),
        (K::KeyA | K::ArrowLeft, false) => C::Move(M::YawLeft),
        (K::KeyD | K::ArrowRight, false) => C::Move(M::YawRight),
        (K::KeyA | K::ArrowLeft, true) | (K::KeyZ, _) => C::Move(M::StrafeLeft),
        (K::KeyD | K::ArrowRight, true) | (K::KeyC, _) => C::Move(M::StrafeRight),
        (K::KeyR | K::PageUp, _) => C::Move(M::PitchUp),
        (K::KeyF | K::PageDown, _) => C::Move(M::PitchDown),
        (K::KeyQ, _) => C::Move(M::RollCcw),
        (K::KeyE, _) => C::Move(M::RollCw),
        (K::Home, _) => C::ResetCamera,
        (K::F12 | K::KeyP, _) => C::Screenshot,
        (K::KeyO | K::Tab, _) => C::ToggleOverlay,
        (K::KeyH, _) => C::ToggleStatus,
        (K::Escape, _) => C::Quit,
        _ => return None,
    };
    Some(command)
}

/// Step sizes of the navigation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Controls {
    /// `k`: how far one forward/back key press moves the image plane, in scene units.
    pub move_step: f32,
    /// How far one strafe key press slides the camera, in scene units.
    pub strafe_step: f32,
    /// Rotation of one yaw/pitch/roll key press, in radians.
    pub turn_step: f32,
    /// Mouse-drag look: radians of rotation per pixel dragged.
    pub look_per_pixel: f32,
}

impl Default for Controls {
    /// Half a unit per move (the paper's scene is about 10 units across), 3° per
    /// turn, 0.2° per dragged pixel.
    fn default() -> Self {
        Self {
            move_step: 0.5,
            strafe_step: 0.5,
            turn_step: 3f32.to_radians(),
            look_per_pixel: 0.2f32.to_radians(),
        }
    }
}

impl Controls {
    /// Default turning speeds with move and strafe steps of 1/40 of `extent`
    /// (e.g. the diagonal of the scene's bounding box), so navigation feels
    /// the same in a small or a large scene.
    pub fn for_scene_extent(extent: f32) -> Self {
        let d = Self::default();
        if !(extent.is_finite() && extent > 0.0) {
            return d;
        }
        let step = extent / 40.0;
        Self { move_step: step, strafe_step: step, ..d }
    }

    /// Applies one move to `camera`.
    pub fn apply(&self, mv: Move, camera: &mut Camera) {
        match mv {
            Move::Forward => camera.advance(self.move_step),
            Move::Back => camera.advance(-self.move_step),
            Move::YawLeft => camera.yaw(self.turn_step),
            Move::YawRight => camera.yaw(-self.turn_step),
            Move::PitchUp => camera.pitch(self.turn_step),
            Move::PitchDown => camera.pitch(-self.turn_step),
            Move::RollCcw => camera.roll(self.turn_step),
            Move::RollCw => camera.roll(-self.turn_step),
            Move::StrafeLeft => camera.strafe(-self.strafe_step, 0.0),
            Move::StrafeRight => camera.strafe(self.strafe_step, 0.0),
            Move::StrafeUp => camera.strafe(0.0, self.strafe_step),
            Move::StrafeDown => camera.strafe(0.0, -self.strafe_step),
        }
    }

    /// Mouse-drag look: the cursor moved by `(dx, dy)` pixels (right, down)
    /// with the button held. Dragging right turns right, dragging down tilts down.
    pub fn look(&self, dx: f64, dy: f64, camera: &mut Camera) {
        if dx != 0.0 {
            camera.yaw(-(dx as f32) * self.look_per_pixel);
        }
        if dy != 0.0 {
            camera.pitch(-(dy as f32) * self.look_per_pixel);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use isin_tracer::Vec3;

    fn close(a: Vec3, b: Vec3) -> bool {
        (a - b).length() < 1e-4
    }

    /// Applies the command bound to `key` to the paper's default camera.
    fn after(key: KeyCode, shift: bool, controls: &Controls) -> Camera {
        let mut c = Camera::default();
        match command_for_key(key, shift) {
            Some(Command::Move(m)) => controls.apply(m, &mut c),
            other => panic!("{key:?} is not a move: {other:?}"),
        }
        c
    }

    fn controls() -> Controls {
        Controls { move_step: 2.0, strafe_step: 1.5, turn_step: 0.25, look_per_pixel: 0.01 }
    }

    #[test]
    fn forward_and_back_move_k_units_along_the_plane_normal() {
        let k = controls();
        let start = Camera::default();
        for key in [KeyCode::KeyW, KeyCode::ArrowUp] {
            let c = after(key, false, &k);
            assert!(close(c.eye, start.eye + start.forward() * 2.0), "{key:?}: {:?}", c.eye);
            assert!(close(c.center(), start.center() + start.forward() * 2.0));
            assert!(close(c.forward(), start.forward()) && close(c.up(), start.up()));
        }
        for key in [KeyCode::KeyS, KeyCode::ArrowDown] {
            let c = after(key, false, &k);
            assert!(close(c.eye, start.eye - start.forward() * 2.0), "{key:?}: {:?}", c.eye);
        }
    }

    #[test]
    fn yaw_keys_turn_about_the_eye_around_up() {
        let k = controls();
        let start = Camera::default();
        for (key, sign) in [(KeyCode::KeyA, 1.0f32), (KeyCode::ArrowLeft, 1.0), (KeyCode::KeyD, -1.0)] {
            let c = after(key, false, &k);
            assert!(close(c.eye, start.eye), "{key:?} keeps the eye");
            assert!(close(c.up(), start.up()), "{key:?} keeps up");
            // Turning left from −Z swings the view towards −X.
            let expect = Vec3::new(-(0.25f32.sin()) * sign, 0.0, -(0.25f32.cos()));
            assert!(close(c.forward(), expect), "{key:?}: forward {:?}", c.forward());
        }
        let c = after(KeyCode::ArrowRight, false, &k);
        assert!(c.forward().x > 0.2, "right arrow turns right: {:?}", c.forward());
    }

    #[test]
    fn pitch_keys_tilt_around_right() {
        let k = controls();
        let start = Camera::default();
        for (key, sign) in [
            (KeyCode::KeyR, 1.0f32),
            (KeyCode::PageUp, 1.0),
            (KeyCode::KeyF, -1.0),
            (KeyCode::PageDown, -1.0),
        ] {
            let c = after(key, false, &k);
            assert!(close(c.eye, start.eye) && close(c.right(), start.right()), "{key:?}");
            let expect = Vec3::new(0.0, 0.25f32.sin() * sign, -(0.25f32.cos()));
            assert!(close(c.forward(), expect), "{key:?}: forward {:?}", c.forward());
        }
    }

    #[test]
    fn roll_keys_turn_the_plane_around_the_view_direction() {
        let k = controls();
        let start = Camera::default();
        let q = after(KeyCode::KeyQ, false, &k);
        assert!(close(q.eye, start.eye) && close(q.forward(), start.forward()));
        // Counter-clockwise as seen by the viewer: the up vector leans left.
        assert!(close(q.up(), Vec3::new(-(0.25f32.sin()), 0.25f32.cos(), 0.0)), "up {:?}", q.up());
        let e = after(KeyCode::KeyE, false, &k);
        assert!(close(e.up(), Vec3::new(0.25f32.sin(), 0.25f32.cos(), 0.0)), "up {:?}", e.up());
    }

    #[test]
    fn strafe_keys_slide_without_turning() {
        let k = controls();
        let start = Camera::default();
        let cases = [
            (KeyCode::KeyZ, false, Vec3::new(-1.5, 0.0, 0.0)),
            (KeyCode::KeyA, true, Vec3::new(-1.5, 0.0, 0.0)),
            (KeyCode::ArrowLeft, true, Vec3::new(-1.5, 0.0, 0.0)),
            (KeyCode::KeyC, false, Vec3::new(1.5, 0.0, 0.0)),
            (KeyCode::KeyD, true, Vec3::new(1.5, 0.0, 0.0)),
            (KeyCode::KeyW, true, Vec3::new(0.0, 1.5, 0.0)),
            (KeyCode::ArrowDown, true, Vec3::new(0.0, -1.5, 0.0)),
        ];
        for (key, shift, delta) in cases {
            let c = after(key, shift, &k);
            assert!(close(c.eye, start.eye + delta), "{key:?} shift={shift}: eye {:?}", c.eye);
            assert!(close(c.forward(), start.forward()) && close(c.up(), start.up()), "{key:?} turned");
        }
    }

    #[test]
    fn moves_follow_the_current_orientation() {
        // After turning a quarter to the left, forward is −X: W must move along it.
        let k = Controls { turn_step: std::f32::consts::FRAC_PI_2, ..controls() };
        let mut c = Camera::default();
        k.apply(Move::YawLeft, &mut c);
        let eye = c.eye;
        k.apply(Move::Forward, &mut c);
        assert!(close(c.eye - eye, Vec3::new(-2.0, 0.0, 0.0)), "{:?}", c.eye - eye);
        k.apply(Move::StrafeRight, &mut c);
        assert!(close(c.eye - eye, Vec3::new(-2.0, 0.0, -1.5)), "{:?}", c.eye - eye);
    }

    #[test]
    fn mouse_drag_looks_around() {
        let k = controls();
        let mut c = Camera::default();
        k.look(10.0, 0.0, &mut c);
        assert!(close(c.forward(), Vec3::new(0.1f32.sin(), 0.0, -(0.1f32.cos()))), "{:?}", c.forward());
        let mut c = Camera::default();
        k.look(0.0, 20.0, &mut c);
        assert!(close(c.forward(), Vec3::new(0.0, -(0.2f32.sin()), -(0.2f32.cos()))), "{:?}", c.forward());
        assert!(close(c.eye, Camera::default().eye));
    }

    #[test]
    fn non_move_keys() {
        assert_eq!(command_for_key(KeyCode::Escape, false), Some(Command::Quit));
        assert_eq!(command_for_key(KeyCode::F12, false), Some(Command::Screenshot));
        assert_eq!(command_for_key(KeyCode::KeyP, true), Some(Command::Screenshot));
        assert_eq!(command_for_key(KeyCode::KeyO, false), Some(Command::ToggleOverlay));
        assert_eq!(command_for_key(KeyCode::Home, false), Some(Command::ResetCamera));
        assert_eq!(command_for_key(KeyCode::KeyH, false), Some(Command::ToggleStatus));
        assert_eq!(command_for_key(KeyCode::KeyX, false), None);
    }

    #[test]
    fn steps_scale_with_the_scene() {
        let c = Controls::for_scene_extent(400.0);
        assert_eq!(c.move_step, 10.0);
        assert_eq!(c.turn_step, Controls::default().turn_step);
        assert_eq!(Controls::for_scene_extent(f32::NAN), Controls::default());
    }
}

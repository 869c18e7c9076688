//! Keyboard and mouse → camera moves, as in the paper: rotate the image plane
//! about the eye (yaw around the view's up axis, pitch around its right axis,
//! roll around the viewing direction) and move it `k` units along its normal;
//! plus strafing and mouse-drag look.
//!
//! A key press moves one step (the paper's "move by k units"); holding a move
//! key down keeps moving smoothly after [`Controls::repeat_delay`], at
//! [`Controls::repeat_rate`] steps per second ([`HeldMoves`]), independent of
//! the system's key-repeat settings.
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
//! | `F12` / `P` | save a screenshot (PNG or JPEG) |
//! | `O` / `Tab` | toggle the tile-ownership overlay |
//! | `H` | toggle the status text |
//! | `Escape` | quit |

use isin_tracer::Camera;
use std::time::{Duration, Instant};
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
    /// Double the move and strafe steps.
    Faster,
    /// Halve the move and strafe steps.
    Slower,
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
        (K::Equal | K::NumpadAdd, _) => C::Faster,
        (K::Minus | K::NumpadSubtract, _) => C::Slower,
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
    /// How long a move key must be held before it moves continuously.
    pub repeat_delay: Duration,
    /// Steps per second of a held move key.
    pub repeat_rate: f32,
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
            repeat_delay: Duration::from_millis(200),
            repeat_rate: 15.0,
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

    /// Multiplies the move and strafe steps by `factor` (turning is
    /// unchanged); a step that would not stay finite and positive is kept.
    pub fn scale_steps(&mut self, factor: f32) {
        if factor.is_finite() && factor > 0.0 {
            let scaled = |v: f32| {
                let s = v * factor;
                if s.is_finite() && s > 0.0 { s } else { v }
            };
            self.move_step = scaled(self.move_step);
            self.strafe_step = scaled(self.strafe_step);
        }
    }

    /// Applies one step of a move to `camera`.
    pub fn apply(&self, mv: Move, camera: &mut Camera) {
        self.apply_steps(mv, 1.0, camera);
    }

    /// Applies `steps` (possibly fractional) steps of a move to `camera`.
    pub fn apply_steps(&self, mv: Move, steps: f32, camera: &mut Camera) {
        let (m, s, t) = (self.move_step * steps, self.strafe_step * steps, self.turn_step * steps);
        match mv {
            Move::Forward => camera.advance(m),
            Move::Back => camera.advance(-m),
            Move::YawLeft => camera.yaw(t),
            Move::YawRight => camera.yaw(-t),
            Move::PitchUp => camera.pitch(t),
            Move::PitchDown => camera.pitch(-t),
            Move::RollCcw => camera.roll(t),
            Move::RollCw => camera.roll(-t),
            Move::StrafeLeft => camera.strafe(-s, 0.0),
            Move::StrafeRight => camera.strafe(s, 0.0),
            Move::StrafeUp => camera.strafe(0.0, s),
            Move::StrafeDown => camera.strafe(0.0, -s),
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

/// Move keys currently held down, for continuous motion.
#[derive(Clone, Debug, Default)]
pub struct HeldMoves {
    /// Key, its move, and the time up to which its motion has been handed out.
    held: Vec<(KeyCode, Move, Instant)>,
}

impl HeldMoves {
    /// Records that `key` (bound to `mv`) went down at `at`. Returns false if
    /// it was already held (a system key repeat), which should not move again.
    pub fn press(&mut self, key: KeyCode, mv: Move, at: Instant, controls: &Controls) -> bool {
        if self.held.iter().any(|h| h.0 == key) {
            return false;
        }
        // Continuous motion starts after the delay.
        self.held.push((key, mv, at + controls.repeat_delay));
        true
    }

    /// Records that `key` was released.
    pub fn release(&mut self, key: KeyCode) {
        self.held.retain(|h| h.0 != key);
    }

    /// Forgets every key (e.g. when the window loses focus).
    pub fn release_all(&mut self) {
        self.held.clear();
    }

    /// True when no move key is held.
    pub fn is_empty(&self) -> bool {
        self.held.is_empty()
    }

    /// The motion due up to `now`: each held key's steps since it was last
    /// asked, at [`Controls::repeat_rate`] per second, once its delay passed.
    pub fn due(&mut self, now: Instant, controls: &Controls) -> Vec<(Move, f32)> {
        let mut out = Vec::new();
        for (_, mv, since) in &mut self.held {
            if now > *since {
                out.push((*mv, now.duration_since(*since).as_secs_f32() * controls.repeat_rate));
                *since = now;
            }
        }
        out
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
        Controls {
            move_step: 2.0,
            strafe_step: 1.5,
            turn_step: 0.25,
            look_per_pixel: 0.01,
            ..Default::default()
        }
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
        assert_eq!(command_for_key(KeyCode::Equal, true), Some(Command::Faster));
        assert_eq!(command_for_key(KeyCode::NumpadSubtract, false), Some(Command::Slower));
    }

    #[test]
    fn speed_keys_scale_the_move_and_strafe_steps_but_not_turning() {
        let mut c = controls();
        let before = after(KeyCode::KeyW, false, &c);
        let start = Camera::default();
        c.scale_steps(2.0);
        let doubled = after(KeyCode::KeyW, false, &c);
        let d1 = (before.eye - start.eye).length();
        let d2 = (doubled.eye - start.eye).length();
        assert!((d2 - 2.0 * d1).abs() < 1e-4, "{d1} then {d2}");
        assert_eq!(
            after(KeyCode::KeyA, false, &c),
            after(KeyCode::KeyA, false, &controls()),
            "turns unchanged"
        );
        let strafe = (after(KeyCode::KeyZ, false, &c).eye - start.eye).length();
        assert!((strafe - 2.0 * controls().strafe_step).abs() < 1e-4, "{strafe}");
        c.scale_steps(0.5);
        assert_eq!(c, controls());
        for bad in [0.0, -1.0, f32::NAN, f32::INFINITY] {
            c.scale_steps(bad);
            assert_eq!(c, controls(), "factor {bad}");
        }
    }

    #[test]
    fn steps_scale_with_the_scene() {
        let c = Controls::for_scene_extent(400.0);
        assert_eq!(c.move_step, 10.0);
        assert_eq!(c.turn_step, Controls::default().turn_step);
        assert_eq!(Controls::for_scene_extent(f32::NAN), Controls::default());
    }

    #[test]
    fn held_keys_move_continuously_after_the_delay() {
        let k = Controls { repeat_delay: Duration::from_millis(200), repeat_rate: 10.0, ..controls() };
        let t0 = Instant::now();
        let ms = |n| t0 + Duration::from_millis(n);
        let mut held = HeldMoves::default();
        assert!(held.press(KeyCode::KeyW, Move::Forward, t0, &k));
        assert!(!held.press(KeyCode::KeyW, Move::Forward, ms(50), &k), "a system repeat is not a new press");
        assert!(held.due(ms(150), &k).is_empty(), "nothing before the delay");
        let due = held.due(ms(300), &k);
        assert_eq!(due.len(), 1);
        assert_eq!(due[0].0, Move::Forward);
        assert!((due[0].1 - 1.0).abs() < 1e-3, "100 ms at 10 steps/s is one step: {due:?}");
        let due = held.due(ms(350), &k);
        assert!((due[0].1 - 0.5).abs() < 1e-3, "{due:?}");
        held.press(KeyCode::KeyA, Move::YawLeft, ms(350), &k);
        assert_eq!(held.due(ms(400), &k).len(), 1, "A is still in its delay");
        held.release(KeyCode::KeyW);
        assert!(held.due(ms(500), &k).iter().all(|(m, _)| *m == Move::YawLeft));
        held.release_all();
        assert!(held.is_empty());
    }

    #[test]
    fn fractional_steps_scale_the_move() {
        let k = controls();
        let mut a = Camera::default();
        k.apply_steps(Move::Forward, 0.5, &mut a);
        assert!(close(a.eye, Camera::default().eye + Vec3::NEG_Z));
        let mut b = Camera::default();
        k.apply_steps(Move::YawLeft, 2.0, &mut b);
        let mut c = Camera::default();
        k.apply(Move::YawLeft, &mut c);
        k.apply(Move::YawLeft, &mut c);
        assert!(close(b.forward(), c.forward()));
    }
}

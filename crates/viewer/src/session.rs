//! What the viewer does, without the window: turns input into cameras and
//! [`FrameRequest`]s, feeds arriving tiles into the [`Accumulator`], refines a
//! still view pass after pass, and keeps the numbers for the status line.
//!
//! Every camera change starts a new *view*, rendered as a sequence of passes
//! ([`PassKind`]):
//!
//! 1. [`PassKind::Moving`]: fast mode ([`Quality::moving_spp`] samples,
//!    [`Quality::moving_light_samples`] shadow rays) at a lower resolution,
//!    shown enlarged (bilinear). The divisor comes from [`Quality::moving`]: fixed, or
//!    chosen by a [`Controller`] from the measured times of recent fast passes
//!    so that moving frames hold a target frame rate. The very first view
//!    (nothing has moved yet) starts at full resolution.
//! 2. [`PassKind::Sharp`]: when no further input came, the same fast settings
//!    at full resolution, so the still image is sharp quickly (skipped when the
//!    moving pass was already full size).
//! 3. [`PassKind::Refine`]: passes of [`Quality::still_spp`] stratified,
//!    jittered samples with the scene's shadow rays and a different
//!    [`RenderSettings::seed`] (base seed + pass number), so each adds new,
//!    deterministic samples. They are averaged in linear light (replacing the
//!    fast passes, which sample pixel centres with one shadow ray) until the
//!    view has [`Quality::max_spp`] samples per pixel.
//!
//! Each pass paints over the previous one tile by tile, so the screen never
//! goes black. Input at any time supersedes the pass in flight; while a move
//! key is held ([`Session::hold`]) the sharp and refinement passes wait, so the
//! renderers are not handed full-resolution work that the next step of the
//! motion would throw away. Only settings (size, samples, seed) differ between
//! passes: the timing-driven divisor never changes how a pixel is rendered.

use crate::accumulate::{Accumulator, map_tile};
use crate::input::{Controls, Move};
use crate::path::Recorder;
use crate::resolution::{Controller, Divisor, MovingResolution};
use crate::source::{FrameId, FrameRequest, FrameSource, SourceEvent, SourceStatus, Waker};
use isin_tracer::{Camera, RenderSettings, Tile};
use std::collections::{BTreeMap, VecDeque};
use std::time::{Duration, Instant};

/// Samples per pass while moving and while refining.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Quality {
    /// Camera samples per pixel of the first pass after a move.
    pub moving_spp: u32,
    /// Shadow rays per area light in the first pass after a move.
    pub moving_light_samples: u32,
    /// Resolution of the first pass after a move: a fixed divisor, or
    /// dynamic to hold a frame rate.
    pub moving: MovingResolution,
    /// Camera samples per pixel of each refinement pass.
    pub still_spp: u32,
    /// Shadow rays per area light in refinement passes.
    pub still_light_samples: u32,
    /// Refinement stops once a view has this many samples per pixel.
    pub max_spp: u32,
}

impl Quality {
    /// Fast passes of 1 sample (the pixel centre) and 1 shadow ray, sized
    /// dynamically for 30 frames per second while moving; refinement passes of
    /// 4 jittered samples with the scene's shadow rays, up to 64 samples per
    /// pixel.
    pub fn for_settings(settings: &RenderSettings) -> Self {
        Self {
            moving_spp: 1,
            moving_light_samples: 1,
            moving: MovingResolution::default(),
            still_spp: 4,
            still_light_samples: settings.light_samples.max(1),
            max_spp: 64,
        }
    }
}

/// Everything the session needs to know up front.
#[derive(Clone, Debug)]
pub struct SessionConfig {
    /// Resolution, recursion depth and base seed (spp and light samples come
    /// from `quality`).
    pub settings: RenderSettings,
    /// Samples per pass.
    pub quality: Quality,
    /// Navigation speeds.
    pub controls: Controls,
    /// The starting camera (also where `Home` goes back to).
    pub camera: Camera,
}

/// What a pass of a view is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PassKind {
    /// The first pass after a move: fast settings, possibly reduced resolution.
    Moving,
    /// The fast settings at full resolution once motion stopped.
    Sharp,
    /// Anti-aliased, soft-shadowed samples added to a still view.
    Refine,
}

impl PassKind {
    /// Accumulation slot within a view: a pass of another kind replaces the
    /// image instead of averaging with it.
    fn slot(self) -> u32 {
        match self {
            PassKind::Moving => 0,
            PassKind::Sharp => 1,
            PassKind::Refine => 2,
        }
    }
}

/// A completed pass, reported once it is on screen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameReport {
    /// The request's id.
    pub frame_id: FrameId,
    /// The view (camera generation): 0 for the starting camera, +1 per move.
    pub view: u32,
    /// Pass within the view: 0 is the moving pass.
    pub pass: u32,
    /// What the pass was for.
    pub kind: PassKind,
    /// The pass's resolution divisor (1 for full resolution).
    pub divisor: Divisor,
    /// The pass's rendered size in pixels.
    pub size: (u32, u32),
    /// Samples per pixel in the view's image after this pass (the fast pass's
    /// one sample is dropped once refinement starts).
    pub spp: u32,
    /// From the request to its last tile.
    pub render_time: Duration,
    /// From the first input the pass shows to its completion (only for the
    /// first pass after a move).
    pub latency: Option<Duration>,
}

#[derive(Clone, Copy, Debug)]
struct InFlight {
    frame_id: FrameId,
    view: u32,
    pass: u32,
    kind: PassKind,
    weight: u32,
    divisor: Divisor,
    /// Rendered size of the pass.
    size: (u32, u32),
    input_at: Option<Instant>,
}

/// The viewer's state, independent of any window.
pub struct Session {
    source: Box<dyn FrameSource>,
    config: SessionConfig,
    camera: Camera,
    view: u32,
    /// Samples per pixel of the current view's completed passes.
    view_spp: u32,
    /// True once the current view has a completed refinement pass.
    refining: bool,
    /// Divisor of the current view's moving pass.
    view_divisor: Divisor,
    /// Chooses the divisor of moving passes.
    controller: Controller,
    /// True while motion goes on (a move key is held): no still passes.
    hold: bool,
    /// The pass that waits for [`Session::hold`] to be released.
    held_pass: Option<u32>,
    /// Time of the first move not yet sent to the source.
    pending_input: Option<Instant>,
    dirty: bool,
    next_id: FrameId,
    in_flight: Option<InFlight>,
    accum: Accumulator,
    owners: BTreeMap<(u32, u32), (Tile, u32)>,
    /// Rendered size of the tiles in `owners`.
    owners_size: (u32, u32),
    recorder: Option<Recorder>,
    /// Completed passes not yet reported, with the input time of moving passes.
    completed: Vec<(FrameReport, Option<Instant>)>,
    completions: VecDeque<Instant>,
    last_report: Option<FrameReport>,
    bytes_window: VecDeque<(Instant, u64)>,
    error: Option<String>,
    /// Cameras still to play back.
    playback: VecDeque<Camera>,
    /// Playback state: `Some(false)` while playing, `Some(true)` once the last
    /// camera's first pass completed.
    played: Option<bool>,
    /// How long a playback dwells on each camera after its first pass.
    dwell: Duration,
    /// When the next playback camera is due (during a dwell).
    playback_due: Option<Instant>,
    /// Aspect ratio of the image plane the view was framed with: the plane
    /// is resized about its centre from this shape when the window changes
    /// ([`Session::resize`]).
    framing: f32,
    /// True when the next request restarts the current camera (after a
    /// resize or a reconnection) rather than a move: not recorded.
    restart: bool,
    /// What the source says about its connection while it is down.
    connection: Option<String>,
    /// Pixels per owner of the pass in flight.
    frame_owners: BTreeMap<u32, u64>,
    /// Pixels per owner of the last completed pass.
    last_owners: BTreeMap<u32, u64>,
}

/// The camera `camera` — framed for a plane of aspect `framing`, then fitted
/// to another — fitted to an image of aspect `aspect` instead: the plane is
/// shrunk back about its centre to the framing's shape, then widened (or
/// heightened) with [`Camera::fit_aspect`]. Resizing back and forth therefore
/// always returns the same plane, and nothing is stretched.
pub fn refit(camera: &Camera, framing: f32, aspect: f32) -> Camera {
    let current = camera.aspect();
    if !(framing > 0.0 && framing.is_finite() && current > 0.0 && current.is_finite()) {
        return camera.fit_aspect(aspect);
    }
    let (mut x, mut y) = (camera.plane_x(), camera.plane_y());
    if current > framing {
        x *= framing / current;
    } else {
        y *= current / framing;
    }
    let c = camera.center();
    let (hx, hy) = (x * 0.5, y * 0.5);
    let core = Camera::from_corners(camera.eye, [c - hx - hy, c + hx - hy, c + hx + hy, c - hx + hy]);
    core.fit_aspect(aspect)
}

/// The size of a window of `width × height` physical pixels rendered at
/// `scale` times its resolution, within the tracer's image limits.
pub fn render_size(width: u32, height: u32, scale: f32) -> (u32, u32) {
    use isin_tracer::limits::{IMAGE_PIXELS, IMAGE_SIDE};
    let scale = if scale.is_finite() && scale > 0.0 { scale as f64 } else { 1.0 };
    let (w, h) = (width.max(1) as f64 * scale, height.max(1) as f64 * scale);
    let side = IMAGE_SIDE.max as f64;
    let fit = (side / w).min(side / h).min((IMAGE_PIXELS.max as f64 / (w * h)).sqrt()).min(1.0);
    // Rounded down when shrunk to the limits, so the product stays within them.
    let round = |v: f64| if fit < 1.0 { (v * fit).floor() } else { v.round() };
    ((round(w) as u32).max(1), (round(h) as u32).max(1))
}

impl Session {
    /// A session drawing from `source`; nothing is requested until [`Session::start`].
    pub fn new(source: Box<dyn FrameSource>, config: SessionConfig) -> Self {
        let (width, height) = (config.settings.width, config.settings.height);
        let accum = Accumulator::new(width, height);
        Self {
            source,
            camera: config.camera,
            controller: Controller::new(config.quality.moving, width, height),
            framing: config.camera.aspect(),
            config,
            view: 0,
            view_spp: 0,
            refining: false,
            view_divisor: Divisor::ONE,
            hold: false,
            held_pass: None,
            pending_input: None,
            dirty: false,
            next_id: 1,
            in_flight: None,
            accum,
            owners: BTreeMap::new(),
            owners_size: (width, height),
            recorder: None,
            completed: Vec::new(),
            completions: VecDeque::new(),
            last_report: None,
            bytes_window: VecDeque::new(),
            error: None,
            playback: VecDeque::new(),
            played: None,
            dwell: Duration::ZERO,
            playback_due: None,
            restart: false,
            connection: None,
            frame_owners: BTreeMap::new(),
            last_owners: BTreeMap::new(),
        }
    }

    /// Records every camera requested from now on into `recorder`.
    pub fn record_to(&mut self, recorder: Recorder) {
        self.recorder = Some(recorder);
    }

    /// Plays `cameras` back as if they were input: the first replaces the
    /// starting camera, each next one is applied as soon as the previous
    /// camera's first (fast) pass completed — a benchmark of the moving
    /// viewer. Call before [`Session::start`].
    pub fn play(&mut self, cameras: impl IntoIterator<Item = Camera>) {
        self.playback = cameras.into_iter().filter(|c| c.validate().is_ok()).collect();
        if let Some(first) = self.playback.pop_front() {
            self.camera = first;
            self.played = Some(false);
        }
    }

    /// Makes a playback dwell `dwell` on each camera after its first pass is
    /// complete (the still view is refined meanwhile) before applying the
    /// next: each move then supersedes refinement passes in flight, as a user
    /// who looks around and moves on does. Zero (the default) moves on at once.
    pub fn set_playback_dwell(&mut self, dwell: Duration) {
        self.dwell = dwell;
    }

    /// When the next camera of a dwelling playback is due, if one is waiting:
    /// the window must call [`Session::tick`] then.
    pub fn next_due(&self) -> Option<Instant> {
        self.playback_due
    }

    /// Applies a playback camera whose dwell is over at `now` (its input time
    /// is when it was due). Returns true when it did.
    pub fn tick(&mut self, now: Instant) -> bool {
        match self.playback_due {
            Some(due) if now >= due => {
                self.playback_due = None;
                self.next_playback_camera(due);
                true
            }
            _ => false,
        }
    }

    fn next_playback_camera(&mut self, at: Instant) {
        match self.playback.pop_front() {
            Some(next) => self.set_camera(next, at),
            None => self.played = Some(true),
        }
    }

    /// True once a playback has shown its last camera.
    pub fn playback_finished(&self) -> bool {
        self.played == Some(true)
    }

    /// Hands the source the waker to call when tiles arrive.
    pub fn set_waker(&mut self, waker: Waker) {
        self.source.set_waker(waker);
    }

    /// Requests the first frame.
    pub fn start(&mut self) {
        self.dirty = true;
        self.flush();
    }

    /// The current camera.
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// The current view (camera generation).
    pub fn view(&self) -> u32 {
        self.view
    }

    /// Applies a move; the frame is requested at the next [`Session::flush`].
    pub fn move_camera(&mut self, mv: Move, at: Instant) {
        let mut camera = self.camera;
        self.config.controls.apply(mv, &mut camera);
        self.set_camera(camera, at);
    }

    /// Applies `steps` (possibly fractional) steps of a move: continuous
    /// motion of a held key.
    pub fn move_steps(&mut self, mv: Move, steps: f32, at: Instant) {
        let mut camera = self.camera;
        self.config.controls.apply_steps(mv, steps, &mut camera);
        self.set_camera(camera, at);
    }

    /// The navigation speeds.
    pub fn controls(&self) -> &Controls {
        &self.config.controls
    }

    /// Multiplies the move and strafe steps by `factor` (the `+` / `-` keys).
    pub fn scale_speed(&mut self, factor: f32) {
        self.config.controls.scale_steps(factor);
        tracing::info!("move step {:.3} scene units", self.config.controls.move_step);
    }

    /// True while the latest camera's first (fast) pass is not complete yet:
    /// continuous motion waits for it, so frames finish while moving.
    pub fn moving_frame_pending(&self) -> bool {
        self.dirty || self.in_flight.is_some_and(|f| f.pass == 0)
    }

    /// Tells the session whether motion goes on (a move key is held down).
    /// While it does, a completed moving pass is not followed by the sharp
    /// and refinement passes — the next step of the motion would supersede
    /// them; once released, the view is sharpened and refined as usual.
    pub fn hold(&mut self, moving: bool) {
        self.hold = moving;
        if !moving
            && !self.dirty
            && self.in_flight.is_none()
            && let Some(pass) = self.held_pass.take()
        {
            self.request_pass(pass, None);
        }
    }

    /// The divisor the next moving pass will use.
    pub fn moving_divisor(&self) -> Divisor {
        self.controller.divisor()
    }

    /// The render resolution: the full size of a view's passes.
    pub fn size(&self) -> (u32, u32) {
        (self.config.settings.width, self.config.settings.height)
    }

    /// Renders at `width × height` from now on (the window was resized): the
    /// image plane of the camera — and of the starting camera — is resized
    /// about its centre to the new shape ([`refit`]), the image on screen is
    /// stretched over the new size until the new view's tiles replace it, and
    /// the view is rendered again, fast pass first. Nothing happens when the
    /// size is the same.
    pub fn resize(&mut self, width: u32, height: u32) {
        let (width, height) = (width.max(1), height.max(1));
        if (width, height) == self.size() {
            return;
        }
        let aspect = width as f32 / height as f32;
        for camera in [&mut self.camera, &mut self.config.camera] {
            let fitted = refit(camera, self.framing, aspect);
            if fitted.validate().is_ok() {
                *camera = fitted;
            }
        }
        let old = std::mem::replace(&mut self.accum, Accumulator::new(width, height));
        let whole = Tile { x: 0, y: 0, w: old.width(), h: old.height() };
        if let Err(e) = self.accum.add_tile_of(u32::MAX, 1.0, whole, &old.to_rgb8(), (whole.w, whole.h)) {
            tracing::debug!("the old image is not carried over: {e}");
        }
        (self.config.settings.width, self.config.settings.height) = (width, height);
        self.controller.resize(width, height);
        self.owners.clear();
        self.owners_size = (width, height);
        self.restart_view();
    }

    /// Renders the current camera again from its first pass (the passes in
    /// flight are forgotten), at the next [`Session::flush`].
    fn restart_view(&mut self) {
        self.in_flight = None;
        self.held_pass = None;
        self.frame_owners.clear();
        self.dirty = true;
        self.restart = true;
    }

    /// Mouse-drag look by `(dx, dy)` pixels.
    pub fn look(&mut self, dx: f64, dy: f64, at: Instant) {
        let mut camera = self.camera;
        self.config.controls.look(dx, dy, &mut camera);
        self.set_camera(camera, at);
    }

    /// Goes back to the starting camera.
    pub fn reset_camera(&mut self, at: Instant) {
        self.set_camera(self.config.camera, at);
    }

    /// Jumps to `camera` (ignored if it cannot produce rays).
    pub fn set_camera(&mut self, camera: Camera, at: Instant) {
        if camera == self.camera && !self.dirty {
            return;
        }
        if let Err(e) = camera.validate() {
            tracing::warn!("ignoring a move to an unusable camera: {e}");
            return;
        }
        self.camera = camera;
        self.dirty = true;
        self.pending_input.get_or_insert(at);
    }

    /// Sends the request for the latest camera if it changed since the last
    /// one (call once per batch of input events, so a burst of mouse motion
    /// becomes one request).
    pub fn flush(&mut self) {
        if !self.dirty {
            return;
        }
        self.dirty = false;
        if self.next_id > 1 {
            self.view += 1;
        }
        self.view_spp = 0;
        self.refining = false;
        self.held_pass = None;
        // The first view is not a move: it starts sharp, and measures the
        // full-resolution cost the controller starts from.
        self.view_divisor = if self.next_id > 1 { self.controller.divisor() } else { Divisor::ONE };
        let restart = std::mem::take(&mut self.restart);
        if let Some(r) = self.recorder.as_mut().filter(|_| !restart) {
            r.record(&self.camera);
        }
        let input_at = self.pending_input.take();
        self.request_pass(0, input_at);
    }

    fn pass_kind(&self, pass: u32) -> PassKind {
        match pass {
            0 => PassKind::Moving,
            1 if !self.view_divisor.is_one() => PassKind::Sharp,
            _ => PassKind::Refine,
        }
    }

    fn pass_settings(&self, pass: u32) -> (RenderSettings, Divisor) {
        let q = &self.config.quality;
        let mut s = self.config.settings;
        let kind = self.pass_kind(pass);
        let divisor = if kind == PassKind::Moving { self.view_divisor } else { Divisor::ONE };
        if kind == PassKind::Refine {
            s.spp = q.still_spp.max(1);
            s.light_samples = q.still_light_samples.max(1);
        } else {
            s.spp = q.moving_spp.max(1);
            s.light_samples = q.moving_light_samples.max(1);
        }
        (s.width, s.height) = divisor.apply(s.width, s.height);
        s.seed = self.config.settings.seed.wrapping_add(pass as u64);
        (s, divisor)
    }

    fn request_pass(&mut self, pass: u32, input_at: Option<Instant>) {
        let (settings, divisor) = self.pass_settings(pass);
        let frame_id = self.next_id;
        self.next_id += 1;
        self.frame_owners.clear();
        self.in_flight = Some(InFlight {
            frame_id,
            view: self.view,
            pass,
            kind: self.pass_kind(pass),
            weight: settings.spp,
            divisor,
            size: (settings.width, settings.height),
            input_at,
        });
        self.source.request(FrameRequest { frame_id, camera: self.camera, settings });
    }

    /// Drains the source. Returns true when the displayed image changed.
    pub fn pump(&mut self, now: Instant) -> bool {
        let mut changed = false;
        while let Some(event) = self.source.try_next() {
            match event {
                SourceEvent::Tile(t) => {
                    let Some(f) = self.in_flight.filter(|f| f.frame_id == t.frame_id) else {
                        continue; // a superseded frame's tile
                    };
                    // Refinement passes share one accumulation key per view; the
                    // moving and sharp passes have their own, so each next kind's
                    // tiles replace the previous kind's.
                    let key = f.view.wrapping_mul(3).wrapping_add(f.kind.slot());
                    match self.accum.add_tile_of(key, f.weight as f32, t.tile, &t.rgb, f.size) {
                        Ok(()) => {
                            let full = (self.accum.width(), self.accum.height());
                            let tile = map_tile(t.tile, f.size, full);
                            if f.size != self.owners_size {
                                // Tiles of another size: the old borders no longer apply.
                                self.owners.clear();
                                self.owners_size = f.size;
                            }
                            self.owners.insert((tile.x, tile.y), (tile, t.owner));
                            *self.frame_owners.entry(t.owner).or_default() += t.tile.pixel_count() as u64;
                            changed = true;
                        }
                        Err(e) => tracing::warn!("dropping a tile: {e}"),
                    }
                }
                SourceEvent::FrameComplete { frame_id, elapsed } => {
                    let Some(f) = self.in_flight.filter(|f| f.frame_id == frame_id) else {
                        continue;
                    };
                    match f.kind {
                        PassKind::Refine if self.refining => self.view_spp += f.weight,
                        PassKind::Refine => {
                            // The fast passes' sample is replaced, not averaged in.
                            self.refining = true;
                            self.view_spp = f.weight;
                        }
                        PassKind::Moving | PassKind::Sharp => {
                            self.view_spp = f.weight;
                            self.controller.observe(f.size.0, f.size.1, elapsed);
                        }
                    }
                    let report = FrameReport {
                        frame_id,
                        view: f.view,
                        pass: f.pass,
                        kind: f.kind,
                        divisor: f.divisor,
                        size: f.size,
                        spp: self.view_spp,
                        render_time: elapsed,
                        latency: None, // measured when it is on screen
                    };
                    self.completed.push((report, f.input_at));
                    self.last_report = Some(report);
                    self.completions.push_back(now);
                    self.in_flight = None;
                    self.last_owners = std::mem::take(&mut self.frame_owners);
                    // A frame came through: whatever went wrong before is over.
                    self.error = None;
                    changed = true;
                    if f.pass == 0 && self.played == Some(false) {
                        if self.dwell.is_zero() || self.playback.is_empty() {
                            self.next_playback_camera(now);
                        } else {
                            self.playback_due = Some(now + self.dwell);
                        }
                    }
                    let next = f.pass + 1;
                    let wanted = match self.pass_kind(next) {
                        PassKind::Sharp => true,
                        _ => self.view_spp < self.config.quality.max_spp,
                    };
                    if !self.dirty && wanted {
                        if self.hold {
                            self.held_pass = Some(next);
                        } else {
                            self.request_pass(next, None);
                        }
                    }
                }
                SourceEvent::Failed(message) => {
                    tracing::error!("frame source failed: {message}");
                    self.error = Some(message);
                    changed = true;
                }
                SourceEvent::Lost(message) => {
                    tracing::warn!("{message}");
                    self.connection = Some(message);
                    changed = true;
                }
                SourceEvent::Reconnected => {
                    tracing::info!("the frame source is back; rendering the view again");
                    self.connection = None;
                    self.error = None;
                    self.restart_view();
                    changed = true;
                }
            }
        }
        changed
    }

    /// True when completed passes wait to be reported by [`Session::take_completed`].
    pub fn has_unreported(&self) -> bool {
        !self.completed.is_empty()
    }

    /// Passes completed since the last call; call right after presenting
    /// them, at `now`, which ends their motion-to-photon latency.
    pub fn take_completed(&mut self, now: Instant) -> Vec<FrameReport> {
        let reports: Vec<FrameReport> = std::mem::take(&mut self.completed)
            .into_iter()
            .map(|(r, input_at)| FrameReport {
                latency: input_at.map(|t| now.saturating_duration_since(t)),
                ..r
            })
            .collect();
        if let Some(last) = reports.last() {
            self.last_report = Some(*last);
        }
        reports
    }

    /// True while a pass is being rendered.
    pub fn busy(&self) -> bool {
        self.in_flight.is_some() || self.dirty
    }

    /// True while rendering, or within a second of the last completed pass
    /// (while the status line's frame rate is still changing).
    pub fn active(&self, now: Instant) -> bool {
        self.busy()
            || self.completions.back().is_some_and(|&t| now.duration_since(t) < Duration::from_millis(1100))
    }

    /// The image to show.
    pub fn image(&self) -> &Accumulator {
        &self.accum
    }

    /// The latest tile at each tile position and who rendered it.
    pub fn tile_owners(&self) -> impl Iterator<Item = &(Tile, u32)> {
        self.owners.values()
    }

    /// The source's counters.
    pub fn source_status(&self) -> SourceStatus {
        self.source.status()
    }

    /// The status text, one string per line.
    pub fn status_lines(&mut self, now: Instant) -> Vec<String> {
        while self.completions.front().is_some_and(|&t| now.duration_since(t) > Duration::from_secs(1)) {
            self.completions.pop_front();
        }
        let status = self.source.status();
        self.bytes_window.push_back((now, status.bytes_received));
        while self.bytes_window.len() > 2
            && self.bytes_window.get(1).is_some_and(|&(t, _)| now.duration_since(t) >= Duration::from_secs(1))
        {
            self.bytes_window.pop_front();
        }
        let rate = match (self.bytes_window.front(), self.bytes_window.back()) {
            (Some(&(t0, b0)), Some(&(t1, b1))) if t1 > t0 => {
                b1.saturating_sub(b0) as f64 / t1.duration_since(t0).as_secs_f64()
            }
            _ => 0.0,
        };
        let ms = |d: Duration| d.as_secs_f64() * 1e3;
        let mut first = format!("{} fps", self.completions.len());
        if let Some(r) = self.last_report {
            first += &format!("  frame {:.1} ms  {} spp", ms(r.render_time), r.spp);
        }
        if let Some(l) = self.last_report.and_then(|r| r.latency) {
            first += &format!("  input->frame {:.0} ms", ms(l));
        }
        if let Some(r) = self.last_report {
            first += &format!("  {}x{} (1/{}", r.size.0, r.size.1, r.divisor);
            first += if self.controller.is_dynamic() { " auto)" } else { ")" };
        }
        let name = |id: u32| status.workers.iter().find(|w| w.id == id).map(|w| w.name.clone());
        let dead = |id: u32| status.workers.iter().any(|w| w.id == id && !w.alive);
        let tiles: Vec<String> = status
            .tiles_per_slave
            .iter()
            .map(|&(id, n)| {
                let who = name(id).unwrap_or_else(|| format!("#{id}"));
                if dead(id) { format!("{who}:{n}(dead)") } else { format!("{who}:{n}") }
            })
            .collect();
        let plural = |n: usize, one: &str, many: &str| format!("{n} {}", if n == 1 { one } else { many });
        let slaves = if status.workers.is_empty() {
            plural(status.live_slaves, "slave", "slaves")
        } else {
            let threads: u32 = status.workers.iter().filter(|w| w.alive).map(|w| w.threads).sum();
            let gone = status.workers.len() - status.live_slaves.min(status.workers.len());
            let mut s = format!(
                "{} ({})",
                plural(status.live_slaves, "live slave", "live slaves"),
                plural(threads as usize, "thread", "threads")
            );
            if gone > 0 {
                s += &format!(", {gone} dead");
            }
            s
        };
        let mut lines = vec![
            first,
            format!("{slaves}  {:.2} MB/s  {}", rate / 1e6, status.transport),
            format!("tiles {}", tiles.join(" ")),
        ];
        lines.extend(self.notices());
        lines
    }

    /// What the viewer must say whatever else is shown: the source's
    /// connection while it is down ("reconnecting…"), the source's notice
    /// (e.g. how to start a slave when there is none) and the last error.
    pub fn notices(&self) -> Vec<String> {
        let notice = if self.connection.is_some() { None } else { self.source.status().notice };
        let error = self.error.as_ref().map(|e| format!("error: {e}"));
        self.connection.iter().cloned().chain(notice).chain(error).collect()
    }

    /// Each slave's share of the pixels of the last completed pass, largest
    /// first, with its name (`#id` when the source does not name it): the
    /// overlay's legend.
    pub fn legend(&self) -> Vec<(u32, String, f32)> {
        let total: u64 = self.last_owners.values().sum();
        if total == 0 {
            return Vec::new();
        }
        let workers = self.source.status().workers;
        let mut legend: Vec<(u32, String, f32)> = self
            .last_owners
            .iter()
            .map(|(&id, &px)| {
                let name =
                    workers.iter().find(|w| w.id == id).map_or_else(|| format!("#{id}"), |w| w.name.clone());
                (id, name, px as f32 / total as f32)
            })
            .collect();
        legend.sort_by(|a, b| b.2.total_cmp(&a.2).then(a.0.cmp(&b.0)));
        legend
    }

    /// Writes the recorded camera path, if recording.
    pub fn save_recording(&self) -> Option<Result<std::path::PathBuf, crate::ViewerError>> {
        self.recorder.as_ref().map(|r| r.save().map(|p| p.to_path_buf()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::source::{TileUpdate, Worker};
    use std::sync::{Arc, Mutex};

    /// A source that records requests and lets the test deliver tiles.
    #[derive(Default, Clone)]
    struct Fake {
        requests: Arc<Mutex<Vec<FrameRequest>>>,
        events: Arc<Mutex<VecDeque<SourceEvent>>>,
        /// What `status` answers (default: one slave over "fake").
        status: Arc<Mutex<Option<SourceStatus>>>,
    }

    impl FrameSource for Fake {
        fn set_waker(&mut self, _: Waker) {}
        fn request(&mut self, r: FrameRequest) {
            self.requests.lock().unwrap().push(r);
        }
        fn try_next(&mut self) -> Option<SourceEvent> {
            self.events.lock().unwrap().pop_front()
        }
        fn status(&self) -> SourceStatus {
            self.status.lock().unwrap().clone().unwrap_or_else(|| SourceStatus {
                live_slaves: 1,
                transport: "fake".into(),
                ..Default::default()
            })
        }
    }

    impl Fake {
        fn last(&self) -> FrameRequest {
            *self.requests.lock().unwrap().last().unwrap()
        }
        fn count(&self) -> usize {
            self.requests.lock().unwrap().len()
        }
        /// Delivers the whole frame as one solid tile, then completes it.
        fn deliver(&self, r: &FrameRequest, value: u8) {
            self.deliver_in(r, value, Duration::from_millis(5));
        }
        /// Delivers the whole frame as one solid tile, then completes it as
        /// if rendering had taken `elapsed`.
        fn deliver_in(&self, r: &FrameRequest, value: u8, elapsed: Duration) {
            let tile = Tile { x: 0, y: 0, w: r.settings.width, h: r.settings.height };
            self.deliver_tile(r, tile, value);
            self.events
                .lock()
                .unwrap()
                .push_back(SourceEvent::FrameComplete { frame_id: r.frame_id, elapsed });
        }
        /// Delivers one solid tile of `r`.
        fn deliver_tile(&self, r: &FrameRequest, tile: Tile, value: u8) {
            self.events.lock().unwrap().push_back(SourceEvent::Tile(TileUpdate {
                frame_id: r.frame_id,
                tile,
                rgb: vec![value; tile.pixel_count() * 3],
                owner: 3,
            }));
        }
    }

    fn session(max_spp: u32) -> (Session, Fake) {
        let fake = Fake::default();
        let settings = RenderSettings { width: 4, height: 2, spp: 9, light_samples: 8, ..Default::default() };
        let mut quality = Quality::for_settings(&settings);
        quality.max_spp = max_spp;
        let config =
            SessionConfig { settings, quality, controls: Controls::default(), camera: Camera::default() };
        let mut s = Session::new(Box::new(fake.clone()), config);
        s.start();
        (s, fake)
    }

    #[test]
    fn a_still_view_is_refined_with_new_seeds_until_max_spp() {
        let (mut s, fake) = session(8);
        let t = Instant::now();
        let first = fake.last();
        assert_eq!((first.settings.spp, first.settings.light_samples), (1, 1), "fast first pass");
        fake.deliver(&first, 0);
        assert!(s.pump(t));
        let mut seeds = vec![first.settings.seed];
        // Two refinement passes of 4 samples each: black, then white.
        for value in [0, 255] {
            let r = fake.last();
            assert!(r.frame_id > first.frame_id);
            assert_eq!(r.camera, first.camera);
            assert_eq!(r.settings.spp, 4, "refinement passes anti-alias");
            assert_eq!(r.settings.light_samples, 8, "refinement uses the scene's shadow rays");
            assert!(!seeds.contains(&r.settings.seed), "each pass draws new samples");
            seeds.push(r.settings.seed);
            fake.deliver(&r, value);
            s.pump(t);
        }
        assert_eq!(fake.count(), 3, "no pass after max_spp");
        assert!(!s.busy());
        let reports = s.take_completed(t);
        assert_eq!(reports.iter().map(|r| (r.pass, r.spp)).collect::<Vec<_>>(), [(0, 1), (1, 4), (2, 8)]);
        assert!(reports.iter().all(|r| r.view == 0));
        // Black and white refinement passes averaged in linear light: sRGB 188.
        let p = s.image().display()[0] & 0xff;
        assert!((187..=188).contains(&p), "{p}");
    }

    #[test]
    fn a_move_supersedes_the_pass_in_flight_and_restarts_fast() {
        let (mut s, fake) = session(64);
        let t0 = Instant::now();
        let first = fake.last();
        fake.deliver(&first, 100);
        s.pump(t0);
        let refine = fake.last();
        assert_eq!(refine.settings.light_samples, 8);
        // Two moves before the next flush become one request.
        s.move_camera(Move::Forward, t0);
        s.move_camera(Move::YawLeft, t0 + Duration::from_millis(3));
        assert_eq!(fake.count(), 2, "requests wait for the flush");
        s.flush();
        assert_eq!(fake.count(), 3);
        let moved = fake.last();
        assert_eq!(moved.settings.spp, 1);
        assert_eq!(moved.settings.light_samples, 1);
        assert_ne!(moved.camera, first.camera);
        let mut expect = Camera::default();
        Controls::default().apply(Move::Forward, &mut expect);
        Controls::default().apply(Move::YawLeft, &mut expect);
        assert_eq!(moved.camera, expect);
        // The superseded refinement's tiles arrive late: ignored.
        fake.deliver(&refine, 255);
        s.pump(t0);
        assert_eq!(s.image().display()[0] & 0xff, 100, "stale tiles are not shown");
        // The new view's tiles replace the old image (no averaging across views).
        fake.deliver(&moved, 30);
        s.pump(t0 + Duration::from_millis(20));
        assert_eq!(s.image().display()[0] & 0xff, 30);
        let reports = s.take_completed(t0 + Duration::from_millis(25));
        let last = reports.last().unwrap();
        assert_eq!((last.view, last.pass, last.spp), (1, 0, 1));
        assert_eq!(
            last.latency,
            Some(Duration::from_millis(25)),
            "latency runs from the first input to the frame on screen"
        );
        assert_eq!(s.view(), 1);
    }

    #[test]
    fn playback_moves_on_after_each_fast_pass() {
        let fake = Fake::default();
        let settings = RenderSettings { width: 2, height: 2, ..Default::default() };
        let config = SessionConfig {
            settings,
            quality: Quality::for_settings(&settings),
            controls: Controls::default(),
            camera: Camera::default(),
        };
        let mut s = Session::new(Box::new(fake.clone()), config);
        let cams: Vec<Camera> = (0..3)
            .map(|i| {
                let mut c = Camera::default();
                c.advance(i as f32);
                c
            })
            .collect();
        s.play(cams.clone());
        s.start();
        let t = Instant::now();
        for (i, cam) in cams.iter().enumerate() {
            let r = fake.last();
            assert_eq!(r.camera, *cam, "camera {i}");
            assert_eq!(r.settings.spp, 1);
            assert!(!s.playback_finished());
            fake.deliver(&r, i as u8);
            s.pump(t);
            s.flush();
        }
        assert!(s.playback_finished());
        assert_eq!(fake.count(), 4, "three moving frames, then refinement of the last camera");
        let views: Vec<(u32, u32)> = s.take_completed(t).iter().map(|r| (r.view, r.pass)).collect();
        assert_eq!(views, [(0, 0), (1, 0), (2, 0)]);
    }

    #[test]
    fn a_dwelling_playback_refines_each_camera_then_moves_on_when_due() {
        let fake = Fake::default();
        let settings = RenderSettings { width: 2, height: 2, light_samples: 4, ..Default::default() };
        let config = SessionConfig {
            settings,
            quality: Quality::for_settings(&settings),
            controls: Controls::default(),
            camera: Camera::default(),
        };
        let mut s = Session::new(Box::new(fake.clone()), config);
        let cams: Vec<Camera> = (0..2)
            .map(|i| {
                let mut c = Camera::default();
                c.advance(i as f32 + 1.0);
                c
            })
            .collect();
        s.play(cams.clone());
        s.set_playback_dwell(Duration::from_millis(300));
        s.start();
        let t0 = Instant::now();
        fake.deliver(&fake.last(), 1);
        s.pump(t0);
        let due = s.next_due().expect("the next camera waits for the dwell");
        assert_eq!(due, t0 + Duration::from_millis(300));
        // Meanwhile the still view is refined.
        let refine = fake.last();
        assert_eq!((refine.camera, refine.settings.spp), (cams[0], 4));
        assert!(!s.tick(t0 + Duration::from_millis(299)), "not due yet");
        s.flush();
        assert_eq!(fake.count(), 2);
        // When due, the next camera supersedes the refinement in flight, and its
        // latency runs from the moment it was due.
        assert!(s.tick(due + Duration::from_millis(7)));
        s.flush();
        let moved = fake.last();
        assert_eq!((moved.camera, moved.settings.spp), (cams[1], 1));
        assert_eq!(s.next_due(), None);
        fake.deliver(&moved, 2);
        s.pump(due + Duration::from_millis(40));
        assert!(s.playback_finished(), "the last camera needs no dwell");
        let reports = s.take_completed(due + Duration::from_millis(50));
        assert_eq!(reports.last().and_then(|r| r.latency), Some(Duration::from_millis(50)));
    }

    #[test]
    fn moving_frames_can_render_at_a_fixed_lower_resolution() {
        let fake = Fake::default();
        let settings = RenderSettings { width: 5, height: 3, ..Default::default() };
        let quality = Quality {
            moving: MovingResolution::Fixed(Divisor::whole(2)),
            ..Quality::for_settings(&settings)
        };
        let config =
            SessionConfig { settings, quality, controls: Controls::default(), camera: Camera::default() };
        let mut s = Session::new(Box::new(fake.clone()), config);
        s.start();
        let first = fake.last();
        assert_eq!((first.settings.width, first.settings.height), (5, 3), "nothing moved yet: full size");
        fake.deliver(&first, 10);
        s.pump(Instant::now());
        s.move_camera(Move::Forward, Instant::now());
        s.flush();
        let fast = fake.last();
        assert_eq!((fast.settings.width, fast.settings.height), (3, 2));
        fake.deliver(&fast, 90);
        s.pump(Instant::now());
        assert!(s.image().display().iter().all(|&p| p == 0x5a5a5a), "the small frame fills the window");
        assert_eq!(s.tile_owners().next().map(|o| o.0), Some(Tile { x: 0, y: 0, w: 5, h: 3 }));
        let sharp = fake.last();
        assert_eq!((sharp.settings.width, sharp.settings.height, sharp.settings.spp), (5, 3, 1));
        fake.deliver(&sharp, 91);
        s.pump(Instant::now());
        let refine = fake.last();
        assert_eq!((refine.settings.width, refine.settings.height, refine.settings.spp), (5, 3, 4));
        let kinds: Vec<(PassKind, Divisor)> =
            s.take_completed(Instant::now()).iter().map(|r| (r.kind, r.divisor)).collect();
        assert_eq!(
            kinds,
            [
                (PassKind::Moving, Divisor::ONE),
                (PassKind::Moving, Divisor::whole(2)),
                (PassKind::Sharp, Divisor::ONE)
            ]
        );
    }

    /// A 640 × 480 session whose fake renderer takes `ms_per_mpx` ms per
    /// million pixels of a fast pass; returns it after its first (full-size) pass.
    fn timed_session(ms_per_mpx: f64) -> (Session, Fake) {
        let fake = Fake::default();
        let settings = RenderSettings { width: 640, height: 480, light_samples: 8, ..Default::default() };
        let config = SessionConfig {
            settings,
            quality: Quality::for_settings(&settings),
            controls: Controls::default(),
            camera: Camera::default(),
        };
        let mut s = Session::new(Box::new(fake.clone()), config);
        s.start();
        let first = fake.last();
        assert_eq!((first.settings.width, first.settings.height), (640, 480));
        fake.deliver_in(&first, 1, fast_time(&first, ms_per_mpx));
        s.pump(Instant::now());
        (s, fake)
    }

    fn fast_time(r: &FrameRequest, ms_per_mpx: f64) -> Duration {
        let mpx = r.settings.width as f64 * r.settings.height as f64 / 1e6;
        Duration::from_secs_f64(ms_per_mpx * mpx / 1e3)
    }

    /// Moves `n` times, each moving pass rendered at `ms_per_mpx`; returns the
    /// moving passes' sizes.
    fn fly(s: &mut Session, fake: &Fake, n: usize, ms_per_mpx: f64) -> Vec<(u32, u32)> {
        (0..n)
            .map(|i| {
                s.move_camera(Move::Forward, Instant::now());
                s.flush();
                let r = fake.last();
                assert_eq!(r.settings.spp, 1, "move {i}");
                fake.deliver_in(&r, 2, fast_time(&r, ms_per_mpx));
                s.pump(Instant::now());
                (r.settings.width, r.settings.height)
            })
            .collect()
    }

    #[test]
    fn slow_moving_frames_render_smaller_and_fast_ones_full_size() {
        // 690 ms per Mpx: 212 ms at 640 × 480, far from 30 fps.
        let (mut s, fake) = timed_session(690.0);
        let sizes = fly(&mut s, &fake, 12, 690.0);
        let (w, h) = sizes[0];
        assert!(w < 320 && h < 240, "the first move is already small: {sizes:?}");
        assert!(
            sizes.iter().all(|&(w, h)| (w as f64 / h as f64 - 4.0 / 3.0).abs() < 0.01),
            "aspect: {sizes:?}"
        );
        let budget = 1e3 / 30.0;
        for &(w, h) in &sizes {
            let t = 690.0 * (w * h) as f64 / 1e6;
            assert!(t < budget, "{w}x{h} takes {t:.1} ms");
        }
        assert!(sizes[4..].iter().all(|&sz| sz == sizes[4]), "settled: {sizes:?}");
        let divisor = s.moving_divisor();
        assert!(divisor > Divisor::whole(2), "{divisor}");
        let lines = s.status_lines(Instant::now()).join("\n");
        assert!(lines.contains(&format!("(1/{divisor} auto)")), "{lines}");
        // Now the renderers are 20 × faster: back to full size while moving.
        let sizes = fly(&mut s, &fake, 40, 30.0);
        assert_eq!(sizes.last(), Some(&(640, 480)), "{sizes:?}");
    }

    #[test]
    fn when_motion_stops_a_sharp_fast_pass_comes_before_refinement_without_a_black_frame() {
        let (mut s, fake) = timed_session(690.0);
        s.move_camera(Move::Forward, Instant::now());
        s.flush();
        let moving = fake.last();
        assert!(moving.settings.width < 640);
        fake.deliver_in(&moving, 50, fast_time(&moving, 690.0));
        s.pump(Instant::now());
        assert!(s.image().display().iter().all(|&p| p == 0x323232), "the moving pass fills the window");
        // No further input: the same fast settings at full resolution.
        let sharp = fake.last();
        assert_eq!(sharp.camera, moving.camera);
        assert_eq!((sharp.settings.width, sharp.settings.height), (640, 480));
        assert_eq!((sharp.settings.spp, sharp.settings.light_samples), (1, 1));
        // Its first tile paints over the enlarged image; the rest still shows it.
        fake.deliver_tile(&sharp, Tile { x: 0, y: 0, w: 32, h: 32 }, 60);
        s.pump(Instant::now());
        let d = s.image().display();
        assert_eq!(d[0], 0x3c3c3c);
        assert_eq!(d[640 * 479 + 639], 0x323232, "not yet rendered: the moving image, not black");
        assert!(d.iter().all(|&p| p != 0));
        fake.deliver_in(&sharp, 60, fast_time(&sharp, 690.0));
        s.pump(Instant::now());
        // Then refinement, which replaces the fast samples.
        let refine = fake.last();
        assert_eq!((refine.settings.width, refine.settings.height), (640, 480));
        assert_eq!((refine.settings.spp, refine.settings.light_samples), (4, 8));
        fake.deliver_tile(&refine, Tile { x: 0, y: 0, w: 640, h: 1 }, 200);
        s.pump(Instant::now());
        assert_eq!(s.image().display()[5], 0xc8c8c8, "refinement replaces the fast pass");
        assert_eq!(s.image().display()[640 * 2], 0x3c3c3c, "the sharp pass stays until then");
        let reports: Vec<(u32, PassKind, u32)> =
            s.take_completed(Instant::now()).iter().map(|r| (r.view, r.kind, r.spp)).collect();
        assert_eq!(reports, [(0, PassKind::Moving, 1), (1, PassKind::Moving, 1), (1, PassKind::Sharp, 1)]);
    }

    #[test]
    fn a_held_key_defers_the_still_passes_until_release() {
        let (mut s, fake) = timed_session(690.0);
        s.hold(true);
        s.move_camera(Move::Forward, Instant::now());
        s.flush();
        assert_eq!(fake.count(), 3, "start, its refinement, the move");
        let moving = fake.last();
        fake.deliver_in(&moving, 50, fast_time(&moving, 690.0));
        s.pump(Instant::now());
        assert_eq!(fake.count(), 3, "no full-resolution pass while the key is down");
        assert!(!s.moving_frame_pending(), "the next step of the motion may go");
        s.hold(false);
        assert_eq!(fake.count(), 4);
        let sharp = fake.last();
        assert_eq!((sharp.settings.width, sharp.settings.spp), (640, 1));
        // A release with nothing pending requests nothing.
        s.hold(true);
        s.hold(false);
        assert_eq!(fake.count(), 4);
    }

    #[test]
    fn unusable_cameras_are_ignored() {
        let (mut s, fake) = session(1);
        let mut broken = Camera::default();
        broken.eye.x = f32::NAN;
        s.set_camera(broken, Instant::now());
        s.flush();
        assert_eq!(fake.count(), 1);
        assert_eq!(*s.camera(), Camera::default());
    }

    #[test]
    fn status_lines_show_the_source_counters() {
        let (mut s, fake) = session(1);
        fake.deliver(&fake.last(), 1);
        let now = Instant::now();
        s.pump(now);
        let lines = s.status_lines(now).join("\n");
        assert!(lines.contains("1 fps"), "{lines}");
        assert!(lines.contains("1 slave ") && lines.contains("fake"), "{lines}");
    }

    #[test]
    fn status_lines_show_a_clusters_slaves_threads_and_dead_ones() {
        let fake = Fake::default();
        let worker = |id: u32, alive: bool| Worker { id, name: format!("w#{id}"), threads: 2, alive };
        *fake.status.lock().unwrap() = Some(SourceStatus {
            live_slaves: 2,
            tiles_per_slave: vec![(3, 40), (5, 0), (7, 12)],
            workers: vec![worker(3, true), worker(5, true), worker(7, false)],
            transport: "quic".into(),
            bytes_received: 0,
            notice: None,
        });
        let settings = RenderSettings { width: 4, height: 2, ..Default::default() };
        let config = SessionConfig {
            settings,
            quality: Quality::for_settings(&settings),
            controls: Controls::default(),
            camera: Camera::default(),
        };
        let mut s = Session::new(Box::new(fake), config);
        let lines = s.status_lines(Instant::now());
        assert_eq!(lines[1], "2 live slaves (4 threads), 1 dead  0.00 MB/s  quic");
        assert_eq!(lines[2], "tiles w#3:40 w#5:0 w#7:12(dead)");
        assert_eq!(lines.len(), 3, "nothing to tell: {lines:?}");
    }

    fn config(width: u32, height: u32) -> SessionConfig {
        let settings = RenderSettings { width, height, ..Default::default() };
        SessionConfig {
            settings,
            quality: Quality::for_settings(&settings),
            controls: Controls::default(),
            camera: Camera::default().fit_aspect(width as f32 / height as f32),
        }
    }

    #[test]
    fn status_lines_count_in_the_singular_and_tell_the_sources_notice() {
        let fake = Fake::default();
        let one = Worker { id: 4, name: "solo".into(), threads: 1, alive: true };
        let hint = "no slaves: start one with `isin slave --connect T`";
        *fake.status.lock().unwrap() = Some(SourceStatus {
            live_slaves: 1,
            tiles_per_slave: vec![(4, 2)],
            workers: vec![one],
            transport: "tcp".into(),
            ..Default::default()
        });
        let mut s = Session::new(Box::new(fake.clone()), config(4, 2));
        let lines = s.status_lines(Instant::now());
        assert!(lines[1].starts_with("1 live slave (1 thread)  "), "{lines:?}");
        assert_eq!(lines[2], "tiles solo:2");
        assert!(s.notices().is_empty());
        *fake.status.lock().unwrap() =
            Some(SourceStatus { notice: Some(hint.into()), transport: "tcp".into(), ..Default::default() });
        let lines = s.status_lines(Instant::now());
        assert_eq!(lines.last().map(String::as_str), Some(hint), "{lines:?}");
        assert_eq!(s.notices(), [hint]);
    }

    #[test]
    fn a_resize_renders_at_the_new_size_with_the_plane_resized_about_its_centre() {
        let fake = Fake::default();
        let mut s = Session::new(Box::new(fake.clone()), config(8, 6));
        s.start();
        fake.deliver(&fake.last(), 40);
        s.pump(Instant::now());
        let before = *s.camera();
        let requests = fake.count();
        s.resize(16, 6);
        assert_eq!(fake.count(), requests, "requested at the next flush");
        assert_eq!(s.image().display().len(), 16 * 6, "the image is the new size at once…");
        assert!(s.image().display().iter().all(|&p| p == 0x282828), "…showing the old one stretched");
        s.flush();
        let r = fake.last();
        assert_eq!(r.frame_id, requests as u64 + 1);
        // The first pass may be smaller (the moving divisor); the still ones are the new size.
        assert!(r.settings.width as f32 / r.settings.height as f32 > 2.0, "{:?}", r.settings);
        let cam = r.camera;
        assert_eq!(cam.eye, before.eye);
        assert!((cam.center() - before.center()).length() < 1e-4, "about its centre");
        assert!((cam.aspect() - 16.0 / 6.0).abs() < 1e-3, "the new shape, not stretched: {}", cam.aspect());
        assert!((cam.plane_y().length() - before.plane_y().length()).abs() < 1e-4, "wider, as tall");
        fake.deliver(&r, 50);
        s.pump(Instant::now());
        let sharp = fake.last();
        assert_eq!((sharp.settings.width, sharp.settings.height), (16, 6));
        // Back to the old size: the very same plane (no drift), narrower than the wide one.
        s.resize(8, 6);
        s.flush();
        let back = fake.last().camera;
        for (a, b) in back.corners.iter().zip(before.corners.iter()) {
            assert!((*a - *b).length() < 1e-4, "{back:?} vs {before:?}");
        }
        let count = fake.count();
        s.resize(8, 6);
        s.flush();
        assert_eq!(fake.count(), count, "the same size requests nothing");
    }

    #[test]
    fn the_render_size_is_the_windows_times_the_scale_within_the_limits() {
        assert_eq!(render_size(400, 200, 1.0), (400, 200));
        assert_eq!(render_size(400, 200, 0.5), (200, 100));
        assert_eq!(render_size(401, 201, 0.5), (201, 101), "rounded");
        assert_eq!(render_size(0, 0, 1.0), (1, 1));
        assert_eq!(render_size(400, 200, f32::NAN), (400, 200));
        let (w, h) = render_size(30_000, 10_000, 4.0);
        assert!(w <= 16_384 && (w as u64 * h as u64) <= isin_tracer::limits::IMAGE_PIXELS.max, "{w}x{h}");
        assert!((w as f32 / h as f32 - 3.0).abs() < 0.01, "the shape kept: {w}x{h}");
    }

    #[test]
    fn a_lost_source_says_so_and_on_reconnection_clears_errors_and_renders_the_view_again() {
        let fake = Fake::default();
        let mut s = Session::new(Box::new(fake.clone()), config(4, 2));
        s.start();
        let first = fake.last();
        let push = |e: SourceEvent| fake.events.lock().unwrap().push_back(e);
        push(SourceEvent::Failed("the master refused a frame".into()));
        push(SourceEvent::Lost("lost the master; reconnecting…".into()));
        assert!(s.pump(Instant::now()));
        assert_eq!(s.notices(), ["lost the master; reconnecting…", "error: the master refused a frame"]);
        push(SourceEvent::Reconnected);
        assert!(s.pump(Instant::now()));
        assert!(s.notices().is_empty(), "{:?}", s.notices());
        s.flush();
        let again = fake.last();
        assert!(again.frame_id > first.frame_id, "asked again");
        assert_eq!(again.camera, first.camera, "for the same camera");
        // The lost frame's late tiles are not shown; the new one completes.
        fake.deliver(&first, 7);
        s.pump(Instant::now());
        assert_ne!(s.image().display()[0] & 0xff, 7);
        fake.deliver(&again, 9);
        s.pump(Instant::now());
        assert_eq!(s.image().display()[0] & 0xff, 9);
    }

    #[test]
    fn the_legend_gives_each_slaves_share_of_the_last_pass_with_its_name() {
        let fake = Fake::default();
        *fake.status.lock().unwrap() = Some(SourceStatus {
            workers: vec![Worker { id: 3, name: "big".into(), threads: 4, alive: true }],
            ..Default::default()
        });
        let mut s = Session::new(Box::new(fake.clone()), config(4, 2));
        s.start();
        assert!(s.legend().is_empty(), "no pass yet");
        let r = fake.last();
        // Three quarters of the image from slave 3, a quarter from 9 (not listed).
        for (x, owner) in [(0, 3), (1, 3), (2, 3), (3, 9)] {
            fake.events.lock().unwrap().push_back(SourceEvent::Tile(TileUpdate {
                frame_id: r.frame_id,
                tile: Tile { x, y: 0, w: 1, h: 2 },
                rgb: vec![1; 6],
                owner,
            }));
        }
        fake.events.lock().unwrap().push_back(SourceEvent::FrameComplete {
            frame_id: r.frame_id,
            elapsed: Duration::from_millis(1),
        });
        s.pump(Instant::now());
        assert_eq!(s.legend(), [(3, "big".to_string(), 0.75), (9, "#9".to_string(), 0.25)]);
    }
}

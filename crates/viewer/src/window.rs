//! The window: winit 0.30 (`ApplicationHandler`) + softbuffer 0.4.
//!
//! The *render resolution* follows the window: its size in physical pixels
//! (so HiDPI screens get every pixel) times [`ViewerOptions::render_scale`].
//! A resize is applied once the window has kept its new size for
//! [`RESIZE_DEBOUNCE`] ([`Session::resize`]: the camera's image plane is
//! resized about its centre, never stretched, and the view rendered again);
//! until then the image is scaled into the window with nearest-neighbour
//! sampling, keeping its aspect ratio (letterboxed).
//!
//! The status text wraps at the window's width, so none of it is cut; the
//! notices (reconnecting, no slaves, errors) are shown even with the status
//! text hidden. With the tile-ownership overlay on, a legend under the status
//! text gives each slave's colour, name and share of the last pass.
//!
//! The loop sleeps until something happens: input, or the frame source's
//! [`Waker`] (a winit user event) when tiles arrive. Input events are applied
//! to the camera as they come and turned into one request per batch (in
//! `about_to_wait`), so a burst of mouse motion costs one frame, not a queue.

use crate::error::ViewerError;
use crate::input::{Command, HeldMoves, command_for_key};
use crate::raster::{Canvas, Placement, owner_colour, wrap};
use crate::session::{FrameReport, Session};
use crate::source::Waker;
use std::num::NonZeroU32;
use std::path::PathBuf;
use std::rc::Rc;
use std::sync::Mutex;
use std::time::{Duration, Instant};
use winit::application::ApplicationHandler;
use winit::dpi::{PhysicalPosition, PhysicalSize};
use winit::event::{ElementState, MouseButton, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{KeyCode, ModifiersState, PhysicalKey};
use winit::window::{Window, WindowId};

/// Something the window did that its owner may want to know about.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum ViewerEvent {
    /// A pass completed and is now on screen.
    FramePresented(FrameReport),
    /// A screenshot was written.
    ScreenshotSaved(PathBuf),
    /// The notices on screen changed ([`Session::notices`]: reconnecting,
    /// no slaves, errors); empty once there are none.
    Notices(Vec<String>),
}

/// The file format of screenshots: the displayed image is sRGB RGB8 (as the
/// cluster's tiles are), so 8-bit formats only.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ScreenshotFormat {
    /// PNG, lossless.
    #[default]
    Png,
    /// JPEG.
    Jpeg,
}

impl ScreenshotFormat {
    /// The file extension.
    pub fn extension(self) -> &'static str {
        match self {
            ScreenshotFormat::Png => "png",
            ScreenshotFormat::Jpeg => "jpg",
        }
    }
}

/// Writes a `width × height` RGB8 screenshot into `dir` as the first free
/// `isin-screenshot-NNNN.EXT`: whole to `NAME.part`, then renamed into place,
/// so no partial or empty file is ever seen under the name.
pub fn save_screenshot(
    dir: &std::path::Path,
    format: ScreenshotFormat,
    (width, height): (u32, u32),
    rgb: &[u8],
) -> Result<PathBuf, ViewerError> {
    let ext = format.extension();
    let path = (0..10_000)
        .map(|i| dir.join(format!("isin-screenshot-{i:04}.{ext}")))
        .find(|p| !p.exists())
        .unwrap_or_else(|| dir.join(format!("isin-screenshot.{ext}")));
    let part = path.with_extension(format!("{ext}.part"));
    let image_format = match format {
        ScreenshotFormat::Png => image::ImageFormat::Png,
        ScreenshotFormat::Jpeg => image::ImageFormat::Jpeg,
    };
    let fail = |e: String| {
        let _ = std::fs::remove_file(&part);
        ViewerError::Image { path: path.clone(), message: e }
    };
    image::save_buffer_with_format(&part, rgb, width, height, image::ColorType::Rgb8, image_format)
        .map_err(|e| fail(e.to_string()))?;
    std::fs::rename(&part, &path).map_err(|e| fail(e.to_string()))?;
    Ok(path)
}

/// Window settings.
pub struct ViewerOptions {
    /// Window title.
    pub title: String,
    /// Initial inner size of the window (default: the render resolution).
    pub window_size: Option<(u32, u32)>,
    /// Render resolution per window pixel (1: one rendered pixel per
    /// physical pixel of the window).
    pub render_scale: f32,
    /// Where screenshots go.
    pub screenshot_dir: PathBuf,
    /// Their file format.
    pub screenshot_format: ScreenshotFormat,
    /// Show the status text at start.
    pub show_status: bool,
    /// Close the window once a playback ([`Session::play`]) has finished.
    pub exit_after_playback: bool,
    /// Called for every [`ViewerEvent`].
    pub on_event: Box<dyn FnMut(&ViewerEvent)>,
}

impl Default for ViewerOptions {
    fn default() -> Self {
        Self {
            title: "isin".into(),
            window_size: None,
            render_scale: 1.0,
            screenshot_dir: PathBuf::from("."),
            screenshot_format: ScreenshotFormat::Png,
            show_status: true,
            exit_after_playback: false,
            on_event: Box::new(|_| {}),
        }
    }
}

/// Fails early, with a message pointing at the headless commands, when there
/// is no display to open a window on.
pub fn check_display() -> Result<(), ViewerError> {
    #[cfg(all(unix, not(target_os = "macos")))]
    {
        let set = |name: &str| std::env::var_os(name).is_some_and(|v| !v.is_empty());
        if !set("DISPLAY") {
            let why = if set("WAYLAND_DISPLAY") {
                "DISPLAY is not set; the viewer talks X11, which Wayland desktops provide through XWayland"
            } else {
                "neither DISPLAY nor WAYLAND_DISPLAY is set"
            };
            return Err(ViewerError::NoDisplay(why.into()));
        }
    }
    Ok(())
}

/// Opens the window and runs until it is closed (Escape or the close button).
///
/// Gives the session a waker, starts it, and drives it from the event loop.
/// Returns an error without opening anything when there is no display.
pub fn run(session: &mut Session, options: ViewerOptions) -> Result<(), ViewerError> {
    check_display()?;
    // winit may panic rather than fail on a broken display connection.
    let built = std::panic::catch_unwind(|| EventLoop::<Wake>::with_user_event().build());
    let event_loop = match built {
        Ok(Ok(el)) => el,
        Ok(Err(e)) => return Err(ViewerError::NoDisplay(e.to_string())),
        Err(_) => return Err(ViewerError::NoDisplay("the window system could not be initialised".into())),
    };
    let proxy = Mutex::new(event_loop.create_proxy());
    let waker = Waker::new(move || {
        if let Ok(p) = proxy.lock() {
            let _ = p.send_event(Wake);
        }
    });
    session.set_waker(waker.clone());
    session.start();
    let mut app = App {
        show_status: options.show_status,
        options,
        session,
        waker,
        gfx: None,
        error: None,
        modifiers: ModifiersState::empty(),
        drag: None,
        cursor: None,
        overlay: false,
        held: HeldMoves::default(),
        last_present: None,
        redraw_due: None,
        resize_due: None,
        notices_said: Vec::new(),
    };
    event_loop.run_app(&mut app).map_err(|e| ViewerError::Window(e.to_string()))?;
    match app.error {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

/// The user event posted by the frame source's waker.
#[derive(Debug, Clone, Copy)]
struct Wake;

struct Gfx {
    window: Rc<Window>,
    surface: softbuffer::Surface<Rc<Window>, Rc<Window>>,
    /// Keeps the display connection alive for the surface.
    _context: softbuffer::Context<Rc<Window>>,
}

struct App<'a> {
    options: ViewerOptions,
    session: &'a mut Session,
    waker: Waker,
    gfx: Option<Gfx>,
    error: Option<ViewerError>,
    modifiers: ModifiersState,
    /// Cursor position at the last drag step while the left button is held.
    drag: Option<PhysicalPosition<f64>>,
    cursor: Option<PhysicalPosition<f64>>,
    overlay: bool,
    show_status: bool,
    held: HeldMoves,
    /// When the window was last drawn.
    last_present: Option<Instant>,
    /// A redraw put off to keep to [`MIN_PRESENT_INTERVAL`].
    redraw_due: Option<Instant>,
    /// The window's new size and when to render at it ([`RESIZE_DEBOUNCE`]).
    resize_due: Option<(Instant, PhysicalSize<u32>)>,
    /// The notices last reported ([`ViewerEvent::Notices`]).
    notices_said: Vec<String>,
}

/// How long the window must keep a new size before the view is rendered at
/// it: dragging a window's edge resizes it many times a second, and each
/// size would otherwise cost a frame.
pub const RESIZE_DEBOUNCE: Duration = Duration::from_millis(120);

/// Shortest time between two redraws for tiles that arrive while a pass is
/// rendered (a completed pass is shown at once). Each redraw scales and
/// presents the whole image; redrawing for every tile cost the window thread
/// as much CPU as a render thread during refinement passes.
pub const MIN_PRESENT_INTERVAL: Duration = Duration::from_millis(33);

impl App<'_> {
    fn fail(&mut self, event_loop: &ActiveEventLoop, error: ViewerError) {
        tracing::error!("{error}");
        self.error.get_or_insert(error);
        event_loop.exit();
    }

    fn create_window(&mut self, event_loop: &ActiveEventLoop) -> Result<Gfx, ViewerError> {
        let img = self.session.image();
        let (w, h) = self.options.window_size.unwrap_or((img.width(), img.height()));
        let attributes = Window::default_attributes()
            .with_title(self.options.title.clone())
            .with_inner_size(PhysicalSize::new(w.max(1), h.max(1)))
            .with_resizable(true);
        let window =
            Rc::new(event_loop.create_window(attributes).map_err(|e| ViewerError::Window(e.to_string()))?);
        let context =
            softbuffer::Context::new(window.clone()).map_err(|e| ViewerError::Window(e.to_string()))?;
        let surface = softbuffer::Surface::new(&context, window.clone())
            .map_err(|e| ViewerError::Window(e.to_string()))?;
        Ok(Gfx { window, surface, _context: context })
    }

    /// Renders at the size of a window of `size` physical pixels from now on.
    fn apply_size(&mut self, size: PhysicalSize<u32>) {
        if size.width == 0 || size.height == 0 {
            return; // minimised: keep the view as it is
        }
        let (w, h) = crate::session::render_size(size.width, size.height, self.options.render_scale);
        if (w, h) != self.session.size() {
            tracing::debug!("window {}x{}: rendering at {w}x{h}", size.width, size.height);
            self.session.resize(w, h);
        }
    }

    fn redraw(&mut self) -> Result<(), ViewerError> {
        let now = Instant::now();
        self.session.pump(now);
        let status = if self.show_status { self.session.status_lines(now) } else { self.session.notices() };
        let notices = self.session.notices();
        let legend = if self.overlay { self.session.legend() } else { Vec::new() };
        let Some(gfx) = &mut self.gfx else { return Ok(()) };
        let size = gfx.window.inner_size();
        let (Some(w), Some(h)) = (NonZeroU32::new(size.width), NonZeroU32::new(size.height)) else {
            return Ok(()); // minimised
        };
        let err = |e: softbuffer::SoftBufferError| ViewerError::Window(e.to_string());
        gfx.surface.resize(w, h).map_err(err)?;
        let mut buffer = gfx.surface.buffer_mut().map_err(err)?;
        let mut canvas = Canvas { pixels: &mut buffer, width: w.get(), height: h.get() };
        let img = self.session.image();
        let at = Placement::fit(img.width(), img.height(), w.get(), h.get());
        canvas.draw_image(img.display(), img.width(), img.height(), at);
        if self.overlay {
            for &(tile, owner) in self.session.tile_owners() {
                let (x0, y0, x1, y1) = at.map_tile(tile, img.width(), img.height());
                canvas.outline(x0, y0, x1, y1, owner_colour(owner));
            }
        }
        // Text in whole multiples of the screen's scale factor, doubled on large windows.
        let base = (gfx.window.scale_factor().round() as u32).max(1);
        let scale = if w.get() >= 960 * base { 2 * base } else { base };
        let columns = (w.get().saturating_sub(4 * scale) / (8 * scale)).max(1) as usize;
        let mut y = 2 * scale;
        for (i, line) in status.iter().enumerate() {
            let colour = if i == 0 && self.show_status { 0x00ff_ff80 } else { 0x00ff_ffff };
            for part in wrap(line, columns) {
                y += canvas.text(2 * scale, y, &part, colour, scale);
            }
        }
        // The overlay's legend: a swatch of each slave's colour, its name and share.
        for (owner, name, share) in &legend {
            let label = format!("{name} {:.0}%", share * 100.0);
            let (x, cols) = (12 * scale, columns.saturating_sub(2).max(1));
            let top = y;
            for part in wrap(&label, cols) {
                y += canvas.text(x, y, &part, 0x00ff_ffff, scale);
            }
            canvas.fill_rect(2 * scale, top, 10 * scale, top + 10 * scale, owner_colour(*owner));
        }
        gfx.window.pre_present_notify();
        buffer.present().map_err(err)?;
        self.last_present = Some(Instant::now());
        self.redraw_due = None;
        for report in self.session.take_completed(Instant::now()) {
            (self.options.on_event)(&ViewerEvent::FramePresented(report));
        }
        if notices != self.notices_said {
            (self.options.on_event)(&ViewerEvent::Notices(notices.clone()));
            self.notices_said = notices;
        }
        Ok(())
    }

    fn screenshot(&mut self) -> Result<PathBuf, ViewerError> {
        let img = self.session.image();
        let path = save_screenshot(
            &self.options.screenshot_dir,
            self.options.screenshot_format,
            (img.width(), img.height()),
            &img.to_rgb8(),
        )?;
        tracing::info!("screenshot saved to {}", path.display());
        Ok(path)
    }

    fn command(&mut self, event_loop: &ActiveEventLoop, key: KeyCode, command: Command) {
        let now = Instant::now();
        match command {
            Command::Move(mv) => {
                // One step per press; holding the key moves on in about_to_wait.
                if self.held.press(key, mv, now, self.session.controls()) {
                    self.session.move_camera(mv, now);
                }
            }
            Command::ResetCamera => self.session.reset_camera(now),
            Command::Screenshot => match self.screenshot() {
                Ok(path) => (self.options.on_event)(&ViewerEvent::ScreenshotSaved(path)),
                Err(e) => tracing::error!("{e}"),
            },
            Command::ToggleOverlay => self.overlay = !self.overlay,
            Command::ToggleStatus => self.show_status = !self.show_status,
            Command::Faster => self.session.scale_speed(2.0),
            Command::Slower => self.session.scale_speed(0.5),
            Command::Quit => event_loop.exit(),
        }
        self.request_redraw();
    }

    fn request_redraw(&self) {
        if let Some(g) = &self.gfx {
            g.window.request_redraw();
        }
    }
}

impl ApplicationHandler<Wake> for App<'_> {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.gfx.is_some() {
            return;
        }
        match self.create_window(event_loop) {
            Ok(gfx) => {
                gfx.window.request_redraw();
                let size = gfx.window.inner_size();
                self.gfx = Some(gfx);
                // The window may not get the size asked for (a window manager,
                // a HiDPI scale factor): render at the one it has.
                self.apply_size(size);
                self.session.flush();
            }
            Err(e) => self.fail(event_loop, e),
        }
    }

    fn user_event(&mut self, _: &ActiveEventLoop, _: Wake) {
        // Re-arm before draining so tiles landing meanwhile wake us again.
        self.waker.rearm();
        let now = Instant::now();
        if !self.session.pump(now) {
            return;
        }
        // A completed pass goes on screen at once (it ends a motion-to-photon
        // measurement); tiles of a pass in progress at most every MIN_PRESENT_INTERVAL.
        let next = self.last_present.map(|t| t + MIN_PRESENT_INTERVAL);
        match next {
            Some(at) if now < at && !self.session.has_unreported() => {
                self.redraw_due.get_or_insert(at);
            }
            _ => {
                self.redraw_due = None;
                self.request_redraw();
            }
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(size) => {
                self.resize_due = Some((Instant::now() + RESIZE_DEBOUNCE, size));
                self.request_redraw();
            }
            WindowEvent::RedrawRequested => {
                if let Err(e) = self.redraw() {
                    self.fail(event_loop, e);
                }
            }
            WindowEvent::ModifiersChanged(m) => self.modifiers = m.state(),
            WindowEvent::KeyboardInput { event, is_synthetic, .. } => {
                let PhysicalKey::Code(code) = event.physical_key else { return };
                // A press is a command only when a key goes down in this window:
                // not a system key repeat, and not one of the presses winit
                // makes up on focus for every key that is already down (X11).
                // A key being pressed while the window gains focus arrives both
                // ways, and would otherwise act twice (the overlay toggled on
                // and off again).
                if event.state == ElementState::Released {
                    self.held.release(code);
                } else if let Some(command) = command_for_key(code, self.modifiers.shift_key())
                    && !event.repeat
                    && !is_synthetic
                {
                    self.command(event_loop, code, command);
                }
            }
            WindowEvent::Focused(false) => self.held.release_all(),
            WindowEvent::MouseInput { state, button: MouseButton::Left, .. } => {
                self.drag = match state {
                    ElementState::Pressed => self.cursor,
                    ElementState::Released => None,
                };
            }
            WindowEvent::CursorMoved { position, .. } => {
                self.cursor = Some(position);
                if let Some(last) = self.drag {
                    self.session.look(position.x - last.x, position.y - last.y, Instant::now());
                    self.drag = Some(position);
                }
            }
            WindowEvent::CursorLeft { .. } => self.cursor = None,
            _ => {}
        }
    }

    fn about_to_wait(&mut self, event_loop: &ActiveEventLoop) {
        if self.options.exit_after_playback
            && self.session.playback_finished()
            && !self.session.has_unreported()
        {
            event_loop.exit();
            return;
        }
        let now = Instant::now();
        // Held keys move on once the last move's frame is complete, by as much
        // as the time since asks for: speed follows the clock, not the frame rate.
        if !self.held.is_empty() && !self.session.moving_frame_pending() {
            for (mv, steps) in self.held.due(now, self.session.controls()) {
                self.session.move_steps(mv, steps, now);
            }
        }
        // A resize once the window has kept its size for RESIZE_DEBOUNCE.
        if let Some((due, size)) = self.resize_due
            && now >= due
        {
            self.resize_due = None;
            self.apply_size(size);
        }
        // A dwelling playback's next camera, when due.
        self.session.tick(now);
        // While a move key is down the motion goes on: no still passes yet.
        self.session.hold(!self.held.is_empty());
        // One request per batch of input events.
        self.session.flush();
        let wake = if !self.held.is_empty() {
            Some(now + Duration::from_millis(5))
        } else if self.show_status && self.session.active(now) {
            // Keep the status line's counters ticking while frames are rendered.
            Some(Instant::now() + Duration::from_millis(250))
        } else {
            None
        };
        let resize = self.resize_due.map(|(at, _)| at);
        let wake = [wake, self.session.next_due(), self.redraw_due, resize].into_iter().flatten().min();
        event_loop.set_control_flow(wake.map_or(ControlFlow::Wait, ControlFlow::WaitUntil));
    }

    fn new_events(&mut self, _: &ActiveEventLoop, cause: winit::event::StartCause) {
        if !matches!(cause, winit::event::StartCause::ResumeTimeReached { .. }) {
            return;
        }
        // A put-off redraw whose time came.
        if self.redraw_due.is_some_and(|at| Instant::now() >= at) {
            self.redraw_due = None;
            self.request_redraw();
        } else if self.held.is_empty() {
            // The status line's timer (held keys' timer redraws when tiles land).
            self.request_redraw();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn screenshots_are_numbered_in_their_format_and_leave_no_part_file() {
        let dir = tempfile::tempdir().unwrap();
        let rgb: Vec<u8> = (0..6 * 4 * 3).map(|i| (i * 7) as u8).collect();
        let a = save_screenshot(dir.path(), ScreenshotFormat::Png, (6, 4), &rgb).unwrap();
        let b = save_screenshot(dir.path(), ScreenshotFormat::Png, (6, 4), &rgb).unwrap();
        let c = save_screenshot(dir.path(), ScreenshotFormat::Jpeg, (6, 4), &rgb).unwrap();
        assert_eq!(a, dir.path().join("isin-screenshot-0000.png"));
        assert_eq!(b, dir.path().join("isin-screenshot-0001.png"));
        assert_eq!(c, dir.path().join("isin-screenshot-0000.jpg"));
        assert_eq!(image::open(&a).unwrap().to_rgb8().into_raw(), rgb);
        let jpeg = std::fs::read(&c).unwrap();
        assert_eq!(image::guess_format(&jpeg).unwrap(), image::ImageFormat::Jpeg);
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 3, "a .part file was left");
        // A failed write leaves nothing either.
        let missing = dir.path().join("no/such/dir");
        assert!(save_screenshot(&missing, ScreenshotFormat::Png, (6, 4), &rgb).is_err());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 3);
    }
}

//! `isin view`: the interactive window.
//!
//! `isin view --connect TICKET` shows what a cluster renders ([`run_remote`],
//! through [`super::remote::Remote`]); `isin view SCENE` starts a cluster of its
//! own (a master and one local slave, [`super::cluster::run_embedded_window`])
//! and shows it the same way: one rendering path. Any [`FrameSource`] plugs in through
//! [`run_with_source`]: it needs only the source, the starting camera, the
//! render settings and the scene's size (for navigation speeds).

use super::remote::Remote;
use crate::assets::load_scene_file;
use anyhow::Context;
use clap::Args;
use isin_tracer::{Camera, RenderSettings};
use isin_transport::Ticket;
use isin_viewer::stats::Summary;
use isin_viewer::{CameraPath, Divisor, FrameReport, MovingResolution};
use isin_viewer::{
    Controls, FrameSource, Quality, Recorder, Session, SessionConfig, SourceStatus, ViewerEvent,
    ViewerOptions,
};
use std::cell::RefCell;
use std::io::Write;
use std::path::PathBuf;
use std::rc::Rc;
use std::time::{Duration, Instant};

/// The key bindings, shown by `isin view --help`.
pub const KEYS_HELP: &str = "\
Keys:
  W / S, Up / Down          move forward / back along the view direction
  A / D, Left / Right       turn left / right
  R / F, PageUp / PageDown  tilt up / down
  Q / E                     roll counter-clockwise / clockwise
  Z / C, Shift+A / Shift+D  strafe left / right
  Shift+W / Shift+S         strafe up / down
  left mouse drag           look around
  Home                      back to the scene's camera
  F12 / P                   save a screenshot (the rendered image; --screenshot-format)
  O / Tab                   tile-ownership overlay (tile borders coloured per slave)
  H                         status text (fps, frame time, slaves, tiles, bytes/s, transport)
  + / -                     double / halve the move and strafe steps
  Escape                    quit
A held move key keeps moving, in frames made as small as needed to hold --target-fps; a still
view is redrawn at full resolution, then refined until --max-spp samples per pixel.";

/// Screenshot formats (`--screenshot-format`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ScreenshotKind {
    /// PNG.
    Png,
    /// JPEG.
    #[value(alias = "jpeg")]
    Jpg,
}

/// Options of the window itself, shared by every way of starting a viewer.
#[derive(Args, Debug, Clone, PartialEq)]
pub struct WindowArgs {
    /// Width of the window as it opens, in pixels (default: the scene's; alone,
    /// the height follows at the scene's aspect). The render resolution follows
    /// the window (times --scale), also when it is resized: another shape than
    /// the scene's widens the view about its centre, never stretched.
    #[arg(long, value_parser = super::bounded::side)]
    pub width: Option<u32>,
    /// Height of the window as it opens, in pixels (default: the scene's; alone,
    /// the width follows).
    #[arg(long, value_parser = super::bounded::side)]
    pub height: Option<u32>,
    /// Render resolution per window pixel: 0.5 renders a quarter of the
    /// pixels and shows them enlarged, 2 renders four samples' worth of
    /// pixels per window pixel (from 0.1 to 4).
    #[arg(long, default_value_t = 1.0, value_parser = parse_scale)]
    pub scale: f32,
    /// Record the navigation (one camera per move) to this camera-path file (TOML).
    #[arg(long, value_name = "PATH")]
    pub record: Option<PathBuf>,
    /// Stop refining a still view at this many samples per pixel.
    #[arg(long, default_value_t = 64, value_parser = super::bounded::spp)]
    pub max_spp: u32,
    /// While moving, always render at 1/N of the resolution in each direction
    /// (shown enlarged, bilinear; N from 1 to 16 in steps of 0.25, e.g. 2.5). Without it
    /// N is chosen from the measured frame times to hold --target-fps.
    /// A still view is sharpened and refined at full resolution.
    #[arg(long, value_name = "N")]
    pub moving_scale: Option<Divisor>,
    /// Frames per second to hold while moving, by rendering moving frames at
    /// a lower resolution (1/1 to 1/8) when needed.
    #[arg(long, default_value_t = 30.0, value_parser = parse_fps)]
    pub target_fps: f32,
    /// Directory screenshots (F12 / P) are saved to.
    #[arg(long, default_value = ".")]
    pub screenshot_dir: PathBuf,
    /// Screenshot format: the displayed image is 8-bit sRGB (the cluster
    /// sends RGB8 tiles), so PNG or JPEG; for EXR use `isin render -o x.exr`.
    #[arg(long, value_enum, default_value_t = ScreenshotKind::Png)]
    pub screenshot_format: ScreenshotKind,
    /// Print a line "frame N complete: ..." on stdout as each pass is shown
    /// (for scripts and tests); with a cluster, also a "status: ..." line
    /// (live slaves, tiles per slave, bytes received, transport, dead slaves).
    #[arg(long)]
    pub print_frames: bool,
    /// Play a camera path back in the window (each camera as soon as the
    /// previous one is on screen) and print motion-to-photon latency and
    /// frames per second while moving.
    #[arg(long, value_name = "PATH")]
    pub play: Option<PathBuf>,
    /// Close the window when the playback is over.
    #[arg(long, requires = "play")]
    pub exit_after_play: bool,
    /// Scene units one forward/back or strafe key press moves (the paper's
    /// `k`; default: 1/40 of the scene's size). `+` / `-` change it while flying.
    #[arg(long, value_name = "K", value_parser = parse_positive)]
    pub move_step: Option<f32>,
    /// Degrees one turn key press (yaw, pitch, roll) rotates.
    #[arg(long, value_name = "DEG", default_value_t = 3.0, value_parser = parse_positive)]
    pub turn_step: f32,
    /// Degrees the view turns per pixel of mouse drag.
    #[arg(long, value_name = "DEG", default_value_t = 0.2, value_parser = parse_positive)]
    pub look_speed: f32,
    /// Steps per second while a move key is held down.
    #[arg(long, value_name = "N", default_value_t = 15.0, value_parser = parse_positive)]
    pub key_rate: f32,
    /// With --play: stay this many milliseconds on each camera after its first
    /// pass is on screen (the still view is sharpened and refined meanwhile),
    /// so that every move supersedes passes in flight — the latency of the
    /// first move after looking around. 0: move on at once.
    #[arg(long, value_name = "MS", default_value_t = 0, requires = "play")]
    pub play_dwell: u64,
}

impl Default for WindowArgs {
    /// The same as an empty command line (for callers that open a viewer
    /// without `isin view`, such as the default `isin`).
    fn default() -> Self {
        Self {
            width: None,
            height: None,
            scale: 1.0,
            record: None,
            max_spp: 64,
            moving_scale: None,
            target_fps: 30.0,
            screenshot_dir: PathBuf::from("."),
            screenshot_format: ScreenshotKind::Png,
            print_frames: false,
            play: None,
            exit_after_play: false,
            play_dwell: 0,
            move_step: None,
            turn_step: 3.0,
            look_speed: 0.2,
            key_rate: 15.0,
        }
    }
}

/// Arguments of `isin view`.
#[derive(Args, Debug)]
pub struct ViewArgs {
    /// Scene file (TOML) or mesh file (.gltf, .glb, .obj). With a ticket it is
    /// sent to the master and flown on the cluster; without one, the master's
    /// own scene is shown.
    pub scene: Option<PathBuf>,
    /// Show what a cluster renders instead.
    #[command(flatten)]
    pub cluster: super::ticket::TicketArgs,
    /// With --connect: where slaves may deliver the tiles straight.
    #[command(flatten)]
    pub direct: super::ticket::DirectArgs,
    #[command(flatten)]
    pub window: WindowArgs,
    /// Render threads of the local slave (default, or 0: one per core; without --connect).
    #[arg(long, value_parser = super::bounded::threads)]
    pub threads: Option<usize>,
    /// Tile edge in pixels.
    #[arg(long, default_value_t = 32, value_parser = super::bounded::tile)]
    pub tile: u32,
}

/// Runs `isin view SCENE` on a cluster of its own, or `isin view --connect
/// TICKET` on a running one.
pub fn run(args: ViewArgs) -> anyhow::Result<()> {
    // Fail before the (possibly slow) scene load or connection when no window can open.
    isin_viewer::check_display()?;
    if let Some(ticket) = args.cluster.ticket()? {
        let own = match &args.scene {
            None => None,
            Some(path) => {
                let (camera, settings, bundle) = crate::assets::load_view(path)?;
                let name = isin_cluster::protocol::served_name(&bundle.name).to_string();
                let hash = isin_cluster::protocol::served_scene_hash(&bundle);
                Some((isin_cluster::protocol::SceneInfo { name, hash, camera, settings }, bundle))
            }
        };
        return run_remote(ticket, None, own, args.direct.direct.clone(), &args.window);
    }
    let scene_path = args
        .scene
        .context("a scene file is needed without a ticket (--connect, --ticket-file or ISIN_TICKET)")?;
    // One rendering path: the scene is served by a master of our own, with
    // one local slave, as a remote cluster would render it.
    let (scene, bundle) = load_scene_file(&scene_path)?;
    let extent = scene_extent(&scene);
    let token = isin_cluster::auth::generate_token()?;
    let mut cfg = isin_actors::master::MasterConfig::new(token, bundle, scene.camera, scene.settings)?;
    cfg.cluster.scheduler.tile_size = args.tile.max(1);
    drop(scene);
    super::cluster::run_embedded_window(cfg, 1, args.threads.unwrap_or(0), extent, &args.window)
}

/// Opens the viewer on the cluster of `ticket`: the master's scene, camera and
/// settings. `extent` (the scene's size, for navigation steps) is guessed
/// from the camera when not known ([`extent_from_camera`]). Closing the window
/// disconnects; the master and its slaves stay up.
pub fn run_remote(
    ticket: Ticket,
    extent: Option<f32>,
    own: Option<(isin_cluster::protocol::SceneInfo, isin_tracer::SceneBundle)>,
    direct: Option<String>,
    window: &WindowArgs,
) -> anyhow::Result<()> {
    let addr = ticket.addr.clone();
    let (remote, source) = Remote::connect(ticket, format!("view-{}", std::process::id()), own, direct)?;
    let scene = remote.scene.clone();
    let extent = extent.unwrap_or_else(|| extent_from_camera(&scene.camera));
    let title = format!("isin — {} via {addr}", scene.name);
    let feed = remote.feed.clone();
    let status: StatusFn = Box::new(move || feed.status());
    let result =
        run_with_source(Box::new(source), scene.camera, scene.settings, extent, window, title, Some(status));
    remote.finish();
    result
}

/// A scene size for navigation steps when only the camera is known: the
/// viewer of a cluster does not load the scene. Scenes are usually framed a
/// few eye-to-plane distances across.
pub fn extent_from_camera(camera: &Camera) -> f32 {
    let d = camera.eye_distance().abs().max(camera.plane_x().length());
    if d.is_finite() { 4.0 * d } else { 0.0 }
}

/// Reads a source's counters for `--print-frames` status lines.
pub type StatusFn = Box<dyn Fn() -> SourceStatus>;

/// Diagonal of the scene's bounding box (0 for an empty scene).
pub fn scene_extent(scene: &isin_tracer::Scene) -> f32 {
    let d = (scene.bounds.max - scene.bounds.min).length();
    if d.is_finite() { d } else { 0.0 }
}

/// Opens the viewer on any frame source. `settings` are the scene's (its
/// resolution is overridden by `--width/--height`, its shadow rays set the
/// refinement quality); `extent` scales the navigation steps.
pub fn run_with_source(
    source: Box<dyn FrameSource>,
    camera: Camera,
    mut settings: RenderSettings,
    extent: f32,
    window: &WindowArgs,
    title: String,
    status: Option<StatusFn>,
) -> anyhow::Result<()> {
    settings = settings.resized(window.width, window.height);
    let window_size = (settings.width, settings.height);
    (settings.width, settings.height) =
        isin_viewer::session::render_size(settings.width, settings.height, window.scale);
    isin_tracer::limits::check_settings(&settings)?;
    // Another shape than the scene's widens the view; never stretched.
    let camera = camera.fit_aspect(settings.width as f32 / settings.height as f32);
    let mut quality = Quality::for_settings(&settings);
    quality.max_spp = window.max_spp.max(1);
    quality.moving = match window.moving_scale {
        Some(d) => MovingResolution::Fixed(d),
        None => MovingResolution::dynamic(window.target_fps),
    };
    let config = SessionConfig { settings, quality, controls: controls_for(window, extent), camera };
    let mut session = Session::new(source, config);
    if let Some(path) = &window.record {
        session.record_to(Recorder::new(path.clone(), settings.width, settings.height));
    }
    if let Some(path) = &window.play {
        let path = CameraPath::load(path)?;
        session.play(path.frames.iter().map(|f| f.camera()));
        session.set_playback_dwell(Duration::from_millis(window.play_dwell));
    }
    let print_frames = window.print_frames;
    let playing = window.play.is_some();
    let moving: Rc<RefCell<Vec<(Instant, FrameReport)>>> = Rc::default();
    let log = moving.clone();
    let options = ViewerOptions {
        title,
        window_size: Some(window_size),
        render_scale: window.scale,
        screenshot_dir: window.screenshot_dir.clone(),
        screenshot_format: match window.screenshot_format {
            ScreenshotKind::Png => isin_viewer::ScreenshotFormat::Png,
            ScreenshotKind::Jpg => isin_viewer::ScreenshotFormat::Jpeg,
        },
        exit_after_playback: window.exit_after_play,
        on_event: Box::new(move |event| match event {
            ViewerEvent::FramePresented(r) => {
                if r.pass == 0 {
                    log.borrow_mut().push((Instant::now(), *r));
                }
                if !print_frames {
                    return;
                }
                let mut line = format!(
                    "frame {} complete: view {} pass {} spp {} size {}x{} scale {} render {:.1} ms",
                    r.frame_id,
                    r.view,
                    r.pass,
                    r.spp,
                    r.size.0,
                    r.size.1,
                    r.divisor,
                    r.render_time.as_secs_f64() * 1e3
                );
                if let Some(l) = r.latency {
                    line += &format!(" latency {:.1} ms", l.as_secs_f64() * 1e3);
                }
                let mut out = std::io::stdout().lock();
                let _ = writeln!(out, "{line}");
                if let Some(status) = &status {
                    let s = status();
                    let tiles: Vec<String> =
                        s.tiles_per_slave.iter().map(|(id, n)| format!("{id}:{n}")).collect();
                    let dead = s.workers.iter().filter(|w| !w.alive).count();
                    let _ = writeln!(
                        out,
                        "status: {} live slaves  tiles {}  {} bytes received  transport {}  dead {dead}",
                        s.live_slaves,
                        tiles.join(" "),
                        s.bytes_received,
                        s.transport
                    );
                }
                let _ = out.flush();
            }
            ViewerEvent::ScreenshotSaved(path) => println!("screenshot {}", path.display()),
            // What the window says on screen besides the counters, for scripts and tests.
            ViewerEvent::Notices(lines) if print_frames => {
                let mut out = std::io::stdout().lock();
                if lines.is_empty() {
                    let _ = writeln!(out, "notice: none");
                }
                for line in lines {
                    let _ = writeln!(out, "notice: {line}");
                }
                let _ = out.flush();
            }
            _ => {}
        }),
        ..ViewerOptions::default()
    };
    let result = isin_viewer::run(&mut session, options);
    if playing {
        print_playback_summary(&moving.borrow(), window.play_dwell > 0);
    }
    if let Some(saved) = session.save_recording() {
        let path = saved.context("cannot save the camera path")?;
        println!("camera path recorded to {}", path.display());
    }
    Ok(result?)
}

/// Prints latency and frame-rate figures of a playback: every moving pass shown
/// after the first, i.e. one per camera move (no frame rate when it dwelled).
fn print_playback_summary(shown: &[(Instant, FrameReport)], dwelled: bool) {
    let latencies: Vec<Duration> = shown.iter().filter_map(|(_, r)| r.latency).collect();
    let renders: Vec<Duration> = shown.iter().skip(1).map(|(_, r)| r.render_time).collect();
    let lat = Summary::of(&latencies);
    let render = Summary::of(&renders);
    let span = match (shown.first(), shown.last()) {
        (Some((t0, _)), Some((t1, _))) if shown.len() > 1 => t1.duration_since(*t0).as_secs_f64(),
        _ => 0.0,
    };
    let fps = if span > 0.0 { (shown.len() - 1) as f64 / span } else { 0.0 };
    let fps =
        if dwelled { "(dwelling: no frame rate)".to_string() } else { format!("{fps:.1} fps while moving") };
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    // Sizes of the moving frames (every move after the starting view).
    let mut divisors: Vec<(Divisor, (u32, u32))> =
        shown.iter().skip(1).map(|(_, r)| (r.divisor, r.size)).collect();
    divisors.sort();
    let sizes = match (divisors.first(), divisors.get(divisors.len() / 2), divisors.last()) {
        (Some(lo), Some(mid), Some(hi)) => {
            let at = |(d, (w, h)): &(Divisor, (u32, u32))| format!("1/{d} ({w}x{h})");
            format!("  moving frames at {} median, {} to {}", at(mid), at(lo), at(hi))
        }
        _ => String::new(),
    };
    println!(
        "playback: {} moves  motion-to-photon median {:.1} ms  p95 {:.1} ms  render median {:.1} ms  \
         p95 {:.1} ms  {}{}",
        lat.count,
        ms(lat.median),
        ms(lat.p95),
        ms(render.median),
        ms(render.p95),
        fps,
        sizes
    );
}

/// The navigation speeds: steps sized for a scene of `extent`, overridden by
/// the command line.
fn controls_for(window: &WindowArgs, extent: f32) -> Controls {
    let mut c = Controls::for_scene_extent(extent);
    if let Some(k) = window.move_step {
        (c.move_step, c.strafe_step) = (k, k);
    }
    c.turn_step = window.turn_step.to_radians();
    c.look_per_pixel = window.look_speed.to_radians();
    c.repeat_rate = window.key_rate;
    c
}

/// Parses a positive, finite number.
fn parse_positive(s: &str) -> Result<f32, String> {
    match s.parse::<f32>() {
        Ok(f) if f.is_finite() && f > 0.0 => Ok(f),
        _ => Err(format!("expected a positive number, not {s:?}")),
    }
}

/// Parses `--scale`: render pixels per window pixel, from 0.1 to 4.
fn parse_scale(s: &str) -> Result<f32, String> {
    match s.parse::<f32>() {
        Ok(f) if (0.1..=4.0).contains(&f) => Ok(f),
        _ => {
            Err(format!("expected a render scale from 0.1 to 4 (render pixels per window pixel), not {s:?}"))
        }
    }
}

/// Parses `--target-fps`: a positive, finite number.
fn parse_fps(s: &str) -> Result<f32, String> {
    match s.parse::<f32>() {
        Ok(f) if f.is_finite() && f > 0.0 && f <= 1000.0 => Ok(f),
        _ => Err(format!("expected frames per second between 0 and 1000, not {s:?}")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Wrapper {
        #[command(flatten)]
        window: WindowArgs,
    }

    #[test]
    fn default_window_args_match_an_empty_command_line() {
        assert_eq!(Wrapper::parse_from(["isin"]).window, WindowArgs::default());
    }

    #[test]
    fn navigation_speeds_come_from_the_scene_unless_given() {
        let default = controls_for(&WindowArgs::default(), 40.0);
        assert_eq!(default, Controls::for_scene_extent(40.0), "defaults: the library's, sized for the scene");
        let w = Wrapper::parse_from([
            "isin",
            "--move-step",
            "0.25",
            "--turn-step",
            "10",
            "--look-speed",
            "0.5",
            "--key-rate",
            "30",
        ])
        .window;
        let c = controls_for(&w, 40.0);
        assert_eq!((c.move_step, c.strafe_step, c.repeat_rate), (0.25, 0.25, 30.0));
        assert!((c.turn_step - 10f32.to_radians()).abs() < 1e-7);
        assert!((c.look_per_pixel - 0.5f32.to_radians()).abs() < 1e-7);
        for bad in [["--move-step", "0"], ["--turn-step", "-1"], ["--key-rate", "inf"]] {
            assert!(Wrapper::try_parse_from(["isin", bad[0], bad[1]]).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn moving_scale_and_target_fps_parse() {
        let w = Wrapper::parse_from(["isin", "--moving-scale", "2.5", "--target-fps", "60"]).window;
        assert_eq!(w.moving_scale.map(|d| d.quarters()), Some(10));
        assert_eq!(w.target_fps, 60.0);
        for bad in [["--moving-scale", "0.5"], ["--moving-scale", "2.2"], ["--target-fps", "0"]] {
            assert!(Wrapper::try_parse_from(["isin", bad[0], bad[1]]).is_err(), "{bad:?}");
        }
    }
}

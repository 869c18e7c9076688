//! End to end: `isin view` in a real X server (Xvfb), driven with xdotool,
//! photographed with ImageMagick's `import`.
//!
//! Needs `Xvfb`, `xdpyinfo` (x11-utils), `xdotool` and `import` (imagemagick).
//! Skipped, with the reason printed, only when Xvfb is missing or cannot start.
//! Screenshots are kept under `target/test-artifacts/viewer/`.
//!
//! Synchronisation is by the viewer's `--print-frames` lines ("frame N
//! complete: view V pass P spp S ..."), printed after the pass is on screen:
//! each move key starts exactly one new view, and `--max-spp 4` makes a view's
//! image final once a line with `spp 4` for it appears.
//!
//! The cluster test runs `isin master` and two `isin slave`s with the harness
//! of the cluster tests (`tests/cluster/util.rs`) and `isin view --connect`.

#[path = "cluster/util.rs"]
mod util;

use std::ffi::OsString;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError, channel};
use std::time::{Duration, Instant};

const WAIT: Duration = Duration::from_secs(120);
const MAX_SPP: u32 = 4;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Stops the child (our own process, by handle) when dropped: SIGTERM first,
/// so an X server removes its lock file, then SIGKILL if it lingers.
struct Reaper(Child);

impl Drop for Reaper {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            let _ = Command::new("kill").args(["-TERM", &self.0.id().to_string()]).status();
            let deadline = Instant::now() + Duration::from_secs(5);
            while Instant::now() < deadline && matches!(self.0.try_wait(), Ok(None)) {
                std::thread::sleep(Duration::from_millis(20)); // polling interval
            }
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn tool_exists(name: &str) -> bool {
    Command::new("sh")
        .args(["-c", &format!("command -v {name}")])
        .stdout(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

fn display_answers(display: &str) -> bool {
    Command::new("xdpyinfo")
        .args(["-display", display])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// Starts Xvfb; `Err` with the reason when it cannot.
///
/// Each server gets an explicit display number from a range of this test
/// process's own (by process id, then a counter), and `-displayfd` tells when
/// it accepts connections. With servers picking numbers themselves
/// (`-displayfd` alone), tests running in parallel now and then saw a viewer
/// fail with "Failed to open connection to X server" on a display that had
/// just answered — most likely a server probing the numbers disturbed
/// another's socket. With an explicit number a server checks that display's
/// lock and exits if it is taken, and the next number is tried.
///
/// `-noreset`: by default an X server resets itself when its last client
/// disconnects, and a client connecting during the reset is refused. The
/// readiness probe (`xdpyinfo`) is such a last client, so a viewer started
/// right after it now and then failed with "Failed to open connection to X
/// server" (seen in CI at load average 3).
fn start_xvfb() -> Result<(Reaper, String), String> {
    start_xvfb_with(&[])
}

/// [`start_xvfb`] with more server options.
fn start_xvfb_with(options: &[&str]) -> Result<(Reaper, String), String> {
    use std::sync::atomic::{AtomicU32, Ordering};
    static NEXT: AtomicU32 = AtomicU32::new(0);
    if !tool_exists("Xvfb") {
        return Err("Xvfb is not installed".into());
    }
    let base = 100 + (std::process::id() % 1000) * 32;
    let mut said = Vec::new();
    for _ in 0..16 {
        let n = base + NEXT.fetch_add(1, Ordering::Relaxed) % 32;
        let display = format!(":{n}");
        let mut child = Command::new("Xvfb")
            .arg(&display)
            .args(["-displayfd", "1", "-screen", "0", "640x480x24", "-nolisten", "tcp", "-noreset"])
            .args(options)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .map_err(|e| format!("cannot run Xvfb: {e}"))?;
        let stdout = child.stdout.take().ok_or("no pipe to Xvfb")?;
        let xvfb = Reaper(child);
        let (tx, rx) = channel();
        std::thread::spawn(move || {
            let mut line = String::new();
            let _ = BufReader::new(stdout).read_line(&mut line);
            let _ = tx.send(line);
        });
        let line = rx
            .recv_timeout(Duration::from_secs(30))
            .map_err(|_| format!("Xvfb {display} did not report that it is ready"))?;
        if line.trim() != n.to_string() {
            said.push(format!("{display}: {line:?}")); // taken (it exited): try the next
            continue;
        }
        if tool_exists("xdpyinfo") && !display_answers(&display) {
            return Err(format!("Xvfb reported {display} but it does not answer"));
        }
        return Ok((xvfb, display));
    }
    Err(format!("Xvfb could not start on any display: {said:?}"))
}

/// A parsed `--print-frames` line.
#[derive(Debug, Clone, Copy)]
struct Done {
    view: u32,
    spp: u32,
}

fn parse_done(line: &str) -> Option<Done> {
    let rest = line.strip_prefix("frame ")?;
    let (_, rest) = rest.split_once(" complete: ")?;
    let words: Vec<&str> = rest.split_whitespace().collect();
    let field =
        |name: &str| words.iter().position(|w| *w == name).and_then(|i| words.get(i + 1)?.parse().ok());
    Some(Done { view: field("view")?, spp: field("spp")? })
}

struct Viewer {
    child: Reaper,
    lines: Receiver<String>,
    log: Vec<String>,
    display: String,
    window: String,
}

impl Viewer {
    /// Waits for a stdout line accepted by `want`.
    fn wait_line(&mut self, what: &str, want: impl Fn(&str) -> bool) -> String {
        let deadline = Instant::now() + WAIT;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(line) => {
                    self.log.push(line.clone());
                    if want(&line) {
                        return line;
                    }
                }
                Err(RecvTimeoutError::Timeout) => {
                    panic!("timed out waiting for {what}; output:\n{:#?}", self.log)
                }
                Err(RecvTimeoutError::Disconnected) => {
                    panic!("viewer exited while waiting for {what}; output:\n{:#?}", self.log)
                }
            }
        }
    }

    /// The first line accepted by `want` that the viewer printed after its
    /// log's line `since`: already read, or waited for.
    fn line_since(&mut self, since: usize, what: &str, want: impl Fn(&str) -> bool) -> String {
        match self.log.iter().skip(since).find(|l| want(l)) {
            Some(l) => l.clone(),
            None => self.wait_line(what, want),
        }
    }

    /// Waits until view `view` is fully refined (its image no longer changes).
    fn wait_view_final(&mut self, view: u32) {
        self.wait_line(&format!("view {view} at {MAX_SPP} spp"), |l| {
            parse_done(l).is_some_and(|d| d.view == view && d.spp >= MAX_SPP)
        });
    }

    fn xdotool(&self, args: &[&str]) {
        let status = Command::new("xdotool").args(args).env("DISPLAY", &self.display).status().unwrap();
        assert!(status.success(), "xdotool {args:?} failed");
    }

    fn press(&self, key: &str) {
        // XTEST key events go to the focused window (no window manager needed).
        self.xdotool(&["windowfocus", "--sync", &self.window]);
        self.xdotool(&["key", key]);
    }

    fn screenshot(&self, file: &Path) -> image::RgbImage {
        let status = Command::new("import")
            .args(["-window", &self.window])
            .arg(file)
            .env("DISPLAY", &self.display)
            .status()
            .expect("ImageMagick's import is needed for screenshots");
        assert!(status.success(), "import failed");
        image::open(file).unwrap().to_rgb8()
    }

    /// A screenshot once `ready` holds for it, or the last one taken after
    /// [`WAIT`]: the X server draws what the viewer presented in its own time,
    /// so a screenshot taken right after the viewer reports a frame may
    /// still show the one before.
    fn screenshot_when(&self, file: &Path, ready: impl Fn(&image::RgbImage) -> bool) -> image::RgbImage {
        let deadline = Instant::now() + WAIT;
        loop {
            let img = self.screenshot(file);
            if ready(&img) || Instant::now() >= deadline {
                return img;
            }
            std::thread::sleep(Duration::from_millis(50)); // polling interval
        }
    }

    fn wait_exit(&mut self) -> ExitStatus {
        let deadline = Instant::now() + Duration::from_secs(30);
        loop {
            if let Some(status) = self.child.0.try_wait().unwrap() {
                return status;
            }
            assert!(Instant::now() < deadline, "viewer did not exit after Escape");
            std::thread::sleep(Duration::from_millis(20)); // polling interval
        }
    }
}

/// Starts `isin ARGS…` (a viewer) on `display` and waits for its window.
fn open_viewer(display: &str, args: &[OsString]) -> Viewer {
    let display = display.to_string();
    let mut child = Command::new(env!("CARGO_BIN_EXE_isin"))
        .args(args)
        .env("DISPLAY", &display)
        .env_remove("WAYLAND_DISPLAY")
        .env("RUST_LOG", "warn")
        .current_dir(repo())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("cannot start isin view");
    let stdout = child.stdout.take().unwrap();
    let (tx, lines) = channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let mut child = Reaper(child);

    // The window exists once xdotool finds it by name.
    let deadline = Instant::now() + WAIT;
    let window = loop {
        let out = Command::new("xdotool")
            .args(["search", "--name", "^isin"])
            .env("DISPLAY", &display)
            .output()
            .unwrap();
        if let Some(id) = String::from_utf8_lossy(&out.stdout).split_whitespace().next() {
            break id.to_string();
        }
        if let Some(status) = child.0.try_wait().unwrap() {
            let said: Vec<String> = lines.try_iter().collect();
            panic!("the viewer exited ({status}) before its window appeared on {display}: {said:#?}");
        }
        assert!(
            Instant::now() < deadline,
            "the viewer window never appeared on {display}; xdotool said {:?}",
            String::from_utf8_lossy(&out.stderr)
        );
        std::thread::sleep(Duration::from_millis(50)); // polling interval
    };
    Viewer { child, lines, log: Vec::new(), display, window }
}

/// Asserts that neither screenshot is blank and that they differ (the view
/// moved); returns their mean absolute difference.
fn assert_view_changed(before: &image::RgbImage, after: &image::RgbImage) -> f64 {
    let (mean_b, var_b) = stats(before);
    let (mean_a, var_a) = stats(after);
    println!("before: mean {mean_b:.1} var {var_b:.1}; after: mean {mean_a:.1} var {var_a:.1}");
    for (name, mean, var) in [("before", mean_b, var_b), ("after", mean_a, var_a)] {
        assert!(var > 50.0, "{name} screenshot looks blank (luminance variance {var:.1})");
        assert!(mean > 5.0 && mean < 250.0, "{name} screenshot is uniformly dark or bright ({mean:.1})");
    }
    let diff = mean_abs_diff(before, after);
    println!("mean absolute difference between before and after: {diff:.2}");
    assert!(diff > 2.0, "the view did not change after moving (difference {diff:.2})");
    diff
}

/// Mean and variance of luminance below the status text (top 40 rows).
fn stats(img: &image::RgbImage) -> (f64, f64) {
    let lum: Vec<f64> = img
        .enumerate_pixels()
        .filter(|(_, y, _)| *y >= 40)
        .map(|(_, _, p)| 0.299 * p[0] as f64 + 0.587 * p[1] as f64 + 0.114 * p[2] as f64)
        .collect();
    let mean = lum.iter().sum::<f64>() / lum.len() as f64;
    let var = lum.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / lum.len() as f64;
    (mean, var)
}

fn mean_abs_diff(a: &image::RgbImage, b: &image::RgbImage) -> f64 {
    assert_eq!(a.dimensions(), b.dimensions());
    let sum: u64 =
        a.as_raw().iter().zip(b.as_raw()).map(|(&x, &y)| (x as i32 - y as i32).unsigned_abs() as u64).sum();
    sum as f64 / a.as_raw().len() as f64
}

#[test]
fn view_moves_on_key_presses_and_quits_on_escape() {
    let scene = repo().join("scenes/paper.toml");
    assert!(scene.exists(), "{} is missing", scene.display());
    let (_xvfb, display) = match start_xvfb() {
        Ok(x) => x,
        Err(why) => {
            // Written to the real stderr so the reason shows without --nocapture.
            use std::io::Write;
            let _ =
                writeln!(std::io::stderr(), "SKIPPED view_moves_on_key_presses_and_quits_on_escape: {why}");
            return;
        }
    };
    for tool in ["xdotool", "import"] {
        assert!(tool_exists(tool), "{tool} is needed (apt-get install xdotool imagemagick)");
    }
    let artefacts = repo().join("target/test-artifacts/viewer");
    std::fs::create_dir_all(&artefacts).unwrap();
    let shots = tempfile::tempdir().unwrap();
    let recording = shots.path().join("recorded.path.toml");

    let mut args: Vec<OsString> = vec!["view".into(), scene.into()];
    args.extend(
        ["--width", "320", "--height", "240", "--print-frames", "--max-spp", &MAX_SPP.to_string()]
            .map(OsString::from),
    );
    args.extend([
        "--screenshot-dir".into(),
        shots.path().into(),
        "--record".into(),
        recording.clone().into(),
    ]);
    let mut v = open_viewer(&display, &args);

    v.wait_view_final(0);
    // `isin view SCENE` renders on a cluster of its own: one local slave.
    let line = v.wait_line("a status line", |l| l.starts_with("status: "));
    let status = parse_status(&line).unwrap_or_else(|| panic!("unparsable status line {line:?}"));
    assert_eq!((status.live, status.transport.as_str()), (1, "tcp"), "{line}");
    let slaves: Vec<u32> = status.tiles.iter().filter(|(_, n)| *n > 0).map(|(id, _)| *id).collect();
    assert_eq!(slaves.len(), 1, "{line}");
    let before = v.screenshot(&artefacts.join("before.png"));
    assert_eq!(before.dimensions(), (320, 240), "the window opens at the render size");

    // One key, one new view: forward along the image-plane normal, then a turn.
    v.press("w");
    v.wait_view_final(1);
    v.press("Left");
    v.wait_view_final(2);
    let after = v.screenshot(&artefacts.join("after.png"));

    // The viewer's own screenshot key writes the rendered image.
    v.press("F12");
    let line = v.wait_line("a screenshot", |l| l.starts_with("screenshot "));
    let saved = PathBuf::from(line.trim_start_matches("screenshot "));
    let own = image::open(&saved).unwrap().to_rgb8();
    assert_eq!(own.dimensions(), (320, 240));
    own.save(artefacts.join("f12.png")).unwrap();

    // The ownership overlay: tile borders (32-pixel tiles, drawn 1:1) in the
    // colour of the slave that made each tile. Shown from the next frame on.
    v.press("o");
    v.press("s");
    v.wait_view_final(3);
    let owners: Vec<[u8; 3]> = slaves
        .iter()
        .map(|&i| {
            let c = isin_viewer::raster::owner_colour(i);
            [(c >> 16) as u8, (c >> 8) as u8, c as u8]
        })
        .collect();
    let on_border = |img: &image::RgbImage, x: u32| {
        (40..240).filter(|&y| owners.contains(&img.get_pixel(x, y).0)).count()
    };
    let drawn = |img: &image::RgbImage| on_border(img, 32) > 150 && on_border(img, 63) > 150;
    let overlay = v.screenshot_when(&artefacts.join("overlay.png"), drawn);
    assert!(drawn(&overlay), "tile borders at x = 32 and 63 are not drawn");
    assert!(
        on_border(&overlay, 48) < 20,
        "a tile's middle column is not a border ({})",
        on_border(&overlay, 48)
    );

    v.press("Escape");
    let status = v.wait_exit();
    assert!(status.success(), "exit status {status:?}; output:\n{:#?}", v.log);

    // The recording holds the cameras: start, one step forward along the
    // plane's normal, a turn to the left about the eye, a step back.
    let path = isin_viewer::CameraPath::load(&recording).unwrap();
    assert_eq!(path.frames.len(), 4, "{path:?}");
    let cams: Vec<isin_tracer::Camera> = path.frames.iter().map(|f| f.camera()).collect();
    let step = cams[1].eye - cams[0].eye;
    assert!(
        step.length() > 0.0 && step.normalize().dot(cams[0].forward()) > 0.9999,
        "W moves forward: {step:?}"
    );
    assert!((cams[2].eye - cams[1].eye).length() < 1e-4, "a turn keeps the eye");
    let turned = cams[1].forward().cross(cams[2].forward());
    assert!(turned.dot(cams[1].up()) > 1e-3, "Left turns left (about up): {turned:?}");

    let diff = assert_view_changed(&before, &after);
    // The F12 image is the rendered frame, which the window shows 1:1 under the status text.
    let diff_own = mean_abs_diff(&own, &after);
    assert!(diff_own < diff, "the saved screenshot differs from the window ({diff_own:.2})");
}

#[test]
fn view_without_a_display_points_to_isin_render() {
    let out = Command::new(env!("CARGO_BIN_EXE_isin"))
        .args(["view", "scenes/paper.toml"])
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .current_dir(repo())
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no display") && err.contains("isin render"), "stderr: {err}");
}

#[test]
fn fly_replays_the_shipped_path_into_pngs() {
    let scene = repo().join("scenes/paper.toml");
    let path_file = repo().join("scenes/paths/paper.toml");
    let path = isin_viewer::CameraPath::load(&path_file).unwrap();
    assert!(path.frames.len() >= 10, "the example path should be a real flight");
    let out = tempfile::tempdir().unwrap();
    let run = Command::new(env!("CARGO_BIN_EXE_isin"))
        .arg("fly")
        .arg(&scene)
        .arg("--path")
        .arg(&path_file)
        .arg("--out-dir")
        .arg(out.path())
        .args(["--width", "48", "--height", "36", "--fast"])
        .current_dir(repo())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "isin fly failed: {}", String::from_utf8_lossy(&run.stderr));
    assert!(stdout.contains("median") && stdout.contains("p95"), "{stdout}");
    let frames: Vec<image::RgbImage> = (0..path.frames.len())
        .map(|i| image::open(out.path().join(format!("frame_{i:04}.png"))).unwrap().to_rgb8())
        .collect();
    assert!(frames.iter().all(|f| f.dimensions() == (48, 36)));
    assert!(!out.path().join(format!("frame_{:04}.png", path.frames.len())).exists());
    let changes = frames.windows(2).filter(|w| w[0] != w[1]).count();
    assert!(
        changes * 2 >= frames.len(),
        "only {changes} of {} frames differ from the previous",
        frames.len()
    );
}

/// A parsed `--print-frames` status line of a cluster-backed viewer:
/// "status: N live slaves  tiles ID:COUNT ID:COUNT  B bytes received  transport T  dead D".
#[derive(Debug)]
struct Status {
    live: usize,
    tiles: Vec<(u32, u64)>,
    transport: String,
    dead: usize,
}

fn parse_status(line: &str) -> Option<Status> {
    let rest = line.strip_prefix("status: ")?;
    let words: Vec<&str> = rest.split_whitespace().collect();
    let live = words.first()?.parse().ok()?;
    let at = words.iter().position(|w| *w == "tiles")?;
    let tiles = words[at + 1..]
        .iter()
        .map_while(|w| {
            let (id, n) = w.split_once(':')?;
            Some((id.parse().ok()?, n.parse().ok()?))
        })
        .collect();
    let transport = words.iter().position(|w| *w == "transport").and_then(|i| words.get(i + 1))?;
    let dead = words.iter().position(|w| *w == "dead").and_then(|i| words.get(i + 1))?.parse().ok()?;
    Some(Status { live, tiles, transport: transport.to_string(), dead })
}

/// How many pixels of `img` (below the status text) have exactly the overlay
/// colour of `owner`.
fn overlay_pixels(img: &image::RgbImage, owner: u32) -> usize {
    let c = isin_viewer::raster::owner_colour(owner);
    let rgb = [(c >> 16) as u8, (c >> 8) as u8, c as u8];
    img.enumerate_pixels().filter(|(_, y, p)| *y >= 40 && p.0 == rgb).count()
}

/// A key that is already down when the window gains focus does nothing.
/// winit reports every such key with a made-up ("synthetic") press when the
/// window is focused (X11); a real press that races the focus change — as
/// `windowfocus` then `key` in these tests can when the machine is busy —
/// arrives both ways, and used to act twice: the overlay went on and off
/// again, and the cluster tests below failed now and then.
#[test]
fn a_key_held_while_the_window_gains_focus_does_not_act() {
    // No system key repeats: the key is held for a while below.
    let (_xvfb, display) = match start_xvfb_with(&["-ardelay", "60000"]) {
        Ok(x) => x,
        Err(why) => {
            use std::io::Write;
            let _ = writeln!(std::io::stderr(), "SKIPPED a_key_held_while_the_window_gains_focus: {why}");
            return;
        }
    };
    for tool in ["xdotool", "import", "xwininfo"] {
        assert!(tool_exists(tool), "{tool} is needed (apt-get install xdotool imagemagick x11-utils)");
    }
    let artefacts = repo().join("target/test-artifacts/viewer-focus");
    std::fs::create_dir_all(&artefacts).unwrap();
    let mut args: Vec<OsString> = vec!["view".into(), repo().join("scenes/paper.toml").into()];
    args.extend(
        ["--width", "160", "--height", "120", "--threads", "2", "--print-frames", "--max-spp", "1"]
            .map(OsString::from),
    );
    let mut v = open_viewer(&display, &args);
    v.wait_line("the first frame", |l| parse_done(l).is_some());
    let line = v.wait_line("a status line", |l| l.starts_with("status: "));
    let slaves: Vec<u32> =
        parse_status(&line).map(|s| s.tiles.iter().map(|t| t.0).collect()).unwrap_or_default();
    assert!(!slaves.is_empty(), "{line}");
    let root = Command::new("xwininfo").arg("-root").env("DISPLAY", &display).output().unwrap();
    let root = String::from_utf8_lossy(&root.stdout);
    let root =
        root.split_whitespace().skip_while(|w| *w != "id:").nth(1).expect("xwininfo names the root window");

    // The overlay key goes down while another window (the root) has the
    // focus, and is still down while the viewer's window takes it.
    v.xdotool(&["windowfocus", "--sync", root]);
    v.xdotool(&["keydown", "o"]);
    v.xdotool(&["windowfocus", "--sync", &v.window]);
    // How long the key is held (the input, not a wait for a result): the
    // viewer handles the focus meanwhile. Were it slower than this, the
    // key would be up by then and there would be nothing to test.
    std::thread::sleep(Duration::from_millis(400));
    v.xdotool(&["keyup", "o"]);
    // Now one real press: the overlay must be on (on and off again if the
    // held key had acted).
    v.press("o");
    let on = |img: &image::RgbImage| slaves.iter().map(|&owner| overlay_pixels(img, owner)).sum::<usize>();
    let shot = v.screenshot_when(&artefacts.join("after.png"), |img| on(img) >= 20);
    assert!(on(&shot) >= 20, "one press of O after a held one shows no overlay; output:\n{:#?}", v.log);
}

#[test]
fn view_connects_to_a_tcp_cluster_and_leaves_it_running() {
    view_on_cluster(util::Transport::Tcp);
}

#[test]
fn view_connects_to_a_quic_cluster_and_leaves_it_running() {
    view_on_cluster(util::Transport::Quic);
}

/// `isin view --connect` on a master with two slaves over `transport`.
fn view_on_cluster(transport: util::Transport) {
    let (_xvfb, display) = match start_xvfb() {
        Ok(x) => x,
        Err(why) => {
            use std::io::Write;
            let _ = writeln!(std::io::stderr(), "SKIPPED view_on_cluster({transport:?}): {why}");
            return;
        }
    };
    for tool in ["xdotool", "import"] {
        assert!(tool_exists(tool), "{tool} is needed (apt-get install xdotool imagemagick)");
    }
    let artefacts = repo().join(format!("target/test-artifacts/viewer-cluster-{}", transport.name()));
    std::fs::create_dir_all(&artefacts).unwrap();
    let mut cluster = util::Cluster::start(transport, 2, &[]);

    // No scene file: the master's scene, camera and settings are shown.
    let args: Vec<OsString> = [
        "view",
        "--connect",
        &cluster.ticket,
        "--width",
        "320",
        "--height",
        "240",
        "--print-frames",
        "--max-spp",
        &MAX_SPP.to_string(),
    ]
    .map(OsString::from)
    .to_vec();
    let mut v = open_viewer(&display, &args);
    v.wait_view_final(0);
    // The status printed after that frame: both slaves live and delivering tiles.
    let line = v.wait_line("a status line", |l| l.starts_with("status: "));
    let status = parse_status(&line).unwrap_or_else(|| panic!("unparsable status line {line:?}"));
    assert_eq!((status.live, status.dead), (2, 0), "the master lists its two slaves: {line}");
    assert_eq!(status.transport, transport.name(), "{line}");
    let owners: Vec<u32> = status.tiles.iter().filter(|(_, n)| *n > 0).map(|(id, _)| *id).collect();
    assert_eq!(owners.len(), 2, "tiles from both slaves: {line}");
    let before = v.screenshot(&artefacts.join("before.png"));
    assert_eq!(before.dimensions(), (320, 240), "the window opens at the render size");

    // The overlay on, then one step forward: a new view, refined to MAX_SPP.
    v.press("o");
    v.press("w");
    v.wait_view_final(1);
    // Tiles per slave of the pass on screen: its status line minus the one before.
    let before_pass = v.log.iter().rev().find_map(|l| parse_status(l)).expect("a status line before");
    let line = v.wait_line("the final pass's status line", |l| l.starts_with("status: "));
    let after_pass = parse_status(&line).unwrap_or_else(|| panic!("unparsable status line {line:?}"));
    let count = |s: &Status, id: u32| s.tiles.iter().find(|(o, _)| *o == id).map_or(0, |(_, n)| *n);
    let drawn: Vec<u32> =
        owners.iter().copied().filter(|&id| count(&after_pass, id) > count(&before_pass, id)).collect();
    assert!(!drawn.is_empty(), "no tiles in the last pass: {before_pass:?} -> {after_pass:?}");
    // The overlay outlines the tiles on screen in the colour of the slave that
    // rendered each: every slave with tiles in the last pass shows.
    let after = v.screenshot_when(&artefacts.join("after.png"), |img| {
        drawn.iter().all(|&owner| overlay_pixels(img, owner) >= 20)
    });
    assert_view_changed(&before, &after);
    for &owner in &drawn {
        let n = overlay_pixels(&after, owner);
        assert!(
            n >= 20,
            "slave {owner}'s tiles are not outlined ({n} pixels of its colour); output:\n{:#?}",
            v.log
        );
        assert!(overlay_pixels(&before, owner) < n, "the overlay was off before");
    }

    // A slave dies: the master tells the viewer (at once over TCP; over QUIC
    // when the connection times out), whose status says so with the next
    // frames shown, rendered by the other slave. Moves until then.
    cluster.slaves[1].kill9();
    let told = Instant::now();
    // Moves until the master notices (QUIC: its idle timeout, a few seconds,
    // however many frames that is) or the wait runs out.
    for step in 0.. {
        v.press(if step % 2 == 0 { "s" } else { "w" });
        let line = v.wait_line("a status line", |l| l.starts_with("status: "));
        let status = parse_status(&line).unwrap_or_else(|| panic!("unparsable status line {line:?}"));
        if (status.live, status.dead) == (1, 1) {
            break;
        }
        assert!(
            told.elapsed() < WAIT,
            "no status line with one live and one dead slave: {line}; output:\n{:#?}",
            v.log
        );
    }

    v.press("Escape");
    let exit = v.wait_exit();
    assert!(exit.success(), "exit status {exit:?}; output:\n{:#?}", v.log);
    // The master and its slaves stay up for the next viewer.
    let (pixels, said) = cluster.render("after-viewer.png", &["--width", "64", "--height", "48"]);
    assert_eq!(pixels.len(), 64 * 48 * 3);
    assert!(said.contains("tiles"), "{said}");
}

#[test]
fn isin_without_arguments_opens_the_viewer_on_its_embedded_cluster() {
    let (_xvfb, display) = match start_xvfb() {
        Ok(x) => x,
        Err(why) => {
            use std::io::Write;
            let _ = writeln!(
                std::io::stderr(),
                "SKIPPED isin_without_arguments_opens_the_viewer_on_its_embedded_cluster: {why}"
            );
            return;
        }
    };
    for tool in ["xdotool", "import"] {
        assert!(tool_exists(tool), "{tool} is needed (apt-get install xdotool imagemagick)");
    }
    let artefacts = repo().join("target/test-artifacts/viewer-default");
    std::fs::create_dir_all(&artefacts).unwrap();
    // No command: only the window options.
    let args: Vec<OsString> =
        ["--width", "320", "--height", "240", "--print-frames", "--max-spp", &MAX_SPP.to_string()]
            .map(OsString::from)
            .to_vec();
    let mut v = open_viewer(&display, &args);
    v.wait_view_final(0);
    let line = v.wait_line("a status line", |l| l.starts_with("status: "));
    let status = parse_status(&line).unwrap_or_else(|| panic!("unparsable status line {line:?}"));
    assert_eq!(
        (status.live, status.transport.as_str()),
        (2, "tcp"),
        "two local slaves over loopback: {line}"
    );
    let shot = v.screenshot(&artefacts.join("default.png"));
    assert_eq!(shot.dimensions(), (320, 240));
    let (mean, var) = stats(&shot);
    assert!(var > 50.0 && mean > 5.0 && mean < 250.0, "blank window (mean {mean:.1}, variance {var:.1})");
    v.press("Escape");
    let exit = v.wait_exit();
    assert!(exit.success(), "exit status {exit:?}; output:\n{:#?}", v.log);
}

/// The `--print-frames` lines of a playback's moving passes (pass 0 of every
/// view after the first): `(size, scale)` as printed.
fn moving_passes(stdout: &str) -> Vec<(String, String)> {
    stdout
        .lines()
        .filter_map(|l| {
            let rest = l.strip_prefix("frame ")?.split_once(" complete: ")?.1;
            let words: Vec<&str> = rest.split_whitespace().collect();
            let field = |name: &str| Some(words[words.iter().position(|w| *w == name)? + 1].to_string());
            if field("pass")? != "0" || field("view")? == "0" {
                return None;
            }
            Some((field("size")?, field("scale")?))
        })
        .collect()
}

#[test]
fn play_sizes_moving_frames_for_the_target_frame_rate_or_a_fixed_scale() {
    let (_xvfb, display) = match start_xvfb() {
        Ok(x) => x,
        Err(why) => {
            use std::io::Write;
            let _ = writeln!(std::io::stderr(), "SKIPPED play_sizes_moving_frames…: {why}");
            return;
        }
    };
    let frames = isin_viewer::CameraPath::load(&repo().join("scenes/paths/paper.toml")).unwrap().frames.len();
    let play = |extra: &[&str]| -> String {
        let out = Command::new(env!("CARGO_BIN_EXE_isin"))
            .args(["view", "scenes/paper.toml", "--width", "160", "--height", "120", "--threads", "1"])
            .args(["--play", "scenes/paths/paper.toml", "--exit-after-play", "--print-frames"])
            .args(extra)
            .env("DISPLAY", &display)
            .env_remove("WAYLAND_DISPLAY")
            .current_dir(repo())
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
        assert!(out.status.success(), "{extra:?}: {stdout}\n{}", String::from_utf8_lossy(&out.stderr));
        assert!(stdout.contains(&format!("playback: {} moves", frames - 1)), "{stdout}");
        stdout
    };
    // 1000 fps leaves under a millisecond per moving frame: the controller
    // picks its smallest sizes (down to 1/8: 20 × 15), how small exactly
    // depending on the measured times. At most a quarter of each side here.
    let fast = play(&["--target-fps", "1000"]);
    let moves = moving_passes(&fast);
    assert_eq!(moves.len(), frames - 1, "{fast}");
    let scales: Vec<f32> = moves.iter().map(|(_, scale)| scale.parse().unwrap()).collect();
    assert!(scales.iter().all(|&d| (4.0..=8.0).contains(&d)), "{moves:?}");
    assert!(fast.contains("moving frames at 1/"), "{fast}");
    // A fixed divisor, fractional: 160 / 2.5 = 64, 120 / 2.5 = 48.
    let fixed = play(&["--moving-scale", "2.5"]);
    let moves = moving_passes(&fixed);
    assert_eq!(moves.len(), frames - 1, "{fixed}");
    assert!(moves.iter().all(|(size, scale)| size == "64x48" && scale == "2.5"), "{moves:?}");
}

/// A parsed `--print-frames` line with the fields the held-key test needs.
#[derive(Debug, Clone)]
struct Pass {
    frame: u64,
    view: u32,
    pass: u32,
    size: String,
}

fn parse_pass(line: &str) -> Option<Pass> {
    let rest = line.strip_prefix("frame ")?;
    let (frame, rest) = rest.split_once(" complete: ")?;
    let words: Vec<&str> = rest.split_whitespace().collect();
    let field = |name: &str| Some(words[words.iter().position(|w| *w == name)? + 1]);
    Some(Pass {
        frame: frame.parse().ok()?,
        view: field("view")?.parse().ok()?,
        pass: field("pass")?.parse().ok()?,
        size: field("size")?.to_string(),
    })
}

#[test]
fn a_held_key_moves_without_still_passes_then_sharpens_on_release() {
    let (_xvfb, display) = match start_xvfb() {
        Ok(x) => x,
        Err(why) => {
            use std::io::Write;
            let _ = writeln!(std::io::stderr(), "SKIPPED a_held_key_moves…: {why}");
            return;
        }
    };
    assert!(tool_exists("xdotool"), "xdotool is needed (apt-get install xdotool)");
    let args: Vec<OsString> = ["view", "scenes/paper.toml", "--width", "320", "--height", "240"]
        .into_iter()
        .chain(["--print-frames", "--max-spp", &MAX_SPP.to_string()])
        .map(OsString::from)
        .collect();
    let mut v = open_viewer(&display, &args);
    v.wait_view_final(0);
    v.xdotool(&["windowfocus", "--sync", &v.window]);
    v.xdotool(&["keydown", "w"]);
    // Several steps of continuous motion while the key is down.
    v.wait_line("view 6", |l| parse_pass(l).is_some_and(|p| p.view >= 6));
    v.xdotool(&["keyup", "w"]);
    let last = v.log.iter().rev().find_map(|l| parse_pass(l)).unwrap().view;
    // After the release the view is sharpened at full size (pass 1), then refined.
    let line = v.wait_line("the still passes after the release", |l| {
        parse_pass(l).is_some_and(|p| p.view >= last && p.pass >= 1)
    });
    let still = parse_pass(&line).unwrap();
    assert_eq!(still.size, "320x240", "{line}");
    let held: Vec<Pass> = v.log.iter().filter_map(|l| parse_pass(l)).filter(|p| p.view >= 1).collect();
    let moving: Vec<&Pass> = held.iter().filter(|p| p.view < still.view || p.pass == 0).collect();
    assert!(moving.iter().all(|p| p.pass == 0), "a still pass while the key was down: {held:#?}");
    // Each step of the motion was the next request: no full-size pass was
    // requested in between (and then superseded, which prints nothing).
    let ids: Vec<u64> = moving.iter().map(|p| p.frame).collect();
    assert!(ids.windows(2).all(|w| w[1] == w[0] + 1), "requests in between the moves: {held:#?}");
    v.xdotool(&["key", "Escape"]);
    let exit = v.wait_exit();
    assert!(exit.success(), "exit status {exit:?}; output:\n{:#?}", v.log);
}

#[test]
fn the_render_resolution_follows_the_window_when_it_is_resized() {
    let (_xvfb, display) = match start_xvfb() {
        Ok(x) => x,
        Err(why) => {
            use std::io::Write;
            let _ = writeln!(std::io::stderr(), "SKIPPED the_render_resolution_follows_the_window: {why}");
            return;
        }
    };
    for tool in ["xdotool", "import"] {
        assert!(tool_exists(tool), "{tool} is needed (apt-get install xdotool imagemagick)");
    }
    let artefacts = repo().join("target/test-artifacts/viewer-resize");
    std::fs::create_dir_all(&artefacts).unwrap();
    let shots = tempfile::tempdir().unwrap();
    let mut args: Vec<OsString> = vec!["view".into(), repo().join("scenes/paper.toml").into()];
    args.extend(
        ["--width", "320", "--height", "240", "--threads", "2", "--print-frames", "--max-spp", "1"]
            .map(OsString::from),
    );
    args.extend(["--screenshot-dir".into(), shots.path().into()]);
    let mut v = open_viewer(&display, &args);
    let first = v.wait_line("the first frame", |l| parse_done(l).is_some());
    assert!(first.contains("size 320x240"), "{first}");

    // Wider and flatter than the scene: the next full-resolution pass is the
    // window's size in pixels, not the old image enlarged.
    v.xdotool(&["windowsize", "--sync", &v.window, "400", "200"]);
    let line = v.wait_line("a full-resolution pass after the resize", |l| {
        parse_pass(l).is_some_and(|p| p.view >= 1) && l.contains(" scale 1 ")
    });
    assert!(line.contains("size 400x200"), "{line}");
    // With --max-spp 1 that pass is the view's last: the image no longer changes.
    v.press("F12");
    let line = v.wait_line("a screenshot", |l| l.starts_with("screenshot "));
    let saved = image::open(line.trim_start_matches("screenshot ")).unwrap().to_rgb8();
    assert_eq!(saved.dimensions(), (400, 200), "the rendered image is the window's size");
    // Drawn 1:1: the window below the status text is the rendered image.
    let rows = |img: &image::RgbImage| -> Vec<u8> {
        img.enumerate_pixels().filter(|(_, y, _)| *y >= 120).flat_map(|(_, _, p)| p.0).collect()
    };
    let diff = |img: &image::RgbImage| {
        let (a, b) = (rows(&saved), rows(img));
        let sum: u64 = a.iter().zip(&b).map(|(&x, &y)| (x as i32 - y as i32).unsigned_abs() as u64).sum();
        sum as f64 / a.len().max(1) as f64
    };
    let shot = v.screenshot_when(&artefacts.join("resized.png"), |img| {
        img.dimensions() == (400, 200) && diff(img) < 3.0
    });
    assert_eq!(shot.dimensions(), (400, 200));
    let d = diff(&shot);
    assert!(d < 3.0, "the window does not show the rendered image 1:1 (mean difference {d:.2})");
    v.press("Escape");
    let exit = v.wait_exit();
    assert!(exit.success(), "exit status {exit:?}; output:\n{:#?}", v.log);
}

/// The viewer of a cluster with no slave shows how to start one; once the
/// master is killed it says it reconnects, and when the master is back (same
/// address, token and identity) it shows frames again without being touched.
#[test]
fn the_viewer_hints_at_slaves_and_survives_a_restart_of_its_master() {
    use util::{Proc, Stream, Transport};
    let (_xvfb, display) = match start_xvfb() {
        Ok(x) => x,
        Err(why) => {
            use std::io::Write;
            let _ = writeln!(std::io::stderr(), "SKIPPED the_viewer_survives_a_restart_of_its_master: {why}");
            return;
        }
    };
    let t = Transport::Tcp;
    let addr = t.free_addr();
    let identity = tempfile::tempdir().unwrap();
    let (identity_args, ticket) = t.prepared_ticket(identity.path(), "tok", &addr);
    let scene = util::scene();
    let start_master = || {
        let mut args = vec!["master", scene.to_str().unwrap(), "--listen", &addr, "--token", "tok"];
        args.extend(t.master_args());
        args.extend(identity_args.iter().map(String::as_str));
        let m = Proc::spawn("master", &args, "info");
        m.wait_for(Stream::Out, "ticket ");
        m
    };
    let mut master = start_master();
    let args: Vec<OsString> = ["view", "--connect", &ticket, "--width", "160", "--height", "120"]
        .into_iter()
        .chain(["--print-frames", "--max-spp", "1"])
        .map(OsString::from)
        .collect();
    let mut v = open_viewer(&display, &args);
    // No slave yet: the window says how to start one.
    let hint = v.wait_line("the no-slaves hint", |l| l.starts_with("notice: no slaves"));
    let hinted = v.log.len();
    assert!(hint.contains("isin slave --connect") && hint.contains(&addr), "{hint}");
    let slave =
        Proc::spawn("slave", &["slave", "--connect", &ticket, "--threads", "1", "--name", "s0"], "info");
    v.wait_line("the first frame", |l| parse_done(l).is_some());
    let line = v.wait_line("a status line", |l| l.starts_with("status: "));
    assert_eq!(parse_status(&line).map(|s| s.live), Some(1), "{line}");
    v.line_since(hinted, "the hint gone once a slave joined", |l| l == "notice: none");

    master.kill9();
    v.wait_line("the viewer saying it reconnects", |l| {
        l.starts_with("notice: lost the master") && l.contains("reconnecting")
    });
    let lost = v.log.len();
    let master = start_master();
    master.wait_for(Stream::Err, "joined with");
    let back = Instant::now();
    let frame = v.wait_line("a frame after the restart", |l| parse_done(l).is_some());
    let took = back.elapsed();
    println!("a frame {took:?} after the slave rejoined: {frame}");
    assert!(took < Duration::from_secs(5), "the viewer took {took:?} to show frames again: {:#?}", v.log);
    let line = v.wait_line("a status line", |l| l.starts_with("status: "));
    let status = parse_status(&line).unwrap_or_else(|| panic!("unparsable status line {line:?}"));
    assert_eq!((status.live, status.dead), (1, 0), "the restarted master's slaves, not stale ones: {line}");
    v.line_since(lost, "the notice cleared", |l| l == "notice: none");
    v.press("Escape");
    let exit = v.wait_exit();
    assert!(exit.success(), "exit status {exit:?}; output:\n{:#?}", v.log);
    drop(slave);
}

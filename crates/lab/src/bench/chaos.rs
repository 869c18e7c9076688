//! `isin bench chaos`: a soak under injected faults. A master and N slave
//! PCs in the lab (network namespaces on one switch, as `isin bench scaling`
//! builds them; one slave behind a 1 Mbit/s cable), a viewer replaying the
//! camera path over and over and a batch job (`isin fly --connect`, one round
//! of frames after another), for a given time, while a seeded schedule
//! ([`faults`]) kills and restarts slaves and the master, stops and continues
//! slaves, unplugs slave cables, makes them lossy and holds their packets.
//!
//! Every frame is checked against a local render of the same camera: the
//! viewer's pixels against an in-process render, the batch job's PNG files
//! byte for byte against `isin fly` without a cluster. A frame is lost when
//! it never completes — a viewer frame within `--frame-timeout` of its first
//! request, re-requested on a new connection whenever the master is lost, as
//! a viewer does; a batch frame whose file is missing when its round ends
//! (the last round is waited for). It reports the faults with their times,
//! the frames requested, completed, identical and lost, the longest frame,
//! the time from each master restart to the next completed frame, the tiles
//! re-rendered, and the processes' resident memory over time ([`rss`]).

pub mod faults;
pub mod rss;
mod summary;

use super::procs::{ChildGuard, start_master, start_slave, wait_joined};
use super::{loadavg, modes, parse_sizes, report};
use crate::client as cluster;
use crate::netlab::{self, Lab, LinkSpec, Support};
use anyhow::Context;
use clap::Args;
use faults::{Fault, FaultKind};
use isin_actors::viewer::{self, ViewerError};
use isin_cluster::auth;
use isin_cluster::scheduler::Work;
use isin_tracer::{Camera, RenderSettings};
use isin_transport::Ticket;
use rss::Sample;
use std::collections::BTreeMap;
use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};
use summary::{BENCH_PROCESS, BatchRound, Injected, ViewerFrame, make_report, markdown, plot};

/// Arguments of `isin bench chaos`.
#[derive(Args, Debug)]
pub struct ChaosArgs {
    /// Scene file (the master's default scene, which the viewer flies through).
    #[arg(long, default_value = "scenes/paper.toml")]
    scene: PathBuf,
    /// Camera path the viewer replays and the batch job renders.
    #[arg(long, default_value = "scenes/paths/paper.toml")]
    path: PathBuf,
    /// Emulated slave PCs (the first one behind the throttled cable).
    #[arg(long, default_value_t = 4)]
    slaves: usize,
    /// Image size of every frame, `WxH` (rendered fast: 1 sample, 1 shadow ray).
    #[arg(long, default_value = "160x120")]
    size: String,
    /// Transport: `tcp` or `quic`.
    #[arg(long, default_value = "tcp")]
    transport: String,
    /// Minutes of soak.
    #[arg(long, conflicts_with = "seconds")]
    minutes: Option<f64>,
    /// Seconds of soak (default: 60).
    #[arg(long)]
    seconds: Option<f64>,
    /// Seed of the fault schedule.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Link rate of every PC's cable, Mbit/s.
    #[arg(long, default_value_t = 100)]
    rate: u32,
    /// Link rate of the first slave's cable, Mbit/s.
    #[arg(long, default_value_t = 1)]
    throttled: u32,
    /// Frames in each round of the batch job (a window of the path, moving on each round).
    #[arg(long, default_value_t = 16)]
    batch_frames: usize,
    /// Seconds a viewer frame may take from its first request before it counts as lost.
    #[arg(long, default_value_t = 30)]
    frame_timeout: u64,
    /// Seconds between memory readings.
    #[arg(long, default_value_t = 2.0)]
    rss_every: f64,
    /// Directory for chaos.json, chaos.md and chaos.svg; also `frames/` (the local
    /// reference, and the batch rounds that lost or changed frames) and `logs/`
    /// (what the master and each slave logged, restarts included).
    #[arg(long = "out", value_name = "DIR", default_value = "target/bench/chaos")]
    out: PathBuf,
}

/// The master and the slaves as they run now (restarts replace them).
struct Procs {
    master: Option<ChildGuard>,
    slaves: Vec<Option<ChildGuard>>,
}

/// What every part of the soak shares.
struct Soak<'a> {
    args: &'a ChaosArgs,
    lab: &'a Lab,
    scene: String,
    ticket: Ticket,
    token: String,
    master_extra: Vec<String>,
    settings: RenderSettings,
    cameras: Vec<Camera>,
    /// In-process renders of `cameras`.
    reference: Vec<Vec<u8>>,
    /// `isin fly` without a cluster: the PNG files of `cameras`.
    reference_png: Vec<Vec<u8>>,
    start: Instant,
    /// Faults end; clients stop asking for more frames.
    deadline: Instant,
    procs: Mutex<Procs>,
    logs: Mutex<Logs>,
    stop: AtomicBool,
}

impl Soak<'_> {
    fn secs(&self, at: Instant) -> f64 {
        at.saturating_duration_since(self.start).as_secs_f64()
    }

    fn now(&self) -> f64 {
        self.secs(Instant::now())
    }

    /// Kills `child` and keeps what it logged.
    fn keep_logs(&self, name: &str, child: Option<ChildGuard>) {
        if let Some(mut c) = child {
            let _ = c.child.kill();
            let _ = c.child.wait();
            // Give the log reader a moment to pass on the last lines.
            std::thread::sleep(Duration::from_millis(20));
            self.logs.lock().unwrap_or_else(|e| e.into_inner()).keep(name, &c);
        }
    }

    fn start_master(&self) -> anyhow::Result<ChildGuard> {
        let (m, ticket) = launch_master(self.lab, &self.scene, &self.token, &self.master_extra)?;
        anyhow::ensure!(
            ticket.to_string() == self.ticket.to_string(),
            "the restarted master printed another ticket: {ticket} (was {})",
            self.ticket
        );
        Ok(m)
    }

    fn start_slave(&self, i: usize) -> anyhow::Result<ChildGuard> {
        launch_slave(self.lab, i, &self.ticket)
    }
}

/// The master in its namespace, on a fixed port (a restart listens where
/// its predecessor did).
fn launch_master(
    lab: &Lab,
    scene: &str,
    token: &str,
    extra: &[String],
) -> anyhow::Result<(ChildGuard, Ticket)> {
    let listen = format!("{}:7878", lab.master().addr);
    start_master(Some(&lab.master().ns), None, scene, &listen, token, extra)
}

/// Slave `i` (0-based) in its namespace, one render thread, named `pcN`.
fn launch_slave(lab: &Lab, i: usize, ticket: &Ticket) -> anyhow::Result<ChildGuard> {
    let ns = &lab.slave(i).context("no such slave")?.ns;
    start_slave(Some(ns), None, ticket, 1, &format!("pc{}", i + 1), &[])
}

/// Runs `isin bench chaos`.
pub fn run(args: ChaosArgs) -> anyhow::Result<()> {
    let seconds = args.minutes.map_or(args.seconds.unwrap_or(60.0), |m| m * 60.0);
    anyhow::ensure!(seconds >= 10.0, "a soak takes at least 10 seconds");
    anyhow::ensure!(args.slaves >= 1, "--slaves must be at least 1");
    modes::check_transports(std::slice::from_ref(&args.transport))?;
    let support = Support::probe();
    if let (Err(e), _) | (_, Err(e)) = (&support.netns, &support.loss) {
        anyhow::bail!("isin bench chaos needs the lab (root, `ip netns`, `tc`, `nft`): {e}");
    }
    let (w, h) = *parse_sizes(&args.size)?.first().context("no size")?;
    let path = isin_viewer::CameraPath::load(&args.path)?;
    anyhow::ensure!(!path.frames.is_empty(), "{} has no cameras", args.path.display());
    let (scene_data, _) = cluster::load_scene_file(&args.scene)?;
    let mut settings = scene_data.settings.resized(Some(w), Some(h));
    // As `isin fly --fast` renders: the soak stresses the cluster, not the tracer.
    (settings.spp, settings.light_samples) = (1, 1);
    let aspect = settings.width as f32 / settings.height as f32;
    let cameras: Vec<Camera> = path.frames.iter().map(|f| f.camera().fit_aspect(aspect)).collect();
    let scene = args.scene.to_str().context("scene path is not UTF-8")?.to_string();
    let frames_dir = args.out.join("frames");
    let _ = std::fs::remove_dir_all(&frames_dir);
    let _ = std::fs::remove_dir_all(args.out.join("logs"));
    println!("chaos: local reference of {} cameras at {w}x{h}", cameras.len());
    let reference: Vec<Vec<u8>> = cameras
        .iter()
        .map(|c| isin_tracer::render_frame(&scene_data, c, &settings, 32, &|_| {}).rgb)
        .collect();
    let reference_png = local_fly(&args, &scene, &frames_dir.join("reference"), cameras.len())?;

    netlab::install_signal_cleanup()?;
    netlab::cleanup_stale();
    let lab = Lab::new(args.slaves, LinkSpec { rate_mbit: Some(args.rate), loss_per_mille: 0 })?;
    lab.set_rate(lab.slave(0).context("no slave")?, Some(args.throttled))?;
    let state = args.out.join("master");
    let _ = std::fs::remove_dir_all(&state);
    let mut master_extra = modes::master_args(&args.transport, "auto");
    for (flag, dir) in [("--identity", "identity"), ("--state", "state")] {
        master_extra.extend([flag.to_string(), state.join(dir).display().to_string()]);
    }
    let token = auth::generate_token()?;
    let loadavg_before = loadavg();
    let (master, ticket) = launch_master(&lab, &scene, &token, &master_extra)?;
    let mut slaves =
        (0..args.slaves).map(|i| launch_slave(&lab, i, &ticket)).collect::<anyhow::Result<Vec<_>>>()?;
    wait_joined(&master, &mut slaves, Duration::from_secs(60))?;
    println!(
        "chaos: {} s over {} with {} slaves (pc1 on {} Mbit/s, the others on {} Mbit/s), seed {}",
        seconds, args.transport, args.slaves, args.throttled, args.rate, args.seed
    );
    let plan = faults::schedule(args.seed, seconds, args.slaves);
    let start = Instant::now();
    let soak = Soak {
        args: &args,
        lab: &lab,
        scene,
        ticket,
        token,
        master_extra,
        settings,
        cameras,
        reference,
        reference_png,
        start,
        deadline: start + Duration::from_secs_f64(seconds),
        procs: Mutex::new(Procs { master: Some(master), slaves: slaves.into_iter().map(Some).collect() }),
        logs: Mutex::new(Logs { dir: args.out.join("logs"), files: BTreeMap::new() }),
        stop: AtomicBool::new(false),
    };
    let (injected, viewer_frames, rounds, series) = std::thread::scope(|s| {
        let sampler = s.spawn(|| sample_rss(&soak));
        let viewer = s.spawn(|| viewer_loop(&soak));
        let batch = s.spawn(|| batch_loop(&soak, &frames_dir));
        let injected = inject(&soak, &plan);
        let viewer = viewer.join().unwrap_or_else(|_| Err(anyhow::anyhow!("the viewer panicked")));
        let batch = batch.join().unwrap_or_else(|_| Err(anyhow::anyhow!("the batch job panicked")));
        soak.stop.store(true, Ordering::Relaxed);
        let series = sampler.join().unwrap_or_default();
        anyhow::Ok((injected, viewer?, batch?, series))
    })?;
    let wall = soak.now();
    let procs = std::mem::replace(
        &mut *soak.procs.lock().unwrap_or_else(|e| e.into_inner()),
        Procs { master: None, slaves: Vec::new() },
    );
    soak.keep_logs("master", procs.master);
    for (i, s) in procs.slaves.into_iter().enumerate() {
        soak.keep_logs(&format!("pc{}", i + 1), s);
    }
    drop(soak);
    drop(lab);
    let report =
        make_report(&args, (w, h), seconds, wall, injected, viewer_frames, rounds, series, loadavg_before);
    let md = markdown(&report);
    report::write_outputs(&args.out, "chaos", &report, true, &md, |p| plot(p, &report))?;
    Ok(())
}

/// `isin fly` of every camera without a cluster, into `dir`: the PNG files.
fn local_fly(args: &ChaosArgs, scene: &str, dir: &Path, n: usize) -> anyhow::Result<Vec<Vec<u8>>> {
    let exe = std::env::current_exe()?;
    let out = std::process::Command::new(exe)
        .args(["fly", scene, "--path"])
        .arg(&args.path)
        .arg("--out-dir")
        .arg(dir)
        .args(fly_size_args(args)?)
        .output()
        .context("cannot run isin fly")?;
    anyhow::ensure!(out.status.success(), "isin fly failed: {}", String::from_utf8_lossy(&out.stderr));
    (0..n).map(|i| std::fs::read(frame_file(dir, i)).context("a reference frame is missing")).collect()
}

fn fly_size_args(args: &ChaosArgs) -> anyhow::Result<Vec<String>> {
    let (w, h) = *parse_sizes(&args.size)?.first().context("no size")?;
    Ok(vec!["--width".into(), w.to_string(), "--height".into(), h.to_string(), "--fast".into()])
}

fn frame_file(dir: &Path, i: usize) -> PathBuf {
    dir.join(format!("frame_{i:04}.png"))
}

/// Runs the schedule: each fault at its time, undone after its span.
fn inject(soak: &Soak, plan: &[Fault]) -> Vec<Injected> {
    let mut out = Vec::new();
    for f in plan {
        let at = soak.start + Duration::from_secs_f64(f.at);
        std::thread::sleep(at.saturating_duration_since(Instant::now()));
        let began = soak.now();
        let mut master_started = None;
        let result = apply(soak, f, &mut master_started);
        // One line, for the log and the report's table.
        let error = result
            .err()
            .map(|e| format!("{e:#}").split_whitespace().collect::<Vec<_>>().join(" ").replace('|', "/"));
        println!(
            "{began:7.1} s  {}{}{} for {:.2} s{}",
            f.kind.describe(),
            f.slave.map(|i| format!(" pc{}", i + 1)).unwrap_or_default(),
            if f.loss_per_mille > 0 {
                format!(" ({:.1} %)", f.loss_per_mille as f64 / 10.0)
            } else {
                String::new()
            },
            f.secs,
            error.as_ref().map(|e| format!(" — failed: {e}")).unwrap_or_default()
        );
        out.push(Injected { fault: f.clone(), began, master_started, error });
    }
    std::thread::sleep(soak.deadline.saturating_duration_since(Instant::now()));
    out
}

fn apply(soak: &Soak, f: &Fault, master_started: &mut Option<f64>) -> anyhow::Result<()> {
    let span = Duration::from_secs_f64(f.secs);
    let procs = || soak.procs.lock().unwrap_or_else(|e| e.into_inner());
    let slave = f.slave.unwrap_or(0);
    let host = soak.lab.slave(slave).context("no such slave")?;
    match f.kind {
        FaultKind::SlaveKill => {
            // Dropping the guard kills it (SIGKILL) and reaps it.
            let gone = procs().slaves[slave].take();
            soak.keep_logs(&format!("pc{}", slave + 1), gone);
            std::thread::sleep(span);
            let s = soak.start_slave(slave)?;
            procs().slaves[slave] = Some(s);
        }
        FaultKind::SlaveStop => {
            let pid = procs().slaves[slave].as_ref().map(ChildGuard::pid).context("slave not running")?;
            signal(pid, libc::SIGSTOP);
            std::thread::sleep(span);
            signal(pid, libc::SIGCONT);
        }
        FaultKind::MasterKill => {
            let gone = procs().master.take();
            soak.keep_logs("master", gone);
            std::thread::sleep(span);
            *master_started = Some(soak.now());
            let m = soak.start_master()?;
            procs().master = Some(m);
        }
        FaultKind::LinkDown => {
            soak.lab.set_host_up(host, false)?;
            std::thread::sleep(span);
            soak.lab.set_host_up(host, true)?;
        }
        FaultKind::Loss | FaultKind::DelaySpike => {
            let per_mille = if f.kind == FaultKind::Loss { f.loss_per_mille } else { 1000 };
            soak.lab.set_host_loss(host, per_mille)?;
            std::thread::sleep(span);
            soak.lab.set_host_loss(host, 0)?;
        }
    }
    Ok(())
}

fn signal(pid: u32, sig: libc::c_int) {
    // SAFETY: kill has no memory preconditions; the pid is a child of ours.
    unsafe { libc::kill(pid as libc::pid_t, sig) };
}

/// Reads the processes' memory every `--rss-every` seconds until the soak
/// stops (and drains their logs, kept by the guards until read).
fn sample_rss(soak: &Soak) -> BTreeMap<String, Vec<Sample>> {
    let mut series: BTreeMap<String, Vec<Sample>> = BTreeMap::new();
    let every = Duration::from_secs_f64(soak.args.rss_every.max(0.2));
    let mut next = Instant::now();
    while !soak.stop.load(Ordering::Relaxed) {
        if Instant::now() >= next {
            next += every;
            let t = soak.now();
            let mut pids = vec![(BENCH_PROCESS.to_string(), std::process::id())];
            {
                let p = soak.procs.lock().unwrap_or_else(|e| e.into_inner());
                let mut logs = soak.logs.lock().unwrap_or_else(|e| e.into_inner());
                if let Some(m) = &p.master {
                    logs.keep("master", m);
                    pids.push(("master".into(), m.pid()));
                }
                for (i, s) in p.slaves.iter().enumerate() {
                    if let Some(s) = s {
                        logs.keep(&format!("pc{}", i + 1), s);
                        pids.push((format!("slave pc{}", i + 1), s.pid()));
                    }
                }
            }
            for (name, pid) in pids {
                if let Some(kib) = rss::read_kib(pid) {
                    series.entry(name).or_default().push(Sample { t, kib });
                }
            }
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    series
}

/// The processes' logs, appended to `DIR/NAME.log` (restarts continue the
/// file), read off the guards so that they do not pile up in memory.
struct Logs {
    dir: PathBuf,
    files: BTreeMap<String, Option<std::fs::File>>,
}

impl Logs {
    fn keep(&mut self, name: &str, child: &ChildGuard) {
        use std::io::Write;
        let lines = child.tail(usize::MAX);
        let file = self.files.entry(name.to_string()).or_insert_with(|| {
            std::fs::create_dir_all(&self.dir).ok()?;
            std::fs::File::create(self.dir.join(format!("{name}.log"))).ok()
        });
        if let Some(f) = file {
            for l in lines {
                let _ = writeln!(f, "{l}");
            }
        }
    }
}

/// The viewer: in the master's namespace, one frame at a time along the
/// path, round and round, until the deadline; reconnects and re-requests
/// whenever the master is lost.
fn viewer_loop(soak: &Soak) -> anyhow::Result<Vec<ViewerFrame>> {
    netlab::netns::enter(&soak.lab.master().ns)?;
    actix::System::new().block_on(async {
        let transport = cluster::client_transport(&soak.ticket)?;
        let timeout = Duration::from_secs(soak.args.frame_timeout.max(1));
        let mut conn: Option<(actix::Addr<viewer::ViewerActor>, Events)> = None;
        let mut frames = Vec::new();
        while Instant::now() < soak.deadline {
            let camera = frames.len() % soak.cameras.len();
            let t0 = Instant::now();
            let mut rec = ViewerFrame {
                camera,
                requested: soak.secs(t0),
                done: None,
                attempts: 0,
                identical: None,
                requeued: 0,
                duplicated: 0,
                errors: Vec::new(),
            };
            let mut backoff = Duration::from_millis(100);
            while rec.done.is_none() {
                let left = timeout.saturating_sub(t0.elapsed());
                if left.is_zero() {
                    rec.errors.push(format!("not completed within {timeout:?}"));
                    if let Some((v, _)) = conn.take() {
                        v.do_send(viewer::Disconnect);
                    }
                    break;
                }
                let (v, mut events) = match conn.take() {
                    Some(c) => c,
                    None => match tokio::time::timeout(
                        left,
                        viewer::connect_as(
                            transport.as_ref(),
                            &soak.ticket,
                            "chaos viewer",
                            Work::Interactive,
                        ),
                    )
                    .await
                    {
                        Ok(Ok((v, _, events))) => (v, events),
                        Ok(Err(e)) if e.is_retryable() => {
                            tokio::time::sleep(backoff).await;
                            backoff = (backoff * 2).min(Duration::from_secs(1));
                            continue;
                        }
                        Ok(Err(e)) => anyhow::bail!("the viewer cannot join: {e}"),
                        Err(_) => continue,
                    },
                };
                rec.attempts += 1;
                let got = tokio::time::timeout(
                    left,
                    viewer::collect_frame(&v, &mut events, soak.cameras[camera], soak.settings),
                )
                .await;
                match got {
                    Ok(Ok((frame, stats))) => {
                        rec.done = Some(soak.now());
                        rec.identical = Some(frame.rgb == soak.reference[camera]);
                        (rec.requeued, rec.duplicated) = (stats.requeued, stats.duplicated);
                        conn = Some((v, events));
                    }
                    // The master went away: a new connection, the frame asked again.
                    Ok(Err(ViewerError::Lost(_))) => {}
                    Ok(Err(e)) => {
                        rec.errors.push(e.to_string());
                        v.do_send(viewer::Disconnect);
                        tokio::time::sleep(Duration::from_millis(200)).await;
                    }
                    Err(_) => {
                        // Timed out: the loop gives the frame up.
                        conn = Some((v, events));
                    }
                }
            }
            frames.push(rec);
        }
        if let Some((v, _)) = conn {
            v.do_send(viewer::Disconnect);
        }
        anyhow::Ok(frames)
    })
}

type Events = tokio::sync::mpsc::UnboundedReceiver<viewer::ViewerEvent>;

/// Seconds a batch round started before the deadline may take past it.
const LAST_ROUND_GRACE: Duration = Duration::from_secs(60);

/// The batch job: `isin fly --connect` in the master's namespace, a window
/// of `--batch-frames` of the path per round, the window moving on each
/// round, until the deadline; the round running then is waited for.
fn batch_loop(soak: &Soak, frames_dir: &Path) -> anyhow::Result<Vec<BatchRound>> {
    let exe = std::env::current_exe()?;
    let n = soak.cameras.len();
    let per = soak.args.batch_frames.clamp(1, n);
    let mut rounds = Vec::new();
    while Instant::now() < soak.deadline {
        let k = rounds.len();
        let first = (k * per) % n;
        let frames = per.min(n - first);
        let dir = frames_dir.join(format!("round_{k:04}"));
        let mut args: Vec<String> = vec!["fly".into(), soak.scene.clone(), "--path".into()];
        args.push(soak.args.path.display().to_string());
        args.extend(["--out-dir".into(), dir.display().to_string()]);
        args.extend(["--frames".into(), format!("{first}..{}", first + frames)]);
        args.extend(["--connect".into(), soak.ticket.to_string()]);
        args.extend(fly_size_args(soak.args)?);
        let cmd = netlab::netns::command(Some(&soak.lab.master().ns), None, &exe, &args);
        let started = soak.now();
        let (mut fly, stdout) = ChildGuard::spawn_cmd(cmd)?;
        let (tx, done) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in stdout.lines().map_while(Result::ok) {
                if line.starts_with("frame ") && line.contains("done at") && tx.send(Instant::now()).is_err()
                {
                    break;
                }
            }
        });
        let hard_end = soak.deadline.max(Instant::now()) + LAST_ROUND_GRACE;
        let status = loop {
            if let Some(st) = fly.exited() {
                break if st.success() { st.to_string() } else { format!("{st}: {:?}", fly.tail(3)) };
            }
            if Instant::now() >= hard_end {
                break format!("still running {LAST_ROUND_GRACE:?} after the end: killed");
            }
            std::thread::sleep(Duration::from_millis(100));
        };
        drop(fly);
        let done_at: Vec<f64> = done.try_iter().map(|t| soak.secs(t)).collect();
        let (mut written, mut identical) = (0, 0);
        for i in first..first + frames {
            if let Ok(bytes) = std::fs::read(frame_file(&dir, i)) {
                written += 1;
                identical += usize::from(bytes == soak.reference_png[i]);
            }
        }
        // A round that checks out is not kept (a 30-minute soak writes some
        // hundred thousand frames); one that does not stays for a look.
        if written == frames && identical == frames {
            let _ = std::fs::remove_dir_all(&dir);
        }
        rounds.push(BatchRound {
            first,
            frames,
            started,
            ended: soak.now(),
            done_at,
            written,
            identical,
            status,
        });
    }
    Ok(rounds)
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: ChaosArgs,
    }

    fn viewer_frame(requested: f64, done: Option<f64>, identical: bool) -> ViewerFrame {
        ViewerFrame {
            camera: 0,
            requested,
            done,
            attempts: 1,
            identical: done.map(|_| identical),
            requeued: 2,
            duplicated: 1,
            errors: Vec::new(),
        }
    }

    fn injected(kind: FaultKind, began: f64, master_started: Option<f64>) -> Injected {
        Injected {
            fault: Fault { at: began, kind, slave: None, secs: 1.0, loss_per_mille: 0 },
            began,
            master_started,
            error: None,
        }
    }

    #[test]
    fn the_report_counts_lost_and_differing_frames_and_times_the_recoveries() {
        let args = Cli::parse_from(["x", "--seconds", "60"]).args;
        let frames = vec![
            viewer_frame(1.0, Some(1.5), true),
            viewer_frame(1.5, Some(4.5), false),
            viewer_frame(4.5, None, false),
        ];
        let round = BatchRound {
            first: 0,
            frames: 4,
            started: 2.0,
            ended: 9.0,
            done_at: vec![3.0, 3.5, 8.0],
            written: 3,
            identical: 3,
            status: "exit status: 0".into(),
        };
        let faults =
            vec![injected(FaultKind::MasterKill, 2.0, Some(3.2)), injected(FaultKind::SlaveKill, 5.0, None)];
        let growing: Vec<Sample> = (0..60).map(|t| Sample { t: t as f64, kib: 30_000 + 1_000 * t }).collect();
        let steady: Vec<Sample> = (0..60).map(|t| Sample { t: t as f64, kib: 30_000 }).collect();
        let mut series = BTreeMap::from([(BENCH_PROCESS.to_string(), growing.clone())]);
        series.insert("master".into(), steady);
        let r = make_report(
            &args,
            (160, 120),
            60.0,
            61.0,
            faults.clone(),
            frames.clone(),
            vec![round.clone()],
            series.clone(),
            String::new(),
        );
        assert_eq!((r.viewer.requested, r.viewer.completed, r.viewer.identical, r.viewer.lost), (3, 2, 1, 1));
        assert_eq!((r.batch.requested, r.batch.completed, r.batch.identical, r.batch.lost), (4, 3, 3, 1));
        assert!((r.viewer.longest_frame - 3.0).abs() < 1e-9 && (r.batch.longest_frame - 4.5).abs() < 1e-9);
        assert_eq!(r.lost(), 2);
        assert!(!r.all_identical());
        // Restarted at 3.2 s: the next frame completed is the batch's at 3.5 s.
        assert!(r.recoveries[0].seconds.is_some_and(|s| (s - 0.3).abs() < 1e-9), "{:?}", r.recoveries);
        assert_eq!((r.tiles_requeued, r.tiles_duplicated), (6, 3));
        assert_eq!(r.fault_counts[&FaultKind::MasterKill], 1);
        assert!(r.rss_flat, "the bench's own memory is not judged");
        assert_eq!(r.viewer_frames.len(), 2, "the differing and the lost frame are kept");
        assert_eq!((r.batch_rounds, r.rounds.len()), (1, 1), "a round with a frame lost is kept");
        series.insert("slave pc1".into(), growing);
        let grows =
            make_report(&args, (160, 120), 60.0, 61.0, faults, frames, vec![round], series, String::new());
        assert!(!grows.rss_flat, "30 → 89 MiB grows");
        assert!(markdown(&grows).contains("| slave pc1 | 29.3 | 86.9 | 86.9 | 58.6 → 86.9 | grows |"));
        let md = markdown(&r);
        assert!(md.contains("| viewer | 3 | 2 | 1 | 1 | 3.00 |"), "{md}");
        assert!(md.contains("**2 frames lost; SOME FRAMES DIFFER; memory flat.**"), "{md}");
        assert!(md.contains("| master killed (-9) and restarted | 1 |"), "{md}");
        assert!(
            md.contains("| 2.0 | master killed (-9) and restarted | master | 1.00 |  | 0.30 |  |"),
            "{md}"
        );
        let dir = tempfile::tempdir().unwrap();
        plot(&dir.path().join("chaos.svg"), &r).unwrap();
    }

    #[test]
    fn minutes_and_seconds_exclude_each_other() {
        assert!(Cli::try_parse_from(["x", "--minutes", "5", "--seconds", "60"]).is_err());
        let a = Cli::parse_from(["x", "--minutes", "30", "--transport", "quic"]).args;
        assert_eq!((a.minutes, a.slaves, a.transport.as_str()), (Some(30.0), 4, "quic"));
    }
}

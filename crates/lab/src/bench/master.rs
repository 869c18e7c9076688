//! `isin bench master`: the master alone at a thousand slaves — no tracer, no
//! network. Two measurements:
//!
//! - **The scheduler**, driven directly: `N` slaves, frames queued two
//!   ahead, every assigned tile answered in the order it was handed out (a
//!   virtual clock advancing a microsecond a result). It gives the
//!   scheduler's CPU time per tile (best of three runs).
//! - **The whole master** (core and actor) over the in-memory transport, with
//!   `N` simulated slaves that answer each tile at once with blank pixels
//!   (on a thread of their own) and a viewer replaying frames (on another):
//!   the most tiles per second the master routes, its own thread's CPU time
//!   per tile, memory per slave, and how long it takes to find out that 100
//!   slaves vanished (silent, connections open) and to hand their tiles to
//!   the others — twice: with the master saturated (its inbound queues full
//!   of answers, which the vanished slaves' last ones wait behind), then with
//!   every simulated slave taking `--render-ms` a tile on each of its
//!   threads, as real slaves do, so that the cluster asks for a fraction of
//!   what the master can route.

use super::loadavg;
use super::report;
use anyhow::Context;
use clap::Args;
use isin_actors::client::{self, Join};
use isin_actors::master::{GetDeaths, GetStatus, Master, MasterConfig};
use isin_actors::slave::thread_cpu_time;
use isin_actors::viewer;
use isin_cluster::codec::Codec;
use isin_cluster::protocol::{self, Message, TileResult};
use isin_cluster::scheduler::{Work, workload};
use isin_tracer::{Camera, RenderSettings, SceneBundle};
use isin_transport::mem::MemTransport;
use isin_transport::{Delivery, Ticket, Transport, TransportKind};
use serde::Serialize;
use serde_bytes::ByteBuf;
use std::collections::{BTreeMap, VecDeque};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// Arguments of `isin bench master`.
#[derive(Args, Debug)]
pub struct MasterBenchArgs {
    /// Simulated slaves.
    #[arg(long, default_value_t = 1000)]
    slaves: usize,
    /// Render threads each slave says it has.
    #[arg(long, default_value_t = 2)]
    threads: u32,
    /// Frame size, `WxH`.
    #[arg(long, default_value = "1920x1080")]
    size: String,
    /// Seconds the whole master routes tiles for.
    #[arg(long, default_value_t = 10)]
    seconds: u64,
    /// Slaves that vanish at once after the timed span, and as many more
    /// with the slaves rendering.
    #[arg(long, default_value_t = 100)]
    vanish: usize,
    /// The master's heartbeat timeout in milliseconds.
    #[arg(long, default_value_t = 2000)]
    heartbeat_timeout_ms: u64,
    /// For the second vanishing: milliseconds each simulated slave's thread
    /// takes a tile (1,000 slaves of 2 threads at 20 ms ask for 100,000
    /// tiles a second).
    #[arg(long, default_value_t = 20)]
    render_ms: u64,
    /// Directory for master.json and master.md.
    #[arg(long, value_name = "DIR", default_value = "target/bench")]
    out_dir: PathBuf,
}

#[derive(Serialize)]
struct MasterReport {
    slaves: usize,
    threads: u32,
    width: u32,
    height: u32,
    /// The scheduler alone: tiles handled and nanoseconds per tile.
    scheduler_tiles: u64,
    scheduler_ns_per_tile: f64,
    /// The whole master: tiles routed per second, its thread's CPU per tile.
    routed_tiles: u64,
    routed_per_second: f64,
    master_cpu_us_per_tile: f64,
    master_cpu_share: f64,
    /// Resident memory added per connected slave (master and the slave's
    /// simulation together), bytes.
    rss_per_slave: f64,
    /// From starting the simulated slaves to the master counting them all
    /// joined, s.
    join_s: f64,
    vanished: usize,
    heartbeat_timeout_ms: u64,
    /// With the master saturated: from the slaves going silent to the master
    /// declaring the last of them dead (their tiles handed to others in the
    /// same step), by the master's stamp of that step, ms.
    detect_ms: Option<f64>,
    /// The longest a vanished slave had been silent by the master's clock
    /// (since the last message the master had taken in from it) when it
    /// was declared dead, ms: the timeout plus the master's own lateness;
    /// `detect_ms` adds the time the slaves' last messages waited to be
    /// taken in.
    silence_at_death_ms: Option<f64>,
    /// Milliseconds a simulated slave's thread took a tile for the second
    /// vanishing.
    render_ms: u64,
    /// `detect_ms` with the slaves rendering (`render_ms` a tile).
    rendering_detect_ms: Option<f64>,
    /// `silence_at_death_ms` with the slaves rendering.
    rendering_silence_at_death_ms: Option<f64>,
    /// Tiles routed a second while the slaves rendered.
    rendering_per_second: f64,
    cores: usize,
    loadavg: String,
    unix_time: u64,
}

/// Runs `isin bench master`.
pub fn run(args: MasterBenchArgs) -> anyhow::Result<()> {
    let (w, h) = *super::parse_sizes(&args.size)?.first().context("no size")?;
    anyhow::ensure!(
        args.slaves >= 1 && args.vanish * 2 < args.slaves,
        "--vanish must be below half of --slaves (it happens twice)"
    );
    let (scheduler_tiles, secs) = scheduler_alone(args.slaves, args.threads, w, h, 6);
    println!(
        "scheduler alone, {} slaves × {} threads: {scheduler_tiles} tiles in {:.3} s, {:.0} ns a tile",
        args.slaves,
        args.threads,
        secs,
        secs * 1e9 / scheduler_tiles.max(1) as f64
    );
    let whole = whole_master(&args, w, h)?;
    let report = MasterReport {
        slaves: args.slaves,
        threads: args.threads,
        width: w,
        height: h,
        scheduler_tiles,
        scheduler_ns_per_tile: secs * 1e9 / scheduler_tiles.max(1) as f64,
        routed_tiles: whole.tiles,
        routed_per_second: whole.tiles as f64 / whole.wall,
        master_cpu_us_per_tile: whole.master_cpu * 1e6 / whole.tiles.max(1) as f64,
        master_cpu_share: whole.master_cpu / whole.wall,
        rss_per_slave: whole.rss_per_slave,
        join_s: whole.join.as_secs_f64(),
        vanished: args.vanish,
        heartbeat_timeout_ms: args.heartbeat_timeout_ms,
        detect_ms: whole.detect.map(|(d, _)| d.as_secs_f64() * 1e3),
        silence_at_death_ms: whole.detect.map(|(_, s)| s.as_secs_f64() * 1e3),
        render_ms: args.render_ms,
        rendering_detect_ms: whole.rendering_detect.map(|(d, _)| d.as_secs_f64() * 1e3),
        rendering_silence_at_death_ms: whole.rendering_detect.map(|(_, s)| s.as_secs_f64() * 1e3),
        rendering_per_second: whole.rendering_per_second,
        cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
        loadavg: loadavg(),
        unix_time: report::unix_time(),
    };
    let md = markdown(&report);
    report::write_json_md(&args.out_dir, "master", &report, &md)?;
    Ok(())
}

/// The scheduler alone ([`workload::run`]): tiles handled and seconds of
/// this thread's CPU time, the best of three runs (the first warms the
/// allocator and the caches; on a shared machine wall time counts others'
/// work too).
fn scheduler_alone(slaves: usize, threads: u32, w: u32, h: u32, frames: usize) -> (u64, f64) {
    (0..3)
        .map(|_| {
            let (t0, c0) = (Instant::now(), thread_cpu_time());
            let tiles = workload::run(slaves, threads, w, h, frames);
            let secs = match (c0, thread_cpu_time()) {
                (Some(a), Some(b)) => b.saturating_sub(a),
                _ => t0.elapsed(),
            };
            (tiles, secs.as_secs_f64())
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap_or_default()
}

struct Whole {
    tiles: u64,
    wall: f64,
    master_cpu: f64,
    rss_per_slave: f64,
    join: Duration,
    /// Declared dead after, and silent for by the master's clock.
    detect: Option<(Duration, Duration)>,
    /// The same with the slaves rendering.
    rendering_detect: Option<(Duration, Duration)>,
    rendering_per_second: f64,
}

/// Resident set size of this process, bytes.
fn rss() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let kb = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().split(' ').next()?.parse::<f64>().ok());
    kb.unwrap_or(0.0) * 1024.0
}

fn fake_scene() -> SceneBundle {
    SceneBundle {
        name: "bench.toml".into(),
        source: "a scene no slave renders".into(),
        assets: BTreeMap::new(),
    }
}

/// A slave that answers every tile with blank pixels: at once while `render`
/// is zero, otherwise each of its `threads` taking `render` µs a tile, in the
/// order they came. After `vanish` is set it says nothing more, its
/// connection left open.
async fn sim_slave(
    t: MemTransport,
    ticket: Ticket,
    name: String,
    threads: u32,
    vanish: Arc<AtomicBool>,
    render: Arc<AtomicU64>,
) -> anyhow::Result<()> {
    use tokio::time::Instant;
    let (mut conn, welcome) =
        client::handshake(&t, &ticket, Join::slave(&name, threads, &[], &[Codec::Raw])).await?;
    if let Some(scene) = &welcome.scene {
        isin_actors::slave::receive_scene(&mut conn, scene.hash).await?;
    }
    client::send_message(&conn, &Message::Ready { hash: welcome.scene.map(|s| s.hash) })?;
    let heartbeat = protocol::encode(&Message::Heartbeat)?;
    let mut beat = tokio::time::interval(Duration::from_millis(500));
    // Answers waiting for their render time to pass, soonest first, and when
    // each thread is next free.
    let mut due: VecDeque<(Instant, Vec<u8>)> = VecDeque::new();
    let mut free_at = vec![Instant::now(); threads.max(1) as usize];
    loop {
        let next_due = due.front().map(|&(at, _)| at);
        let frame = tokio::select! {
            f = conn.receiver.recv() => f,
            _ = beat.tick() => {
                if vanish.load(Ordering::Relaxed) {
                    // Silent from now on, the connection still open.
                    std::future::pending::<()>().await;
                }
                let _ = conn.sender.send(heartbeat.clone());
                continue;
            }
            _ = tokio::time::sleep_until(next_due.unwrap_or_else(Instant::now)), if next_due.is_some() => {
                if vanish.load(Ordering::Relaxed) {
                    std::future::pending::<()>().await;
                }
                let now = Instant::now();
                while due.front().is_some_and(|&(at, _)| at <= now) {
                    if let Some((_, answer)) = due.pop_front() {
                        let _ = conn.sender.send_as(answer, Delivery::Independent);
                    }
                }
                continue;
            }
        };
        let Some(Ok(frame)) = frame else { return Ok(()) };
        if vanish.load(Ordering::Relaxed) {
            std::future::pending::<()>().await;
        }
        if let Ok(Message::TileAssignment(a)) = protocol::decode(&frame, protocol::DEFAULT_MAX_FRAME) {
            let render = Duration::from_micros(render.load(Ordering::Relaxed));
            for job in a.tiles {
                let pixels = ByteBuf::from(vec![0u8; job.tile.pixel_count() * 3]);
                let r = TileResult {
                    frame: a.frame,
                    id: job.id,
                    tile: job.tile,
                    render_micros: render.as_micros() as u64,
                    codec: Codec::Raw,
                    pixels,
                };
                let answer = protocol::encode(&Message::TileResult(r))?;
                let Some(thread) = free_at.iter_mut().min().filter(|_| !render.is_zero()) else {
                    let _ = conn.sender.send_as(answer, Delivery::Independent);
                    continue;
                };
                let at = (*thread).max(Instant::now()) + render;
                *thread = at;
                let i = due.partition_point(|&(t, _)| t <= at);
                due.insert(i, (at, answer));
            }
        }
    }
}

/// Silences the slaves of `vanish` and waits (three timeouts at most) for
/// the master to declare them all dead: when it did, by its own stamp, and
/// the longest silence by its clock ([`GetDeaths`]; polled with that cheap
/// query: a full status a millisecond, with its list of 1,000 slaves, would
/// itself keep the master from its work).
fn vanish_and_detect(
    sys: &actix::SystemRunner,
    master: &actix::Addr<Master>,
    vanish: &[Arc<AtomicBool>],
    timeout: Duration,
) -> anyhow::Result<Option<(Duration, Duration)>> {
    let deaths = || sys.block_on(master.send(GetDeaths));
    let deaths0 = deaths()?.count;
    let gone = Instant::now();
    for v in vanish {
        v.store(true, Ordering::Relaxed);
    }
    let limit = gone + timeout * 3;
    while Instant::now() < limit {
        let d = deaths()?;
        if d.count >= deaths0 + vanish.len() as u64 {
            // When the master declared the last of them (and handed back its
            // tiles), by the master's own stamp: this poll answers later.
            let declared = d.last_timeout_death.map_or_else(|| gone.elapsed(), |at| at.duration_since(gone));
            return Ok(Some((declared, d.longest_silence)));
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    Ok(None)
}

fn whole_master(args: &MasterBenchArgs, w: u32, h: u32) -> anyhow::Result<Whole> {
    let t = MemTransport::new();
    let token = "bench".to_string();
    let ticket = Ticket {
        transport: TransportKind::TcpInsecure,
        token: token.clone(),
        addr: "master".into(),
        fingerprint: None,
    };
    // The master on a thread of its own, answering CPU-time questions there.
    let (cpu_tx, mut cpu_rx) = tokio::sync::mpsc::unbounded_channel::<std::sync::mpsc::Sender<f64>>();
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    let (mt, timeout) = (t.clone(), Duration::from_millis(args.heartbeat_timeout_ms));
    std::thread::Builder::new().name("isin-master".into()).spawn(move || {
        actix::System::new().block_on(async move {
            let mut cfg =
                match MasterConfig::new(token, fake_scene(), Camera::default(), RenderSettings::default()) {
                    Ok(c) => c,
                    Err(e) => return drop(ready_tx.send(Err(anyhow::Error::new(e)))),
                };
            cfg.cluster.scheduler.heartbeat_timeout = timeout;
            cfg.cluster.budgets.max_peers = 1 << 16;
            cfg.cluster.budgets.max_handshaking = 1 << 16;
            let listener = match mt.listen("master").await {
                Ok(l) => l,
                Err(e) => return drop(ready_tx.send(Err(e.into()))),
            };
            let addr = match Master::new(cfg) {
                Ok(m) => m.serve(listener),
                Err(e) => return drop(ready_tx.send(Err(e.into()))),
            };
            let _ = ready_tx.send(Ok(addr));
            while let Some(reply) = cpu_rx.recv().await {
                let _ = reply.send(thread_cpu_time().map_or(0.0, |d| d.as_secs_f64()));
            }
        });
    })?;
    let master = ready_rx.recv()??;
    let master_cpu = || -> f64 {
        let (tx, rx) = std::sync::mpsc::channel();
        let _ = cpu_tx.send(tx);
        rx.recv().unwrap_or(0.0)
    };
    let rss0 = rss();
    let joining = Instant::now();
    // The slaves on a thread of their own.
    let vanish: Vec<Arc<AtomicBool>> = (0..args.slaves).map(|_| Arc::new(AtomicBool::new(false))).collect();
    let render = Arc::new(AtomicU64::new(0));
    let st = t.clone();
    let (sticket, svanish, srender, threads) = (ticket.clone(), vanish.clone(), render.clone(), args.threads);
    std::thread::Builder::new().name("isin-sim-slaves".into()).spawn(move || {
        let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().expect("a runtime");
        rt.block_on(async move {
            let local = tokio::task::LocalSet::new();
            local
                .run_until(async move {
                    for (i, v) in svanish.into_iter().enumerate() {
                        let (t, tk, r) = (st.clone(), sticket.clone(), srender.clone());
                        tokio::task::spawn_local(async move {
                            if let Err(e) = sim_slave(t, tk, format!("sim{i}"), threads, v, r).await {
                                tracing::warn!("simulated slave {i}: {e}");
                            }
                        });
                    }
                    std::future::pending::<()>().await;
                })
                .await;
        });
    })?;
    let sys = actix::System::new();
    let status = |m: &actix::Addr<Master>| sys.block_on(m.send(GetStatus));
    let deadline = Instant::now() + Duration::from_secs(120);
    while status(&master)?.slaves.len() < args.slaves {
        anyhow::ensure!(Instant::now() < deadline, "the simulated slaves did not all join within 2 minutes");
        std::thread::sleep(Duration::from_millis(20));
    }
    let join = joining.elapsed();
    let rss_per_slave = (rss() - rss0) / args.slaves as f64;
    println!(
        "{} simulated slaves joined in {:.2} s ({:.1} kB each)",
        args.slaves,
        join.as_secs_f64(),
        rss_per_slave / 1e3
    );
    // The viewer: frames queued three ahead, for the timed span.
    let routed = Arc::new(AtomicU64::new(0));
    let stop = Arc::new(AtomicBool::new(false));
    let (vt, vticket, vrouted, vstop) = (t.clone(), ticket.clone(), routed.clone(), stop.clone());
    let viewer_thread = std::thread::Builder::new().name("isin-bench-viewer".into()).spawn(
        move || -> anyhow::Result<()> {
            actix::System::new().block_on(async move {
                let (v, _, mut events) =
                    viewer::connect_as(&vt, &vticket, "bench", Work::Interactive).await?;
                let settings = RenderSettings { width: w, height: h, spp: 1, ..RenderSettings::default() };
                let cameras: Vec<Camera> = (0..100_000).map(|_| Camera::default()).collect();
                let run =
                    viewer::collect_frames(&v, &mut events, &cameras, None, settings, 3, |_, _, stats| {
                        vrouted.fetch_add(u64::from(stats.tiles), Ordering::Relaxed);
                        if vstop.load(Ordering::Relaxed) { anyhow::bail!("stopped") } else { anyhow::Ok(()) }
                    });
                let _ = run.await;
                anyhow::Ok(())
            })
        },
    )?;
    // Warm-up: the first frames.
    while routed.load(Ordering::Relaxed) == 0 {
        std::thread::sleep(Duration::from_millis(5));
    }
    let (tiles0, cpu0, t0) = (routed.load(Ordering::Relaxed), master_cpu(), Instant::now());
    std::thread::sleep(Duration::from_secs(args.seconds.max(1)));
    let (tiles, cpu, wall) =
        (routed.load(Ordering::Relaxed) - tiles0, master_cpu() - cpu0, t0.elapsed().as_secs_f64());
    println!(
        "routed {tiles} tiles in {wall:.1} s: {:.0} tiles/s, master thread {:.2} µs CPU a tile",
        tiles as f64 / wall,
        cpu * 1e6 / tiles.max(1) as f64
    );
    // 100 slaves vanish at once: how long until the master knows, saturated.
    let timeout = Duration::from_millis(args.heartbeat_timeout_ms);
    let (first, second) = vanish.split_at(args.vanish);
    let detect = vanish_and_detect(&sys, &master, first, timeout)?;
    // Again with the slaves rendering, once their answers come at that pace.
    render.store(args.render_ms * 1000, Ordering::Relaxed);
    std::thread::sleep(Duration::from_secs(1));
    let (tiles0, t0) = (routed.load(Ordering::Relaxed), Instant::now());
    std::thread::sleep(Duration::from_secs(2));
    let rendering_per_second = (routed.load(Ordering::Relaxed) - tiles0) as f64 / t0.elapsed().as_secs_f64();
    let rendering_detect = vanish_and_detect(&sys, &master, &second[..args.vanish], timeout)?;
    stop.store(true, Ordering::Relaxed);
    let _ = viewer_thread.join();
    Ok(Whole {
        tiles,
        wall,
        master_cpu: cpu,
        rss_per_slave,
        join,
        detect,
        rendering_detect,
        rendering_per_second,
    })
}

fn markdown(r: &MasterReport) -> String {
    let detect = |d: Option<f64>, s: Option<f64>| match (d, s) {
        (Some(d), Some(s)) => format!("{d:.0} ms (silent {s:.0} ms by the master's clock)"),
        _ => "not within 3 timeouts".to_string(),
    };
    format!(
        "The master at {} simulated slaves ({} threads each), {}x{} frames:\n\n\
         | measure | value |\n|---|---:|\n\
         | scheduler CPU per tile | {:.0} ns |\n\
         | tiles routed per second (whole master, one thread) | {:.0} |\n\
         | master thread CPU per tile | {:.2} µs |\n\
         | master thread busy | {:.0} % |\n\
         | memory per slave (master + its simulation) | {:.1} kB |\n\
         | all slaves joined in | {:.2} s |\n\
         | {} slaves vanish, master saturated: declared dead after (timeout {} ms) | {} |\n\
         | tiles routed per second, slaves rendering {} ms a tile | {:.0} |\n\
         | {} more vanish, slaves rendering: declared dead after | {} |\n",
        r.slaves,
        r.threads,
        r.width,
        r.height,
        r.scheduler_ns_per_tile,
        r.routed_per_second,
        r.master_cpu_us_per_tile,
        r.master_cpu_share * 100.0,
        r.rss_per_slave / 1e3,
        r.join_s,
        r.vanished,
        r.heartbeat_timeout_ms,
        detect(r.detect_ms, r.silence_at_death_ms),
        r.render_ms,
        r.rendering_per_second,
        r.vanished,
        detect(r.rendering_detect_ms, r.rendering_silence_at_death_ms),
    )
}

//! `isin bench cluster`: frames per second through a real cluster (a master
//! and 1 or 2 slave processes on loopback) against in-process rendering with
//! the same number of render threads, bytes on the wire per frame, and the
//! time from a slave's `kill -9` to its tiles being handed to another slave.

use super::procs::{ChildGuard, cpu_secs, start_master};
use super::{loadavg, parse_list};
use crate::client as cluster;
use crate::client::load_scene_file;
use anyhow::Context;
use clap::Args;
use isin_actors::viewer;
use isin_cluster::auth;
use isin_transport::Ticket;
use serde::Serialize;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Arguments of `isin bench cluster`.
#[derive(Args, Debug)]
pub struct ClusterBenchArgs {
    /// Scene file.
    #[arg(long, default_value = "scenes/paper.toml")]
    scene: PathBuf,
    /// Timed frames per configuration (after one warm-up frame).
    #[arg(long, default_value_t = 10)]
    frames: u32,
    /// Image sizes, `WxH` comma-separated.
    #[arg(long, default_value = "320x240,640x480")]
    sizes: String,
    /// Slave process counts, comma-separated.
    #[arg(long, default_value = "1,2")]
    slaves: String,
    /// Total render threads (split among the slaves; the in-process baseline uses as many).
    #[arg(long)]
    threads: Option<usize>,
    /// Where to write the JSON results.
    #[arg(short, long = "output", alias = "out", value_name = "FILE", default_value = "bench-cluster.json")]
    out: PathBuf,
}

#[derive(Serialize)]
struct Row {
    width: u32,
    height: u32,
    slaves: usize,
    threads_per_slave: usize,
    inprocess_fps: f64,
    cluster_fps: f64,
    efficiency: f64,
    /// CPU seconds per frame, in-process (the bench process).
    inprocess_cpu_s_per_frame: f64,
    /// CPU seconds per frame, cluster (master + slaves + the viewer in the bench process).
    cluster_cpu_s_per_frame: f64,
    /// `inprocess_cpu / cluster_cpu`: the cluster's overhead, insensitive to other load on the machine.
    cpu_efficiency: f64,
    bytes_per_frame_slaves_to_master: f64,
    bytes_per_frame_master_to_viewer: f64,
    raw_rgb_bytes_per_frame: u64,
}

#[derive(Serialize)]
struct KillResult {
    width: u32,
    height: u32,
    /// From `kill -9` to the master logging the slave dead.
    kill_to_death_ms: f64,
    /// From `kill -9` to the master logging its tiles handed to another slave.
    kill_to_reassigned_ms: f64,
    /// Tiles the dead slave held.
    requeued: u32,
}

#[derive(Serialize)]
struct Report {
    scene: String,
    cores: usize,
    threads: usize,
    frames: u32,
    transport: &'static str,
    /// `/proc/loadavg` before and after: wall-clock figures mean little on a busy machine.
    loadavg_before: String,
    loadavg_after: String,
    rows: Vec<Row>,
    kill: Option<KillResult>,
}

/// Runs `isin bench cluster`.
pub(super) fn run_cluster(args: ClusterBenchArgs) -> anyhow::Result<()> {
    let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
    let threads = args.threads.unwrap_or(cores).max(1);
    let sizes: Vec<(u32, u32)> = args
        .sizes
        .split(',')
        .map(|s| {
            let (w, h) = s.trim().split_once('x').context("size must be WxH")?;
            Ok((w.parse()?, h.parse()?))
        })
        .collect::<anyhow::Result<_>>()?;
    let slave_counts: Vec<usize> = parse_list(&args.slaves)?;
    let (scene, _) = load_scene_file(&args.scene)?;
    let scene_arg = args.scene.to_str().context("scene path is not UTF-8")?.to_string();

    let loadavg_before = loadavg();
    let scene = Arc::new(scene);
    let pool = Arc::new(rayon::ThreadPoolBuilder::new().num_threads(threads).build()?);
    let frames = args.frames.max(1);
    let rows = actix::System::new().block_on(async {
        let mut rows = Vec::new();
        for &(w, h) in &sizes {
            rows.extend(bench_size(&scene, &scene_arg, &pool, threads, &slave_counts, w, h, frames).await?);
        }
        anyhow::Ok(rows)
    })?;
    let (kw, kh) = *sizes.last().context("no sizes")?;
    let kill = match kill_latency(&scene_arg, threads, kw, kh) {
        Ok(k) => {
            println!(
                "kill -9 of a slave at {kw}x{kh}: declared dead after {:.1} ms, {} tiles reassigned after {:.1} ms",
                k.kill_to_death_ms, k.requeued, k.kill_to_reassigned_ms
            );
            Some(k)
        }
        Err(e) => {
            println!("kill measurement failed: {e:#}");
            None
        }
    };
    let report = Report {
        scene: scene_arg,
        cores,
        threads,
        frames: args.frames,
        transport: "tcp",
        loadavg_before,
        loadavg_after: loadavg(),
        rows,
        kill,
    };
    std::fs::write(&args.out, serde_json::to_string_pretty(&report)?)
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    println!("wrote {}", args.out.display());
    Ok(())
}

/// Starts a master and `n` slave processes; returns the guards and the ticket.
fn start_cluster(scene: &str, n: usize, per: usize) -> anyhow::Result<(ChildGuard, Vec<ChildGuard>, Ticket)> {
    let token = auth::generate_token()?;
    let (master, ticket) = start_master(None, None, scene, "127.0.0.1:0", &token, &[])?;
    let mut slaves = Vec::new();
    let per_s = per.to_string();
    for i in 0..n {
        let name = format!("bench{i}");
        let (s, _) = ChildGuard::spawn(&[
            "slave",
            "--connect",
            &ticket.to_string(),
            "--threads",
            &per_s,
            "--name",
            &name,
        ])?;
        slaves.push(s);
    }
    for _ in 0..n {
        master.wait_for("joined with", Duration::from_secs(60))?;
    }
    Ok((master, slaves, ticket))
}

/// A running cluster under test and what was measured on it.
struct Bench {
    slaves: usize,
    per: usize,
    pids: Vec<String>,
    viewer: actix::Addr<viewer::ViewerActor>,
    events: tokio::sync::mpsc::UnboundedReceiver<viewer::ViewerEvent>,
    camera: isin_tracer::Camera,
    secs: f64,
    cpu: f64,
    bytes_in: u64,
    _guards: (ChildGuard, Vec<ChildGuard>),
}

/// One image size: the in-process baseline and every cluster setup, their
/// frames interleaved (baseline, cluster 1, cluster 2, baseline, …) so that
/// whatever else loads the machine weighs on all of them alike.
#[allow(clippy::too_many_arguments)]
async fn bench_size(
    scene: &Arc<isin_tracer::Scene>,
    scene_arg: &str,
    pool: &Arc<rayon::ThreadPool>,
    threads: usize,
    slave_counts: &[usize],
    w: u32,
    h: u32,
    frames: u32,
) -> anyhow::Result<Vec<Row>> {
    let mut settings = scene.settings;
    settings.width = w;
    settings.height = h;
    let mut benches = Vec::new();
    for &n in slave_counts {
        let per = (threads / n).max(1);
        let (master, slaves, ticket) = start_cluster(scene_arg, n, per)?;
        let pids = std::iter::once(&master)
            .chain(&slaves)
            .map(|g| g.child.id().to_string())
            .chain(["self".to_string()])
            .collect();
        let transport = cluster::client_transport(&ticket)?;
        let (v, info, events) = viewer::connect(transport.as_ref(), &ticket, "bench").await?;
        let info = info.context("the master serves no scene")?;
        benches.push(Bench {
            slaves: n,
            per,
            pids,
            viewer: v,
            events,
            camera: info.camera,
            secs: 0.0,
            cpu: 0.0,
            bytes_in: 0,
            _guards: (master, slaves),
        });
    }
    let local = || {
        let (scene, pool) = (scene.clone(), pool.clone());
        tokio::task::spawn_blocking(move || {
            let (t0, c0) = (Instant::now(), cpu_secs("self"));
            pool.install(|| isin_tracer::render_frame(&scene, &scene.camera, &settings, 32, &|_| {}));
            (t0.elapsed().as_secs_f64(), cpu_secs("self") - c0)
        })
    };
    // Warm-up: one frame of each.
    local().await?;
    for b in &mut benches {
        viewer::collect_frame(&b.viewer, &mut b.events, b.camera, settings).await?;
    }
    let mut wire_before = Vec::new();
    for b in &benches {
        wire_before.push(b.viewer.send(viewer::GetWireStats).await?.bytes_received);
    }
    let (mut local_secs, mut local_cpu) = (0.0, 0.0);
    for _ in 0..frames {
        let (s, c) = local().await?;
        local_secs += s;
        local_cpu += c;
        for b in &mut benches {
            let cpu = |pids: &[String]| pids.iter().map(|p| cpu_secs(p)).sum::<f64>();
            let (t0, c0) = (Instant::now(), cpu(&b.pids));
            let (_, stats) = viewer::collect_frame(&b.viewer, &mut b.events, b.camera, settings).await?;
            b.secs += t0.elapsed().as_secs_f64();
            b.cpu += cpu(&b.pids) - c0;
            b.bytes_in += stats.bytes_in;
        }
    }
    let n = frames as f64;
    let (inprocess_fps, inprocess_cpu) = (n / local_secs, local_cpu / n);
    println!(
        "{w}x{h} in-process, {threads} threads: {inprocess_fps:.2} frames/s, {inprocess_cpu:.3} CPU s/frame"
    );
    let mut rows = Vec::new();
    for (b, before) in benches.iter().zip(wire_before) {
        let after = b.viewer.send(viewer::GetWireStats).await?.bytes_received;
        let (fps, cpu) = (n / b.secs, b.cpu / n);
        let row = Row {
            width: w,
            height: h,
            slaves: b.slaves,
            threads_per_slave: b.per,
            inprocess_fps,
            cluster_fps: fps,
            efficiency: fps / inprocess_fps,
            inprocess_cpu_s_per_frame: inprocess_cpu,
            cluster_cpu_s_per_frame: cpu,
            cpu_efficiency: inprocess_cpu / cpu,
            bytes_per_frame_slaves_to_master: b.bytes_in as f64 / n,
            bytes_per_frame_master_to_viewer: (after - before) as f64 / n,
            raw_rgb_bytes_per_frame: w as u64 * h as u64 * 3,
        };
        println!(
            "{w}x{h} cluster, {} slave(s) × {} threads: {fps:.2} frames/s, efficiency {:.3}, \
             {cpu:.3} CPU s/frame (CPU efficiency {:.3}), {:.0} kB/frame slaves→master, \
             {:.0} kB/frame master→viewer",
            b.slaves,
            b.per,
            row.efficiency,
            row.cpu_efficiency,
            row.bytes_per_frame_slaves_to_master / 1e3,
            row.bytes_per_frame_master_to_viewer / 1e3
        );
        rows.push(row);
    }
    Ok(rows)
}

/// Renders frames continuously through 2 slaves, kills one mid-frame, and
/// times the master's reaction from its log lines.
fn kill_latency(scene: &str, threads: usize, w: u32, h: u32) -> anyhow::Result<KillResult> {
    let per = (threads / 2).max(1);
    let (master, mut slaves, ticket) = start_cluster(scene, 2, per)?;
    let transport = cluster::client_transport(&ticket)?;
    let viewer_thread = std::thread::spawn(move || {
        actix::System::new().block_on(async move {
            let (v, info, mut events) = viewer::connect(transport.as_ref(), &ticket, "bench").await?;
            let info = info.context("the master serves no scene")?;
            let mut settings = info.settings;
            settings.width = w;
            settings.height = h;
            for _ in 0..4 {
                viewer::collect_frame(&v, &mut events, info.camera, settings).await?;
            }
            anyhow::Ok(())
        })
    });
    // Kill during the second frame, shortly after it was requested.
    master.wait_for("frame done", Duration::from_secs(120))?;
    let victim = slaves.remove(1);
    let mut victim = victim;
    let t_kill = Instant::now();
    victim.child.kill()?;
    let (t_dead, dead) = master.wait_for("dead (", Duration::from_secs(60))?;
    let requeued =
        dead.split("; ").nth(1).and_then(|s| s.split(' ').next()).and_then(|n| n.parse().ok()).unwrap_or(0);
    let t_re = if requeued > 0 { master.wait_for("reassigned", Duration::from_secs(60))?.0 } else { t_dead };
    viewer_thread.join().map_err(|_| anyhow::anyhow!("viewer thread panicked"))??;
    Ok(KillResult {
        width: w,
        height: h,
        kill_to_death_ms: (t_dead - t_kill).as_secs_f64() * 1e3,
        kill_to_reassigned_ms: (t_re - t_kill).as_secs_f64() * 1e3,
        requeued,
    })
}

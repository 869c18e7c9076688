//! `isin bench transports`: TCP against QUIC, per compression mode, on
//! loopback and on the lab's emulated LAN at 100 Mbit/s and 1 Gbit/s with 0 %,
//! 0.1 % and 1 % random loss.
//!
//! Two kinds of run, labelled apart because they answer different questions:
//! - **traced**: the slaves really render every tile (on this 2-core machine the
//!   tracer is the limit, not the network);
//! - **cached**: the slaves serve real rendered tiles from a warm frame cache
//!   (`isin slave --cache-tiles DIR`: every camera of the path rendered once,
//!   then the path replayed), so frames/s is what master, transport and link
//!   sustain with real pixel data.
//!
//! Per run: frames/s (frames requested one after another), bytes per frame
//! received by the master as counted by the transport and on the master's
//! interface (the lab only; the two should agree within the protocol
//! headers), tile latency (from the frame request to each tile reaching the
//! viewer, p50/p99), the round trip of a one-tile frame on the idle cluster
//! (p50/p99), and CPU seconds per frame of the master and of all slaves.

use super::modes;
use super::procs::{ChildGuard, cpu_secs, start_master, start_slave, wait_joined};
use super::report::{self, Series, quantile};
use super::{loadavg, parse_list, parse_sizes};
use crate::client as cluster;
use crate::netlab::{self, Lab, LinkSpec, Support};
use anyhow::Context;
use clap::Args;
use isin_actors::viewer::{self, RequestFrame, ViewerEvent};
use isin_cluster::auth;
use isin_tracer::{Camera, RenderSettings};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Arguments of `isin bench transports`.
#[derive(Args, Debug)]
pub struct TransportsArgs {
    /// Scene file.
    #[arg(long, default_value = "scenes/paper.toml")]
    scene: PathBuf,
    /// Camera path replayed.
    #[arg(long, default_value = "scenes/paths/paper.toml")]
    path: PathBuf,
    /// Image size, `WxH`.
    #[arg(long, default_value = "640x480")]
    size: String,
    /// Transports, comma-separated.
    #[arg(long, default_value = "tcp,quic")]
    transports: String,
    /// Compression modes, comma-separated (default: every mode this build can run).
    #[arg(long)]
    compression: Option<String>,
    /// Conditions: `loopback` or `RATE_MBIT:LOSS_PER_MILLE`, comma-separated.
    #[arg(long, default_value = "loopback,100:0,100:1,100:10,1000:0,1000:1,1000:10")]
    conditions: String,
    /// Kinds of run: `traced` (slaves render), `cached` (slaves serve a warm frame cache).
    #[arg(long, default_value = "cached,traced")]
    kinds: String,
    /// Slave processes.
    #[arg(long, default_value_t = 2)]
    slaves: usize,
    /// Render threads per slave.
    #[arg(long, default_value_t = 1)]
    threads: usize,
    /// Timed frames per cached run (cycling through the path's cameras).
    #[arg(long, default_value_t = 48)]
    frames: usize,
    /// Timed frames per traced run.
    #[arg(long, default_value_t = 6)]
    traced_frames: usize,
    /// Distinct cameras of the path used (evenly spaced).
    #[arg(long, default_value_t = 16)]
    cameras: usize,
    /// One-tile frames timed per run for the round trip.
    #[arg(long, default_value_t = 40)]
    probes: usize,
    /// Tile edge in pixels.
    #[arg(long, default_value_t = 32)]
    tile: u32,
    /// Where the slaves keep rendered frames (`isin slave --cache-tiles`).
    #[arg(long, default_value = "target/bench/frame-cache")]
    cache_dir: PathBuf,
    /// A short run: loopback and 100 Mbit/s at 0 % and 1 % loss, cached only, 24 frames.
    #[arg(long)]
    quick: bool,
    /// Only redraw transports.md and transports.svg from this JSON report (of an earlier run).
    #[arg(long)]
    from_json: Option<PathBuf>,
    /// Directory for transports.json, transports.md and transports.svg.
    #[arg(long, value_name = "DIR", default_value = "target/bench")]
    out_dir: PathBuf,
}

/// Where a run's traffic goes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Condition {
    Loopback,
    Lan(LinkSpec),
}

impl Condition {
    fn parse(s: &str) -> anyhow::Result<Condition> {
        if s.trim() == "loopback" {
            return Ok(Condition::Loopback);
        }
        let (r, l) = s.trim().split_once(':').with_context(|| format!("condition `{s}` is not RATE:LOSS"))?;
        Ok(Condition::Lan(LinkSpec { rate_mbit: Some(r.parse()?), loss_per_mille: l.parse()? }))
    }

    fn label(&self) -> String {
        match self {
            Condition::Loopback => "loopback".into(),
            Condition::Lan(l) => l.label(),
        }
    }
}

/// One measured configuration.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
struct Row {
    condition: String,
    rate_mbit: Option<u32>,
    loss_per_mille: u32,
    kind: String,
    transport: String,
    compression: String,
    frames: usize,
    fps: f64,
    /// Bytes the master received per frame, counted by the transport.
    bytes_per_frame: f64,
    /// Bytes received per frame on the master's interface (lab only).
    iface_bytes_per_frame: Option<f64>,
    /// Interface ÷ transport bytes.
    iface_over_transport: Option<f64>,
    /// Raw RGB8 bytes of a frame.
    raw_bytes_per_frame: u64,
    /// From the frame request to a tile at the viewer, ms.
    tile_latency_p50_ms: f64,
    tile_latency_p99_ms: f64,
    /// A one-tile frame on the idle cluster, request to done, ms.
    one_tile_rtt_p50_ms: f64,
    one_tile_rtt_p99_ms: f64,
    /// CPU seconds per frame.
    master_cpu_per_frame: f64,
    slaves_cpu_per_frame: f64,
    /// Frames the master finished with straggler copies.
    duplicated_per_frame: f64,
}

#[derive(Serialize, serde::Deserialize)]
struct Report {
    scene: String,
    path: String,
    width: u32,
    height: u32,
    slaves: usize,
    threads_per_slave: usize,
    cores: usize,
    lab_notes: Vec<String>,
    loadavg_before: String,
    loadavg_after: String,
    unix_time: u64,
    rows: Vec<Row>,
}

struct RunSpec<'a> {
    scene: &'a str,
    transport: &'a str,
    compression: &'a str,
    kind: &'a str,
    settings_size: (u32, u32),
    cameras: &'a [Camera],
    frames: usize,
    probes: usize,
    tile: u32,
    slaves: usize,
    threads: usize,
    cache_dir: &'a Path,
}

/// Runs `isin bench transports`.
pub fn run(args: TransportsArgs) -> anyhow::Result<()> {
    if let Some(json) = &args.from_json {
        let text =
            std::fs::read_to_string(json).with_context(|| format!("cannot read {}", json.display()))?;
        let report: Report = serde_json::from_str(&text)?;
        return write_outputs(&report, &args.out_dir, false);
    }
    let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
    let (w, h) = *parse_sizes(&args.size)?.first().context("no size")?;
    let transports: Vec<String> = parse_list(&args.transports)?;
    let compressions: Vec<String> = match &args.compression {
        Some(c) => parse_list(c)?,
        None => modes::default_compressions(),
    };
    modes::check_transports(&transports)?;
    modes::check_compressions(&compressions)?;
    let mut conditions: Vec<Condition> =
        args.conditions.split(',').map(Condition::parse).collect::<anyhow::Result<_>>()?;
    let mut kinds: Vec<String> = parse_list(&args.kinds)?;
    let mut frames = args.frames.max(1);
    if args.quick {
        conditions = ["loopback", "100:0", "100:10"]
            .iter()
            .map(|c| Condition::parse(c))
            .collect::<anyhow::Result<_>>()?;
        kinds = vec!["cached".into()];
        frames = frames.min(24);
    }
    for k in &kinds {
        anyhow::ensure!(k == "traced" || k == "cached", "unknown kind `{k}` (traced, cached)");
    }
    let scene_arg = args.scene.to_str().context("scene path is not UTF-8")?.to_string();
    let path = isin_viewer::CameraPath::load(&args.path)?;
    anyhow::ensure!(!path.frames.is_empty(), "{} has no cameras", args.path.display());
    let n_cam = args.cameras.clamp(1, path.frames.len());
    let cameras: Vec<Camera> =
        (0..n_cam).map(|i| path.frames[i * path.frames.len() / n_cam].camera()).collect();
    let cache_dir = std::path::absolute(&args.cache_dir)?;

    let support = Support::probe();
    let mut notes = support.describe();
    let lab_ok = support.netns.is_ok();
    let wants_loss = conditions.iter().any(|c| matches!(c, Condition::Lan(l) if l.loss_per_mille > 0));
    if !lab_ok || (wants_loss && support.loss.is_err()) {
        let before = conditions.len();
        conditions.retain(|c| match c {
            Condition::Loopback => true,
            Condition::Lan(l) => lab_ok && (l.loss_per_mille == 0 || support.loss.is_ok()),
        });
        notes.push(format!(
            "{} emulated-LAN conditions skipped; loopback still runs",
            before - conditions.len()
        ));
    }
    for n in &notes {
        println!("note: {n}");
    }
    let mut lab: Option<Lab> = None;
    if conditions.iter().any(|c| matches!(c, Condition::Lan(_))) {
        netlab::install_signal_cleanup()?;
        for gone in netlab::cleanup_stale() {
            println!("removed {gone}, left over from an earlier run");
        }
        lab = Some(Lab::new(args.slaves, LinkSpec::default())?);
    }
    let loadavg_before = loadavg();
    let mut rows = Vec::new();
    for cond in &conditions {
        let run_lab = match cond {
            Condition::Loopback => None,
            Condition::Lan(link) => {
                let l = lab.as_mut().context("no lab")?;
                if l.link() != *link {
                    l.set_link(*link)?;
                }
                Some(&*l)
            }
        };
        for kind in &kinds {
            for transport in &transports {
                for compression in &compressions {
                    let spec = RunSpec {
                        scene: &scene_arg,
                        transport,
                        compression,
                        kind,
                        settings_size: (w, h),
                        cameras: &cameras,
                        frames: if kind == "traced" { args.traced_frames.max(1) } else { frames },
                        probes: args.probes,
                        tile: args.tile,
                        slaves: args.slaves.max(1),
                        threads: args.threads.max(1),
                        cache_dir: &cache_dir,
                    };
                    let what = format!("{} {kind} {transport}/{compression}", cond.label());
                    let row = match run_once(run_lab, cond, &spec) {
                        Ok(r) => r,
                        Err(e) => {
                            println!("{what} failed, trying once more: {e:#}");
                            run_once(run_lab, cond, &spec).with_context(|| what.clone())?
                        }
                    };
                    println!(
                        "{:<26} {kind:<6} {transport:<4} {compression:<4}: {:6.2} fps, {:5.0} kB/frame (iface {}), \
                         tile latency p50/p99 {:.1}/{:.1} ms, 1-tile RTT {:.2}/{:.2} ms, CPU/frame master {:.3} s, \
                         slaves {:.3} s",
                        cond.label(),
                        row.fps,
                        row.bytes_per_frame / 1e3,
                        row.iface_bytes_per_frame.map_or("–".into(), |b| format!("{:.0} kB", b / 1e3)),
                        row.tile_latency_p50_ms,
                        row.tile_latency_p99_ms,
                        row.one_tile_rtt_p50_ms,
                        row.one_tile_rtt_p99_ms,
                        row.master_cpu_per_frame,
                        row.slaves_cpu_per_frame
                    );
                    rows.push(row);
                }
            }
        }
    }
    drop(lab);
    let report = Report {
        scene: scene_arg,
        path: args.path.display().to_string(),
        width: w,
        height: h,
        slaves: args.slaves,
        threads_per_slave: args.threads,
        cores,
        lab_notes: notes,
        loadavg_before,
        loadavg_after: loadavg(),
        unix_time: report::unix_time(),
        rows,
    };
    write_outputs(&report, &args.out_dir, true)
}

fn write_outputs(report: &Report, dir: &Path, json: bool) -> anyhow::Result<()> {
    report::write_outputs(dir, "transports", report, json, &markdown(report), |path| plot(path, &report.rows))
}

fn run_once(lab: Option<&Lab>, cond: &Condition, spec: &RunSpec) -> anyhow::Result<Row> {
    let token = auth::generate_token()?;
    let master_ns = lab.map(|l| l.master().ns.clone());
    let listen = lab.map_or("127.0.0.1:0".to_string(), |l| format!("{}:0", l.master().addr));
    let mut master_extra = modes::master_args(spec.transport, spec.compression);
    master_extra.extend(["--tile".to_string(), spec.tile.to_string()]);
    let (master, ticket) =
        start_master(master_ns.as_deref(), None, spec.scene, &listen, &token, &master_extra)?;
    let slave_extra: Vec<String> = if spec.kind == "cached" {
        vec!["--cache-tiles".into(), spec.cache_dir.display().to_string()]
    } else {
        Vec::new()
    };
    let mut slaves: Vec<ChildGuard> = Vec::new();
    for i in 0..spec.slaves {
        let ns = lab.and_then(|l| l.slave(i)).map(|h| h.ns.as_str());
        slaves.push(start_slave(ns, None, &ticket, spec.threads, &format!("pc{}", i + 1), &slave_extra)?);
    }
    wait_joined(&master, &mut slaves, Duration::from_secs(120))?;
    let pids: Vec<String> = slaves.iter().map(|s| s.pid().to_string()).collect();
    let master_pid = master.pid().to_string();
    let iface = || lab.and_then(|l| l.counters(l.master()).ok());
    let (w, h) = spec.settings_size;
    let m = std::thread::scope(|scope| {
        scope
            .spawn(|| {
                if let Some(ns) = &master_ns {
                    netlab::netns::enter(ns)?;
                }
                actix::System::new().block_on(async {
                    let transport = cluster::client_transport(&ticket)?;
                    let (v, info, mut events) = viewer::connect(transport.as_ref(), &ticket, "bench").await?;
                    let info = info.context("the master serves no scene")?;
                    let settings = RenderSettings { width: w, height: h, ..info.settings };
                    // Warm-up: cached runs fill the cache with every camera; traced runs render one frame.
                    let warm = if spec.kind == "cached" { spec.cameras } else { &spec.cameras[..1] };
                    for &c in warm {
                        timed_frame(&v, &mut events, c, settings).await?;
                    }
                    let (c0, s0, i0) =
                        (cpu_secs(&master_pid), pids.iter().map(|p| cpu_secs(p)).sum::<f64>(), iface());
                    let (mut secs, mut lat, mut bytes, mut dup) = (Vec::new(), Vec::new(), 0u64, 0u64);
                    for i in 0..spec.frames {
                        let f = timed_frame(&v, &mut events, spec.cameras[i % spec.cameras.len()], settings)
                            .await?;
                        secs.push(f.secs);
                        lat.extend(f.tile_secs);
                        bytes += f.bytes_in;
                        dup += u64::from(f.duplicated);
                    }
                    let (c1, s1, i1) =
                        (cpu_secs(&master_pid), pids.iter().map(|p| cpu_secs(p)).sum::<f64>(), iface());
                    let probe = RenderSettings { width: spec.tile, height: spec.tile, ..settings };
                    let mut rtt = Vec::new();
                    timed_frame(&v, &mut events, spec.cameras[0], probe).await?;
                    for _ in 0..spec.probes {
                        rtt.push(timed_frame(&v, &mut events, spec.cameras[0], probe).await?.secs);
                    }
                    let _ = v.send(viewer::Disconnect).await;
                    let iface_bytes = match (i0, i1) {
                        (Some(a), Some(b)) => Some(b.since(&a).rx_bytes),
                        _ => None,
                    };
                    anyhow::Ok((secs, lat, bytes, dup, c1 - c0, s1 - s0, iface_bytes, rtt))
                })
            })
            .join()
            .map_err(|_| anyhow::anyhow!("viewer thread panicked"))?
    })?;
    let (secs, lat, bytes, dup, master_cpu, slaves_cpu, iface_bytes, rtt) = m;
    let n = secs.len().max(1) as f64;
    let bytes_per_frame = bytes as f64 / n;
    let iface_bytes_per_frame = iface_bytes.map(|b| b as f64 / n);
    let (rate_mbit, loss_per_mille) = match cond {
        Condition::Loopback => (None, 0),
        Condition::Lan(l) => (l.rate_mbit, l.loss_per_mille),
    };
    Ok(Row {
        condition: cond.label(),
        rate_mbit,
        loss_per_mille,
        kind: spec.kind.to_string(),
        transport: spec.transport.to_string(),
        compression: spec.compression.to_string(),
        frames: secs.len(),
        fps: n / secs.iter().sum::<f64>().max(1e-9),
        bytes_per_frame,
        iface_bytes_per_frame,
        iface_over_transport: iface_bytes_per_frame.map(|i| i / bytes_per_frame.max(1.0)),
        raw_bytes_per_frame: u64::from(w) * u64::from(h) * 3,
        tile_latency_p50_ms: quantile(&lat, 0.5) * 1e3,
        tile_latency_p99_ms: quantile(&lat, 0.99) * 1e3,
        one_tile_rtt_p50_ms: quantile(&rtt, 0.5) * 1e3,
        one_tile_rtt_p99_ms: quantile(&rtt, 0.99) * 1e3,
        master_cpu_per_frame: master_cpu / n,
        slaves_cpu_per_frame: slaves_cpu / n,
        duplicated_per_frame: dup as f64 / n,
    })
}

/// A frame's timings as seen by the viewer.
struct Timed {
    secs: f64,
    tile_secs: Vec<f64>,
    bytes_in: u64,
    duplicated: u32,
}

/// Requests a frame and waits for it, noting when each tile arrived.
async fn timed_frame(
    v: &actix::Addr<viewer::ViewerActor>,
    events: &mut tokio::sync::mpsc::UnboundedReceiver<ViewerEvent>,
    camera: Camera,
    settings: RenderSettings,
) -> anyhow::Result<Timed> {
    let t0 = Instant::now();
    let request = v.send(RequestFrame { camera, settings }).await?;
    let (mut tile_secs, mut covered) = (Vec::new(), 0usize);
    while let Some(ev) = events.recv().await {
        match ev {
            ViewerEvent::Tile { request: r, tile, .. } if r == request => {
                tile_secs.push(t0.elapsed().as_secs_f64());
                covered += tile.pixel_count();
            }
            ViewerEvent::FrameDone { request: r, stats } if r == request => {
                anyhow::ensure!(
                    covered == settings.width as usize * settings.height as usize,
                    "frame done with {covered} pixels delivered"
                );
                return Ok(Timed {
                    secs: t0.elapsed().as_secs_f64(),
                    tile_secs,
                    bytes_in: stats.bytes_in,
                    duplicated: stats.duplicated,
                });
            }
            ViewerEvent::Error(e) | ViewerEvent::Closed(e) => anyhow::bail!("master: {e}"),
            _ => {}
        }
    }
    anyhow::bail!("connection to the master closed")
}

fn markdown(rep: &Report) -> String {
    let mut out = format!(
        "Scene `{}` at {}×{}, {} slaves × {} render thread(s), cameras of `{}`; load average {} → {}.\n\n",
        rep.scene,
        rep.width,
        rep.height,
        rep.slaves,
        rep.threads_per_slave,
        rep.path,
        rep.loadavg_before,
        rep.loadavg_after
    );
    for n in &rep.lab_notes {
        out.push_str(&format!("Note: {n}.\n\n"));
    }
    let rows: Vec<Vec<String>> = rep
        .rows
        .iter()
        .map(|r| {
            vec![
                r.condition.clone(),
                r.kind.clone(),
                r.transport.clone(),
                r.compression.clone(),
                format!("{:.2}", r.fps),
                format!("{:.0}", r.bytes_per_frame / 1e3),
                r.iface_bytes_per_frame.map_or("–".into(), |b| format!("{:.0}", b / 1e3)),
                r.iface_over_transport.map_or("–".into(), |x| format!("{x:.3}")),
                format!("{:.2}", r.raw_bytes_per_frame as f64 / r.bytes_per_frame.max(1.0)),
                format!("{:.1} / {:.1}", r.tile_latency_p50_ms, r.tile_latency_p99_ms),
                format!("{:.2} / {:.2}", r.one_tile_rtt_p50_ms, r.one_tile_rtt_p99_ms),
                format!("{:.3}", r.master_cpu_per_frame),
                format!("{:.3}", r.slaves_cpu_per_frame),
            ]
        })
        .collect();
    out.push_str(&report::table(
        &[
            "condition",
            "kind",
            "transport",
            "compression",
            "frames/s",
            "kB/frame (transport)",
            "kB/frame (interface)",
            "interface ÷ transport",
            "raw ÷ wire",
            "tile latency p50 / p99 ms",
            "1-tile RTT p50 / p99 ms",
            "master CPU s/frame",
            "slaves CPU s/frame",
        ],
        &rows,
    ));
    out
}

/// What a kind of run measures, in plain words.
fn kind_name(kind: &str) -> &str {
    match kind {
        "cached" => "tiles from cache",
        "traced" => "tiles rendered",
        other => other,
    }
}

/// Frames/s against loss, one line per (kind, transport, compression, rate):
/// TCP solid, QUIC dashed, one colour per (kind, compression, rate). The
/// x axis holds the loss rates measured; the y axis is logarithmic when the
/// lines differ by more than a factor of 10 (rendered runs against tiles
/// from cache).
fn plot(path: &Path, rows: &[Row]) -> anyhow::Result<()> {
    let mut keys: Vec<(String, String, String, u32)> = Vec::new();
    let mut losses: Vec<u32> = Vec::new();
    for r in rows {
        if let Some(rate) = r.rate_mbit {
            let k = (r.kind.clone(), r.transport.clone(), r.compression.clone(), rate);
            if !keys.contains(&k) {
                keys.push(k);
            }
            if !losses.contains(&r.loss_per_mille) {
                losses.push(r.loss_per_mille);
            }
        }
    }
    losses.sort_unstable();
    let mut colours: Vec<(&str, &str, u32)> = Vec::new();
    let series: Vec<Series> = keys
        .iter()
        .map(|(kind, transport, compression, rate)| {
            let family = (kind.as_str(), compression.as_str(), *rate);
            let color = colours.iter().position(|c| *c == family).unwrap_or_else(|| {
                colours.push(family);
                colours.len() - 1
            });
            let link =
                if *rate >= 1000 { format!("{} Gbit/s", rate / 1000) } else { format!("{rate} Mbit/s") };
            Series {
                name: format!(
                    "{}, {}, {link}, {}",
                    modes::transport_name(transport),
                    modes::compression_name(compression),
                    kind_name(kind)
                ),
                points: rows
                    .iter()
                    .filter(|r| {
                        &r.kind == kind
                            && &r.transport == transport
                            && &r.compression == compression
                            && r.rate_mbit == Some(*rate)
                    })
                    .filter_map(|r| {
                        losses.iter().position(|&l| l == r.loss_per_mille).map(|x| (x as f64, r.fps))
                    })
                    .collect(),
                color,
                dashed: transport == "quic",
            }
        })
        .collect();
    let names: Vec<String> = losses.iter().map(|&l| format!("{} %", l as f64 / 10.0)).collect();
    let names: Vec<&str> = names.iter().map(String::as_str).collect();
    report::line_plot(
        path,
        &report::Plot {
            title: "Frames per second against random packet loss",
            x_label: "packets lost at random on every host's input (%)",
            y_label: "frames per second",
            y_scale: report::YScale::fitting(&series),
            x_names: Some(&names),
            series: &series,
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conditions_parse() {
        assert_eq!(Condition::parse("loopback").unwrap(), Condition::Loopback);
        assert_eq!(
            Condition::parse("100:10").unwrap(),
            Condition::Lan(LinkSpec { rate_mbit: Some(100), loss_per_mille: 10 })
        );
        assert_eq!(Condition::parse("1000:1").unwrap().label(), "1 Gbit/s, 0.1 % loss");
        assert!(Condition::parse("fast").is_err());
    }

    fn row(kind: &str, transport: &str, compression: &str, loss_per_mille: u32, fps: f64) -> Row {
        Row {
            condition: String::new(),
            rate_mbit: Some(100),
            loss_per_mille,
            kind: kind.into(),
            transport: transport.into(),
            compression: compression.into(),
            frames: 6,
            fps,
            bytes_per_frame: 4e5,
            iface_bytes_per_frame: None,
            iface_over_transport: None,
            raw_bytes_per_frame: 921_600,
            tile_latency_p50_ms: 1.0,
            tile_latency_p99_ms: 1.0,
            one_tile_rtt_p50_ms: 1.0,
            one_tile_rtt_p99_ms: 1.0,
            master_cpu_per_frame: 0.01,
            slaves_cpu_per_frame: 0.1,
            duplicated_per_frame: 0.0,
        }
    }

    #[test]
    fn the_plot_speaks_plainly_and_spreads_rendered_and_cached_runs_on_a_log_axis() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("transports.svg");
        let rows = [
            row("cached", "tcp", "auto", 0, 29.7),
            row("cached", "tcp", "auto", 10, 22.6),
            row("cached", "quic", "raw", 0, 12.4),
            row("traced", "tcp", "auto", 0, 1.4),
            row("traced", "quic", "auto", 10, 1.7),
        ];
        plot(&p, &rows).unwrap();
        let svg = std::fs::read_to_string(&p).unwrap();
        for name in [
            "TLS over TCP, QOI tiles, 100 Mbit/s, tiles from cache",
            "QUIC, raw tiles, 100 Mbit/s, tiles from cache",
            "QUIC, QOI tiles, 100 Mbit/s, tiles rendered",
            "frames per second (log scale)",
            "0 %",
            "1 %",
        ] {
            assert!(svg.contains(&format!(">\n{name}\n<")), "`{name}` missing");
        }
        assert!(!svg.contains("0.1 %"), "a loss rate not measured has no column");
        for jargon in ["cached", "traced", "tcp/", "/auto", "quic/"] {
            assert!(!svg.contains(jargon), "`{jargon}` in the plot");
        }
    }
}

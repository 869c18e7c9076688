//! `isin bench scaling`: the paper's Table 1 (seconds per frame and speedup
//! with 1–12 PCs on a 100 Mbit/s LAN) on one machine.
//!
//! Every slave is an emulated PC ([`crate::netlab`]): its own network
//! namespace on a switch, its cable rate-limited with tbf, its CPU limited by a
//! cgroup quota of `cpu_total / N_max` of a core, so that the N slaves together
//! never have more CPU than the machine; by default `N_max + 1` PCs share it,
//! the master having one of its own ([`default_cpu_total`]). The master sits
//! in a namespace of its own behind one such cable; the viewer (this process)
//! talks to it inside the master's namespace, like the paper's master showing
//! frames on its screen.
//! Frames are the cameras of a recorded path, requested one after another —
//! by default with the next frame queued at the master while one renders
//! (`--pipeline 2`: slaves roll from one frame straight into the next, as a
//! replaying viewer would have them), or with a barrier between frames
//! (`--pipeline 1`: each requested when the previous one completed). Seconds
//! per frame are the intervals between completions (throughput); the latency
//! of each frame (request to completion) is reported beside them.
//!
//! Besides seconds per frame it measures where the time went, so that a run
//! whose efficiency falls short names the saturated resource: the master's
//! link (interface counters against the rate), the master's CPU, and for the
//! slaves' render threads the time on a CPU, waiting for one (throttled by the
//! quota or crowded out by other load, `/proc/PID/task/*/schedstat` and the
//! cgroup's `cpu.stat`) and idle (no tile to render).

use super::modes;
use super::procs::{ChildGuard, MachineStat, SchedStat, cpu_secs, start_master, start_slave, wait_joined};
use super::replay;
use super::report::{self, Series, median, quantile};
use super::{loadavg, parse_list, parse_sizes};
use crate::client as cluster;
use crate::netlab::{self, CpuCgroup, Lab, LinkSpec, Support, netns::IfCounters};
use anyhow::Context;
use clap::Args;
use isin_actors::viewer;
use isin_cluster::auth;
use isin_tracer::{Camera, RenderSettings};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The paper's Table 1: PCs, seconds per 320×240 frame.
pub const PAPER: [(usize, f64); 8] =
    [(1, 2.61), (2, 1.33), (3, 0.89), (4, 0.68), (5, 0.56), (6, 0.48), (8, 0.39), (12, 0.32)];

/// Efficiency below which the bench names the saturated resource.
pub const EFFICIENCY_BAR: f64 = 0.9;

/// Arguments of `isin bench scaling`.
#[derive(Args, Debug)]
pub struct ScalingArgs {
    /// Scene file.
    #[arg(long, default_value = "scenes/paper.toml")]
    scene: PathBuf,
    /// Camera path replayed (evenly spaced cameras of it, see --frames).
    #[arg(long, default_value = "scenes/paths/paper.toml")]
    path: PathBuf,
    /// Slave counts N, comma-separated (the largest is N_max).
    #[arg(long, default_value = "1,2,3,4,5,6,8,12")]
    slaves: String,
    /// Image sizes, `WxH` comma-separated.
    #[arg(long, default_value = "320x240,640x480")]
    sizes: String,
    /// Transports, comma-separated (tcp, quic).
    #[arg(long, default_value = "tcp,quic")]
    transports: String,
    /// Compression modes, comma-separated (default: every mode this build can run).
    #[arg(long)]
    compression: Option<String>,
    /// Link rates in Mbit/s, comma-separated (100: the paper's LAN; 1000 optional).
    #[arg(long, default_value = "100")]
    rates: String,
    /// Cores shared by the slaves: each gets CPU_TOTAL / N_max of a core
    /// (default: N_max / (N_max + 1) of the machine, so that the master is a
    /// PC of its own, as in the paper; the machine's core count gives the
    /// slaves all of it, and the master's work comes out of their share).
    #[arg(long)]
    cpu_total: Option<f64>,
    /// CFS weight (`cpu.shares`) of each emulated PC's cgroup and of the master's
    /// (a plain process weighs 1024): a heavy weight keeps other load on the
    /// machine from taking the PCs' quota (they still never get more than it).
    #[arg(long, default_value_t = 8192)]
    cpu_weight: u64,
    /// Timed frames per run at 320×240 (larger images: fewer, in proportion, at least 4).
    #[arg(long, default_value_t = 16)]
    frames: usize,
    /// Runs of every slave count per configuration, alternating (1, 12, 1, 12, …);
    /// their frames are pooled (medians over all of them), so that a change of
    /// load on the shared machine during a sweep weighs on every N alike.
    #[arg(long, default_value_t = 1)]
    repeat: usize,
    /// Tile edge in pixels (`isin master --tile`).
    #[arg(long, default_value_t = 32)]
    tile: u32,
    /// Frames kept requested at the master at once, comma-separated: 1 requests
    /// each frame when the previous one completed (a barrier between frames); 2
    /// keeps the next frame queued behind the one rendering (pipelined replay).
    #[arg(long, default_value = "2")]
    pipeline: String,
    /// Extra argument for `isin master` (repeatable), e.g. `--master-arg=--no-duplicates`.
    #[arg(long = "master-arg", allow_hyphen_values = true)]
    master_args: Vec<String>,
    /// A short run: N = 1,2,4,12, 320×240, TCP, 8 frames.
    #[arg(long)]
    quick: bool,
    /// Skip the lab even when root: all processes on loopback, no quotas.
    #[arg(long)]
    loopback: bool,
    /// Only redraw scaling.md and scaling.svg from this JSON report of an earlier run
    /// (recomputing the derived columns: crowding and the bottleneck).
    #[arg(long)]
    from_json: Option<PathBuf>,
    /// Directory for scaling.json, scaling.md and scaling.svg.
    #[arg(long, value_name = "DIR", default_value = "target/bench")]
    out_dir: PathBuf,
}

/// One measured configuration.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct Row {
    width: u32,
    height: u32,
    transport: String,
    compression: String,
    /// Link rate, Mbit/s (`None` on loopback).
    rate_mbit: Option<u32>,
    /// Frames kept requested at once (1: one at a time).
    #[serde(default = "one")]
    pipeline: usize,
    slaves: usize,
    frames: usize,
    /// Seconds per frame (intervals between completions): median and 95th percentile.
    sec_median: f64,
    sec_p95: f64,
    /// Seconds from a frame's request to its completion: median and 95th percentile.
    #[serde(default)]
    latency_median: f64,
    #[serde(default)]
    latency_p95: f64,
    /// Median seconds from a request to its first tile (the cluster's ramp-up).
    #[serde(default)]
    first_tile_median: f64,
    /// Median seconds a frame took to deliver its last tenth of pixels (its tail).
    #[serde(default)]
    last_tenth_median: f64,
    /// Frames per second over the whole replay (throughput).
    fps: f64,
    /// Throughput against the smallest N (taken as linear up to there): frames
    /// per second at N ÷ at N = 1. The same cameras at every N, so this is the
    /// ratio of the replay's total times.
    speedup: f64,
    /// Speedup ÷ N.
    efficiency: f64,
    /// Median seconds per frame at N = 1 ÷ at N (the definition before
    /// pipelining: with frames pipelined, an interval between completions is
    /// not one frame's cost, and the median of intervals at N = 1 leaves out
    /// the path's expensive frames that a pipeline spreads over its neighbours).
    #[serde(default)]
    speedup_median: f64,
    /// `speedup_median` ÷ N.
    #[serde(default)]
    efficiency_median: f64,
    /// Bytes the master received per frame, counted by the transport (framing and heartbeats included).
    bytes_per_frame: f64,
    /// Bytes received per frame on the master's interface (Ethernet frames), when in the lab.
    iface_bytes_per_frame: Option<f64>,
    /// The master's received bits per second ÷ the link rate.
    link_utilisation: Option<f64>,
    /// The master process's CPU seconds per wall second.
    master_cpu: f64,
    /// Slaves' render threads: CPU time ÷ (quota × wall), averaged over slaves.
    slave_quota_use: Option<f64>,
    /// Slaves' render threads: share of wall time with nothing to render.
    slave_idle: f64,
    /// Slaves' render threads: share of their quota lost to other load on the
    /// machine (`1 − quota used − idle`; without quotas: time waiting for a core).
    slave_crowded: f64,
    /// Tiles handed to a second slave per frame (straggler copies).
    duplicated_per_frame: f64,
    /// Where efficiency < 0.9: the saturated resource, from the figures above.
    bottleneck: Option<String>,
    /// Where the machine's CPU went, per frame (in the lab).
    #[serde(default)]
    cpu_per_frame: Option<CpuPerFrame>,
}

/// Where the machine's CPU went during a run: CPU milliseconds per frame,
/// summed over cores (`/proc/stat` and each process's threads'
/// `/proc/PID/task/*/schedstat`). At N = N_max the slaves' quotas add up to
/// the machine, so everything that is not `slave_render` comes out of them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct CpuPerFrame {
    /// The master process.
    master: f64,
    /// This process: the viewer receiving the tiles (and the bench's log readers).
    viewer: f64,
    /// The slaves' render threads.
    slave_render: f64,
    /// The slaves' other threads (network, TLS or QUIC, heartbeats), inside their quotas.
    slave_other: f64,
    /// Hard and soft interrupts (the kernel's network work: veth, bridge, tbf, TCP/UDP).
    irq: f64,
    /// Busy time of everything else: other processes and kernel threads.
    other: f64,
    /// Idle cores.
    idle: f64,
    /// Stolen by the hypervisor.
    steal: f64,
}

impl CpuPerFrame {
    /// Everything but the slaves' render threads, idle and steal: the CPU that
    /// at N = N_max comes out of the slaves' quotas.
    fn overhead(&self) -> f64 {
        self.master + self.viewer + self.slave_other + self.irq + self.other
    }

    /// What took the CPU besides the render threads, largest first, as
    /// `" — per frame: master 4.3 ms, …"` (empty when nothing did).
    fn takers(&self) -> String {
        let mut parts = [
            ("the slaves' own network threads", self.slave_other),
            ("master", self.master),
            ("viewer", self.viewer),
            ("interrupts (network)", self.irq),
            ("other processes", self.other),
        ];
        parts.sort_by(|a, b| b.1.total_cmp(&a.1));
        let list: Vec<String> =
            parts.iter().filter(|p| p.1 >= 0.05).map(|(n, ms)| format!("{n} {ms:.1} ms")).collect();
        if list.is_empty() { String::new() } else { format!(" — CPU per frame: {}", list.join(", ")) }
    }

    fn describe(&self) -> String {
        format!(
            "CPU ms/frame: render {:.1}, slaves' other threads {:.1}, master {:.1}, viewer {:.1}, irq {:.1}, \
             other {:.1}, idle {:.1}, steal {:.1}",
            self.slave_render,
            self.slave_other,
            self.master,
            self.viewer,
            self.irq,
            self.other,
            self.idle,
            self.steal
        )
    }
}

#[derive(Serialize, serde::Deserialize)]
struct Meta {
    scene: String,
    path: String,
    cameras_in_path: usize,
    cores: usize,
    lab: bool,
    lab_notes: Vec<String>,
    cpu_total: Option<f64>,
    slave_share_of_a_core: Option<f64>,
    cfs_period_us: Option<u64>,
    cfs_quota_us: Option<u64>,
    tile: u32,
    /// Frames kept requested at once, per group (`--pipeline`).
    #[serde(default)]
    pipeline: Vec<usize>,
    /// CFS weight of the PCs' and the master's cgroups (`--cpu-weight`).
    #[serde(default)]
    cpu_weight: Option<u64>,
    /// Alternating runs per slave count, pooled (`--repeat`).
    #[serde(default = "one")]
    repeat: usize,
    loadavg_before: String,
    loadavg_after: String,
    unix_time: u64,
}

#[derive(Serialize, serde::Deserialize)]
struct Report {
    meta: Meta,
    paper: Vec<(usize, f64)>,
    rows: Vec<Row>,
}

/// Counters sampled before and after a run.
struct Snapshot {
    at: Instant,
    master_cpu: f64,
    master_run: f64,
    viewer_run: f64,
    slaves_run: Vec<f64>,
    machine: MachineStat,
    render: Vec<SchedStat>,
    throttled_us: Vec<f64>,
    iface: Option<IfCounters>,
}

/// What one run (one N) needs.
struct RunSpec<'a> {
    scene: &'a str,
    transport: &'a str,
    compression: &'a str,
    n: usize,
    settings_size: (u32, u32),
    cameras: &'a [Camera],
    pipeline: usize,
    master_extra: Vec<String>,
}

fn one() -> usize {
    1
}

/// Per-frame results and the counters around them.
struct RunResult {
    secs: Vec<f64>,
    latency: Vec<f64>,
    first_tile: Vec<f64>,
    last_tenth: Vec<f64>,
    bytes_in: Vec<u64>,
    duplicated: u64,
    /// Counters from the first frame's request to the last one's completion.
    delta: Delta,
}

/// What the counters of a [`Snapshot`] moved by over a run (summed over repeats).
#[derive(Default)]
struct Delta {
    wall: f64,
    master_cpu: f64,
    /// Run time of the master's threads, of the viewer's, of each slave's (all threads).
    master_run: f64,
    viewer_run: f64,
    slaves_run: Vec<f64>,
    machine: MachineStat,
    render: Vec<SchedStat>,
    throttled: Vec<f64>,
    iface: Option<IfCounters>,
}

impl Delta {
    fn between(before: &Snapshot, after: &Snapshot) -> Delta {
        Delta {
            wall: (after.at - before.at).as_secs_f64(),
            master_cpu: after.master_cpu - before.master_cpu,
            master_run: after.master_run - before.master_run,
            viewer_run: after.viewer_run - before.viewer_run,
            slaves_run: after.slaves_run.iter().zip(&before.slaves_run).map(|(a, b)| a - b).collect(),
            machine: after.machine.since(&before.machine),
            render: after.render.iter().zip(&before.render).map(|(a, b)| a.since(b)).collect(),
            throttled: after
                .throttled_us
                .iter()
                .zip(&before.throttled_us)
                .map(|(a, b)| (a - b) / 1e6)
                .collect(),
            iface: match (&before.iface, &after.iface) {
                (Some(b), Some(a)) => Some(a.since(b)),
                _ => None,
            },
        }
    }
}

impl RunResult {
    /// Pools a repeat of the same run into this one: samples side by side,
    /// counters summed.
    fn absorb(&mut self, o: RunResult) {
        self.secs.extend(o.secs);
        self.latency.extend(o.latency);
        self.first_tile.extend(o.first_tile);
        self.last_tenth.extend(o.last_tenth);
        self.bytes_in.extend(o.bytes_in);
        self.duplicated += o.duplicated;
        let (d, e) = (&mut self.delta, o.delta);
        d.wall += e.wall;
        d.master_cpu += e.master_cpu;
        d.master_run += e.master_run;
        d.viewer_run += e.viewer_run;
        for (a, b) in d.slaves_run.iter_mut().zip(&e.slaves_run) {
            *a += b;
        }
        d.machine = d.machine.plus(&e.machine);
        for (a, b) in d.render.iter_mut().zip(&e.render) {
            (a.run, a.wait) = (a.run + b.run, a.wait + b.wait);
        }
        for (a, b) in d.throttled.iter_mut().zip(&e.throttled) {
            *a += b;
        }
        d.iface = match (d.iface, e.iface) {
            (Some(a), Some(b)) => Some(IfCounters {
                rx_bytes: a.rx_bytes + b.rx_bytes,
                tx_bytes: a.tx_bytes + b.tx_bytes,
                rx_packets: a.rx_packets + b.rx_packets,
                tx_packets: a.tx_packets + b.tx_packets,
            }),
            _ => None,
        };
    }
}

/// Runs `isin bench scaling`.
pub fn run(args: ScalingArgs) -> anyhow::Result<()> {
    if let Some(json) = &args.from_json {
        let text =
            std::fs::read_to_string(json).with_context(|| format!("cannot read {}", json.display()))?;
        let mut report: Report = serde_json::from_str(&text)?;
        for r in &mut report.rows {
            if let Some(u) = r.slave_quota_use {
                r.slave_crowded = (1.0 - u - r.slave_idle).clamp(0.0, 1.0);
            }
        }
        for key in groups(&report.rows) {
            let mut g: Vec<Row> = report.rows.iter().filter(|r| group_key(r) == key).cloned().collect();
            fill_speedups(&mut g);
            for new in g {
                if let Some(r) =
                    report.rows.iter_mut().find(|r| group_key(r) == key && r.slaves == new.slaves)
                {
                    *r = new;
                }
            }
        }
        return write_outputs(&report, &args.out_dir, false);
    }
    let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
    let (mut slave_counts, mut sizes, mut transports, mut frames): (Vec<usize>, _, Vec<String>, _) = (
        parse_list(&args.slaves)?,
        parse_sizes(&args.sizes)?,
        parse_list(&args.transports)?,
        args.frames.max(1),
    );
    if args.quick {
        slave_counts = vec![1, 2, 4, 12];
        sizes = vec![(320, 240)];
        transports = vec!["tcp".into()];
        frames = frames.min(8);
    }
    slave_counts.sort_unstable();
    slave_counts.dedup();
    anyhow::ensure!(slave_counts.first().is_some_and(|&n| n >= 1), "slave counts must be ≥ 1");
    let n_max = *slave_counts.last().context("no slave counts")?;
    let compressions: Vec<String> = match &args.compression {
        Some(c) => parse_list(c)?,
        None => modes::default_compressions(),
    };
    modes::check_transports(&transports)?;
    modes::check_compressions(&compressions)?;
    let rates: Vec<u32> = parse_list(&args.rates)?;
    let pipelines: Vec<usize> = parse_list(&args.pipeline)?;
    anyhow::ensure!(pipelines.iter().all(|&p| (1..=4).contains(&p)), "--pipeline takes 1 to 4 frames");
    let scene_arg = args.scene.to_str().context("scene path is not UTF-8")?.to_string();
    let path = isin_viewer::CameraPath::load(&args.path)?;
    anyhow::ensure!(!path.frames.is_empty(), "{} has no cameras", args.path.display());

    let support = Support::probe();
    let mut notes = support.describe();
    let use_lab = !args.loopback && support.netns.is_ok() && support.cpu_quota.is_ok();
    if !use_lab {
        notes.push(if args.loopback {
            "--loopback: no lab".into()
        } else {
            "no lab: running on loopback without rate limits or CPU quotas — every slave \
             competes for all cores, so speedup cannot exceed the core count"
                .into()
        });
        for n in &notes {
            println!("note: {n}");
        }
    } else {
        netlab::install_signal_cleanup()?;
        for gone in netlab::cleanup_stale() {
            println!("removed {gone}, left over from an earlier run");
        }
    }
    let cpu_total = args.cpu_total.unwrap_or_else(|| default_cpu_total(cores, n_max));
    let share = cpu_total / n_max as f64;
    let cgroups: Vec<CpuCgroup> = if use_lab {
        (1..=n_max).map(|i| CpuCgroup::create(&format!("s{i}"), share)).collect::<anyhow::Result<_>>()?
    } else {
        Vec::new()
    };
    let master_cgroup = if use_lab { Some(CpuCgroup::unlimited("master")?) } else { None };
    for cg in cgroups.iter().chain(&master_cgroup) {
        cg.set_weight(args.cpu_weight)?;
    }
    if let Some(cg) = cgroups.first() {
        println!(
            "lab: {n_max} slave PCs with {:.3} of a core each (CFS quota {} µs per {} µs), {:.3} in total; \
             CPU weight {} (a plain process: {})",
            cg.share(),
            cg.quota_us,
            cg.period_us,
            cpu_total,
            args.cpu_weight,
            netlab::cgroup::PLAIN_WEIGHT
        );
    }
    let loadavg_before = loadavg();
    let mut rows = Vec::new();
    let rate_list: Vec<Option<u32>> =
        if use_lab { rates.iter().map(|&r| Some(r)).collect() } else { vec![None] };
    for &rate in &rate_list {
        let mut lab = if use_lab {
            Some(Lab::new(n_max, LinkSpec { rate_mbit: rate, loss_per_mille: 0 })?)
        } else {
            None
        };
        if let (Some(lab), Some(r)) = (lab.as_mut(), rate) {
            println!(
                "lab: every PC on a {r} Mbit/s cable to one switch ({} namespaces)",
                lab.slave_count() + 2
            );
        }
        for &(w, h) in &sizes {
            let n_frames = (frames * 320 * 240 / (w as usize * h as usize).max(1)).max(4).min(frames.max(4));
            let cameras: Vec<Camera> =
                (0..n_frames).map(|i| path.frames[i * path.frames.len() / n_frames].camera()).collect();
            for transport in &transports {
                for (compression, &pipeline) in
                    compressions.iter().flat_map(|c| pipelines.iter().map(move |p| (c, p)))
                {
                    let mut group: Vec<Row> = Vec::new();
                    // Repeats alternate the slave counts (1, 12, 1, 12, …), so that
                    // a change of load on the machine weighs on every N alike.
                    let mut pooled: Vec<RunResult> = Vec::new();
                    for repeat in 0..args.repeat.max(1) {
                        let mut specs: Vec<RunSpec> = Vec::new();
                        for &n in &slave_counts {
                            let mut master_extra = modes::master_args(transport, compression);
                            master_extra.extend(["--tile".to_string(), args.tile.to_string()]);
                            master_extra.extend(args.master_args.iter().cloned());
                            let spec = RunSpec {
                                scene: &scene_arg,
                                transport,
                                compression,
                                n,
                                settings_size: (w, h),
                                cameras: &cameras,
                                pipeline,
                                master_extra,
                            };
                            let what =
                                format!("{w}x{h} {transport}/{compression}, {n} slaves, pipeline {pipeline}");
                            let cgs = (master_cgroup.as_ref(), cgroups.as_slice());
                            let r = match run_once(lab.as_ref(), cgs, &spec) {
                                Ok(r) => r,
                                Err(e) => {
                                    println!("{what} failed, trying once more: {e:#}");
                                    run_once(lab.as_ref(), cgs, &spec).with_context(|| what.clone())?
                                }
                            };
                            specs.push(spec);
                            match pooled.get_mut(specs.len() - 1) {
                                Some(p) => p.absorb(r),
                                None => pooled.push(r),
                            }
                        }
                        if repeat + 1 < args.repeat {
                            continue;
                        }
                        for (spec, r) in specs.iter().zip(&pooled) {
                            group.push(make_row(spec, rate, cgroups.first().map(CpuCgroup::share), r));
                        }
                        fill_speedups(&mut group);
                        for row in &group {
                            let n = row.slaves;
                            println!(
                                "{w}x{h} {transport}/{compression} open {pipeline} N={n:>2}: {:.3} s/frame (p95 {:.3}), \
                             latency {:.3} s (p95 {:.3}), first tile {:.1} ms, last tenth {:.1} ms, {:.2} fps, \
                             speedup {:.2}, efficiency {:.2}, {:.0} kB/frame, master CPU {:.2}, slaves idle {:.0} %, \
                             crowded {:.0} %{}",
                                row.sec_median,
                                row.sec_p95,
                                row.latency_median,
                                row.latency_p95,
                                row.first_tile_median * 1e3,
                                row.last_tenth_median * 1e3,
                                row.fps,
                                row.speedup,
                                row.efficiency,
                                row.bytes_per_frame / 1e3,
                                row.master_cpu,
                                row.slave_idle * 100.0,
                                row.slave_crowded * 100.0,
                                row.bottleneck
                                    .as_ref()
                                    .map(|b| format!(" — short of {EFFICIENCY_BAR}: {b}"))
                                    .unwrap_or_default()
                            );
                            if let Some(c) = &row.cpu_per_frame {
                                println!(
                                    "    {}; not rendering: {:.1} ms/frame ({:.0} % of the render time)",
                                    c.describe(),
                                    c.overhead(),
                                    100.0 * c.overhead() / c.slave_render.max(1e-9)
                                );
                            }
                        }
                    }
                    rows.extend(group);
                }
            }
        }
        drop(lab.take());
    }
    drop(cgroups);
    drop(master_cgroup);
    let unix_time = report::unix_time();
    let first = cgroups_meta(use_lab, share);
    let report = Report {
        meta: Meta {
            scene: scene_arg,
            path: args.path.display().to_string(),
            cameras_in_path: path.frames.len(),
            cores,
            lab: use_lab,
            lab_notes: notes,
            cpu_total: use_lab.then_some(cpu_total),
            slave_share_of_a_core: use_lab.then_some(share),
            cfs_period_us: first.map(|f| f.0),
            cfs_quota_us: first.map(|f| f.1),
            tile: args.tile,
            pipeline: pipelines.clone(),
            cpu_weight: use_lab.then_some(args.cpu_weight),
            repeat: args.repeat.max(1),
            loadavg_before,
            loadavg_after: loadavg(),
            unix_time,
        },
        paper: PAPER.to_vec(),
        rows,
    };
    write_outputs(&report, &args.out_dir, true)
}

/// The slaves' cores in all by default: `N_max + 1` equal PCs share the
/// machine, the slaves' and the master's (with the viewer at its screen and
/// the emulated switch's kernel work beside it). The master's cgroup has no
/// quota: it takes its PC's share and whatever the slaves leave idle, at every
/// N alike, so that N = 1 and N = N_max compare the slaves, not the lab.
pub fn default_cpu_total(cores: usize, n_max: usize) -> f64 {
    cores as f64 * n_max as f64 / (n_max as f64 + 1.0)
}

fn write_outputs(report: &Report, dir: &Path, json: bool) -> anyhow::Result<()> {
    report::write_outputs(dir, "scaling", report, json, &markdown(report), |path| plot(path, &report.rows))
}

fn cgroups_meta(use_lab: bool, share: f64) -> Option<(u64, u64)> {
    use_lab.then(|| netlab::cgroup::period_for_share(share))
}

/// Starts a master and `spec.n` slaves (in the master's and the slaves'
/// cgroups when given), replays the cameras, stops them.
fn run_once(
    lab: Option<&Lab>,
    (master_cgroup, cgroups): (Option<&CpuCgroup>, &[CpuCgroup]),
    spec: &RunSpec,
) -> anyhow::Result<RunResult> {
    let token = auth::generate_token()?;
    let master_ns = lab.map(|l| l.master().ns.clone());
    let listen = lab.map_or("127.0.0.1:0".to_string(), |l| format!("{}:0", l.master().addr));
    let (master, ticket) =
        start_master(master_ns.as_deref(), master_cgroup, spec.scene, &listen, &token, &spec.master_extra)?;
    let mut slaves: Vec<ChildGuard> = Vec::new();
    for i in 0..spec.n {
        let ns = lab.and_then(|l| l.slave(i)).map(|h| h.ns.as_str());
        slaves.push(start_slave(ns, cgroups.get(i), &ticket, 1, &format!("pc{}", i + 1), &[])?);
    }
    wait_joined(&master, &mut slaves, Duration::from_secs(120))?;
    let (master_pid, slave_pids): (String, Vec<u32>) =
        (master.pid().to_string(), slaves.iter().map(ChildGuard::pid).collect());
    let (master_pid_n, own_pid) = (master.pid(), std::process::id());
    // The interface counters take a process spawn to read (milliseconds in
    // which the slaves sit idle): read them outside the timed span, so that the
    // span is the replay's — before the clock at the start, after it at the end.
    let snapshot = |start: bool| {
        let iface_first = if start { Some(lab.and_then(|l| l.counters(l.master()).ok())) } else { None };
        let end_at = (!start).then(Instant::now);
        let mut s = Snapshot {
            at: Instant::now(),
            master_cpu: cpu_secs(&master_pid),
            master_run: SchedStat::read(master_pid_n, "").run,
            viewer_run: SchedStat::read(own_pid, "").run,
            slaves_run: slave_pids.iter().map(|&p| SchedStat::read(p, "").run).collect(),
            machine: MachineStat::read(),
            render: slave_pids.iter().map(|&p| SchedStat::read(p, "isin-render")).collect(),
            throttled_us: cgroups.iter().take(spec.n).map(|c| c.throttled().1).collect(),
            iface: None,
        };
        s.iface = iface_first.unwrap_or_else(|| lab.and_then(|l| l.counters(l.master()).ok()));
        s.at = end_at.unwrap_or_else(Instant::now);
        s
    };
    let (w, h) = spec.settings_size;
    let cameras = spec.cameras;
    std::thread::scope(|scope| {
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
                    // Warm-up: scene loaded and caches hot on every slave.
                    viewer::collect_frame(&v, &mut events, cameras[0], settings).await?;
                    let before = snapshot(true);
                    let r = replay::replay(&v, &mut events, cameras, settings, spec.pipeline).await?;
                    let after = snapshot(false);
                    let _ = v.send(viewer::Disconnect).await;
                    anyhow::Ok(RunResult {
                        secs: r.intervals(),
                        latency: r.latencies(),
                        first_tile: r.first_tile(),
                        last_tenth: r.last_tenth(),
                        bytes_in: r.frames.iter().map(|f| f.stats.bytes_in).collect(),
                        duplicated: r.frames.iter().map(|f| u64::from(f.stats.duplicated)).sum(),
                        delta: Delta::between(&before, &after),
                    })
                })
            })
            .join()
            .map_err(|_| anyhow::anyhow!("viewer thread panicked"))?
    })
}

/// Speedups and efficiencies of a group's rows against its first (smallest N,
/// taken as linear up to there), and the bottleneck where efficiency is short.
fn fill_speedups(group: &mut [Row]) {
    let Some(first) = group.first() else { return };
    let n0 = first.slaves as f64;
    // Frames per second of one slave, and seconds per frame on one slave.
    let (fps_1, median_1) = (first.fps / n0, first.sec_median * n0);
    for r in group.iter_mut() {
        let n = r.slaves as f64;
        r.speedup = r.fps / fps_1.max(1e-12);
        r.efficiency = r.speedup / n;
        r.speedup_median = median_1 / r.sec_median.max(1e-12);
        r.efficiency_median = r.speedup_median / n;
        r.bottleneck = (r.slaves > 1 && r.efficiency < EFFICIENCY_BAR).then(|| bottleneck(r));
    }
}

fn make_row(spec: &RunSpec, rate: Option<u32>, share: Option<f64>, r: &RunResult) -> Row {
    let n = spec.n;
    let frames = r.secs.len();
    let wall = r.delta.wall.max(1e-9);
    let sec_median = median(&r.secs);
    let bytes_per_frame = r.bytes_in.iter().sum::<u64>() as f64 / frames.max(1) as f64;
    let iface = r.delta.iface;
    let link_utilisation = match (iface, rate) {
        (Some(c), Some(rate)) => Some(c.rx_bytes as f64 * 8.0 / wall / (f64::from(rate) * 1e6)),
        _ => None,
    };
    let master_cpu = r.delta.master_cpu / wall;
    let (render, throttled) = (&r.delta.render, &r.delta.throttled);
    let mean = |f: &dyn Fn(usize) -> f64| (0..render.len()).map(f).sum::<f64>() / render.len().max(1) as f64;
    let slave_idle = mean(&|i| (1.0 - (render[i].run + render[i].wait) / wall).max(0.0));
    let slave_quota_use = share.map(|s| mean(&|i| render[i].run / (s * wall)));
    // With a quota, a slave with work gets `share` of a core unless the machine
    // is too busy to give it: the quota it neither used nor left idle was lost
    // to other load. Without one, count the wait for a core beyond throttling.
    let slave_crowded = match slave_quota_use {
        Some(u) => (1.0 - u - slave_idle).clamp(0.0, 1.0),
        None => {
            mean(&|i| ((render[i].wait - throttled.get(i).copied().unwrap_or(0.0)) / wall).clamp(0.0, 1.0))
        }
    };
    let duplicated_per_frame = r.duplicated as f64 / frames.max(1) as f64;
    let d = &r.delta;
    let cpu_per_frame = (d.machine.busy() > 0.0).then(|| {
        let per_frame = |secs: f64| secs * 1e3 / frames.max(1) as f64;
        let render_run: f64 = render.iter().map(|s| s.run).sum();
        let slaves_run: f64 = d.slaves_run.iter().sum();
        let irq = d.machine.irq;
        let named = d.master_run + d.viewer_run + slaves_run;
        CpuPerFrame {
            master: per_frame(d.master_run),
            viewer: per_frame(d.viewer_run),
            slave_render: per_frame(render_run),
            slave_other: per_frame((slaves_run - render_run).max(0.0)),
            irq: per_frame(irq),
            other: per_frame((d.machine.busy() - named - irq).max(0.0)),
            idle: per_frame(d.machine.idle),
            steal: per_frame(d.machine.steal),
        }
    });
    Row {
        width: spec.settings_size.0,
        height: spec.settings_size.1,
        transport: spec.transport.to_string(),
        compression: spec.compression.to_string(),
        rate_mbit: rate,
        pipeline: spec.pipeline,
        slaves: n,
        frames,
        sec_median,
        sec_p95: quantile(&r.secs, 0.95),
        latency_median: median(&r.latency),
        latency_p95: quantile(&r.latency, 0.95),
        first_tile_median: median(&r.first_tile),
        last_tenth_median: median(&r.last_tenth),
        fps: frames as f64 / r.secs.iter().sum::<f64>().max(1e-9),
        speedup: 0.0,
        efficiency: 0.0,
        speedup_median: 0.0,
        efficiency_median: 0.0,
        bytes_per_frame,
        iface_bytes_per_frame: iface.map(|c| c.rx_bytes as f64 / frames.max(1) as f64),
        link_utilisation,
        master_cpu,
        slave_quota_use,
        slave_idle,
        slave_crowded,
        duplicated_per_frame,
        bottleneck: None,
        cpu_per_frame,
    }
}

/// Names the resource that kept a run below the efficiency bar, from its measurements.
fn bottleneck(r: &Row) -> String {
    let mut why = Vec::new();
    if let Some(u) = r.link_utilisation.filter(|&u| u >= 0.7) {
        why.push(format!("link: the master's port ran at {:.0} % of its rate", u * 100.0));
    }
    if r.master_cpu >= 0.7 {
        why.push(format!("master CPU: {:.2} cores busy", r.master_cpu));
    }
    if r.slave_crowded >= 0.05 && r.slave_crowded >= r.slave_idle {
        let takers = r.cpu_per_frame.map(|c| c.takers()).unwrap_or_default();
        why.push(format!(
            "machine CPU: slaves lost {:.0} % of their quota to other load on the machine \
             (the N slaves' quotas add up to the whole machine; other processes compete){takers}",
            r.slave_crowded * 100.0
        ));
    }
    if r.slave_idle >= 0.05 && r.slave_idle > r.slave_crowded {
        why.push(format!(
            "scheduling: slaves' render threads had no tile {:.0} % of the time (round trips between \
             tiles, end-of-frame tail)",
            r.slave_idle * 100.0
        ));
    }
    if r.duplicated_per_frame >= 1.0 {
        why.push(format!("{:.1} straggler tiles rendered twice per frame", r.duplicated_per_frame));
    }
    if why.is_empty() {
        why.push(format!(
            "no single resource saturated (slaves idle {:.0} %, crowded {:.0} %, master CPU {:.2})",
            r.slave_idle * 100.0,
            r.slave_crowded * 100.0,
            r.master_cpu
        ));
    }
    why.join("; ")
}

fn fmt_opt(v: Option<f64>, f: impl Fn(f64) -> String) -> String {
    v.map_or("–".into(), f)
}

/// The Markdown report: Table 1 layout per configuration, then the details.
fn markdown(rep: &Report) -> String {
    let m = &rep.meta;
    let mut out = String::new();
    out.push_str(&format!(
        "Scene `{}`, {} frames (evenly spaced cameras of `{}`, {} run(s) per N pooled); lab: {}{}; tile {} px; load average {} → {}.\n\n",
        m.scene,
        rep.rows.first().map_or(0, |r| r.frames),
        m.path,
        m.repeat,
        if m.lab { "yes" } else { "no (loopback)" },
        match (m.slave_share_of_a_core, m.cfs_quota_us, m.cfs_period_us) {
            (Some(s), Some(q), Some(p)) => format!(
                ", each slave {s:.3} of a core (quota {q} µs / {p} µs{})",
                m.cpu_weight.map(|w| format!(", CPU weight {w}")).unwrap_or_default()
            ),
            _ => String::new(),
        },
        m.tile,
        m.loadavg_before,
        m.loadavg_after
    ));
    for n in &m.lab_notes {
        out.push_str(&format!("Note: {n}.\n\n"));
    }
    let ns: Vec<usize> = {
        let mut v: Vec<usize> = rep.rows.iter().map(|r| r.slaves).collect();
        v.sort_unstable();
        v.dedup();
        v
    };
    let mut header = vec!["PCs".to_string()];
    header.extend(ns.iter().map(|n| n.to_string()));
    let paper_at = |n: usize| PAPER.iter().find(|p| p.0 == n).map(|p| p.1);
    let mut rows = vec![
        std::iter::once("paper 320×240: s/frame".to_string())
            .chain(ns.iter().map(|&n| fmt_opt(paper_at(n), |s| format!("{s:.2}"))))
            .collect::<Vec<_>>(),
        std::iter::once("paper: speedup".to_string())
            .chain(ns.iter().map(|&n| fmt_opt(paper_at(n), |s| format!("{:.2}", PAPER[0].1 / s))))
            .collect(),
    ];
    for key in groups(&rep.rows) {
        let g: Vec<&Row> = rep.rows.iter().filter(|r| group_key(r) == key).collect();
        let at = |n: usize| g.iter().find(|r| r.slaves == n);
        let label = group_label(g[0]);
        rows.push(
            std::iter::once(format!("isin {label}: s/frame"))
                .chain(ns.iter().map(|&n| fmt_opt(at(n).map(|r| r.sec_median), |s| format!("{s:.3}"))))
                .collect(),
        );
        rows.push(
            std::iter::once(format!("isin {label}: speedup"))
                .chain(ns.iter().map(|&n| fmt_opt(at(n).map(|r| r.speedup), |s| format!("{s:.2}"))))
                .collect(),
        );
        rows.push(
            std::iter::once(format!("isin {label}: efficiency"))
                .chain(ns.iter().map(|&n| fmt_opt(at(n).map(|r| r.efficiency), |s| format!("{s:.2}"))))
                .collect(),
        );
    }
    let header_refs: Vec<&str> = header.iter().map(String::as_str).collect();
    out.push_str(&report::table(&header_refs, &rows));
    out.push_str(
        "\nDetails (seconds per frame — intervals between completions — and latency — request to \
         completion —: median / p95; first tile: request to first tile; last tenth: the time a frame \
         took to deliver its last 10 % of pixels; `N open`: frames kept requested at once):\n\n",
    );
    let detail: Vec<Vec<String>> = rep
        .rows
        .iter()
        .map(|r| {
            vec![
                group_label(r),
                r.slaves.to_string(),
                format!("{:.3} / {:.3}", r.sec_median, r.sec_p95),
                format!("{:.3} / {:.3}", r.latency_median, r.latency_p95),
                format!("{:.1} / {:.1}", r.first_tile_median * 1e3, r.last_tenth_median * 1e3),
                format!("{:.2}", r.fps),
                format!("{:.2}", r.speedup),
                format!("{:.2}", r.efficiency),
                format!("{:.2}", r.efficiency_median),
                format!("{:.0}", r.bytes_per_frame / 1e3),
                fmt_opt(r.iface_bytes_per_frame, |b| format!("{:.0}", b / 1e3)),
                fmt_opt(r.link_utilisation, |u| format!("{:.1} %", u * 100.0)),
                format!("{:.2}", r.master_cpu),
                fmt_opt(r.slave_quota_use, |u| format!("{:.0} %", u * 100.0)),
                format!("{:.0} %", r.slave_idle * 100.0),
                format!("{:.0} %", r.slave_crowded * 100.0),
                format!("{:.1}", r.duplicated_per_frame),
                r.bottleneck.clone().unwrap_or_default(),
            ]
        })
        .collect();
    out.push_str(&report::table(
        &[
            "setup",
            "N",
            "s/frame",
            "latency s",
            "first tile / last tenth ms",
            "fps",
            "speedup",
            "eff.",
            "eff. (median s/frame)",
            "kB/frame (transport)",
            "kB/frame (interface)",
            "master link",
            "master CPU",
            "slave quota used",
            "slave idle",
            "slave crowded",
            "dup. tiles/frame",
            "short of 0.9 because",
        ],
        &detail,
    ));
    let cpu: Vec<Vec<String>> = rep
        .rows
        .iter()
        .filter_map(|r| {
            let c = r.cpu_per_frame?;
            let mut v = vec![group_label(r), r.slaves.to_string()];
            v.extend(
                [
                    c.slave_render,
                    c.slave_other,
                    c.master,
                    c.viewer,
                    c.irq,
                    c.other,
                    c.overhead(),
                    c.idle,
                    c.steal,
                ]
                .iter()
                .map(|x| format!("{x:.1}")),
            );
            Some(v)
        })
        .collect();
    if !cpu.is_empty() {
        out.push_str(
            "\nWhere the machine's CPU went, in CPU milliseconds per frame (all cores; `not rendering`: \
             everything but the render threads, idle and steal — at N = N_max it comes out of the slaves' \
             quotas):\n\n",
        );
        out.push_str(&report::table(
            &[
                "setup",
                "N",
                "slaves render",
                "slaves other threads",
                "master",
                "viewer",
                "irq/softirq",
                "other",
                "not rendering",
                "idle",
                "steal",
            ],
            &cpu,
        ));
    }
    out
}

type GroupKey = (u32, u32, String, String, Option<u32>, usize);

fn group_key(r: &Row) -> GroupKey {
    (r.width, r.height, r.transport.clone(), r.compression.clone(), r.rate_mbit, r.pipeline)
}

fn groups(rows: &[Row]) -> Vec<GroupKey> {
    let mut keys: Vec<GroupKey> = Vec::new();
    for r in rows {
        let k = group_key(r);
        if !keys.contains(&k) {
            keys.push(k);
        }
    }
    keys
}

fn group_label(r: &Row) -> String {
    let rate = match r.rate_mbit {
        Some(m) if m >= 1000 => format!(", {} Gbit/s", m / 1000),
        Some(m) => format!(", {m} Mbit/s"),
        None => ", loopback".into(),
    };
    let open = if r.pipeline > 1 { format!(", {} open", r.pipeline) } else { String::new() };
    format!("{}×{} {}/{}{rate}{open}", r.width, r.height, r.transport, r.compression)
}

/// A configuration in plain words, for the plot's legend.
fn plot_label(r: &Row) -> String {
    let rate = match r.rate_mbit {
        Some(m) if m >= 1000 => format!("{} Gbit/s links", m / 1000),
        Some(m) => format!("{m} Mbit/s links"),
        None => "loopback".into(),
    };
    let frames = match r.pipeline {
        1 => "one frame at a time".to_string(),
        2 => "next frame queued".to_string(),
        n => format!("{} frames queued", n - 1),
    };
    format!(
        "isin {}×{}, {}, {}, {rate}, {frames}",
        r.width,
        r.height,
        modes::transport_name(&r.transport),
        modes::compression_name(&r.compression)
    )
}

/// The speedup plot: isin per configuration, the paper, ideal.
fn plot(path: &Path, rows: &[Row]) -> anyhow::Result<()> {
    let n_max = rows.iter().map(|r| r.slaves).max().unwrap_or(12).max(12) as f64;
    let mut series = vec![
        Series {
            name: "ideal: N times one PC".into(),
            points: vec![(1.0, 1.0), (n_max, n_max)],
            color: 6,
            dashed: true,
        },
        Series {
            name: "the paper's cluster, 320×240, 100 Mbit/s LAN (Table 1)".into(),
            points: PAPER.iter().map(|&(n, s)| (n as f64, PAPER[0].1 / s)).collect(),
            color: 5,
            dashed: false,
        },
    ];
    for (i, key) in groups(rows).into_iter().enumerate() {
        let g: Vec<&Row> = rows.iter().filter(|r| group_key(r) == key).collect();
        series.push(Series {
            name: plot_label(g[0]),
            points: g.iter().map(|r| (r.slaves as f64, r.speedup)).collect(),
            color: [0, 1, 2, 3, 4, 7][i % 6],
            dashed: false,
        });
    }
    report::line_plot(
        path,
        &report::Plot {
            title: "Speedup with N slave PCs against one",
            x_label: "slave PCs N",
            y_label: "speedup (frames/s ÷ frames/s of one PC)",
            y_scale: report::YScale::Linear,
            x_names: None,
            series: &series,
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(n: usize, eff: f64) -> Row {
        Row {
            width: 320,
            height: 240,
            transport: "tcp".into(),
            compression: "raw".into(),
            rate_mbit: Some(100),
            pipeline: 1,
            slaves: n,
            frames: 4,
            sec_median: 1.0 / (n as f64 * eff),
            sec_p95: 1.0,
            latency_median: 1.0,
            latency_p95: 1.0,
            first_tile_median: 0.01,
            last_tenth_median: 0.01,
            fps: 1.0,
            speedup: n as f64 * eff,
            efficiency: eff,
            speedup_median: n as f64 * eff,
            efficiency_median: eff,
            bytes_per_frame: 230e3,
            iface_bytes_per_frame: Some(240e3),
            link_utilisation: Some(0.1),
            master_cpu: 0.1,
            slave_quota_use: Some(0.9),
            slave_idle: 0.02,
            slave_crowded: 0.0,
            duplicated_per_frame: 0.0,
            bottleneck: None,
            cpu_per_frame: None,
        }
    }

    #[test]
    fn bottleneck_names_the_saturated_resource() {
        let mut r = row(12, 0.6);
        r.link_utilisation = Some(0.95);
        assert!(bottleneck(&r).starts_with("link"), "{}", bottleneck(&r));
        let mut r = row(12, 0.6);
        r.slave_crowded = 0.3;
        assert!(bottleneck(&r).contains("machine CPU"), "{}", bottleneck(&r));
        // With a CPU account, the takers are named, largest first.
        r.cpu_per_frame = Some(CpuPerFrame {
            master: 4.0,
            viewer: 1.0,
            slave_render: 130.0,
            slave_other: 6.0,
            irq: 2.0,
            other: 9.0,
            idle: 0.0,
            steal: 0.0,
        });
        let b = bottleneck(&r);
        let (other, own, master) =
            (b.find("other processes 9.0"), b.find("network threads 6.0"), b.find("master 4.0"));
        assert!(other < own && own < master && other.is_some(), "{b}");
        let mut r = row(12, 0.6);
        r.slave_idle = 0.3;
        assert!(bottleneck(&r).contains("scheduling"), "{}", bottleneck(&r));
        let mut r = row(12, 0.6);
        r.master_cpu = 0.95;
        assert!(bottleneck(&r).contains("master CPU"), "{}", bottleneck(&r));
    }

    #[test]
    fn speedup_is_throughput_against_the_first_row_and_the_median_one_is_kept() {
        let mut g = vec![row(1, 1.0), row(12, 1.0)];
        (g[0].fps, g[0].sec_median) = (1.0, 0.9);
        (g[1].fps, g[1].sec_median) = (10.8, 0.1);
        g[1].slave_idle = 0.3;
        fill_speedups(&mut g);
        assert!((g[1].speedup - 10.8).abs() < 1e-9 && (g[1].efficiency - 0.9).abs() < 1e-9);
        assert!((g[1].speedup_median - 9.0).abs() < 1e-9 && (g[1].efficiency_median - 0.75).abs() < 1e-9);
        assert!(g[1].bottleneck.is_none(), "0.9 meets the bar");
        g[1].fps = 10.0;
        fill_speedups(&mut g);
        assert!(
            g[1].bottleneck.as_deref().is_some_and(|b| b.contains("scheduling")),
            "{:?}",
            g[1].bottleneck
        );
        assert_eq!((g[0].speedup, g[0].efficiency), (1.0, 1.0));
    }

    #[test]
    fn the_plot_names_its_lines_in_plain_words() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("scaling.svg");
        let mut rows = vec![row(1, 1.0), row(12, 0.95)];
        for r in &mut rows {
            (r.compression, r.pipeline) = ("auto".into(), 2);
        }
        plot(&p, &rows).unwrap();
        let svg = std::fs::read_to_string(&p).unwrap();
        assert!(
            svg.contains("isin 320×240, TLS over TCP, QOI tiles, 100 Mbit/s links, next frame queued"),
            "{svg}"
        );
        assert!(svg.contains("slave PCs N") && svg.contains("frames/s of one PC"), "axis labels");
        for jargon in ["tcp/", "/auto", " open"] {
            assert!(!svg.contains(jargon), "`{jargon}` in the plot");
        }
    }

    #[test]
    fn markdown_puts_paper_and_isin_rows_under_the_pc_counts() {
        let rep = Report {
            meta: Meta {
                scene: "s".into(),
                path: "p".into(),
                cameras_in_path: 4,
                cores: 2,
                lab: true,
                lab_notes: vec![],
                cpu_total: Some(2.0),
                slave_share_of_a_core: Some(1.0 / 6.0),
                cfs_period_us: Some(6000),
                cfs_quota_us: Some(1000),
                tile: 32,
                pipeline: vec![1],
                cpu_weight: Some(8192),
                repeat: 1,
                loadavg_before: "1".into(),
                loadavg_after: "1".into(),
                unix_time: 0,
            },
            paper: PAPER.to_vec(),
            rows: vec![row(1, 1.0), row(12, 0.95)],
        };
        let md = markdown(&rep);
        let header = md.lines().find(|l| l.starts_with("| PCs")).unwrap();
        assert_eq!(header, "| PCs | 1 | 12 |");
        assert!(md.contains("| paper 320×240: s/frame | 2.61 | 0.32 |"), "{md}");
        assert!(md.contains("| paper: speedup | 1.00 | 8.16 |"), "{md}");
        assert!(md.contains("isin 320×240 tcp/raw, 100 Mbit/s: efficiency | 1.00 | 0.95 |"), "{md}");
    }
}

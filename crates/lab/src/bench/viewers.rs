//! `isin bench viewers`: several viewers flying at once on one cluster whose
//! master sits on a slow link, with every tile relayed by the master, then
//! with viewers that take their tiles straight from the slaves
//! ([`isin_cluster::protocol::DirectRoute`]: the master still schedules every
//! tile and checks a sample of them).
//!
//! The lab: the master on a cable of `--master-rate` Mbit/s; the slaves and
//! each viewer on a PC of their own on `--rate` cables. The slaves serve real
//! rendered tiles from a warm frame cache (`isin slave --cache-tiles`, every
//! camera rendered once in a warm-up), so what limits the frames is the
//! network more than the machine's cores. Per mode and number of viewers:
//! each viewer's frames/s (each asks for its next frame as soon as the last
//! is whole), the bytes on the master's cable each way, and the share of the
//! tiles that went straight. Where relayed tiles fill the master's cable,
//! frames/s stop growing with viewers; the crossover is the first number of
//! viewers at which direct delivery serves 5 % more frames in all (beyond it
//! the cores that run every emulated PC may be what limits either way).

use super::procs::{ChildGuard, start_master, start_slave, wait_joined};
use super::report;
use super::{loadavg, parse_list, parse_sizes};
use crate::client as cluster;
use crate::netlab::{self, Lab, LinkSpec, Support};
use anyhow::Context;
use clap::Args;
use isin_actors::viewer::{self, DirectListener, Setup};
use isin_cluster::auth;
use isin_cluster::scheduler::Work;
use isin_tracer::{Camera, RenderSettings};
use serde::Serialize;
use std::path::PathBuf;
use std::sync::{Arc, Barrier};
use std::time::{Duration, Instant};

/// Arguments of `isin bench viewers`.
#[derive(Args, Debug)]
pub struct ViewersArgs {
    /// Scene file the viewers fly (the master's default scene).
    #[arg(long, default_value = "scenes/paper.toml")]
    scene: PathBuf,
    /// Camera path the viewers replay (each from its own starting point).
    #[arg(long, default_value = "scenes/paths/paper.toml")]
    path: PathBuf,
    /// Distinct cameras of the path used (evenly spaced; each rendered once
    /// in the warm-up, then served from the slaves' frame caches).
    #[arg(long, default_value_t = 8)]
    cameras: usize,
    /// Emulated slave PCs.
    #[arg(long, default_value_t = 8)]
    slaves: usize,
    /// Numbers of viewers flying at once, comma-separated.
    #[arg(long, default_value = "1,2,4")]
    viewers: String,
    /// Image size of every viewer's frames, `WxH`.
    #[arg(long, default_value = "640x480")]
    size: String,
    /// Transport: `tcp` or `quic`.
    #[arg(long, default_value = "tcp")]
    transport: String,
    /// Rate of the master's cable in Mbit/s (each way).
    #[arg(long, default_value_t = 100)]
    master_rate: u32,
    /// Rate of every slave's and viewer's cable in Mbit/s.
    #[arg(long, default_value_t = 1000)]
    rate: u32,
    /// Seconds each mode and number of viewers is timed.
    #[arg(long, default_value_t = 10)]
    seconds: u64,
    /// Where the slaves keep rendered frames (`isin slave --cache-tiles`).
    #[arg(long, default_value = "target/bench/frame-cache")]
    cache_dir: PathBuf,
    /// Directory for viewers.json and viewers.md.
    #[arg(long, value_name = "DIR", default_value = "target/bench")]
    out_dir: PathBuf,
}

/// How the viewers get their tiles.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
enum Mode {
    /// Every tile through the master.
    Relay,
    /// Straight from the slaves, a sample through the master.
    Direct,
}

/// One mode at one number of viewers.
#[derive(Clone, Debug, Serialize)]
struct Row {
    mode: Mode,
    viewers: usize,
    /// Frames/s of each viewer.
    fps: Vec<f64>,
    /// All viewers' frames/s together.
    total_fps: f64,
    /// Bits/s out of and into the master's cable.
    master_out_mbit: f64,
    master_in_mbit: f64,
    /// Tiles that went straight, of all tiles.
    direct_share: f64,
    seconds: f64,
}

#[derive(Serialize)]
struct ViewersReport {
    scene: String,
    slaves: usize,
    width: u32,
    height: u32,
    transport: String,
    master_rate_mbit: u32,
    rate_mbit: u32,
    rows: Vec<Row>,
    /// The fewest viewers at which direct delivery served 5 % more frames.
    crossover: Option<usize>,
    cores: usize,
    loadavg_before: String,
    loadavg_after: String,
    unix_time: u64,
}

/// Runs `isin bench viewers`.
pub fn run(args: ViewersArgs) -> anyhow::Result<()> {
    let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
    let (w, h) = *parse_sizes(&args.size)?.first().context("no size")?;
    let counts: Vec<usize> = parse_list(&args.viewers)?;
    let most = counts.iter().copied().max().context("no --viewers")?;
    anyhow::ensure!(args.slaves >= 1 && most >= 1, "--slaves and --viewers must be at least 1");
    let support = Support::probe();
    if let Err(e) = &support.netns {
        anyhow::bail!("this bench needs the lab (network namespaces, root): {e}");
    }
    let path = isin_viewer::CameraPath::load(&args.path)?;
    anyhow::ensure!(!path.frames.is_empty(), "{} has no cameras", args.path.display());
    let n = args.cameras.clamp(1, path.frames.len());
    let cameras: Vec<Camera> = (0..n).map(|i| path.frames[i * path.frames.len() / n].camera()).collect();
    let scene = args.scene.to_str().context("scene path is not UTF-8")?.to_string();
    netlab::install_signal_cleanup()?;
    netlab::cleanup_stale();
    // Slaves first, then one PC per viewer.
    let lab = Lab::new(args.slaves + most, LinkSpec { rate_mbit: Some(args.rate), loss_per_mille: 0 })?;
    lab.set_rate(lab.master(), Some(args.master_rate))?;
    let loadavg_before = loadavg();
    let token = auth::generate_token()?;
    let listen = format!("{}:0", lab.master().addr);
    let transport_args = super::modes::master_args(&args.transport, "auto");
    let (master, ticket) =
        start_master(Some(&lab.master().ns), None, &scene, &listen, &token, &transport_args)?;
    std::fs::create_dir_all(&args.cache_dir)?;
    let cache = vec!["--cache-tiles".to_string(), args.cache_dir.display().to_string()];
    let mut slaves: Vec<ChildGuard> = Vec::new();
    for i in 0..args.slaves {
        let ns = lab.slave(i).map(|h| h.ns.as_str());
        slaves.push(start_slave(ns, None, &ticket, 1, &format!("pc{}", i + 1), &cache)?);
    }
    wait_joined(&master, &mut slaves, Duration::from_secs(120))?;
    let span = Duration::from_secs(args.seconds.max(1));
    let mut rows = Vec::new();
    for mode in [Mode::Relay, Mode::Direct] {
        for &v in &counts {
            let row = run_one(&lab, &ticket, args.slaves, mode, v, &cameras, (w, h), span)?;
            println!(
                "{mode:?} × {v}: {:.2} frames/s in all, master cable {:.1} Mbit/s out, {:.1} in, {:.0} % direct",
                row.total_fps,
                row.master_out_mbit,
                row.master_in_mbit,
                row.direct_share * 100.0
            );
            rows.push(row);
        }
    }
    drop((slaves, master, lab));
    let crossover = counts.iter().copied().find(|&v| {
        let fps = |m| rows.iter().find(|r| r.mode == m && r.viewers == v).map_or(0.0, |r| r.total_fps);
        fps(Mode::Direct) > 1.05 * fps(Mode::Relay)
    });
    let report = ViewersReport {
        scene,
        slaves: args.slaves,
        width: w,
        height: h,
        transport: args.transport.clone(),
        master_rate_mbit: args.master_rate,
        rate_mbit: args.rate,
        rows,
        crossover,
        cores,
        loadavg_before,
        loadavg_after: loadavg(),
        unix_time: report::unix_time(),
    };
    let md = markdown(&report);
    report::write_json_md(&args.out_dir, "viewers", &report, &md)?;
    Ok(())
}

/// `viewers` viewers, each on its own PC, flying for `span` after a warm-up.
#[allow(clippy::too_many_arguments)]
fn run_one(
    lab: &Lab,
    ticket: &isin_transport::Ticket,
    first_pc: usize,
    mode: Mode,
    viewers: usize,
    cameras: &[Camera],
    (w, h): (u32, u32),
    span: Duration,
) -> anyhow::Result<Row> {
    let warm = Arc::new(Barrier::new(viewers + 1));
    let start = Arc::new(Barrier::new(viewers + 1));
    let done = Arc::new(Barrier::new(viewers + 1));
    std::thread::scope(|scope| {
        let handles: Vec<_> = (0..viewers)
            .map(|k| {
                let host = lab.slave(first_pc + k).context("no PC for a viewer")?.clone();
                let (warm, start, done) = (warm.clone(), start.clone(), done.clone());
                Ok(scope.spawn(move || -> anyhow::Result<(f64, u32, u32)> {
                    // A viewer that fails still passes the barriers: the
                    // others and the timing thread never wait for it forever.
                    let stage = std::cell::Cell::new(0u8);
                    let out = netlab::netns::enter(&host.ns).and_then(|()| {
                        actix::System::new().block_on(async {
                            let transport = cluster::client_transport(ticket)?;
                            let name = format!("viewer{}", k + 1);
                            let setup =
                                Setup { name: &name, work: Work::Interactive, scene: None, job: None };
                            let c = match mode {
                                Mode::Relay => {
                                    viewer::connect_with(transport.as_ref(), ticket, setup).await?
                                }
                                Mode::Direct => {
                                    let (server, fingerprint) = cluster::direct_server(ticket.transport)?;
                                    let bind = format!("{}:0", host.addr);
                                    let d = DirectListener::bind(server.as_ref(), &bind, fingerprint).await?;
                                    viewer::connect_direct(transport.as_ref(), ticket, setup, d).await?
                                }
                            };
                            let info = c.default_scene.context("the master serves no scene")?;
                            let settings = RenderSettings { width: w, height: h, ..info.settings };
                            let (v, mut events) = (c.addr, c.events);
                            let offset = k * cameras.len() / viewers;
                            let camera = |i: usize| cameras[(offset + i) % cameras.len()];
                            // Warm-up: every camera once (rendered, or from the cache).
                            for i in 0..cameras.len() {
                                viewer::collect_frame(&v, &mut events, camera(i), settings).await?;
                            }
                            warm.wait();
                            stage.set(1);
                            start.wait();
                            stage.set(2);
                            let t0 = Instant::now();
                            let (mut frames, mut tiles, mut direct) = (0usize, 0u32, 0u32);
                            while t0.elapsed() < span {
                                let (_, stats) =
                                    viewer::collect_frame(&v, &mut events, camera(frames), settings).await?;
                                (tiles, direct) = (tiles + stats.tiles, direct + stats.direct);
                                frames += 1;
                            }
                            let fps = frames as f64 / t0.elapsed().as_secs_f64();
                            let _ = v.send(viewer::Disconnect).await;
                            anyhow::Ok((fps, tiles, direct))
                        })
                    });
                    if stage.get() < 1 {
                        warm.wait();
                    }
                    if stage.get() < 2 {
                        start.wait();
                    }
                    done.wait();
                    out
                }))
            })
            .collect::<anyhow::Result<_>>()?;
        warm.wait();
        let before = (lab.counters(lab.master())?, Instant::now());
        start.wait();
        done.wait();
        let (after, secs) = (lab.counters(lab.master())?, before.1.elapsed().as_secs_f64());
        let results: Vec<(f64, u32, u32)> = handles
            .into_iter()
            .map(|h| h.join().unwrap_or_else(|_| Err(anyhow::anyhow!("viewer panicked"))))
            .collect::<anyhow::Result<_>>()?;
        let d = after.since(&before.0);
        let mbit = |bytes: u64| bytes as f64 * 8.0 / secs / 1e6;
        let (tiles, direct) =
            results.iter().fold((0u64, 0u64), |(t, d), r| (t + u64::from(r.1), d + u64::from(r.2)));
        let fps: Vec<f64> = results.iter().map(|r| r.0).collect();
        Ok(Row {
            mode,
            viewers,
            total_fps: fps.iter().sum(),
            fps,
            master_out_mbit: mbit(d.tx_bytes),
            master_in_mbit: mbit(d.rx_bytes),
            direct_share: if tiles == 0 { 0.0 } else { direct as f64 / tiles as f64 },
            seconds: secs,
        })
    })
}

fn markdown(r: &ViewersReport) -> String {
    let mut out = format!(
        "Viewers flying at once, {}x{}, {} slave PCs on {} Mbit/s cables, the master on {} Mbit/s, {}:\n\n",
        r.width, r.height, r.slaves, r.rate_mbit, r.master_rate_mbit, r.transport
    );
    let rows: Vec<Vec<String>> = r
        .rows
        .iter()
        .map(|row| {
            let mode = match row.mode {
                Mode::Relay => "through the master",
                Mode::Direct => "straight from slaves",
            };
            vec![
                mode.to_string(),
                row.viewers.to_string(),
                format!("{:.2}", row.total_fps / row.viewers.max(1) as f64),
                format!("{:.2}", row.total_fps),
                format!("{:.1}", row.master_out_mbit),
                format!("{:.1}", row.master_in_mbit),
                format!("{:.0} %", row.direct_share * 100.0),
            ]
        })
        .collect();
    out.push_str(&report::table(
        &[
            "tiles",
            "viewers",
            "frames/s each",
            "frames/s in all",
            "master cable out, Mbit/s",
            "in, Mbit/s",
            "tiles direct",
        ],
        &rows,
    ));
    out.push_str(&match r.crossover {
        Some(v) => format!(
            "\nStraight from the slaves first serves 5 % more frames in all than through the master at {v} viewer{}.\n",
            if v == 1 { "" } else { "s" }
        ),
        None => {
            "\nNo crossover: straight from the slaves never served 5 % more frames in all at these numbers of viewers.\n"
                .into()
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_names_each_mode_and_the_crossover() {
        let row = |mode, viewers, total_fps, out| Row {
            mode,
            viewers,
            fps: vec![total_fps / viewers as f64; viewers],
            total_fps,
            master_out_mbit: out,
            master_in_mbit: out,
            direct_share: if mode == Mode::Direct { 0.9 } else { 0.0 },
            seconds: 10.0,
        };
        let mut r = ViewersReport {
            scene: "scenes/paper.toml".into(),
            slaves: 8,
            width: 640,
            height: 480,
            transport: "tcp".into(),
            master_rate_mbit: 100,
            rate_mbit: 1000,
            rows: vec![row(Mode::Relay, 4, 8.0, 95.0), row(Mode::Direct, 4, 20.0, 12.0)],
            crossover: Some(4),
            cores: 2,
            loadavg_before: String::new(),
            loadavg_after: String::new(),
            unix_time: 0,
        };
        let md = markdown(&r);
        assert!(md.contains("| through the master | 4 | 2.00 | 8.00 | 95.0 | 95.0 | 0 % |"), "{md}");
        assert!(md.contains("| straight from slaves | 4 | 5.00 | 20.00 | 12.0 | 12.0 | 90 % |"), "{md}");
        assert!(md.contains("than through the master at 4 viewers."), "{md}");
        r.crossover = None;
        assert!(markdown(&r).contains("No crossover"));
    }
}

//! `isin bench shared`: one cluster shared by several clients at once — two
//! people flying (interactive viewers, each asking for its next frame as soon
//! as the last one is done) and one batch job (an animation, frames queued two
//! ahead) — in the same lab as `isin bench scaling` (N emulated slave PCs,
//! each on its own rate-limited link with a CPU quota).
//!
//! It reports each client's frames/s over the timed span and the cluster's
//! utilisation: the share of the slaves' render-thread time spent rendering
//! or waiting for a core (the rest, no tile to render, is what the clients
//! together left unused). The first frame of every client is a warm-up and
//! the span starts once all three have one.

use super::procs::{ChildGuard, SchedStat, start_master, start_slave, wait_joined};
use super::report;
use super::{loadavg, parse_sizes};
use crate::client as cluster;
use crate::netlab::{self, CpuCgroup, Lab, LinkSpec, Support};
use anyhow::Context;
use clap::Args;
use isin_actors::viewer;
use isin_cluster::auth;
use isin_cluster::scheduler::Work;
use isin_tracer::{Camera, RenderSettings};
use serde::Serialize;
use std::path::PathBuf;
use std::sync::{Arc, Barrier};
use std::time::{Duration, Instant};

/// Arguments of `isin bench shared`.
#[derive(Args, Debug)]
pub struct SharedArgs {
    /// Scene file every client renders (the master's default scene).
    #[arg(long, default_value = "scenes/paper.toml")]
    scene: PathBuf,
    /// Camera path the clients replay (each from its own starting point).
    #[arg(long, default_value = "scenes/paths/paper.toml")]
    path: PathBuf,
    /// Emulated slave PCs.
    #[arg(long, default_value_t = 12)]
    slaves: usize,
    /// Image size of every client's frames, `WxH`.
    #[arg(long, default_value = "320x240")]
    size: String,
    /// Transport: `tcp` or `quic`.
    #[arg(long, default_value = "tcp")]
    transport: String,
    /// Link rate of every PC in Mbit/s.
    #[arg(long, default_value_t = 100)]
    rate: u32,
    /// Seconds of the timed span.
    #[arg(long, default_value_t = 20)]
    seconds: u64,
    /// Cores shared by the slaves (default: all cores), as `bench scaling`.
    #[arg(long)]
    cpu_total: Option<f64>,
    /// CFS weight of every PC's cgroup and of the master's, as `bench scaling`.
    #[arg(long, default_value_t = 8192)]
    cpu_weight: u64,
    /// Directory for shared.json and shared.md.
    #[arg(long, value_name = "DIR", default_value = "target/bench")]
    out_dir: PathBuf,
}

/// One client's figures.
#[derive(Clone, Debug, Serialize)]
struct ClientRow {
    name: String,
    work: String,
    frames: usize,
    fps: f64,
}

#[derive(Serialize)]
struct SharedReport {
    scene: String,
    slaves: usize,
    width: u32,
    height: u32,
    transport: String,
    rate_mbit: Option<u32>,
    lab: bool,
    seconds: f64,
    clients: Vec<ClientRow>,
    /// Share of the slaves' render-thread time rendering or waiting for a core.
    utilisation: f64,
    cores: usize,
    loadavg_before: String,
    loadavg_after: String,
    unix_time: u64,
}

/// What a client does in the timed span.
#[derive(Clone, Copy)]
enum Role {
    Flyer,
    Batch,
}

/// Runs `isin bench shared`.
pub fn run(args: SharedArgs) -> anyhow::Result<()> {
    let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
    let (w, h) = *parse_sizes(&args.size)?.first().context("no size")?;
    anyhow::ensure!(args.slaves >= 1, "--slaves must be at least 1");
    let path = isin_viewer::CameraPath::load(&args.path)?;
    anyhow::ensure!(path.frames.len() >= 3, "{} has too few cameras", args.path.display());
    let cameras: Vec<Camera> = path.frames.iter().map(|f| f.camera()).collect();
    let scene = args.scene.to_str().context("scene path is not UTF-8")?.to_string();
    let support = Support::probe();
    let use_lab = support.netns.is_ok() && support.cpu_quota.is_ok();
    if use_lab {
        netlab::install_signal_cleanup()?;
        netlab::cleanup_stale();
    } else {
        for n in support.describe() {
            println!("note: {n}");
        }
        println!("note: no lab: all processes on loopback, without rate limits or CPU quotas");
    }
    // The same PCs as `bench scaling` at N = slaves.
    let share = args.cpu_total.unwrap_or(cores as f64) / args.slaves as f64;
    let cgroups: Vec<CpuCgroup> = if use_lab {
        (1..=args.slaves)
            .map(|i| CpuCgroup::create(&format!("s{i}"), share))
            .collect::<anyhow::Result<_>>()?
    } else {
        Vec::new()
    };
    let master_cgroup = if use_lab { Some(CpuCgroup::unlimited("master")?) } else { None };
    for cg in cgroups.iter().chain(&master_cgroup) {
        cg.set_weight(args.cpu_weight)?;
    }
    let lab = if use_lab {
        Some(Lab::new(args.slaves, LinkSpec { rate_mbit: Some(args.rate), loss_per_mille: 0 })?)
    } else {
        None
    };
    let loadavg_before = loadavg();
    let token = auth::generate_token()?;
    let master_ns = lab.as_ref().map(|l| l.master().ns.clone());
    let listen = lab.as_ref().map_or("127.0.0.1:0".to_string(), |l| format!("{}:0", l.master().addr));
    let transport_args = super::modes::master_args(&args.transport, "auto");
    let (master, ticket) =
        start_master(master_ns.as_deref(), master_cgroup.as_ref(), &scene, &listen, &token, &transport_args)?;
    let mut slaves: Vec<ChildGuard> = Vec::new();
    for i in 0..args.slaves {
        let ns = lab.as_ref().and_then(|l| l.slave(i)).map(|h| h.ns.as_str());
        slaves.push(start_slave(ns, cgroups.get(i), &ticket, 1, &format!("pc{}", i + 1), &[])?);
    }
    wait_joined(&master, &mut slaves, Duration::from_secs(120))?;
    let pids: Vec<u32> = slaves.iter().map(ChildGuard::pid).collect();
    let render = || pids.iter().map(|&p| SchedStat::read(p, "isin-render")).collect::<Vec<_>>();
    let span = Duration::from_secs(args.seconds.max(1));
    let roles = [("viewer 1", Role::Flyer), ("viewer 2", Role::Flyer), ("batch job", Role::Batch)];
    // Everyone warmed up, then the span starts for all at once.
    let warm = Arc::new(Barrier::new(roles.len() + 1));
    let start = Arc::new(Barrier::new(roles.len() + 1));
    let (rows, utilisation, seconds) = std::thread::scope(|scope| {
        let handles: Vec<_> = roles
            .iter()
            .enumerate()
            .map(|(k, &(name, role))| {
                let (ticket, cameras, master_ns) = (&ticket, &cameras, &master_ns);
                let (warm, start) = (warm.clone(), start.clone());
                scope.spawn(move || -> anyhow::Result<ClientRow> {
                    if let Some(ns) = master_ns {
                        netlab::netns::enter(ns)?;
                    }
                    actix::System::new().block_on(async move {
                        let transport = cluster::client_transport(ticket)?;
                        let work = match role {
                            Role::Flyer => Work::Interactive,
                            Role::Batch => Work::Batch,
                        };
                        let (v, info, mut events) =
                            viewer::connect_as(transport.as_ref(), ticket, name, work).await?;
                        let info = info.context("the master serves no scene")?;
                        let settings = RenderSettings { width: w, height: h, ..info.settings };
                        // Each client starts at its own point of the path.
                        let offset = k * cameras.len() / roles.len();
                        let camera = |i: usize| cameras[(offset + i) % cameras.len()];
                        viewer::collect_frame(&v, &mut events, camera(0), settings).await?;
                        warm.wait();
                        start.wait();
                        let t0 = Instant::now();
                        let mut frames = 0usize;
                        match role {
                            Role::Flyer => {
                                while t0.elapsed() < span {
                                    viewer::collect_frame(&v, &mut events, camera(frames + 1), settings)
                                        .await?;
                                    frames += 1;
                                }
                            }
                            Role::Batch => {
                                let path: Vec<Camera> = (1..100_000).map(camera).collect();
                                let run = viewer::collect_frames(
                                    &v,
                                    &mut events,
                                    &path,
                                    None,
                                    settings,
                                    2,
                                    |_, _, _| {
                                        frames += 1;
                                        anyhow::Ok(())
                                    },
                                );
                                // The span ends mid-job: frames done by then count.
                                let _ = tokio::time::timeout(span.saturating_sub(t0.elapsed()), run).await;
                            }
                        }
                        let secs = t0.elapsed().as_secs_f64();
                        let _ = v.send(viewer::Disconnect).await;
                        let work = match role {
                            Role::Flyer => "interactive",
                            Role::Batch => "batch",
                        };
                        anyhow::Ok(ClientRow {
                            name: name.into(),
                            work: work.into(),
                            frames,
                            fps: frames as f64 / secs,
                        })
                    })
                })
            })
            .collect();
        warm.wait();
        let before = (render(), Instant::now());
        start.wait();
        let rows: Vec<anyhow::Result<ClientRow>> = handles
            .into_iter()
            .map(|h| h.join().unwrap_or_else(|_| Err(anyhow::anyhow!("client panicked"))))
            .collect();
        let (after, wall) = (render(), before.1.elapsed().as_secs_f64());
        let busy: f64 = after
            .iter()
            .zip(&before.0)
            .map(|(a, b)| a.since(b))
            .map(|d| ((d.run + d.wait) / wall).min(1.0))
            .sum();
        (rows, busy / pids.len().max(1) as f64, wall)
    });
    let clients = rows.into_iter().collect::<anyhow::Result<Vec<_>>>()?;
    drop((slaves, master, lab, cgroups, master_cgroup));
    let report = SharedReport {
        scene,
        slaves: args.slaves,
        width: w,
        height: h,
        transport: args.transport.clone(),
        rate_mbit: use_lab.then_some(args.rate),
        lab: use_lab,
        seconds,
        clients,
        utilisation,
        cores,
        loadavg_before,
        loadavg_after: loadavg(),
        unix_time: report::unix_time(),
    };
    let md = markdown(&report);
    report::write_json_md(&args.out_dir, "shared", &report, &md)?;
    Ok(())
}

fn markdown(r: &SharedReport) -> String {
    let mut out = format!(
        "Two viewers flying and one batch job on {} slave PCs{}, {}x{}, {}, {:.0} s:\n\n\
         | client | work | frames | frames/s |\n|---|---|---:|---:|\n",
        r.slaves,
        r.rate_mbit.map(|m| format!(" ({m} Mbit/s links)")).unwrap_or_else(|| " (loopback, no lab)".into()),
        r.width,
        r.height,
        r.transport,
        r.seconds
    );
    for c in &r.clients {
        out.push_str(&format!("| {} | {} | {} | {:.2} |\n", c.name, c.work, c.frames, c.fps));
    }
    out.push_str(&format!(
        "\nCluster utilisation (slaves' render threads busy): {:.1} %\n",
        r.utilisation * 100.0
    ));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_names_every_client_and_the_utilisation() {
        let row = |name: &str, work: &str, fps: f64| ClientRow {
            name: name.into(),
            work: work.into(),
            frames: 10,
            fps,
        };
        let r = SharedReport {
            scene: "scenes/paper.toml".into(),
            slaves: 12,
            width: 320,
            height: 240,
            transport: "tcp".into(),
            rate_mbit: Some(100),
            lab: true,
            seconds: 20.0,
            clients: vec![
                row("viewer 1", "interactive", 6.5),
                row("viewer 2", "interactive", 6.25),
                row("batch job", "batch", 1.5),
            ],
            utilisation: 0.912,
            cores: 2,
            loadavg_before: String::new(),
            loadavg_after: String::new(),
            unix_time: 0,
        };
        let md = markdown(&r);
        assert!(md.contains("12 slave PCs (100 Mbit/s links)"), "{md}");
        assert!(md.contains("| viewer 2 | interactive | 10 | 6.25 |"), "{md}");
        assert!(md.contains("| batch job | batch | 10 | 1.50 |"), "{md}");
        assert!(md.contains("91.2 %"), "{md}");
    }
}

//! `isin bench sync`: a slave joining over a shaped link, and how long it
//! takes until it renders (issue 27, "scene sync at link speed").
//!
//! In the lab ([`crate::netlab`], root only): a master with the scene in a
//! namespace of its own, one slave PC on a cable shaped by tbf to each rate
//! in turn. A viewer in the master's namespace asks for a frame first, so
//! the frame waits for a slave; then the slave starts, and the time from its
//! start (process, handshake, scene transfer, unpacking, loading and BVH
//! build, first tile rendered) to the first tile at the viewer is measured.
//! The slave's log splits the time: the transfer (first chunk to last), the
//! decoding of the bundle and the build ("loaded scene … in … ms, shadow
//! cells … in … ms"). The master's status gives the bytes it sent.
//!
//! Then the same slave rejoins: frozen (SIGSTOP) until the master declares
//! it dead, a new frame requested, thawed; it reconnects holding the scene,
//! so the master sends no scene byte and the first tile comes after a
//! handshake and a tile's render.
//!
//! Goal (the issue's): first tile within 1.5 × the compressed transfer time
//! at link speed plus the slave's own build time.

use super::procs::{start_master, start_slave};
use super::report;
use super::{loadavg, parse_list};
use crate::client as cluster;
use crate::netlab::{self, Lab, LinkSpec, Support};
use anyhow::Context;
use clap::Args;
use isin_actors::viewer::{self, ViewerEvent};
use isin_cluster::auth;
use isin_tracer::RenderSettings;
use serde::Serialize;
use std::path::PathBuf;
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// Arguments of `isin bench sync`.
#[derive(Args, Debug)]
pub struct SyncArgs {
    /// Scene file (the default: the 1.6M-triangle dragon).
    #[arg(long, default_value = "scenes/dragon.toml")]
    scene: PathBuf,
    /// Link rates in Mbit/s, comma-separated.
    #[arg(long, default_value = "1000,100")]
    rates: String,
    /// Transport (tcp or quic).
    #[arg(long, default_value = "tcp")]
    transport: String,
    /// Frame size of the frame whose first tile is timed.
    #[arg(long, default_value_t = 320)]
    width: u32,
    /// Frame height.
    #[arg(long, default_value_t = 240)]
    height: u32,
    /// The slave's render threads (default: every core).
    #[arg(long)]
    threads: Option<usize>,
    /// Directory for sync.json and sync.md.
    #[arg(long, value_name = "DIR", default_value = "target/bench")]
    out_dir: PathBuf,
}

/// One link rate's figures.
#[derive(Clone, Debug, Serialize)]
struct Row {
    rate_mbit: u32,
    /// The encoded bundle, uncompressed.
    raw_bytes: u64,
    /// Its compressed stream.
    compressed_bytes: u64,
    /// What the master counted sent to the slave (frames of the scene).
    scene_bytes_sent: u64,
    /// `raw_bytes` at the link's rate.
    raw_transfer_s: f64,
    /// `scene_bytes_sent` at the link's rate.
    compressed_transfer_s: f64,
    /// The slave's first chunk to its last, as it logged.
    received_s: f64,
    /// Decoding and checking the whole bundle after the last chunk.
    decoded_s: f64,
    /// Loading the scene and building its BVH.
    load_s: f64,
    /// Filling the shadow cells.
    shadow_cells_s: f64,
    triangles: u64,
    /// The slave's start to the first tile at the viewer.
    first_tile_s: f64,
    /// The slave's connection (as the master logs it accepted, TLS done)
    /// to the first tile at the viewer: the "from connect".
    connect_first_tile_s: f64,
    /// 1.5 × the compressed transfer time plus the build (load + shadow cells).
    goal_s: f64,
    /// Whether the first tile from the connection came within the goal.
    met: bool,
    /// The rejoin: scene bytes the master sent (should be 0).
    rejoin_scene_bytes_sent: u64,
    /// The thaw to the first tile of a new frame.
    rejoin_first_tile_s: f64,
}

#[derive(Debug, Serialize)]
struct Report {
    scene: String,
    transport: String,
    width: u32,
    height: u32,
    threads: usize,
    loadavg_before: String,
    loadavg_after: String,
    rows: Vec<Row>,
}

/// Runs `isin bench sync`.
pub fn run(args: SyncArgs) -> anyhow::Result<()> {
    let rates: Vec<u32> = parse_list(&args.rates)?;
    let support = Support::probe();
    if let Err(e) = &support.netns {
        anyhow::bail!("isin bench sync needs the lab (network namespaces, as root): {e}");
    }
    netlab::install_signal_cleanup()?;
    for gone in netlab::cleanup_stale() {
        println!("removed {gone}, left over from an earlier run");
    }
    let scene = args.scene.to_str().context("scene path is not UTF-8")?.to_string();
    let threads = args.threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let loadavg_before = loadavg();
    let mut lab = Lab::new(1, LinkSpec { rate_mbit: rates.first().copied(), loss_per_mille: 0 })?;
    let mut rows = Vec::new();
    for &rate in &rates {
        lab.set_link(LinkSpec { rate_mbit: Some(rate), loss_per_mille: 0 })?;
        println!("sync: one slave PC on a {rate} Mbit/s cable, scene {scene}");
        let row =
            run_once(&lab, &args, &scene, rate, threads).with_context(|| format!("at {rate} Mbit/s"))?;
        println!(
            "  {} bytes sent ({} raw), first tile {:.3} s after the slave's start, {:.3} s after it connected \
             (goal {:.3} s: {}); rejoin: {} bytes, {:.3} s",
            row.scene_bytes_sent,
            row.raw_bytes,
            row.first_tile_s,
            row.connect_first_tile_s,
            row.goal_s,
            if row.met { "met" } else { "missed" },
            row.rejoin_scene_bytes_sent,
            row.rejoin_first_tile_s
        );
        rows.push(row);
    }
    drop(lab);
    let report = Report {
        scene,
        transport: args.transport.clone(),
        width: args.width,
        height: args.height,
        threads,
        loadavg_before,
        loadavg_after: loadavg(),
        rows,
    };
    let md = markdown(&report);
    report::write_json_md(&args.out_dir, "sync", &report, &md)?;
    Ok(())
}

/// What the viewer thread is told to do, and what it answers.
enum Ask {
    /// Request a frame (the camera nudged by this much).
    Frame(f32),
}

/// The first tile's arrival and the master's scene bytes once the frame is done.
type Answer = anyhow::Result<(Instant, u64)>;

fn run_once(lab: &Lab, args: &SyncArgs, scene: &str, rate: u32, threads: usize) -> anyhow::Result<Row> {
    let token = auth::generate_token()?;
    let master_ns = lab.master().ns.clone();
    let listen = format!("{}:0", lab.master().addr);
    let extra: Vec<String> = ["--transport", &args.transport, "--heartbeat-timeout-ms", "1500"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let (master, ticket) = start_master(Some(&master_ns), None, scene, &listen, &token, &extra)?;
    // The viewer's runtime must never block (its actor heartbeats): it
    // awaits its orders on a tokio channel.
    let (ask_tx, mut ask_rx) = tokio::sync::mpsc::unbounded_channel::<Ask>();
    let (asked_tx, asked_rx) = mpsc::channel::<()>();
    let (done_tx, done_rx) = mpsc::channel::<Answer>();
    let (w, h) = (args.width, args.height);
    std::thread::scope(|scope| -> anyhow::Result<Row> {
        let viewer_ticket = ticket.clone();
        let ns = master_ns.clone();
        scope.spawn(move || {
            let mut run = || -> anyhow::Result<()> {
                netlab::netns::enter(&ns)?;
                actix::System::new().block_on(async {
                    let transport = cluster::client_transport(&viewer_ticket)?;
                    let (v, info, mut events) =
                        viewer::connect(transport.as_ref(), &viewer_ticket, "bench").await?;
                    let info = info.context("the master serves no scene")?;
                    let settings = RenderSettings { width: w, height: h, ..info.settings };
                    while let Some(Ask::Frame(nudge)) = ask_rx.recv().await {
                        let mut camera = info.camera;
                        camera.eye.x += nudge;
                        let request = v.send(viewer::RequestFrame { camera, settings }).await?;
                        let _ = asked_tx.send(());
                        let mut first = None;
                        let answer = loop {
                            match events.recv().await {
                                Some(ViewerEvent::Tile { request: r, .. }) if r == request => {
                                    first.get_or_insert_with(Instant::now);
                                }
                                Some(ViewerEvent::FrameDone { request: r, .. }) if r == request => {
                                    let status = v.send(viewer::GetClusterStatus).await?;
                                    let bytes = status.map_or(0, |s| s.scene_bytes_sent);
                                    break first.map(|t| (t, bytes)).context("a frame done without tiles");
                                }
                                Some(ViewerEvent::Error(e)) => {
                                    break Err(anyhow::anyhow!("the master says: {e}"));
                                }
                                Some(ViewerEvent::Closed(why)) => {
                                    break Err(anyhow::anyhow!("viewer connection ended: {why}"));
                                }
                                Some(_) => {}
                                None => break Err(anyhow::anyhow!("viewer events ended")),
                            }
                        };
                        let _ = done_tx.send(answer);
                    }
                    anyhow::Ok(())
                })
            };
            if let Err(e) = run() {
                let _ = done_tx.send(Err(e));
            }
        });
        let timeout = Duration::from_secs(600);
        // The frame waits at the master; the slave starts.
        ask_tx.send(Ask::Frame(0.0))?;
        wait_asked(&asked_rx, &done_rx)?;
        let ns = lab.slave(0).map(|h| h.ns.as_str());
        let t0 = Instant::now();
        let slave = start_slave(ns, None, &ticket, threads, "pc1", &[])?;
        let (first, sent) = done_rx.recv_timeout(timeout).context("no first frame")??;
        let first_tile_s = first.duration_since(t0).as_secs_f64();
        // The master's first connection after the slave started is the slave's.
        let connected = loop {
            let (at, _) = master.wait_for("connection #", Duration::from_secs(5))?;
            if at >= t0 {
                break at;
            }
        };
        let connect_first_tile_s = first.saturating_duration_since(connected).as_secs_f64();
        let (_, received) = slave.wait_for("received: ", Duration::from_secs(5))?;
        let (_, loaded) = slave.wait_for("loaded scene", Duration::from_secs(5))?;
        let loaded = &loaded[loaded.find("loaded scene").unwrap_or(0)..];
        let raw_bytes = number_after(&received, "compressed, ")?;
        let compressed_bytes = number_after(&received, "received: ")?;
        let received_s = number_after_f(&received, "unpacked, in ")?;
        let decoded_s = number_after_f(&received, "decoded in ")?;
        let triangles = number_after(loaded, "(")?;
        let load_s = number_after_f(loaded, "triangles) in ")? / 1e3;
        let shadow_cells_s =
            number_after_f(&loaded[loaded.find("shadow cells").unwrap_or(0)..], ") in ")? / 1e3;
        // The rejoin.
        let pid = slave.pid() as libc::pid_t;
        // SAFETY: signalling a child process this bench started.
        anyhow::ensure!(unsafe { libc::kill(pid, libc::SIGSTOP) } == 0, "cannot stop the slave");
        master.wait_for("dead (Timeout)", Duration::from_secs(30))?;
        ask_tx.send(Ask::Frame(0.01))?;
        wait_asked(&asked_rx, &done_rx)?;
        let t1 = Instant::now();
        // SAFETY: as above.
        anyhow::ensure!(unsafe { libc::kill(pid, libc::SIGCONT) } == 0, "cannot resume the slave");
        let (first2, sent2) = done_rx.recv_timeout(timeout).context("no frame after the rejoin")??;
        drop(ask_tx);
        drop(slave);
        drop(master);
        let secs = |bytes: u64| bytes as f64 * 8.0 / (f64::from(rate) * 1e6);
        let compressed_transfer_s = secs(sent);
        let goal_s = 1.5 * compressed_transfer_s + load_s + shadow_cells_s;
        Ok(Row {
            rate_mbit: rate,
            raw_bytes,
            compressed_bytes,
            scene_bytes_sent: sent,
            raw_transfer_s: secs(raw_bytes),
            compressed_transfer_s,
            received_s,
            decoded_s,
            load_s,
            shadow_cells_s,
            triangles,
            first_tile_s,
            connect_first_tile_s,
            goal_s,
            met: connect_first_tile_s <= goal_s,
            rejoin_scene_bytes_sent: sent2.saturating_sub(sent),
            rejoin_first_tile_s: first2.duration_since(t1).as_secs_f64(),
        })
    })
}

/// Waits for the viewer thread to have sent its request (or to have failed).
fn wait_asked(asked: &mpsc::Receiver<()>, done: &mpsc::Receiver<Answer>) -> anyhow::Result<()> {
    match asked.recv_timeout(Duration::from_secs(30)) {
        Ok(()) => Ok(()),
        Err(_) => match done.try_recv() {
            Ok(Err(e)) => Err(e),
            _ => anyhow::bail!("the viewer sent no request"),
        },
    }
}

/// The decimal number right after `after` in `line`.
fn number_after_f(line: &str, after: &str) -> anyhow::Result<f64> {
    let at = line.find(after).with_context(|| format!("no `{after}` in `{line}`"))? + after.len();
    let text: String = line[at..].chars().take_while(|c| c.is_ascii_digit() || *c == '.').collect();
    text.parse().with_context(|| format!("no number after `{after}` in `{line}`"))
}

/// The whole number right after `after` in `line`.
fn number_after(line: &str, after: &str) -> anyhow::Result<u64> {
    Ok(number_after_f(line, after)? as u64)
}

fn markdown(r: &Report) -> String {
    let mib = |b: u64| format!("{:.2} MiB", b as f64 / (1 << 20) as f64);
    let s = |x: f64| format!("{x:.2} s");
    let rows: Vec<Vec<String>> = r
        .rows
        .iter()
        .map(|x| {
            vec![
                format!("{} Mbit/s", x.rate_mbit),
                mib(x.raw_bytes),
                mib(x.scene_bytes_sent),
                s(x.raw_transfer_s),
                s(x.compressed_transfer_s),
                s(x.received_s),
                s(x.decoded_s),
                s(x.load_s + x.shadow_cells_s),
                s(x.first_tile_s),
                s(x.connect_first_tile_s),
                format!("{} ({})", s(x.goal_s), if x.met { "met" } else { "missed" }),
                format!("{} B", x.rejoin_scene_bytes_sent),
                s(x.rejoin_first_tile_s),
            ]
        })
        .collect();
    let table = report::table(
        &[
            "link",
            "bundle",
            "sent",
            "raw at link",
            "sent at link",
            "received in",
            "decoded in",
            "built in",
            "first tile",
            "from connect",
            "goal",
            "rejoin sent",
            "rejoin first tile",
        ],
        &rows,
    );
    format!(
        "Scene sync: {} ({} triangles) to one slave PC ({} threads) over {}, first tile of a {}×{} frame; \
         load average {} before, {} after.\n\n{table}\n\"built in\": loading the scene and its BVH plus its \
         shadow cells; \"goal\": 1.5 × \"sent at link\" + \"built in\", met or missed by \"from connect\"; \"first tile\" \
         counts from the slave's start (process, handshake, transfer, decoding, build, one tile), \"from \
         connect\" from the master's accepting its connection (TLS done).\n",
        r.scene,
        r.rows.first().map_or(0, |x| x.triangles),
        r.threads,
        r.transport,
        r.width,
        r.height,
        r.loadavg_before,
        r.loadavg_after
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_slaves_log_lines_give_their_numbers() {
        let received = "2026-12-03T06:00:00Z INFO isin_actors::slave::incoming: scene dragon.toml received: \
                        1234 bytes compressed, 5678 unpacked, in 0.250 s (decoded in 0.010 s)";
        assert_eq!(number_after(received, "received: ").unwrap(), 1234);
        assert_eq!(number_after(received, "compressed, ").unwrap(), 5678);
        assert_eq!(number_after_f(received, "unpacked, in ").unwrap(), 0.25);
        assert_eq!(number_after_f(received, "decoded in ").unwrap(), 0.01);
        let loaded = "loaded scene dragon.toml (1600000 triangles) in 2345 ms, shadow cells (12) in 67 ms";
        assert_eq!(number_after(loaded, "(").unwrap(), 1_600_000);
        assert_eq!(number_after_f(loaded, "triangles) in ").unwrap(), 2345.0);
        assert_eq!(number_after_f(&loaded[loaded.find("shadow cells").unwrap()..], ") in ").unwrap(), 67.0);
        assert!(number_after(loaded, "nothing").is_err());
    }
}

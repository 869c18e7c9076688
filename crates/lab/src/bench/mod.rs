//! `isin bench`: measurements of whole clusters of `isin` processes.
//!
//! - [`cluster`]: `isin bench cluster`, frames/s and efficiency of 1–2 local
//!   slaves against in-process rendering, and the reaction to a killed slave;
//! - [`scaling`]: `isin bench scaling`, the paper's Table 1 with N emulated
//!   slave PCs (network namespaces, rate-limited links, CPU quotas);
//! - [`transports`]: `isin bench transports`, TCP against QUIC under rate
//!   limits and packet loss;
//! - [`master`]: `isin bench master`, the master alone at a thousand
//!   simulated slaves;
//! - [`shared`]: `isin bench shared`, two viewers and a batch job on one
//!   emulated cluster at once;
//! - [`sync`]: `isin bench sync`, a slave joining over a shaped link: scene
//!   bytes, transfer, build and first tile, then its rejoin;
//! - [`viewers`]: `isin bench viewers`, several viewers on a master behind a
//!   slow link, tiles relayed by the master against straight from slaves;
//! - [`chaos`]: `isin bench chaos`, a soak of a master, slaves, a viewer and
//!   a batch job under injected faults (kills, stops, link faults);
//! - [`procs`]: starting masters and slaves (inside the lab or on loopback)
//!   and reading their CPU time; [`modes`]: the transport and compression
//!   modes the benches run; [`report`]: statistics, tables and plots;
//!   [`replay`]: replaying a camera path, one frame at a time or pipelined.

mod chaos;
mod cluster;
mod master;
pub mod modes;
pub mod procs;
pub mod replay;
pub mod report;
mod scaling;
mod shared;
mod sync;
mod transports;
mod viewers;

use clap::{Args, Subcommand};

/// Arguments of `isin bench`.
#[derive(Args, Debug)]
pub struct BenchArgs {
    #[command(subcommand)]
    what: BenchCommand,
}

#[derive(Subcommand, Debug)]
enum BenchCommand {
    /// Cluster throughput and efficiency against in-process rendering.
    Cluster(cluster::ClusterBenchArgs),
    /// The paper's Table 1: speedup with 1–12 emulated slave PCs on a 100 Mbit/s LAN.
    Scaling(scaling::ScalingArgs),
    /// TCP against QUIC: frames/s, bytes, latency and CPU under rate limits and loss.
    Transports(transports::TransportsArgs),
    /// Two viewers flying and a batch job on one emulated cluster: frames/s of each, utilisation.
    Shared(shared::SharedArgs),
    /// The master alone at a thousand simulated slaves: scheduler and routing cost, failure detection.
    Master(master::MasterBenchArgs),
    /// A slave joining over a shaped link: scene bytes, transfer, build, first tile; then its rejoin.
    Sync(sync::SyncArgs),
    /// A soak under injected faults: frames lost, byte-identical, recovery after master restarts, memory.
    Chaos(chaos::ChaosArgs),
    /// Several viewers on a master behind a slow link: tiles through the master against straight from slaves.
    Viewers(viewers::ViewersArgs),
}

/// Runs `isin bench`.
pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    match args.what {
        BenchCommand::Cluster(a) => cluster::run_cluster(a),
        BenchCommand::Scaling(a) => scaling::run(a),
        BenchCommand::Transports(a) => transports::run(a),
        BenchCommand::Shared(a) => shared::run(a),
        BenchCommand::Master(a) => master::run(a),
        BenchCommand::Sync(a) => sync::run(a),
        BenchCommand::Chaos(a) => chaos::run(a),
        BenchCommand::Viewers(a) => viewers::run(a),
    }
}

/// `/proc/loadavg`, trimmed: wall-clock figures mean little on a busy machine.
pub fn loadavg() -> String {
    std::fs::read_to_string("/proc/loadavg").unwrap_or_default().trim().to_string()
}

/// A comma-separated list.
pub fn parse_list<T: std::str::FromStr>(s: &str) -> anyhow::Result<Vec<T>> {
    s.split(',').map(|x| x.trim().parse::<T>().map_err(|_| anyhow::anyhow!("bad list item `{x}`"))).collect()
}

/// A comma-separated list of `WxH` sizes.
pub fn parse_sizes(s: &str) -> anyhow::Result<Vec<(u32, u32)>> {
    s.split(',')
        .map(|s| {
            let (w, h) = s.trim().split_once('x').ok_or_else(|| anyhow::anyhow!("size `{s}` is not WxH"))?;
            Ok((w.parse()?, h.parse()?))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lists_and_sizes_parse_and_reject_garbage() {
        assert_eq!(parse_list::<usize>("1, 2,12").unwrap(), vec![1, 2, 12]);
        assert!(parse_list::<usize>("1,x").is_err());
        assert_eq!(parse_sizes("320x240,640x480").unwrap(), vec![(320, 240), (640, 480)]);
        assert!(parse_sizes("320").is_err());
    }
}

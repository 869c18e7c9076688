//! `isin slave`: render tiles for a master.

use super::cluster;
use crate::frame_cache::FrameCache;
use anyhow::Context;
use clap::Args;
use isin_actors::slave::{self, SlaveOptions, Tracer};
use std::sync::Arc;

/// Arguments of `isin slave`.
#[derive(Args, Debug)]
pub struct SlaveArgs {
    /// The master to join.
    #[command(flatten)]
    pub master: super::ticket::TicketArgs,
    /// Render threads (default, or 0: one per core).
    #[arg(long, value_parser = super::bounded::threads)]
    pub threads: Option<usize>,
    /// Name in the master's logs (default: host name and process id).
    #[arg(long)]
    pub name: Option<String>,
    /// For network measurements: render each frame (scene, camera, settings) once,
    /// keep it in DIR (slaves on one machine may share it) and serve every later
    /// tile of it from there — the same bytes, without the tracer's cost.
    #[arg(long, value_name = "DIR")]
    pub cache_tiles: Option<std::path::PathBuf>,
}

/// Runs `isin slave` until refused or killed.
pub fn run(args: SlaveArgs) -> anyhow::Result<()> {
    let ticket = args.master.require()?;
    let transport = cluster::client_transport(&ticket)?;
    let mut opts = SlaveOptions::default();
    // 0 means one per core, as for every command.
    if let Some(n) = args.threads.filter(|&n| n > 0) {
        opts.threads = n;
    }
    opts.name = args.name.unwrap_or_else(|| format!("slave-{}", std::process::id()));
    // Viewers that take their tiles straight are dialled the master's way.
    opts.direct = Some(isin_lab::client::direct_dialer(ticket.transport));
    let cache = match args.cache_tiles {
        Some(dir) => Some(Arc::new(
            FrameCache::new(Tracer, Some(dir.clone()))
                .with_context(|| format!("cannot create the tile cache {}", dir.display()))?,
        )),
        None => None,
    };
    actix::System::new().block_on(async move {
        match cache {
            Some(cache) => slave::run(transport, ticket, opts, cache).await?,
            None => slave::run(transport, ticket, opts, Arc::new(Tracer)).await?,
        }
        anyhow::Ok(())
    })
}

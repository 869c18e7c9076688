//! `isin master`: serve slaves and clients — a default scene, if given, and
//! the scenes clients bring.

use super::cluster;
use crate::assets::load_scene_file;
use clap::Args;
use isin_actors::master::{Master, MasterConfig};
use isin_cluster::codec::Compression;
use isin_cluster::scheduler::SchedulerConfig;
use isin_cluster::{DefaultScene, auth};
use isin_transport::{Ticket, TransportKind};
use std::io::Write;
use std::path::PathBuf;
use std::time::Duration;

/// Arguments of `isin master`.
#[derive(Args, Debug)]
pub struct MasterArgs {
    /// Default scene (TOML, or a mesh file), shown to viewers that name none;
    /// without it clients bring their own (`isin render SCENE --cluster …`).
    pub scene: Option<PathBuf>,
    /// Directory where scenes clients sent and batch jobs are kept (created
    /// if missing), so that after a restart — a crash included — every job
    /// resumes where it was: its client reconnects and is told which frames
    /// are done.
    #[arg(long, value_name = "DIR")]
    pub state: Option<PathBuf>,
    /// Address to listen on (port 0 picks a free port; the ticket shows the real one).
    #[arg(long, default_value = "0.0.0.0:7878")]
    pub listen: String,
    /// Transport: `tcp` or `quic`, both TLS 1.3 with a self-signed certificate
    /// whose fingerprint the ticket carries and slaves pin.
    #[arg(long, default_value = "tcp")]
    pub transport: TransportKind,
    /// Plaintext TCP instead of TLS (trusted networks only: the token still
    /// authenticates, but frames can be read and altered). The ticket then
    /// starts with `isin+tcp-insecure://`.
    #[arg(long)]
    pub insecure: bool,
    /// Directory holding the master's TLS certificate and key (`cert.der`,
    /// `key.der`; created on first use), so tickets survive restarts.
    #[arg(long)]
    pub identity: Option<PathBuf>,
    /// Shared secret slaves and viewers must prove (generated if absent).
    #[arg(long, env = "ISIN_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// Also write the join ticket to this file, readable by its owner only
    /// (mode 0600), for slaves to read with `--ticket-file`.
    #[arg(long, value_name = "PATH")]
    pub ticket_out: Option<PathBuf>,
    /// Tile edge in pixels (halved, down to 16, while a frame would have fewer
    /// than 8 tiles per render thread in the cluster).
    #[arg(long, default_value_t = 32, value_parser = super::bounded::tile)]
    pub tile: u32,
    /// Milliseconds of silence after which a slave is declared dead.
    #[arg(long, default_value_t = 5000, value_parser = super::bounded::heartbeat_ms)]
    pub heartbeat_timeout_ms: u64,
    /// Do not hand idle slaves copies of straggling tiles.
    #[arg(long)]
    pub no_duplicates: bool,
    /// Tile compression: `auto` (the best codec a slave offers: qoi), `raw`,
    /// or a codec (`qoi`, `lz4`; raw for slaves that do not offer it).
    #[arg(long, default_value = "auto")]
    pub compression: Compression,
    /// Tiles queued per slave beyond one per render thread (the in-flight window;
    /// near the end of a frame slaves only get one tile per thread anyway).
    #[arg(long, default_value_t = SchedulerConfig::default().queue_depth, value_parser = super::bounded::queue_depth)]
    pub queue_depth: u32,
}

/// Runs `isin master` until killed.
pub fn run(args: MasterArgs) -> anyhow::Result<()> {
    let default = match &args.scene {
        None => None,
        Some(path) => {
            let (scene, bundle) = load_scene_file(path)?;
            Some(DefaultScene { bundle, camera: scene.camera, settings: scene.settings })
        }
    };
    let token = match args.token {
        Some(t) if t.is_empty() => anyhow::bail!("--token must not be empty"),
        Some(t) => t,
        None => auth::generate_token()?,
    };
    let mut cfg = MasterConfig::serving(token.clone(), default)?;
    cfg.state = args.state.clone();
    cfg.cluster.scheduler.tile_size = args.tile.max(1);
    cfg.cluster.scheduler.heartbeat_timeout = Duration::from_millis(args.heartbeat_timeout_ms.max(1));
    cfg.cluster.scheduler.duplicate_stragglers = !args.no_duplicates;
    cfg.cluster.scheduler.queue_depth = args.queue_depth;
    cfg.cluster.compression = args.compression;
    let kind = match (args.transport, args.insecure) {
        (kind, false) => kind,
        (TransportKind::Tcp | TransportKind::TcpInsecure, true) => TransportKind::TcpInsecure,
        (other, true) => anyhow::bail!("--insecure is for TCP only; --transport {other} is always encrypted"),
    };
    let (transport, fingerprint) = cluster::server_transport(kind, args.identity.as_deref())?;
    actix::System::new().block_on(async move {
        let listener = transport.listen(&args.listen).await?;
        let addr = listener.local_addr();
        let ticket = Ticket { transport: kind, token, addr: addr.clone(), fingerprint };
        if let Some(path) = &args.ticket_out {
            cluster::write_private(path, format!("{ticket}\n").as_bytes())?;
        }
        let mut out = std::io::stdout().lock();
        writeln!(out, "listening {addr}")?;
        writeln!(out, "ticket {ticket}")?;
        writeln!(out, "join with: {}", super::ticket::join_hint(&ticket))?;
        out.flush()?;
        drop(out);
        if addr.starts_with("0.0.0.0") || addr.starts_with("[::]") {
            match &args.ticket_out {
                Some(path) => tracing::warn!(
                    "listening on all interfaces: the ticket in {} names {addr}, which slaves cannot \
                     reach; put this machine's address in its place, or listen on it (--listen ADDR:PORT)",
                    path.display()
                ),
                None => tracing::info!(
                    "listening on all interfaces: give slaves this machine's address in place of {addr}"
                ),
            }
        }
        let _master = Master::new(cfg)?.serve(listener);
        std::future::pending::<()>().await;
        anyhow::Ok(())
    })
}

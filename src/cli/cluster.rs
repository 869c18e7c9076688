//! Shared pieces of the cluster commands, and the embedded default: master,
//! local slaves and a viewer in one process over loopback TLS/TCP — the viewer
//! window when there is a display, a few frames to `paper.png` otherwise.

use crate::assets::load_view;
use actix::Addr;
use anyhow::Context;
use isin_actors::master::{GetStatus, Master, MasterConfig};
use isin_actors::slave::{self, SlaveOptions, Tracer};
use isin_actors::viewer;
use isin_cluster::auth;
use isin_cluster::protocol;
use isin_tracer::{Camera, RenderSettings};
use isin_transport::{Fingerprint, Ticket, Transport, TransportKind};
use isin_transport_quic::QuicTransport;
use isin_transport_tcp::TcpTransport;
use isin_transport_tls::Identity;
use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The transport a master of `kind` listens with (`isin master` picks
/// plaintext only with `--insecure`), and the certificate fingerprint its
/// ticket must carry (the encrypted ones). The master keeps its TLS identity
/// in `identity_dir` when given (created on first use), so tickets stay valid
/// across restarts; otherwise it generates a fresh one.
pub fn server_transport(
    kind: TransportKind,
    identity_dir: Option<&Path>,
) -> anyhow::Result<(Arc<dyn Transport>, Option<Fingerprint>)> {
    let identity = || match identity_dir {
        Some(dir) => load_or_create_identity(dir),
        None => Ok(Identity::generate()?),
    };
    match kind {
        TransportKind::Tcp => {
            let identity = identity()?;
            Ok((Arc::new(TcpTransport::server(&identity)?), Some(identity.fingerprint())))
        }
        TransportKind::TcpInsecure => {
            if identity_dir.is_some() {
                tracing::warn!("--identity is not used by plaintext TCP (--insecure)");
            }
            Ok((Arc::new(TcpTransport::insecure()), None))
        }
        TransportKind::Quic => {
            let identity = identity()?;
            Ok((Arc::new(QuicTransport::server(&identity)?), Some(identity.fingerprint())))
        }
    }
}

/// The transport a slave or viewer reaches the master of `ticket` with: TLS
/// pinning the ticket's fingerprint for `tcp` and `quic`, plaintext only for
/// a `tcp-insecure` ticket (never as a fallback).
pub use isin_lab::client::client_transport;

/// Reads `cert.der` and `key.der` from `dir`, or generates them there.
fn load_or_create_identity(dir: &Path) -> anyhow::Result<Identity> {
    let (cert, key) = (dir.join("cert.der"), dir.join("key.der"));
    if cert.exists() && key.exists() {
        let c = std::fs::read(&cert).with_context(|| format!("cannot read {}", cert.display()))?;
        let k = std::fs::read(&key).with_context(|| format!("cannot read {}", key.display()))?;
        return Ok(Identity::from_der(c.into(), k.into()));
    }
    let identity = Identity::generate()?;
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    std::fs::write(&cert, identity.cert_der().as_ref())
        .with_context(|| format!("cannot write {}", cert.display()))?;
    write_private(&key, identity.key_der().secret_pkcs8_der())?;
    Ok(identity)
}

/// Writes a secret file readable by its owner only.
pub fn write_private(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    use std::io::Write;
    use std::os::unix::fs::OpenOptionsExt;
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(true)
        .mode(0o600)
        .open(path)
        .with_context(|| format!("cannot write {}", path.display()))?;
    // An existing file keeps its mode through `open`: narrowed here.
    f.set_permissions(std::os::unix::fs::PermissionsExt::from_mode(0o600))
        .with_context(|| format!("cannot restrict {} to its owner", path.display()))?;
    f.write_all(bytes).with_context(|| format!("cannot write {}", path.display()))
}

/// How long a client keeps trying to reach a master at most between two
/// attempts.
const CLIENT_MAX_BACKOFF: Duration = Duration::from_secs(5);

/// Connects a client to the master of `ticket` as `setup` says, retrying
/// with capped exponential backoff while the master cannot be reached (it
/// may be restarting), and saying so once a minute. Gives up at once when
/// retrying cannot help (a wrong token or fingerprint, a refused scene).
///
/// With `direct` (`HOST:PORT`), the client listens there for slaves that
/// deliver its tiles straight ([`viewer::connect_direct`]).
pub async fn connect_client(
    transport: &dyn Transport,
    ticket: &Ticket,
    setup: viewer::Setup<'_>,
    direct: Option<&str>,
) -> anyhow::Result<viewer::Connected> {
    let mut backoff = Duration::from_millis(100);
    let mut said: Option<Instant> = None;
    loop {
        match connect_once(transport, ticket, setup, direct).await? {
            Ok(c) => return Ok(c),
            Err(e) if !e.is_retryable() => {
                return Err(
                    anyhow::Error::new(e).context(format!("cannot use the master at {}", ticket.addr))
                );
            }
            Err(e) => {
                if said.is_none_or(|at| at.elapsed() >= isin_actors::slave::RETRY_REPORT) {
                    said = Some(Instant::now());
                    tracing::warn!(
                        "cannot reach the master at {} yet ({e}); retrying (said again in a minute)",
                        ticket.addr
                    );
                }
                tokio::time::sleep(backoff).await;
                backoff = (backoff * 2).min(CLIENT_MAX_BACKOFF);
            }
        }
    }
}

/// One attempt of [`connect_client`]: the outer error is this machine's
/// (the `direct` address cannot be listened on), the inner the master's.
pub async fn connect_once(
    transport: &dyn Transport,
    ticket: &Ticket,
    setup: viewer::Setup<'_>,
    direct: Option<&str>,
) -> anyhow::Result<Result<viewer::Connected, isin_actors::client::JoinError>> {
    Ok(match direct {
        None => viewer::connect_with(transport, ticket, setup).await,
        Some(addr) => {
            let (server, fingerprint) = isin_lab::client::direct_server(ticket.transport)?;
            let listener = viewer::DirectListener::bind(server.as_ref(), addr, fingerprint)
                .await
                .with_context(|| format!("--direct {addr}"))?;
            viewer::connect_direct(transport, ticket, setup, listener).await
        }
    })
}

/// Runs `job` within `timeout` (if given), as `--timeout` asks.
pub async fn within<T>(
    timeout: Option<Duration>,
    job: impl std::future::Future<Output = anyhow::Result<T>>,
) -> anyhow::Result<T> {
    match timeout {
        None => job.await,
        Some(t) => tokio::time::timeout(t, job)
            .await
            .map_err(|_| anyhow::anyhow!("gave up after --timeout {} s", t.as_secs_f64()))?,
    }
}

/// Renders one frame of the scene at `path` through the cluster of
/// `ticket`: the scene goes to the master unless it holds it already, and
/// the scene's own camera and settings are used, with the given overrides.
/// If the master is lost mid-frame (a restart), the client reconnects and
/// asks again.
pub fn render_frame(
    ticket: &Ticket,
    direct: Option<&str>,
    path: &Path,
    width: Option<u32>,
    height: Option<u32>,
    spp: Option<u32>,
    timeout: Option<Duration>,
) -> anyhow::Result<(isin_tracer::Frame, isin_cluster::protocol::FrameStats, String, u64)> {
    let transport = client_transport(ticket)?;
    let (camera, settings, bundle) = load_view(path)?;
    let name = protocol::served_name(&bundle.name).to_string();
    // As a local render: the scene's aspect kept, another shape widening the view.
    let mut settings = settings.resized(width, height);
    settings.spp = spp.unwrap_or(settings.spp);
    let camera = camera.fit_aspect(settings.width as f32 / settings.height as f32);
    actix::System::new().block_on(within(timeout, async move {
        // A still: batch work, which fills what people flying leave.
        let work = isin_cluster::scheduler::Work::Batch;
        let setup = viewer::Setup { name: "render", work, scene: Some(&bundle), job: None };
        loop {
            let mut c = connect_client(transport.as_ref(), ticket, setup, direct).await?;
            match viewer::collect_frame(&c.addr, &mut c.events, camera, settings).await {
                Ok((frame, stats)) => {
                    let wire = c.addr.send(viewer::GetWireStats).await?;
                    return Ok((frame, stats, name, wire.bytes_received));
                }
                Err(viewer::ViewerError::Lost(why)) => tracing::warn!("{why}; reconnecting"),
                Err(e) => return Err(e.into()),
            }
        }
    }))
}

/// Local slaves of the embedded default.
const DEFAULT_SLAVES: usize = 2;

/// The default scene, `scenes/paper.toml`, built into the binary with its
/// textures: `isin` alone works wherever the binary is, checkout or not.
fn default_scene() -> anyhow::Result<(isin_tracer::Scene, isin_tracer::SceneBundle)> {
    let mut assets = std::collections::BTreeMap::new();
    assets.insert("textures/wood.png".to_string(), include_bytes!("../../scenes/textures/wood.png").to_vec());
    assets.insert(
        "textures/bricks.png".to_string(),
        include_bytes!("../../scenes/textures/bricks.png").to_vec(),
    );
    let source = include_str!("../../scenes/paper.toml").to_string();
    let bundle = isin_tracer::SceneBundle { name: "paper.toml".into(), source, assets };
    let scene = bundle.load()?;
    Ok((scene, bundle))
}

/// Starts a master on loopback and `slaves` local slaves splitting `threads`
/// render threads (0: one per core); must run inside an actix system.
/// Returns the master and its ticket.
async fn start_embedded(
    cfg: MasterConfig,
    slaves: usize,
    threads: usize,
) -> anyhow::Result<(Addr<Master>, Ticket)> {
    let slaves = slaves.max(1);
    let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
    let threads = (if threads == 0 { cores } else { threads } / slaves).max(1);
    // TLS even on loopback: the printed ticket lets slaves of other processes join.
    let identity = Identity::generate()?;
    let tcp: Arc<dyn Transport> = Arc::new(TcpTransport::both(&identity, identity.fingerprint())?);
    let listener = tcp.listen("127.0.0.1:0").await?;
    let ticket = Ticket {
        transport: TransportKind::Tcp,
        token: cfg.cluster.token.clone(),
        addr: listener.local_addr(),
        fingerprint: Some(identity.fingerprint()),
    };
    println!("embedded cluster: master on {} with {slaves} local slaves × {threads} threads", ticket.addr);
    println!("join more slaves with: {}", super::ticket::join_hint(&ticket));
    let master = Master::new(cfg)?.serve(listener);
    for i in 0..slaves {
        let opts = SlaveOptions {
            name: format!("local{i}"),
            threads,
            direct: Some(isin_lab::client::direct_dialer(TransportKind::Tcp)),
            ..SlaveOptions::default()
        };
        let (t, tk) = (tcp.clone(), ticket.clone());
        actix::spawn(async move {
            if let Err(e) = slave::run(t, tk, opts, Arc::new(Tracer)).await {
                tracing::error!("local slave stopped: {e}");
            }
        });
    }
    // The local slaves join within moments (they load the scene first): the
    // viewer starts once they have, not with a frame that waits for them.
    let deadline = Instant::now() + std::time::Duration::from_secs(30);
    while master.send(GetStatus).await?.slaves.len() < slaves && Instant::now() < deadline {
        tokio::time::sleep(std::time::Duration::from_millis(10)).await;
    }
    Ok((master, ticket))
}

/// `isin` with no arguments: a whole cluster in one process, shown in the
/// viewer window when there is a display.
pub fn run_default(window: &super::view::WindowArgs) -> anyhow::Result<()> {
    match isin_viewer::check_display() {
        Ok(()) => run_default_window(window),
        Err(e) => {
            run_default_headless()?;
            println!("{e}");
            println!(
                "the viewer needs a display: `isin view SCENE` (or `isin view --connect TICKET` on a \
                 cluster); headless, `isin render SCENE -o out.png`"
            );
            Ok(())
        }
    }
}

/// The embedded cluster on a thread of its own, the viewer window on the main thread.
fn run_default_window(window: &super::view::WindowArgs) -> anyhow::Result<()> {
    let (scene, bundle) = default_scene()?;
    let token = auth::generate_token()?;
    let extent = super::view::scene_extent(&scene);
    let cfg = MasterConfig::new(token, bundle, scene.camera, scene.settings)?;
    drop(scene);
    run_embedded_window(cfg, DEFAULT_SLAVES, 0, extent, window)
}

/// The viewer window on a cluster of its own: a master serving `cfg`'s
/// default scene and `slaves` local slaves with `threads` render threads in
/// all (0: one per core), on a thread of their own, the window on the main
/// thread. `isin view SCENE` and the default `isin` both render this way, the
/// same path as a remote cluster's. `extent` (the scene's size) scales the
/// navigation steps.
pub fn run_embedded_window(
    cfg: MasterConfig,
    slaves: usize,
    threads: usize,
    extent: f32,
    window: &super::view::WindowArgs,
) -> anyhow::Result<()> {
    let (ticket_tx, ticket_rx) = std::sync::mpsc::channel();
    std::thread::Builder::new()
        .name("isin-embedded-cluster".into())
        .spawn(move || {
            actix::System::new().block_on(async move {
                let started = start_embedded(cfg, slaves, threads).await;
                let ok = started.is_ok();
                let _ = ticket_tx.send(started.map(|(_, ticket)| ticket));
                if ok {
                    // Serves until the process ends with the window.
                    std::future::pending::<()>().await;
                }
            });
        })
        .context("cannot start the embedded cluster")?;
    let ticket = ticket_rx.recv().context("the embedded cluster did not start")??;
    super::view::run_remote(ticket, Some(extent), None, None, window)
}

/// Without a display: a few frames through the embedded cluster, the first
/// written to `paper.png`.
fn run_default_headless() -> anyhow::Result<()> {
    let (scene, bundle) = default_scene()?;
    let token = auth::generate_token()?;
    let cfg = MasterConfig::new(token, bundle, scene.camera, scene.settings)?;
    let settings: RenderSettings = scene.settings;
    let camera: Camera = scene.camera;
    drop(scene);
    actix::System::new().block_on(async move {
        let (master, ticket) = start_embedded(cfg, DEFAULT_SLAVES, 0).await?;
        let tcp = client_transport(&ticket)?;
        let (v, _, mut events) = viewer::connect(tcp.as_ref(), &ticket, "embedded-viewer").await?;
        // A few camera moves, as a user at the viewer would make.
        let mut cam = camera;
        for step in 0..3 {
            let t0 = Instant::now();
            let (frame, stats) = viewer::collect_frame(&v, &mut events, cam, settings).await?;
            let ms = t0.elapsed().as_secs_f64() * 1e3;
            let per: Vec<String> = stats.per_slave.iter().map(|(k, n)| format!("{k}: {n}")).collect();
            println!(
                "frame {step}: {}x{} in {ms:.1} ms, {} tiles ({}), {} duplicated",
                settings.width,
                settings.height,
                stats.tiles,
                per.join(", "),
                stats.duplicated
            );
            if step == 0 {
                image::save_buffer(
                    "paper.png",
                    &frame.rgb,
                    frame.width,
                    frame.height,
                    image::ColorType::Rgb8,
                )
                .context("cannot write paper.png")?;
                println!("wrote paper.png");
            }
            cam.yaw(0.08);
        }
        let status = master.send(GetStatus).await?;
        for s in &status.slaves {
            println!(
                "slave {:<10} {} threads, {} tiles, {:.2} Mpixels, {} wasted",
                s.name,
                s.threads,
                s.tiles_done,
                s.pixels_done as f64 / 1e6,
                s.wasted
            );
        }
        println!(
            "wire: {:.2} MB received, {:.2} MB sent by the master",
            status.wire.bytes_received as f64 / 1e6,
            status.wire.bytes_sent as f64 / 1e6
        );
        actix::System::current().stop();
        anyhow::Ok(())
    })
}

//! Shared pieces of the cluster commands, and the embedded default: master,
//! local slaves and a viewer in one process over loopback TLS/TCP — the viewer
//! window when there is a display, a few frames to `paper.png` otherwise.

use crate::assets::load_bundle;
use actix::Addr;
use anyhow::Context;
use isin_actors::master::{GetStatus, Master, MasterConfig};
use isin_actors::slave::{self, SlaveOptions, Tracer};
use isin_actors::viewer;
use isin_cluster::auth;
use isin_cluster::protocol::{self, SceneInfo};
use isin_tracer::{Camera, RenderSettings};
use isin_transport::{Fingerprint, Ticket, Transport, TransportKind};
use isin_transport_quic::QuicTransport;
use isin_transport_tcp::TcpTransport;
use isin_transport_tls::Identity;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

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
pub fn client_transport(ticket: &Ticket) -> anyhow::Result<Arc<dyn Transport>> {
    Ok(match ticket.transport {
        TransportKind::Tcp => Arc::new(TcpTransport::client(ticket.pinned()?)?),
        TransportKind::TcpInsecure => Arc::new(TcpTransport::insecure()),
        TransportKind::Quic => Arc::new(QuicTransport::client(ticket.pinned()?)?),
    })
}

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

/// Refuses to go on when the master of a cluster serves another scene than
/// `path` (a master serves the scene it was started with).
pub fn check_scene(served: &SceneInfo, path: &Path) -> anyhow::Result<()> {
    let ours = protocol::served_scene_hash(&load_bundle(path)?);
    anyhow::ensure!(
        ours == served.hash,
        "the master serves {} (scene {}), not {} (scene {}): a master renders the scene it was \
         started with; start one with `isin master {}`",
        served.name,
        protocol::short_hash(&served.hash),
        path.display(),
        protocol::short_hash(&ours),
        path.display()
    );
    Ok(())
}

/// Renders one frame of the scene at `path` through the cluster of
/// `ticket` (whose master must serve that scene); the scene's camera and
/// settings come from the master, with the given overrides.
pub fn render_frame(
    ticket: &Ticket,
    path: &Path,
    width: Option<u32>,
    height: Option<u32>,
    spp: Option<u32>,
) -> anyhow::Result<(isin_tracer::Frame, isin_cluster::protocol::FrameStats, String, u64)> {
    let transport = client_transport(ticket)?;
    actix::System::new().block_on(async move {
        // A still: batch work, which fills what people flying leave.
        let work = isin_cluster::scheduler::Work::Batch;
        let (v, scene, mut events) = viewer::connect_as(transport.as_ref(), ticket, "render", work).await?;
        check_scene(&scene, path)?;
        // As a local render: the scene's aspect kept, another shape widening the view.
        let mut settings = scene.settings.resized(width, height);
        settings.spp = spp.unwrap_or(settings.spp);
        let camera = scene.camera.fit_aspect(settings.width as f32 / settings.height as f32);
        let (frame, stats) = viewer::collect_frame(&v, &mut events, camera, settings).await?;
        let wire = v.send(viewer::GetWireStats).await?;
        Ok((frame, stats, scene.name, wire.bytes_received))
    })
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

/// Starts a master on loopback and `slaves` local slaves splitting the cores;
/// must run inside an actix system. Returns the master and its ticket.
async fn start_embedded(cfg: MasterConfig, slaves: usize) -> anyhow::Result<(Addr<Master>, Ticket)> {
    let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
    let threads = (cores / slaves).max(1);
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
        let opts = SlaveOptions { name: format!("local{i}"), threads, ..SlaveOptions::default() };
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
    let (ticket_tx, ticket_rx) = std::sync::mpsc::channel();
    std::thread::Builder::new()
        .name("isin-embedded-cluster".into())
        .spawn(move || {
            actix::System::new().block_on(async move {
                let started = start_embedded(cfg, DEFAULT_SLAVES).await;
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
    super::view::run_remote(ticket, Some(extent), window)
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
        let (master, ticket) = start_embedded(cfg, DEFAULT_SLAVES).await?;
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

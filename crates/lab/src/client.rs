//! What the benches (and `isin` itself) need of a cluster client: the
//! transport a ticket names, how slaves and viewers reach each other for
//! tiles that skip the master, and a scene read from disk for the
//! in-process baseline.

use anyhow::Context;
use isin_actors::slave::Dialer;
use isin_tracer::{AssetSource, Scene, SceneBundle};
use isin_transport::{Fingerprint, Ticket, Transport, TransportKind};
use isin_transport_quic::QuicTransport;
use isin_transport_tcp::TcpTransport;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

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

/// How a slave of a master speaking `kind` reaches a viewer that takes its
/// tiles straight: the same transport, TLS pinning the certificate the
/// viewer's offer names (plain TCP's masters: TLS over TCP for an offer
/// with a fingerprint). An offer without one is dialled only by a slave
/// whose master speaks plaintext itself.
pub fn direct_dialer(kind: TransportKind) -> Dialer {
    Dialer::new(move |fingerprint| {
        let fingerprint = fingerprint
            .map(str::parse::<Fingerprint>)
            .transpose()
            .map_err(|e| format!("the viewer's offer: {e}"))?;
        let transport = match (kind, fingerprint) {
            (TransportKind::TcpInsecure, Some(_)) => TransportKind::Tcp,
            (TransportKind::TcpInsecure, None) => TransportKind::TcpInsecure,
            (k, Some(_)) => k,
            (_, None) => return Err("the viewer offers plaintext; this cluster speaks TLS".into()),
        };
        let ticket = Ticket { transport, token: String::new(), addr: String::new(), fingerprint };
        client_transport(&ticket).map_err(|e| e.to_string())
    })
}

/// The transport a viewer listens for slaves with, beside its connection
/// to a master speaking `kind`, and the fingerprint of its certificate: a
/// fresh identity (the viewer's offer carries it to the slaves through the
/// master); plaintext for a plaintext master.
pub fn direct_server(kind: TransportKind) -> anyhow::Result<(Arc<dyn Transport>, Option<Fingerprint>)> {
    if kind == TransportKind::TcpInsecure {
        return Ok((Arc::new(TcpTransport::insecure()), None));
    }
    let identity = isin_transport_tls::Identity::generate()?;
    let fingerprint = Some(identity.fingerprint());
    Ok(match kind {
        TransportKind::Quic => (Arc::new(QuicTransport::server(&identity)?), fingerprint),
        _ => (Arc::new(TcpTransport::server(&identity)?), fingerprint),
    })
}

/// Assets read relative to the scene file's directory.
struct DiskAssets {
    base: PathBuf,
    read: BTreeMap<String, Vec<u8>>,
}

impl AssetSource for DiskAssets {
    fn read(&mut self, path: &str) -> Result<Vec<u8>, String> {
        if let Some(bytes) = self.read.get(path) {
            return Ok(bytes.clone());
        }
        let full = self.base.join(path);
        let bytes = std::fs::read(&full).map_err(|e| format!("cannot read {}: {e}", full.display()))?;
        self.read.insert(path.to_owned(), bytes.clone());
        Ok(bytes)
    }
}

/// Loads a scene file (`.toml`), or the scene made around a mesh file
/// (`.gltf`, `.glb`, `.obj`), and the assets it refers to.
pub fn load_scene_file(path: &Path) -> anyhow::Result<(Scene, SceneBundle)> {
    let base = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let mut assets = DiskAssets { base, read: BTreeMap::new() };
    let mesh = path
        .file_name()
        .and_then(|f| f.to_str())
        .filter(|f| isin_tracer::scenefile::MeshFormat::from_path(f).is_some());
    let (name, source) = match mesh {
        Some(file) => (
            format!("{} (scene made around it)", path.display()),
            isin_tracer::scenefile::mesh_scene(file, &mut assets)?,
        ),
        None => (
            path.display().to_string(),
            std::fs::read_to_string(path)
                .with_context(|| format!("cannot read scene file {}", path.display()))?,
        ),
    };
    let parts = isin_tracer::parse_scene(&name, &source, &mut assets)?;
    Ok((Scene::new(parts), SceneBundle { name, source, assets: assets.read }))
}

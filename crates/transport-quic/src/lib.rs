//! # isin-transport-quic — the cluster transport over QUIC
//!
//! [`QuicTransport`] implements the same [`Transport`] interface as TCP, on
//! quinn with rustls (ring provider), so the actors cannot tell them apart.
//!
//! ## Why a stream per tile
//! Over TCP every byte waits for every byte before it: one lost packet stalls
//! all tiles queued behind it until the retransmission arrives (Linux's minimum
//! retransmission timeout is 200 ms). QUIC streams are delivered independently,
//! so each tile travels on its own unidirectional stream and a loss delays only
//! the tile it hit. Not every message may be reordered, though: the handshake
//! (`Challenge`, `Hello`, `Welcome`, `SceneBegin` and its chunks, `Ready`), `Cancel` after
//! `TileAssignment`, or `FrameDone` after the last `FrameTile` rely on order.
//! So a connection also has one long-lived control stream for *ordered*
//! frames, and each frame records how many frames of the other kind preceded
//! it: an ordered frame is delivered after everything sent before it, an
//! independent frame after the ordered frames sent before it, and independent
//! frames overtake only each other (details in [`wire`]). Which frames are
//! independent is the sender's choice ([`Delivery`](isin_transport::Delivery),
//! given to [`FrameSender::send_as`](isin_transport::FrameSender::send_as)):
//! the transport never looks inside a frame. [`QuicOptions::single_stream`]
//! puts everything on the control stream instead, for comparison.
//!
//! ## Why pinning
//! The master has no certificate from an authority: it generates a
//! self-signed one at start ([`tls::Identity::generate`]) and its SHA-256
//! fingerprint goes into the join ticket next to the token. A slave accepts
//! exactly that certificate ([`tls::PinnedServerVerifier`]), so it cannot be
//! talked into a man-in-the-middle, and the token-based mutual authentication
//! of the actors then runs inside an encrypted session. There is no "accept
//! any certificate" mode. The [`tls`] module builds plain rustls
//! configurations so TLS over TCP can use the same identity and pinning.
//!
//! ## Tuning
//! [`QuicOptions`]: 1 s keep-alives and a 3 s idle timeout (a vanished peer
//! sends no FIN over UDP; this way its connection ends — `recv` yields `None`
//! — before the master's 5 s heartbeat timeout, as a killed TCP peer's
//! would), 4 MiB UDP socket
//! buffers set explicitly, 256 frame streams of 2 MiB windows in a bounded
//! 32 MiB connection window (room for many 12–100 KB tiles in flight, but not
//! for a peer to make this side buffer without limit), and a 5 ms ACK delay
//! requested from the peer so a lost last packet is probed quickly.
//!
//! ## Restarts
//! A master restarted with the same identity (`isin master --identity`) keeps
//! its stateless-reset key, derived from the identity's private key
//! ([`reset_key`]): a peer still holding a connection to the master that
//! died gets a stateless reset from the new one for its next packet (a
//! keep-alive at the latest) and reconnects at once, instead of waiting out
//! the idle timeout for an answer that never comes.
//!
//! ## Limits
//! As on every transport, an announced frame is checked against the maximum
//! frame and reserved from the listener's memory budget before its bytes are
//! read, and must arrive within the frame timeout; refusals close the
//! connection with [`CLOSE_TOO_LARGE`], [`CLOSE_OVER_BUDGET`] or
//! [`CLOSE_FRAME_TIMEOUT`]. Reservations are held while a frame waits in the
//! sequencer, so frames held back for ordering count against the budget too.
//!
//! ## Counting
//! Each connection counts frames and their framing like every transport
//! (`ConnStats`); [`QuicTransport::wire_stats`] adds what QUIC itself put on
//! the wire over all of a transport's connections — UDP bytes and datagrams,
//! losses, ACKs — for cross-checking (about 2.5 % over the frame bytes for
//! 12 KB tiles on loopback).
//!
//! ## Example
//! ```no_run
//! # async fn demo() -> Result<(), Box<dyn std::error::Error>> {
//! use isin_transport::Transport;
//! use isin_transport_quic::{QuicTransport, tls::Identity};
//! let identity = Identity::generate()?;
//! let fingerprint = identity.fingerprint(); // goes into the join ticket
//! let master = QuicTransport::server(&identity)?;
//! let mut listener = master.listen("0.0.0.0:7878").await?;
//! // On the slave, from the ticket:
//! let slave = QuicTransport::client(fingerprint)?;
//! let conn = slave.connect("master.example:7878").await?;
//! # Ok(()) }
//! ```

pub mod config;
mod conn;
pub mod stats;
pub mod wire;

pub use config::QuicOptions;
pub use conn::{CLOSE_DONE, CLOSE_FRAME_TIMEOUT, CLOSE_OVER_BUDGET, CLOSE_PROTOCOL, CLOSE_TOO_LARGE};
/// The TLS identity and pinning shared with TCP (the `isin-transport-tls` crate).
pub use isin_transport_tls as tls;
pub use stats::WireStats;

use hmac::{Hmac, Mac};
use isin_transport::{
    BoxFuture, ConnShared, Connection, INITIAL_MAX_FRAME, Listener, ListenerLimits, MemoryBudget, Transport,
    TransportError,
};
use quinn::crypto::rustls::{QuicClientConfig, QuicServerConfig};
use quinn::{Endpoint, EndpointConfig, TokioRuntime, VarInt};
use sha2::{Digest, Sha256};
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;
use tls::{Fingerprint, Identity, TlsError};
use tokio::sync::mpsc;

/// Connections accepted but not yet taken by [`Listener::accept`].
const ACCEPT_QUEUE: usize = 64;

/// QUIC transport: a server side (with the master's [`Identity`]) and/or a
/// client side (pinning the master's [`Fingerprint`]).
#[derive(Clone)]
pub struct QuicTransport {
    server: Option<Arc<QuicServerConfig>>,
    /// The listening side's stateless-reset key (from its identity).
    reset: Option<Arc<ResetKey>>,
    pinned: Option<Fingerprint>,
    identity: Option<Fingerprint>,
    options: QuicOptions,
    registry: Arc<stats::Registry>,
}

impl std::fmt::Debug for QuicTransport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("QuicTransport")
            .field("identity", &self.identity)
            .field("pinned", &self.pinned)
            .field("options", &self.options)
            .finish_non_exhaustive()
    }
}

fn quic_server_config(identity: &Identity) -> Result<QuicServerConfig, TlsError> {
    let tls = tls::server_config(identity, &[tls::ALPN_QUIC])?;
    QuicServerConfig::try_from(tls).map_err(|e| TlsError::Quic(e.to_string()))
}

/// A client configuration around its own verifier (kept to explain failures).
fn quic_client_config(
    pinned: Fingerprint,
) -> Result<(QuicClientConfig, Arc<tls::PinnedServerVerifier>), TlsError> {
    let verifier = Arc::new(tls::PinnedServerVerifier::new(pinned, &tls::provider()));
    let tls = tls::client_config_with(verifier.clone(), &[tls::ALPN_QUIC])?;
    let quic = QuicClientConfig::try_from(tls).map_err(|e| TlsError::Quic(e.to_string()))?;
    Ok((quic, verifier))
}

impl QuicTransport {
    /// The master's side: listens with `identity`'s certificate (its
    /// [`fingerprint`](Self::fingerprint) is what tickets carry). Cannot connect.
    pub fn server(identity: &Identity) -> Result<Self, TlsError> {
        Ok(Self {
            server: Some(Arc::new(quic_server_config(identity)?)),
            reset: Some(Arc::new(reset_key(identity))),
            pinned: None,
            identity: Some(identity.fingerprint()),
            options: QuicOptions::default(),
            registry: Arc::default(),
        })
    }

    /// A slave's or viewer's side: connects to a master whose certificate has
    /// the fingerprint `pinned` (from the join ticket), and to nothing else.
    pub fn client(pinned: Fingerprint) -> Result<Self, TlsError> {
        // Fail early if the configuration cannot be built; connect builds a fresh one.
        quic_client_config(pinned)?;
        Ok(Self {
            server: None,
            reset: None,
            pinned: Some(pinned),
            identity: None,
            options: QuicOptions::default(),
            registry: Arc::default(),
        })
    }

    /// Both sides at once: listens with `identity` and connects to masters
    /// pinning `pinned` (e.g. an embedded cluster in one process).
    pub fn both(identity: &Identity, pinned: Fingerprint) -> Result<Self, TlsError> {
        quic_client_config(pinned)?;
        Ok(Self { pinned: Some(pinned), ..Self::server(identity)? })
    }

    /// Replaces the tuning.
    pub fn with_options(mut self, options: QuicOptions) -> Self {
        self.options = options;
        self
    }

    /// The fingerprint of the certificate this side presents when listening.
    pub fn fingerprint(&self) -> Option<Fingerprint> {
        self.identity
    }

    /// What QUIC put on the wire over every connection this transport (and its
    /// clones) made or accepted: UDP bytes, datagrams, losses.
    pub fn wire_stats(&self) -> WireStats {
        self.registry.snapshot()
    }

    /// The tuning in use.
    pub fn options(&self) -> &QuicOptions {
        &self.options
    }

    fn transport_config(&self) -> Arc<quinn::TransportConfig> {
        Arc::new(self.options.transport_config())
    }
}

/// The address to use for `HOST:PORT`: IPv4 when the name has both (a lost
/// UDP handshake is only noticed after the idle timeout, so unlike TCP there
/// is no quick trying of each address in turn; masters mostly listen on IPv4).
async fn resolve(addr: &str) -> Result<SocketAddr, TransportError> {
    let addrs = isin_transport::resolve(addr).await?;
    Ok(addrs.iter().find(|a| a.is_ipv4()).copied().unwrap_or(addrs[0]))
}

fn endpoint(
    bind: SocketAddr,
    server: Option<quinn::ServerConfig>,
    reset: Option<Arc<ResetKey>>,
    opts: &QuicOptions,
) -> std::io::Result<Endpoint> {
    let socket = config::bind_udp(bind, opts.socket_buffer)?;
    let config = match reset {
        Some(key) => {
            let mut config = EndpointConfig::new(key);
            config.cid_generator(|| Box::new(RandomCids));
            config
        }
        None => EndpointConfig::default(),
    };
    Endpoint::new(config, server, socket, Arc::new(TokioRuntime))
}

/// The key a listener's stateless-reset tokens are made with: HMAC-SHA256
/// keyed by a hash of the identity's private key, so that a master restarted
/// with the same identity makes the tokens its predecessor gave out.
pub struct ResetKey(Hmac<Sha256>);

/// The stateless-reset key of `identity` (the same for the same identity;
/// the tokens tell nothing of the private key).
pub fn reset_key(identity: &Identity) -> ResetKey {
    let secret = Sha256::new()
        .chain_update(b"isin QUIC stateless reset key\0")
        .chain_update(identity.key_der().secret_pkcs8_der())
        .finalize();
    ResetKey(Hmac::new_from_slice(&secret).expect("HMAC takes a key of any length"))
}

/// Random connection ids of 8 bytes that a listener does not try to tell
/// from junk: quinn's default ids are signed with a key of the process, so a
/// restarted master would drop its predecessor's as invalid instead of
/// answering them with a stateless reset (junk gets one too, at most one
/// per 20 ms, never larger than what it answers).
struct RandomCids;

impl quinn::ConnectionIdGenerator for RandomCids {
    fn generate_cid(&mut self) -> quinn::ConnectionId {
        let mut id = [0u8; 8];
        if getrandom::fill(&mut id).is_err() {
            // No system randomness: ids unique enough from the clock and a counter.
            static N: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
            let t = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
            id[..4].copy_from_slice(&t.subsec_nanos().to_le_bytes());
            id[4..].copy_from_slice(&N.fetch_add(1, std::sync::atomic::Ordering::Relaxed).to_le_bytes());
        }
        quinn::ConnectionId::new(&id)
    }

    fn cid_len(&self) -> usize {
        8
    }

    fn cid_lifetime(&self) -> Option<Duration> {
        None
    }
}

impl quinn::crypto::HmacKey for ResetKey {
    fn sign(&self, data: &[u8], signature_out: &mut [u8]) {
        let tag = self.0.clone().chain_update(data).finalize().into_bytes();
        let n = signature_out.len().min(tag.len());
        signature_out[..n].copy_from_slice(&tag[..n]);
    }

    fn signature_len(&self) -> usize {
        32
    }

    fn verify(&self, data: &[u8], signature: &[u8]) -> Result<(), quinn::crypto::CryptoError> {
        self.0.clone().chain_update(data).verify_slice(signature).map_err(|_| quinn::crypto::CryptoError)
    }
}

/// Explains a failed QUIC connection attempt in words a user can act on; a
/// certificate with the wrong fingerprint is [`TransportError::Untrusted`].
fn describe(addr: &str, e: &quinn::ConnectionError, verifier: &tls::PinnedServerVerifier) -> TransportError {
    let reason = if let Some(mismatch) = verifier.rejected() {
        return TransportError::Untrusted { reason: mismatch.to_string() };
    } else if matches!(e, quinn::ConnectionError::TimedOut) {
        "no answer (is the master running, and UDP to it allowed?)".to_string()
    } else {
        e.to_string()
    };
    TransportError::Connect { addr: addr.to_string(), reason }
}

impl Transport for QuicTransport {
    fn name(&self) -> &'static str {
        "quic"
    }

    fn listen<'a>(&'a self, addr: &'a str) -> BoxFuture<'a, Result<Box<dyn Listener>, TransportError>> {
        Box::pin(async move {
            let err = |reason: String| TransportError::Listen { addr: addr.to_string(), reason };
            let crypto = self.server.clone().ok_or_else(|| {
                err("this QUIC transport has no certificate to serve (use QuicTransport::server)".into())
            })?;
            let bind = resolve(addr).await?;
            let mut server = quinn::ServerConfig::with_crypto(crypto);
            server.transport_config(self.transport_config());
            let endpoint = endpoint(bind, Some(server), self.reset.clone(), &self.options)
                .map_err(|e| err(e.to_string()))?;
            let local = endpoint.local_addr().map_err(|e| err(e.to_string()))?.to_string();
            let (tx, rx) = mpsc::channel(ACCEPT_QUEUE);
            let limits = ListenerLimits::new();
            let task = tokio::spawn(accept_loop(
                endpoint.clone(),
                tx,
                self.options.clone(),
                self.registry.clone(),
                limits.clone(),
            ));
            tracing::debug!(addr = %local, "QUIC listening");
            Ok(Box::new(QuicListener { endpoint, addr: local, rx, task, limits }) as Box<dyn Listener>)
        })
    }

    fn connect<'a>(&'a self, addr: &'a str) -> BoxFuture<'a, Result<Connection, TransportError>> {
        Box::pin(async move {
            let err = |reason: String| TransportError::Connect { addr: addr.to_string(), reason };
            let pinned = self.pinned.ok_or_else(|| {
                err("no certificate fingerprint to pin (QUIC needs the one in the join ticket)".into())
            })?;
            let (crypto, verifier) = quic_client_config(pinned).map_err(|e| err(e.to_string()))?;
            let target = resolve(addr).await?;
            let bind: SocketAddr = if target.is_ipv6() { "[::]:0".parse() } else { "0.0.0.0:0".parse() }
                .map_err(|_| err("".into()))?;
            let endpoint = endpoint(bind, None, None, &self.options).map_err(|e| err(e.to_string()))?;
            let mut client = quinn::ClientConfig::new(Arc::new(crypto));
            client.transport_config(self.transport_config());
            let conn = endpoint
                .connect_with(client, target, tls::SERVER_NAME)
                .map_err(|e| err(e.to_string()))?
                .await
                .map_err(|e| describe(addr, &e, &verifier))?;
            let (mut send, recv) = conn.open_bi().await.map_err(|e| describe(addr, &e, &verifier))?;
            send.write_all(wire::PREAMBLE).await.map_err(|e| err(e.to_string()))?;
            let shared = ConnShared::new(INITIAL_MAX_FRAME);
            Ok(conn::spawn(conn, send, recv, Some(endpoint), shared, &self.options, self.registry.clone()))
        })
    }
}

/// Accepts QUIC connections; each handshake runs in its own task, so a peer
/// that stalls or fails it never holds up the others.
struct QuicListener {
    endpoint: Endpoint,
    addr: String,
    rx: mpsc::Receiver<Connection>,
    task: tokio::task::JoinHandle<()>,
    limits: Arc<ListenerLimits>,
}

impl Drop for QuicListener {
    fn drop(&mut self) {
        // Stop taking new connections; established ones live on.
        self.task.abort();
        self.endpoint.set_server_config(None);
    }
}

impl Listener for QuicListener {
    fn local_addr(&self) -> String {
        self.addr.clone()
    }

    fn accept(&mut self) -> BoxFuture<'_, Result<Connection, TransportError>> {
        Box::pin(async move { self.rx.recv().await.ok_or(TransportError::Closed) })
    }

    fn set_budget(&mut self, budget: Arc<MemoryBudget>) {
        self.limits.set_budget(budget);
    }

    fn set_frame_timeout(&mut self, timeout: Duration) {
        self.limits.set_frame_timeout(timeout);
    }
}

async fn accept_loop(
    endpoint: Endpoint,
    tx: mpsc::Sender<Connection>,
    opts: QuicOptions,
    registry: Arc<stats::Registry>,
    limits: Arc<ListenerLimits>,
) {
    while let Some(incoming) = endpoint.accept().await {
        let tx = tx.clone();
        let limits = limits.clone();
        let opts = opts.clone();
        let registry = registry.clone();
        tokio::spawn(async move {
            let remote = incoming.remote_address();
            match tokio::time::timeout(opts.handshake_timeout, establish(incoming)).await {
                Ok(Ok((conn, send, recv))) => {
                    let c = conn::spawn(conn, send, recv, None, limits.conn_shared(), &opts, registry);
                    // If nobody accepts any more, dropping `c` closes it.
                    let _ = tx.send(c).await;
                }
                Ok(Err(e)) => tracing::info!(%remote, "QUIC connection refused: {e}"),
                Err(_) => tracing::info!(%remote, "QUIC handshake timed out"),
            }
        });
    }
}

/// TLS handshake, then the client's control stream with its preamble.
async fn establish(
    incoming: quinn::Incoming,
) -> Result<(quinn::Connection, quinn::SendStream, quinn::RecvStream), String> {
    let conn = incoming.await.map_err(|e| format!("handshake failed: {e}"))?;
    let (send, mut recv) = conn.accept_bi().await.map_err(|e| format!("no control stream: {e}"))?;
    let mut preamble = [0u8; wire::PREAMBLE.len()];
    recv.read_exact(&mut preamble).await.map_err(|e| format!("no preamble: {e}"))?;
    if &preamble != wire::PREAMBLE {
        conn.close(VarInt::from_u32(CLOSE_PROTOCOL), b"not an isin peer");
        return Err("wrong preamble: not an isin peer of this version".into());
    }
    Ok((conn, send, recv))
}

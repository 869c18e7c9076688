//! # isin-transport-tcp — the cluster transport over TCP
//!
//! Length-delimited frames over tokio TCP streams, implementing the
//! [`isin_transport::Transport`] interface the actors use. By default
//! the stream is TLS 1.3 ([`TcpTransport::server`] / [`TcpTransport::client`]):
//! the master presents its self-signed [`tls::Identity`], the slave pins the
//! certificate's SHA-256 from the join ticket (no "accept any certificate"),
//! exactly as over QUIC — both use the `isin-transport-tls` crate (re-exported
//! here as [`tls`]), so neither transport pulls in the other's network stack.
//! Plaintext is [`TcpTransport::insecure`], a separate transport with its own
//! kind ([`TransportKind::TcpInsecure`](isin_transport::TransportKind)), so a
//! ticket says which one a master speaks and a slave never falls back from one
//! to the other.
//!
//! Each connection sets `TCP_NODELAY` (tiles are latency-sensitive and the codec
//! already batches writes), starts with the small handshake frame limit (raised
//! by the master once the peer has authenticated), reserves every announced
//! frame from the listener's memory budget before allocating it and reads it
//! under the frame timeout ([`Listener::set_budget`],
//! [`Listener::set_frame_timeout`]), and reports the peer closing as the end of
//! its frame stream. A TLS listener runs each handshake in its
//! own task under a timeout, so a peer that stalls it holds up no one.
//!
//! ## Counting
//! Over TLS, [`ConnStats`](isin_transport::ConnStats) bytes are what
//! crossed the socket — handshake, record headers and authentication tags
//! included — counted by a wrapper under the TLS layer ([`counted`]). Over
//! plaintext they are the frames and their 4-byte length prefixes, which is
//! the same thing.

pub mod counted;
/// The TLS identity and pinning shared with QUIC (the `isin-transport-tls` crate).
pub use isin_transport_tls as tls;

use counted::Counted;
use isin_transport::stream::{self, Counting};
use isin_transport::{
    BoxFuture, ConnShared, Connection, INITIAL_MAX_FRAME, Listener, ListenerLimits, MemoryBudget, Transport,
    TransportError,
};
use std::sync::Arc;
use std::time::Duration;
use tls::{Fingerprint, Identity, PinnedServerVerifier, TlsError};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::mpsc;
use tokio_rustls::{TlsAcceptor, TlsConnector};

/// A TLS handshake taking longer than this is abandoned (the peer's
/// connection is closed; the listener goes on).
pub const TLS_HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// Connections accepted (TLS done) but not yet taken by [`Listener::accept`].
const ACCEPT_QUEUE: usize = 64;

#[derive(Clone)]
enum Security {
    /// Plaintext.
    Insecure,
    /// TLS 1.3: may listen with `acceptor` and/or connect pinning `pinned`.
    Tls { acceptor: Option<TlsAcceptor>, identity: Option<Fingerprint>, pinned: Option<Fingerprint> },
}

/// TCP transport: TLS with a pinned certificate, or plaintext (see the
/// [crate docs](crate)).
#[derive(Clone)]
pub struct TcpTransport {
    security: Security,
}

impl std::fmt::Debug for TcpTransport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.security {
            Security::Insecure => write!(f, "TcpTransport(insecure)"),
            Security::Tls { identity, pinned, .. } => f
                .debug_struct("TcpTransport")
                .field("identity", identity)
                .field("pinned", pinned)
                .finish_non_exhaustive(),
        }
    }
}

impl Default for TcpTransport {
    /// Plaintext, as [`TcpTransport::insecure`].
    fn default() -> Self {
        Self::insecure()
    }
}

impl TcpTransport {
    /// Plaintext TCP, as [`TcpTransport::insecure`] (kept for callers that
    /// measure the bare transport; the cluster commands use TLS unless told
    /// `--insecure`).
    pub fn new() -> Self {
        Self::insecure()
    }

    /// Plaintext TCP: anyone on the path can read and alter the frames (the
    /// token handshake still keeps strangers out). Named `tcp-insecure`.
    pub fn insecure() -> Self {
        Self { security: Security::Insecure }
    }

    /// The master's side of TLS over TCP: listens presenting `identity` (its
    /// [`fingerprint`](Self::fingerprint) is what tickets carry). Cannot connect.
    pub fn server(identity: &Identity) -> Result<Self, TlsError> {
        let cfg = tls::server_config(identity, &[tls::ALPN_TCP])?;
        Ok(Self {
            security: Security::Tls {
                acceptor: Some(TlsAcceptor::from(Arc::new(cfg))),
                identity: Some(identity.fingerprint()),
                pinned: None,
            },
        })
    }

    /// A slave's or viewer's side: connects over TLS to a master whose
    /// certificate has the fingerprint `pinned` (from the join ticket), and to
    /// nothing else.
    pub fn client(pinned: Fingerprint) -> Result<Self, TlsError> {
        // Fail early if the configuration cannot be built; connect builds a fresh one.
        tls::client_config(pinned, &[tls::ALPN_TCP])?;
        Ok(Self { security: Security::Tls { acceptor: None, identity: None, pinned: Some(pinned) } })
    }

    /// Both sides at once: listens with `identity` and connects pinning
    /// `pinned` (e.g. an embedded cluster in one process).
    pub fn both(identity: &Identity, pinned: Fingerprint) -> Result<Self, TlsError> {
        let mut t = Self::server(identity)?;
        tls::client_config(pinned, &[tls::ALPN_TCP])?;
        if let Security::Tls { pinned: p, .. } = &mut t.security {
            *p = Some(pinned);
        }
        Ok(t)
    }

    /// Whether frames are encrypted.
    pub fn is_tls(&self) -> bool {
        matches!(self.security, Security::Tls { .. })
    }

    /// The fingerprint of the certificate this side presents when listening.
    pub fn fingerprint(&self) -> Option<Fingerprint> {
        match &self.security {
            Security::Tls { identity, .. } => *identity,
            Security::Insecure => None,
        }
    }
}

fn nodelay(sock: &TcpStream, peer: &str) {
    if let Err(e) = sock.set_nodelay(true) {
        tracing::warn!(%peer, "cannot set TCP_NODELAY: {e}");
    }
}

fn wrap_plain(sock: TcpStream, peer: String, shared: Arc<ConnShared>) -> Connection {
    nodelay(&sock, &peer);
    let (r, w) = sock.into_split();
    stream::spawn_with(r, w, peer, shared, Counting::Frames)
}

/// Plaintext listener: connections are ready as soon as accepted.
struct PlainListener {
    inner: TcpListener,
    addr: String,
    limits: Arc<ListenerLimits>,
}

impl Listener for PlainListener {
    fn local_addr(&self) -> String {
        self.addr.clone()
    }

    fn accept(&mut self) -> BoxFuture<'_, Result<Connection, TransportError>> {
        Box::pin(async move {
            let (sock, peer) = self.inner.accept().await?;
            Ok(wrap_plain(sock, peer.to_string(), self.limits.conn_shared()))
        })
    }

    fn set_budget(&mut self, budget: Arc<MemoryBudget>) {
        self.limits.set_budget(budget);
    }

    fn set_frame_timeout(&mut self, timeout: Duration) {
        self.limits.set_frame_timeout(timeout);
    }
}

/// TLS listener: an accept loop hands each socket to its own handshake task;
/// finished handshakes queue up for [`Listener::accept`].
struct TlsListener {
    addr: String,
    rx: mpsc::Receiver<Connection>,
    task: tokio::task::JoinHandle<()>,
    limits: Arc<ListenerLimits>,
}

impl Drop for TlsListener {
    fn drop(&mut self) {
        // Stops accepting (the socket closes with the task); established
        // connections live on.
        self.task.abort();
    }
}

impl Listener for TlsListener {
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

async fn tls_accept_loop(
    listener: TcpListener,
    acceptor: TlsAcceptor,
    tx: mpsc::Sender<Connection>,
    limits: Arc<ListenerLimits>,
) {
    loop {
        let (sock, peer) = match listener.accept().await {
            Ok(s) => s,
            Err(e) => {
                // E.g. out of file descriptors: do not spin.
                tracing::warn!("TCP accept failed: {e}");
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
        };
        let (acceptor, tx) = (acceptor.clone(), tx.clone());
        let shared = limits.conn_shared();
        tokio::spawn(async move {
            let peer = peer.to_string();
            match tokio::time::timeout(TLS_HANDSHAKE_TIMEOUT, tls_accept(sock, &peer, &acceptor, shared))
                .await
            {
                Ok(Ok(conn)) => {
                    // If nobody accepts any more, dropping `conn` closes it.
                    let _ = tx.send(conn).await;
                }
                Ok(Err(e)) => tracing::info!(%peer, "TLS connection refused: {e}"),
                Err(_) => tracing::info!(%peer, "TLS handshake timed out"),
            }
        });
    }
}

async fn tls_accept(
    sock: TcpStream,
    peer: &str,
    acceptor: &TlsAcceptor,
    shared: Arc<ConnShared>,
) -> Result<Connection, String> {
    nodelay(&sock, peer);
    let tls = acceptor
        .accept(Counted::new(sock, shared.clone()))
        .await
        .map_err(|e| format!("handshake failed: {e}"))?;
    if tls.get_ref().1.alpn_protocol() != Some(tls::ALPN_TCP) {
        return Err("the peer does not speak isin over TLS (no `isin-tcp/1` ALPN)".into());
    }
    let (r, w) = tokio::io::split(tls);
    Ok(stream::spawn_with(r, w, peer.to_string(), shared, Counting::External))
}

/// Explains a failed TLS handshake in words a user can act on.
fn describe(addr: &str, e: &std::io::Error, verifier: &PinnedServerVerifier) -> TransportError {
    if let Some(mismatch) = verifier.rejected() {
        return TransportError::Untrusted { reason: mismatch.to_string() };
    }
    let text = e.to_string();
    let hint = if text.contains("corrupt message") || text.contains("InvalidContentType") {
        " (is the master running with --insecure? Its ticket then starts with isin+tcp-insecure://)"
    } else {
        ""
    };
    TransportError::Connect { addr: addr.to_string(), reason: format!("TLS handshake failed: {text}{hint}") }
}

impl Transport for TcpTransport {
    fn name(&self) -> &'static str {
        match self.security {
            Security::Tls { .. } => "tcp",
            Security::Insecure => "tcp-insecure",
        }
    }

    fn listen<'a>(&'a self, addr: &'a str) -> BoxFuture<'a, Result<Box<dyn Listener>, TransportError>> {
        Box::pin(async move {
            let err =
                |e: std::io::Error| TransportError::Listen { addr: addr.to_string(), reason: e.to_string() };
            let acceptor = match &self.security {
                Security::Insecure => None,
                Security::Tls { acceptor: Some(a), .. } => Some(a.clone()),
                Security::Tls { acceptor: None, .. } => {
                    return Err(TransportError::Listen {
                        addr: addr.to_string(),
                        reason: "this TCP transport has no certificate to serve (use TcpTransport::server)"
                            .into(),
                    });
                }
            };
            let inner = TcpListener::bind(addr).await.map_err(err)?;
            let local = inner.local_addr().map_err(err)?.to_string();
            let limits = ListenerLimits::new();
            Ok(match acceptor {
                None => Box::new(PlainListener { inner, addr: local, limits }) as Box<dyn Listener>,
                Some(acceptor) => {
                    let (tx, rx) = mpsc::channel(ACCEPT_QUEUE);
                    let task = tokio::spawn(tls_accept_loop(inner, acceptor, tx, limits.clone()));
                    Box::new(TlsListener { addr: local, rx, task, limits })
                }
            })
        })
    }

    fn connect<'a>(&'a self, addr: &'a str) -> BoxFuture<'a, Result<Connection, TransportError>> {
        Box::pin(async move {
            let err = |reason: String| TransportError::Connect { addr: addr.to_string(), reason };
            let pinned = match &self.security {
                Security::Insecure => None,
                Security::Tls { pinned: Some(p), .. } => Some(*p),
                Security::Tls { pinned: None, .. } => {
                    return Err(err(
                        "no certificate fingerprint to pin (TLS needs the one in the join ticket)".into(),
                    ));
                }
            };
            let addrs = isin_transport::resolve(addr).await?;
            let sock = TcpStream::connect(&addrs[..]).await.map_err(|e| err(e.to_string()))?;
            let Some(pinned) = pinned else {
                return Ok(wrap_plain(sock, addr.to_string(), ConnShared::new(INITIAL_MAX_FRAME)));
            };
            nodelay(&sock, addr);
            let verifier = Arc::new(PinnedServerVerifier::new(pinned, &tls::provider()));
            let cfg = tls::client_config_with(verifier.clone(), &[tls::ALPN_TCP])
                .map_err(|e| err(e.to_string()))?;
            let name = tokio_rustls::rustls::pki_types::ServerName::try_from(tls::SERVER_NAME)
                .map_err(|e| err(e.to_string()))?;
            let shared = ConnShared::new(INITIAL_MAX_FRAME);
            let tls = TlsConnector::from(Arc::new(cfg))
                .connect(name, Counted::new(sock, shared.clone()))
                .await
                .map_err(|e| describe(addr, &e, &verifier))?;
            let (r, w) = tokio::io::split(tls);
            Ok(stream::spawn_with(r, w, addr.to_string(), shared, Counting::External))
        })
    }
}

#[cfg(test)]
mod tests;

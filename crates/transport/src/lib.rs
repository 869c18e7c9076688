//! # isin-transport — the interface every transport implements
//!
//! What the actors need from a network, and nothing
//! about which network it is.
//!
//! A [`Transport`] listens and connects; either way the result is a
//! [`Connection`]: a [`FrameSender`] (cheap to clone, usable from any thread —
//! render threads send their tiles straight into it) and a [`FrameReceiver`]
//! yielding whole frames until the peer closes. Behind the pair run the
//! transport's own tasks, so TCP (one length-delimited byte stream), QUIC (a
//! stream per frame, or one long-lived stream) or an in-memory pipe all look the
//! same to the actors. Every connection has byte and frame counters and a
//! maximum frame length that can be raised once the peer has authenticated.
//!
//! ## What a peer can make this side hold
//! Every transport's reader, on learning a frame's announced length, checks
//! it against the connection's maximum frame, then reserves that many bytes
//! from the connection's [`MemoryBudget`] — both *before* allocating
//! ([`ConnShared::admit`]). A frame over the maximum
//! ([`TransportError::FrameTooLarge`]) or over budget
//! ([`TransportError::OverBudget`]) fails the connection at once, never
//! waiting for memory to free up. A frame must also arrive whole within the
//! connection's frame timeout ([`DEFAULT_FRAME_TIMEOUT`];
//! [`TransportError::FrameTimeout`]), so a peer that announces a large frame
//! and trickles its bytes cannot pin the reservation for long. A listener
//! gives every connection it accepts the same budget and timeout
//! ([`Listener::set_budget`], [`Listener::set_frame_timeout`]).
//!
//! [`stream`] holds the length-delimited codec over any byte stream (used by
//! TCP and by the in-memory [`mem`] transport the tests use). [`ticket`] holds
//! the join ticket: which [`TransportKind`] a master speaks, and the
//! [`Fingerprint`] of the certificate it presents.

use std::future::Future;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::{Notify, mpsc};

pub mod budget;
pub mod mem;
pub mod stream;
pub mod ticket;

pub use budget::{MemoryBudget, Reservation};
pub use ticket::{Fingerprint, Ticket, TicketError, TransportKind};

/// The largest frame every new connection accepts until the application
/// raises it ([`FrameSender::set_max_frame`]) — once the peer has proved who
/// it is. An unauthenticated peer cannot make anyone allocate more than this.
/// It must hold the protocol's largest handshake message.
pub const INITIAL_MAX_FRAME: usize = 16 << 10;

/// How long a frame may take to arrive once its length was read, unless the
/// connection says otherwise ([`ConnShared::set_frame_timeout`]). It must
/// cover the largest frame the application raises the limit to at the slowest
/// link it supports.
pub const DEFAULT_FRAME_TIMEOUT: Duration = Duration::from_secs(30);

/// The addresses of `HOST:PORT`; [`TransportError::Unresolvable`] when it has none.
pub async fn resolve(addr: &str) -> Result<Vec<std::net::SocketAddr>, TransportError> {
    let unresolvable = |reason: String| TransportError::Unresolvable { addr: addr.to_string(), reason };
    let addrs: Vec<_> =
        tokio::net::lookup_host(addr).await.map_err(|e| unresolvable(e.to_string()))?.collect();
    if addrs.is_empty() {
        return Err(unresolvable("no address found".into()));
    }
    Ok(addrs)
}

/// A boxed, sendable future (the trait methods are object-safe this way).
pub type BoxFuture<'a, T> = Pin<Box<dyn Future<Output = T> + Send + 'a>>;

/// What can go wrong on a connection.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    /// Could not reach the peer.
    #[error("cannot connect to {addr}: {reason}")]
    Connect {
        /// Where.
        addr: String,
        /// Why.
        reason: String,
    },
    /// Could not bind.
    #[error("cannot listen on {addr}: {reason}")]
    Listen {
        /// Where.
        addr: String,
        /// Why.
        reason: String,
    },
    /// The peer announced a frame longer than allowed; the connection is closed.
    #[error("peer announced a frame of {len} bytes, the maximum is {max}")]
    FrameTooLarge {
        /// Announced length.
        len: u64,
        /// Maximum.
        max: usize,
    },
    /// Reserving the announced frame's bytes would take the connection's
    /// [`MemoryBudget`] over its limit; the connection is closed.
    #[error("a frame of {len} bytes would exceed the memory budget ({in_use} of {limit} bytes in use)")]
    OverBudget {
        /// Announced length.
        len: u64,
        /// Bytes reserved when it was refused.
        in_use: usize,
        /// The budget's limit.
        limit: usize,
    },
    /// The peer did not complete an announced frame in time; the connection is
    /// closed.
    #[error("the peer did not complete a frame of {len} bytes within {timeout:?}")]
    FrameTimeout {
        /// Announced length.
        len: u64,
        /// The connection's frame timeout.
        timeout: Duration,
    },
    /// The peer's host name does not resolve to any address. Worth retrying
    /// for a while (a name server may be down), not forever.
    #[error("cannot resolve {addr}: {reason}")]
    Unresolvable {
        /// The `HOST:PORT` given.
        addr: String,
        /// Why.
        reason: String,
    },
    /// The byte stream failed or ended inside a frame.
    #[error("connection error: {0}")]
    Io(#[from] std::io::Error),
    /// The connection was closed locally.
    #[error("connection closed")]
    Closed,
    /// The peer is not the one we were told to trust (e.g. its certificate's
    /// fingerprint is not the ticket's): retrying will not help.
    #[error("refusing the peer: {reason}")]
    Untrusted {
        /// Why.
        reason: String,
    },
}

/// Opens connections. Implemented by TCP and QUIC.
pub trait Transport: Send + Sync + 'static {
    /// Short name (`tcp`, `quic`, `mem`), as written in join tickets.
    fn name(&self) -> &'static str;
    /// Starts listening on `addr` (`HOST:PORT`; port 0 picks a free one).
    fn listen<'a>(&'a self, addr: &'a str) -> BoxFuture<'a, Result<Box<dyn Listener>, TransportError>>;
    /// Connects to a listener at `addr`. Must be called inside a tokio runtime.
    fn connect<'a>(&'a self, addr: &'a str) -> BoxFuture<'a, Result<Connection, TransportError>>;
}

/// Accepts incoming connections.
pub trait Listener: Send + 'static {
    /// The address actually bound (with the real port when 0 was asked).
    fn local_addr(&self) -> String;
    /// The next incoming connection.
    fn accept(&mut self) -> BoxFuture<'_, Result<Connection, TransportError>>;
    /// Every connection accepted from now on reserves its incoming frames
    /// from `budget` (shared by all of them; see [`budget`]). Without one,
    /// connections are bounded by their maximum frame only.
    fn set_budget(&mut self, budget: Arc<MemoryBudget>);
    /// Every connection accepted from now on fails a frame not complete
    /// within `timeout` of its length ([`DEFAULT_FRAME_TIMEOUT`] otherwise).
    fn set_frame_timeout(&mut self, timeout: Duration);
}

/// What a listener applies to the connections it accepts: for transport
/// implementations, which share it between the [`Listener`] and the tasks
/// that create connections.
#[derive(Debug)]
pub struct ListenerLimits {
    budget: Mutex<Option<Arc<MemoryBudget>>>,
    frame_timeout: Mutex<Duration>,
}

impl ListenerLimits {
    /// No budget, the default frame timeout.
    pub fn new() -> Arc<Self> {
        Arc::new(Self { budget: Mutex::new(None), frame_timeout: Mutex::new(DEFAULT_FRAME_TIMEOUT) })
    }

    /// See [`Listener::set_budget`].
    pub fn set_budget(&self, budget: Arc<MemoryBudget>) {
        if let Ok(mut b) = self.budget.lock() {
            *b = Some(budget);
        }
    }

    /// See [`Listener::set_frame_timeout`].
    pub fn set_frame_timeout(&self, timeout: Duration) {
        if let Ok(mut t) = self.frame_timeout.lock() {
            *t = timeout;
        }
    }

    /// Fresh connection state at [`INITIAL_MAX_FRAME`], under these limits.
    pub fn conn_shared(&self) -> Arc<ConnShared> {
        let shared = ConnShared::new(INITIAL_MAX_FRAME);
        shared.set_budget(self.budget.lock().ok().and_then(|b| b.clone()));
        if let Ok(t) = self.frame_timeout.lock() {
            shared.set_frame_timeout(*t);
        }
        shared
    }
}

/// State shared by a connection's two halves and its transport tasks.
#[derive(Debug)]
pub struct ConnShared {
    bytes_sent: AtomicU64,
    bytes_received: AtomicU64,
    frames_sent: AtomicU64,
    frames_received: AtomicU64,
    max_frame: AtomicUsize,
    budget: Mutex<Option<Arc<MemoryBudget>>>,
    frame_timeout_micros: AtomicU64,
    closed: AtomicBool,
    /// Woken when the connection is closed locally.
    pub close_notify: Notify,
}

impl ConnShared {
    /// Fresh counters with a maximum frame length, no budget and the default
    /// frame timeout.
    pub fn new(max_frame: usize) -> Arc<Self> {
        Arc::new(Self {
            bytes_sent: AtomicU64::new(0),
            bytes_received: AtomicU64::new(0),
            frames_sent: AtomicU64::new(0),
            frames_received: AtomicU64::new(0),
            max_frame: AtomicUsize::new(max_frame),
            budget: Mutex::new(None),
            frame_timeout_micros: AtomicU64::new(DEFAULT_FRAME_TIMEOUT.as_micros() as u64),
            closed: AtomicBool::new(false),
            close_notify: Notify::new(),
        })
    }

    /// The largest frame currently accepted.
    pub fn max_frame(&self) -> usize {
        self.max_frame.load(Ordering::Relaxed)
    }

    /// Reserves incoming frames from `budget` from now on (`None`: no budget).
    pub fn set_budget(&self, budget: Option<Arc<MemoryBudget>>) {
        if let Ok(mut b) = self.budget.lock() {
            *b = budget;
        }
    }

    /// The budget incoming frames reserve from, if any.
    pub fn budget(&self) -> Option<Arc<MemoryBudget>> {
        self.budget.lock().ok().and_then(|b| b.clone())
    }

    /// How long a frame may take to arrive once its length was read.
    pub fn set_frame_timeout(&self, timeout: Duration) {
        let micros = u64::try_from(timeout.as_micros()).unwrap_or(u64::MAX);
        self.frame_timeout_micros.store(micros, Ordering::Relaxed);
    }

    /// See [`set_frame_timeout`](Self::set_frame_timeout).
    pub fn frame_timeout(&self) -> Duration {
        Duration::from_micros(self.frame_timeout_micros.load(Ordering::Relaxed))
    }

    /// What a reader calls on learning that the peer announces a frame of
    /// `len` bytes, before allocating anything for it: refuses a frame over
    /// the maximum ([`TransportError::FrameTooLarge`]) or over the budget
    /// ([`TransportError::OverBudget`]); otherwise the reservation to keep
    /// with the frame until the application takes it.
    pub fn admit(&self, len: u64) -> Result<Reservation, TransportError> {
        let max = self.max_frame();
        if len > max as u64 {
            return Err(TransportError::FrameTooLarge { len, max });
        }
        // len <= max, which is a usize.
        let len = len as usize;
        match self.budget() {
            Some(b) => b.try_reserve(len),
            None => Ok(Reservation::unbudgeted(len)),
        }
    }

    /// Whether the connection was closed locally.
    pub fn is_closed(&self) -> bool {
        self.closed.load(Ordering::Acquire)
    }

    /// Adds bytes written to the socket without counting a frame: for
    /// transports that count below their own framing (TLS records, handshakes),
    /// together with [`count_frame_sent`](Self::count_frame_sent).
    pub fn add_bytes_sent(&self, n: u64) {
        self.bytes_sent.fetch_add(n, Ordering::Relaxed);
    }

    /// Adds bytes read from the socket without counting a frame (see
    /// [`add_bytes_sent`](Self::add_bytes_sent)).
    pub fn add_bytes_received(&self, n: u64) {
        self.bytes_received.fetch_add(n, Ordering::Relaxed);
    }

    /// Counts one frame written, its bytes being counted elsewhere.
    pub fn count_frame_sent(&self) {
        self.frames_sent.fetch_add(1, Ordering::Relaxed);
    }

    /// Counts one frame read, its bytes being counted elsewhere.
    pub fn count_frame_received(&self) {
        self.frames_received.fetch_add(1, Ordering::Relaxed);
    }

    /// Transports call this for every frame written (`wire` bytes incl. framing).
    pub fn count_sent(&self, wire: u64) {
        self.bytes_sent.fetch_add(wire, Ordering::Relaxed);
        self.frames_sent.fetch_add(1, Ordering::Relaxed);
    }

    /// Transports call this for every frame read (`wire` bytes incl. framing).
    pub fn count_received(&self, wire: u64) {
        self.bytes_received.fetch_add(wire, Ordering::Relaxed);
        self.frames_received.fetch_add(1, Ordering::Relaxed);
    }

    /// A snapshot of the counters.
    pub fn stats(&self) -> ConnStats {
        ConnStats {
            bytes_sent: self.bytes_sent.load(Ordering::Relaxed),
            bytes_received: self.bytes_received.load(Ordering::Relaxed),
            frames_sent: self.frames_sent.load(Ordering::Relaxed),
            frames_received: self.frames_received.load(Ordering::Relaxed),
        }
    }

    fn close(&self) {
        self.closed.store(true, Ordering::Release);
        self.close_notify.notify_waiters();
        self.close_notify.notify_one();
    }
}

/// Byte and frame counters of a connection.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ConnStats {
    /// Bytes written, framing included.
    pub bytes_sent: u64,
    /// Bytes read, framing included.
    pub bytes_received: u64,
    /// Frames written.
    pub frames_sent: u64,
    /// Frames read.
    pub frames_received: u64,
}

/// How a frame may travel relative to the others on its connection. The
/// sender chooses (the cluster core classes its messages); a transport that
/// has one ordered byte stream (TCP) treats both alike.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Delivery {
    /// In send order with every other frame: never overtakes, nor is
    /// overtaken by, anything sent before it.
    #[default]
    Ordered,
    /// May overtake other independent frames sent since the last ordered one
    /// (tiles: a lost packet delays only its own tile), never an ordered frame.
    Independent,
}

/// What the writer side of a transport is asked to do, in order.
#[derive(Debug)]
pub enum Outgoing {
    /// Send this frame, delivered as it says.
    Frame(Vec<u8>, Delivery),
    /// Flush what was queued before, then close.
    Close,
}

/// Sends frames on a connection. Clone freely; usable from any thread.
#[derive(Clone, Debug)]
pub struct FrameSender {
    tx: mpsc::UnboundedSender<Outgoing>,
    shared: Arc<ConnShared>,
}

impl FrameSender {
    /// A sender feeding `tx` (transport implementations build these).
    pub fn new(tx: mpsc::UnboundedSender<Outgoing>, shared: Arc<ConnShared>) -> Self {
        Self { tx, shared }
    }

    /// Queues an [ordered](Delivery::Ordered) frame; `Err(Closed)` once the
    /// connection is closed.
    pub fn send(&self, frame: Vec<u8>) -> Result<(), TransportError> {
        self.send_as(frame, Delivery::Ordered)
    }

    /// Queues a frame delivered as `delivery` says; `Err(Closed)` once the
    /// connection is closed.
    pub fn send_as(&self, frame: Vec<u8>, delivery: Delivery) -> Result<(), TransportError> {
        if self.shared.is_closed() {
            return Err(TransportError::Closed);
        }
        self.tx.send(Outgoing::Frame(frame, delivery)).map_err(|_| TransportError::Closed)
    }

    /// Flushes what was queued, then closes both directions.
    pub fn close(&self) {
        if !self.shared.is_closed() {
            let _ = self.tx.send(Outgoing::Close);
            self.shared.close();
        }
    }

    /// Raises (or lowers) the largest frame accepted from the peer.
    pub fn set_max_frame(&self, max: usize) {
        self.shared.max_frame.store(max, Ordering::Relaxed);
    }

    /// Changes how long a frame from the peer may take once its length was
    /// read (e.g. longer once the peer may send a whole scene).
    pub fn set_frame_timeout(&self, timeout: Duration) {
        self.shared.set_frame_timeout(timeout);
    }

    /// The connection's counters.
    pub fn stats(&self) -> ConnStats {
        self.shared.stats()
    }

    /// Whether the connection is closed.
    pub fn is_closed(&self) -> bool {
        self.shared.is_closed() || self.tx.is_closed()
    }
}

/// What a transport's reader hands its [`FrameReceiver`]: a frame with the
/// budget it holds until the application takes it, or the error that ended
/// the connection.
pub type Incoming = Result<(Vec<u8>, Reservation), TransportError>;

/// Receives whole frames until the peer closes (`None`) or the connection
/// fails (one `Err`, then `None`).
#[derive(Debug)]
pub struct FrameReceiver {
    rx: mpsc::Receiver<Incoming>,
}

impl FrameReceiver {
    /// A receiver fed by a transport's reader task.
    pub fn new(rx: mpsc::Receiver<Incoming>) -> Self {
        Self { rx }
    }

    /// The next frame; its bytes leave the connection's budget as it is
    /// returned.
    pub async fn recv(&mut self) -> Option<Result<Vec<u8>, TransportError>> {
        self.rx.recv().await.map(|r| r.map(|(frame, _reservation)| frame))
    }
}

/// One connection: both directions and the peer's address.
#[derive(Debug)]
pub struct Connection {
    /// The peer's address, for logs.
    pub peer: String,
    /// Outgoing frames.
    pub sender: FrameSender,
    /// Incoming frames.
    pub receiver: FrameReceiver,
}

//! An in-memory transport: connections are `tokio::io::duplex` pipes running
//! the same length-delimited codec as TCP, under the same limits (maximum
//! frame, memory budget, frame timeout). For tests of the actors without
//! sockets.

use crate::stream::{self, Counting};
use crate::{BoxFuture, Connection, Listener, ListenerLimits, MemoryBudget, Transport, TransportError};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::mpsc;

/// A listener's queue of connections and the limits its side of each gets.
type Registered = (mpsc::UnboundedSender<Connection>, Arc<ListenerLimits>);

/// A namespace of in-memory listeners, addressed by any string.
#[derive(Clone, Default)]
pub struct MemTransport {
    listeners: Arc<Mutex<HashMap<String, Registered>>>,
}

impl MemTransport {
    /// A fresh, empty namespace.
    pub fn new() -> Self {
        Self::default()
    }
}

struct MemListener {
    addr: String,
    rx: mpsc::UnboundedReceiver<Connection>,
    limits: Arc<ListenerLimits>,
}

impl Listener for MemListener {
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

impl MemTransport {
    /// Connects to the listener at `addr` like [`Transport::connect`], but
    /// returns this side's raw byte pipe instead of a [`Connection`]: for tests
    /// that must write what no [`FrameSender`](crate::FrameSender) would (a
    /// bad length prefix, a frame trickled byte by byte). The listener's side
    /// is an ordinary connection under its limits.
    pub async fn connect_raw(&self, addr: &str) -> Result<tokio::io::DuplexStream, TransportError> {
        let listener = self.listeners.lock().map_err(|_| TransportError::Closed)?.get(addr).cloned();
        let refused = || TransportError::Connect { addr: addr.to_string(), reason: "no listener".into() };
        let (listener, limits) = listener.ok_or_else(refused)?;
        let (ours, theirs) = tokio::io::duplex(256 << 10);
        let (r, w) = tokio::io::split(theirs);
        let conn = stream::spawn_with(r, w, "mem-peer".to_string(), limits.conn_shared(), Counting::Frames);
        listener.send(conn).map_err(|_| refused())?;
        Ok(ours)
    }
}

impl Transport for MemTransport {
    fn name(&self) -> &'static str {
        "mem"
    }

    fn listen<'a>(&'a self, addr: &'a str) -> BoxFuture<'a, Result<Box<dyn Listener>, TransportError>> {
        Box::pin(async move {
            let (tx, rx) = mpsc::unbounded_channel();
            let limits = ListenerLimits::new();
            let registered = (tx, limits.clone());
            self.listeners.lock().map_err(|_| TransportError::Closed)?.insert(addr.to_string(), registered);
            Ok(Box::new(MemListener { addr: addr.to_string(), rx, limits }) as Box<dyn Listener>)
        })
    }

    fn connect<'a>(&'a self, addr: &'a str) -> BoxFuture<'a, Result<Connection, TransportError>> {
        Box::pin(async move {
            let listener = self.listeners.lock().map_err(|_| TransportError::Closed)?.get(addr).cloned();
            let refused = || TransportError::Connect { addr: addr.to_string(), reason: "no listener".into() };
            let (listener, limits) = listener.ok_or_else(refused)?;
            let (a, b) = tokio::io::duplex(256 << 10);
            let (ar, aw) = tokio::io::split(a);
            let (br, bw) = tokio::io::split(b);
            // Both ends start at the handshake limit, as real transports do.
            let max = crate::INITIAL_MAX_FRAME;
            let ours = stream::spawn(ar, aw, addr.to_string(), max);
            let theirs =
                stream::spawn_with(br, bw, "mem-peer".to_string(), limits.conn_shared(), Counting::Frames);
            listener.send(theirs).map_err(|_| refused())?;
            Ok(ours)
        })
    }
}

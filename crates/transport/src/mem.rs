//! An in-memory transport: connections are `tokio::io::duplex` pipes running
//! the same length-delimited codec as TCP. For tests of the actors without
//! sockets.

use crate::{BoxFuture, Connection, Listener, Transport, TransportError, stream};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use tokio::sync::mpsc;

/// A namespace of in-memory listeners, addressed by any string.
#[derive(Clone, Default)]
pub struct MemTransport {
    listeners: Arc<Mutex<HashMap<String, mpsc::UnboundedSender<Connection>>>>,
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
}

impl Listener for MemListener {
    fn local_addr(&self) -> String {
        self.addr.clone()
    }

    fn accept(&mut self) -> BoxFuture<'_, Result<Connection, TransportError>> {
        Box::pin(async move { self.rx.recv().await.ok_or(TransportError::Closed) })
    }
}

impl Transport for MemTransport {
    fn name(&self) -> &'static str {
        "mem"
    }

    fn listen<'a>(&'a self, addr: &'a str) -> BoxFuture<'a, Result<Box<dyn Listener>, TransportError>> {
        Box::pin(async move {
            let (tx, rx) = mpsc::unbounded_channel();
            self.listeners.lock().map_err(|_| TransportError::Closed)?.insert(addr.to_string(), tx);
            Ok(Box::new(MemListener { addr: addr.to_string(), rx }) as Box<dyn Listener>)
        })
    }

    fn connect<'a>(&'a self, addr: &'a str) -> BoxFuture<'a, Result<Connection, TransportError>> {
        Box::pin(async move {
            let listener = self.listeners.lock().map_err(|_| TransportError::Closed)?.get(addr).cloned();
            let refused = || TransportError::Connect { addr: addr.to_string(), reason: "no listener".into() };
            let listener = listener.ok_or_else(refused)?;
            let (a, b) = tokio::io::duplex(256 << 10);
            let (ar, aw) = tokio::io::split(a);
            let (br, bw) = tokio::io::split(b);
            // Both ends start at the handshake limit, as real transports do.
            let max = crate::INITIAL_MAX_FRAME;
            let ours = stream::spawn(ar, aw, addr.to_string(), max);
            let theirs = stream::spawn(br, bw, "mem-peer".to_string(), max);
            listener.send(theirs).map_err(|_| refused())?;
            Ok(ours)
        })
    }
}

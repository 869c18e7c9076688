//! # isin-transport-tcp — the cluster transport over TCP
//!
//! Length-delimited frames over tokio TCP streams, implementing the
//! [`isin_actors::transport::Transport`] interface the actors use. Each
//! connection sets `TCP_NODELAY` (tiles are latency-sensitive and the codec
//! already batches writes), starts with the small handshake frame limit (raised
//! by the master once the peer has authenticated), and reports the peer closing
//! as the end of its frame stream.

use isin_actors::protocol::HANDSHAKE_MAX_FRAME;
use isin_actors::transport::{BoxFuture, Connection, Listener, Transport, TransportError, stream};
use tokio::net::{TcpListener, TcpStream};

/// TCP transport.
#[derive(Clone, Copy, Debug, Default)]
pub struct TcpTransport;

impl TcpTransport {
    /// The TCP transport.
    pub fn new() -> Self {
        Self
    }
}

fn wrap(sock: TcpStream, peer: String) -> Connection {
    if let Err(e) = sock.set_nodelay(true) {
        tracing::warn!(%peer, "cannot set TCP_NODELAY: {e}");
    }
    let (r, w) = sock.into_split();
    stream::spawn(r, w, peer, HANDSHAKE_MAX_FRAME)
}

struct TcpListenerBox {
    inner: TcpListener,
    addr: String,
}

impl Listener for TcpListenerBox {
    fn local_addr(&self) -> String {
        self.addr.clone()
    }

    fn accept(&mut self) -> BoxFuture<'_, Result<Connection, TransportError>> {
        Box::pin(async move {
            let (sock, peer) = self.inner.accept().await?;
            Ok(wrap(sock, peer.to_string()))
        })
    }
}

impl Transport for TcpTransport {
    fn name(&self) -> &'static str {
        "tcp"
    }

    fn listen<'a>(&'a self, addr: &'a str) -> BoxFuture<'a, Result<Box<dyn Listener>, TransportError>> {
        Box::pin(async move {
            let err =
                |e: std::io::Error| TransportError::Listen { addr: addr.to_string(), reason: e.to_string() };
            let inner = TcpListener::bind(addr).await.map_err(err)?;
            let addr = inner.local_addr().map_err(err)?.to_string();
            Ok(Box::new(TcpListenerBox { inner, addr }) as Box<dyn Listener>)
        })
    }

    fn connect<'a>(&'a self, addr: &'a str) -> BoxFuture<'a, Result<Connection, TransportError>> {
        Box::pin(async move {
            let sock = TcpStream::connect(addr)
                .await
                .map_err(|e| TransportError::Connect { addr: addr.to_string(), reason: e.to_string() })?;
            Ok(wrap(sock, addr.to_string()))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    #[tokio::test]
    async fn frames_cross_a_real_socket_both_ways() {
        let t = TcpTransport::new();
        let mut l = t.listen("127.0.0.1:0").await.unwrap();
        let addr = l.local_addr();
        assert!(!addr.ends_with(":0"));
        let mut client = t.connect(&addr).await.unwrap();
        let mut server = l.accept().await.unwrap();
        client.sender.send(b"hello".to_vec()).unwrap();
        assert_eq!(server.receiver.recv().await.unwrap().unwrap(), b"hello");
        server.sender.send(vec![9; 1000]).unwrap();
        assert_eq!(client.receiver.recv().await.unwrap().unwrap(), vec![9; 1000]);
        assert_eq!(server.sender.stats().bytes_sent, 1004);
        drop(client);
        // Dropping every handle of the client closes the socket: clean end.
        assert!(server.receiver.recv().await.is_none());
    }

    #[tokio::test]
    async fn oversized_prefix_closes_only_that_connection() {
        let t = TcpTransport::new();
        let mut l = t.listen("127.0.0.1:0").await.unwrap();
        let addr = l.local_addr();
        let mut raw = tokio::net::TcpStream::connect(&addr).await.unwrap();
        let mut bad = l.accept().await.unwrap();
        raw.write_all(&(HANDSHAKE_MAX_FRAME as u32 + 1).to_be_bytes()).await.unwrap();
        assert!(matches!(bad.receiver.recv().await, Some(Err(TransportError::FrameTooLarge { .. }))));
        bad.sender.close();
        // The raw peer sees the close.
        let mut buf = [0u8; 8];
        assert_eq!(raw.read(&mut buf).await.unwrap(), 0);
        // The listener still serves others.
        let good = t.connect(&addr).await.unwrap();
        let mut served = l.accept().await.unwrap();
        good.sender.send(b"ok".to_vec()).unwrap();
        assert_eq!(served.receiver.recv().await.unwrap().unwrap(), b"ok");
    }

    #[tokio::test]
    async fn connect_to_nothing_is_a_clear_error() {
        let t = TcpTransport::new();
        let l = t.listen("127.0.0.1:0").await.unwrap();
        let addr = l.local_addr();
        drop(l);
        let err = t.connect(&addr).await.unwrap_err();
        assert!(err.to_string().contains(&addr), "{err}");
    }
}

//! The [`tls`] module's configurations used as TLS over TCP would use them
//! (tokio-rustls, ALPN `isin-tcp/1`): the pinned certificate is accepted, any
//! other refused in the handshake, and frames cross
//! the encrypted stream with the actors' length-delimited codec.

use isin_actors::transport::stream;
use isin_transport_quic::tls::{self, Identity};
use std::sync::Arc;
use std::time::Duration;
use tokio::net::{TcpListener, TcpStream};
use tokio::time::timeout;
use tokio_rustls::rustls::pki_types::ServerName;
use tokio_rustls::{TlsAcceptor, TlsConnector};

const BOUND: Duration = Duration::from_secs(20);

#[tokio::test]
async fn tls_over_tcp_with_the_pinned_identity_carries_frames() {
    let id = Identity::generate().unwrap();
    let acceptor = TlsAcceptor::from(Arc::new(tls::server_config(&id, &[tls::ALPN_TCP]).unwrap()));
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let server = tokio::spawn(async move {
        let (sock, peer) = listener.accept().await.unwrap();
        let tls = acceptor.accept(sock).await.unwrap();
        assert_eq!(tls.get_ref().1.alpn_protocol(), Some(tls::ALPN_TCP));
        let (r, w) = tokio::io::split(tls);
        let mut conn = stream::spawn(r, w, peer.to_string(), 1 << 20);
        let f = conn.receiver.recv().await.unwrap().unwrap();
        conn.sender.send(f.iter().rev().copied().collect()).unwrap();
        conn.sender.close();
        assert!(conn.receiver.recv().await.is_none());
    });
    let connector =
        TlsConnector::from(Arc::new(tls::client_config(id.fingerprint(), &[tls::ALPN_TCP]).unwrap()));
    let sock = TcpStream::connect(addr).await.unwrap();
    let tls = connector.connect(ServerName::try_from(tls::SERVER_NAME).unwrap(), sock).await.unwrap();
    let (r, w) = tokio::io::split(tls);
    let mut conn = stream::spawn(r, w, addr.to_string(), 1 << 20);
    let payload: Vec<u8> = (0..50_000u32).map(|i| i as u8).collect();
    conn.sender.send(payload.clone()).unwrap();
    let back = timeout(BOUND, conn.receiver.recv()).await.unwrap().unwrap().unwrap();
    assert_eq!(back, payload.iter().rev().copied().collect::<Vec<_>>());
    assert!(timeout(BOUND, conn.receiver.recv()).await.unwrap().is_none());
    drop(conn);
    timeout(BOUND, server).await.unwrap().unwrap();
}

#[tokio::test]
async fn tls_over_tcp_refuses_an_unpinned_certificate() {
    let id = Identity::generate().unwrap();
    let acceptor = TlsAcceptor::from(Arc::new(tls::server_config(&id, &[tls::ALPN_TCP]).unwrap()));
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let server = tokio::spawn(async move {
        let (sock, _) = listener.accept().await.unwrap();
        // The handshake fails on the server too (the client aborts it).
        assert!(acceptor.accept(sock).await.is_err());
    });
    let other = Identity::generate().unwrap();
    let connector =
        TlsConnector::from(Arc::new(tls::client_config(other.fingerprint(), &[tls::ALPN_TCP]).unwrap()));
    let mut sock = TcpStream::connect(addr).await.unwrap();
    let name = ServerName::try_from(tls::SERVER_NAME).unwrap();
    let err = timeout(BOUND, connector.connect(name, &mut sock)).await.unwrap().unwrap_err();
    assert!(err.to_string().contains("certificate"), "{err}");
    timeout(BOUND, server).await.unwrap().unwrap();
}

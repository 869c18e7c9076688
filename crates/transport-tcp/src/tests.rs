//! What only the TCP transports do, over real loopback sockets: TLS counts
//! socket bytes, never falls back to plaintext, keeps plaintext and silent
//! peers away from accept, and tells a vanished peer from a cut frame. What
//! every transport must do is the conformance suite's
//! (`crates/transport/tests/conformance.rs`).

use super::*;
use tokio::io::AsyncWriteExt;
use tokio::time::timeout;

const BOUND: Duration = Duration::from_secs(20);

/// A TLS server and a client pinning its certificate.
fn tls_pair() -> (TcpTransport, TcpTransport) {
    let id = Identity::generate().unwrap();
    (TcpTransport::server(&id).unwrap(), TcpTransport::client(id.fingerprint()).unwrap())
}

async fn next(c: &mut Connection) -> Vec<u8> {
    timeout(BOUND, c.receiver.recv()).await.expect("in time").expect("open").expect("a frame")
}

#[tokio::test]
async fn tls_counts_socket_bytes_handshake_and_records_included() {
    let (server_t, client_t) = tls_pair();
    assert_eq!((server_t.name(), client_t.name()), ("tcp", "tcp"));
    let mut l = server_t.listen("127.0.0.1:0").await.unwrap();
    let addr = l.local_addr();
    let mut client = timeout(BOUND, client_t.connect(&addr)).await.unwrap().unwrap();
    let mut server = timeout(BOUND, l.accept()).await.unwrap().unwrap();
    server.sender.set_max_frame(1 << 20);
    let payloads: Vec<Vec<u8>> = (0..20u32).map(|i| vec![i as u8; 100 + 3000 * i as usize]).collect();
    for p in &payloads {
        client.sender.send(p.clone()).unwrap();
    }
    for p in &payloads {
        assert_eq!(&next(&mut server).await, p);
    }
    server.sender.send(b"back".to_vec()).unwrap();
    assert_eq!(next(&mut client).await, b"back");
    client.sender.close();
    assert!(timeout(BOUND, server.receiver.recv()).await.unwrap().is_none(), "clean end after close_notify");
    server.sender.close();
    assert!(timeout(BOUND, client.receiver.recv()).await.unwrap().is_none());
    let (c, s) = (client.sender.stats(), server.sender.stats());
    assert_eq!((c.frames_sent, s.frames_received), (20, 20));
    // Both ends count the socket independently: every byte one wrote, the
    // other read (handshake and close_notify included)…
    assert_eq!(c.bytes_sent, s.bytes_received);
    assert_eq!(s.bytes_sent, c.bytes_received);
    // …and that is more than the frames: TLS records and the handshake.
    let framed: u64 = payloads.iter().map(|p| 4 + p.len() as u64).sum();
    assert!(c.bytes_sent > framed + 20 * 21, "{} socket bytes for {framed} frame bytes", c.bytes_sent);
    // The server's certificate alone is a few hundred bytes.
    assert!(s.bytes_sent > 300 + 8, "{s:?}");
}

#[tokio::test]
async fn a_tls_client_never_falls_back_to_plaintext() {
    let plain = TcpTransport::insecure();
    let mut l = plain.listen("127.0.0.1:0").await.unwrap();
    let addr = l.local_addr();
    let (_, client_t) = tls_pair();
    let connecting = tokio::spawn(async move { client_t.connect(&addr).await });
    let mut server = timeout(BOUND, l.accept()).await.unwrap().unwrap();
    // The plaintext side sees a TLS ClientHello, whose first bytes read as an
    // enormous frame length: no frame is ever delivered.
    match timeout(BOUND, server.receiver.recv()).await.unwrap() {
        Some(Err(TransportError::FrameTooLarge { .. })) => {}
        other => panic!("plaintext server got {other:?}"),
    }
    server.sender.close();
    let err = timeout(BOUND, connecting).await.unwrap().unwrap().unwrap_err();
    assert!(err.to_string().contains("TLS"), "{err}");
}

#[tokio::test]
async fn plaintext_and_silent_peers_do_not_reach_or_block_a_tls_listener() {
    let (server_t, client_t) = tls_pair();
    let mut l = server_t.listen("127.0.0.1:0").await.unwrap();
    let addr = l.local_addr();
    // A peer that connects and says nothing: its handshake waits alone.
    let _silent = tokio::net::TcpStream::connect(&addr).await.unwrap();
    // A plaintext isin peer: its frame is not a TLS record; the server drops it.
    let plain = TcpTransport::insecure().connect(&addr).await.unwrap();
    plain.sender.send(b"plaintext hello".to_vec()).unwrap();
    let mut plain_rx = plain.receiver;
    assert!(
        !matches!(timeout(BOUND, plain_rx.recv()).await.unwrap(), Some(Ok(_))),
        "the TLS server answered a plaintext peer with a frame"
    );
    let good = timeout(BOUND, client_t.connect(&addr)).await.unwrap().unwrap();
    good.sender.send(b"tls".to_vec()).unwrap();
    let mut first = timeout(BOUND, l.accept()).await.unwrap().unwrap();
    assert_eq!(next(&mut first).await, b"tls");
}

#[tokio::test]
async fn a_tls_peer_vanishing_between_frames_ends_the_stream_cleanly() {
    // As a killed slave does: the socket closes without a TLS close_notify.
    let id = Identity::generate().unwrap();
    let server_t = TcpTransport::server(&id).unwrap();
    let mut l = server_t.listen("127.0.0.1:0").await.unwrap();
    let addr = l.local_addr();
    let cfg = tls::client_config(id.fingerprint(), &[tls::ALPN_TCP]).unwrap();
    let sock = TcpStream::connect(&addr).await.unwrap();
    let name = tokio_rustls::rustls::pki_types::ServerName::try_from(tls::SERVER_NAME).unwrap();
    let mut raw = TlsConnector::from(Arc::new(cfg)).connect(name, sock).await.unwrap();
    raw.write_all(&[0, 0, 0, 2, b'h', b'i']).await.unwrap();
    raw.flush().await.unwrap();
    let mut server = timeout(BOUND, l.accept()).await.unwrap().unwrap();
    assert_eq!(next(&mut server).await, b"hi");
    drop(raw);
    let end = timeout(BOUND, server.receiver.recv()).await.unwrap();
    assert!(end.is_none(), "a clean end, not {end:?}");
    // Cut inside a frame, it is an error.
    let cfg = tls::client_config(id.fingerprint(), &[tls::ALPN_TCP]).unwrap();
    let sock = TcpStream::connect(&addr).await.unwrap();
    let name = tokio_rustls::rustls::pki_types::ServerName::try_from(tls::SERVER_NAME).unwrap();
    let mut raw = TlsConnector::from(Arc::new(cfg)).connect(name, sock).await.unwrap();
    raw.write_all(&[0, 0, 0, 9, b'h']).await.unwrap();
    raw.flush().await.unwrap();
    let mut server = timeout(BOUND, l.accept()).await.unwrap().unwrap();
    drop(raw);
    assert!(matches!(timeout(BOUND, server.receiver.recv()).await.unwrap(), Some(Err(_))));
}

//! Tests of both TCP transports over real loopback sockets.

use super::*;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
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
async fn frames_cross_a_real_socket_both_ways() {
    let t = TcpTransport::insecure();
    assert_eq!(t.name(), "tcp-insecure");
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
async fn tls_frames_cross_both_ways_and_socket_bytes_are_counted() {
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
async fn a_wrong_fingerprint_is_refused_clearly_and_the_listener_goes_on() {
    let (server_t, client_t) = tls_pair();
    let mut l = server_t.listen("127.0.0.1:0").await.unwrap();
    let addr = l.local_addr();
    let impostor = Identity::generate().unwrap();
    let wrong = TcpTransport::client(impostor.fingerprint()).unwrap();
    let err = timeout(BOUND, wrong.connect(&addr)).await.unwrap().unwrap_err();
    assert!(matches!(err, TransportError::Untrusted { .. }), "{err:?}");
    let text = err.to_string();
    assert!(text.contains(&impostor.fingerprint().to_string()), "{text}");
    assert!(text.contains(&server_t.fingerprint().unwrap().to_string()), "{text}");
    // The refused connection never reached accept: the first one accepted is good.
    let good = timeout(BOUND, client_t.connect(&addr)).await.unwrap().unwrap();
    good.sender.send(b"ok".to_vec()).unwrap();
    let mut first = timeout(BOUND, l.accept()).await.unwrap().unwrap();
    assert_eq!(next(&mut first).await, b"ok");
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
async fn oversized_prefix_closes_only_that_connection() {
    for (server_t, client_t) in [(TcpTransport::insecure(), TcpTransport::insecure()), tls_pair()] {
        let mut l = server_t.listen("127.0.0.1:0").await.unwrap();
        let addr = l.local_addr();
        // A frame of INITIAL_MAX_FRAME + 1 bytes: its prefix alone is refused.
        let bad_client = client_t.connect(&addr).await.unwrap();
        bad_client.sender.send(vec![1; INITIAL_MAX_FRAME + 1]).unwrap();
        let mut bad = timeout(BOUND, l.accept()).await.unwrap().unwrap();
        assert!(
            matches!(bad.receiver.recv().await, Some(Err(TransportError::FrameTooLarge { .. }))),
            "{}",
            server_t.name()
        );
        bad.sender.close();
        let mut bad_rx = bad_client.receiver;
        assert!(!matches!(timeout(BOUND, bad_rx.recv()).await.unwrap(), Some(Ok(_))));
        // The listener still serves others.
        let good = client_t.connect(&addr).await.unwrap();
        let mut served = timeout(BOUND, l.accept()).await.unwrap().unwrap();
        good.sender.send(b"ok".to_vec()).unwrap();
        assert_eq!(next(&mut served).await, b"ok");
    }
}

#[tokio::test]
async fn raw_garbage_is_refused_without_reading_a_body() {
    let t = TcpTransport::insecure();
    let mut l = t.listen("127.0.0.1:0").await.unwrap();
    let addr = l.local_addr();
    let mut raw = tokio::net::TcpStream::connect(&addr).await.unwrap();
    let mut bad = l.accept().await.unwrap();
    raw.write_all(&(INITIAL_MAX_FRAME as u32 + 1).to_be_bytes()).await.unwrap();
    assert!(matches!(bad.receiver.recv().await, Some(Err(TransportError::FrameTooLarge { .. }))));
    bad.sender.close();
    let mut buf = [0u8; 8];
    assert_eq!(raw.read(&mut buf).await.unwrap(), 0);
}

#[tokio::test]
async fn misuse_and_unreachable_masters_are_clear_errors() {
    let (server_t, client_t) = tls_pair();
    let err = client_t.listen("127.0.0.1:0").await.err().expect("a client-only transport cannot listen");
    assert!(err.to_string().contains("certificate"), "{err}");
    let err = server_t.connect("127.0.0.1:9").await.unwrap_err();
    assert!(err.to_string().contains("fingerprint"), "{err}");
    let l = TcpTransport::insecure().listen("127.0.0.1:0").await.unwrap();
    let addr = l.local_addr();
    drop(l);
    for t in [TcpTransport::insecure(), client_t] {
        let err = t.connect(&addr).await.unwrap_err();
        assert!(matches!(err, TransportError::Connect { .. }) && err.to_string().contains(&addr), "{err}");
    }
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

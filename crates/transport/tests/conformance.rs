//! The transport conformance suite: what every transport must do, written
//! once and run over each of them — in memory, TLS over TCP, plaintext TCP
//! and QUIC, on real loopback sockets for the last three.
//!
//! Each test body is a closure over the [`Kind`] under test;
//! [`conformance_test!`] makes one module per body with one `#[tokio::test]`
//! per transport (`mem`, `tls`, `plain`, `quic`), so a failure names both.
//!
//! Contents:
//! - `frames_cross_both_ways_in_a_legal_order_and_are_counted`
//! - `a_wrong_fingerprint_is_refused_clearly` (TLS and QUIC)
//! - `an_oversized_announced_frame_is_refused_without_waiting_for_its_body`
//! - `a_frame_over_the_memory_budget_is_refused_and_closes_its_connection`
//! - `a_trickling_peer_is_timed_out_and_its_reservation_freed`
//! - `a_vanished_peer_ends_the_receiver`
//! - `misuse_is_an_error_not_a_panic`, `one_sided_encrypted_transports_refuse_clearly`
//!
//! Peers that must break the rules — announce a length and never send the
//! body, trickle bytes — are [`RawPeer`]s: a connection below the framing of
//! each transport (a byte pipe, a TCP socket, a TLS stream, a QUIC control
//! stream), writing frame headers of the test's choosing. What only QUIC does
//! (a stream per independent frame, loss, the idle timeout) is tested in
//! `crates/transport-quic/tests/quic.rs`; the token handshake (a wrong token)
//! is the cluster's, above every transport.

use isin_transport::mem::MemTransport;
use isin_transport::{
    Connection, Delivery, INITIAL_MAX_FRAME, Listener, MemoryBudget, Transport, TransportError,
};
use isin_transport_quic::{QuicOptions, QuicTransport, wire};
use isin_transport_tcp::TcpTransport;
use isin_transport_tls::{self as tls, Fingerprint, Identity};
use std::sync::Arc;
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::time::timeout;

/// How long any single wait may take before the test fails.
const BOUND: Duration = Duration::from_secs(20);

/// The transport under test.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Mem,
    Tls,
    Plain,
    Quic,
}

impl Kind {
    fn named(name: &str) -> Kind {
        match name {
            "mem" => Kind::Mem,
            "tls" => Kind::Tls,
            "plain" => Kind::Plain,
            "quic" => Kind::Quic,
            other => panic!("no transport kind {other}"),
        }
    }
}

/// One test body per transport: `conformance_test!(name, |k: Kind| async move { … })`,
/// optionally with the list of transports it applies to.
macro_rules! conformance_test {
    ($name:ident, $body:expr) => {
        conformance_test!($name, $body, [mem, tls, plain, quic]);
    };
    ($name:ident, $body:expr, [$($kind:ident),*]) => {
        mod $name {
            #[allow(unused_imports)]
            use super::*;
            $(
                #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
                async fn $kind() {
                    ($body)(Kind::named(stringify!($kind))).await
                }
            )*
        }
    };
}

/// A listening side and a client side that reaches it.
struct Setup {
    kind: Kind,
    server: Box<dyn Transport>,
    client: Box<dyn Transport>,
    /// The in-memory namespace, for raw peers.
    mem: Option<MemTransport>,
    /// The certificate the server presents (TLS and QUIC).
    fingerprint: Option<Fingerprint>,
}

fn quic_options() -> QuicOptions {
    QuicOptions {
        keep_alive: Duration::from_millis(200),
        idle_timeout: Duration::from_secs(1),
        ..QuicOptions::default()
    }
}

impl Setup {
    fn new(kind: Kind) -> Setup {
        let id = Identity::generate().expect("identity");
        let fp = id.fingerprint();
        match kind {
            Kind::Mem => {
                let t = MemTransport::new();
                Setup {
                    kind,
                    server: Box::new(t.clone()),
                    client: Box::new(t.clone()),
                    mem: Some(t),
                    fingerprint: None,
                }
            }
            Kind::Plain => Setup {
                kind,
                server: Box::new(TcpTransport::insecure()),
                client: Box::new(TcpTransport::insecure()),
                mem: None,
                fingerprint: None,
            },
            Kind::Tls => Setup {
                kind,
                server: Box::new(TcpTransport::server(&id).expect("server")),
                client: Box::new(TcpTransport::client(fp).expect("client")),
                mem: None,
                fingerprint: Some(fp),
            },
            Kind::Quic => Setup {
                kind,
                server: Box::new(QuicTransport::server(&id).expect("server").with_options(quic_options())),
                client: Box::new(QuicTransport::client(fp).expect("client").with_options(quic_options())),
                mem: None,
                fingerprint: Some(fp),
            },
        }
    }

    /// A client of this kind that pins `pinned` (TLS and QUIC).
    fn client_pinning(&self, pinned: Fingerprint) -> Box<dyn Transport> {
        match self.kind {
            Kind::Tls => Box::new(TcpTransport::client(pinned).expect("client")),
            Kind::Quic => {
                Box::new(QuicTransport::client(pinned).expect("client").with_options(quic_options()))
            }
            Kind::Mem | Kind::Plain => unreachable!("{:?} pins no certificate", self.kind),
        }
    }

    async fn listen(&self) -> Box<dyn Listener> {
        self.server.listen("127.0.0.1:0").await.expect("listen")
    }

    /// A connected pair: (client side, server side).
    async fn pair(&self, l: &mut Box<dyn Listener>) -> (Connection, Connection) {
        let c =
            timeout(BOUND, self.client.connect(&l.local_addr())).await.expect("in time").expect("connect");
        let s = timeout(BOUND, l.accept()).await.expect("in time").expect("accept");
        (c, s)
    }

    /// A peer below the framing, connected to `l`, and the server's side of it.
    async fn raw(&self, l: &mut Box<dyn Listener>) -> (RawPeer, Connection) {
        let addr = l.local_addr();
        let raw = match self.kind {
            Kind::Mem => {
                let pipe = self.mem.as_ref().expect("namespace").connect_raw(&addr).await.expect("connect");
                RawPeer::Stream(Box::new(pipe))
            }
            Kind::Plain => {
                RawPeer::Stream(Box::new(tokio::net::TcpStream::connect(&addr).await.expect("connect")))
            }
            Kind::Tls => {
                let fp = self.fingerprint.expect("fingerprint");
                let cfg = tls::client_config(fp, &[tls::ALPN_TCP]).expect("config");
                let sock = tokio::net::TcpStream::connect(&addr).await.expect("connect");
                let name =
                    tokio_rustls::rustls::pki_types::ServerName::try_from(tls::SERVER_NAME).expect("name");
                let stream =
                    tokio_rustls::TlsConnector::from(Arc::new(cfg)).connect(name, sock).await.expect("TLS");
                RawPeer::Stream(Box::new(stream))
            }
            Kind::Quic => {
                let fp = self.fingerprint.expect("fingerprint");
                let cfg = tls::client_config(fp, &[tls::ALPN_QUIC]).expect("config");
                let crypto = quinn::crypto::rustls::QuicClientConfig::try_from(cfg).expect("QUIC config");
                let ep = quinn::Endpoint::client("127.0.0.1:0".parse().expect("addr")).expect("endpoint");
                let conn = ep
                    .connect_with(
                        quinn::ClientConfig::new(Arc::new(crypto)),
                        addr.parse().expect("addr"),
                        tls::SERVER_NAME,
                    )
                    .expect("connect")
                    .await
                    .expect("handshake");
                let (mut send, recv) = conn.open_bi().await.expect("control stream");
                send.write_all(wire::PREAMBLE).await.expect("preamble");
                RawPeer::Quic { _ep: ep, conn, send, _recv: recv }
            }
        };
        let s = timeout(BOUND, l.accept()).await.expect("in time").expect("accept");
        (raw, s)
    }
}

/// A byte stream a raw peer writes frames onto.
trait RawStream: AsyncRead + AsyncWrite + Unpin + Send {}
impl<T: AsyncRead + AsyncWrite + Unpin + Send> RawStream for T {}

/// A peer that writes the transport's framing itself (see the crate docs).
enum RawPeer {
    /// Length-delimited frames over a byte stream (mem, plaintext, TLS).
    Stream(Box<dyn RawStream>),
    /// Control-stream records over QUIC.
    Quic { _ep: quinn::Endpoint, conn: quinn::Connection, send: quinn::SendStream, _recv: quinn::RecvStream },
}

impl RawPeer {
    /// Writes the header of an ordered frame of `len` bytes.
    async fn announce(&mut self, len: u32) {
        match self {
            RawPeer::Stream(s) => {
                s.write_all(&len.to_be_bytes()).await.expect("write");
                s.flush().await.expect("flush");
            }
            RawPeer::Quic { send, .. } => send.write_all(&wire::control_header(0, len)).await.expect("write"),
        }
    }

    /// Writes body bytes; `false` once the server has closed the connection.
    async fn write(&mut self, bytes: &[u8]) -> bool {
        match self {
            RawPeer::Stream(s) => s.write_all(bytes).await.is_ok() && s.flush().await.is_ok(),
            RawPeer::Quic { send, .. } => send.write_all(bytes).await.is_ok(),
        }
    }

    /// Waits until the server closes the connection (or fails the test).
    async fn expect_closed(&mut self) {
        match self {
            RawPeer::Stream(s) => {
                let mut buf = [0u8; 64];
                loop {
                    match timeout(BOUND, s.read(&mut buf)).await.expect("the server closed the connection") {
                        Ok(0) | Err(_) => return,
                        Ok(_) => continue,
                    }
                }
            }
            RawPeer::Quic { conn, .. } => {
                timeout(BOUND, conn.closed()).await.expect("the server closed the connection");
            }
        }
    }
}

/// Test frames: `[seq: u32][bytes that depend on seq and index]`.
fn frame(seq: u32, len: usize) -> Vec<u8> {
    let mut f = seq.to_be_bytes().to_vec();
    f.extend((4..len.max(4)).map(|i| (seq as usize).wrapping_mul(31).wrapping_add(i) as u8));
    f
}

/// A mix: every 4th frame ordered, the others independent, sizes varied.
fn plan(n: u32) -> Vec<(Vec<u8>, Delivery)> {
    (0..n)
        .map(|seq| {
            let delivery = if seq % 4 == 0 { Delivery::Ordered } else { Delivery::Independent };
            (frame(seq, 4 + (seq as usize * 977) % 12_000), delivery)
        })
        .collect()
}

/// Receives every frame of `sent` and checks it is intact, delivered once,
/// and in a legal order: an ordered frame after everything sent before it, an
/// independent frame after every ordered frame sent before it.
async fn receive_checked(conn: &mut Connection, sent: &[(Vec<u8>, Delivery)]) {
    let mut got = vec![false; sent.len()];
    for _ in 0..sent.len() {
        let f = timeout(BOUND, conn.receiver.recv())
            .await
            .expect("frame in time")
            .expect("open")
            .expect("a frame");
        let seq = u32::from_be_bytes(f[..4].try_into().expect("4 bytes")) as usize;
        assert_eq!(f, sent[seq].0, "frame {seq} intact");
        assert!(!got[seq], "frame {seq} delivered twice");
        got[seq] = true;
        for (earlier, (_, d)) in sent.iter().enumerate().take(seq) {
            let must = sent[seq].1 == Delivery::Ordered || *d == Delivery::Ordered;
            assert!(!must || got[earlier], "frame {seq} overtook frame {earlier}");
        }
    }
}

/// The next item of `conn`'s receiver, which must be an error.
async fn next_error(conn: &mut Connection) -> TransportError {
    match timeout(BOUND, conn.receiver.recv()).await.expect("in time") {
        Some(Err(e)) => e,
        other => panic!("expected an error, got {other:?}"),
    }
}

/// Waits (bounded) until the budget holds `bytes`: the reader has taken a
/// reservation no event reports.
async fn until_in_use(budget: &MemoryBudget, bytes: usize) {
    let t0 = std::time::Instant::now();
    while budget.in_use() != bytes {
        assert!(t0.elapsed() < BOUND, "budget holds {} bytes, expected {bytes}", budget.in_use());
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
}

conformance_test!(frames_cross_both_ways_in_a_legal_order_and_are_counted, |k: Kind| async move {
    let setup = Setup::new(k);
    let mut l = setup.listen().await;
    assert!(!l.local_addr().ends_with(":0") || k == Kind::Mem, "the real port: {}", l.local_addr());
    let (mut c, mut s) = setup.pair(&mut l).await;
    let (up, down) = (plan(120), plan(80));
    // Both directions at once, the client's from a plain thread as render threads send.
    let cs = c.sender.clone();
    let u = up.clone();
    let sender = std::thread::spawn(move || u.into_iter().for_each(|(f, d)| cs.send_as(f, d).expect("send")));
    for (f, d) in &down {
        s.sender.send_as(f.clone(), *d).expect("send");
    }
    tokio::join!(receive_checked(&mut s, &up), receive_checked(&mut c, &down));
    sender.join().expect("sender thread");
    // Every frame is in. A writer counts bytes once its socket took them, and
    // the peer may read them first: wait, within the bound, for the counts of
    // both sides to agree. (Compared before closing: what a side writes while
    // closing — TLS's close_notify — its peer may never read.)
    let deadline = std::time::Instant::now() + BOUND;
    let agree = || {
        let (a, b) = (c.sender.stats(), s.sender.stats());
        a.bytes_sent == b.bytes_received && b.bytes_sent == a.bytes_received
    };
    while !agree() && std::time::Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    let (cst, sst) = (c.sender.stats(), s.sender.stats());
    assert_eq!((cst.frames_sent, sst.frames_received), (120, 120));
    assert_eq!((sst.frames_sent, cst.frames_received), (80, 80));
    // Each side counts independently; what one wrote, the other read…
    assert_eq!(cst.bytes_sent, sst.bytes_received);
    assert_eq!(sst.bytes_sent, cst.bytes_received);
    // …and that is at least the frames and a 4-byte header each.
    let framed = |p: &[(Vec<u8>, Delivery)]| p.iter().map(|(f, _)| 4 + f.len() as u64).sum::<u64>();
    assert!(cst.bytes_sent >= framed(&up), "{cst:?}");
    assert!(sst.bytes_sent >= framed(&down), "{sst:?}");
    // Closing ends the other side's stream cleanly, both ways.
    c.sender.close();
    assert!(timeout(BOUND, s.receiver.recv()).await.expect("in time").is_none(), "clean end");
    s.sender.close();
    assert!(timeout(BOUND, c.receiver.recv()).await.expect("in time").is_none(), "clean end");
});

conformance_test!(
    a_wrong_fingerprint_is_refused_clearly,
    |k: Kind| async move {
        let setup = Setup::new(k);
        let mut l = setup.listen().await;
        let impostor = Identity::generate().expect("identity").fingerprint();
        let err = timeout(BOUND, setup.client_pinning(impostor).connect(&l.local_addr()))
            .await
            .expect("in time")
            .expect_err("a certificate with another fingerprint must be refused");
        assert!(matches!(err, TransportError::Untrusted { .. }), "{err:?}");
        let text = err.to_string();
        assert!(text.contains(&impostor.to_string()), "{text}");
        assert!(text.contains(&setup.fingerprint.expect("fingerprint").to_string()), "{text}");
        // The refused peer never reached accept: the first connection accepted is a good one.
        let (c, mut s) = setup.pair(&mut l).await;
        c.sender.send(frame(7, 10)).expect("send");
        assert_eq!(
            timeout(BOUND, s.receiver.recv()).await.expect("in time").expect("open").expect("frame"),
            frame(7, 10)
        );
    },
    [tls, quic]
);

conformance_test!(
    an_oversized_announced_frame_is_refused_without_waiting_for_its_body,
    |k: Kind| async move {
        let setup = Setup::new(k);
        let mut l = setup.listen().await;
        let budget = MemoryBudget::new(1 << 30);
        l.set_budget(budget.clone());
        let (mut raw, mut s) = setup.raw(&mut l).await;
        // The largest length the wire can announce, and no body: a reader that
        // waited for (or allocated) the body would never answer.
        raw.announce(u32::MAX).await;
        match next_error(&mut s).await {
            TransportError::FrameTooLarge { len, max } => {
                assert_eq!((len, max), (u32::MAX as u64, INITIAL_MAX_FRAME))
            }
            other => panic!("expected FrameTooLarge, got {other:?}"),
        }
        assert!(
            timeout(BOUND, s.receiver.recv()).await.expect("in time").is_none(),
            "one error, then the end"
        );
        assert_eq!(budget.in_use(), 0, "nothing was reserved for a frame over the limit");
        assert_eq!(s.sender.stats().frames_received, 0);
        raw.expect_closed().await;
        // The listener serves others.
        let (c, mut s2) = setup.pair(&mut l).await;
        c.sender.send(frame(1, 100)).expect("send");
        assert_eq!(
            timeout(BOUND, s2.receiver.recv()).await.expect("in time").expect("open").expect("frame"),
            frame(1, 100)
        );
    }
);

conformance_test!(
    a_frame_over_the_memory_budget_is_refused_and_closes_its_connection,
    |k: Kind| async move {
        let setup = Setup::new(k);
        let mut l = setup.listen().await;
        // Room for one 12 KB frame (both under the handshake limit), not two.
        let budget = MemoryBudget::new(20_000);
        l.set_budget(budget.clone());
        let (mut holder, mut held) = setup.raw(&mut l).await;
        let (mut greedy, mut refused) = setup.raw(&mut l).await;
        // The first peer announces 12 KB and sends a byte: its reservation stands.
        holder.announce(12_000).await;
        assert!(holder.write(&[0]).await);
        until_in_use(&budget, 12_000).await;
        // The second's 12 KB would exceed the budget: refused at once, never waited for.
        greedy.announce(12_000).await;
        match next_error(&mut refused).await {
            TransportError::OverBudget { len, in_use, limit } => {
                assert_eq!((len, in_use, limit), (12_000, 12_000, 20_000))
            }
            other => panic!("expected OverBudget, got {other:?}"),
        }
        assert!(timeout(BOUND, refused.receiver.recv()).await.expect("in time").is_none());
        greedy.expect_closed().await;
        assert_eq!(budget.in_use(), 12_000, "the refusal reserved nothing");
        // The first frame completes; its bytes leave the budget when the application takes it.
        assert!(holder.write(&[7; 11_999]).await);
        let f = timeout(BOUND, held.receiver.recv()).await.expect("in time").expect("open").expect("frame");
        assert_eq!((f.len(), f[0], f[11_999]), (12_000, 0, 7));
        assert_eq!(budget.in_use(), 0);
        // A frame too large for the budget alone is refused even when nothing is held.
        held.sender.set_max_frame(1 << 20);
        holder.announce(20_001).await;
        assert!(matches!(
            next_error(&mut held).await,
            TransportError::OverBudget { len: 20_001, in_use: 0, .. }
        ));
        holder.expect_closed().await;
        assert_eq!(budget.in_use(), 0);
    }
);

conformance_test!(a_trickling_peer_is_timed_out_and_its_reservation_freed, |k: Kind| async move {
    let setup = Setup::new(k);
    let mut l = setup.listen().await;
    let budget = MemoryBudget::new(1 << 20);
    l.set_budget(budget.clone());
    l.set_frame_timeout(Duration::from_millis(300));
    let (mut raw, mut s) = setup.raw(&mut l).await;
    raw.announce(1000).await;
    until_in_use(&budget, 1000).await;
    // One byte now and then: progress, but the frame is never done in time.
    let trickle = tokio::spawn(async move {
        for _ in 0..100 {
            if !raw.write(&[1]).await {
                break;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        raw
    });
    match next_error(&mut s).await {
        TransportError::FrameTimeout { len, timeout } => {
            assert_eq!((len, timeout), (1000, Duration::from_millis(300)))
        }
        other => panic!("expected FrameTimeout, got {other:?}"),
    }
    assert!(timeout(BOUND, s.receiver.recv()).await.expect("in time").is_none());
    assert_eq!(budget.in_use(), 0, "the late frame's reservation was given back");
    let mut raw = timeout(BOUND, trickle).await.expect("the trickler learnt it was cut off").expect("task");
    raw.expect_closed().await;
});

conformance_test!(a_vanished_peer_ends_the_receiver, |k: Kind| async move {
    let setup = Setup::new(k);
    let mut l = setup.listen().await;
    // A well-behaved peer dropped without a close: its frames, then the end.
    let (c, mut s) = setup.pair(&mut l).await;
    c.sender.send_as(frame(3, 5000), Delivery::Independent).expect("send");
    drop(c);
    assert_eq!(
        timeout(BOUND, s.receiver.recv()).await.expect("in time").expect("open").expect("frame"),
        frame(3, 5000)
    );
    assert!(timeout(BOUND, s.receiver.recv()).await.expect("the end in time").is_none());
    // A peer whose connection simply goes away between frames (a killed
    // process: no close record, no TLS close_notify) ends the stream too.
    let (mut raw, mut s) = setup.raw(&mut l).await;
    raw.announce(2).await;
    assert!(raw.write(b"hi").await);
    assert_eq!(
        timeout(BOUND, s.receiver.recv()).await.expect("in time").expect("open").expect("frame"),
        b"hi"
    );
    drop(raw);
    match timeout(BOUND, s.receiver.recv()).await.expect("the end in time") {
        None => {}
        // QUIC has no clean end without the peer's end record; the loss may be reported.
        Some(Err(e)) if k == Kind::Quic => eprintln!("QUIC: {e}"),
        other => panic!("expected the end, got {other:?}"),
    }
});

conformance_test!(misuse_is_an_error_not_a_panic, |k: Kind| async move {
    let setup = Setup::new(k);
    let mut l = setup.listen().await;
    let (c, s) = setup.pair(&mut l).await;
    c.sender.close();
    assert!(matches!(c.sender.send(frame(0, 8)), Err(TransportError::Closed)));
    assert!(matches!(c.sender.send_as(frame(0, 8), Delivery::Independent), Err(TransportError::Closed)));
    assert!(c.sender.is_closed());
    c.sender.close(); // twice is harmless
    drop(s);
    // Nothing listening there any more.
    let addr = l.local_addr();
    drop(l);
    let addr = if k == Kind::Mem { "nobody".to_string() } else { addr };
    let err =
        timeout(BOUND, setup.client.connect(&addr)).await.expect("in time").expect_err("nobody listens");
    assert!(matches!(err, TransportError::Connect { .. }), "{err:?}");
    assert!(err.to_string().contains(&addr), "{err}");
});

conformance_test!(
    one_sided_encrypted_transports_refuse_clearly,
    |k: Kind| async move {
        let setup = Setup::new(k);
        let err =
            setup.client.listen("127.0.0.1:0").await.err().expect("a client-only transport cannot listen");
        assert!(
            matches!(err, TransportError::Listen { .. }) && err.to_string().contains("certificate"),
            "{err}"
        );
        let err =
            setup.server.connect("127.0.0.1:9").await.expect_err("a server-only transport cannot connect");
        assert!(
            matches!(err, TransportError::Connect { .. }) && err.to_string().contains("fingerprint"),
            "{err}"
        );
    },
    [tls, quic]
);

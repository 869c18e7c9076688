//! What only QUIC does, over real UDP sockets on 127.0.0.1: delivery and
//! ordering rules (a stream per independent frame), QUIC's own counters,
//! packet loss, the idle timeout noticing a vanished peer, closing, and a
//! listener that keeps serving through broken peers. What every transport
//! must do is the conformance suite's (`crates/transport/tests/conformance.rs`).
//!
//! Test frames are `[kind][seq: u32][payload]`; the tests send kind 1 as
//! [independent](Delivery::Independent) (its own stream), anything else
//! ordered ([`send`]). Payload bytes are a function of (seq, index), so
//! corruption is caught too.

mod relay;

use isin_transport::{Connection, Delivery, FrameSender, Listener, Transport, TransportError};
use isin_transport_quic::tls::{self, Identity};
use isin_transport_quic::wire;
use isin_transport_quic::{QuicOptions, QuicTransport};
use relay::Relay;
use std::collections::HashSet;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::time::timeout;

const BOUND: Duration = Duration::from_secs(20);

/// How the tests send a frame: kind 1 independent, anything else ordered.
fn by_first_byte(frame: &[u8]) -> Delivery {
    if frame.first() == Some(&1) { Delivery::Independent } else { Delivery::Ordered }
}

/// Sends `frame` delivered as its first byte says ([`by_first_byte`]).
fn send(sender: &FrameSender, frame: Vec<u8>) {
    let delivery = by_first_byte(&frame);
    sender.send_as(frame, delivery).unwrap();
}

fn options() -> QuicOptions {
    QuicOptions {
        keep_alive: Duration::from_millis(200),
        idle_timeout: Duration::from_secs(1),
        ..QuicOptions::default()
    }
}

/// A server transport and a client transport pinning it.
fn transports() -> (QuicTransport, QuicTransport) {
    let id = Identity::generate().unwrap();
    let server = QuicTransport::server(&id).unwrap().with_options(options());
    let client = QuicTransport::client(id.fingerprint()).unwrap().with_options(options());
    (server, client)
}

async fn listen(t: &QuicTransport) -> Box<dyn Listener> {
    t.listen("127.0.0.1:0").await.unwrap()
}

/// A connected pair (client side, server side), both accepting frames up to `max`.
async fn pair(max: usize) -> (Connection, Connection, Box<dyn Listener>, QuicTransport) {
    let (server, client) = transports();
    let mut l = listen(&server).await;
    let c = timeout(BOUND, client.connect(&l.local_addr())).await.unwrap().unwrap();
    let s = timeout(BOUND, l.accept()).await.unwrap().unwrap();
    c.sender.set_max_frame(max);
    s.sender.set_max_frame(max);
    (c, s, l, client)
}

fn frame(kind: u8, seq: u32, len: usize) -> Vec<u8> {
    let mut f = Vec::with_capacity(len.max(5));
    f.push(kind);
    f.extend_from_slice(&seq.to_be_bytes());
    f.extend((5..len).map(|i| (seq as usize).wrapping_mul(31).wrapping_add(i) as u8));
    f
}

fn check_payload(f: &[u8]) -> u32 {
    assert!(f.len() >= 5, "frame of {} bytes", f.len());
    let seq = u32::from_be_bytes([f[1], f[2], f[3], f[4]]);
    for (i, &b) in f.iter().enumerate().skip(5) {
        assert_eq!(b, (seq as usize).wrapping_mul(31).wrapping_add(i) as u8, "frame {seq} byte {i}");
    }
    seq
}

/// A mixed plan: every 5th frame ordered and small, the others independent,
/// alternating `big` bytes and a few bytes.
fn plan(n: u32, big: usize) -> Vec<Vec<u8>> {
    (0..n)
        .map(|seq| match seq % 5 {
            0 => frame(0, seq, 40),
            1 | 3 => frame(1, seq, big),
            _ => frame(1, seq, 7),
        })
        .collect()
}

fn wire_bytes(frames: &[Vec<u8>]) -> u64 {
    frames
        .iter()
        .map(|f| {
            let header = match by_first_byte(f) {
                Delivery::Ordered => wire::CONTROL_HEADER,
                Delivery::Independent => wire::STREAM_HEADER,
            };
            (header + f.len()) as u64
        })
        .sum()
}

/// Receives `sent.len()` frames and checks content and the ordering rules:
/// an ordered frame arrives after everything sent before it; an independent
/// frame after every ordered frame sent before it.
async fn receive_checked(conn: &mut Connection, sent: &[Vec<u8>]) {
    let mut got = HashSet::new();
    for _ in 0..sent.len() {
        let f = timeout(BOUND, conn.receiver.recv()).await.expect("frame in time").expect("open").unwrap();
        let seq = check_payload(&f);
        assert_eq!(f, sent[seq as usize], "frame {seq} intact");
        assert!(got.insert(seq), "frame {seq} delivered twice");
        for (earlier, e) in sent.iter().enumerate().take(seq as usize) {
            let must = by_first_byte(&f) == Delivery::Ordered || by_first_byte(e) == Delivery::Ordered;
            assert!(!must || got.contains(&(earlier as u32)), "frame {seq} overtook frame {earlier}");
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn many_frames_round_trip_both_ways_with_ordering_rules_and_counters() {
    let (mut c, mut s, _l, client) = pair(1 << 20).await;
    let up = plan(300, 200_000);
    let down = plan(300, 150_000);
    // Both directions at once, senders on plain threads as render threads would.
    let (cs, ss) = (c.sender.clone(), s.sender.clone());
    let (u, d) = (up.clone(), down.clone());
    let t1 = std::thread::spawn(move || u.into_iter().for_each(|f| send(&cs, f)));
    let t2 = std::thread::spawn(move || d.into_iter().for_each(|f| send(&ss, f)));
    let (r1, r2) = tokio::join!(receive_checked(&mut s, &up), receive_checked(&mut c, &down));
    let _ = (r1, r2);
    t1.join().unwrap();
    t2.join().unwrap();
    let (cst, sst) = (c.sender.stats(), s.sender.stats());
    assert_eq!((cst.frames_sent, sst.frames_received), (300, 300));
    assert_eq!((sst.frames_sent, cst.frames_received), (300, 300));
    assert_eq!(cst.bytes_sent, wire_bytes(&up));
    assert_eq!(sst.bytes_received, cst.bytes_sent);
    assert_eq!(sst.bytes_sent, wire_bytes(&down));
    assert_eq!(cst.bytes_received, sst.bytes_sent);
    // QUIC's own count of UDP bytes covers the frames plus packet overhead
    // (headers, AEAD tags, ACKs; a few % for large frames) and, on a loaded
    // machine, retransmissions of datagrams the loopback dropped: bounded, not exact.
    let w = client.wire_stats();
    assert_eq!(w.connections, 1);
    assert!(w.udp_tx_bytes > cst.bytes_sent && w.udp_tx_bytes < cst.bytes_sent + cst.bytes_sent / 2, "{w:?}");
    assert!(w.udp_rx_bytes > cst.bytes_received, "{w:?}");
    // The shorter ACK delay was requested from the peer (ACK-frequency extension).
    assert!(w.ack_frequency_sent >= 1 && w.acks_sent > 0, "{w:?}");
}

#[tokio::test]
async fn the_senders_delivery_decides_the_stream_and_single_stream_orders_everything() {
    let tile = |id: u8| vec![id; 12_288];
    let hb = b"heartbeat".to_vec();
    for single_stream in [false, true] {
        let id = Identity::generate().unwrap();
        let server = QuicTransport::server(&id).unwrap();
        let client = QuicTransport::client(id.fingerprint())
            .unwrap()
            .with_options(QuicOptions { single_stream, ..QuicOptions::default() });
        let mut l = listen(&server).await;
        let c = client.connect(&l.local_addr()).await.unwrap();
        let mut s = timeout(BOUND, l.accept()).await.unwrap().unwrap();
        s.sender.set_max_frame(1 << 20);
        for id in 0..20 {
            c.sender.send_as(tile(id), Delivery::Independent).unwrap();
        }
        c.sender.send(hb.clone()).unwrap();
        let mut tiles = Vec::new();
        for _ in 0..20 {
            let f = timeout(BOUND, s.receiver.recv()).await.unwrap().unwrap().unwrap();
            assert_ne!(f, hb, "the ordered frame overtook a tile sent before it");
            tiles.push(f[0]);
        }
        assert_eq!(timeout(BOUND, s.receiver.recv()).await.unwrap().unwrap().unwrap(), hb);
        let mut sorted = tiles.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..20).collect::<Vec<u8>>(), "every tile once");
        // Independent tiles each on a stream (12-byte header), the ordered frame
        // on the control stream (13); with one stream, all 21 on the control stream.
        let expected = if single_stream {
            assert_eq!(tiles, sorted, "one stream delivers in send order");
            21 * wire::CONTROL_HEADER + 20 * 12_288 + hb.len()
        } else {
            20 * (12_288 + wire::STREAM_HEADER) + hb.len() + wire::CONTROL_HEADER
        };
        assert_eq!(s.sender.stats().bytes_received, expected as u64, "single_stream: {single_stream}");
    }
}

#[tokio::test]
async fn close_delivers_everything_queued_then_ends_both_sides() {
    let (c, mut s, _l, _t) = pair(1 << 20).await;
    let frames = plan(50, 60_000);
    for f in &frames {
        send(&c.sender, f.clone());
    }
    c.sender.close();
    assert!(c.sender.send(frame(0, 0, 5)).is_err());
    receive_checked(&mut s, &frames).await;
    assert!(timeout(BOUND, s.receiver.recv()).await.unwrap().is_none());
    // The server's side learns the connection is gone.
    let t0 = Instant::now();
    while !s.sender.is_closed() {
        assert!(t0.elapsed() < BOUND, "server sender never saw the close");
        let _ = s.sender.send(frame(0, 0, 5));
        tokio::task::yield_now().await;
    }
}

#[tokio::test]
async fn dropping_the_senders_half_closes_and_the_other_direction_still_works() {
    let (c, mut s, _l, _t) = pair(1 << 20).await;
    let Connection { sender, mut receiver, .. } = c;
    let frames = plan(20, 30_000);
    for f in &frames {
        send(&sender, f.clone());
    }
    drop(sender);
    receive_checked(&mut s, &frames).await;
    assert!(timeout(BOUND, s.receiver.recv()).await.unwrap().is_none(), "end of the client's direction");
    // The server can still talk to the client.
    let back = plan(20, 30_000);
    for f in &back {
        send(&s.sender, f.clone());
    }
    s.sender.close();
    for _ in 0..back.len() {
        let f = timeout(BOUND, receiver.recv()).await.unwrap().unwrap().unwrap();
        check_payload(&f);
    }
    assert!(timeout(BOUND, receiver.recv()).await.unwrap().is_none());
}

#[tokio::test]
async fn dropping_a_connection_ends_the_peers_stream() {
    let (c, mut s, _l, _t) = pair(1 << 20).await;
    send(&c.sender, frame(1, 0, 5000));
    drop(c);
    assert_eq!(check_payload(&timeout(BOUND, s.receiver.recv()).await.unwrap().unwrap().unwrap()), 0);
    assert!(timeout(BOUND, s.receiver.recv()).await.unwrap().is_none());
}

#[tokio::test]
async fn a_vanished_peer_is_noticed_within_the_idle_timeout() {
    let (server, client) = transports();
    let mut l = listen(&server).await;
    let relay = Relay::start(l.local_addr().parse().unwrap(), 0, 1).await;
    let mut c = client.connect(&relay.addr.to_string()).await.unwrap();
    let mut s = timeout(BOUND, l.accept()).await.unwrap().unwrap();
    c.sender.send(frame(0, 1, 10)).unwrap();
    assert_eq!(check_payload(&timeout(BOUND, s.receiver.recv()).await.unwrap().unwrap().unwrap()), 1);
    // Keep-alives hold an idle connection open well past the idle timeout…
    let idle = options().idle_timeout;
    assert!(timeout(idle * 3, s.receiver.recv()).await.is_err(), "idle but alive connection must stay open");
    // …and when the peer vanishes without a word, both ends notice within it.
    relay.go_silent();
    let t0 = Instant::now();
    let end = timeout(idle * 4, s.receiver.recv()).await.expect("server noticed the vanished client");
    assert!(end.is_none(), "{end:?}");
    let elapsed = t0.elapsed();
    assert!(elapsed >= idle / 2 && elapsed <= idle * 3, "{elapsed:?}");
    assert!(timeout(idle * 4, c.receiver.recv()).await.expect("client noticed too").is_none());
    assert!(relay.dropped.load(std::sync::atomic::Ordering::Relaxed) > 0);
}

#[tokio::test]
async fn broken_peers_do_not_hold_up_accept() {
    let (server, client) = transports();
    let mut l = listen(&server).await;
    let addr: std::net::SocketAddr = l.local_addr().parse().unwrap();
    // Garbage datagrams.
    let junk = tokio::net::UdpSocket::bind("127.0.0.1:0").await.unwrap();
    for i in 0..20u8 {
        junk.send_to(&[i; 1200], addr).await.unwrap();
    }
    // A peer that completes TLS (right fingerprint) but never opens the control stream.
    let ep = quinn::Endpoint::client("127.0.0.1:0".parse().unwrap()).unwrap();
    let tls_cfg = tls::client_config(server.fingerprint().unwrap(), &[tls::ALPN_QUIC]).unwrap();
    let crypto = quinn::crypto::rustls::QuicClientConfig::try_from(tls_cfg).unwrap();
    let silent = ep
        .connect_with(quinn::ClientConfig::new(Arc::new(crypto)), addr, tls::SERVER_NAME)
        .unwrap()
        .await
        .unwrap();
    // A peer speaking another application protocol.
    let tls_cfg = tls::client_config(server.fingerprint().unwrap(), &[b"h3"]).unwrap();
    let crypto = quinn::crypto::rustls::QuicClientConfig::try_from(tls_cfg).unwrap();
    let other = ep.connect_with(quinn::ClientConfig::new(Arc::new(crypto)), addr, tls::SERVER_NAME).unwrap();
    assert!(timeout(BOUND, other).await.unwrap().is_err(), "ALPN mismatch must fail the handshake");
    // A peer that opens the control stream with a wrong preamble.
    let tls_cfg = tls::client_config(server.fingerprint().unwrap(), &[tls::ALPN_QUIC]).unwrap();
    let crypto = quinn::crypto::rustls::QuicClientConfig::try_from(tls_cfg).unwrap();
    let liar = ep
        .connect_with(quinn::ClientConfig::new(Arc::new(crypto)), addr, tls::SERVER_NAME)
        .unwrap()
        .await
        .unwrap();
    let (mut send, _recv) = liar.open_bi().await.unwrap();
    send.write_all(b"GET / HTTP/1.1\r\n").await.unwrap();
    assert!(timeout(BOUND, liar.closed()).await.is_ok(), "a wrong preamble closes the connection");
    // Meanwhile a proper peer is accepted promptly, long before the silent
    // one's handshake timeout (10 s) could have freed a serial accept loop.
    let t0 = Instant::now();
    let good = client.connect(&l.local_addr()).await.unwrap();
    good.sender.send(frame(0, 9, 20)).unwrap();
    let mut conn = timeout(Duration::from_secs(5), l.accept()).await.expect("accept not held up").unwrap();
    assert_eq!(check_payload(&timeout(BOUND, conn.receiver.recv()).await.unwrap().unwrap().unwrap()), 9);
    assert!(t0.elapsed() < Duration::from_secs(5));
    drop(silent);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn under_packet_loss_everything_arrives_in_a_legal_order() {
    let (server, client) = transports();
    let mut l = listen(&server).await;
    let relay = Relay::start(l.local_addr().parse().unwrap(), 30, 7).await;
    let mut c = timeout(BOUND, client.connect(&relay.addr.to_string())).await.unwrap().unwrap();
    let mut s = timeout(BOUND, l.accept()).await.unwrap().unwrap();
    c.sender.set_max_frame(1 << 20);
    s.sender.set_max_frame(1 << 20);
    let up = plan(200, 12_288);
    let down = plan(100, 30_000);
    for f in &up {
        send(&c.sender, f.clone());
    }
    for f in &down {
        send(&s.sender, f.clone());
    }
    tokio::join!(receive_checked(&mut s, &up), receive_checked(&mut c, &down));
    let dropped = relay.dropped.load(std::sync::atomic::Ordering::Relaxed);
    let forwarded = relay.forwarded.load(std::sync::atomic::Ordering::Relaxed);
    assert!(dropped > 0 && forwarded > 10 * dropped, "the relay dropped {dropped} of {forwarded} datagrams");
}

#[tokio::test]
async fn names_resolve_ipv4_first() {
    let (server, client) = transports();
    let mut l = listen(&server).await;
    let port = l.local_addr().rsplit_once(':').unwrap().1.to_string();
    let c = timeout(BOUND, client.connect(&format!("localhost:{port}"))).await.unwrap().unwrap();
    c.sender.send(frame(0, 4, 9)).unwrap();
    let mut s = timeout(BOUND, l.accept()).await.unwrap().unwrap();
    assert_eq!(check_payload(&timeout(BOUND, s.receiver.recv()).await.unwrap().unwrap().unwrap()), 4);
    let err = client.connect("no-such-host.invalid:1").await.unwrap_err();
    assert!(matches!(err, TransportError::Unresolvable { .. }), "{err:?}");
}

#[tokio::test]
async fn dropping_the_listener_refuses_newcomers_but_keeps_established_connections() {
    let (mut c, mut s, l, client) = pair(1 << 20).await;
    let addr = l.local_addr();
    drop(l);
    let err = timeout(BOUND, client.connect(&addr)).await.unwrap().unwrap_err();
    assert!(matches!(err, TransportError::Connect { .. }), "{err:?}");
    c.sender.send(frame(0, 1, 100)).unwrap();
    assert_eq!(check_payload(&timeout(BOUND, s.receiver.recv()).await.unwrap().unwrap().unwrap()), 1);
    send(&s.sender, frame(1, 2, 100));
    assert_eq!(check_payload(&timeout(BOUND, c.receiver.recv()).await.unwrap().unwrap().unwrap()), 2);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn many_clients_at_once_each_get_their_own_frames() {
    let (server, client) = transports();
    let mut l = listen(&server).await;
    let addr = l.local_addr();
    let clients: Vec<_> = (0..16u8)
        .map(|k| {
            let (client, addr) = (client.clone(), addr.clone());
            tokio::spawn(async move {
                let mut c = timeout(BOUND, client.connect(&addr)).await.unwrap().unwrap();
                c.sender.set_max_frame(1 << 20);
                // Announce who we are; once the server has raised its limit (its
                // "go"), send 40 frames and expect them echoed back in a legal order.
                c.sender.send(vec![0, k]).unwrap();
                assert_eq!(timeout(BOUND, c.receiver.recv()).await.unwrap().unwrap().unwrap(), b"go");
                let frames = plan(40, 20_000);
                for f in &frames {
                    send(&c.sender, f.clone());
                }
                receive_checked(&mut c, &frames).await;
                c.sender.close();
            })
        })
        .collect();
    let mut servers = Vec::new();
    for _ in 0..16 {
        let mut s = timeout(BOUND, l.accept()).await.unwrap().unwrap();
        s.sender.set_max_frame(1 << 20);
        servers.push(tokio::spawn(async move {
            let hello = timeout(BOUND, s.receiver.recv()).await.unwrap().unwrap().unwrap();
            assert_eq!(hello.len(), 2);
            s.sender.send(b"go".to_vec()).unwrap();
            while let Some(f) = timeout(BOUND, s.receiver.recv()).await.unwrap() {
                send(&s.sender, f.unwrap());
            }
            hello[1]
        }));
    }
    for c in clients {
        timeout(BOUND, c).await.unwrap().unwrap();
    }
    let mut seen = HashSet::new();
    for s in servers {
        assert!(seen.insert(timeout(BOUND, s).await.unwrap().unwrap()));
    }
    assert_eq!(seen.len(), 16);
    assert_eq!(server.wire_stats().connections, 16);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_restarted_listener_with_the_same_identity_resets_its_predecessors_connections_at_once() {
    let id = Identity::generate().unwrap();
    // An idle timeout far longer than the keep-alive: ending within a few
    // keep-alives can only be the new listener's stateless reset.
    let opts = QuicOptions {
        keep_alive: Duration::from_millis(100),
        idle_timeout: Duration::from_secs(10),
        ..QuicOptions::default()
    };
    let server = QuicTransport::server(&id).unwrap().with_options(opts.clone());
    let client = QuicTransport::client(id.fingerprint()).unwrap().with_options(opts);
    // The first listener on a runtime of its own, which stops running once
    // it accepted and is then dropped without a word to the peer: a master
    // killed with -9.
    // (A transport of its own: a transport's counters hold its connections.)
    let first = QuicTransport::server(&id).unwrap().with_options(server.options().clone());
    let (addr_tx, addr_rx) = std::sync::mpsc::channel();
    let (stop_tx, stop_rx) = std::sync::mpsc::channel();
    let gone = std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
        let held = rt.block_on(async {
            let mut l = first.listen("127.0.0.1:0").await.unwrap();
            addr_tx.send(l.local_addr()).unwrap();
            timeout(BOUND, l.accept()).await.unwrap().map(|s| (l, s))
        });
        stop_rx.recv().unwrap();
        drop(held);
        rt.shutdown_background();
    });
    let addr: String = addr_rx.recv().unwrap();
    let mut c = timeout(BOUND, client.connect(&addr)).await.unwrap().unwrap();
    stop_tx.send(()).unwrap();
    gone.join().unwrap();
    // The new listener, same identity, same port.
    let _again = server.listen(&addr).await.unwrap();
    let t0 = Instant::now();
    let end = timeout(Duration::from_secs(5), c.receiver.recv()).await.expect("the connection stayed open");
    assert!(end.is_none() || end.as_ref().is_some_and(|e| e.is_err()), "{end:?}");
    assert!(t0.elapsed() < Duration::from_secs(2), "reset after {:?}", t0.elapsed());
}

#[test]
fn the_stateless_reset_key_follows_the_identity() {
    use quinn::crypto::HmacKey;
    let (a, b) = (Identity::generate().unwrap(), Identity::generate().unwrap());
    let sign = |id: &Identity, data: &[u8]| {
        let mut out = [0u8; 32];
        isin_transport_quic::reset_key(id).sign(data, &mut out);
        out
    };
    assert_eq!(sign(&a, b"cid"), sign(&a, b"cid"), "a restarted master makes the same tokens");
    assert_ne!(sign(&a, b"cid"), sign(&b, b"cid"));
    assert_ne!(sign(&a, b"cid"), sign(&a, b"other cid"));
    let key = isin_transport_quic::reset_key(&a);
    assert_eq!(key.signature_len(), 32);
    assert!(key.verify(b"cid", &sign(&a, b"cid")).is_ok());
    assert!(key.verify(b"cid", &sign(&b, b"cid")).is_err());
}

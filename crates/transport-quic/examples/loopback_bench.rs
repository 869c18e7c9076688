//! Loopback micro-benchmark: 12 KB tiles (the size of a 64×64 RGB8
//! `TileResult` frame, sent [independent](Delivery::Independent)) from a
//! "slave" to a "master" over QUIC, TLS over TCP and plaintext TCP, both ends
//! in this process. The master answers each tile with a small ordered frame as
//! an acknowledgement (a `Heartbeat`'s size); the slave keeps `WINDOW` tiles in
//! flight.
//!
//! Prints tiles/s, process CPU time per tile (both ends together: user +
//! system), the tile round-trip p50/p99, the interface's byte count per tile
//! and, for QUIC, the UDP bytes quinn sent per tile (slave side).
//!
//! With `LOSS` (per mille) above 0, the QUIC runs go through an in-process
//! UDP relay that drops that share of datagrams each way (TCP cannot, and is
//! left out): a stream per tile against all tiles on one stream shows what
//! head-of-line blocking costs.
//!
//! ```text
//! cargo run --release -p isin-transport-quic --example loopback_bench [-- TILES WINDOW LOSS]
//! ```

#[path = "../tests/relay/mod.rs"]
mod relay;

use isin_transport::{Connection, Delivery, Transport};
use isin_transport_quic::tls::Identity;
use isin_transport_quic::{QuicOptions, QuicTransport};
use isin_transport_tcp::TcpTransport;
use std::collections::VecDeque;
use std::time::{Duration, Instant};

fn cpu_time() -> Duration {
    // SAFETY: getrusage only writes the struct we hand it.
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) };
    let tv = |t: libc::timeval| Duration::new(t.tv_sec as u64, t.tv_usec as u32 * 1000);
    tv(u.ru_utime) + tv(u.ru_stime)
}

/// Largest frame either end accepts.
const MAX_FRAME: usize = 1 << 20;
/// Bytes of an encoded `TileResult` around its pixels.
const TILE_HEADER: usize = 32;

/// A tile-sized frame: 64×64 RGB8 pixels and a message header's worth of bytes.
fn tile(id: u32) -> Vec<u8> {
    (0..TILE_HEADER + 64 * 64 * 3).map(|i| (i as u32 ^ id) as u8).collect()
}

/// A one-stream QUIC transport: every frame ordered, on the control stream.
fn single_stream(t: &QuicTransport) -> QuicTransport {
    t.clone().with_options(QuicOptions { single_stream: true, ..t.options().clone() })
}

struct Outcome {
    tiles_per_s: f64,
    cpu_us_per_tile: f64,
    p50_ms: f64,
    p99_ms: f64,
    max_ms: f64,
    wire_bytes_per_tile: f64,
}

async fn run(
    server: &dyn Transport,
    client: &dyn Transport,
    tiles: u32,
    window: usize,
    loss: u64,
) -> Outcome {
    let mut listener = server.listen("127.0.0.1:0").await.expect("listen");
    let mut addr = listener.local_addr();
    let _relay = if loss > 0 {
        let r = relay::Relay::start(addr.parse().expect("address"), loss, 0x5eed).await;
        addr = r.addr.to_string();
        Some(r)
    } else {
        None
    };
    let slave = client.connect(&addr).await.expect("connect");
    let master = listener.accept().await.expect("accept");
    let echo = tokio::spawn(echo(master));
    let o = drive(slave, tiles, window).await;
    let _ = echo.await;
    o
}

/// The master's side: answers every tile with a small ordered frame.
async fn echo(mut master: Connection) {
    master.sender.set_max_frame(MAX_FRAME);
    let ack = vec![0u8; 4];
    while let Some(Ok(_)) = master.receiver.recv().await {
        if master.sender.send(ack.clone()).is_err() {
            break;
        }
    }
}

/// The slave's side: `tiles` tiles, `window` in flight.
async fn drive(mut slave: Connection, tiles: u32, window: usize) -> Outcome {
    slave.sender.set_max_frame(MAX_FRAME);
    let frames: Vec<Vec<u8>> = (0..tiles).map(tile).collect();
    let (t0, c0) = (Instant::now(), cpu_time());
    let mut sent_at = VecDeque::with_capacity(window);
    let mut rtts = Vec::with_capacity(tiles as usize);
    let mut next = 0usize;
    while rtts.len() < tiles as usize {
        while next < frames.len() && sent_at.len() < window {
            slave.sender.send_as(frames[next].clone(), Delivery::Independent).expect("send");
            sent_at.push_back(Instant::now());
            next += 1;
        }
        slave.receiver.recv().await.expect("open").expect("ack");
        // Acks are not matched to tiles (tiles may overtake each other): the
        // oldest outstanding send is the fair reference.
        rtts.push(sent_at.pop_front().expect("outstanding").elapsed());
    }
    let (wall, cpu) = (t0.elapsed(), cpu_time() - c0);
    let wire = slave.sender.stats().bytes_sent as f64 / tiles as f64;
    slave.sender.close();
    rtts.sort();
    let q = |p: f64| rtts[((rtts.len() - 1) as f64 * p) as usize].as_secs_f64() * 1e3;
    Outcome {
        tiles_per_s: tiles as f64 / wall.as_secs_f64(),
        cpu_us_per_tile: cpu.as_secs_f64() * 1e6 / tiles as f64,
        p50_ms: q(0.5),
        p99_ms: q(0.99),
        max_ms: q(1.0),
        wire_bytes_per_tile: wire,
    }
}

/// Two-process mode, e.g. across network namespaces:
/// `serve ADDR tcp|tcp-insecure|quic` prints the certificate fingerprint and echoes every
/// connection; `send ADDR tcp|tcp-insecure|quic|quic1 FINGERPRINT TILES WINDOW` prints one
/// table row (`quic1`: every frame on one stream; `tcp` is TLS).
fn two_process(args: &[String]) -> bool {
    let rt =
        || tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().expect("rt");
    match args {
        [mode, addr, kind] if mode == "serve" => {
            let id = Identity::generate().expect("identity");
            let t: Box<dyn Transport> = match kind.as_str() {
                "tcp" => Box::new(TcpTransport::server(&id).expect("server")),
                "tcp-insecure" => Box::new(TcpTransport::insecure()),
                _ => Box::new(QuicTransport::server(&id).expect("server")),
            };
            println!("fp={}", id.fingerprint());
            rt().block_on(async {
                let mut l = t.listen(addr).await.expect("listen");
                println!("listening {}", l.local_addr());
                while let Ok(c) = l.accept().await {
                    tokio::spawn(echo(c));
                }
            });
            true
        }
        [mode, addr, kind, fp, tiles, window] if mode == "send" => {
            let fp = fp.parse().expect("fingerprint");
            let t: Box<dyn Transport> = match kind.as_str() {
                "tcp" => Box::new(TcpTransport::client(fp).expect("client")),
                "tcp-insecure" => Box::new(TcpTransport::insecure()),
                "quic1" => Box::new(single_stream(&QuicTransport::client(fp).expect("client"))),
                _ => Box::new(QuicTransport::client(fp).expect("client")),
            };
            let (tiles, window) = (tiles.parse().expect("tiles"), window.parse().expect("window"));
            let o =
                rt().block_on(async { drive(t.connect(addr).await.expect("connect"), tiles, window).await });
            println!(
                "| {kind} | {:.0} | {:.1} | {:.3} | {:.3} | {:.1} | {:.0} |",
                o.tiles_per_s, o.cpu_us_per_tile, o.p50_ms, o.p99_ms, o.max_ms, o.wire_bytes_per_tile
            );
            true
        }
        _ => false,
    }
}

fn main() {
    let all: Vec<String> = std::env::args().skip(1).collect();
    if two_process(&all) {
        return;
    }
    let mut args = all.into_iter();
    let tiles: u32 = args.next().and_then(|a| a.parse().ok()).unwrap_or(20_000);
    let window: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(16);
    let loss: u64 = args.next().and_then(|a| a.parse().ok()).unwrap_or(0);
    let rt =
        tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().expect("runtime");
    rt.block_on(async {
        let id = Identity::generate().expect("identity");
        let quic_server = QuicTransport::server(&id).expect("server");
        let quic_client = QuicTransport::client(id.fingerprint()).expect("client");
        let tcp = TcpTransport::both(&id, id.fingerprint()).expect("TLS over TCP");
        let plain = TcpTransport::insecure();
        // Same, but every frame on the control stream: the cost of a stream per tile.
        let (one_server, one_client) = (single_stream(&quic_server), single_stream(&quic_client));
        println!(
            "{tiles} tiles of {} bytes, {window} in flight, loopback, one process, {:.1} % loss",
            tile(0).len(),
            loss as f64 / 10.0
        );
        println!(
            "| transport | tiles/s | CPU µs/tile (both ends) | RTT p50 ms | RTT p99 ms | max ms | interface bytes/tile | UDP bytes/tile |"
        );
        println!("|---|---|---|---|---|---|---|---|");
        // Warm up both, then measure.
        run(&tcp, &tcp, 500, window, 0).await;
        run(&plain, &plain, 500, window, 0).await;
        run(&quic_server, &quic_client, 500, window, 0).await;
        for (name, s, c) in [
            ("TCP (TLS)", &tcp as &dyn Transport, &tcp as &dyn Transport),
            ("TCP (plaintext)", &plain, &plain),
            ("QUIC", &quic_server, &quic_client),
            ("QUIC, one stream", &one_server, &one_client),
        ] {
            if loss > 0 && name.starts_with("TCP") {
                continue;
            }
            let udp0 = quic_client.wire_stats().udp_tx_bytes;
            let o = run(s, c, tiles, window, if name.starts_with("TCP") { 0 } else { loss }).await;
            let udp = match name {
                "QUIC" | "QUIC, one stream" => format!("{:.0}", (quic_client.wire_stats().udp_tx_bytes - udp0) as f64 / tiles as f64),
                _ => "–".to_string(),
            };
            println!(
                "| {name} | {:.0} | {:.1} | {:.3} | {:.3} | {:.1} | {:.0} | {udp} |",
                o.tiles_per_s, o.cpu_us_per_tile, o.p50_ms, o.p99_ms, o.max_ms, o.wire_bytes_per_tile
            );
        }
    });
}

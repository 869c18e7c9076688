//! Hostile peers that know the token: real peers on real sockets, speaking
//! the real protocol and lying in it, against a real `isin master`.
//!
//! - `a_slave_stalled_after_login…`: logs in, takes the scene, never says
//!   `Ready` nor anything else; dropped within the heartbeat timeout.
//! - `a_slave_returning_tiles_it_was_never_handed…`: answers its assignment
//!   with white results for every other tile of the frame; refused, and the
//!   frame is byte-identical to `isin render`.
//! - `logged_in_viewers_cannot_pin_the_masters_memory`: viewers that each
//!   announce a 64 MiB frame are closed before the master reads it; its RSS
//!   stays where it was.

use super::SMALL;
use super::util::{Cluster, Stream, Transport, assert_same_pixels, client_transport, render_local};
use isin_actors::client::{self, JoinError};
use isin_cluster::auth;
use isin_cluster::codec::Codec;
use isin_cluster::protocol::{self, DEFAULT_MAX_FRAME, Hello, Message, Role, TileResult};
use isin_tracer::Tile;
use isin_transport::{Connection, Ticket};
use std::collections::BTreeSet;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

const TIMEOUT: Duration = Duration::from_secs(30);

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread().enable_all().build().expect("runtime")
}

/// Logs in to `c`'s master as a slave and receives the scene.
async fn login_slave(c: &Cluster, name: &str) -> (Connection, protocol::Welcome) {
    let ticket: Ticket = c.ticket.parse().expect("ticket");
    let t = client_transport(c);
    let (mut conn, welcome) =
        client::handshake(t.as_ref(), &ticket, client::Join::slave(name, 1, &[], &[])).await.expect("login");
    let hash = welcome.scene.as_ref().expect("a default scene").hash;
    isin_actors::slave::receive_scene(&mut conn, hash).await.expect("the scene");
    (conn, welcome)
}

/// The reason of the master's `Reject`, after which the connection ends.
async fn rejection(conn: &mut Connection, mut on: impl FnMut(&Connection, Message)) -> String {
    loop {
        match client::recv_message(conn, DEFAULT_MAX_FRAME, TIMEOUT).await {
            Ok(Message::Reject { reason }) => {
                let end = client::recv_message(conn, DEFAULT_MAX_FRAME, TIMEOUT).await;
                assert!(matches!(end, Err(JoinError::Closed | JoinError::Transport(_))), "{end:?}");
                return reason;
            }
            Ok(m) => on(conn, m),
            Err(e) => panic!("the connection ended without a reason: {e}"),
        }
    }
}

cluster_test!(
    a_slave_stalled_after_login_is_dropped_within_its_deadline,
    |t: Transport| {
        let c = Cluster::start(t, 0, &["--heartbeat-timeout-ms", "1000"]);
        let (reason, took) = runtime().block_on(async {
            let (mut conn, _) = login_slave(&c, "stalled").await;
            let t0 = Instant::now();
            // Heartbeats from the master arrive; it never hears back.
            (rejection(&mut conn, |_, _| {}).await, t0.elapsed())
        });
        assert!(reason.contains("silent"), "{reason}");
        // The deadline is one second from login; the master looks every 50 ms.
        assert!(took < Duration::from_secs(3), "dropped after {took:?}");
        c.master.wait_for(Stream::Err, "refused stalled");
    },
    insecure
);

/// Answers its first assignment with white results for every tile of the
/// frame it was not handed; returns why the master refused it.
async fn forge(c: &Cluster) -> String {
    let (mut conn, welcome) = login_slave(c, "forger").await;
    client::send_message(&conn, &Message::Ready { hash: welcome.scene.map(|s| s.hash) }).expect("ready");
    let mut forged = false;
    rejection(&mut conn, |conn, m| {
        let Message::TileAssignment(a) = m else { return };
        if std::mem::replace(&mut forged, true) {
            return;
        }
        let mine: BTreeSet<u32> = a.tiles.iter().map(|j| j.id).collect();
        let edge = a.tiles.iter().map(|j| j.tile.w.max(j.tile.h)).max().unwrap_or(32);
        for (id, tile) in Tile::grid(a.settings.width, a.settings.height, edge).into_iter().enumerate() {
            let id = id as u32;
            if mine.contains(&id) {
                continue;
            }
            let pixels = vec![255u8; tile.pixel_count() * 3].into();
            let r = TileResult { frame: a.frame, id, tile, render_micros: 1, codec: Codec::Raw, pixels };
            let _ = client::send_message(conn, &Message::TileResult(r));
        }
    })
    .await
}

cluster_test!(a_slave_returning_tiles_it_was_never_handed_is_refused_and_the_frame_stays_identical, |t| {
    let c = Cluster::start(t, 2, &[]);
    std::thread::scope(|s| {
        let forger = s.spawn(|| runtime().block_on(forge(&c)));
        c.wait_joined(3);
        let (cluster, _) = c.render("frame.png", SMALL);
        assert_same_pixels(&cluster, &render_local(SMALL), "cluster frame with a forger vs isin render");
        let reason = forger.join().expect("the forger thread");
        assert!(reason.contains("never handed"), "{reason}");
    });
    c.master.wait_for(Stream::Err, "refused a result for a tile forger");
});

/// Reads one plaintext-TCP frame and decodes it.
fn read_message(s: &mut TcpStream) -> Message {
    let mut len = [0u8; 4];
    s.read_exact(&mut len).expect("a frame length");
    let mut body = vec![0u8; u32::from_be_bytes(len) as usize];
    s.read_exact(&mut body).expect("a frame body");
    protocol::decode(&body, usize::MAX).expect("a message")
}

fn write_message(s: &mut TcpStream, m: &Message) {
    let body = protocol::encode(m).expect("encodes");
    s.write_all(&(body.len() as u32).to_be_bytes()).expect("write");
    s.write_all(&body).expect("write");
}

/// The master's resident memory, in KiB.
fn rss_kib(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).expect("/proc status");
    let line = status.lines().find(|l| l.starts_with("VmRSS:")).expect("VmRSS");
    line.split_whitespace().nth(1).and_then(|n| n.parse().ok()).expect("a number")
}

#[test]
fn logged_in_viewers_cannot_pin_the_masters_memory() {
    const VIEWERS: usize = 32;
    const ANNOUNCED: u32 = 64 << 20;
    const SENT: usize = 1 << 20;
    let c = Cluster::start(Transport::TcpInsecure, 0, &[]);
    let token = c.ticket.parse::<Ticket>().expect("ticket").token;
    let before = rss_kib(c.master.pid());
    let mut viewers = Vec::new();
    for i in 0..VIEWERS {
        let mut s = TcpStream::connect(&c.addr).expect("connect");
        s.set_read_timeout(Some(TIMEOUT)).expect("timeout");
        let Message::Challenge { nonce } = read_message(&mut s) else { panic!("no challenge") };
        let client_nonce = [i as u8; 32];
        let proof = auth::client_proof(&token, Role::Viewer, &nonce, &client_nonce);
        let name = format!("hog{i}");
        let hello = Hello {
            role: Role::Viewer,
            name,
            threads: 0,
            client_nonce,
            proof,
            cached_scenes: vec![],
            codecs: vec![],
            work: Default::default(),
            direct: None,
        };
        write_message(&mut s, &Message::Hello(hello));
        assert!(matches!(read_message(&mut s), Message::Welcome(_)), "viewer {i} not welcomed");
        // A frame of 64 MiB announced, and a mebibyte of it sent. The master
        // may close before taking it all: a failed write is what we want.
        let _ = s.write_all(&ANNOUNCED.to_be_bytes());
        let _ = s.write_all(&vec![0x42; SENT]);
        viewers.push(s);
    }
    // Every byte written is with the master now (or was refused): what it holds.
    let during = rss_kib(c.master.pid());
    for (i, s) in viewers.iter_mut().enumerate() {
        let mut rest = Vec::new();
        match s.read_to_end(&mut rest) {
            Ok(_) => {}
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => {}
            Err(e) => panic!("viewer {i} was not closed: {e}"),
        }
    }
    println!(
        "master RSS {before} KiB before, {during} KiB while {VIEWERS} logged-in viewers each announced a \
         {} MiB frame and sent {} MiB of it",
        ANNOUNCED >> 20,
        SENT >> 20
    );
    assert!(during < before + 8 * 1024, "RSS grew from {before} to {during} KiB");
    // Every one of them refused (the master's last log lines may still be on their way).
    c.master.wait_for_n(Stream::Err, "refused hog", VIEWERS);
}

//! End-to-end tests of the cluster: real `isin master`, `isin slave` and
//! `isin render --connect` processes on loopback sockets.
//!
//! Each test body takes the transport it runs over; `cluster_test!` expands
//! it once per transport, so the same assertions hold for TLS over TCP and
//! QUIC (and, for the tests marked `insecure`, plaintext TCP too). Nothing
//! waits on sleeps: tests wait for lines the processes print (the ticket,
//! "joined", "dead", …) with a timeout.
//!
//! Contents:
//! - `identical`: a frame through master + 3 slaves equals `isin render`.
//! - `fly_through_the_cluster…`: `fly --connect --frames 10..16` writes the frames `fly` writes here.
//! - `another_aspect…`: `--width`/`--height` of another shape give the local render's pixels.
//! - `kill_mid_frame`: `kill -9` of a slave holding tiles; the frame completes, identical.
//! - `hot_join`: a 4th slave joining mid-session receives tiles.
//! - `hot_join_mid_frame`: a slave joining while a frame is open takes part in that frame.
//! - `embedded_default…`: `isin` with no arguments renders through its in-process cluster,
//!   identical to `isin render`.
//! - `wrong_token`: refused with a clear message; no scene data reaches the intruder.
//! - `garbage`: garbage bytes and an oversized length prefix; the master keeps rendering.
//! - `slave_waits_for_master`: a slave started before its master joins once it is up.
//! - `silent_slave_times_out_and_rejoins_with_cached_scene`: SIGSTOP → declared dead by
//!   timeout, frame still identical; SIGCONT → reconnects without being sent the scene again.
//! - `a_rejoining_slave_is_sent_no_scene_bytes…`: `isin status` counts the compressed scene
//!   once per new slave and nothing for a slave that rejoins holding it.
//! - `every_codec_is_byte_identical`: `--compression raw|lz4|qoi` (and `auto`, in
//!   `identical`) all deliver frames equal to `isin render`; slaves report the codec picked.
//! - `wrong_fingerprint`: a slave whose ticket pins another certificate gives up at once with
//!   both fingerprints named; the master never sees it authenticate.
//! - `tls_ticket_never_falls_back_to_plaintext`: a TLS ticket aimed at a plaintext master fails.
//! - [`hostile`]: peers that know the token and lie in the protocol.
//! - [`clients`]: several viewers on one cluster at once.
//! - [`jobs`]: scenes clients bring, and a flight surviving `kill -9` of its master.
//! - [`contrib`]: the systemd unit's slave command joins a master.
//! - [`logs`]: what the default log level says, and what it leaves to DEBUG.
//! - [`secrets`]: tickets read from a file or the environment, never the command line.
//! - [`paths`]: keyframed camera paths flown through a cluster.

mod util;

use util::{Cluster, Proc, Stream, Transport, assert_same_pixels, render_local};

/// Runs `$body(transport)` as one `#[test]` per transport (TLS over TCP and
/// QUIC; with `insecure` after the body, plaintext TCP as well).
macro_rules! cluster_test {
    ($(#[$meta:meta])* $name:ident, $body:expr) => {
        cluster_test!(@mod $(#[$meta])* $name, $body, {});
    };
    ($(#[$meta:meta])* $name:ident, $body:expr, insecure) => {
        cluster_test!(@mod $(#[$meta])* $name, $body, {
            $(#[$meta])*
            #[test]
            fn tcp_insecure() {
                ($body)(Transport::TcpInsecure)
            }
        });
    };
    (@mod $(#[$meta:meta])* $name:ident, $body:expr, {$($extra:tt)*}) => {
        mod $name {
            #[allow(unused_imports)]
            use super::*;
            $(#[$meta])*
            #[test]
            fn tcp() {
                ($body)(Transport::Tcp)
            }
            $(#[$meta])*
            #[test]
            fn quic() {
                ($body)(Transport::Quic)
            }
            $($extra)*
        }
    };
}

mod clients;
mod contrib;
mod hostile;
mod jobs;
mod logs;
mod paths;
mod secrets;

const SMALL: &[&str] = &["--width", "160", "--height", "120"];
/// Long enough (≈ 0.5 s on 2 cores) that a frame is surely in flight when a
/// test acts on it.
const SLOW: &[&str] = &["--width", "320", "--height", "240", "--spp", "2"];

cluster_test!(fly_through_the_cluster_equals_fly_here_frame_for_frame, |t| {
    let c = Cluster::start(t, 2, &[]);
    let (scene, path) = (util::scene(), util::root().join("scenes/paths/paper.toml"));
    let fly = |out: &std::path::Path, cluster: Option<&str>| {
        let mut args = vec!["fly", scene.to_str().unwrap(), "--path", path.to_str().unwrap()];
        args.extend([
            "--out-dir",
            out.to_str().unwrap(),
            "--width",
            "160",
            "--height",
            "120",
            "--frames",
            "10..16",
        ]);
        args.extend(cluster.map(|t| ["--connect", t]).into_iter().flatten());
        let mut p = Proc::spawn("fly", &args, "warn");
        assert!(p.wait_exit().success(), "fly failed\n{}", p.dump());
    };
    let (here, there) = (c.dir.path().join("here"), c.dir.path().join("there"));
    fly(&here, None);
    fly(&there, Some(&c.ticket));
    for i in 10..16 {
        let name = format!("frame_{i:04}.png");
        let (a, b) = (util::pixels(&here.join(&name)), util::pixels(&there.join(&name)));
        assert_same_pixels(&b, &a, &format!("{name}: cluster vs here"));
    }
    let written = std::fs::read_dir(&there).unwrap().count();
    assert_eq!(written, 6, "frames 10..16 and no others");
});

cluster_test!(another_aspect_is_widened_as_locally_not_stretched, |t| {
    let c = Cluster::start(t, 2, &[]);
    for size in [&["--width", "200", "--height", "100"][..], &["--width", "90"]] {
        let (cluster, _) = c.render("wide.png", size);
        assert_same_pixels(&cluster, &render_local(size), &format!("cluster vs isin render at {size:?}"));
    }
});

cluster_test!(
    identical,
    |t: Transport| {
        let c = Cluster::start(t, 3, &[]);
        let (cluster, stdout) = c.render("frame.png", SMALL);
        assert_same_pixels(&cluster, &render_local(SMALL), "cluster frame vs isin render");
        // Work really was spread: at least two slaves delivered tiles.
        let line = stdout.lines().find(|l| l.starts_with("tiles")).expect("tiles line");
        assert!(line.matches('#').count() >= 2, "{line}");
    },
    insecure
);

cluster_test!(
    tiles_straight_from_the_slaves_are_the_same_pixels,
    |t: Transport| {
        let c = Cluster::start(t, 2, &[]);
        let direct: Vec<&str> = SLOW.iter().copied().chain(["--direct", "127.0.0.1:0"]).collect();
        let (cluster, stdout) = c.render("direct.png", &direct);
        assert_same_pixels(&cluster, &render_local(SLOW), "tiles straight from the slaves vs isin render");
        let line = stdout.lines().find(|l| l.starts_with("direct")).expect("direct line");
        let n: u32 = line.split_whitespace().nth(1).and_then(|n| n.parse().ok()).expect("a count");
        assert!(n > 0, "no tile went straight to the viewer: {line}");
    },
    insecure
);

cluster_test!(kill_mid_frame, |t: Transport| {
    // No straggler copies: the killed slave's tiles can only come back through
    // reassignment once it is declared dead (at once over TCP, whose socket
    // closes; after the idle timeout over QUIC, whose UDP peer just goes quiet).
    let mut c = Cluster::start(t, 3, &["--no-duplicates"]);
    let (mut render, out) = c.render_async("frame.png", SLOW);
    // The master hands every slave its window as soon as the frame arrives.
    c.master.wait_for(Stream::Err, "frame requested");
    c.slaves[1].kill9();
    c.master.wait_for(Stream::Err, "dead (Disconnected)");
    assert!(render.wait_exit().success(), "{}\n{}", render.dump(), c.master.dump());
    let dead = c.master.wait_for(Stream::Err, "dead (Disconnected)");
    assert!(!dead.contains("; 0 tiles requeued"), "the killed slave held tiles: {dead}");
    c.master.wait_for(Stream::Err, "reassigned");
    assert_same_pixels(&util::pixels(&out), &render_local(SLOW), "frame after a slave's kill");
});

cluster_test!(hot_join, |t: Transport| {
    let mut c = Cluster::start(t, 3, &[]);
    c.render("before.png", SMALL);
    c.add_slave("late");
    c.wait_joined(4);
    let (pixels, stdout) = c.render("after.png", SLOW);
    let line = stdout.lines().find(|l| l.starts_with("tiles")).expect("tiles line").to_string();
    let late = line.split(['(', ',', ')']).map(str::trim).find(|s| s.starts_with("late#"));
    let n: u32 = late.and_then(|s| s.split(": ").nth(1)).and_then(|n| n.parse().ok()).unwrap_or(0);
    assert!(n > 0, "the late slave rendered no tile: {line}");
    assert_same_pixels(&pixels, &render_local(SLOW), "frame with the late slave");
});

cluster_test!(wrong_token, |t: Transport| {
    let c = Cluster::start(t, 1, &[]);
    let wrong = c.ticket_with_token("not-the-token");
    // A viewer…
    let (mut p, out) = {
        let scene = util::scene();
        let o = c.dir.path().join("intruder.png");
        let args = ["render", scene.to_str().unwrap(), "--connect", &wrong, "-o", o.to_str().unwrap()];
        (Proc::spawn("intruder render", &args, "info"), o)
    };
    assert!(!p.wait_exit().success());
    p.wait_for(Stream::Err, "wrong token");
    assert!(!out.exists());
    // …and a slave are refused, and the slave gives up instead of retrying.
    let mut s = Proc::spawn("intruder slave", &["slave", "--connect", &wrong, "--threads", "1"], "debug");
    assert!(!s.wait_exit().success());
    s.wait_for(Stream::Err, "wrong token");
    assert!(
        s.matching(Stream::Err, |l| l.contains("loaded scene") || l.contains("joined")).is_empty(),
        "{}",
        s.dump()
    );
    c.master.wait_for_n(Stream::Err, "wrong token", 2);
    assert!(
        c.master.matching(Stream::Err, |l| l.contains("sending scene")).len() == 1,
        "only the real slave got the scene"
    );
    // The cluster still works.
    c.render("ok.png", SMALL);
});

cluster_test!(
    garbage,
    |t: Transport| {
        let c = Cluster::start(t, 2, &[]);
        // Random bytes.
        let junk: Vec<u8> = (0..4096u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8).collect();
        util::RawPeer::connect(&c).send_then_expect_close(&junk);
        // A frame far beyond the pre-authentication limit.
        util::RawPeer::connect(&c).send_oversized_then_expect_close();
        // A well-framed message that is not a message.
        util::RawPeer::connect(&c).send_frame_then_expect_close(&[0, 1, 0xc1, 0xc1, 0xc1, 0xc1, 0xc1, 0xc1]);
        c.master.wait_for_n(Stream::Err, "bad frame", 3);
        // A peer that connects and says nothing does not block anyone either.
        let _idle = util::RawPeer::connect(&c);
        let (pixels, _) = c.render("after-garbage.png", SMALL);
        assert_same_pixels(&pixels, &render_local(SMALL), "frame after garbage");
    },
    insecure
);

cluster_test!(slave_waits_for_master, |t: Transport| {
    // Start the slave before the master exists.
    let addr = t.free_addr();
    let identity = tempfile::tempdir().expect("temp dir");
    let (identity_args, ticket) = t.prepared_ticket(identity.path(), "tok", &addr);
    let slave = Proc::spawn("early slave", &["slave", "--connect", &ticket, "--threads", "1"], "info");
    slave.wait_for(Stream::Err, "retrying");
    let scene = util::scene();
    let mut args = vec!["master", scene.to_str().unwrap(), "--listen", &addr, "--token", "tok"];
    args.extend(t.master_args());
    args.extend(identity_args.iter().map(String::as_str));
    let master = Proc::spawn("master", &args, "info");
    master.wait_for(Stream::Out, "ticket ");
    slave.wait_for(Stream::Err, "joined master");
    master.wait_for(Stream::Err, "joined with");
});

cluster_test!(silent_slave_times_out_and_rejoins_with_cached_scene, |t: Transport| {
    // A slave frozen with SIGSTOP keeps its socket open but says nothing: only
    // the heartbeat timeout can find it out.
    let c = Cluster::start(t, 2, &["--heartbeat-timeout-ms", "1000"]);
    let (mut render, out) = c.render_async("frame.png", SLOW);
    c.master.wait_for(Stream::Err, "frame requested");
    let pid = c.slaves[0].pid() as libc::pid_t;
    // SAFETY: signalling a child process this test started.
    assert_eq!(unsafe { libc::kill(pid, libc::SIGSTOP) }, 0);
    c.master.wait_for(Stream::Err, "dead (Timeout)");
    assert!(render.wait_exit().success(), "{}\n{}", render.dump(), c.master.dump());
    assert_same_pixels(&util::pixels(&out), &render_local(SLOW), "frame with a frozen slave");
    // Thawed, it finds its connection closed, reconnects, and is not sent the
    // scene again.
    // SAFETY: as above.
    assert_eq!(unsafe { libc::kill(pid, libc::SIGCONT) }, 0);
    c.slaves[0].wait_for_n(Stream::Err, "joined master", 2);
    c.master.wait_for(Stream::Err, "(scene cached)");
    c.wait_joined(3);
    assert_eq!(c.slaves[0].matching(Stream::Err, |l| l.contains("loaded scene")).len(), 1);
    c.render("after.png", SMALL);
});

/// What `isin status` says the master has sent of scenes, in bytes.
fn scene_bytes_sent(c: &Cluster) -> u64 {
    let mut p = Proc::spawn("status", &["status", &c.ticket], "warn");
    assert!(p.wait_exit().success(), "{}", p.dump());
    let line = p.wait_for(Stream::Out, "scene bytes sent");
    line.split_whitespace().next().and_then(|n| n.parse().ok()).unwrap_or_else(|| panic!("{line}"))
}

cluster_test!(a_rejoining_slave_is_sent_no_scene_bytes_and_a_new_one_the_compressed_scene, |t: Transport| {
    let mut c = Cluster::start(t, 1, &["--heartbeat-timeout-ms", "1000"]);
    // The first slave got the scene compressed: what it received is what
    // the master counts (its frames: a few bytes of framing per chunk more).
    let one = scene_bytes_sent(&c);
    let line = c.slaves[0].wait_for(Stream::Err, "received: ");
    let number = |after: &str| -> u64 {
        let rest = &line[line.find(after).unwrap_or_else(|| panic!("{line}")) + after.len()..];
        rest.split_whitespace().next().and_then(|n| n.parse().ok()).unwrap_or_else(|| panic!("{line}"))
    };
    let compressed = number("received: ");
    let raw = number("compressed, ");
    assert!(compressed < raw, "{line}");
    assert!(one >= compressed && one < compressed + 4096, "{one} bytes sent; {line}");
    // A new slave gets it again.
    c.add_slave("s1");
    c.wait_joined(2);
    assert_eq!(scene_bytes_sent(&c), 2 * one);
    // The first, frozen until the master declares it dead and thawed, rejoins
    // holding the scene: not a byte of it is sent.
    let pid = c.slaves[0].pid() as libc::pid_t;
    // SAFETY: signalling a child process this test started.
    assert_eq!(unsafe { libc::kill(pid, libc::SIGSTOP) }, 0);
    c.master.wait_for(Stream::Err, "dead (Timeout)");
    // SAFETY: as above.
    assert_eq!(unsafe { libc::kill(pid, libc::SIGCONT) }, 0);
    c.slaves[0].wait_for_n(Stream::Err, "joined master", 2);
    c.wait_joined(3);
    assert_eq!(scene_bytes_sent(&c), 2 * one);
    assert_eq!(c.slaves[0].matching(Stream::Err, |l| l.contains("received: ")).len(), 1);
    c.render("after.png", SMALL);
});

cluster_test!(hot_join_mid_frame, |t: Transport| {
    // A frame of ≈ 2 CPU seconds: the newcomer joins while it is being rendered
    // and takes part in it.
    const BIG: &[&str] = &["--width", "640", "--height", "480", "--spp", "2"];
    let mut c = Cluster::start(t, 1, &[]);
    let (mut render, out) = c.render_async("frame.png", BIG);
    c.master.wait_for(Stream::Err, "frame requested");
    c.add_slave("newcomer");
    c.wait_joined(2);
    assert!(render.wait_exit().success(), "{}\n{}", render.dump(), c.master.dump());
    let line = render.wait_for(Stream::Out, "tiles ");
    assert!(line.contains("newcomer#"), "the newcomer rendered no tile of the open frame: {line}");
    assert_same_pixels(&util::pixels(&out), &render_local(BIG), "frame finished with a newcomer");
});

#[test]
fn embedded_default_renders_the_paper_scene_through_its_own_cluster() {
    // `isin` with no arguments: master + local slaves in one process.
    let dir = tempfile::tempdir().unwrap();
    let mut p = Proc::spawn_in("isin (no arguments)", dir.path(), &[], "info");
    assert!(p.wait_exit().success(), "{}", p.dump());
    p.wait_for(Stream::Out, "frame 2:");
    assert_eq!(p.matching(Stream::Out, |l| l.starts_with("slave ")).len(), 2, "{}", p.dump());
    // Without a display it says so, and where the window and the file renderer are.
    let hint = p.matching(Stream::Out, |l| l.contains("isin view") && l.contains("isin render"));
    assert!(!hint.is_empty(), "no pointer to isin view / isin render\n{}", p.dump());
    let cluster = util::pixels(&dir.path().join("paper.png"));
    assert_same_pixels(&cluster, &render_local(&[]), "embedded cluster frame vs isin render");
}

cluster_test!(wrong_fingerprint, |t: Transport| {
    let c = Cluster::start(t, 1, &[]);
    let mut ticket: isin_transport::Ticket = c.ticket.parse().expect("ticket");
    let real = ticket.fingerprint.expect("encrypted tickets carry a fingerprint").to_string();
    let other = isin_transport_tls::Identity::generate().expect("identity").fingerprint();
    ticket.fingerprint = Some(other);
    let other = other.to_string();
    let mut s = Proc::spawn(
        "impostor-fp slave",
        &["slave", "--connect", &ticket.to_string(), "--threads", "1"],
        "info",
    );
    // Refused in the TLS handshake, and not retried: a wrong ticket stays wrong.
    assert!(!s.wait_exit().success(), "{}", s.dump());
    let line = s.wait_for(Stream::Err, "fingerprint");
    assert!(line.contains(&real) && line.contains(&other), "{line}");
    assert!(s.matching(Stream::Err, |l| l.contains("retrying")).is_empty(), "{}", s.dump());
    // The master never saw it past TLS: still one slave, which renders.
    assert_eq!(c.master.matching(Stream::Err, |l| l.contains("authenticated")).len(), 1);
    c.render("still.png", SMALL);
});

#[test]
fn tls_ticket_never_falls_back_to_plaintext() {
    let c = Cluster::start(Transport::TcpInsecure, 1, &[]);
    // The plaintext master's address in a TLS ticket: the slave must fail the
    // TLS handshake (and keep retrying it), never speak plaintext.
    let ticket: isin_transport::Ticket = c.ticket.parse().expect("ticket");
    let fp = isin_transport_tls::Identity::generate().expect("identity").fingerprint();
    let tls_ticket = format!("isin://{}@{}?fp={fp}", ticket.token, ticket.addr);
    let s = Proc::spawn("tls slave", &["slave", "--connect", &tls_ticket, "--threads", "1"], "info");
    let line = s.wait_for(Stream::Err, "retrying");
    assert!(line.contains("TLS"), "{line}");
    assert!(s.matching(Stream::Err, |l| l.contains("joined")).is_empty(), "{}", s.dump());
    c.master.wait_for(Stream::Err, "bad frame");
    assert_eq!(c.master.matching(Stream::Err, |l| l.contains("authenticated")).len(), 1);
}

cluster_test!(every_codec_is_byte_identical, |t: Transport| {
    let local = render_local(SMALL);
    for codec in ["raw", "lz4", "qoi"] {
        let c = Cluster::start(t, 2, &["--compression", codec]);
        for s in &c.slaves {
            let line = s.wait_for(Stream::Err, "joined master");
            assert!(line.contains(&format!("tiles in {codec})")), "{line}");
        }
        let (cluster, _) = c.render("frame.png", SMALL);
        assert_same_pixels(&cluster, &local, &format!("cluster frame with {codec} vs isin render"));
    }
});

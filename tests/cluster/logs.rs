//! The log at its default level (no `RUST_LOG`): the master says who joined
//! and which clients came and went, not every frame; every line is from
//! isin's own crates (third-party crates log only warnings); `RUST_LOG`
//! still brings the per-frame lines back.

use super::util::{self, Proc, Stream, Transport};
use std::path::Path;

/// A master and a slave at `log` (empty: the default), one render through
/// them; returns the master once the render's client has left it.
fn one_render(t: Transport, log: &str) -> Proc {
    let scene = util::scene();
    let mut args = vec!["master", scene.to_str().unwrap(), "--listen", "127.0.0.1:0"];
    args.extend_from_slice(t.master_args());
    let master = Proc::spawn_with_env("master", Path::new("."), &args, log, &[]);
    let ticket = master.wait_for(Stream::Out, "ticket ").trim_start_matches("ticket ").trim().to_string();
    let _slave = Proc::spawn_with_env(
        "slave",
        Path::new("."),
        &["slave", "--connect", &ticket, "--threads", "1"],
        log,
        &[],
    );
    master.wait_for(Stream::Err, "joined with");
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("frame.png");
    let args = [
        "render",
        scene.to_str().unwrap(),
        "--connect",
        &ticket,
        "--width",
        "64",
        "--height",
        "48",
        "-o",
        out.to_str().unwrap(),
    ];
    let mut render = Proc::spawn_with_env("render", Path::new("."), &args, log, &[]);
    assert!(render.wait_exit().success(), "{}", render.dump());
    // Logged after the frame was done: everything about the frame is in by now.
    master.wait_for(Stream::Err, "left (");
    master
}

cluster_test!(the_default_log_says_joins_and_clients_not_frames, |t: Transport| {
    let master = one_render(t, "");
    let err = master.matching(Stream::Err, |_| true);
    assert!(err.iter().any(|l| l.contains(" INFO ") && l.contains("joined with")), "{}", master.dump());
    assert!(err.iter().any(|l| l.contains("viewer") && l.contains("connected")), "{}", master.dump());
    assert!(
        !err.iter().any(|l| l.contains("frame done")),
        "per-frame lines at the default level\n{}",
        master.dump()
    );
    for line in &err {
        // `LEVEL target: message`, after the time stamp.
        let target = line.split_whitespace().nth(2).unwrap_or("");
        assert!(target.starts_with("isin"), "a line from outside isin at the default level: {line}");
    }

    let master = one_render(t, "info,isin_cluster=debug");
    assert!(!master.matching(Stream::Err, |l| l.contains("frame done")).is_empty(), "{}", master.dump());
});

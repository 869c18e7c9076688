//! Tickets kept off the command line: a master writes its ticket to a file
//! only its owner can read (`--ticket-out`), a slave reads it from there
//! (`--ticket-file`) and `isin render` from the environment (`ISIN_TICKET`),
//! and the frame is still the one `isin render` makes on this machine.

use super::util::{self, Proc, Stream, Transport, assert_same_pixels, pixels, render_local};
use std::os::unix::fs::PermissionsExt;

cluster_test!(a_ticket_from_a_file_or_the_environment_joins_and_renders, |t: Transport| {
    let dir = tempfile::tempdir().expect("temp dir");
    let ticket_file = dir.path().join("ticket");
    // An existing, world-readable file is narrowed to its owner.
    std::fs::write(&ticket_file, "stale").unwrap();
    std::fs::set_permissions(&ticket_file, std::fs::Permissions::from_mode(0o644)).unwrap();
    let scene = util::scene();
    let mut args = vec![
        "master",
        scene.to_str().unwrap(),
        "--listen",
        "127.0.0.1:0",
        "--ticket-out",
        ticket_file.to_str().unwrap(),
    ];
    args.extend_from_slice(t.master_args());
    let master = Proc::spawn("master", &args, "info");
    let printed = master.wait_for(Stream::Out, "ticket ").trim_start_matches("ticket ").trim().to_string();
    let hint = master.wait_for(Stream::Out, "join with: ");
    assert!(
        hint.ends_with(&format!("isin slave --connect '{printed}'")),
        "the hint does not quote the ticket: {hint}"
    );

    let written = std::fs::read_to_string(&ticket_file).unwrap();
    assert_eq!(written.trim(), printed, "--ticket-out holds another ticket than the one printed");
    let mode = std::fs::metadata(&ticket_file).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode, 0o600, "the ticket file is mode {mode:o}");

    let ticket_arg = ticket_file.to_str().unwrap();
    let _slave = Proc::spawn("slave", &["slave", "--ticket-file", ticket_arg, "--threads", "1"], "info");
    master.wait_for(Stream::Err, "joined with");

    let out = dir.path().join("cluster.png");
    let render_args =
        ["render", scene.to_str().unwrap(), "--width", "160", "--height", "120", "-o", out.to_str().unwrap()];
    let mut render = Proc::spawn_with_env(
        "render",
        std::path::Path::new("."),
        &render_args,
        "info",
        &[("ISIN_TICKET", &printed)],
    );
    assert!(
        render.wait_exit().success(),
        "render from ISIN_TICKET failed\n{}\n{}",
        render.dump(),
        master.dump()
    );
    assert!(
        !render.matching(Stream::Out, |l| l.contains("via cluster")).is_empty(),
        "render did not go through the cluster\n{}",
        render.dump()
    );
    assert_same_pixels(
        &pixels(&out),
        &render_local(&["--width", "160", "--height", "120"]),
        "ISIN_TICKET render",
    );

    // The same through --ticket-file, which wins over the environment.
    let out2 = dir.path().join("cluster2.png");
    let render_args2 = [
        "render",
        scene.to_str().unwrap(),
        "--width",
        "160",
        "--height",
        "120",
        "--ticket-file",
        ticket_arg,
        "-o",
        out2.to_str().unwrap(),
    ];
    let env = [("ISIN_TICKET", "isin+tcp-insecure://wrong@127.0.0.1:9")];
    let mut render = Proc::spawn_with_env("render", std::path::Path::new("."), &render_args2, "info", &env);
    assert!(render.wait_exit().success(), "render from --ticket-file failed\n{}", render.dump());
    assert_same_pixels(&pixels(&out), &pixels(&out2), "--ticket-file render");
});

#[test]
fn a_slave_without_any_ticket_says_where_one_may_come_from() {
    let mut p = Proc::spawn("slave", &["slave"], "warn");
    assert!(!p.wait_exit().success());
    let said = p.matching(Stream::Err, |_| true).join("\n");
    for source in ["--connect", "--ticket-file", "ISIN_TICKET"] {
        assert!(said.contains(source), "the error does not name {source}: {said}");
    }
}

#[test]
fn a_ticket_file_naming_all_interfaces_is_warned_about() {
    let dir = tempfile::tempdir().expect("temp dir");
    let ticket_file = dir.path().join("ticket");
    let scene = util::scene();
    let args = [
        "master",
        scene.to_str().unwrap(),
        "--listen",
        "0.0.0.0:0",
        "--ticket-out",
        ticket_file.to_str().unwrap(),
    ];
    let master = Proc::spawn("master", &args, "warn");
    let warning = master.wait_for(Stream::Err, "which slaves cannot reach");
    assert!(warning.contains(ticket_file.to_str().unwrap()), "{warning}");
    assert!(std::fs::read_to_string(&ticket_file).unwrap().contains("@0.0.0.0:"));
}

#[test]
fn the_masters_token_may_come_from_the_environment() {
    let scene = util::scene();
    let args = ["master", scene.to_str().unwrap(), "--listen", "127.0.0.1:0"];
    let env = [("ISIN_TOKEN", "from-the-environment")];
    let master = Proc::spawn_with_env("master", std::path::Path::new("."), &args, "warn", &env);
    let ticket = master.wait_for(Stream::Out, "ticket ");
    assert!(ticket.contains("://from-the-environment@127.0.0.1:"), "{ticket}");
}

//! Every number is bounded before work starts: out-of-range options are
//! refused at once by the real `isin` binary, naming the limit; a ticket that
//! cannot work is refused instead of retried forever; an output image isin
//! cannot write is refused before rendering and leaves no file behind.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).to_path_buf()
}

/// Runs `isin ARGS`, which must exit (within 30 s) with an error; returns
/// its standard error.
fn refused(args: &[&str]) -> String {
    refused_within(args, Duration::from_secs(30))
}

/// [`refused`], allowing `limit` for it.
fn refused_within(args: &[&str], limit: Duration) -> String {
    let mut child = Command::new(env!("CARGO_BIN_EXE_isin"))
        .args(args)
        .current_dir(root())
        .env("RUST_LOG", "warn")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("isin starts");
    let deadline = Instant::now() + limit;
    // Waiting on the process to exit (no signal to wait for but its end).
    while child.try_wait().expect("wait").is_none() {
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("isin {args:?} kept running instead of refusing");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let Output { status, stderr, .. } = child.wait_with_output().expect("output");
    let stderr = String::from_utf8_lossy(&stderr).into_owned();
    assert!(!status.success(), "isin {args:?} succeeded\n{stderr}");
    stderr
}

#[test]
fn out_of_range_options_are_refused_naming_the_limit() {
    let scene = "scenes/cornell.toml";
    let cases: &[(&[&str], &str)] = &[
        (&["render", scene, "--width", "100000", "--height", "100000"], "above the limit of 16384"),
        (&["render", scene, "--tile", "0"], "below the limit of 8"),
        (&["render", scene, "--spp", "0"], "below the limit of 1"),
        (
            &["slave", "--connect", "isin+tcp-insecure://t@127.0.0.1:9", "--threads", "100000"],
            "above the limit of 256",
        ),
        (&["master", scene, "--queue-depth", "4294967295"], "above the limit of 64"),
        (&["master", scene, "--heartbeat-timeout-ms", "0"], "below the limit of 1000"),
    ];
    for (args, says) in cases {
        let err = refused(args);
        assert!(err.contains(says), "isin {args:?} did not say `{says}`:\n{err}");
    }
}

#[test]
fn a_ticket_whose_port_cannot_exist_is_refused_not_retried() {
    let err = refused(&["slave", "--connect", "isin+tcp-insecure://tok@127.0.0.1:99999"]);
    assert!(err.contains("port `99999`"), "{err}");
}

#[test]
fn an_output_isin_cannot_write_is_refused_before_rendering_and_leaves_nothing() {
    let dir = tempfile::tempdir().expect("temp dir");
    let tiff = dir.path().join("x.tiff");
    let err = refused(&["render", "scenes/cornell.toml", "-o", tiff.to_str().unwrap(), "--width", "64"]);
    assert!(err.contains("png, jpg (or jpeg), exr, pfm"), "{err}");
    let missing = dir.path().join("no/such/dir/x.png");
    let err = refused(&["render", "scenes/cornell.toml", "-o", missing.to_str().unwrap(), "--width", "64"]);
    assert!(err.contains("cannot write"), "{err}");
    let left: Vec<_> = std::fs::read_dir(dir.path()).expect("dir").collect();
    assert!(left.is_empty(), "left behind: {left:?}");
}

#[test]
fn a_slave_whose_master_host_never_resolves_gives_up_with_a_clear_error() {
    // `.invalid` never resolves (RFC 2606).
    // Ten tries: with a name server that answers at once ~20 s of backoff; one
    // that times out each lookup takes longer.
    let err = refused_within(
        &["slave", "--connect", "isin+tcp-insecure://tok@master.invalid:7878"],
        Duration::from_secs(180),
    );
    assert!(err.contains("cannot resolve master.invalid:7878"), "{err}");
    let said = err.lines().filter(|l| l.contains("retrying")).count();
    assert_eq!(said, 1, "retrying is said once a minute, not per attempt:\n{err}");
}

//! The command line itself, through the real `isin` binary: shell
//! completions and the manual page, the version on every command, `isin
//! FILE` as `isin view FILE`, the older spellings of options still taken,
//! and every `isin bench` command's help (benchmarks themselves are not run).

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).to_path_buf()
}

/// Runs `isin ARGS` in the checkout with no display; returns when it exits.
fn isin(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_isin"))
        .args(args)
        .current_dir(root())
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .env_remove("ISIN_TICKET")
        .env("RUST_BACKTRACE", "0")
        .env("RUST_LOG", "warn")
        .stdin(Stdio::null())
        .output()
        .expect("isin runs")
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn completions_name_every_command() {
    let out = isin(&["completions", "bash"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let script = stdout(&out);
    assert!(script.contains("complete -F _isin"), "not a bash completion script:\n{script}");
    for command in ["render", "view", "fly", "scene", "master", "slave", "bench", "completions", "man"] {
        assert!(script.contains(command), "the completion script does not name `{command}`");
    }
    for shell in ["zsh", "fish", "elvish", "powershell"] {
        let out = isin(&["completions", shell]);
        assert!(out.status.success() && stdout(&out).contains("render"), "{shell}: {}", stderr(&out));
    }
    let out = isin(&["completions", "tcsh"]);
    assert!(!out.status.success(), "an unknown shell is refused");
}

#[test]
fn the_manual_page_is_roff_and_says_what_no_arguments_do() {
    let out = isin(&["man"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let page = stdout(&out);
    assert!(page.contains(".TH isin 1"), "no roff title header:\n{page}");
    assert!(page.contains(".SH NAME") && page.contains(".SH SYNOPSIS"), "no roff sections:\n{page}");
    assert!(page.contains("paper.png"), "the page does not say what isin alone writes:\n{page}");
}

#[test]
fn the_help_says_what_no_arguments_do() {
    let out = isin(&["--help"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let help = stdout(&out);
    assert!(help.contains("With no arguments"), "{help}");
    assert!(help.contains("paper.png") && help.contains("current folder"), "{help}");
    assert!(help.contains("isin view FILE"), "{help}");
}

#[test]
fn every_command_prints_the_version() {
    let version = env!("CARGO_PKG_VERSION");
    for args in
        [&["-V"][..], &["--version"], &["render", "-V"], &["slave", "--version"], &["bench", "scaling", "-V"]]
    {
        let out = isin(args);
        assert!(out.status.success(), "isin {args:?}: {}", stderr(&out));
        assert!(stdout(&out).contains(version), "isin {args:?} printed {:?}", stdout(&out));
    }
}

/// Headless, `isin FILE …` does what `isin view FILE …` does: the same
/// refusal, naming the missing display, and the same exit status.
#[test]
fn a_file_alone_is_isin_view_of_it() {
    for extra in [&[][..], &["--threads", "1", "--width", "64"]] {
        let short: Vec<&str> = ["scenes/cornell.toml"].iter().chain(extra).copied().collect();
        let long: Vec<&str> = ["view", "scenes/cornell.toml"].iter().chain(extra).copied().collect();
        let (a, b) = (isin(&short), isin(&long));
        assert!(!b.status.success(), "isin view without a display succeeded");
        assert_eq!(a.status.code(), b.status.code(), "isin {short:?} against isin {long:?}");
        assert_eq!(stderr(&a), stderr(&b), "isin {short:?} against isin {long:?}");
        assert!(stderr(&a).contains("no display"), "{}", stderr(&a));
    }
    // A mistyped command is still one, with clap's suggestion.
    let out = isin(&["rendr", "scenes/cornell.toml"]);
    assert!(stderr(&out).contains("a similar subcommand exists: 'render'"), "{}", stderr(&out));
}

/// Scripts written for the older spellings keep working: each old option is
/// taken as its new name (the same error, from past the argument parser).
#[test]
fn older_spellings_are_taken_as_their_new_names() {
    let ticket = "isin+tcp-insecure://tok@127.0.0.1:9";
    let pairs: &[(&[&str], &[&str])] = &[
        (
            &["render", "scenes/cornell.toml", "--cluster", ticket, "-o", "out.txt"],
            &["render", "scenes/cornell.toml", "--connect", ticket, "-o", "out.txt"],
        ),
        (
            &["fly", "scenes/cornell.toml", "--path", "no-such-path.toml", "--out", "frames"],
            &["fly", "scenes/cornell.toml", "--path", "no-such-path.toml", "--out-dir", "frames"],
        ),
        (
            &["fly", "scenes/cornell.toml", "--path", "no-such-path.toml", "--cluster", ticket],
            &["fly", "scenes/cornell.toml", "--path", "no-such-path.toml", "--connect", ticket],
        ),
        (
            &["bench", "cluster", "--sizes", "320", "--out", "bench.json"],
            &["bench", "cluster", "--sizes", "320", "--output", "bench.json"],
        ),
    ];
    for (old, new) in pairs {
        let (a, b) = (isin(old), isin(new));
        assert!(!b.status.success(), "isin {new:?} was meant to fail past the parser");
        assert!(!stderr(&b).contains("unexpected argument"), "{}", stderr(&b));
        assert_eq!(stderr(&a), stderr(&b), "isin {old:?} against isin {new:?}");
    }
    assert!(!root().join("frames").exists() && !root().join("bench.json").exists());
}

#[test]
fn every_bench_command_has_help() {
    for args in [
        &["bench", "--help"][..],
        &["bench", "cluster", "--help"],
        &["bench", "scaling", "--help"],
        &["bench", "transports", "--help"],
    ] {
        let out = isin(args);
        assert!(out.status.success(), "isin {args:?}: {}", stderr(&out));
        assert!(stdout(&out).contains("Usage: isin bench"), "isin {args:?}: {}", stdout(&out));
    }
}

#[test]
fn a_ticket_is_given_one_way_at_a_time() {
    let out = isin(&["slave", "--connect", "isin+tcp-insecure://t@127.0.0.1:9", "--ticket-file", "ticket"]);
    assert!(!out.status.success());
    assert!(stderr(&out).contains("cannot be used with"), "{}", stderr(&out));
    let out = isin(&["slave", "--ticket-file", "no-such-ticket-file"]);
    assert!(stderr(&out).contains("cannot read ticket file no-such-ticket-file"), "{}", stderr(&out));
}

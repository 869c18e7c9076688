//! `contrib/isin-slave.service` works with this `isin`: the unit's own
//! `ExecStart` line — the binary swapped for the built one, systemd's `%d`
//! (credentials) and `%H` (host name) filled in as systemd would — joins a
//! master from the ticket file it wrote, and the unit keeps its promises
//! (an unprivileged dynamic user, restarted always, the ticket as a credential).

use super::util::{self, Proc, Stream, Transport};
use std::path::Path;

/// The value of `key=` in `unit` (its one line).
fn setting<'a>(unit: &'a str, key: &str) -> &'a str {
    let prefix = format!("{key}=");
    let mut values = unit.lines().filter_map(|l| l.strip_prefix(prefix.as_str()));
    let value = values.next().unwrap_or_else(|| panic!("the unit has no {key}="));
    assert!(values.next().is_none(), "the unit sets {key}= twice");
    value
}

cluster_test!(the_units_slave_command_joins_from_the_ticket_file, |t: Transport| {
    let unit = std::fs::read_to_string(util::root().join("contrib/isin-slave.service")).expect("the unit");
    assert_eq!(setting(&unit, "DynamicUser"), "yes");
    assert_eq!(setting(&unit, "Restart"), "always");
    let (credential, source) = setting(&unit, "LoadCredential").split_once(':').expect("NAME:PATH");
    assert_eq!(source, "/etc/isin/ticket");

    let credentials = tempfile::tempdir().unwrap();
    let ticket_file = credentials.path().join(credential);
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
    master.wait_for(Stream::Out, "ticket ");

    let exec = setting(&unit, "ExecStart")
        .replace("%d", credentials.path().to_str().unwrap())
        .replace("%H", "farm-pc");
    let mut words = exec.split_whitespace();
    assert_eq!(words.next(), Some("/usr/local/bin/isin"), "{exec}");
    let args: Vec<&str> = words.chain(["--threads", "1"]).collect();
    assert!(args.contains(&"--ticket-file"), "the unit passes the ticket on the command line: {exec}");
    let _slave = Proc::spawn_with_env("unit's slave", Path::new("/"), &args, "", &[]);
    let joined = master.wait_for(Stream::Err, "joined with");
    assert!(joined.contains("farm-pc"), "{joined}");
});

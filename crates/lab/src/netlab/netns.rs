//! Network namespaces joined by a bridge: the emulated LAN.
//!
//! Layout for `n` slaves (all names under [`PREFIX`](super::PREFIX)):
//!
//! ```text
//!   isin-bench-m  (master, 10.231.0.1)  eth0 ──veth── h0 ┐
//!   isin-bench-s1 (slave 1, 10.231.0.11) eth0 ──veth── h1 ├ br0 in isin-bench-sw
//!   …                                                     │
//!   isin-bench-sN (slave N, 10.231.0.(10+N)) eth0 ─veth─ hN ┘
//! ```
//!
//! A host's cable is shaped in both directions: `tbf` on its `eth0` (what it
//! sends) and on its switch port `hI` (what it receives), so the master's port,
//! like the paper's master PC, carries all slaves' tiles through one
//! rate-limited link. Loss is dropped on each host's input (`eth0`), so it hits
//! both directions. Offloads (TSO/GSO/GRO) are off so that a drop or the rate
//! limiter sees single packets, and IPv6 is off so that no stray router or
//! neighbour traffic shows in the interface counters.

use super::{PREFIX, run};
use anyhow::Context;
use std::net::Ipv4Addr;
use std::os::fd::AsRawFd;
use std::process::Command;

/// The emulated cable of every host.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct LinkSpec {
    /// Rate limit in Mbit/s each way (`None`: the veth's own speed).
    pub rate_mbit: Option<u32>,
    /// Packets dropped at random on each host's input, per 1000.
    pub loss_per_mille: u32,
}

impl LinkSpec {
    /// `tbf` arguments for this rate: a bucket of 4 ms of traffic (at least
    /// 32 KB, so one full-size packet always fits) and at most 50 ms queued.
    pub fn tbf_args(rate_mbit: u32) -> Vec<String> {
        let burst = (u64::from(rate_mbit) * 1_000_000 / 8 / 250).max(32 * 1024);
        ["tbf", "rate", &format!("{rate_mbit}mbit"), "burst", &burst.to_string(), "latency", "50ms"]
            .map(String::from)
            .to_vec()
    }

    /// The nftables rule body dropping `loss_per_mille` of the packets arriving on `eth0`.
    pub fn loss_rule(loss_per_mille: u32) -> String {
        format!("iifname \"eth0\" numgen random mod 1000 lt {loss_per_mille} drop")
    }

    /// Short label: `100 Mbit/s, 1 % loss`.
    pub fn label(&self) -> String {
        let rate = match self.rate_mbit {
            Some(r) if r >= 1000 && r % 1000 == 0 => format!("{} Gbit/s", r / 1000),
            Some(r) => format!("{r} Mbit/s"),
            None => "unlimited".into(),
        };
        format!("{rate}, {} % loss", self.loss_per_mille as f64 / 10.0)
    }
}

/// One emulated PC: a namespace with one interface, `eth0`, on the switch.
#[derive(Clone, Debug)]
pub struct Host {
    /// Namespace name.
    pub ns: String,
    /// Its address on the LAN.
    pub addr: Ipv4Addr,
    /// Its port on the switch (an interface in the switch namespace).
    pub port: String,
}

/// Byte and packet counters of an interface.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct IfCounters {
    /// Bytes received (Ethernet frames, headers included).
    pub rx_bytes: u64,
    /// Bytes sent.
    pub tx_bytes: u64,
    /// Packets received.
    pub rx_packets: u64,
    /// Packets sent.
    pub tx_packets: u64,
}

impl IfCounters {
    /// Counts since `earlier`.
    pub fn since(&self, earlier: &IfCounters) -> IfCounters {
        IfCounters {
            rx_bytes: self.rx_bytes.saturating_sub(earlier.rx_bytes),
            tx_bytes: self.tx_bytes.saturating_sub(earlier.tx_bytes),
            rx_packets: self.rx_packets.saturating_sub(earlier.rx_packets),
            tx_packets: self.tx_packets.saturating_sub(earlier.tx_packets),
        }
    }
}

/// The emulated LAN: a master, `n` slaves and a switch; removed on drop.
pub struct Lab {
    switch: String,
    master: Host,
    slaves: Vec<Host>,
    link: LinkSpec,
    namespaces: Vec<String>,
}

/// The switch namespace's name.
fn switch_name() -> String {
    format!("{PREFIX}sw")
}

impl Lab {
    /// Builds the LAN for `slaves` slaves with every cable shaped as `link`.
    /// Removes namespaces left by an earlier run first (see also
    /// [`cleanup_stale`](super::cleanup_stale), which removes cgroups too).
    pub fn new(slaves: usize, link: LinkSpec) -> anyhow::Result<Lab> {
        anyhow::ensure!(slaves <= 200, "at most 200 slaves in the lab");
        for ns in list_namespaces().into_iter().filter(|n| n.starts_with(PREFIX)) {
            tracing::warn!("removing namespace {ns}, left over from an earlier run");
            remove_namespace(&ns);
        }
        let mut lab = Lab {
            switch: switch_name(),
            master: Host { ns: format!("{PREFIX}m"), addr: Ipv4Addr::new(10, 231, 0, 1), port: "h0".into() },
            slaves: (1..=slaves)
                .map(|i| Host {
                    ns: format!("{PREFIX}s{i}"),
                    addr: Ipv4Addr::new(10, 231, 0, 10 + i as u8),
                    port: format!("h{i}"),
                })
                .collect(),
            link: LinkSpec::default(),
            namespaces: Vec::new(),
        };
        // On failure the partly built lab is dropped, which removes what exists.
        let sw = lab.switch.clone();
        lab.add_namespace(&sw)?;
        run("ip", &["-n", &sw, "link", "add", "br0", "type", "bridge"])?;
        run("ip", &["-n", &sw, "link", "set", "br0", "up"])?;
        // A switch forwards frames; it does not run the host's firewall. With
        // br_netfilter loaded, every bridged packet would also pass through
        // iptables, in the sender's context: CPU a real LAN does not spend
        // (best effort: without the module these settings do not exist).
        let _ = run(
            "ip",
            &[
                "netns",
                "exec",
                &sw,
                "sysctl",
                "-qw",
                "net.bridge.bridge-nf-call-iptables=0",
                "net.bridge.bridge-nf-call-ip6tables=0",
                "net.bridge.bridge-nf-call-arptables=0",
            ],
        );
        for host in std::iter::once(lab.master.clone()).chain(lab.slaves.clone()) {
            lab.add_namespace(&host.ns)?;
            run(
                "ip",
                &[
                    "-n", &sw, "link", "add", &host.port, "type", "veth", "peer", "name", "eth0", "netns",
                    &host.ns,
                ],
            )?;
            run("ip", &["-n", &sw, "link", "set", &host.port, "master", "br0", "up"])?;
            run("ip", &["-n", &host.ns, "addr", "add", &format!("{}/24", host.addr), "dev", "eth0"])?;
            run("ip", &["-n", &host.ns, "link", "set", "eth0", "up"])?;
            offloads_off(&sw, &host.port);
            offloads_off(&host.ns, "eth0");
        }
        lab.set_link(link)?;
        Ok(lab)
    }

    fn add_namespace(&mut self, ns: &str) -> anyhow::Result<()> {
        run("ip", &["netns", "add", ns])?;
        super::register_namespace(ns);
        self.namespaces.push(ns.to_string());
        run("ip", &["-n", ns, "link", "set", "lo", "up"])?;
        // Best effort: no IPv6 chatter in the counters.
        let _ = run(
            "ip",
            &[
                "netns",
                "exec",
                ns,
                "sysctl",
                "-qw",
                "net.ipv6.conf.all.disable_ipv6=1",
                "net.ipv6.conf.default.disable_ipv6=1",
            ],
        );
        Ok(())
    }

    /// Reshapes every cable (rate and loss), keeping the namespaces.
    pub fn set_link(&mut self, link: LinkSpec) -> anyhow::Result<()> {
        for host in std::iter::once(&self.master).chain(&self.slaves) {
            self.set_rate(host, link.rate_mbit)?;
            let nft = |args: &[&str]| nft(&host.ns, args);
            let _ = nft(&["delete", "table", "inet", "isin_loss"]);
            if link.loss_per_mille > 0 {
                nft(&["add", "table", "inet", "isin_loss"])?;
                nft(&["add", "chain", "inet", "isin_loss", "in", "{ type filter hook input priority 0; }"])?;
                nft(&["add", "rule", "inet", "isin_loss", "in", &LinkSpec::loss_rule(link.loss_per_mille)])?;
            }
        }
        self.link = link;
        tracing::info!("lab link: {}", link.label());
        Ok(())
    }

    /// Rate-limits both directions of `host`'s cable to `rate_mbit` (`None`:
    /// the veth's own speed), leaving the other cables as they are.
    pub fn set_rate(&self, host: &Host, rate_mbit: Option<u32>) -> anyhow::Result<()> {
        for (ns, dev) in [(host.ns.as_str(), "eth0"), (self.switch.as_str(), host.port.as_str())] {
            match rate_mbit {
                Some(r) => {
                    let mut args: Vec<String> =
                        ["-n", ns, "qdisc", "replace", "dev", dev, "root"].map(String::from).to_vec();
                    args.extend(LinkSpec::tbf_args(r));
                    let args: Vec<&str> = args.iter().map(String::as_str).collect();
                    run("tc", &args)?;
                }
                None => {
                    // No root qdisc of ours: nothing to delete is fine.
                    let _ = run("tc", &["-n", ns, "qdisc", "del", "dev", dev, "root"]);
                }
            }
        }
        Ok(())
    }

    /// Drops `per_mille` of the packets of `host`'s cable in both directions
    /// (on its `eth0`'s input and output; 1000: the cable holds nothing), in
    /// an nftables table of its own beside the lab-wide loss; 0 removes it.
    pub fn set_host_loss(&self, host: &Host, per_mille: u32) -> anyhow::Result<()> {
        let nft = |args: &[&str]| nft(&host.ns, args);
        let _ = nft(&["delete", "table", "inet", "isin_host_loss"]);
        if per_mille == 0 {
            return Ok(());
        }
        // numgen draws below 1000: all of them is a plain drop.
        let rule = if per_mille >= 1000 {
            "iifname \"eth0\" drop".to_string()
        } else {
            LinkSpec::loss_rule(per_mille)
        };
        nft(&["add", "table", "inet", "isin_host_loss"])?;
        nft(&["add", "chain", "inet", "isin_host_loss", "in", "{ type filter hook input priority 0; }"])?;
        nft(&["add", "chain", "inet", "isin_host_loss", "out", "{ type filter hook output priority 0; }"])?;
        nft(&["add", "rule", "inet", "isin_host_loss", "in", &rule])?;
        nft(&["add", "rule", "inet", "isin_host_loss", "out", &rule.replace("iifname", "oifname")])?;
        Ok(())
    }

    /// Unplugs (`up` false) or plugs back `host`'s cable: its `eth0` down or up.
    pub fn set_host_up(&self, host: &Host, up: bool) -> anyhow::Result<()> {
        run("ip", &["-n", &host.ns, "link", "set", "eth0", if up { "up" } else { "down" }])?;
        Ok(())
    }

    /// The current cable shape.
    pub fn link(&self) -> LinkSpec {
        self.link
    }

    /// The master's host.
    pub fn master(&self) -> &Host {
        &self.master
    }

    /// Slave `i` (0-based).
    pub fn slave(&self, i: usize) -> Option<&Host> {
        self.slaves.get(i)
    }

    /// Number of slave hosts.
    pub fn slave_count(&self) -> usize {
        self.slaves.len()
    }

    /// Counters of a host's `eth0`.
    pub fn counters(&self, host: &Host) -> anyhow::Result<IfCounters> {
        counters(&host.ns, "eth0")
    }
}

impl Drop for Lab {
    fn drop(&mut self) {
        for ns in self.namespaces.drain(..).rev() {
            remove_namespace(&ns);
        }
    }
}

/// Runs `nft ARGS…` inside namespace `ns`.
fn nft(ns: &str, args: &[&str]) -> anyhow::Result<String> {
    let mut all = vec!["netns", "exec", ns, "nft"];
    all.extend_from_slice(args);
    run("ip", &all)
}

fn offloads_off(ns: &str, dev: &str) {
    let _ = run("ip", &["netns", "exec", ns, "ethtool", "-K", dev, "tso", "off", "gso", "off", "gro", "off"]);
}

/// Reads an interface's counters with `ip -s -j link`.
pub fn counters(ns: &str, dev: &str) -> anyhow::Result<IfCounters> {
    let json = run("ip", &["-n", ns, "-s", "-j", "link", "show", "dev", dev])?;
    parse_counters(&json).with_context(|| format!("cannot read the counters of {dev} in {ns}"))
}

/// Parses `ip -s -j link show dev X` output.
pub fn parse_counters(json: &str) -> anyhow::Result<IfCounters> {
    let v: serde_json::Value = serde_json::from_str(json)?;
    let s = v.get(0).and_then(|l| l.get("stats64")).context("no stats64 in `ip -s -j link` output")?;
    let get = |dir: &str, what: &str| s.get(dir).and_then(|d| d.get(what)).and_then(|x| x.as_u64());
    Ok(IfCounters {
        rx_bytes: get("rx", "bytes").context("rx bytes")?,
        tx_bytes: get("tx", "bytes").context("tx bytes")?,
        rx_packets: get("rx", "packets").context("rx packets")?,
        tx_packets: get("tx", "packets").context("tx packets")?,
    })
}

/// Namespaces that exist (`ip netns list`).
pub fn list_namespaces() -> Vec<String> {
    run("ip", &["netns", "list"])
        .map(|out| out.lines().filter_map(|l| l.split_whitespace().next()).map(String::from).collect())
        .unwrap_or_default()
}

/// Kills what runs in namespace `ns` and deletes it (best effort).
pub fn remove_namespace(ns: &str) {
    if let Ok(pids) = run("ip", &["netns", "pids", ns]) {
        for pid in pids.split_whitespace().filter_map(|p| p.parse::<libc::pid_t>().ok()) {
            // SAFETY: kill has no memory preconditions; these run in the lab's namespace.
            unsafe { libc::kill(pid, libc::SIGKILL) };
        }
    }
    if let Err(e) = run("ip", &["netns", "del", ns]) {
        tracing::warn!("cannot remove namespace {ns}: {e:#}");
    }
    super::unregister_namespace(ns);
}

/// Moves the calling thread into namespace `ns`: sockets it creates from now
/// on live there. (Other threads, and the process's children spawned by other
/// threads, are not affected.)
pub fn enter(ns: &str) -> anyhow::Result<()> {
    let f = std::fs::File::open(format!("/run/netns/{ns}"))
        .with_context(|| format!("no network namespace {ns}"))?;
    // SAFETY: setns on a valid namespace file descriptor; affects this thread only.
    let r = unsafe { libc::setns(f.as_raw_fd(), libc::CLONE_NEWNET) };
    if r != 0 {
        anyhow::bail!("setns({ns}) failed: {}", std::io::Error::last_os_error());
    }
    Ok(())
}

/// A command for `exe args…` that runs in namespace `ns` (when given) and in
/// the cgroup whose `cgroup.procs` is `procs` (when given). The process id of
/// the returned command's child is that of `exe` itself (the shell and `ip
/// netns exec` both exec). The shell joins the cgroup before entering the
/// namespace: `ip netns exec` mounts the namespace's own `/sys`, without cgroups.
pub fn command(
    ns: Option<&str>,
    procs: Option<&std::path::Path>,
    exe: &std::path::Path,
    args: &[String],
) -> Command {
    let mut script = String::new();
    if let Some(p) = procs {
        script.push_str(&format!("echo $$ > '{}' && ", p.display()));
    }
    script.push_str("exec ");
    if let Some(ns) = ns {
        script.push_str(&format!("ip netns exec '{ns}' "));
    }
    script.push_str("\"$0\" \"$@\"");
    let mut cmd = Command::new("sh");
    cmd.args(["-c", &script]).arg(exe).args(args);
    cmd
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{Read, Write};
    use std::time::{Duration, Instant};

    #[test]
    fn tbf_bucket_holds_a_packet_and_grows_with_the_rate() {
        let b = |r| LinkSpec::tbf_args(r)[4].parse::<u64>().unwrap();
        assert!(b(1) >= 1514, "a full Ethernet frame must fit the bucket");
        assert!(b(1000) > b(100));
        assert_eq!(LinkSpec::tbf_args(100)[2], "100mbit");
    }

    #[test]
    fn labels_and_rules_say_what_they_do() {
        let l = LinkSpec { rate_mbit: Some(1000), loss_per_mille: 1 };
        assert_eq!(l.label(), "1 Gbit/s, 0.1 % loss");
        assert!(LinkSpec::loss_rule(10).contains("mod 1000 lt 10 drop"));
    }

    #[test]
    fn counters_parse_iproute2_json() {
        let json = r#"[{"ifname":"eth0","stats64":{"rx":{"bytes":1000,"packets":7},"tx":{"bytes":20,"packets":2}}}]"#;
        let c = parse_counters(json).unwrap();
        assert_eq!((c.rx_bytes, c.tx_bytes, c.rx_packets, c.tx_packets), (1000, 20, 7, 2));
        assert!(parse_counters("[{}]").is_err());
    }

    #[test]
    fn command_without_namespace_runs_the_program_with_its_arguments() {
        let out =
            command(None, None, std::path::Path::new("echo"), &["a b".into(), "c".into()]).output().unwrap();
        assert_eq!(String::from_utf8_lossy(&out.stdout), "a b c\n");
    }

    /// Root only: a lab with one slave; TCP from the slave to the master is
    /// rate-limited by tbf, the interface counters see the bytes, and the
    /// namespaces are gone after drop.
    #[test]
    fn lab_shapes_traffic_between_namespaces_and_cleans_up() {
        if let Err(e) = crate::netlab::Support::probe().netns {
            println!("skipped: the lab needs namespaces ({e})");
            return;
        }
        let _serial = crate::netlab::tests_lock();
        if list_namespaces().iter().any(|n| n.starts_with(PREFIX)) {
            println!("skipped: a lab (a running `isin bench`?) exists; building one would remove it");
            return;
        }
        let lab = Lab::new(1, LinkSpec { rate_mbit: Some(20), loss_per_mille: 0 }).unwrap();
        let (m, s) = (lab.master().clone(), lab.slave(0).unwrap().clone());
        let server = std::thread::spawn(move || {
            enter(&m.ns).unwrap();
            let l = std::net::TcpListener::bind((m.addr, 7901)).unwrap();
            // Never block forever: a failed client must fail the test, not hang it.
            l.set_nonblocking(true).unwrap();
            let t0 = Instant::now();
            let mut c = loop {
                match l.accept() {
                    Ok((c, _)) => break c,
                    Err(_) if t0.elapsed() < Duration::from_secs(20) => std::thread::yield_now(),
                    Err(e) => panic!("no connection from the slave's namespace: {e}"),
                }
            };
            c.set_nonblocking(false).unwrap();
            c.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
            let mut buf = Vec::new();
            c.read_to_end(&mut buf).unwrap();
            buf.len()
        });
        let m_addr = lab.master().addr;
        let before = lab.counters(lab.master()).unwrap();
        let sent = 1_500_000usize;
        let client = std::thread::spawn(move || {
            enter(&s.ns).unwrap();
            let t0 = Instant::now();
            let mut c = loop {
                match std::net::TcpStream::connect((m_addr, 7901)) {
                    Ok(c) => break c,
                    Err(_) if t0.elapsed() < Duration::from_secs(5) => std::thread::yield_now(),
                    Err(e) => panic!("cannot reach the master's namespace: {e}"),
                }
            };
            let t1 = Instant::now();
            c.write_all(&vec![7u8; sent]).unwrap();
            c.shutdown(std::net::Shutdown::Write).unwrap();
            t1
        });
        let t1 = client.join().unwrap();
        assert_eq!(server.join().unwrap(), sent);
        let secs = t1.elapsed().as_secs_f64();
        let mbit = sent as f64 * 8.0 / secs / 1e6;
        assert!(mbit < 20.0 * 1.25, "tbf should hold 20 Mbit/s, measured {mbit:.1}");
        let c = lab.counters(lab.master()).unwrap().since(&before);
        assert!(c.rx_bytes >= sent as u64, "master's eth0 saw {} bytes of {sent}", c.rx_bytes);
        let names: Vec<String> = lab.namespaces.clone();
        drop(lab);
        let left = list_namespaces();
        assert!(names.iter().all(|n| !left.contains(n)), "left over: {left:?}");
    }
}

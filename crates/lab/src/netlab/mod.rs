//! A network and CPU lab for the benchmarks: emulated PCs on one machine.
//!
//! Each emulated host (the master, every slave) gets its own network namespace
//! and joins a "switch" namespace holding a Linux bridge through a veth pair,
//! like PCs plugged into a LAN switch. Both directions of every host's cable
//! can be rate-limited with `tc … tbf` (this kernel has no `netem`) and made
//! lossy with nftables (`numgen random mod 1000 < N drop` on the host's input);
//! each slave can be put in a cgroup v1 CPU controller with a CFS quota, so it
//! is a "slow PC" with a fixed share of a core.
//!
//! Everything the lab creates is named with [`PREFIX`] and lives only inside
//! its own namespaces (no interface or address is added to the caller's
//! namespace): it is removed when the [`Lab`] is dropped, when the process
//! gets Ctrl-C or SIGTERM ([`install_signal_cleanup`]), and — left over from a
//! crashed run — when the next lab starts ([`cleanup_stale`]).
//!
//! Modules: [`netns`] (namespaces, veth, bridge, tbf, nftables, interface
//! counters), [`cgroup`] (CPU quotas).

pub mod cgroup;
pub mod netns;

use anyhow::Context;
use std::process::Command;
use std::sync::Mutex;

pub use cgroup::CpuCgroup;
pub use netns::{Lab, LinkSpec};

/// Prefix of every namespace and cgroup the lab creates.
pub const PREFIX: &str = "isin-bench-";

/// What the lab can do on this machine.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Support {
    /// Namespaces, veth pairs, bridges and tbf work (root, `ip netns`, `tc`).
    pub netns: Result<(), String>,
    /// nftables random drops (the `nft` tool).
    pub loss: Result<(), String>,
    /// cgroup v1 CPU quotas under [`cgroup::CPU_ROOT`].
    pub cpu_quota: Result<(), String>,
}

impl Support {
    /// Probes the machine (cheap: looks at the user id, the tools and the cgroup mount).
    pub fn probe() -> Support {
        // SAFETY: geteuid has no preconditions.
        let root = unsafe { libc::geteuid() } == 0;
        let not_root = || Err("not running as root".to_string());
        let netns = if !root {
            not_root()
        } else if !tool_works("ip", &["netns", "list"]) {
            Err("`ip netns` is not available (iproute2 missing?)".into())
        } else if !tool_works("tc", &["-V"]) {
            Err("`tc` (iproute2) is not available".into())
        } else {
            Ok(())
        };
        let loss = if !root {
            not_root()
        } else if !tool_works("nft", &["--version"]) {
            Err("`nft` (nftables) is not available".into())
        } else {
            Ok(())
        };
        let cpu_quota = if !root { not_root() } else { cgroup::probe() };
        Support { netns, loss, cpu_quota }
    }

    /// One line per missing feature, for the bench's output.
    pub fn describe(&self) -> Vec<String> {
        let mut out = Vec::new();
        for (what, r) in [
            ("network namespaces", &self.netns),
            ("random packet loss", &self.loss),
            ("CPU quotas", &self.cpu_quota),
        ] {
            if let Err(e) = r {
                out.push(format!("{what}: unavailable ({e})"));
            }
        }
        out
    }
}

fn tool_works(tool: &str, args: &[&str]) -> bool {
    Command::new(tool)
        .args(args)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// Runs an external command (`ip`, `tc`, `nft`, …); fails with its stderr.
pub(crate) fn run(cmd: &str, args: &[&str]) -> anyhow::Result<String> {
    let out = Command::new(cmd).args(args).output().with_context(|| format!("cannot run {cmd}"))?;
    if !out.status.success() {
        anyhow::bail!("`{cmd} {}` failed: {}", args.join(" "), String::from_utf8_lossy(&out.stderr).trim());
    }
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

/// What the lab has created and not yet removed, for cleanup on a signal.
#[derive(Default)]
struct Registry {
    namespaces: Vec<String>,
    cgroups: Vec<String>,
    pids: Vec<u32>,
}

static REGISTRY: Mutex<Registry> =
    Mutex::new(Registry { namespaces: Vec::new(), cgroups: Vec::new(), pids: Vec::new() });

fn registry() -> std::sync::MutexGuard<'static, Registry> {
    REGISTRY.lock().unwrap_or_else(|e| e.into_inner())
}

/// Remembers a process running inside the lab, to be killed on Ctrl-C.
pub fn register_pid(pid: u32) {
    registry().pids.push(pid);
}

/// Forgets a process (it exited or was killed).
pub fn unregister_pid(pid: u32) {
    registry().pids.retain(|&p| p != pid);
}

pub(crate) fn register_namespace(name: &str) {
    registry().namespaces.push(name.to_string());
}

pub(crate) fn unregister_namespace(name: &str) {
    registry().namespaces.retain(|n| n != name);
}

pub(crate) fn register_cgroup(name: &str) {
    registry().cgroups.push(name.to_string());
}

pub(crate) fn unregister_cgroup(name: &str) {
    registry().cgroups.retain(|n| n != name);
}

/// Kills the registered processes and removes the registered namespaces and cgroups.
fn cleanup_registered() {
    let r = std::mem::take(&mut *registry());
    for pid in r.pids {
        // SAFETY: kill has no memory preconditions; the pid is one of our children.
        unsafe { libc::kill(pid as libc::pid_t, libc::SIGKILL) };
    }
    for ns in r.namespaces {
        netns::remove_namespace(&ns);
    }
    for cg in r.cgroups {
        cgroup::remove(&cg);
    }
}

/// Removes namespaces and cgroups named [`PREFIX`]… left by an earlier run
/// (killing what still runs in them). Returns what was removed.
pub fn cleanup_stale() -> Vec<String> {
    let mut removed = Vec::new();
    for ns in netns::list_namespaces() {
        if ns.starts_with(PREFIX) {
            netns::remove_namespace(&ns);
            removed.push(format!("netns {ns}"));
        }
    }
    for cg in cgroup::list() {
        if cg.starts_with(PREFIX) {
            cgroup::remove(&cg);
            removed.push(format!("cgroup cpu/{cg}"));
        }
    }
    removed
}

/// On Ctrl-C (SIGINT) or SIGTERM: kill the lab's processes, remove its
/// namespaces and cgroups, and exit with status 130. Call once, early.
pub fn install_signal_cleanup() -> anyhow::Result<()> {
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    std::thread::Builder::new().name("isin-lab-signals".into()).spawn(move || {
        rt.block_on(async {
            use tokio::signal::unix::{SignalKind, signal};
            let (Ok(mut int), Ok(mut term)) =
                (signal(SignalKind::interrupt()), signal(SignalKind::terminate()))
            else {
                tracing::warn!("cannot watch signals: the lab is cleaned at the next start instead");
                return;
            };
            tokio::select! {
                _ = int.recv() => {}
                _ = term.recv() => {}
            }
            eprintln!("interrupted: removing the lab's namespaces and cgroups");
            cleanup_registered();
            std::process::exit(130);
        })
    })?;
    Ok(())
}

/// Lab tests share fixed names: run them one at a time.
#[cfg(test)]
pub(crate) fn tests_lock() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn probe_reports_every_missing_feature_by_name() {
        let s = Support::probe();
        let lines = s.describe();
        let missing = [&s.netns, &s.loss, &s.cpu_quota].iter().filter(|r| r.is_err()).count();
        assert_eq!(lines.len(), missing);
        // SAFETY: geteuid has no preconditions.
        if unsafe { libc::geteuid() } != 0 {
            assert!(s.netns.is_err() && s.cpu_quota.is_err(), "non-root cannot build the lab");
        }
    }

    #[test]
    fn failing_command_reports_its_stderr() {
        let e = run("sh", &["-c", "echo boom >&2; exit 3"]).unwrap_err().to_string();
        assert!(e.contains("boom"), "{e}");
    }
}

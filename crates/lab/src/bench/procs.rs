//! Masters and slaves as child processes of the bench — on loopback, or inside
//! the lab's namespaces and CPU cgroups — and what `/proc` says about them.

use crate::netlab::{self, CpuCgroup};
use anyhow::Context;
use isin_transport::Ticket;
use std::io::{BufRead, BufReader};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// A child process killed on drop, with its stderr lines (and arrival times) on a channel.
pub struct ChildGuard {
    /// The process.
    pub child: Child,
    lines: mpsc::Receiver<(Instant, String)>,
}

impl ChildGuard {
    /// Starts this executable with `args` (on loopback, in the caller's namespace).
    pub fn spawn(args: &[&str]) -> anyhow::Result<(Self, BufReader<ChildStdout>)> {
        let exe = std::env::current_exe()?;
        let args: Vec<String> = args.iter().map(|a| a.to_string()).collect();
        Self::spawn_cmd(netlab::netns::command(None, None, &exe, &args))
    }

    /// Starts `cmd` with piped stdout and stderr, logging at INFO and the
    /// master's per-frame lines (DEBUG), which the benches time.
    pub fn spawn_cmd(mut cmd: Command) -> anyhow::Result<(Self, BufReader<ChildStdout>)> {
        let mut child = cmd
            .env("RUST_LOG", "info,isin_cluster::cluster=debug")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .context("cannot start a cluster process")?;
        netlab::register_pid(child.id());
        let stdout = BufReader::new(child.stdout.take().context("stdout")?);
        let stderr = child.stderr.take().context("stderr")?;
        let (tx, lines) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                if tx.send((Instant::now(), line)).is_err() {
                    break;
                }
            }
        });
        Ok((Self { child, lines }, stdout))
    }

    /// Waits for a stderr line containing `needle`; returns when it arrived.
    pub fn wait_for(&self, needle: &str, timeout: Duration) -> anyhow::Result<(Instant, String)> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let (at, line) =
                self.lines.recv_timeout(left).with_context(|| format!("no `{needle}` within {timeout:?}"))?;
            if line.contains(needle) {
                return Ok((at, line));
            }
        }
    }

    /// The stderr lines not consumed yet (the last `n`).
    pub fn tail(&self, n: usize) -> Vec<String> {
        let all: Vec<String> = self.lines.try_iter().map(|(_, l)| l).collect();
        all[all.len().saturating_sub(n)..].to_vec()
    }

    /// Whether the process has exited (with its status).
    pub fn exited(&mut self) -> Option<std::process::ExitStatus> {
        self.child.try_wait().ok().flatten()
    }

    /// The process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }
}

impl Drop for ChildGuard {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        netlab::unregister_pid(self.child.id());
    }
}

/// Starts `isin master SCENE --listen LISTEN --token TOKEN EXTRA…` (in
/// namespace `ns` and cgroup `cgroup` when given) and reads its ticket.
pub fn start_master(
    ns: Option<&str>,
    cgroup: Option<&CpuCgroup>,
    scene: &str,
    listen: &str,
    token: &str,
    extra: &[String],
) -> anyhow::Result<(ChildGuard, Ticket)> {
    let exe = std::env::current_exe()?;
    let mut args: Vec<String> =
        ["master", scene, "--listen", listen, "--token", token].iter().map(|s| s.to_string()).collect();
    args.extend_from_slice(extra);
    let procs = cgroup.map(CpuCgroup::procs_file);
    let (master, mut out) = ChildGuard::spawn_cmd(netlab::netns::command(ns, procs.as_deref(), &exe, &args))?;
    let mut ticket = None;
    for _ in 0..10 {
        let mut line = String::new();
        if out.read_line(&mut line)? == 0 {
            break;
        }
        if let Some(t) = line.strip_prefix("ticket ") {
            ticket = Some(t.trim().to_string());
            break;
        }
    }
    // Keep reading: a master whose stdout is closed fails on its next line
    // ("join with: …") and exits — that was an intermittent "slaves never join".
    std::thread::spawn(move || for _ in out.lines() {});
    let ticket: Ticket = ticket.context("master printed no ticket")?.parse()?;
    Ok((master, ticket))
}

/// Starts `isin slave --connect TICKET --threads N --name NAME EXTRA…`, in
/// namespace `ns` and cgroup `cgroup` when given.
pub fn start_slave(
    ns: Option<&str>,
    cgroup: Option<&CpuCgroup>,
    ticket: &Ticket,
    threads: usize,
    name: &str,
    extra: &[String],
) -> anyhow::Result<ChildGuard> {
    let exe = std::env::current_exe()?;
    let mut args: Vec<String> = vec![
        "slave".into(),
        "--connect".into(),
        ticket.to_string(),
        "--threads".into(),
        threads.to_string(),
        "--name".into(),
        name.into(),
    ];
    args.extend_from_slice(extra);
    let procs = cgroup.map(CpuCgroup::procs_file);
    Ok(ChildGuard::spawn_cmd(netlab::netns::command(ns, procs.as_deref(), &exe, &args))?.0)
}

/// Waits until the master logged `n` slaves joined; fails early when a slave exits.
pub fn wait_joined(master: &ChildGuard, slaves: &mut [ChildGuard], timeout: Duration) -> anyhow::Result<()> {
    let deadline = Instant::now() + timeout;
    let mut joined = 0;
    while joined < slaves.len() {
        if let Some((i, status)) =
            slaves.iter_mut().enumerate().find_map(|(i, s)| s.exited().map(|st| (i, st)))
        {
            anyhow::bail!("slave {} exited ({status}) before joining: {:?}", i + 1, slaves[i].tail(5));
        }
        if Instant::now() >= deadline {
            anyhow::bail!(
                "only {joined} of {} slaves joined within {timeout:?}; master: {:?}; slave 1: {:?}",
                slaves.len(),
                master.tail(5),
                slaves[0].tail(5)
            );
        }
        if master.wait_for("joined with", Duration::from_millis(500)).is_ok() {
            joined += 1;
        }
    }
    Ok(())
}

/// CPU seconds (user + system) from a `/proc/…/stat` file's contents at `path`.
pub fn cpu_secs_of(path: &str) -> f64 {
    let Ok(stat) = std::fs::read_to_string(path) else { return 0.0 };
    // Fields after the parenthesised command name; utime and stime are the 12th and 13th.
    let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|x| x.parse::<f64>().ok()).unwrap_or(0.0);
    // SAFETY: sysconf has no preconditions.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) }.max(1) as f64;
    (ticks(11) + ticks(12)) / hz
}

/// CPU seconds used so far by process `pid` (`self` for this one).
pub fn cpu_secs(pid: &str) -> f64 {
    cpu_secs_of(&format!("/proc/{pid}/stat"))
}

/// Scheduler accounting of a process's threads whose name starts with
/// `prefix` (e.g. `isin-render`), from `/proc/PID/task/*/schedstat`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SchedStat {
    /// Seconds on a CPU.
    pub run: f64,
    /// Seconds runnable but waiting for a CPU (includes time throttled by a quota).
    pub wait: f64,
}

impl SchedStat {
    /// Reads the sum over the matching threads.
    pub fn read(pid: u32, prefix: &str) -> SchedStat {
        let mut s = SchedStat::default();
        let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else { return s };
        for t in tasks.filter_map(Result::ok) {
            let comm = std::fs::read_to_string(t.path().join("comm")).unwrap_or_default();
            if !comm.starts_with(prefix) {
                continue;
            }
            let stat = std::fs::read_to_string(t.path().join("schedstat")).unwrap_or_default();
            let v: Vec<f64> = stat.split_whitespace().filter_map(|x| x.parse().ok()).collect();
            if let [run, wait, ..] = v[..] {
                s.run += run / 1e9;
                s.wait += wait / 1e9;
            }
        }
        s
    }

    /// Accounting since `earlier`.
    pub fn since(&self, earlier: &SchedStat) -> SchedStat {
        SchedStat { run: self.run - earlier.run, wait: self.wait - earlier.wait }
    }
}

/// The machine's CPU time by kind, from the first line of `/proc/stat`, in
/// seconds summed over all cores.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MachineStat {
    /// User and nice time.
    pub user: f64,
    /// System time (outside interrupts).
    pub system: f64,
    /// Idle and I/O wait.
    pub idle: f64,
    /// Hard and soft interrupts (softirq: most of the kernel's network work).
    pub irq: f64,
    /// Time the hypervisor gave this VM's virtual CPUs to others.
    pub steal: f64,
}

impl MachineStat {
    /// Reads `/proc/stat` (all zero if unreadable).
    pub fn read() -> MachineStat {
        Self::parse(&std::fs::read_to_string("/proc/stat").unwrap_or_default())
    }

    /// Parses the `cpu` line of a `/proc/stat` text.
    pub fn parse(text: &str) -> MachineStat {
        let Some(line) = text.lines().find(|l| l.starts_with("cpu ")) else { return MachineStat::default() };
        let v: Vec<f64> = line.split_whitespace().skip(1).filter_map(|x| x.parse().ok()).collect();
        // SAFETY: sysconf has no preconditions.
        let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) }.max(1) as f64;
        let f = |i: usize| v.get(i).copied().unwrap_or(0.0) / hz;
        MachineStat { user: f(0) + f(1), system: f(2), idle: f(3) + f(4), irq: f(5) + f(6), steal: f(7) }
    }

    /// Time since `earlier`.
    pub fn since(&self, e: &MachineStat) -> MachineStat {
        MachineStat {
            user: self.user - e.user,
            system: self.system - e.system,
            idle: self.idle - e.idle,
            irq: self.irq - e.irq,
            steal: self.steal - e.steal,
        }
    }

    /// Sums two spans.
    pub fn plus(&self, o: &MachineStat) -> MachineStat {
        MachineStat {
            user: self.user + o.user,
            system: self.system + o.system,
            idle: self.idle + o.idle,
            irq: self.irq + o.irq,
            steal: self.steal + o.steal,
        }
    }

    /// CPU time spent on anything (not idle, not stolen).
    pub fn busy(&self) -> f64 {
        self.user + self.system + self.irq
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn machine_stat_reads_the_cpu_line_by_kind() {
        // SAFETY: sysconf has no preconditions.
        let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) } as f64;
        let s = MachineStat::parse("cpu  100 20 30 400 5 6 7 8 0 0\ncpu0 1 2 3 4 5 6 7 8 0 0\n");
        let close = |a: f64, ticks: f64| (a - ticks / hz).abs() < 1e-9;
        assert!(close(s.user, 120.0), "{s:?}");
        assert!(close(s.system, 30.0) && close(s.idle, 405.0) && close(s.irq, 13.0) && close(s.steal, 8.0));
        assert!(close(s.busy(), 163.0), "{s:?}");
        let later = MachineStat::parse("cpu  200 20 30 500 5 6 7 8 0 0\n");
        assert!(close(later.since(&s).user, 100.0) && close(later.since(&s).idle, 100.0));
        assert!(close(s.plus(&later).user, 340.0));
        assert_eq!(MachineStat::parse("garbage"), MachineStat::default());
        let now = MachineStat::read();
        assert!(now.busy() + now.idle > 0.0 || std::fs::metadata("/proc/stat").is_err());
    }

    #[test]
    fn own_cpu_time_grows_with_work() {
        let c0 = cpu_secs("self");
        let t0 = Instant::now();
        let mut x = 0u64;
        while t0.elapsed() < Duration::from_millis(200) {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1);
        }
        std::hint::black_box(x);
        assert!(cpu_secs("self") - c0 > 0.05);
    }

    #[test]
    fn schedstat_of_this_test_thread_counts_run_time() {
        let name = std::thread::current().name().unwrap_or("").to_string();
        // The test harness names threads after the test; /proc truncates names to 15 bytes.
        let prefix: String = name.chars().take(15).collect();
        let s0 = SchedStat::read(std::process::id(), &prefix);
        let t0 = Instant::now();
        let mut x = 1u64;
        while t0.elapsed() < Duration::from_millis(100) {
            x = x.rotate_left(7) ^ 0x9e37;
        }
        std::hint::black_box(x);
        let s = SchedStat::read(std::process::id(), &prefix).since(&s0);
        if prefix.is_empty() || std::fs::metadata("/proc/self/task").is_err() {
            println!("skipped: no named thread or no /proc");
            return;
        }
        assert!(s.run > 0.02, "{s:?}");
    }
}

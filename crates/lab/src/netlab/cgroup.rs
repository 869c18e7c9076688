//! cgroup v1 CPU quotas: a "slow PC" is a process limited to a share of a core.
//!
//! The quota is enforced per CFS period; a short period (a few ms) makes the
//! throttling smooth at the scale of one frame instead of letting a process run
//! flat out for 100 ms and then stall for 500. The kernel wants the quota to be
//! at least 1 ms, so the period is lengthened for small shares
//! ([`period_for_share`]).

use super::PREFIX;
use anyhow::Context;
use std::path::{Path, PathBuf};

/// Where the cgroup v1 `cpu` controller is mounted.
pub const CPU_ROOT: &str = "/sys/fs/cgroup/cpu";

/// Preferred CFS period, µs.
pub const PERIOD_US: u64 = 5_000;

/// Smallest quota the kernel accepts, µs.
pub const MIN_QUOTA_US: u64 = 1_000;

/// The CFS weight (`cpu.shares`) of a plain process at nice 0, and of a new cgroup.
pub const PLAIN_WEIGHT: u64 = 1024;

/// Checks that cgroup v1 CPU quotas can be set here.
pub fn probe() -> Result<(), String> {
    let root = Path::new(CPU_ROOT);
    if !root.join("cpu.cfs_quota_us").exists() {
        return Err(format!("no cgroup v1 cpu controller at {CPU_ROOT}"));
    }
    let test = root.join(format!("{PREFIX}probe-{}", std::process::id()));
    std::fs::create_dir(&test).map_err(|e| format!("cannot create a cgroup under {CPU_ROOT}: {e}"))?;
    let ok = std::fs::write(test.join("cpu.cfs_period_us"), PERIOD_US.to_string())
        .and_then(|_| std::fs::write(test.join("cpu.cfs_quota_us"), MIN_QUOTA_US.to_string()))
        .map_err(|e| format!("cannot set a CFS quota: {e}"));
    let _ = std::fs::remove_dir(&test);
    ok
}

/// `(period, quota)` in µs for `share` of a core: [`PERIOD_US`], or longer so
/// that the quota is at least [`MIN_QUOTA_US`].
pub fn period_for_share(share: f64) -> (u64, u64) {
    let share = share.clamp(1e-3, 64.0);
    let period = PERIOD_US.max((MIN_QUOTA_US as f64 / share).ceil() as u64);
    (period, ((period as f64 * share).round() as u64).max(MIN_QUOTA_US))
}

/// A CPU cgroup with a quota; removed (after killing its processes) on drop.
#[derive(Debug)]
pub struct CpuCgroup {
    name: String,
    dir: PathBuf,
    /// CFS period, µs.
    pub period_us: u64,
    /// CFS quota per period, µs.
    pub quota_us: u64,
}

impl CpuCgroup {
    /// Creates the group `PREFIX` + `name` (replacing a leftover of that name),
    /// registered for removal, with no settings written yet.
    fn make(name: &str) -> anyhow::Result<CpuCgroup> {
        let name = format!("{PREFIX}{name}");
        let dir = Path::new(CPU_ROOT).join(&name);
        if dir.exists() {
            remove(&name);
        }
        std::fs::create_dir(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
        super::register_cgroup(&name);
        Ok(CpuCgroup { name, dir, period_us: 0, quota_us: 0 })
    }

    /// Creates `PREFIX` + `name` with `share` of a core.
    pub fn create(name: &str, share: f64) -> anyhow::Result<CpuCgroup> {
        let mut cg = Self::make(name)?;
        let (period, quota) = period_for_share(share);
        // Quota off first: a new period must not conflict with an old quota.
        cg.write("cpu.cfs_quota_us", "-1")?;
        cg.write("cpu.cfs_period_us", &period.to_string())?;
        cg.write("cpu.cfs_quota_us", &quota.to_string())?;
        (cg.period_us, cg.quota_us) = (period, quota);
        Ok(cg)
    }

    /// Creates `PREFIX` + `name` with no quota (for the master: its CPU is not
    /// limited, only weighted, see [`CpuCgroup::set_weight`]).
    pub fn unlimited(name: &str) -> anyhow::Result<CpuCgroup> {
        let cg = Self::make(name)?;
        cg.write("cpu.cfs_quota_us", "-1")?;
        Ok(cg)
    }

    /// Sets the cgroup's CFS weight (`cpu.shares`; a plain process weighs
    /// [`PLAIN_WEIGHT`]). A heavy weight makes a runnable process of the cgroup
    /// win the CPU against other load on the machine — the quota still caps it
    /// — so that an emulated PC gets its share of a core as a real one would.
    pub fn set_weight(&self, shares: u64) -> anyhow::Result<()> {
        self.write("cpu.shares", &shares.clamp(2, 262_144).to_string())
    }

    /// The cgroup's CFS weight (`cpu.shares`), if readable.
    #[cfg(test)]
    pub fn weight(&self) -> Option<u64> {
        std::fs::read_to_string(self.dir.join("cpu.shares")).ok()?.trim().parse().ok()
    }

    fn write(&self, file: &str, value: &str) -> anyhow::Result<()> {
        let p = self.dir.join(file);
        std::fs::write(&p, value).with_context(|| format!("cannot write {value} to {}", p.display()))
    }

    /// The share of a core the quota grants.
    pub fn share(&self) -> f64 {
        self.quota_us as f64 / self.period_us as f64
    }

    /// The `cgroup.procs` file: write a process id there to move the process in.
    pub fn procs_file(&self) -> PathBuf {
        self.dir.join("cgroup.procs")
    }

    /// Moves process `pid` (all its threads) into the cgroup.
    #[cfg(test)]
    pub fn add(&self, pid: u32) -> anyhow::Result<()> {
        self.write("cgroup.procs", &pid.to_string())
    }

    /// Throttling so far: `(periods throttled, total µs throttled)` from `cpu.stat`.
    pub fn throttled(&self) -> (u64, f64) {
        let stat = std::fs::read_to_string(self.dir.join("cpu.stat")).unwrap_or_default();
        let field = |k: &str| {
            stat.lines()
                .find_map(|l| l.strip_prefix(k).and_then(|v| v.trim().parse::<u64>().ok()))
                .unwrap_or(0)
        };
        (field("nr_throttled "), field("throttled_time ") as f64 / 1e3)
    }
}

impl Drop for CpuCgroup {
    fn drop(&mut self) {
        remove(&self.name);
    }
}

/// Names of the cgroups directly under [`CPU_ROOT`].
pub fn list() -> Vec<String> {
    std::fs::read_dir(CPU_ROOT)
        .map(|d| {
            d.filter_map(Result::ok)
                .filter(|e| e.path().is_dir())
                .filter_map(|e| e.file_name().into_string().ok())
                .collect()
        })
        .unwrap_or_default()
}

/// Kills the processes in cgroup `name` and removes it (best effort).
pub fn remove(name: &str) {
    let dir = Path::new(CPU_ROOT).join(name);
    for _ in 0..50 {
        let procs = std::fs::read_to_string(dir.join("cgroup.procs")).unwrap_or_default();
        let pids: Vec<libc::pid_t> = procs.split_whitespace().filter_map(|p| p.parse().ok()).collect();
        if pids.is_empty() {
            break;
        }
        for pid in pids {
            // SAFETY: kill has no memory preconditions; these are the lab's processes.
            unsafe { libc::kill(pid, libc::SIGKILL) };
        }
        // Killed processes leave the cgroup once reaped; wait a moment for that.
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    if dir.exists()
        && let Err(e) = std::fs::remove_dir(&dir)
    {
        tracing::warn!("cannot remove cgroup {}: {e}", dir.display());
    }
    super::unregister_cgroup(name);
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::{Duration, Instant};

    #[test]
    fn small_shares_get_a_longer_period_and_the_minimum_quota() {
        assert_eq!(period_for_share(0.5), (PERIOD_US, PERIOD_US / 2));
        let (p, q) = period_for_share(1.0 / 12.0);
        assert!(q >= MIN_QUOTA_US && p > PERIOD_US, "{p} {q}");
        assert!((q as f64 / p as f64 - 1.0 / 12.0).abs() < 0.01);
    }

    /// Root only: a busy process in a cgroup with a 10 % quota gets about 10 % of a core.
    #[test]
    fn quota_limits_a_busy_process() {
        if let Err(e) = crate::netlab::Support::probe().cpu_quota {
            println!("skipped: CPU quotas unavailable ({e})");
            return;
        }
        let _serial = crate::netlab::tests_lock();
        let cg = CpuCgroup::create("test-quota", 0.1).unwrap();
        // (Only this test's own cgroup is touched: a running bench's are left alone.)
        let mut child = std::process::Command::new("sh").args(["-c", "while :; do :; done"]).spawn().unwrap();
        cg.add(child.id()).unwrap();
        let stat = format!("/proc/{}/stat", child.id());
        // utime + stime in clock ticks (fields 14 and 15; the name before them has no spaces here).
        let cpu = || {
            let s = std::fs::read_to_string(&stat).unwrap();
            let f: Vec<f64> = s.split_whitespace().skip(13).take(2).map(|x| x.parse().unwrap()).collect();
            // SAFETY: sysconf has no preconditions.
            (f[0] + f[1]) / unsafe { libc::sysconf(libc::_SC_CLK_TCK) } as f64
        };
        let (t0, c0) = (Instant::now(), cpu());
        // Measure over a fixed wall span: polling the clock, not sleeping to synchronise.
        while t0.elapsed() < Duration::from_millis(600) {
            std::thread::sleep(Duration::from_millis(20));
        }
        let used = (cpu() - c0) / t0.elapsed().as_secs_f64();
        let (nr, _) = cg.throttled();
        child.kill().unwrap();
        child.wait().unwrap();
        assert!(used < 0.2, "quota 0.1 core, used {used:.2}");
        assert!(nr > 0, "the busy loop should have been throttled");
        assert_eq!(cg.weight(), Some(PLAIN_WEIGHT));
        cg.set_weight(8 * PLAIN_WEIGHT).unwrap();
        assert_eq!(cg.weight(), Some(8 * PLAIN_WEIGHT));
        drop(cg);
        assert!(!list().contains(&format!("{PREFIX}test-quota")));
    }
}

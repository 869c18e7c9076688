//! Resident memory of the soak's processes over time, and whether it grew.
//!
//! The rule for "flat": the peak of the last quarter of the run is at most
//! the peak of the second quarter plus 10 % plus 4 MiB. Peaks, not means,
//! because restarted processes begin small again: a restart dips the curve,
//! it does not make it grow. The first quarter is left out (warm-up: caches,
//! scenes loaded, buffers grown to their working size).

use serde::Serialize;

/// One reading.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Sample {
    /// Seconds from the start of the soak.
    pub t: f64,
    /// Resident set size, KiB.
    pub kib: u64,
}

/// `VmRSS` of a `/proc/PID/status` text, KiB.
pub fn parse_vmrss(status: &str) -> Option<u64> {
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// `VmRSS` of process `pid` (`None` once it is gone).
pub fn read_kib(pid: u32) -> Option<u64> {
    parse_vmrss(&std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?)
}

/// Slack of the rule, KiB.
pub const SLACK_KIB: u64 = 4 * 1024;
/// Growth the rule allows, as a fraction of the second quarter's peak.
pub const GROWTH: f64 = 0.10;

/// One process's memory over the run.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RssSummary {
    /// Which process (`master`, `slave pc1`, …).
    pub process: String,
    /// Readings taken.
    pub samples: usize,
    /// First, last and largest readings, MiB.
    pub first_mib: f64,
    pub last_mib: f64,
    pub max_mib: f64,
    /// Peaks of the second and the last quarter of the run, MiB.
    pub second_quarter_peak_mib: f64,
    pub last_quarter_peak_mib: f64,
    /// The last quarter's peak within the rule.
    pub flat: bool,
}

/// Summarises `samples` of a run of `run_secs` seconds. A run without
/// readings in both quarters is called flat (nothing says it grew).
pub fn summarize(process: &str, samples: &[Sample], run_secs: f64) -> RssSummary {
    let mib = |k: u64| k as f64 / 1024.0;
    let peak = |lo: f64, hi: f64| samples.iter().filter(|s| s.t >= lo && s.t <= hi).map(|s| s.kib).max();
    let q = run_secs / 4.0;
    let (second, last) = (peak(q, 2.0 * q), peak(3.0 * q, f64::INFINITY));
    let flat = match (second, last) {
        (Some(s), Some(l)) => l as f64 <= s as f64 * (1.0 + GROWTH) + SLACK_KIB as f64,
        _ => true,
    };
    RssSummary {
        process: process.to_string(),
        samples: samples.len(),
        first_mib: samples.first().map_or(0.0, |s| mib(s.kib)),
        last_mib: samples.last().map_or(0.0, |s| mib(s.kib)),
        max_mib: samples.iter().map(|s| mib(s.kib)).fold(0.0, f64::max),
        second_quarter_peak_mib: second.map_or(0.0, mib),
        last_quarter_peak_mib: last.map_or(0.0, mib),
        flat,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(f: impl Fn(f64) -> u64) -> Vec<Sample> {
        (0..=100).map(|i| Sample { t: i as f64, kib: f(i as f64) }).collect()
    }

    #[test]
    fn vmrss_is_read_from_proc_status() {
        let text = "Name:\tisin\nVmPeak:\t  9000 kB\nVmRSS:\t   12345 kB\nThreads:\t4\n";
        assert_eq!(parse_vmrss(text), Some(12345));
        assert_eq!(parse_vmrss("Name: x\n"), None);
        assert!(read_kib(std::process::id()).is_some_and(|k| k > 0));
    }

    #[test]
    fn steady_memory_and_restart_dips_are_flat() {
        assert!(summarize("m", &run(|_| 50_000), 100.0).flat);
        // Restarted every 20 s: back to 20 MiB, grows to 50 MiB within seconds.
        let restarts = run(|t| if t % 20.0 < 2.0 { 20_000 } else { 50_000 });
        let s = summarize("m", &restarts, 100.0);
        assert!(s.flat, "{s:?}");
        assert_eq!((s.first_mib * 1024.0) as u64, 20_000);
        // Warm-up growth in the first quarter does not count.
        assert!(
            summarize("m", &run(|t| if t < 20.0 { 10_000 + 2_000 * t as u64 } else { 50_000 }), 100.0).flat
        );
    }

    #[test]
    fn growth_across_the_run_is_not_flat() {
        // 1 MiB every 2 s: 25 MiB more at the end than mid-run.
        let s = summarize("slave", &run(|t| 40_000 + 512 * t as u64), 100.0);
        assert!(!s.flat, "{s:?}");
        assert!(s.last_quarter_peak_mib > s.second_quarter_peak_mib);
        // Within 10 % + 4 MiB is flat.
        let small = summarize("slave", &run(|t| 40_000 + 40 * t as u64), 100.0);
        assert!(small.flat, "{small:?}");
        assert!(summarize("none", &[], 100.0).flat);
    }
}

//! Timing summaries for frame times and latencies (median, p95) as printed by
//! `isin fly` and `isin view --play`.

use std::time::Duration;

/// Order statistics of a set of durations (nearest-rank percentiles).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Summary {
    /// Number of samples.
    pub count: usize,
    /// 50th percentile.
    pub median: Duration,
    /// 95th percentile.
    pub p95: Duration,
    /// Largest sample.
    pub max: Duration,
    /// Sum of all samples.
    pub total: Duration,
}

impl Summary {
    /// Summarises `times` (all zero for an empty set).
    pub fn of(times: &[Duration]) -> Self {
        let mut sorted = times.to_vec();
        sorted.sort();
        let rank = |p: f64| -> Duration {
            if sorted.is_empty() {
                return Duration::ZERO;
            }
            let k = ((p * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
            sorted[k - 1]
        };
        Summary {
            count: sorted.len(),
            median: rank(0.5),
            p95: rank(0.95),
            max: rank(1.0),
            total: sorted.iter().sum(),
        }
    }

    /// Samples per second of summed time (frames per second for frame times).
    pub fn rate(&self) -> f64 {
        if self.total.is_zero() { 0.0 } else { self.count as f64 / self.total.as_secs_f64() }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank_percentiles() {
        let t: Vec<Duration> = (1..=20).rev().map(Duration::from_millis).collect();
        let s = Summary::of(&t);
        assert_eq!(s.median, Duration::from_millis(10));
        assert_eq!(s.p95, Duration::from_millis(19));
        assert_eq!(s.max, Duration::from_millis(20));
        assert_eq!(s.count, 20);
        assert!((s.rate() - 20.0 / 0.210).abs() < 1e-9);
        let e = Summary::of(&[]);
        assert_eq!((e.median, e.rate()), (Duration::ZERO, 0.0));
    }
}

//! The chaos soak's fault schedule: drawn from a seeded generator, so that a
//! run can be repeated fault for fault (`--seed`).
//!
//! Faults come one after another, each followed by time to settle: every
//! fault is over (the process restarted, the link restored) before the next
//! begins, and a master restart is given the clients' and slaves' reconnection
//! backoff (up to 5 s) before anything else happens. Kinds are drawn from
//! shuffled bags holding every kind once, so that any run long enough for one
//! bag (a 60-second one is) injects every kind.

use serde::Serialize;

/// What a fault does.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum FaultKind {
    /// `kill -9` of a slave, restarted after a while.
    SlaveKill,
    /// SIGSTOP of a slave, SIGCONT after a while (past the heartbeat timeout
    /// or not).
    SlaveStop,
    /// `kill -9` of the master, restarted after a while with the same
    /// identity, state and token.
    MasterKill,
    /// A slave's cable unplugged and plugged back.
    LinkDown,
    /// 1–10 % of a slave's packets dropped, both ways, for a while.
    Loss,
    /// A slave's cable holding every packet for 50–500 ms (without netem, the
    /// packets are dropped and the transports deliver them late, retransmitted).
    DelaySpike,
}

impl FaultKind {
    /// Every kind, in a fixed order.
    pub const ALL: [FaultKind; 6] = [
        FaultKind::SlaveKill,
        FaultKind::SlaveStop,
        FaultKind::MasterKill,
        FaultKind::LinkDown,
        FaultKind::Loss,
        FaultKind::DelaySpike,
    ];

    /// In plain words, for the report.
    pub fn describe(self) -> &'static str {
        match self {
            FaultKind::SlaveKill => "slave killed (-9) and restarted",
            FaultKind::SlaveStop => "slave stopped (SIGSTOP) and continued",
            FaultKind::MasterKill => "master killed (-9) and restarted",
            FaultKind::LinkDown => "slave link down and up",
            FaultKind::Loss => "packet loss on a slave link",
            FaultKind::DelaySpike => "delay spike on a slave link",
        }
    }

    /// Seconds the fault lasts: the time down, stopped, unplugged, lossy or held.
    fn draw_secs(self, rng: &mut Rng) -> f64 {
        match self {
            FaultKind::SlaveKill => rng.range(0.5, 3.0),
            FaultKind::SlaveStop => rng.range(1.0, 8.0),
            FaultKind::MasterKill => rng.range(0.5, 2.0),
            FaultKind::LinkDown => rng.range(1.0, 6.0),
            FaultKind::Loss => rng.range(3.0, 10.0),
            FaultKind::DelaySpike => rng.range(0.05, 0.5),
        }
    }

    /// Seconds left after the fault is over before the next one begins.
    fn settle(self, rng: &mut Rng) -> f64 {
        match self {
            // Slaves and clients reconnect with a backoff of up to 5 s.
            FaultKind::MasterKill => 5.0 + rng.range(0.0, 1.0),
            _ => rng.range(1.5, 3.0),
        }
    }
}

/// One planned fault.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Fault {
    /// Seconds from the start of the soak.
    pub at: f64,
    /// What it does.
    pub kind: FaultKind,
    /// The slave it hits (0-based), for the kinds that hit one.
    pub slave: Option<usize>,
    /// How long it lasts, seconds.
    pub secs: f64,
    /// Packets dropped per 1000, for [`FaultKind::Loss`].
    pub loss_per_mille: u32,
}

/// Seconds at the start of a soak without faults (the cluster warms up).
pub const WARMUP: f64 = 4.0;
/// Seconds at the end of a soak without faults (the last frames complete).
pub const QUIET_END: f64 = 6.0;

/// The faults of a soak of `seconds` with `slaves` slaves, from `seed`: in
/// time order, none overlapping, all over by `seconds - QUIET_END`.
pub fn schedule(seed: u64, seconds: f64, slaves: usize) -> Vec<Fault> {
    let mut rng = Rng::new(seed);
    let end = seconds - QUIET_END;
    let mut out = Vec::new();
    let mut bag: Vec<FaultKind> = Vec::new();
    let mut t = WARMUP;
    loop {
        if bag.is_empty() {
            bag = FaultKind::ALL.to_vec();
            rng.shuffle(&mut bag);
        }
        let kind = bag[bag.len() - 1];
        let secs = kind.draw_secs(&mut rng);
        if t + secs > end {
            break;
        }
        bag.pop();
        let slave = (kind != FaultKind::MasterKill && slaves > 0).then(|| rng.below(slaves));
        let loss_per_mille = if kind == FaultKind::Loss { 10 + rng.below(91) as u32 } else { 0 };
        out.push(Fault { at: t, kind, slave, secs, loss_per_mille });
        t += secs + kind.settle(&mut rng);
    }
    out
}

/// SplitMix64: small, seeded, the same numbers on every machine.
pub struct Rng(u64);

impl Rng {
    /// A generator from `seed`.
    pub fn new(seed: u64) -> Rng {
        Rng(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    /// Uniform in 0..n (n ≥ 1).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }

    /// Fisher–Yates.
    pub fn shuffle<T>(&mut self, v: &mut [T]) {
        for i in (1..v.len()).rev() {
            v.swap(i, self.below(i + 1));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_same_seed_gives_the_same_schedule_and_another_seed_another() {
        assert_eq!(schedule(7, 300.0, 4), schedule(7, 300.0, 4));
        assert_ne!(schedule(7, 300.0, 4), schedule(8, 300.0, 4));
    }

    #[test]
    fn a_minute_injects_every_kind_and_faults_never_overlap() {
        for seed in 0..500 {
            let s = schedule(seed, 60.0, 4);
            for kind in FaultKind::ALL {
                assert!(s.iter().any(|f| f.kind == kind), "seed {seed}: no {kind:?} in {s:?}");
            }
            for w in s.windows(2) {
                assert!(w[0].at + w[0].secs < w[1].at, "seed {seed}: {w:?} overlap");
            }
            let last = s.last().unwrap();
            assert!(s[0].at >= WARMUP && last.at + last.secs <= 60.0 - QUIET_END, "seed {seed}");
        }
    }

    #[test]
    fn faults_stay_within_their_ranges() {
        let s = schedule(3, 1800.0, 4);
        assert!(s.len() > 200, "{} faults in 30 minutes", s.len());
        for f in &s {
            match f.kind {
                FaultKind::MasterKill => assert_eq!(f.slave, None),
                _ => assert!(f.slave.is_some_and(|i| i < 4), "{f:?}"),
            }
            if f.kind == FaultKind::Loss {
                assert!((10..=100).contains(&f.loss_per_mille), "{f:?}");
            } else {
                assert_eq!(f.loss_per_mille, 0);
            }
            if f.kind == FaultKind::DelaySpike {
                assert!((0.05..0.5).contains(&f.secs), "{f:?}");
            }
        }
        // A master restart is followed by the reconnection backoff.
        for w in s.windows(2).filter(|w| w[0].kind == FaultKind::MasterKill) {
            assert!(w[1].at - (w[0].at + w[0].secs) >= 5.0, "{w:?}");
        }
    }

    #[test]
    fn too_short_a_soak_has_no_faults() {
        assert!(schedule(1, WARMUP + QUIET_END, 4).is_empty());
    }

    #[test]
    fn rng_draws_within_bounds() {
        let mut r = Rng::new(1);
        for _ in 0..1000 {
            let x = r.range(2.0, 3.0);
            assert!((2.0..3.0).contains(&x));
            assert!(r.below(5) < 5);
        }
        let mut v: Vec<u32> = (0..10).collect();
        r.shuffle(&mut v);
        let mut sorted = v.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..10).collect::<Vec<_>>());
    }
}

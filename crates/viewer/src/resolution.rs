//! Dynamic resolution while moving: how much smaller the first pass after a
//! move is rendered, chosen from the measured times of recent fast passes so
//! that moving frames hold a target frame rate.
//!
//! A [`Divisor`] shrinks the image in each direction (in steps of ¼, so 1.5 or
//! 2.5 are possible); the [`Controller`] picks one from a ladder of divisors
//! between its bounds. It only sees pass times and pixel counts, never a clock,
//! so it is deterministic for a given sequence of measurements and its choice
//! only ever changes the *settings* of a request (width and height), not how
//! the tracer renders a pixel.
//!
//! The cost model is a cost per pixel (median of the last few fast passes, any
//! size): the predicted time of a divisor is that cost times its pixel count.
//! Hysteresis keeps the size from flickering:
//!
//! - coarser when the current size is predicted to take longer than
//!   [`HIGH`] × the budget, straight to the finest size predicted to fit the
//!   budget (several steps at once after a slow frame);
//! - finer by one step only when that finer size is predicted to take less
//!   than [`LOW`] × the budget, and only after [`SETTLE_FINER`] passes at the
//!   current size;
//! - since the ladder's steps are fine (1.3–1.6× in pixels) and the two
//!   thresholds far apart, a constant cost settles on one size and stays.

use std::collections::VecDeque;
use std::fmt;
use std::str::FromStr;
use std::time::Duration;

/// A resolution divisor: the image is rendered at `1/d` of the full size in
/// each direction. Stored in quarter steps (`quarters / 4`), at least 1.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Divisor(u32);

impl Divisor {
    /// Full resolution.
    pub const ONE: Divisor = Divisor(4);

    /// The divisor `quarters / 4` (at least 1).
    pub fn from_quarters(quarters: u32) -> Self {
        Divisor(quarters.max(4))
    }

    /// The integer divisor `n` (at least 1).
    pub fn whole(n: u32) -> Self {
        Divisor::from_quarters(n.saturating_mul(4))
    }

    /// The divisor in quarter steps.
    pub fn quarters(self) -> u32 {
        self.0
    }

    /// The divisor as a number.
    pub fn get(self) -> f32 {
        self.0 as f32 / 4.0
    }

    /// True for full resolution.
    pub fn is_one(self) -> bool {
        self.0 == 4
    }

    /// Size of a `width × height` image divided by this divisor: each side
    /// rounded to the nearest pixel, at least 1 (integer arithmetic only).
    pub fn apply(self, width: u32, height: u32) -> (u32, u32) {
        let q = self.0 as u64;
        let side = |n: u32| (((n as u64 * 4 + q / 2) / q).max(1)).min(n.max(1) as u64) as u32;
        (side(width), side(height))
    }
}

impl Default for Divisor {
    fn default() -> Self {
        Divisor::ONE
    }
}

impl fmt::Display for Divisor {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let frac = ["", ".25", ".5", ".75"][(self.0 % 4) as usize];
        write!(f, "{}{}", self.0 / 4, frac)
    }
}

/// Why a divisor could not be parsed.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("a resolution divisor is a number from 1 to {max} in steps of 0.25 (e.g. 2 or 2.5), not {0:?}", max = MAX_DIVISOR)]
pub struct DivisorError(String);

/// The largest divisor accepted anywhere.
pub const MAX_DIVISOR: u32 = 16;

impl FromStr for Divisor {
    type Err = DivisorError;

    /// Parses `2`, `2.5`, `1.25`… (multiples of 0.25 from 1 to [`MAX_DIVISOR`]).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let err = || DivisorError(s.to_string());
        let (whole, frac) = s.trim().split_once('.').unwrap_or((s.trim(), ""));
        let whole: u32 = whole.parse().map_err(|_| err())?;
        let quarter = match frac.trim_end_matches('0') {
            "" => 0,
            "25" => 1,
            "5" => 2,
            "75" => 3,
            _ => return Err(err()),
        };
        let q = whole.checked_mul(4).and_then(|w| w.checked_add(quarter)).ok_or_else(err)?;
        if !(4..=MAX_DIVISOR * 4).contains(&q) {
            return Err(err());
        }
        Ok(Divisor(q))
    }
}

/// The divisors the controller chooses from (in quarters): steps of 1.3–1.6×
/// in pixel count.
const LADDER: [u32; 13] = [4, 5, 6, 7, 8, 10, 12, 14, 16, 20, 24, 28, 32];

/// Go coarser when the current size is predicted to exceed this share of the budget.
pub const HIGH: f64 = 1.05;
/// Go finer when the next finer size is predicted to stay under this share of the budget.
pub const LOW: f64 = 0.75;
/// Passes at a size before going finer again.
pub const SETTLE_FINER: u32 = 3;
/// Passes at a size before going coarser again (one slow frame is not enough).
pub const SETTLE_COARSER: u32 = 2;
/// Fast passes the cost estimate remembers.
const HISTORY: usize = 5;
/// Share of a frame's period the render may take: the rest is for the
/// window, the network and the next request.
const HEADROOM: f64 = 0.85;

/// How the first pass after a move is sized.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MovingResolution {
    /// Always this divisor (`--moving-scale`).
    Fixed(Divisor),
    /// Chosen by a [`Controller`] to hold `target_fps`, between `min` and `max`.
    Dynamic {
        /// Frames per second to hold while moving.
        target_fps: f32,
        /// Finest divisor allowed.
        min: Divisor,
        /// Coarsest divisor allowed.
        max: Divisor,
    },
}

impl MovingResolution {
    /// Dynamic, holding `target_fps` with divisors from 1 to 8.
    pub fn dynamic(target_fps: f32) -> Self {
        MovingResolution::Dynamic { target_fps, min: Divisor::ONE, max: Divisor::whole(8) }
    }
}

impl Default for MovingResolution {
    /// Dynamic at 30 frames per second.
    fn default() -> Self {
        MovingResolution::dynamic(30.0)
    }
}

/// Picks the divisor of moving passes from measured pass times.
#[derive(Clone, Debug)]
pub struct Controller {
    width: u32,
    height: u32,
    /// Fixed divisor, or the ladder to choose from.
    ladder: Vec<Divisor>,
    /// Render time a moving pass may take, in seconds.
    budget: f64,
    /// Position in `ladder`; `None` until the first measurement.
    index: Option<usize>,
    /// Seconds per pixel of recent fast passes, oldest first.
    costs: VecDeque<f64>,
    /// Measurements since the divisor last changed.
    since_change: u32,
}

impl Controller {
    /// A controller for a `width × height` image.
    pub fn new(mode: MovingResolution, width: u32, height: u32) -> Self {
        let (ladder, fps) = match mode {
            MovingResolution::Fixed(d) => (vec![d], 1.0),
            MovingResolution::Dynamic { target_fps, min, max } => {
                let (lo, hi) = (min.min(max), min.max(max));
                let mut ladder: Vec<Divisor> =
                    LADDER.iter().map(|&q| Divisor(q)).filter(|d| (lo..=hi).contains(d)).collect();
                if ladder.is_empty() {
                    ladder.push(lo);
                }
                (ladder, target_fps)
            }
        };
        let fps = if fps.is_finite() && fps > 0.0 { fps as f64 } else { 30.0 };
        let index = (ladder.len() == 1).then_some(0);
        Self { width, height, ladder, budget: HEADROOM / fps, index, costs: VecDeque::new(), since_change: 0 }
    }

    /// Sizes the passes for a `width × height` image from now on (the window
    /// was resized). The measured cost per pixel still holds, so the divisor
    /// for the new size is chosen from it at the next measurement.
    pub fn resize(&mut self, width: u32, height: u32) {
        (self.width, self.height) = (width, height);
        self.since_change = SETTLE_COARSER.max(SETTLE_FINER);
    }

    /// The divisor for the next moving pass: the finest allowed until
    /// something was measured.
    pub fn divisor(&self) -> Divisor {
        self.ladder[self.index.unwrap_or(0)]
    }

    /// The render time a moving pass aims for.
    pub fn budget(&self) -> Duration {
        Duration::from_secs_f64(self.budget)
    }

    /// True when the divisor adapts (not `--moving-scale`).
    pub fn is_dynamic(&self) -> bool {
        self.ladder.len() > 1
    }

    fn pixels(&self, i: usize) -> f64 {
        let (w, h) = self.ladder[i].apply(self.width, self.height);
        w as f64 * h as f64
    }

    /// Median seconds per pixel of the remembered passes.
    fn cost(&self) -> Option<f64> {
        let mut c: Vec<f64> = self.costs.iter().copied().collect();
        c.sort_by(f64::total_cmp);
        let n = c.len();
        match n {
            0 => None,
            _ if n % 2 == 1 => Some(c[n / 2]),
            _ => Some((c[n / 2 - 1] + c[n / 2]) / 2.0),
        }
    }

    /// The finest ladder position at or after `from` predicted to fit the budget.
    fn finest_fitting(&self, from: usize, cost: f64) -> usize {
        (from..self.ladder.len())
            .find(|&i| cost * self.pixels(i) <= self.budget)
            .unwrap_or(self.ladder.len() - 1)
    }

    /// Takes the render time of a fast pass (1 sample, 1 shadow ray) of
    /// `width × height` pixels, at any divisor, and updates the divisor.
    pub fn observe(&mut self, width: u32, height: u32, elapsed: Duration) {
        let pixels = width as f64 * height as f64;
        let secs = elapsed.as_secs_f64();
        if pixels < 1.0 || !secs.is_finite() {
            return;
        }
        self.costs.push_back(secs / pixels);
        while self.costs.len() > HISTORY {
            self.costs.pop_front();
        }
        self.since_change = self.since_change.saturating_add(1);
        if !self.is_dynamic() {
            return;
        }
        let Some(cost) = self.cost() else { return };
        let next = match self.index {
            None => self.finest_fitting(0, cost),
            Some(i) if self.since_change >= SETTLE_COARSER && cost * self.pixels(i) > HIGH * self.budget => {
                self.finest_fitting(i, cost)
            }
            Some(i)
                if i > 0
                    && self.since_change >= SETTLE_FINER
                    && cost * self.pixels(i - 1) < LOW * self.budget =>
            {
                i - 1
            }
            Some(i) => i,
        };
        if self.index != Some(next) {
            if let Some(i) = self.index {
                tracing::debug!("moving resolution 1/{} -> 1/{}", self.ladder[i], self.ladder[next]);
            }
            self.index = Some(next);
            self.since_change = 0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: u32 = 640;
    const H: u32 = 480;

    fn ms(v: f64) -> Duration {
        Duration::from_secs_f64(v / 1e3)
    }

    /// A renderer whose time is `fixed` ms plus `per_mpx` ms per million pixels.
    fn time(d: Divisor, fixed: f64, per_mpx: f64) -> Duration {
        let (w, h) = d.apply(W, H);
        ms(fixed + per_mpx * (w as f64 * h as f64) / 1e6)
    }

    /// Runs `n` moving passes against the model; returns the divisors used.
    fn run(c: &mut Controller, n: usize, fixed: f64, per_mpx: f64) -> Vec<Divisor> {
        (0..n)
            .map(|_| {
                let d = c.divisor();
                let (w, h) = d.apply(W, H);
                c.observe(w, h, time(d, fixed, per_mpx));
                d
            })
            .collect()
    }

    #[test]
    fn divisors_parse_print_and_shrink_images() {
        for (s, q, shown) in [("1", 4, "1"), ("2.5", 10, "2.5"), ("1.25", 5, "1.25"), ("3.50", 14, "3.5")] {
            let d: Divisor = s.parse().unwrap();
            assert_eq!(d.quarters(), q, "{s}");
            assert_eq!(d.to_string(), shown);
        }
        for bad in ["0", "0.5", "2.3", "17", "x", "", "-1", "99999999999"] {
            assert!(bad.parse::<Divisor>().is_err(), "{bad:?} accepted");
        }
        assert_eq!(Divisor::ONE.apply(W, H), (W, H));
        assert_eq!(Divisor::whole(2).apply(W, H), (320, 240));
        assert_eq!("2.5".parse::<Divisor>().unwrap().apply(W, H), (256, 192));
        assert_eq!(Divisor::whole(3).apply(W, H), (213, 160));
        assert_eq!(Divisor::whole(4).apply(5, 3), (1, 1), "never empty");
        assert_eq!(Divisor::from_quarters(0), Divisor::ONE);
    }

    #[test]
    fn slow_frames_scale_down_at_once_to_a_size_that_fits() {
        // 213 ms at full resolution (≈ 0.69 µs per pixel): far over 30 fps.
        let mut c = Controller::new(MovingResolution::default(), W, H);
        assert_eq!(c.divisor(), Divisor::ONE, "nothing measured yet");
        c.observe(W, H, ms(213.0));
        let d = c.divisor();
        assert!(d > Divisor::whole(2), "one slow frame is enough to start: {d}");
        let t = time(d, 0.0, 213.0 / 0.3072);
        assert!(t <= c.budget(), "{d} predicted {t:?} over {:?}", c.budget());
    }

    #[test]
    fn fast_frames_scale_back_up_to_full_resolution() {
        let mut c = Controller::new(MovingResolution::default(), W, H);
        c.observe(W, H, ms(213.0));
        assert!(c.divisor() > Divisor::whole(2));
        // The scene got cheap (e.g. looking at the sky): 5 ms at full resolution.
        let used = run(&mut c, 40, 0.0, 5.0 / 0.3072);
        assert_eq!(c.divisor(), Divisor::ONE);
        assert!(used.windows(2).all(|w| w[1] <= w[0]), "monotone on the way up: {used:?}");
        let changes = used.windows(2).filter(|w| w[1] != w[0]).count();
        assert!(changes > 1, "one step at a time: {used:?}");
    }

    #[test]
    fn stays_within_bounds() {
        let bounded =
            MovingResolution::Dynamic { target_fps: 30.0, min: Divisor::whole(2), max: Divisor::whole(4) };
        let mut c = Controller::new(bounded, W, H);
        let slow = run(&mut c, 10, 0.0, 10_000.0);
        assert!(slow.iter().all(|&d| d >= Divisor::whole(2) && d <= Divisor::whole(4)), "{slow:?}");
        assert_eq!(c.divisor(), Divisor::whole(4));
        let fast = run(&mut c, 40, 0.0, 0.01);
        assert!(fast.iter().all(|&d| d >= Divisor::whole(2) && d <= Divisor::whole(4)), "{fast:?}");
        assert_eq!(c.divisor(), Divisor::whole(2));
        // The default bounds: 1 to 8.
        let mut d = Controller::new(MovingResolution::default(), W, H);
        run(&mut d, 10, 1000.0, 0.0);
        assert_eq!(d.divisor(), Divisor::whole(8));
    }

    #[test]
    fn a_steady_cost_settles_on_one_size_without_oscillating() {
        // Costs with a fixed overhead (as the cluster has), so the per-pixel
        // model is off by a different amount at every size.
        for (fixed, per_mpx) in [(5.0, 680.0), (0.0, 700.0), (12.0, 300.0), (2.0, 120.0), (1.0, 2000.0)] {
            let mut c = Controller::new(MovingResolution::default(), W, H);
            c.observe(W, H, time(Divisor::ONE, fixed, per_mpx));
            let used = run(&mut c, 60, fixed, per_mpx);
            let tail = &used[20..];
            assert!(tail.iter().all(|&d| d == tail[0]), "({fixed}, {per_mpx}) flickers: {used:?}");
            let changes = used.windows(2).filter(|w| w[1] != w[0]).count();
            assert!(changes <= 4, "({fixed}, {per_mpx}) changed {changes} times: {used:?}");
        }
    }

    #[test]
    fn noise_around_the_budget_does_not_flicker() {
        // ±8 % deterministic jitter on a cost that sits right at one size.
        let mut c = Controller::new(MovingResolution::default(), W, H);
        c.observe(W, H, ms(213.0));
        let mut used = Vec::new();
        for i in 0..80u32 {
            let d = c.divisor();
            let (w, h) = d.apply(W, H);
            let jitter = 1.0 + 0.08 * [0.0, 1.0, -1.0, 0.5, -0.5, 1.0, -1.0][(i % 7) as usize];
            c.observe(w, h, time(d, 4.0 * jitter, 690.0 * jitter));
            used.push(d);
        }
        let changes = used.windows(2).filter(|w| w[1] != w[0]).count();
        assert!(changes <= 2, "{changes} changes: {used:?}");
    }

    #[test]
    fn one_slow_frame_does_not_change_the_size() {
        let mut c = Controller::new(MovingResolution::default(), W, H);
        run(&mut c, 20, 3.0, 300.0);
        let settled = c.divisor();
        let (w, h) = settled.apply(W, H);
        c.observe(w, h, ms(500.0)); // another process took the CPU for a moment
        assert_eq!(c.divisor(), settled);
        run(&mut c, 5, 3.0, 300.0);
        assert_eq!(c.divisor(), settled);
    }

    #[test]
    fn a_fixed_divisor_never_changes() {
        let mut c = Controller::new(MovingResolution::Fixed(Divisor::whole(3)), W, H);
        assert!(!c.is_dynamic());
        assert_eq!(run(&mut c, 5, 1000.0, 0.0), vec![Divisor::whole(3); 5]);
        assert_eq!(run(&mut c, 5, 0.0, 0.0), vec![Divisor::whole(3); 5]);
    }
}

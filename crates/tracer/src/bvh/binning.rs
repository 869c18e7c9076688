//! Binned SAH split search: each primitive's centroid falls into one of [`BINS`]
//! equal slots per axis; one pass fills the bins of all three axes (the bin
//! indices of a centroid are computed at once in one `Vec4`), a sweep over the
//! bin boundaries finds the cheapest split.
//!
//! Large nodes bin fixed-size chunks in parallel and merge them: bin boxes are
//! unions of NaN-free boxes and counts are integers, so merging is exact and
//! the result does not depend on how the chunks were scheduled.

use super::primref::{Box4, PrimRef};
use glam::Vec4;
use rayon::prelude::*;

/// Centroid bins per axis.
pub(super) const BINS: usize = 16;

/// SAH cost of visiting a node, relative to one triangle test.
pub(super) const TRAVERSAL_COST: f32 = 1.0;

/// Nodes with at least this many primitives are binned in parallel chunks.
pub(super) const PARALLEL_MIN: usize = 16 * 1024;

/// Primitives per parallel chunk (fixed, so results never depend on the pool).
pub(super) const CHUNK: usize = 4096;

/// Runs of at least this many primitives are binned into two sets of bins (see `Bins::fill`).
const TWO_SETS_MIN: usize = 64;

const _: () = assert!(BINS.is_power_of_two());

/// Maps centroids to bins for one node.
#[derive(Clone, Copy, Debug)]
pub(super) struct BinMap {
    /// Centroid box's lower corner.
    min: Vec4,
    /// `BINS / extent` per axis; 0 on axes that cannot be binned.
    scale: Vec4,
    /// Axes that can be binned (positive, finite extent with a positive, finite scale).
    ok: [bool; 3],
}

impl BinMap {
    /// The map for a node whose centroids lie in `cent`; `None` when no axis can separate them.
    pub(super) fn new(cent: &Box4) -> Option<BinMap> {
        let mut scale = Vec4::ZERO;
        let mut ok = [false; 3];
        for axis in 0..3 {
            let extent = cent.max[axis] - cent.min[axis];
            let s = BINS as f32 / extent;
            if extent > 0.0 && s.is_finite() && s > 0.0 {
                scale[axis] = s;
                ok[axis] = true;
            }
        }
        ok.iter().any(|&o| o).then_some(BinMap { min: cent.min, scale, ok })
    }

    /// The bins of centroid `c` on the three axes. On a binnable axis `(c − min) ·
    /// scale` is a finite number in about `0..=BINS` (centroids are finite and
    /// within the box, `scale = BINS / extent`): the clamp keeps the maximum (and
    /// rounding overshoots) in the last bin, the same on every machine. On other
    /// axes (scale 0) the value is 0, or NaN when `c − min` overflows; either
    /// way the index stays in range and that axis is never split.
    /// Binning and partitioning both use this, so they always agree.
    #[inline(always)]
    pub(super) fn bins(&self, c: Vec4) -> [usize; 3] {
        let f = ((c - self.min) * self.scale).min(Vec4::splat((BINS - 1) as f32)).max(Vec4::ZERO);
        // `f` is in 0..=BINS-1 on every lane, where truncation is exact both ways.
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::{__m128i, _mm_cvttps_epi32};
            // SAFETY: SSE2 is part of the x86_64 baseline; the conversion only reads a register.
            let i: [i32; 4] = unsafe { std::mem::transmute::<__m128i, [i32; 4]>(_mm_cvttps_epi32(f.into())) };
            [i[0] as usize, i[1] as usize, i[2] as usize]
        }
        #[cfg(not(target_arch = "x86_64"))]
        [f.x as usize, f.y as usize, f.z as usize]
    }

    /// Whether a primitive with centroid `c` goes to the left side of `split`:
    /// exactly `self.bins(c)[split.axis] <= split.bin`, since with `x = (c − min) ·
    /// scale` on the split's axis, `trunc(clamp(x, 0, BINS − 1)) ≤ bin` holds
    /// if and only if `x < bin + 1` (`bin < BINS − 1`; `x` is never NaN on a
    /// binnable axis, see [`BinMap::bins`]). Cheaper: no clamp, conversion or extraction.
    #[inline(always)]
    pub(super) fn goes_left(&self, c: Vec4, split: &Split) -> bool {
        let below = ((c - self.min) * self.scale).cmplt(Vec4::splat((split.bin + 1) as f32));
        below.bitmask() >> split.axis & 1 == 1
    }
}

/// A candidate split: primitives whose centroid falls in bins `0..=bin` of `axis` go left.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Split {
    /// Axis.
    pub axis: usize,
    /// Last bin of the left side.
    pub bin: usize,
    /// SAH cost times the node's area (so zero-area nodes compare without NaNs).
    pub cost: f32,
}

/// The bins of all three axes.
#[derive(Clone, Debug)]
pub(super) struct Bins {
    boxes: [[Box4; BINS]; 3],
    counts: [[u32; BINS]; 3],
}

impl Bins {
    const EMPTY: Bins = Bins { boxes: [[Box4::EMPTY; BINS]; 3], counts: [[0; BINS]; 3] };

    /// Adds one primitive.
    #[inline(always)]
    fn add(&mut self, p: &PrimRef, map: &BinMap) {
        let b = map.bins(p.centroid());
        for (axis, &bin) in b.iter().enumerate() {
            // `bin < BINS` (see `BinMap::bins`); the mask only tells the compiler so.
            let bin = bin & (BINS - 1);
            self.boxes[axis][bin].grow_box(p.min(), p.max());
            self.counts[axis][bin] += 1;
        }
    }

    /// Adds `prims`. Longer runs alternate between two sets of bins merged at
    /// the end: neighbouring primitives often fall in the same bins, and one set
    /// would make each wait for the previous one's store. The merge is exact
    /// (see the module docs), so the bins are those of one set.
    #[inline(always)]
    fn fill(&mut self, prims: &[PrimRef], map: &BinMap) {
        if prims.len() < TWO_SETS_MIN {
            for p in prims {
                self.add(p, map);
            }
            return;
        }
        let mut odd = Bins::EMPTY;
        let mut pairs = prims.chunks_exact(2);
        for pair in &mut pairs {
            self.add(&pair[0], map);
            odd.add(&pair[1], map);
        }
        for p in pairs.remainder() {
            self.add(p, map);
        }
        self.merge_from(&odd);
    }

    fn merge(mut self, o: &Bins) -> Bins {
        self.merge_from(o);
        self
    }

    /// Adds the primitives binned in `o`.
    #[inline(always)]
    fn merge_from(&mut self, o: &Bins) {
        for axis in 0..3 {
            for i in 0..BINS {
                self.boxes[axis][i] = self.boxes[axis][i].union(&o.boxes[axis][i]);
                self.counts[axis][i] += o.counts[axis][i];
            }
        }
    }

    /// The bins of `prims`, binned in parallel chunks (large nodes).
    fn of_par(prims: &[PrimRef], map: &BinMap) -> Bins {
        prims
            .par_chunks(CHUNK)
            .map(|c| {
                let mut bins = Bins::EMPTY;
                bins.fill(c, map);
                bins
            })
            .reduce(|| Bins::EMPTY, |a, b| a.merge(&b))
    }

    /// The cheapest bin-boundary split of `prims` over the binnable axes (ties go
    /// to the lower axis, then the lower bin), or `None` when no boundary has
    /// primitives on both sides.
    pub(super) fn best_split(prims: &[PrimRef], map: &BinMap) -> Option<Split> {
        // Filled in place (not returned from a function): the bins are 1.7 kB.
        let mut bins = Bins::EMPTY;
        if prims.len() >= PARALLEL_MIN {
            bins = Bins::of_par(prims, map);
        } else {
            bins.fill(prims, map);
        }
        let mut best: Option<Split> = None;
        for (axis, found) in sweep3(&bins).into_iter().enumerate() {
            if !map.ok[axis] {
                continue;
            }
            if let Some((bin, cost)) = found {
                if best.is_none_or(|b| cost < b.cost) {
                    best = Some(Split { axis, bin, cost });
                }
            }
        }
        best
    }
}

/// `sweep` of each axis's bins, the three side by side, one vector lane per
/// axis: the same operations on each lane as `sweep` on that axis (see
/// `Box4::area3`), so the same answers, bit for bit (a test compares).
fn sweep3(bins: &Bins) -> [Option<(usize, f32)>; 3] {
    let counts = |i: usize, cnt: &mut [u32; 3]| {
        for (c, axis) in cnt.iter_mut().zip(&bins.counts) {
            *c += axis[i];
        }
        Vec4::new(cnt[0] as f32, cnt[1] as f32, cnt[2] as f32, 0.0)
    };
    let grow = |i: usize, acc: &mut [Box4; 3]| {
        for (a, axis) in acc.iter_mut().zip(&bins.boxes) {
            *a = a.union(&axis[i]);
        }
    };
    // right_cost[i]: area * count of bins i+1.. (NaN where there are none).
    let mut right_cost = [Vec4::NAN; BINS];
    let (mut acc, mut cnt) = ([Box4::EMPTY; 3], [0u32; 3]);
    for i in (1..BINS).rev() {
        grow(i, &mut acc);
        let c = counts(i, &mut cnt);
        right_cost[i - 1] = Vec4::select(c.cmpgt(Vec4::ZERO), Box4::area3(&acc) * c, Vec4::NAN);
    }
    grow(0, &mut acc);
    let node_cost = TRAVERSAL_COST * Box4::area3(&acc);
    let (mut acc, mut cnt) = ([Box4::EMPTY; 3], [0u32; 3]);
    let mut cost = [Vec4::ZERO; BINS];
    for i in 0..BINS - 1 {
        grow(i, &mut acc);
        let c = counts(i, &mut cnt);
        cost[i] = node_cost + Box4::area3(&acc) * c + right_cost[i];
    }
    // Each axis's choice exactly as in `sweep`.
    std::array::from_fn(|axis| {
        let mut best: Option<(usize, f32)> = None;
        let mut cnt = 0u32;
        for i in 0..BINS - 1 {
            cnt += bins.counts[axis][i];
            if cnt == 0 || right_cost[i][axis].is_nan() {
                continue;
            }
            let c = cost[i][axis];
            if best.is_none_or(|(_, b)| c < b) {
                best = Some((i, c));
            }
        }
        best
    })
}

/// The cheapest boundary of one axis's bins: `(last bin of the left side, cost)`,
/// ties going to the lower bin; only boundaries with primitives on both sides.
/// The one-axis form of [`sweep3`] (tests compare them).
#[cfg(test)]
fn sweep(boxes: &[Box4; BINS], counts: &[u32; BINS]) -> Option<(usize, f32)> {
    // right_cost[i]: area * count of bins i+1.. (the right side of boundary i).
    let mut right_cost = [f32::NAN; BINS];
    let (mut acc, mut cnt) = (Box4::EMPTY, 0u32);
    for i in (1..BINS).rev() {
        acc = acc.union(&boxes[i]);
        cnt += counts[i];
        if cnt > 0 {
            right_cost[i - 1] = acc.area() * cnt as f32;
        }
    }
    let node_area = acc.union(&boxes[0]).area();
    let (mut acc, mut cnt) = (Box4::EMPTY, 0u32);
    let mut best: Option<(usize, f32)> = None;
    for i in 0..BINS - 1 {
        acc = acc.union(&boxes[i]);
        cnt += counts[i];
        let right = right_cost[i];
        if cnt == 0 || right.is_nan() {
            continue;
        }
        let cost = TRAVERSAL_COST * node_area + acc.area() * cnt as f32 + right;
        if best.is_none_or(|(_, c)| cost < c) {
            best = Some((i, cost));
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::PreTriangle;
    use crate::shapes::Triangle;
    use glam::Vec3;

    fn prim(id: u32, x: f32) -> PrimRef {
        let tri =
            Triangle { v: [Vec3::new(x, 0.0, 0.0), Vec3::new(x + 0.1, 1.0, 0.0), Vec3::new(x, 0.0, 1.0)] };
        PrimRef::new(id, &tri, &PreTriangle::new(&tri))
    }

    #[test]
    fn bins_cover_the_centroid_range() {
        let cent = Box4 { min: Vec4::new(1.0, 0.0, 0.0, 0.0), max: Vec4::new(4.0, 0.0, 0.0, 0.0) };
        let map = BinMap::new(&cent).expect("x can be binned");
        assert_eq!(map.ok, [true, false, false]);
        let at = |x: f32| map.bins(Vec4::new(x, 0.0, 0.0, 0.0))[0];
        assert_eq!(at(1.0), 0);
        assert_eq!(at(4.0), BINS - 1);
        assert_eq!(at(2.5), BINS / 2);
        assert!(BinMap::new(&Box4 { min: Vec4::ONE, max: Vec4::ONE }).is_none());
    }

    #[test]
    fn goes_left_agrees_with_the_bins() {
        let cent = Box4 { min: Vec4::new(-1.0, 2.0, 0.0, 0.0), max: Vec4::new(3.0, 2.5, 1e-30, 0.0) };
        let map = BinMap::new(&cent).expect("binnable");
        let s = crate::sampling::Sampler::new(9, 9, 9, 9);
        for i in 0..20_000u32 {
            // Points in and around the box, some exactly on bin boundaries.
            let t = Vec4::new(s.get(3 * i), s.get(3 * i + 1), s.get(3 * i + 2), 0.0) * 1.2 - Vec4::splat(0.1);
            let mut c = cent.min + (cent.max - cent.min) * t;
            if i % 7 == 0 {
                c.x = -1.0 + 0.25 * (i % 17) as f32;
            }
            let b = map.bins(c);
            for (axis, &in_bin) in b.iter().enumerate().filter(|&(axis, _)| map.ok[axis]) {
                for bin in 0..BINS - 1 {
                    let split = Split { axis, bin, cost: 0.0 };
                    assert_eq!(map.goes_left(c, &split), in_bin <= bin, "{c:?} axis {axis} bin {bin}");
                }
            }
        }
    }

    #[test]
    fn three_axis_sweep_is_the_one_axis_sweep() {
        let mut next = crate::sampling::Sampler::new(6, 5, 4, 3).stream();
        let specials = [0.0, -0.0, 1e-30, 3e38, f32::INFINITY, f32::NEG_INFINITY];
        let mut found = 0;
        for case in 0..3000usize {
            let mut bins = Bins::EMPTY;
            for axis in 0..3 {
                for bin in 0..BINS {
                    // Empty bins now and then (runs of them, and whole axes).
                    if (case + axis) % 13 == 0 || next() < 0.3 {
                        continue;
                    }
                    let lo = Vec4::new(next(), next(), next(), 0.0) * 10.0 - Vec4::splat(5.0);
                    let mut hi = lo + Vec4::new(next(), next(), next(), 0.0);
                    if case % 7 == 0 {
                        hi[bin % 3] = specials[(case / 7 + bin) % specials.len()];
                    }
                    bins.boxes[axis][bin] = Box4 { min: lo, max: hi };
                    bins.counts[axis][bin] = 1 + (next() * 50.0) as u32;
                }
            }
            for (axis, three) in sweep3(&bins).into_iter().enumerate() {
                let one = sweep(&bins.boxes[axis], &bins.counts[axis]);
                let bits = |r: Option<(usize, f32)>| r.map(|(b, c)| (b, c.to_bits()));
                assert_eq!(bits(three), bits(one), "case {case} axis {axis}");
                found += usize::from(one.is_some());
            }
        }
        assert!(found > 5000, "{found} splits found");
    }

    #[test]
    fn parallel_binning_equals_sequential_and_splits_two_clusters() {
        // Two clusters far apart along x: the best split separates them.
        let prims: Vec<PrimRef> = (0..40_000u32)
            .map(|i| prim(i, if i % 3 == 0 { 100.0 } else { 0.0 } + (i % 97) as f32 * 0.01))
            .collect();
        let (_, cent) = super::super::primref::bounds_of(&prims);
        let map = BinMap::new(&cent).expect("binnable");
        let par = Bins::of_par(&prims, &map);
        let mut seq = Bins::EMPTY;
        seq.fill(&prims, &map);
        assert_eq!(par.boxes, seq.boxes);
        assert_eq!(par.counts, seq.counts);
        let split = Bins::best_split(&prims, &map).expect("a split");
        assert_eq!(split.axis, 0);
        let left = prims.iter().filter(|p| map.goes_left(p.centroid(), &split)).count();
        assert_eq!(left, prims.iter().filter(|p| p.id() % 3 != 0).count());
    }
}

//! Exact SAH split search for small nodes: per axis, the primitives sorted by
//! centroid (ties by position in the node, so the order is total), and every
//! split between two neighbours in that order evaluated. For a handful of
//! primitives this is both cheaper than filling and sweeping three axes of bins
//! and at least as good. Nodes of up to [`TINY_MAX`] primitives (most nodes of a
//! tree) go further: every way to split them in two is evaluated.

use super::binning::TRAVERSAL_COST;
use super::partition::Sides;
use super::primref::{Box4, PrimRef};
use glam::Vec4;

/// Largest node the exact sweep handles.
pub(super) const SMALL_MAX: usize = 12;

/// Largest node whose every split is evaluated.
pub(super) const TINY_MAX: usize = 4;

/// The cheapest split of `prims` (2..=[`TINY_MAX`] of them) into two non-empty
/// sets, as [`split_small`] (each side keeps its order; ties go to the first
/// left set in the order of the bit masks over all but the last primitive).
pub(super) fn split_tiny(
    prims: &mut [PrimRef],
    node_area: f32,
    commit: impl FnOnce(f32) -> bool,
) -> Option<(f32, Sides)> {
    let n = prims.len();
    debug_assert!((2..=TINY_MAX).contains(&n));
    if n == 2 {
        // One split only; the primitives are already in order.
        let (a, b) = (&prims[0], &prims[1]);
        let geo = [Box4 { min: a.min(), max: a.max() }, Box4 { min: b.min(), max: b.max() }];
        let cost = TRAVERSAL_COST * node_area + geo[0].area() + geo[1].area();
        if !commit(cost) {
            return None;
        }
        let cent = [a.centroid(), b.centroid()].map(|c| Box4 { min: c, max: c });
        return Some((cost, Sides { mid: 1, geo, cent }));
    }
    let full = (1usize << n) - 1;
    // boxes[m]: the box of the primitives whose bits are set in m.
    let mut boxes = [Box4::EMPTY; 1 << TINY_MAX];
    for m in 1..=full {
        let low = m.trailing_zeros() as usize;
        let p = &prims[low];
        boxes[m] = boxes[m & (m - 1)];
        boxes[m].grow_box(p.min(), p.max());
    }
    // Left sets: non-empty subsets of all but the last primitive (which always goes right).
    let mut best: Option<(f32, usize)> = None;
    for m in 1..=full >> 1 {
        let r = full ^ m;
        let cost = TRAVERSAL_COST * node_area
            + boxes[m].area() * m.count_ones() as f32
            + boxes[r].area() * r.count_ones() as f32;
        if best.is_none_or(|(c, _)| cost < c) {
            best = Some((cost, m));
        }
    }
    let (cost, mask) = best?;
    if !commit(cost) {
        return None;
    }
    // Fixed-size copies (n is 3 or 4), which compile to moves rather than a memcpy call.
    let mut tmp = [PrimRef::ZERO; TINY_MAX];
    tmp[..3].copy_from_slice(&prims[..3]);
    if n == TINY_MAX {
        tmp[3] = prims[3];
    }
    let mut sides = Sides { mid: mask.count_ones() as usize, geo: [Box4::EMPTY; 2], cent: [Box4::EMPTY; 2] };
    sides.geo = [boxes[mask], boxes[full ^ mask]];
    let (mut l, mut r) = (0, sides.mid);
    for (i, p) in tmp[..n].iter().enumerate() {
        let side = if mask >> i & 1 == 1 {
            prims[l] = *p;
            l += 1;
            0
        } else {
            prims[r] = *p;
            r += 1;
            1
        };
        sides.cent[side].grow(p.centroid());
    }
    Some((cost, sides))
}

/// The cheapest split of `prims` (2..=[`SMALL_MAX`] of them) between neighbours in
/// centroid order: returns its cost (SAH cost times the node's area, as
/// `binning::Split::cost`) and the sides, after reordering `prims` so that the
/// left side comes first (each side in centroid order). Ties go to the lower
/// axis, then the smaller left side. `None` when `commit` rejects the cost (then
/// `prims` is left as it was).
pub(super) fn split_small(
    prims: &mut [PrimRef],
    node_area: f32,
    commit: impl FnOnce(f32) -> bool,
) -> Option<(f32, Sides)> {
    let n = prims.len();
    debug_assert!((2..=SMALL_MAX).contains(&n));
    let mut cent = [Vec4::ZERO; SMALL_MAX];
    for (c, p) in cent.iter_mut().zip(prims.iter()) {
        *c = p.centroid();
    }
    // Per axis, the primitives in centroid order.
    let mut orders = [[0u8; SMALL_MAX]; 3];
    for (axis, order) in orders.iter_mut().enumerate() {
        // Insertion sort by (centroid, position): keys are the centroid's bits
        // mapped to an unsigned order equal to `f32::total_cmp`'s, then the position.
        let mut keys = [0u64; SMALL_MAX];
        for (i, c) in cent[..n].iter().enumerate() {
            let b = c[axis].to_bits();
            let ordered = if b >> 31 == 1 { !b } else { b | 1 << 31 };
            let key = u64::from(ordered) << 32 | i as u64;
            let mut j = i;
            while j > 0 && keys[j - 1] > key {
                keys[j] = keys[j - 1];
                j -= 1;
            }
            keys[j] = key;
        }
        for (o, k) in order.iter_mut().zip(&keys[..n]) {
            *o = *k as u8;
        }
    }
    // The sweeps of the three axes side by side, one vector lane per axis (the
    // same operations per lane as one axis at a time, see `Box4::area3`).
    // right_cost[k]: area * count of order[k..].
    let mut right_cost = [Vec4::ZERO; SMALL_MAX];
    let mut acc = [Box4::EMPTY; 3];
    for k in (1..n).rev() {
        for (b, order) in acc.iter_mut().zip(&orders) {
            let p = &prims[order[k] as usize];
            b.grow_box(p.min(), p.max());
        }
        right_cost[k] = Box4::area3(&acc) * (n - k) as f32;
    }
    let base = Vec4::splat(TRAVERSAL_COST * node_area);
    let mut costs = [Vec4::ZERO; SMALL_MAX];
    let mut acc = [Box4::EMPTY; 3];
    for k in 1..n {
        for (b, order) in acc.iter_mut().zip(&orders) {
            let p = &prims[order[k - 1] as usize];
            b.grow_box(p.min(), p.max());
        }
        costs[k] = base + Box4::area3(&acc) * k as f32 + right_cost[k];
    }
    // The first cheapest split, axis by axis (a NaN cost is taken only as the first).
    let mut best: Option<(f32, usize, usize)> = None;
    for axis in 0..3 {
        for (k, c) in costs.iter().enumerate().take(n).skip(1) {
            let cost = c[axis];
            if best.is_none_or(|(b, ..)| cost < b) {
                best = Some((cost, k, axis));
            }
        }
    }
    let (cost, mid, axis) = best?;
    if !commit(cost) {
        return None;
    }
    let order = orders[axis];
    let mut sorted = [PrimRef::ZERO; SMALL_MAX];
    for (s, &o) in sorted.iter_mut().zip(&order[..n]) {
        *s = prims[o as usize];
    }
    let mut sides = Sides { mid, geo: [Box4::EMPTY; 2], cent: [Box4::EMPTY; 2] };
    // The copy back is part of this loop (a bare copy loop would become a memcpy call).
    for (k, &o) in order[..n].iter().enumerate() {
        let side = usize::from(k >= mid);
        let p = sorted[k];
        prims[k] = p;
        sides.geo[side].grow_box(p.min(), p.max());
        sides.cent[side].grow(cent[o as usize]);
    }
    Some((cost, sides))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::PreTriangle;
    use crate::shapes::Triangle;
    use glam::Vec3;

    fn prim(id: u32, o: Vec3) -> PrimRef {
        let tri = Triangle { v: [o, o + Vec3::X * 0.1, o + Vec3::Y * 0.1] };
        PrimRef::new(id, &tri, &PreTriangle::new(&tri))
    }

    /// SAH cost (times area) of splitting `prims` into `left` / the rest, brute force.
    fn cost(all: &[PrimRef], left: &[u32], node_area: f32) -> f32 {
        let (mut l, mut r, mut nl) = (Box4::EMPTY, Box4::EMPTY, 0);
        for p in all {
            if left.contains(&p.id()) {
                l.grow_box(p.min(), p.max());
                nl += 1;
            } else {
                r.grow_box(p.min(), p.max());
            }
        }
        TRAVERSAL_COST * node_area + l.area() * nl as f32 + r.area() * (all.len() - nl) as f32
    }

    #[test]
    fn finds_the_cheapest_ordered_split_and_partitions_by_it() {
        // Two tight groups along y, interleaved in input order, spread along x.
        let mut prims: Vec<PrimRef> = (0..9u32)
            .map(|i| prim(i, Vec3::new(i as f32 * 0.05, if i % 2 == 0 { 0.0 } else { 10.0 }, 0.0)))
            .collect();
        let all = prims.clone();
        let (geo, _) = super::super::primref::bounds_of(&prims);
        let (c, sides) = split_small(&mut prims, geo.area(), |_| true).expect("a split");
        let left: Vec<u32> = prims[..sides.mid].iter().map(PrimRef::id).collect();
        let mut sorted_left = left.clone();
        sorted_left.sort_unstable();
        assert_eq!(sorted_left, vec![0, 2, 4, 6, 8], "the y = 0 group goes left");
        assert_eq!(c, cost(&all, &left, geo.area()));
        // No split along x is cheaper.
        for k in 1..9u32 {
            assert!(c <= cost(&all, &(0..k).collect::<Vec<_>>(), geo.area()));
        }
        // Rejecting the cost leaves the input untouched.
        let mut again = all.clone();
        assert!(split_small(&mut again, geo.area(), |_| false).is_none());
        assert_eq!(again.iter().map(PrimRef::id).collect::<Vec<_>>(), (0..9).collect::<Vec<_>>());
    }

    #[test]
    fn tiny_nodes_get_the_cheapest_of_all_bipartitions() {
        let mut uniform = crate::sampling::Sampler::new(3, 1, 4, 1).stream();
        let mut next = || uniform() * 10.0;
        for case in 0..300 {
            let n = 2 + case % (TINY_MAX - 1);
            let all: Vec<PrimRef> =
                (0..n as u32).map(|i| prim(i, Vec3::new(next(), next(), next()))).collect();
            let (geo, _) = super::super::primref::bounds_of(&all);
            // Brute force over every left set (as input indices; the last primitive
            // on the right, so that each split is costed with its sides in one order).
            let mut best = f32::INFINITY;
            for m in 1..1u32 << (n - 1) {
                let left: Vec<u32> = (0..n as u32).filter(|i| m >> i & 1 == 1).collect();
                best = best.min(cost(&all, &left, geo.area()));
            }
            let mut prims = all.clone();
            let (c, sides) = split_tiny(&mut prims, geo.area(), |_| true).expect("a split");
            assert_eq!(c, best, "case {case}");
            let left: Vec<u32> = prims[..sides.mid].iter().map(PrimRef::id).collect();
            assert_eq!(c, cost(&all, &left, geo.area()), "case {case}: the sides are the split costed");
            let (lg, lc) = super::super::primref::bounds_of(&prims[..sides.mid]);
            let (rg, rc) = super::super::primref::bounds_of(&prims[sides.mid..]);
            assert_eq!([lg, rg].map(Box4::to_aabb), sides.geo.map(Box4::to_aabb));
            assert_eq!([lc, rc].map(Box4::to_aabb), sides.cent.map(Box4::to_aabb));
        }
    }
}

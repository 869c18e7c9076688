//! Top-down binned SAH builder.
//!
//! Each node bins its primitives' centroids into [`BINS`] equal slots per axis,
//! evaluates the surface-area heuristic at every bin boundary and either splits at
//! the cheapest one or, when that is no cheaper than intersecting everything,
//! makes a leaf. Where binning cannot separate the primitives (all centroids in
//! one spot, non-finite extents) or the tree gets deep, it falls back to a median
//! split on a total order, so every input terminates within [`MAX_DEPTH`].
//!
//! Determinism: every decision is a function of the primitives in the node and
//! their order, which is itself determined by the parent's partition; subtrees
//! built on other threads are laid out and relocated exactly as the sequential
//! build would lay them out. The tree is therefore identical for any rayon pool.

use super::{Bvh, MAX_DEPTH, MAX_LEAF_SIZE, MAX_TRIANGLES, Node, PreTriangle};
use crate::geometry::Aabb;
use crate::shapes::Triangle;
use glam::{Vec3, Vec3A};
use rayon::prelude::*;

/// Centroid bins per axis.
const BINS: usize = 16;
/// SAH cost of visiting a node, relative to one triangle test.
const TRAVERSAL_COST: f32 = 1.0;
/// Nodes with at least this many primitives build their children in parallel.
const PARALLEL_THRESHOLD: usize = 4096;
/// From this depth on, nodes are split at the median: halving guarantees the
/// rest of the tree fits in `MAX_DEPTH` for up to `MAX_TRIANGLES` triangles.
const MEDIAN_DEPTH: usize = MAX_DEPTH - 34;
const _: () = assert!(MAX_TRIANGLES <= 1 << 30 && MEDIAN_DEPTH + 32 <= MAX_DEPTH);

/// What the builder knows about one input triangle.
#[derive(Clone, Copy, Debug)]
struct PrimInfo {
    bounds: Box3,
    centroid: Vec3A,
}

/// The builder's box: SIMD-friendly and, unlike [`Aabb`], only ever fed
/// NaN-free values (see [`prim_info`]), where every platform's vector min/max
/// gives the exact result — so the tree stays the same on every machine.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Box3 {
    min: Vec3A,
    max: Vec3A,
}

impl Box3 {
    const EMPTY: Box3 = Box3 { min: Vec3A::INFINITY, max: Vec3A::NEG_INFINITY };

    #[inline(always)]
    fn union(&self, o: &Box3) -> Box3 {
        Box3 { min: self.min.min(o.min), max: self.max.max(o.max) }
    }

    #[inline(always)]
    fn grow(&mut self, p: Vec3A) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }

    /// Surface area; 0 for the empty box.
    #[inline(always)]
    fn area(&self) -> f32 {
        let e = (self.max - self.min).max(Vec3A::ZERO);
        2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
    }

    fn extent(&self) -> Vec3A {
        (self.max - self.min).max(Vec3A::ZERO)
    }

    fn to_aabb(self) -> Aabb {
        Aabb { min: self.min.into(), max: self.max.into() }
    }
}

/// Builds the BVH (see [`Bvh::build`]).
pub(super) fn build(triangles: &[Triangle]) -> Bvh {
    assert!(triangles.len() <= MAX_TRIANGLES, "BVH: more than {MAX_TRIANGLES} triangles");
    if triangles.is_empty() {
        return Bvh::default();
    }
    let (nodes, tris, ids) = binary(triangles);
    let mut wide = super::wide::collapse(&nodes);
    let bounds = nodes[0].bounds();
    drop(nodes);
    let (blocks, prim_ids) = super::wide::place_leaves(&mut wide, &tris, &ids);
    Bvh { bounds, blocks, prim_ids, count: triangles.len(), wide, scalar_only: false, no_avx: false }
}

/// The binary tree over `triangles` (not empty), the triangles in leaf order and
/// their input indices.
pub(super) fn binary(triangles: &[Triangle]) -> (Vec<Node>, Vec<PreTriangle>, Vec<u32>) {
    let pre: Vec<PreTriangle> = triangles.par_iter().map(PreTriangle::new).collect();
    let prims: Vec<PrimInfo> = pre.par_iter().zip(triangles).map(|(p, t)| prim_info(p, t)).collect();
    let mut refs: Vec<u32> = (0..triangles.len() as u32).collect();
    let mut nodes = Vec::with_capacity(2 * triangles.len() / MAX_LEAF_SIZE.max(2) + 1);
    build_node(&prims, &mut refs, 0, 0, &mut nodes);
    let tris = refs.iter().map(|&r| pre[r as usize]).collect();
    (nodes, tris, refs)
}

/// Bounds over both the input vertices and the ones the intersection test
/// reconstructs (`v0 + e1`, `v0 + e2`), so leaf boxes contain either exactly.
///
/// The result is free of NaNs — NaN coordinates are ignored (such a triangle can
/// never be hit) and an axis with no number at all collapses to 0 — because the
/// box unions that follow are only order-independent (hence deterministic and
/// properly nested) on NaN-free boxes.
fn prim_info(pre: &PreTriangle, tri: &Triangle) -> PrimInfo {
    let mut min = Vec3::INFINITY;
    let mut max = Vec3::NEG_INFINITY;
    for p in tri.v.into_iter().chain(pre.vertices()) {
        // f32::min/max return the other operand when one is NaN.
        min = Vec3::new(min.x.min(p.x), min.y.min(p.y), min.z.min(p.z));
        max = Vec3::new(max.x.max(p.x), max.y.max(p.y), max.z.max(p.z));
    }
    for axis in 0..3 {
        if min[axis] > max[axis] {
            (min[axis], max[axis]) = (0.0, 0.0);
        }
    }
    // (+inf) + (-inf) is NaN: such a centroid goes to 0 on that axis.
    let centroid = (min + max) * 0.5;
    let centroid = Vec3::select(centroid.is_nan_mask(), Vec3::ZERO, centroid);
    PrimInfo { bounds: Box3 { min: min.into(), max: max.into() }, centroid: centroid.into() }
}

/// Appends the subtree over `refs` (whose first element is triangle `first` in
/// leaf order) to `out`, depth-first. Indices stored in the new nodes are
/// relative to the start of `out`.
fn build_node(prims: &[PrimInfo], refs: &mut [u32], first: u32, depth: usize, out: &mut Vec<Node>) {
    let (bounds, centroids) = bounds_and_centroids(prims, refs);
    let at = out.len();
    let Some(mid) = choose_split(prims, refs, &bounds, &centroids, depth) else {
        out.push(Node::leaf(&bounds.to_aabb(), first, refs.len() as u32));
        return;
    };
    out.push(Node::interior(&bounds.to_aabb(), 0));
    let (left, right) = refs.split_at_mut(mid);
    let right_first = first + mid as u32;
    if left.len() + right.len() >= PARALLEL_THRESHOLD {
        let (l, r) = rayon::join(
            || subtree(prims, left, first, depth + 1),
            || subtree(prims, right, right_first, depth + 1),
        );
        append_relocated(out, &l);
        out[at].offset = out.len() as u32;
        append_relocated(out, &r);
    } else {
        build_node(prims, left, first, depth + 1, out);
        out[at].offset = out.len() as u32;
        build_node(prims, right, right_first, depth + 1, out);
    }
}

/// The union of the primitives' boxes and the box around their centroids, in one
/// pass — over chunks in parallel for large nodes. Unions of NaN-free boxes are
/// exact, associative and commutative, so the result is the same for any split.
fn bounds_and_centroids(prims: &[PrimInfo], refs: &[u32]) -> (Box3, Box3) {
    if refs.len() >= PARALLEL_THRESHOLD {
        return refs
            .par_chunks(PARALLEL_CHUNK)
            .map(|c| bounds_and_centroids_seq(prims, c))
            .reduce(|| (Box3::EMPTY, Box3::EMPTY), |a, b| (a.0.union(&b.0), a.1.union(&b.1)));
    }
    bounds_and_centroids_seq(prims, refs)
}

/// Primitives per parallel task when binning a large node.
const PARALLEL_CHUNK: usize = 2048;

fn bounds_and_centroids_seq(prims: &[PrimInfo], refs: &[u32]) -> (Box3, Box3) {
    let mut bounds = Box3::EMPTY;
    let mut centroids = Box3::EMPTY;
    for &r in refs {
        let p = &prims[r as usize];
        bounds = bounds.union(&p.bounds);
        centroids.grow(p.centroid);
    }
    (bounds, centroids)
}

/// A subtree in its own vector (node indices relative to its start).
fn subtree(prims: &[PrimInfo], refs: &mut [u32], first: u32, depth: usize) -> Vec<Node> {
    let mut v = Vec::with_capacity(2 * refs.len() / MAX_LEAF_SIZE.max(2) + 1);
    build_node(prims, refs, first, depth, &mut v);
    v
}

/// Appends `sub` to `out`, shifting its interior nodes' child indices.
fn append_relocated(out: &mut Vec<Node>, sub: &[Node]) {
    let base = out.len() as u32;
    out.extend(sub.iter().map(|n| {
        let mut n = *n;
        if !n.is_leaf() {
            n.offset += base;
        }
        n
    }));
}

/// Decides how to split `refs`; on a split, partitions `refs` in place and
/// returns the size of the first part (always in `1..refs.len()`). `None` means
/// make a leaf.
fn choose_split(
    prims: &[PrimInfo],
    refs: &mut [u32],
    bounds: &Box3,
    centroids: &Box3,
    depth: usize,
) -> Option<usize> {
    let n = refs.len();
    if n <= 1 {
        return None;
    }
    if depth >= MEDIAN_DEPTH {
        return (n > MAX_LEAF_SIZE).then(|| median_split(prims, refs, centroids));
    }
    let best = best_binned_split(prims, refs, centroids);
    // Costs are SAH costs multiplied by the node's area, so that zero-area
    // nodes (all triangles degenerate and in one spot) compare without NaNs.
    let leaf_cost = n as f32 * bounds.area();
    match best {
        Some(split) if n > MAX_LEAF_SIZE || split.cost < leaf_cost => {
            Some(partition(prims, refs, &split, centroids))
        }
        _ if n > MAX_LEAF_SIZE => Some(median_split(prims, refs, centroids)),
        _ => None,
    }
}

/// A candidate split: primitives whose centroid falls in bins `0..=bin` of `axis` go left.
#[derive(Clone, Copy, Debug)]
struct Split {
    axis: usize,
    bin: usize,
    cost: f32,
}

#[derive(Clone, Copy, Debug)]
struct Bin {
    bounds: Box3,
    count: u32,
}

impl Bin {
    const EMPTY: Bin = Bin { bounds: Box3::EMPTY, count: 0 };
}

/// The centroid bins of all three axes (axes without a scale stay empty).
fn fill_bins(
    prims: &[PrimInfo],
    refs: &[u32],
    centroids: &Box3,
    scales: &[Option<f32>; 3],
) -> [[Bin; BINS]; 3] {
    let mut bins = [[Bin::EMPTY; BINS]; 3];
    for &r in refs {
        let p = &prims[r as usize];
        for (axis, scale) in scales.iter().enumerate() {
            if let Some(scale) = *scale {
                let b = &mut bins[axis][bin_index(p.centroid[axis], centroids.min[axis], scale)];
                b.bounds = b.bounds.union(&p.bounds);
                b.count += 1;
            }
        }
    }
    bins
}

/// Maps centroid coordinate `c` to its bin. `scale = BINS / extent`; the clamp
/// keeps the maximum (and rounding overshoots) in the last bin. The same function
/// serves binning and partitioning, so they always agree.
#[inline]
fn bin_index(c: f32, min: f32, scale: f32) -> usize {
    (((c - min) * scale) as usize).min(BINS - 1)
}

/// Bin scale for `axis`, or `None` when the centroids cannot be binned along it.
fn bin_scale(centroids: &Box3, axis: usize) -> Option<f32> {
    let extent = centroids.max[axis] - centroids.min[axis];
    let scale = BINS as f32 / extent;
    (extent > 0.0 && scale.is_finite()).then_some(scale)
}

/// The cheapest bin-boundary split over all three axes (ties go to the lower
/// axis, then the lower bin), or `None` when no axis can separate the centroids.
/// One pass over the primitives fills the bins of all three axes.
fn best_binned_split(prims: &[PrimInfo], refs: &[u32], centroids: &Box3) -> Option<Split> {
    let scales = [0, 1, 2].map(|axis| bin_scale(centroids, axis));
    if scales.iter().all(Option::is_none) {
        return None;
    }
    // Large nodes fill per-chunk bins in parallel and merge them; bin boxes are
    // unions of NaN-free boxes and counts are integers, so merging is exact and
    // the bins are the same for any split into chunks.
    let bins = if refs.len() >= PARALLEL_THRESHOLD {
        refs.par_chunks(PARALLEL_CHUNK).map(|c| fill_bins(prims, c, centroids, &scales)).reduce(
            || [[Bin::EMPTY; BINS]; 3],
            |mut a, b| {
                for (ra, rb) in a.iter_mut().zip(&b) {
                    for (x, y) in ra.iter_mut().zip(rb) {
                        x.bounds = x.bounds.union(&y.bounds);
                        x.count += y.count;
                    }
                }
                a
            },
        )
    } else {
        fill_bins(prims, refs, centroids, &scales)
    };
    let mut best: Option<Split> = None;
    for (axis, axis_bins) in bins.iter().enumerate() {
        if scales[axis].is_none() {
            continue;
        }
        if let Some((bin, cost)) = sweep(axis_bins) {
            if best.is_none_or(|b| cost < b.cost) {
                best = Some(Split { axis, bin, cost });
            }
        }
    }
    best
}

/// The cheapest boundary of one axis's bins: `(last bin of the left side, cost)`,
/// ties going to the lower bin; only boundaries with primitives on both sides.
fn sweep(bins: &[Bin; BINS]) -> Option<(usize, f32)> {
    // right_cost[i]: area * count of bins i+1.. (the right side of boundary i).
    let mut right_cost = [f32::NAN; BINS];
    let (mut acc, mut cnt) = (Box3::EMPTY, 0u32);
    for i in (1..BINS).rev() {
        acc = acc.union(&bins[i].bounds);
        cnt += bins[i].count;
        if cnt > 0 {
            right_cost[i - 1] = acc.area() * cnt as f32;
        }
    }
    let node_area = acc.union(&bins[0].bounds).area();
    let (mut acc, mut cnt) = (Box3::EMPTY, 0u32);
    let mut best: Option<(usize, f32)> = None;
    for (i, bin) in bins.iter().enumerate().take(BINS - 1) {
        acc = acc.union(&bin.bounds);
        cnt += bin.count;
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

/// Partitions `refs` so that the split's left side comes first (order within
/// each side follows a fixed, deterministic swap pattern) and returns its size.
fn partition(prims: &[PrimInfo], refs: &mut [u32], split: &Split, centroids: &Box3) -> usize {
    let (axis, min) = (split.axis, centroids.min[split.axis]);
    let scale = bin_scale(centroids, axis).unwrap_or(0.0);
    let goes_left = |r: u32| bin_index(prims[r as usize].centroid[axis], min, scale) <= split.bin;
    let (mut i, mut j) = (0usize, refs.len());
    while i < j {
        if goes_left(refs[i]) {
            i += 1;
        } else {
            j -= 1;
            refs.swap(i, j);
        }
    }
    i
}

/// Splits at the median along the centroids' widest axis, ordering by
/// (centroid, input index): a total order, so the result is deterministic even
/// when centroids coincide or are NaN.
fn median_split(prims: &[PrimInfo], refs: &mut [u32], centroids: &Box3) -> usize {
    let extent = centroids.extent();
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    let mid = refs.len() / 2;
    refs.select_nth_unstable_by(mid, |&a, &b| {
        let (ca, cb) = (prims[a as usize].centroid[axis], prims[b as usize].centroid[axis]);
        ca.total_cmp(&cb).then(a.cmp(&b))
    });
    mid
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bins_cover_the_centroid_range() {
        let scale = BINS as f32 / 3.0;
        assert_eq!(bin_index(1.0, 1.0, scale), 0);
        assert_eq!(bin_index(4.0, 1.0, scale), BINS - 1);
        assert_eq!(bin_index(2.5, 1.0, scale), BINS / 2);
    }

    #[test]
    fn median_split_halves_identical_centroids() {
        let p = PrimInfo { bounds: Box3 { min: Vec3A::ONE, max: Vec3A::ONE }, centroid: Vec3A::ONE };
        let prims = vec![p; 9];
        let mut refs: Vec<u32> = (0..9).rev().collect();
        let centroids = Box3 { min: Vec3A::ONE, max: Vec3A::ONE };
        let mid = median_split(&prims, &mut refs, &centroids);
        assert_eq!(mid, 4);
        let mut left = refs[..mid].to_vec();
        left.sort();
        assert_eq!(left, vec![0, 1, 2, 3], "ties are broken by input index");
    }
}

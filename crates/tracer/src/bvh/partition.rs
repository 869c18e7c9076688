//! Splitting a node's primitive references into its two children, in place,
//! while gathering the children's boxes and centroid boxes on the way (so no
//! node needs a separate bounds pass).
//!
//! Small nodes use a two-pointer in-place partition; large ones (a size
//! threshold, never the thread count) count and scatter fixed-size chunks in
//! parallel through a scratch buffer, which keeps each side in input order.
//! Either way the result is a pure function of the node's references.

use super::binning::{CHUNK, PARALLEL_MIN};
use super::build::Slot;
use super::primref::{Box4, PrimRef, bounds_of};
use glam::Vec4;
use rayon::prelude::*;

/// The two sides of a split node: the left side is `prims[..mid]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Sides {
    /// Size of the left side.
    pub mid: usize,
    /// Boxes of the left and right side.
    pub geo: [Box4; 2],
    /// Centroid boxes of the left and right side.
    pub cent: [Box4; 2],
}

/// Moves the references whose centroid `goes_left` to the front of `prims`.
/// `scratch` (as long as `prims`) is used for large nodes.
pub(super) fn partition(
    prims: &mut [PrimRef],
    scratch: &mut [Slot],
    goes_left: impl Fn(Vec4) -> bool + Sync,
) -> Sides {
    if prims.len() >= PARALLEL_MIN && scratch.len() == prims.len() {
        partition_par(prims, scratch, goes_left)
    } else {
        partition_seq(prims, goes_left)
    }
}

/// Two pointers: left-goers stay, others are swapped to the back.
fn partition_seq(prims: &mut [PrimRef], goes_left: impl Fn(Vec4) -> bool) -> Sides {
    let mut geo = [Box4::EMPTY; 2];
    let mut cent = [Box4::EMPTY; 2];
    let (mut i, mut j) = (0usize, prims.len());
    while i < j {
        let p = prims[i];
        let c = p.centroid();
        if goes_left(c) {
            geo[0].grow_box(p.min(), p.max());
            cent[0].grow(c);
            i += 1;
        } else {
            geo[1].grow_box(p.min(), p.max());
            cent[1].grow(c);
            j -= 1;
            prims.swap(i, j);
        }
    }
    Sides { mid: i, geo, cent }
}

/// Per chunk: left count, and the boxes and centroid boxes of both sides.
type ChunkSides = (usize, [Box4; 2], [Box4; 2]);

/// Stable parallel partition through `scratch`: one pass copies each chunk to
/// `scratch` while counting its sides, a second scatters it back into place.
fn partition_par(
    prims: &mut [PrimRef],
    scratch: &mut [Slot],
    goes_left: impl Fn(Vec4) -> bool + Sync,
) -> Sides {
    let per_chunk: Vec<ChunkSides> = prims
        .par_chunks(CHUNK)
        .zip(scratch.par_chunks_mut(CHUNK))
        .map(|(chunk, copy)| {
            let (mut geo, mut cent, mut left) = ([Box4::EMPTY; 2], [Box4::EMPTY; 2], 0);
            for (p, slot) in chunk.iter().zip(copy) {
                *slot = p.to_slot();
                let c = p.centroid();
                let side = usize::from(!goes_left(c));
                left += 1 - side;
                geo[side].grow_box(p.min(), p.max());
                cent[side].grow(c);
            }
            (left, geo, cent)
        })
        .collect();
    let mid: usize = per_chunk.iter().map(|c| c.0).sum();
    // Each chunk's destinations: its run of the left side, its run of the right side.
    let n = prims.len();
    let (mut left_rest, mut right_rest) = prims.split_at_mut(mid);
    let mut dsts = Vec::with_capacity(per_chunk.len());
    for (k, &(left, ..)) in per_chunk.iter().enumerate() {
        let len = CHUNK.min(n - k * CHUNK);
        let (l, lr) = std::mem::take(&mut left_rest).split_at_mut(left);
        let (r, rr) = std::mem::take(&mut right_rest).split_at_mut(len - left);
        (left_rest, right_rest) = (lr, rr);
        dsts.push((l, r));
    }
    scratch.par_chunks(CHUNK).zip(dsts).for_each(|(chunk, (l, r))| {
        let (mut i, mut j) = (0, 0);
        for s in chunk {
            let p = PrimRef::from_slot(s);
            if goes_left(p.centroid()) {
                l[i] = p;
                i += 1;
            } else {
                r[j] = p;
                j += 1;
            }
        }
    });
    let mut sides = Sides { mid, geo: [Box4::EMPTY; 2], cent: [Box4::EMPTY; 2] };
    for (_, geo, cent) in &per_chunk {
        for s in 0..2 {
            sides.geo[s] = sides.geo[s].union(&geo[s]);
            sides.cent[s] = sides.cent[s].union(&cent[s]);
        }
    }
    sides
}

/// Splits at the median along the centroid box's widest axis, ordering by
/// (centroid, input index): a total order, so the halves are deterministic even
/// when centroids coincide.
pub(super) fn median(prims: &mut [PrimRef], cent: &Box4) -> Sides {
    let extent = cent.extent();
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    let mid = prims.len() / 2;
    prims.select_nth_unstable_by(mid, |a, b| {
        let (ca, cb) = (a.centroid()[axis], b.centroid()[axis]);
        ca.total_cmp(&cb).then(a.id().cmp(&b.id()))
    });
    let (lg, lc) = bounds_of(&prims[..mid]);
    let (rg, rc) = bounds_of(&prims[mid..]);
    Sides { mid, geo: [lg, rg], cent: [lc, rc] }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::PreTriangle;
    use crate::shapes::Triangle;
    use glam::Vec3;

    fn prims(n: u32) -> Vec<PrimRef> {
        (0..n)
            .map(|i| {
                let o = Vec3::new((i * 7919 % 1000) as f32, (i % 13) as f32, (i % 5) as f32);
                let tri = Triangle { v: [o, o + Vec3::X, o + Vec3::Y] };
                PrimRef::new(i, &tri, &PreTriangle::new(&tri))
            })
            .collect()
    }

    fn check(all: &[PrimRef], sides: &Sides, goes_left: impl Fn(Vec4) -> bool) {
        let (l, r) = all.split_at(sides.mid);
        assert!(l.iter().all(|p| goes_left(p.centroid())));
        assert!(r.iter().all(|p| !goes_left(p.centroid())));
        let (lg, lc) = bounds_of(l);
        let (rg, rc) = bounds_of(r);
        assert_eq!((sides.geo[0].to_aabb(), sides.geo[1].to_aabb()), (lg.to_aabb(), rg.to_aabb()));
        assert_eq!((sides.cent[0].to_aabb(), sides.cent[1].to_aabb()), (lc.to_aabb(), rc.to_aabb()));
    }

    #[test]
    fn sequential_and_parallel_partitions_split_correctly_and_keep_every_reference() {
        let goes_left = |c: Vec4| c.x < 400.0;
        for n in [0u32, 1, 5, 1000, 3 * PARALLEL_MIN as u32 + 17] {
            let input = prims(n);
            let mut a = input.clone();
            let mut scratch = vec![[0u32; 8]; a.len()];
            let sides = partition(&mut a, &mut scratch, goes_left);
            check(&a, &sides, goes_left);
            let mut ids: Vec<u32> = a.iter().map(PrimRef::id).collect();
            ids.sort_unstable();
            assert_eq!(ids, (0..n).collect::<Vec<_>>());
            if n >= PARALLEL_MIN as u32 {
                // The parallel partition is stable, on any pool.
                let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("pool");
                let mut b = input.clone();
                let sides_b = one.install(|| partition(&mut b, &mut scratch, goes_left));
                assert_eq!(sides, sides_b);
                assert_eq!(
                    a.iter().map(PrimRef::id).collect::<Vec<_>>(),
                    b.iter().map(PrimRef::id).collect::<Vec<_>>()
                );
                let mut stable: Vec<u32> =
                    input.iter().filter(|p| goes_left(p.centroid())).map(PrimRef::id).collect();
                stable.extend(input.iter().filter(|p| !goes_left(p.centroid())).map(PrimRef::id));
                assert_eq!(a.iter().map(PrimRef::id).collect::<Vec<_>>(), stable);
            }
        }
    }

    #[test]
    fn median_split_halves_identical_centroids_by_index() {
        let tri = Triangle { v: [Vec3::ONE; 3] };
        let p = |i| PrimRef::new(i, &tri, &PreTriangle::new(&tri));
        let mut refs: Vec<PrimRef> = (0..9).rev().map(p).collect();
        let (_, cent) = bounds_of(&refs);
        let sides = median(&mut refs, &cent);
        assert_eq!(sides.mid, 4);
        let mut left: Vec<u32> = refs[..4].iter().map(PrimRef::id).collect();
        left.sort_unstable();
        assert_eq!(left, vec![0, 1, 2, 3], "ties are broken by input index");
    }
}

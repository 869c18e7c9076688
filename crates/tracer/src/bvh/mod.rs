//! Bounding volume hierarchy over all triangles of a scene, built with the binned
//! surface-area heuristic.
//!
//! * `build` — top-down binned SAH builder (parallel with rayon, yet the tree
//!   is a pure function of the input triangles: any thread count, any machine,
//!   the same bytes), with its parts: `primref` (32-byte primitive
//!   references and box maths), `binning` (16-bin SAH, binned in parallel at
//!   large nodes), `partition` (in-place split, parallel for large nodes) and
//!   `sweep` (exact SAH for small nodes).
//! * `blocks` — leaf triangles in structure-of-arrays blocks of four, tested
//!   with one SSE Möller–Trumbore (bit-identical to the scalar test).
//! * `packet` — any-hit for up to four rays at once (on top of `packet8`).
//! * `shaft` — whether anything can block shadow rays from a box to a light
//!   (shaft culling), for `crate::shadows`.
//! * `packet8` — nearest and any hit for packets of eight rays (camera rays,
//!   shadow rays from one point to an area light) that traverse the tree once
//!   per packet, with the same answer for every ray as the single-ray queries.
//! * `wide` — the tree rays traverse: the binary tree collapsed into 8-wide
//!   nodes whose eight boxes one AVX (or two SSE) instruction sequences test
//!   at once (with a bit-identical scalar fallback); nearest-hit traversal visits children
//!   nearest first with early-out against the best hit so far, any-hit
//!   traversal stops at the first hit.
//!
//! # Memory layout
//!
//! The builder makes a binary tree of 32-byte nodes in depth-first order: the root is
//! node 0, an interior node's first child directly follows it and its second
//! child's index is stored in the node. Traversal uses the 8-wide nodes it is
//! collapsed into (224 bytes each, see `wide`), and 4-wide ones (128 bytes)
//! where a node has at most four children — a third to two thirds of all
//! nodes, at the bottom of the tree; the binary nodes are then dropped. Triangles are stored once, in the precomputed Möller–Trumbore form
//! `(v0, e1, e2)` ([`PreTriangle`]), four to a structure-of-arrays block (see
//! `blocks`); a leaf owns a run of lanes in one block, and `prim_ids` maps each
//! lane back to the index in the slice the BVH was built from ([`Hit::prim`]).

mod binning;
mod blocks;
mod build;
mod packet;
mod packet8;
mod partition;
mod primref;
mod shaft;
mod sweep;
mod wide;

pub use packet8::LANES as PACKET_LANES;
pub use shaft::{SHAFT_PLANES, SURFACE_PLANES, Shaft, ShaftEntry, SurfacePlanes};

use crate::geometry::{Aabb, Ray};
use crate::shapes::{Hit, Triangle};
use glam::Vec3;

/// Most triangles a leaf holds.
pub const MAX_LEAF_SIZE: usize = 4;

/// Deepest a node can be (the root is at depth 0). The builder switches to
/// median splits well before this, and traversal stacks are sized from it.
pub const MAX_DEPTH: usize = 64;

/// Most triangles a BVH can hold (2^27): the median-split fallback then stays
/// within [`MAX_DEPTH`], and every triangle lane (at most four per triangle)
/// fits the 29 bits a wide node's child word has for it.
pub const MAX_TRIANGLES: usize = 1 << 27;

/// One node of the binary tree the builder makes: 32 bytes, aligned so a node never straddles a cache line.
///
/// | bytes  | field    | interior node                 | leaf                                   |
/// |--------|----------|-------------------------------|----------------------------------------|
/// | 0..12  | `min`    | box lower corner (x, y, z)    | box lower corner                       |
/// | 12..16 | `offset` | index of the second child     | index of the first triangle (leaf order) |
/// | 16..28 | `max`    | box upper corner (x, y, z)    | box upper corner                       |
/// | 28..32 | `count`  | 0                             | number of triangles, 1..=[`MAX_LEAF_SIZE`] |
///
/// The first child of interior node `i` is node `i + 1` (depth-first order).
///
/// Only the builder makes these; they are collapsed into the 8-wide tree and dropped.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(32))]
struct Node {
    /// Lower corner of the box.
    min: [f32; 3],
    /// Interior: index of the second child. Leaf: first triangle in leaf order.
    offset: u32,
    /// Upper corner of the box.
    max: [f32; 3],
    /// 0 for an interior node, else the number of triangles in the leaf.
    count: u32,
}

const _: () = assert!(std::mem::size_of::<Node>() == 32);
const _: () = assert!(std::mem::align_of::<Node>() == 32);

impl Node {
    /// True for a leaf.
    #[inline(always)]
    fn is_leaf(&self) -> bool {
        self.count != 0
    }

    /// The node's box.
    fn bounds(&self) -> Aabb {
        Aabb { min: Vec3::from_array(self.min), max: Vec3::from_array(self.max) }
    }

    fn leaf(bounds: &Aabb, first: u32, count: u32) -> Self {
        Node { min: bounds.min.to_array(), offset: first, max: bounds.max.to_array(), count }
    }

    fn interior(bounds: &Aabb, second_child: u32) -> Self {
        Node { min: bounds.min.to_array(), offset: second_child, max: bounds.max.to_array(), count: 0 }
    }
}

/// A triangle in the precomputed form Möller–Trumbore works on: `v0`,
/// `e1 = v1 - v0`, `e2 = v2 - v0` (36 bytes).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PreTriangle {
    /// First vertex.
    pub v0: Vec3,
    /// `v1 - v0`.
    pub e1: Vec3,
    /// `v2 - v0`.
    pub e2: Vec3,
}

impl PreTriangle {
    /// Precomputes `tri` exactly as [`Triangle::intersect`] does, so both give the same bits.
    pub fn new(tri: &Triangle) -> Self {
        let (v0, e1, e2) = tri.edges();
        PreTriangle { v0, e1, e2 }
    }

    /// The three vertices as the intersection test sees them (`v0`, `v0 + e1`,
    /// `v0 + e2`; these may differ from the input vertices in the last bit).
    pub fn vertices(&self) -> [Vec3; 3] {
        [self.v0, self.v0 + self.e1, self.v0 + self.e2]
    }
}

/// A BVH over a triangle list. It keeps its own, traversal-friendly copy of the
/// triangle data; [`Hit::prim`] refers to the index in the list it was built from.
///
/// The default value is the empty BVH: every query misses.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Bvh {
    /// Box around every triangle (the empty box when there are none).
    bounds: Aabb,
    /// Leaf triangles, four to a block (see `blocks`).
    blocks: Vec<blocks::TriBlock>,
    /// `prim_ids[4 * b + k]` is the input index of lane `k` of block `b`
    /// (`u32::MAX` for an empty lane).
    prim_ids: Vec<u32>,
    /// Number of triangles.
    count: usize,
    /// The 8-wide nodes of the tree traversal uses (the root is node 0).
    wide: Vec<wide::WideNode>,
    /// Its 4-wide nodes (see `wide`).
    narrow: Vec<wide::NarrowNode>,
    /// Use the scalar box and triangle tests even where SIMD ones exist.
    scalar_only: bool,
    /// Use the SSE box test even where the CPU has AVX.
    no_avx: bool,
    /// Prefetch nodes and triangle blocks during single-ray traversal: set
    /// when the tree is larger than [`PREFETCH_MIN_BYTES`] (a hint that only
    /// pays where the tree does not stay in the caches; answers are the same).
    prefetch: bool,
}

/// Trees of at least this many bytes ([`Bvh::memory_bytes`]) prefetch during
/// single-ray traversal. Measured: +10–30% incoherent rays on the 1.6M dragon
/// (99 MB), −0–5% on the 4–6 MB bunny, dragon 100k and Sponza trees.
pub const PREFETCH_MIN_BYTES: usize = 32 << 20;

/// A violated BVH invariant, found by [`Bvh::validate`].
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("invalid BVH at node {node}: {problem}")]
pub struct InvalidBvh {
    /// Index of the offending node (0 for whole-tree problems).
    pub node: usize,
    /// What is wrong.
    pub problem: String,
}

impl Bvh {
    /// Builds the hierarchy over `triangles` with the binned SAH. Uses the current
    /// rayon pool for large subtrees; the result does not depend on its size.
    ///
    /// # Panics
    /// When given more than [`MAX_TRIANGLES`] triangles.
    pub fn build(triangles: &[Triangle]) -> Self {
        build::build(triangles)
    }

    /// Nearest hit with `t_min < t < t_max`. Equal to a brute-force scan with
    /// [`Triangle::intersect`] over all triangles (up to the choice between
    /// hits at bit-identical `t`).
    pub fn intersect(&self, ray: &Ray, t_min: f32, t_max: f32) -> Option<Hit> {
        wide::intersect(self, ray, t_min, t_max)
    }

    /// True when anything lies on the ray with `t_min < t < t_max` (shadow rays).
    /// Stops at the first hit found.
    pub fn occluded(&self, ray: &Ray, t_min: f32, t_max: f32) -> bool {
        wide::occluded(self, ray, t_min, t_max)
    }

    /// Any-hit for up to four rays at once (e.g. the shadow rays from one point
    /// to an area light's corners): bit `j` of the result is set when ray `j`,
    /// selected by bit `j` of `active`, hits something with
    /// `t_min[j] < t < t_max[j]`. Exactly `occluded(&rays[j], t_min[j], t_max[j])`
    /// for every active ray: [`Bvh::occluded8`] with four lanes empty.
    pub fn occluded4(&self, rays: &[Ray; 4], t_min: [f32; 4], t_max: [f32; 4], active: u32) -> u32 {
        packet::occluded4(self, rays, t_min, t_max, active)
    }

    /// Nearest hits of a packet of [`PACKET_LANES`] rays: entry `j` is exactly
    /// `intersect(&rays[j], t_min[j], t_max[j])` (same `t`, `u`, `v`, `prim`, bit
    /// for bit) for every ray selected by bit `j` of `active`, `None` for the others.
    ///
    /// Made for camera rays: a 4×2 block of pixels seen from one eye. The packet
    /// walks the tree once (interval-arithmetic bounds of all rays per node, then
    /// each ray's own box and triangle tests at the leaves, eight rays per AVX
    /// instruction). It is fastest when the rays are coherent; any rays give the
    /// right answer. Rays whose direction components differ in sign on some axis,
    /// have a zero or non-finite component or a non-finite origin, a machine
    /// without AVX and [`Bvh::set_simd`]`(false)` fall back to single-ray queries.
    ///
    /// ```
    /// use isin_tracer::bvh::{Bvh, PACKET_LANES};
    /// use isin_tracer::geometry::Ray;
    /// use isin_tracer::shapes::Triangle;
    /// use isin_tracer::Vec3;
    ///
    /// let v = [Vec3::new(-9.0, 0.0, -9.0), Vec3::new(9.0, 0.0, -9.0), Vec3::new(0.0, 0.0, 9.0)];
    /// let floor = Triangle { v };
    /// let bvh = Bvh::build(&[floor]);
    /// // A 4×2 block of pixels seen from one eye; bit j of `active` selects ray j
    /// // (clear the bits of pixels outside the tile).
    /// let eye = Vec3::new(0.0, 2.0, 5.0);
    /// let rays: [Ray; PACKET_LANES] = std::array::from_fn(|j| {
    ///     let (px, py) = ((j % 4) as f32, (j / 4) as f32);
    ///     Ray::new(eye, Vec3::new(px * 0.01, -0.5 - py * 0.01, -1.0).normalize())
    /// });
    /// let hits = bvh.intersect8(&rays, [0.0; PACKET_LANES], [f32::INFINITY; PACKET_LANES], 0xff);
    /// for (j, hit) in hits.iter().enumerate() {
    ///     // The same bits as the single-ray query.
    ///     assert_eq!(*hit, bvh.intersect(&rays[j], 0.0, f32::INFINITY));
    ///     assert!(hit.is_some());
    /// }
    /// ```
    pub fn intersect8(
        &self,
        rays: &[Ray; PACKET_LANES],
        t_min: [f32; PACKET_LANES],
        t_max: [f32; PACKET_LANES],
        active: u8,
    ) -> [Option<Hit>; PACKET_LANES] {
        packet8::intersect8(self, rays, t_min, t_max, active)
    }

    /// Any-hit for a packet of [`PACKET_LANES`] rays (e.g. shadow rays from one
    /// shading point to points on an area light): bit `j` of the result is
    /// exactly `occluded(&rays[j], t_min[j], t_max[j])` for every ray selected by
    /// bit `j` of `active`, 0 for the others. Traversal as in [`Bvh::intersect8`].
    pub fn occluded8(
        &self,
        rays: &[Ray; PACKET_LANES],
        t_min: [f32; PACKET_LANES],
        t_max: [f32; PACKET_LANES],
        active: u8,
    ) -> u8 {
        packet8::occluded8(self, rays, t_min, t_max, active)
    }

    /// Whether nothing can block a segment inside `shaft` that ends at most
    /// `1 − 10⁻³` of the way to a point of the light whose corners (or
    /// position) are `light`: `Some` with the planes of the surfaces left
    /// out (those with the whole light on one side, see `shaft`), which the
    /// segment's start must clear; `None` when a triangle may block it or
    /// there are more than [`SURFACE_PLANES`] such surfaces. `margin` covers
    /// rounding, in world units.
    pub fn shaft_clear(&self, shaft: &Shaft, light: &[Vec3], margin: f32) -> Option<SurfacePlanes> {
        shaft::shaft_clear(self, shaft, light, margin)
    }

    /// An entry node for shadow rays inside `shaft`: up to eight subtrees
    /// that hold every triangle overlapping it (`None` for an empty tree).
    pub fn shaft_entry(&self, shaft: &Shaft) -> Option<ShaftEntry> {
        shaft::shaft_entry(self, shaft)
    }

    /// [`Bvh::occluded`] for a ray that lies inside the shaft `entry` was
    /// made for (up to `t_max`): the same answer, from a walk that starts at
    /// `entry`'s subtrees instead of the root. The triangles left out of
    /// them lie outside the shaft, so the ray cannot hit them.
    #[inline]
    pub fn occluded_from(&self, entry: &ShaftEntry, ray: &Ray, t_min: f32, t_max: f32) -> bool {
        wide::occluded_from(self, &entry.0, ray, t_min, t_max)
    }

    /// Chooses the SIMD box test (the default, where the machine has one) or
    /// the scalar one. Both give the same bits; this exists so tests can prove it.
    pub fn set_simd(&mut self, on: bool) {
        self.scalar_only = !on;
    }

    /// True when queries use the SIMD box test.
    pub fn simd_active(&self) -> bool {
        wide::SIMD_AVAILABLE && !self.scalar_only
    }

    /// Allows (the default) or forbids the AVX box test, which is used where the
    /// CPU has AVX and SIMD is on; without it the SSE one is. All give the same
    /// bits; this exists so tests can prove it.
    pub fn set_avx(&mut self, on: bool) {
        self.no_avx = !on;
    }

    /// True when queries use the AVX box test (checked at run time).
    pub fn avx_active(&self) -> bool {
        #[cfg(target_arch = "x86_64")]
        if !self.scalar_only && !self.no_avx {
            return std::arch::is_x86_feature_detected!("avx");
        }
        false
    }

    /// Bytes the tree and its triangle data occupy (8- and 4-wide nodes,
    /// precomputed triangles, primitive ids). The binary tree the builder makes is dropped
    /// once it has been collapsed.
    pub fn memory_bytes(&self) -> usize {
        use std::mem::size_of;
        self.wide.len() * size_of::<wide::WideNode>()
            + self.narrow.len() * size_of::<wide::NarrowNode>()
            + self.blocks.len() * size_of::<blocks::TriBlock>()
            + self.prim_ids.len() * size_of::<u32>()
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.count
    }

    /// Number of nodes of the tree rays traverse (8-wide and 4-wide nodes).
    pub fn node_count(&self) -> usize {
        self.wide.len() + self.narrow.len()
    }

    /// Bounding box of everything (empty box for the empty BVH).
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// Checks the tree's invariants:
    /// * the empty BVH has no nodes, triangles or ids;
    /// * every node is reached exactly once from the root (wide node 0), within
    ///   [`MAX_DEPTH`] levels, and comes after its parent when of the same kind;
    ///   4-wide nodes have only leaf children;
    /// * every interior child's box contains the boxes of its own children;
    /// * leaves hold 1..=[`MAX_LEAF_SIZE`] triangles within one block, every
    ///   non-empty lane is in exactly one leaf, and each leaf's box contains its
    ///   triangles' vertices (NaN coordinates, which can never be hit, are not checked);
    /// * the lane-to-input map covers every primitive exactly once.
    pub fn validate(&self) -> Result<(), InvalidBvh> {
        let fail = |node: usize, problem: String| Err(InvalidBvh { node, problem });
        let n = self.count;
        if self.prim_ids.len() != 4 * self.blocks.len() {
            return fail(0, format!("{} blocks but {} lane ids", self.blocks.len(), self.prim_ids.len()));
        }
        if self.wide.is_empty() {
            return if n == 0 && self.blocks.is_empty() && self.narrow.is_empty() {
                Ok(())
            } else {
                fail(0, format!("{n} triangles but no nodes"))
            };
        }
        let mut seen_prim = vec![false; n];
        for &p in self.prim_ids.iter().filter(|&&p| p != u32::MAX) {
            match seen_prim.get_mut(p as usize) {
                Some(seen) if !*seen => *seen = true,
                _ => return fail(0, format!("primitive id {p} out of range or repeated")),
            }
        }
        if let Some(p) = seen_prim.iter().position(|s| !s) {
            return fail(0, format!("primitive {p} is in no lane"));
        }
        wide::validate(self)
    }
}

/// Containment that only fails on a definite "outside": a NaN coordinate (a
/// triangle that can never be hit) does not count as sticking out.
fn contains_point(b: &Aabb, p: Vec3) -> bool {
    !(p.cmplt(b.min).any() || p.cmpgt(b.max).any())
}

fn contains_box(outer: &Aabb, inner: &Aabb) -> bool {
    outer.min.cmple(inner.min).all() && inner.max.cmple(outer.max).all()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(n: usize) -> Vec<Triangle> {
        let p = |i: usize, j: usize| Vec3::new(i as f32, (i * j % 7) as f32 * 0.1, j as f32);
        let mut tris = Vec::new();
        for i in 0..n {
            for j in 0..n {
                tris.push(Triangle { v: [p(i, j), p(i + 1, j), p(i, j + 1)] });
            }
        }
        tris
    }

    #[test]
    fn validate_accepts_built_trees_and_catches_corruption() {
        let bvh = Bvh::build(&grid(20));
        bvh.validate().expect("freshly built tree is valid");
        assert!(bvh.wide.len() > 1);

        let mut shrunk = bvh.clone();
        let (node, slot) = wide::first_leaf_slot(&shrunk.wide).expect("a leaf");
        wide::shrink_slot(&mut shrunk.wide[node], slot, 0.5);
        assert!(shrunk.validate().is_err(), "a leaf box that no longer holds its triangle");

        let mut dup = bvh.clone();
        let used: Vec<usize> = (0..dup.prim_ids.len()).filter(|&i| dup.prim_ids[i] != u32::MAX).collect();
        dup.prim_ids[used[1]] = dup.prim_ids[used[0]];
        assert!(dup.validate().is_err(), "a primitive listed twice");

        let mut root = bvh.clone();
        root.bounds.max.y -= 1.0;
        assert!(root.validate().is_err(), "a child box sticking out of the whole tree's box");

        let mut narrow = bvh.clone();
        assert!(!narrow.narrow.is_empty(), "a grid has small leaf clusters");
        narrow.narrow[0].child[0] = 1;
        assert!(narrow.validate().is_err(), "a narrow node with an interior child");

        let mut cut = bvh;
        cut.wide.pop();
        assert!(cut.validate().is_err(), "a dangling child index");
    }

    #[test]
    fn prefetching_changes_no_answer() {
        let tris = grid(40);
        let plain = Bvh::build(&tris);
        assert!(!plain.prefetch, "a small tree does not prefetch");
        let mut hinted = plain.clone();
        hinted.prefetch = true;
        let mut next = crate::sampling::Sampler::new(3, 1, 4, 1).stream();
        let mut hits = 0;
        for _ in 0..4000 {
            let o = Vec3::new(next() * 50.0 - 5.0, next() * 6.0 - 1.0, next() * 50.0 - 5.0);
            let dir = Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5);
            let ray = Ray::new(o, dir);
            let a = plain.intersect(&ray, 0.0, f32::INFINITY);
            assert_eq!(a, hinted.intersect(&ray, 0.0, f32::INFINITY));
            assert_eq!(plain.occluded(&ray, 0.0, 30.0), hinted.occluded(&ray, 0.0, 30.0));
            hits += a.is_some() as usize;
        }
        assert!(hits > 500, "{hits} hits");
    }

    #[test]
    fn leaves_are_small_and_cover_every_triangle_once() {
        let tris = grid(30);
        let bvh = Bvh::build(&tris);
        let mut ids: Vec<u32> = bvh.prim_ids.iter().copied().filter(|&i| i != u32::MAX).collect();
        ids.sort_unstable();
        assert_eq!(ids, (0..tris.len() as u32).collect::<Vec<_>>());
        assert!(bvh.blocks.len() * 4 < tris.len() * 11 / 10, "blocks are nearly full");
        for (k, &id) in bvh.prim_ids.iter().enumerate() {
            if id != u32::MAX {
                assert_eq!(bvh.blocks[k / 4].get(k % 4), PreTriangle::new(&tris[id as usize]));
            }
        }
    }
}

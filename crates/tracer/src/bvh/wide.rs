//! The 8-wide BVH that rays actually traverse, collapsed from the binary tree.
//!
//! **Narrow nodes.** A node with at most four children is stored as a 4-wide
//! [`NarrowNode`] (128 bytes instead of 224): the collapse stops short of eight
//! children only where nothing but leaves remain, so these are the many small
//! leaf clusters at the bottom of the tree (a third to two thirds of its
//! nodes). An interior child word with [`NARROW`] set points into the narrow
//! nodes. Their box test is the SSE one on their four slots, which computes
//! exactly what the 8-wide tests compute on the same four slots; leaves are
//! tested in slot order as in a wide node, so hits and traversal order are
//! what an all-wide tree gives.
//!
//! Each [`WideNode`] holds the boxes of up to eight children in structure-of-arrays
//! form (all eight `min.x`, then all eight `min.y`, …), so one AVX instruction
//! sequence (or two SSE ones) slab-tests all eight against a ray. A child is
//! either another `WideNode` or a leaf (a run of 1..=4 lanes of one triangle
//! block, see `blocks`); unused slots are empty leaves with inverted
//! (`+inf..-inf`) boxes.
//!
//! **Collapsing.** Starting from the binary root, a wide node takes the binary
//! node's two children and keeps replacing the child with the largest box
//! surface (ties: the first) by its own two children until it has eight or only
//! leaves remain. The result is a pure function of the binary tree.
//!
//! **Same bits with and without SIMD.** The AVX path ([`entries_avx`]), the SSE
//! path ([`entries_sse`]) and the scalar path ([`entries_scalar`]) perform the
//! same IEEE operations in the same order on every lane: `(plane − origin) ·
//! inv_dir`, then `maxps(t, acc)` / `minps(t, acc)`, which are exactly
//! `if t > acc { t } else { acc }` and `if t < acc { t } else { acc }` —
//! including for NaN and signed zeros — and no fused multiply-add. So the entry
//! distances, hence the traversal order and every hit, are identical; tests
//! compare the paths on random boxes, on random rays through real meshes and on
//! rendered bytes. SSE2 is part of the x86_64 baseline; AVX is detected at run
//! time (`is_x86_feature_detected!`), and the traversal loops are then compiled
//! for AVX as a whole (`#[target_feature]`) so the box test inlines. Other
//! architectures use the scalar path.

use super::blocks::{self, Hits4, TriBlock};
use super::build::{Slot, load};
use super::{Bvh, InvalidBvh, MAX_DEPTH, MAX_LEAF_SIZE, Node, contains_box, contains_point};
use crate::geometry::{Aabb, Ray};
use crate::shapes::Hit;
use rayon::prelude::*;
use std::mem::MaybeUninit;

/// Slab-test exits are scaled by this factor (1 + 2γ₃ rounded up, after Ize,
/// "Robust BVH Ray Traversal", JCGT 2013) so that rounding in the box test never
/// culls a box the exact ray passes through. It only ever visits slightly more.
pub(super) const ROBUST_EXIT: f32 = 1.0 + 4.0 * f32::EPSILON;

/// Marks a leaf in [`WideNode::child`].
pub(super) const LEAF: u32 = 1 << 31;
/// A leaf's triangle count minus one sits at this bit of its child word.
const COUNT_SHIFT: u32 = 29;
/// A leaf's first lane (or, during the build, first triangle) in the low bits.
const FIRST_MASK: u32 = (1 << COUNT_SHIFT) - 1;

/// The child word of a leaf of `count` (1..=4) triangles starting at `first`.
#[inline(always)]
pub(super) fn leaf_word(first: u32, count: u32) -> u32 {
    debug_assert!((1..=4).contains(&count) && first <= FIRST_MASK);
    LEAF | (count - 1) << COUNT_SHIFT | first
}

/// `(first, count)` of a leaf's child word.
#[inline(always)]
pub(super) fn leaf_range(word: u32) -> (u32, u32) {
    (word & FIRST_MASK, ((word >> COUNT_SHIFT) & 3) + 1)
}

/// The word of an unused slot: a one-triangle leaf at lane 0, behind an empty
/// box. A ray only enters an empty box when its origin or direction is not
/// finite, and such a ray never hits a triangle, so this is harmless.
const UNUSED: u32 = LEAF;

// Every lane index (at most four lanes per triangle) fits the child word.
const _: () = assert!(4 * super::MAX_TRIANGLES <= FIRST_MASK as usize + 1);

/// Children per wide node.
pub(super) const W: usize = 8;

/// Children per narrow node.
pub(super) const W4: usize = 4;

/// Flag of an interior child word whose node is a [`NarrowNode`] (the low bits
/// index `Bvh::narrow`); without it they index `Bvh::wide`.
pub(super) const NARROW: u32 = 1 << 30;

/// A node of `N` children: their boxes in structure-of-arrays form and their
/// child words. Aligned to 32 bytes, so no row straddles a cache line.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(32))]
pub(super) struct Slots<const N: usize> {
    /// `bounds[a][k]`: for `a` in 0..3 the lower corner of child `k` on axis
    /// `a`, for `a` in 3..6 the upper corner on axis `a − 3`.
    pub(super) bounds: [[f32; N]; 6],
    /// Interior child: index of its node (bit 31 clear; [`NARROW`] set for a
    /// narrow node). Leaf: [`leaf_word`] of its first lane (`4 · block + lane`,
    /// see `blocks`; during the build, its first triangle in leaf order) and
    /// triangle count. Unused: [`UNUSED`].
    pub(super) child: [u32; N],
}

/// A node of the 8-wide BVH (224 bytes).
pub(super) type WideNode = Slots<W>;

/// A node of at most four children (128 bytes with its padding): made by the
/// collapse wherever a wide node would use at most four slots — always a node
/// whose children are all leaves. Its box tests compute, slot for slot, what
/// they compute on a wide node with the same first four slots and empty rest,
/// so traversal (order included) is the same as if it were one.
pub(super) type NarrowNode = Slots<W4>;

const _: () = assert!(std::mem::size_of::<WideNode>() == 224);
const _: () = assert!(std::mem::size_of::<NarrowNode>() == 128);

impl<const N: usize> Slots<N> {
    pub(super) const EMPTY: Self = Slots {
        bounds: [
            [f32::INFINITY; N],
            [f32::INFINITY; N],
            [f32::INFINITY; N],
            [f32::NEG_INFINITY; N],
            [f32::NEG_INFINITY; N],
            [f32::NEG_INFINITY; N],
        ],
        child: [UNUSED; N],
    };

    /// Sets slot `k`'s box.
    pub(super) fn set_box(&mut self, k: usize, b: &Aabb) {
        for a in 0..3 {
            self.bounds[a][k] = b.min[a];
            self.bounds[a + 3][k] = b.max[a];
        }
    }

    fn set(&mut self, k: usize, n: &Node) {
        for a in 0..3 {
            self.bounds[a][k] = n.min[a];
            self.bounds[a + 3][k] = n.max[a];
        }
    }

    /// True when slot `k` holds nothing (its box is empty; real boxes, NaN-free, never are).
    fn is_unused(&self, k: usize) -> bool {
        self.child[k] == UNUSED && self.bounds[0][k] > self.bounds[3][k]
    }

    /// Child `k`'s box.
    fn child_bounds(&self, k: usize) -> Aabb {
        let b = &self.bounds;
        Aabb {
            min: glam::Vec3::new(b[0][k], b[1][k], b[2][k]),
            max: glam::Vec3::new(b[3][k], b[4][k], b[5][k]),
        }
    }

    /// Points the leaf slots (whose words hold the leaf's first triangle in
    /// leaf order) at their lanes (`lane_of[first triangle]`).
    fn place_leaves(&mut self, lane_of: &[u32]) {
        for k in 0..N {
            if self.child[k] & LEAF != 0 && !self.is_unused(k) {
                let (first, count) = leaf_range(self.child[k]);
                self.child[k] = leaf_word(lane_of[first as usize], count);
            }
        }
    }
}

/// A node of either kind, as traversal sees it.
#[derive(Clone, Copy, Debug)]
pub(super) enum NodeRef<'a> {
    /// An 8-wide node.
    Wide(&'a WideNode),
    /// A 4-wide node.
    Narrow(&'a NarrowNode),
}

impl<'a> NodeRef<'a> {
    /// The node an interior child word (or 0, the root) points to.
    #[inline(always)]
    pub(super) fn of(bvh: &'a Bvh, word: u32) -> Self {
        if word & NARROW == 0 {
            NodeRef::Wide(&bvh.wide[word as usize])
        } else {
            NodeRef::Narrow(&bvh.narrow[(word & !NARROW) as usize])
        }
    }

    /// The child words (8 or 4).
    #[inline(always)]
    pub(super) fn children(self) -> &'a [u32] {
        match self {
            NodeRef::Wide(n) => &n.child,
            NodeRef::Narrow(n) => &n.child,
        }
    }

    /// Coordinate `a` of child `k`'s box (see [`Slots::bounds`]).
    #[inline(always)]
    pub(super) fn bound(self, a: usize, k: usize) -> f32 {
        match self {
            NodeRef::Wide(n) => n.bounds[a][k],
            NodeRef::Narrow(n) => n.bounds[a][k],
        }
    }

    /// True when slot `k` holds nothing.
    fn is_unused(self, k: usize) -> bool {
        match self {
            NodeRef::Wide(n) => n.is_unused(k),
            NodeRef::Narrow(n) => n.is_unused(k),
        }
    }

    /// Child `k`'s box.
    fn child_bounds(self, k: usize) -> Aabb {
        match self {
            NodeRef::Wide(n) => n.child_bounds(k),
            NodeRef::Narrow(n) => n.child_bounds(k),
        }
    }
}

/// Checks the wide tree's invariants (see [`Bvh::validate`]; the primitive map is checked there).
pub(super) fn validate(bvh: &Bvh) -> Result<(), InvalidBvh> {
    let fail = |node: usize, problem: String| Err(InvalidBvh { node, problem });
    // Wide nodes first, then narrow ones: `node` in errors is this position.
    let at = |word: u32| {
        if word & NARROW == 0 { word as usize } else { bvh.wide.len() + (word & !NARROW) as usize }
    };
    let in_range = |word: u32| {
        if word & NARROW == 0 {
            (word as usize) < bvh.wide.len()
        } else {
            ((word & !NARROW) as usize) < bvh.narrow.len()
        }
    };
    let mut visited = vec![false; bvh.wide.len() + bvh.narrow.len()];
    let mut covered = vec![false; bvh.prim_ids.len()];
    // (node, depth, the box its children must lie in)
    let mut stack = vec![(0u32, 0usize, bvh.bounds)];
    while let Some((word, depth, outer)) = stack.pop() {
        let i = at(word);
        if !in_range(word) || visited[i] {
            return fail(i, "child index out of range or reached twice".into());
        }
        visited[i] = true;
        if depth > MAX_DEPTH {
            return fail(i, format!("depth {depth} exceeds {MAX_DEPTH}"));
        }
        let node = NodeRef::of(bvh, word);
        for (k, &word) in node.children().iter().enumerate() {
            if node.is_unused(k) {
                continue;
            }
            let b = node.child_bounds(k);
            if !contains_box(&outer, &b) {
                return fail(i, format!("child {k}'s box is not inside its parent's"));
            }
            if word & LEAF == 0 {
                if i >= bvh.wide.len() {
                    return fail(i, format!("child {k} of a narrow node is not a leaf"));
                }
                let child = at(word);
                if child <= i && (child < bvh.wide.len()) == (i < bvh.wide.len()) {
                    return fail(i, format!("child {k} ({child}) does not come after its parent"));
                }
                stack.push((word, depth + 1, b));
                continue;
            }
            let (child, count) = leaf_range(word);
            let (child, count) = (child as usize, count as usize);
            if count == 0 || count > MAX_LEAF_SIZE || child % 4 + count > 4 || child / 4 >= bvh.blocks.len() {
                return fail(i, format!("leaf lanes {child}+{count} invalid"));
            }
            for (lane, slot) in covered.iter_mut().enumerate().skip(child).take(count) {
                if std::mem::replace(slot, true) {
                    return fail(i, format!("lane {lane} is in two leaves"));
                }
                if bvh.prim_ids[lane] == u32::MAX {
                    return fail(i, format!("lane {lane} is empty but in a leaf"));
                }
                let tri = bvh.blocks[lane / 4].get(lane % 4);
                if !tri.vertices().iter().all(|&p| contains_point(&b, p)) {
                    return fail(i, format!("lane {lane}'s triangle sticks out of its leaf's box"));
                }
            }
        }
    }
    if let Some(i) = visited.iter().position(|v| !v) {
        return fail(i, "unreachable node".into());
    }
    if let Some(lane) = (0..covered.len()).find(|&l| !covered[l] && bvh.prim_ids[l] != u32::MAX) {
        return fail(0, format!("lane {lane} holds a triangle but is in no leaf"));
    }
    Ok(())
}

/// The first (node, slot) holding a leaf (for tests that corrupt a tree).
#[cfg(test)]
pub(super) fn first_leaf_slot(wide: &[WideNode]) -> Option<(usize, usize)> {
    wide.iter()
        .enumerate()
        .find_map(|(i, n)| (0..W).find(|&k| n.child[k] & LEAF != 0 && !n.is_unused(k)).map(|k| (i, k)))
}

/// Moves the upper x plane of slot `k` down by `by` (for tests that corrupt a tree).
#[cfg(test)]
pub(super) fn shrink_slot(node: &mut WideNode, k: usize, by: f32) {
    node.bounds[3][k] -= by;
}

/// The collapsed tree: wide and narrow nodes, each kind in depth-first order;
/// the root is wide node 0.
#[derive(Debug, Default)]
pub(super) struct Collapsed {
    /// 8-wide nodes.
    pub(super) wide: Vec<WideNode>,
    /// 4-wide nodes.
    pub(super) narrow: Vec<NarrowNode>,
}

/// Collapses the binary tree in `nodes` (depth-first, see [`Node`] and
/// `build::Slot`; slots no node points to are ignored) into 8-wide nodes, and
/// 4-wide ones where at most four children remain.
///
/// The builder has already turned every binary subtree that should be one leaf
/// of the wide tree into a leaf node (see `build`), so here a leaf is a leaf.
pub(super) fn collapse(nodes: &[Slot]) -> Collapsed {
    // Room for the usual node counts (about 1/20 and 1/30 of the binary slots);
    // pages never written are never resident.
    let mut out = Collapsed {
        wide: Vec::with_capacity(nodes.len() / 12 + 1),
        narrow: Vec::with_capacity(nodes.len() / 16 + 1),
    };
    let Some(root) = nodes.first().map(load) else { return out };
    if root.is_leaf() {
        let mut n = WideNode::EMPTY;
        n.set(0, &root);
        n.child[0] = leaf_word(root.offset, root.count);
        out.wide.push(n);
    } else {
        collapse_node(nodes, 0, &root, 0, &mut out);
    }
    out
}

/// Points every leaf slot of `tree` (whose words still hold the leaf's first
/// triangle in leaf order) at its lanes: `leaves[i]` is `(first, count)` of a
/// leaf and `starts[i]` its first lane (`blocks::pack`). `lane_of` is scratch
/// space, one word per triangle with any contents (only the words at leaves'
/// first triangles are read, and they are written first): the builder passes a
/// buffer it no longer needs rather than have fresh memory allocated.
pub(super) fn place_leaves(tree: &mut Collapsed, leaves: &[(u32, u32)], starts: &[u32], lane_of: &mut [u32]) {
    for (&(first, _), &start) in leaves.iter().zip(starts) {
        lane_of[first as usize] = start;
    }
    let lane_of = &*lane_of;
    rayon::join(
        || tree.wide.par_iter_mut().for_each(|w| w.place_leaves(lane_of)),
        || tree.narrow.par_iter_mut().for_each(|w| w.place_leaves(lane_of)),
    );
}

/// SAH cost of visiting a wide node's box, relative to one triangle test, when
/// deciding whether to merge a small binary subtree into one leaf.
pub(super) const MERGE_TRAVERSAL_COST: f32 = 1.0;

/// SAH cost of testing one leaf, in the same unit: its 1..=4 triangles are
/// tested at once (see `blocks`), so the cost does not depend on how many.
pub(super) const LEAF_COST: f32 = 1.5;

/// A child of a wide node: its binary node's index, the node and its box's area.
type Kid = (usize, Node, f32);

/// The children of the wide node for binary interior node `node` (at index `i`).
///
/// Starting from the node's two children, it keeps replacing the interior child
/// with the largest box surface (ties: the first) by its own two children until
/// it has eight or only leaves remain.
fn frontier(nodes: &[Slot], i: usize, node: &Node) -> ([Kid; W], usize) {
    let entry = |k: usize| {
        let n = load(&nodes[k]);
        (k, n, n.bounds().area())
    };
    let mut kids = [(0usize, *node, 0.0f32); W];
    (kids[0], kids[1]) = (entry(i + 1), entry(node.offset as usize));
    let mut len = 2;
    while len < W {
        let mut pick: Option<(usize, f32)> = None;
        for (slot, (_, n, area)) in kids[..len].iter().enumerate() {
            if !n.is_leaf() && pick.is_none_or(|(_, a)| *area > a) {
                pick = Some((slot, *area));
            }
        }
        let Some((slot, _)) = pick else { break };
        let (k, n, _) = kids[slot];
        kids.copy_within(slot + 1..len, slot + 2);
        kids[slot] = entry(k + 1);
        kids[slot + 1] = entry(n.offset as usize);
        len += 1;
    }
    (kids, len)
}

/// Appends the node for binary interior node `node`, at index `i` and `depth`
/// wide levels below the root, and its subtree (depth-first, children in slot
/// order); returns its child word. It is a narrow node when it has at most four
/// children (never the root).
///
/// Sequential: the build runs it next to the parallel `blocks::pack`, which
/// takes a little longer, so a second thread has the packing to share. (It
/// used to collapse the root's children's subtrees in parallel, into vectors of
/// their own that were then copied into place: a third more fresh memory for
/// the nodes, and page faults cost this machine about 1.5 µs per 4 KiB page,
/// serialised across threads.)
fn collapse_node(nodes: &[Slot], i: usize, node: &Node, depth: usize, out: &mut Collapsed) -> u32 {
    let (kids, len) = frontier(nodes, i, node);
    // The node's slot is taken before its children's (depth-first order).
    if depth > 0 && len <= W4 {
        let at = out.narrow.len();
        out.narrow.push(NarrowNode::EMPTY);
        out.narrow[at] = fill_slots(nodes, &kids[..len], depth, out);
        return NARROW | at as u32;
    }
    let at = out.wide.len();
    out.wide.push(WideNode::EMPTY);
    out.wide[at] = fill_slots(nodes, &kids[..len], depth, out);
    at as u32
}

/// A node of `N` slots holding `kids` (a node at `depth`), interior ones
/// collapsed below it.
fn fill_slots<const N: usize>(nodes: &[Slot], kids: &[Kid], depth: usize, out: &mut Collapsed) -> Slots<N> {
    let mut slots = Slots::<N>::EMPTY;
    for (slot, (k, n, _)) in kids.iter().enumerate() {
        slots.set(slot, n);
        slots.child[slot] = if n.is_leaf() {
            leaf_word(n.offset, n.count)
        } else {
            collapse_node(nodes, *k, n, depth + 1, out)
        };
    }
    slots
}

/// A ray prepared for wide box tests: per axis, which row of [`WideNode::bounds`]
/// holds the entry plane (the max plane when the direction is negative).
#[derive(Clone, Copy, Debug)]
pub(super) struct WideRay {
    origin: [f32; 3],
    inv_dir: [f32; 3],
    near: [usize; 3],
    far: [usize; 3],
}

impl WideRay {
    /// `1 / ±0` gives `±inf`, so axis-parallel rays need no special case.
    #[inline(always)]
    pub(super) fn new(ray: &Ray) -> Self {
        let inv = ray.dir.recip().to_array();
        // Sign bit, not `< 0`: -0 gives -inf, whose near plane is the max.
        let neg = |a: usize| inv[a].is_sign_negative() as usize;
        WideRay {
            origin: ray.origin.to_array(),
            inv_dir: inv,
            near: [3 * neg(0), 1 + 3 * neg(1), 2 + 3 * neg(2)],
            far: [3 - 3 * neg(0), 4 - 3 * neg(1), 5 - 3 * neg(2)],
        }
    }
}

/// `max(x, acc)`; returns `acc` when `x` is NaN (`acc` is never NaN).
#[inline(always)]
fn max_keep(x: f32, acc: f32) -> f32 {
    if x > acc { x } else { acc }
}

/// `min(x, acc)`; returns `acc` when `x` is NaN.
#[inline(always)]
fn min_keep(x: f32, acc: f32) -> f32 {
    if x < acc { x } else { acc }
}

/// Entry distance of the ray into each child's box within `(t_min, t_max)`,
/// `f32::INFINITY` where it misses. Scalar reference.
///
/// `(plane - origin) * inv_dir` is NaN only when the origin lies exactly on a
/// plane of an axis the ray is parallel to; `max_keep`/`min_keep` then keep the
/// running value, treating that slab as no constraint, which is conservative.
#[inline(always)]
fn entries_scalar<const N: usize>(node: &Slots<N>, r: &WideRay, t_min: f32, t_max: f32) -> ([f32; W], u32) {
    let mut out = [f32::INFINITY; W];
    let mut mask = 0;
    for (k, e) in out.iter_mut().enumerate().take(N) {
        let mut near = t_min;
        let mut far = t_max;
        for a in 0..3 {
            let t0 = (node.bounds[r.near[a]][k] - r.origin[a]) * r.inv_dir[a];
            let t1 = (node.bounds[r.far[a]][k] - r.origin[a]) * r.inv_dir[a];
            near = max_keep(t0, near);
            far = min_keep(t1, far);
        }
        if near <= far * ROBUST_EXIT {
            *e = near;
            mask |= 1 << k;
        }
    }
    (out, mask)
}

/// [`entries_scalar`] for four children at once (`at..at + 4`) with SSE (see
/// the module docs for why the bits are the same); writes their entries to `out`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn entries_sse4<const N: usize>(
    node: &Slots<N>,
    at: usize,
    r: &WideRay,
    t_min: f32,
    t_max: f32,
    out: &mut [f32; 4],
) -> u32 {
    use std::arch::x86_64::*;
    // SAFETY: SSE and SSE2 are part of the x86_64 baseline, so these
    // instructions exist on every machine this code is compiled for; the loads
    // read 16 bytes at `at` of a `[f32; N]` row (`at + 4 <= N`, checked by the
    // slice index) and the store writes the 16 bytes of `out` (unaligned access
    // is allowed).
    unsafe {
        let load = |a: &[f32; N]| _mm_loadu_ps(a[at..at + 4].as_ptr());
        let mut near = _mm_set1_ps(t_min);
        let mut far = _mm_set1_ps(t_max);
        for a in 0..3 {
            let o = _mm_set1_ps(r.origin[a]);
            let inv = _mm_set1_ps(r.inv_dir[a]);
            let t0 = _mm_mul_ps(_mm_sub_ps(load(&node.bounds[r.near[a]]), o), inv);
            let t1 = _mm_mul_ps(_mm_sub_ps(load(&node.bounds[r.far[a]]), o), inv);
            // maxps(x, acc) = x > acc ? x : acc; minps(x, acc) = x < acc ? x : acc.
            near = _mm_max_ps(t0, near);
            far = _mm_min_ps(t1, far);
        }
        let hit = _mm_cmple_ps(near, _mm_mul_ps(far, _mm_set1_ps(ROBUST_EXIT)));
        let e = _mm_or_ps(_mm_and_ps(hit, near), _mm_andnot_ps(hit, _mm_set1_ps(f32::INFINITY)));
        _mm_storeu_ps(out.as_mut_ptr(), e);
        _mm_movemask_ps(hit) as u32
    }
}

/// [`entries_scalar`] for all eight children with two SSE halves.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn entries_sse(node: &WideNode, r: &WideRay, t_min: f32, t_max: f32) -> ([f32; W], u32) {
    let (mut lo, mut hi) = ([0.0f32; 4], [0.0f32; 4]);
    let m = entries_sse4(node, 0, r, t_min, t_max, &mut lo)
        | entries_sse4(node, 4, r, t_min, t_max, &mut hi) << 4;
    let mut out = [0.0f32; W];
    out[..4].copy_from_slice(&lo);
    out[4..].copy_from_slice(&hi);
    (out, m)
}

/// [`entries_scalar`] for all eight children at once with AVX: the 256-bit
/// forms of the SSE instructions, which compute the same on every lane
/// (`vmaxps`/`vminps` return the second operand on NaN like `maxps`/`minps`).
///
/// # Safety
/// The CPU must support AVX; only call it from a function compiled with
/// `#[target_feature(enable = "avx")]` after checking that.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn entries_avx(node: &WideNode, r: &WideRay, t_min: f32, t_max: f32) -> ([f32; W], u32) {
    use std::arch::x86_64::*;
    // SAFETY: the caller guarantees AVX; the loads read the 32 bytes of a
    // `[f32; 8]` row and the store writes the 32 bytes of `out`.
    unsafe {
        let load = |a: &[f32; W]| _mm256_loadu_ps(a.as_ptr());
        let mut near = _mm256_set1_ps(t_min);
        let mut far = _mm256_set1_ps(t_max);
        for a in 0..3 {
            let o = _mm256_set1_ps(r.origin[a]);
            let inv = _mm256_set1_ps(r.inv_dir[a]);
            let t0 = _mm256_mul_ps(_mm256_sub_ps(load(&node.bounds[r.near[a]]), o), inv);
            let t1 = _mm256_mul_ps(_mm256_sub_ps(load(&node.bounds[r.far[a]]), o), inv);
            near = _mm256_max_ps(t0, near);
            far = _mm256_min_ps(t1, far);
        }
        let hit = _mm256_cmp_ps::<_CMP_LE_OQ>(near, _mm256_mul_ps(far, _mm256_set1_ps(ROBUST_EXIT)));
        let e = _mm256_blendv_ps(_mm256_set1_ps(f32::INFINITY), near, hit);
        let mut out = [0.0f32; W];
        _mm256_storeu_ps(out.as_mut_ptr(), e);
        (out, _mm256_movemask_ps(hit) as u32)
    }
}

/// Box entries, and a mask with bit `k` set where child `k` is hit. `AVX` may
/// only be set inside a function compiled for AVX on a machine that has it.
#[inline(always)]
pub(super) fn entries<const AVX: bool>(
    node: &WideNode,
    r: &WideRay,
    t_min: f32,
    t_max: f32,
    simd: bool,
) -> ([f32; W], u32) {
    #[cfg(target_arch = "x86_64")]
    {
        if AVX {
            // SAFETY: `AVX` is only set by the AVX entry points, which check the CPU.
            return unsafe { entries_avx(node, r, t_min, t_max) };
        }
        if simd {
            return entries_sse(node, r, t_min, t_max);
        }
    }
    let _ = simd;
    entries_scalar(node, r, t_min, t_max)
}

/// [`entries`] of a narrow node: one SSE sequence (the same bits as the first
/// half of a wide node's with the same children).
#[inline(always)]
pub(super) fn entries4(
    node: &NarrowNode,
    r: &WideRay,
    t_min: f32,
    t_max: f32,
    simd: bool,
) -> ([f32; W4], u32) {
    #[cfg(target_arch = "x86_64")]
    if simd {
        let mut out = [0.0f32; W4];
        let mask = entries_sse4(node, 0, r, t_min, t_max, &mut out);
        return (out, mask);
    }
    let _ = simd;
    let (e, mask) = entries_scalar(node, r, t_min, t_max);
    ([e[0], e[1], e[2], e[3]], mask)
}

/// True when this build has a SIMD box test (x86_64: SSE2, always present).
pub(super) const SIMD_AVAILABLE: bool = cfg!(target_arch = "x86_64");

/// Most entries a traversal stack holds: a wide node pushes at most `W - 1` of
/// its children and descends into another, at most [`MAX_DEPTH`] levels deep.
const STACK: usize = (W - 1) * MAX_DEPTH + W;

/// Fixed-size, uninitialised traversal stack (of wide node indices, with
/// their entry distances for nearest-hit queries): no per-ray memset.
pub(super) struct Stack<T: Copy> {
    items: [MaybeUninit<T>; STACK],
    len: usize,
}

impl<T: Copy> Stack<T> {
    #[inline(always)]
    pub(super) fn new() -> Self {
        Stack { items: [const { MaybeUninit::uninit() }; STACK], len: 0 }
    }

    #[inline(always)]
    pub(super) fn push(&mut self, item: T) {
        self.items[self.len] = MaybeUninit::new(item);
        self.len += 1;
    }

    #[inline(always)]
    pub(super) fn pop(&mut self) -> Option<T> {
        self.len = self.len.checked_sub(1)?;
        // SAFETY: every slot below the length was written by `push`.
        Some(unsafe { self.items[self.len].assume_init() })
    }
}

impl<T: Copy> Stack<T> {
    /// The top entry, if any.
    #[inline(always)]
    pub(super) fn peek(&self) -> Option<T> {
        let top = self.len.checked_sub(1)?;
        // SAFETY: every slot below the length was written by `push`.
        Some(unsafe { self.items[top].assume_init() })
    }
}

/// Asks the CPU to start loading the node an interior child word points to
/// (a hint: it changes no result).
#[inline(always)]
fn prefetch_node(bvh: &Bvh, word: u32) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        let (p, lines): (*const i8, usize) = if word & NARROW == 0 {
            match bvh.wide.get(word as usize) {
                Some(n) => (std::ptr::from_ref(n).cast(), 4),
                None => return,
            }
        } else {
            match bvh.narrow.get((word & !NARROW) as usize) {
                Some(n) => (std::ptr::from_ref(n).cast(), 2),
                None => return,
            }
        };
        for l in 0..lines {
            // SAFETY: SSE is part of the x86_64 baseline; a prefetch never
            // faults, and the addresses lie inside the node (`wrapping_add`).
            unsafe { _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(64 * l)) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (bvh, word);
}

/// Asks the CPU to start loading the triangle block of a leaf's child word (a hint).
#[inline(always)]
fn prefetch_block(blocks: &[TriBlock], word: u32) {
    #[cfg(target_arch = "x86_64")]
    if let Some(b) = blocks.get((leaf_range(word).0 / 4) as usize) {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        let p: *const i8 = std::ptr::from_ref(b).cast();
        for l in 0..3 {
            // SAFETY: SSE is part of the x86_64 baseline; a prefetch never
            // faults (`wrapping_add`: no pointer arithmetic promises).
            unsafe { _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(64 * l)) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (blocks, word);
}

impl Stack<(u32, f32)> {
    /// Pushes the interior children in the mask `inner` whose entry distance
    /// `e[k]` is at most `limit`, so that they pop nearest first, and among
    /// equal distances in slot order — the order [`descend_nearest`] visits
    /// them in. An insertion sort into the top of the stack.
    #[inline(always)]
    pub(super) fn push_nearest_last(
        &mut self,
        children: &[u32; W],
        e: &[f32; W],
        mut inner: u32,
        limit: f32,
    ) {
        let base = self.len;
        while inner != 0 {
            let k = inner.trailing_zeros() as usize;
            inner &= inner - 1;
            let t = e[k];
            if t > limit {
                continue;
            }
            // Entries at or nearer than `t` (pushed earlier, so from lower
            // slots) move up: they pop first.
            let mut j = self.len;
            while j > base {
                // SAFETY: `base <= j - 1 < len`: written by `push` or below.
                let below = unsafe { self.items[j - 1].assume_init() };
                if below.1 > t {
                    break;
                }
                self.items[j] = MaybeUninit::new(below);
                j -= 1;
            }
            self.items[j] = MaybeUninit::new((children[k], t));
            self.len += 1;
        }
    }
}

/// A ray prepared for the triangle tests of leaves.
pub(super) struct LeafRay<'a> {
    ray: &'a Ray,
    #[cfg(target_arch = "x86_64")]
    sse: blocks::RaySse,
    simd: bool,
}

impl<'a> LeafRay<'a> {
    #[inline(always)]
    pub(super) fn new(ray: &'a Ray, simd: bool) -> Self {
        LeafRay {
            ray,
            #[cfg(target_arch = "x86_64")]
            sse: blocks::RaySse::new(ray),
            simd,
        }
    }

    /// Hits on leaf `(first lane, count)`.
    #[inline(always)]
    pub(super) fn hits(&self, blocks: &[TriBlock], first: u32, count: u32, t_min: f32, t_max: f32) -> Hits4 {
        let block = &blocks[(first / 4) as usize];
        let lanes = ((1u32 << count) - 1) << (first % 4);
        #[cfg(target_arch = "x86_64")]
        if self.simd {
            return blocks::hits_sse(block, &self.sse, t_min, t_max, lanes);
        }
        let _ = self.simd;
        blocks::hits_scalar(block, self.ray, t_min, t_max, lanes)
    }
}

/// The nearest-hit traversal's next step at a node: of the interior children
/// in the mask `inner` whose entry distance `e[k]` is at most `limit`, pushes
/// all but the nearest onto `stack`, farthest first, and returns the nearest
/// (stable on ties, so deterministic); `None` when no child qualifies.
#[inline(always)]
pub(super) fn descend_nearest(
    children: &[u32],
    e: &[f32; W],
    mut inner: u32,
    limit: f32,
    stack: &mut Stack<(u32, f32)>,
) -> Option<u32> {
    let mut order = [(0.0f32, 0u32); W];
    let mut n = 0;
    while inner != 0 {
        let k = inner.trailing_zeros() as usize;
        inner &= inner - 1;
        let t = e[k];
        if t > limit {
            continue;
        }
        let mut j = n;
        while j > 0 && order[j - 1].0 > t {
            order[j] = order[j - 1];
            j -= 1;
        }
        order[j] = (t, children[k]);
        n += 1;
    }
    if n == 0 {
        return None;
    }
    for &(t, c) in order[1..n].iter().rev() {
        stack.push((c, t));
    }
    Some(order[0].1)
}

/// Bit `k` set where child `k` of `node` is a leaf or unused (bit 31 of its
/// word). `AVX` as in [`entries`].
#[inline(always)]
pub(super) fn leaf_bits<const AVX: bool>(node: &WideNode) -> u32 {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        if AVX {
            // SAFETY: `AVX` is only set by the AVX entry points, which check
            // the CPU; the load reads the 32 bytes of `child`.
            return unsafe {
                _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_loadu_si256(node.child.as_ptr().cast()))) as u32
            };
        }
        // SAFETY: SSE2 is part of the x86_64 baseline; the loads read the two
        // 16-byte halves of `child`.
        return unsafe {
            let half = |at: usize| _mm_castsi128_ps(_mm_loadu_si128(node.child[at..at + 4].as_ptr().cast()));
            (_mm_movemask_ps(half(0)) | _mm_movemask_ps(half(4)) << 4) as u32
        };
    }
    #[allow(unreachable_code)]
    node.child.iter().enumerate().fold(0, |m, (k, &c)| m | (c >> 31) << k)
}

/// Tests the leaf of child word `word` for the nearest-hit query: a hit nearer
/// than `best_t` (the lowest lane on ties) becomes the best, as `(lane, u, v)`.
/// With `ids` (large trees), a new best lane's entry there starts loading: the
/// hit's primitive index is read when the walk ends, and on a large mesh it is
/// a cache miss that the rest of the walk can hide.
#[inline(always)]
fn nearest_in_leaf(
    lr: &LeafRay,
    blocks: &[TriBlock],
    word: u32,
    t_min: f32,
    best_t: &mut f32,
    best: &mut Option<(u32, f32, f32)>,
    ids: Option<&[u32]>,
) {
    let (first, count) = leaf_range(word);
    let h = lr.hits(blocks, first, count, t_min, *best_t);
    let mut m = h.mask;
    let mut improved = None;
    while m != 0 {
        let lane = m.trailing_zeros() as usize;
        m &= m - 1;
        if h.t[lane] < *best_t {
            *best_t = h.t[lane];
            let at = (first & !3) + lane as u32;
            *best = Some((at, h.u[lane], h.v[lane]));
            improved = Some(at);
        }
    }
    #[cfg(target_arch = "x86_64")]
    if let (Some(ids), Some(at)) = (ids, improved) {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        // SAFETY: SSE is part of the x86_64 baseline; a prefetch never faults
        // (`wrapping_add`: no pointer arithmetic promises).
        unsafe { _mm_prefetch::<_MM_HINT_T0>(ids.as_ptr().wrapping_add(at as usize).cast()) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (ids, improved);
}

/// Nearest hit (see [`Bvh::intersect`]).
///
/// At each node the hit leaves are tested at once (in lane order: the order
/// only decides between hits at bit-identical `t`, and it is the same on every
/// machine); the hit interior children still in front of the best hit are
/// pushed so that they pop nearest first (slot order on ties), and the top is
/// visited next ([`Stack::push_nearest_last`]). Within a
/// leaf, the nearest lane wins, the lowest lane on ties — what testing the
/// lanes one after another with a shrinking `t_max` would give.
pub(super) fn intersect(bvh: &Bvh, ray: &Ray, t_min: f32, t_max: f32) -> Option<Hit> {
    #[cfg(target_arch = "x86_64")]
    if bvh.avx_active() {
        // SAFETY: `avx_active` checked that this CPU has AVX.
        return unsafe { intersect_avx(bvh, ray, t_min, t_max) };
    }
    intersect_with::<false>(bvh, ray, t_min, t_max)
}

/// [`intersect`] compiled for AVX.
///
/// # Safety
/// The CPU must support AVX.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
unsafe fn intersect_avx(bvh: &Bvh, ray: &Ray, t_min: f32, t_max: f32) -> Option<Hit> {
    intersect_with::<true>(bvh, ray, t_min, t_max)
}

/// [`intersect`] with the AVX box test when `AVX` is set (see [`entries`]).
#[inline(always)]
fn intersect_with<const AVX: bool>(bvh: &Bvh, ray: &Ray, t_min: f32, t_max: f32) -> Option<Hit> {
    if bvh.wide.is_empty() {
        return None;
    }
    let simd = !bvh.scalar_only;
    let r = WideRay::new(ray);
    let lr = LeafRay::new(ray, simd);
    let blocks = &bvh.blocks[..];
    let ids = bvh.prefetch.then_some(&bvh.prim_ids[..]);
    let mut best_t = t_max;
    let mut best: Option<(u32, f32, f32)> = None;
    let mut stack = Stack::<(u32, f32)>::new();
    let mut current = 0u32;
    loop {
        if current & NARROW != 0 {
            // Only leaves below (see `NarrowNode`), tested in slot order.
            let node = &bvh.narrow[(current & !NARROW) as usize];
            let (e, mut mask) = entries4(node, &r, t_min, best_t, AVX || simd);
            while mask != 0 {
                let k = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                if e[k] <= best_t * ROBUST_EXIT {
                    nearest_in_leaf(&lr, blocks, node.child[k], t_min, &mut best_t, &mut best, ids);
                }
            }
        } else {
            let node = &bvh.wide[current as usize];
            let (e, mask) = entries::<AVX>(node, &r, t_min, best_t, simd);
            let leaf = leaf_bits::<AVX>(node);
            let (mut leaves, inner) = (mask & leaf, mask & !leaf);
            if bvh.prefetch && leaves.count_ones() > 1 {
                // Several leaves: start loading all their blocks at once.
                let mut m = leaves;
                while m != 0 {
                    let k = m.trailing_zeros() as usize;
                    m &= m - 1;
                    prefetch_block(blocks, node.child[k]);
                }
            }
            while leaves != 0 {
                let k = leaves.trailing_zeros() as usize;
                leaves &= leaves - 1;
                if e[k] <= best_t * ROBUST_EXIT {
                    nearest_in_leaf(&lr, blocks, node.child[k], t_min, &mut best_t, &mut best, ids);
                }
            }
            // Interior children still in front of the best hit, nearest first
            // (stable on ties, so deterministic).
            stack.push_nearest_last(&node.child, &e, inner, best_t * ROBUST_EXIT);
        }
        current = loop {
            match stack.pop() {
                None => {
                    return best.map(|(lane, u, v)| Hit {
                        t: best_t,
                        u,
                        v,
                        prim: bvh.prim_ids[lane as usize],
                    });
                }
                Some((c, t)) if t <= best_t * ROBUST_EXIT => {
                    if let Some((next, _)) = stack.peek().filter(|_| bvh.prefetch) {
                        prefetch_node(bvh, next);
                    }
                    break c;
                }
                Some(_) => {}
            }
        };
    }
}

/// Any hit (see [`Bvh::occluded`]).
pub(super) fn occluded(bvh: &Bvh, ray: &Ray, t_min: f32, t_max: f32) -> bool {
    match bvh.wide.first() {
        Some(root) => occluded_from(bvh, root, ray, t_min, t_max),
        None => false,
    }
}

/// Any hit in the subtrees that the slots of `start` point to (the root, or
/// a shadow cell's entry node, see [`super::ShaftEntry`]).
#[inline(always)]
pub(super) fn occluded_from(bvh: &Bvh, start: &WideNode, ray: &Ray, t_min: f32, t_max: f32) -> bool {
    #[cfg(target_arch = "x86_64")]
    if bvh.avx_active() {
        // SAFETY: `avx_active` checked that this CPU has AVX.
        return unsafe { occluded_avx(bvh, start, ray, t_min, t_max) };
    }
    occluded_with::<false>(bvh, start, ray, t_min, t_max)
}

/// [`occluded_from`] compiled for AVX.
///
/// # Safety
/// The CPU must support AVX.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
unsafe fn occluded_avx(bvh: &Bvh, start: &WideNode, ray: &Ray, t_min: f32, t_max: f32) -> bool {
    occluded_with::<true>(bvh, start, ray, t_min, t_max)
}

/// [`occluded_from`] with the AVX box test when `AVX` is set (see [`entries`]).
#[inline(always)]
fn occluded_with<const AVX: bool>(bvh: &Bvh, start: &WideNode, ray: &Ray, t_min: f32, t_max: f32) -> bool {
    let simd = !bvh.scalar_only;
    let r = WideRay::new(ray);
    let lr = LeafRay::new(ray, simd);
    let blocks = &bvh.blocks[..];
    // Interior children are visited in slot order: the first one next, the
    // others from the stack (so the last slots come second). Any order gives
    // the same answer. Turning the order by the ray's dominant direction (the
    // far end first) saved 12–17 % of the instructions of shadow rays to a
    // light above the bunny and the dragon, but cost 2–10 % of the wall time
    // of whole frames (paper, bunny and 1.6M dragon scenes, paired runs).
    let mut stack = Stack::<u32>::new();
    let mut node = start;
    loop {
        let (_, mask) = entries::<AVX>(node, &r, t_min, t_max, simd);
        let leaf = leaf_bits::<AVX>(node);
        let (mut leaves, mut inner) = (mask & leaf, mask & !leaf);
        while leaves != 0 {
            let k = leaves.trailing_zeros() as usize;
            leaves &= leaves - 1;
            let (first, count) = leaf_range(node.child[k]);
            if lr.hits(blocks, first, count, t_min, t_max).mask != 0 {
                return true;
            }
        }
        let mut next = None;
        while inner != 0 {
            let k = inner.trailing_zeros() as usize;
            inner &= inner - 1;
            if next.is_none() {
                next = Some(node.child[k]);
            } else {
                stack.push(node.child[k]);
            }
        }
        let mut current = match next.or_else(|| stack.pop()) {
            Some(c) => c,
            None => return false,
        };
        if let Some(next) = stack.peek().filter(|_| bvh.prefetch) {
            prefetch_node(bvh, next);
        }
        while current & NARROW != 0 {
            // Only leaves below (see `NarrowNode`).
            let node = &bvh.narrow[(current & !NARROW) as usize];
            let (_, mut mask) = entries4(node, &r, t_min, t_max, AVX || simd);
            while mask != 0 {
                let k = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                let (first, count) = leaf_range(node.child[k]);
                if lr.hits(blocks, first, count, t_min, t_max).mask != 0 {
                    return true;
                }
            }
            current = match stack.pop() {
                Some(c) => c,
                None => return false,
            };
            if let Some(next) = stack.peek().filter(|_| bvh.prefetch) {
                prefetch_node(bvh, next);
            }
        }
        node = &bvh.wide[current as usize];
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Sampler;
    use glam::Vec3;

    /// [`entries_avx`] compiled for AVX.
    ///
    /// # Safety
    /// The CPU must support AVX.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx")]
    unsafe fn avx_entries_for_test(node: &WideNode, r: &WideRay, t_min: f32, t_max: f32) -> ([f32; W], u32) {
        // SAFETY: this function is compiled for AVX and the caller checked the CPU.
        unsafe { entries_avx(node, r, t_min, t_max) }
    }

    #[test]
    fn avx_sse_and_scalar_box_tests_agree_bit_for_bit() {
        // Random boxes and rays, including axis-parallel directions, origins on
        // box planes and empty slots.
        let mut uniform = Sampler::new(1, 2, 3, 4).stream();
        let mut next = || uniform() * 8.0 - 4.0;
        for i in 0..20_000 {
            let mut node = WideNode::EMPTY;
            for k in 0..(1 + i % W) {
                let (a, b) = (Vec3::new(next(), next(), next()), Vec3::new(next(), next(), next()));
                let n = Node { min: a.min(b).to_array(), offset: 0, max: a.max(b).to_array(), count: 1 };
                node.set(k, &n);
            }
            let mut dir = Vec3::new(next(), next(), next());
            if i % 5 == 0 {
                dir[i % 3] = if i % 2 == 0 { 0.0 } else { -0.0 };
            }
            let mut origin = Vec3::new(next(), next(), next());
            if i % 7 == 0 {
                origin[i % 3] = node.bounds[i % 3][0];
            }
            let r = WideRay::new(&Ray::new(origin, dir));
            let (t_min, t_max) = (0.0, if i % 3 == 0 { f32::INFINITY } else { next().abs() * 2.0 });
            let (a, ma) = entries::<false>(&node, &r, t_min, t_max, true);
            let (b, mb) = entries_scalar(&node, &r, t_min, t_max);
            if i % W < W4 {
                // The same (at most four) children in a narrow node: the same
                // entries and mask, by SSE and by the scalar test.
                let mut narrow = NarrowNode::EMPTY;
                for row in 0..6 {
                    narrow.bounds[row].copy_from_slice(&node.bounds[row][..W4]);
                }
                for simd in [true, false] {
                    let (c, mc) = entries4(&narrow, &r, t_min, t_max, simd);
                    assert_eq!(
                        c.map(f32::to_bits)[..],
                        b.map(f32::to_bits)[..W4],
                        "case {i} (narrow, SIMD {simd})"
                    );
                    assert_eq!(mc, mb, "case {i} (narrow, SIMD {simd})");
                }
            }
            assert_eq!(a.map(f32::to_bits), b.map(f32::to_bits), "case {i}");
            assert_eq!(ma, mb, "case {i}");
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx") {
                // SAFETY: the CPU has AVX (checked just above).
                let (c, mc) = unsafe { avx_entries_for_test(&node, &r, t_min, t_max) };
                assert_eq!(c.map(f32::to_bits), b.map(f32::to_bits), "case {i} (AVX)");
                assert_eq!(mc, mb, "case {i} (AVX)");
            }
            for (k, t) in a.iter().enumerate() {
                assert_eq!(ma & (1 << k) != 0, *t != f32::INFINITY, "case {i}: mask matches entries");
            }
        }
    }

    #[test]
    fn stack_peek_and_prefetch_hints() {
        let mut st = Stack::<u32>::new();
        assert_eq!(st.peek(), None);
        st.push(3);
        st.push(5);
        assert_eq!(st.peek(), Some(5));
        assert_eq!(st.pop(), Some(5));
        assert_eq!(st.peek(), Some(3));
        // A hint for any word, in range or not, of either kind, is harmless.
        let bvh = Bvh::default();
        for word in [0, 7, NARROW, NARROW | 9, LEAF - 1] {
            prefetch_node(&bvh, word);
        }
    }

    #[test]
    fn pushing_nearest_last_visits_children_in_descend_nearest_order() {
        // Random entry distances with many ties, random interior masks and
        // limits, on top of a non-empty stack: both give the same sequence.
        let mut next = Sampler::new(9, 8, 7, 6).stream();
        let mut node = WideNode::EMPTY;
        for (k, c) in node.child.iter_mut().enumerate() {
            *c = 100 + k as u32;
        }
        for i in 0..5_000 {
            let e: [f32; W] = std::array::from_fn(|_| (next() * 4.0).floor());
            let inner = (next() * 256.0) as u32 & 0xff;
            let limit = if i % 3 == 0 { f32::INFINITY } else { (next() * 4.0).floor() };
            let mut a = Stack::<(u32, f32)>::new();
            let mut b = Stack::<(u32, f32)>::new();
            a.push((7, -1.0));
            b.push((7, -1.0));
            let mut order_a = Vec::new();
            if let Some(first) = descend_nearest(&node.child, &e, inner, limit, &mut a) {
                order_a.push(first);
            }
            while let Some((c, _)) = a.pop() {
                order_a.push(c);
            }
            b.push_nearest_last(&node.child, &e, inner, limit);
            let mut order_b = Vec::new();
            while let Some((c, _)) = b.pop() {
                order_b.push(c);
            }
            assert_eq!(order_a, order_b, "case {i}: entries {e:?}, mask {inner:#x}, limit {limit}");
        }
    }

    #[test]
    fn collapsed_nodes_are_wide_and_cover_the_binary_leaves() {
        let p = |i: usize, j: usize| Vec3::new(i as f32, (i * j % 5) as f32 * 0.2, j as f32);
        let mut tris = Vec::new();
        for i in 0..25 {
            for j in 0..25 {
                tris.push(crate::shapes::Triangle { v: [p(i, j), p(i + 1, j), p(i, j + 1)] });
            }
        }
        let bvh = Bvh::build(&tris);
        let (nodes, _) = super::super::build::binary(&tris);
        // Interior binary nodes reachable from the root (the array has unused slots).
        let (mut interior, mut binary_leaves, mut todo) = (0, 0, vec![0usize]);
        while let Some(i) = todo.pop() {
            let node = load(&nodes[i]);
            if node.is_leaf() {
                binary_leaves += 1;
            } else {
                interior += 1;
                todo.extend([i + 1, node.offset as usize]);
            }
        }
        let (mut wide_leaves, mut used) = (0, 0);
        let mut seen = vec![0u32; bvh.prim_ids.len()];
        let nodes = bvh.wide.iter().map(NodeRef::Wide).chain(bvh.narrow.iter().map(NodeRef::Narrow));
        for n in nodes {
            let slots = n.children().len();
            let filled = (0..slots).filter(|&k| !n.is_unused(k)).count();
            used += filled;
            if slots == W4 {
                assert!(filled >= 2, "a narrow node holds two to four children");
            } else {
                assert!(filled > W4 || std::ptr::eq(n.children(), &bvh.wide[0].child), "wide nodes hold > 4");
            }
            for k in 0..slots {
                let word = n.children()[k];
                if word & LEAF != 0 && !n.is_unused(k) {
                    wide_leaves += 1;
                    let (first, count) = leaf_range(word);
                    seen[first as usize..(first + count) as usize].iter_mut().for_each(|s| *s += 1);
                }
            }
        }
        for (lane, &s) in seen.iter().enumerate() {
            assert_eq!(s, (bvh.prim_ids[lane] != u32::MAX) as u32, "every triangle in exactly one wide leaf");
        }
        let all = bvh.wide.len() + bvh.narrow.len();
        assert!(!bvh.narrow.is_empty(), "small subtrees become narrow nodes");
        // Every node but the root fills one slot of its parent.
        assert_eq!(used, all - 1 + wide_leaves);
        // Each binary leaf is one wide leaf, and every binary interior node is
        // expanded by exactly one node (a node of k slots expands k - 1):
        // more than 2 per node on average (7 when the tree is full; a
        // subtree ending in two leaves gives 1).
        assert_eq!(wide_leaves, binary_leaves);
        assert_eq!(used - all, interior);
        assert!(all * 2 < interior, "{all} nodes for {interior} binary interior nodes");
    }
}

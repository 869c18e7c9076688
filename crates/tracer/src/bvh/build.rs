//! Top-down binned SAH builder.
//!
//! Each node bins its primitives' centroids (see `binning`; nodes of up to
//! `SMALL_MAX` primitives sort them instead, see `sweep`), evaluates the
//! surface-area heuristic at every boundary and either splits at the
//! cheapest one or, when that is no cheaper than intersecting everything, makes
//! a leaf. Where binning cannot separate the primitives (all centroids in one
//! spot) or the tree gets deep, it falls back to a median split on a total
//! order, so every input terminates within [`MAX_DEPTH`].
//!
//! **No per-node allocation.** The builder works on one array of 32-byte
//! primitive references ([`PrimRef`]: box and input index), partitioned in place
//! (see `partition`), so every node's primitives are a contiguous run and its
//! children's boxes come out of the partition pass. Nodes go straight into one
//! pre-allocated array: the subtree over `n` primitives owns exactly `2n − 1`
//! slots, its root first, its left subtree next (`2·n_left − 1` slots), then its
//! right subtree — the depth-first layout of [`Node`] (first child at `i + 1`),
//! with unused slots where leaves hold several primitives. Subtrees built on
//! other threads write their own disjoint slots; nothing is relocated.
//!
//! **Leaves for the wide tree.** On the way back up, a subtree of at most
//! [`MAX_LEAF_SIZE`] triangles becomes one leaf when the cost model of the wide
//! tree prefers it (`LEAF_COST · A ≤ MERGE_TRAVERSAL_COST · A + cost(left) +
//! cost(right)`: a leaf's triangles are tested together, see `blocks`), so
//! `wide::collapse` only has to group nodes.
//!
//! **Determinism.** Every decision is a function of the primitives in the node
//! and their order, which is itself determined by the parent's partition; which
//! code path runs (parallel binning, parallel partition, `rayon::join`) depends
//! on node sizes only, and the parallel paths compute exactly what their
//! sequential counterparts do (box unions of NaN-free boxes and integer counts
//! are exact in any order). The tree is therefore identical for any rayon pool.

use super::binning::{BinMap, Bins, PARALLEL_MIN};
use super::partition::{Sides, median, partition};
use super::primref::{Box4, PrimRef, bounds_of};
use super::sweep::{SMALL_MAX, TINY_MAX, split_small, split_tiny};
use super::wide::{LEAF_COST, MERGE_TRAVERSAL_COST};
use super::{Bvh, MAX_DEPTH, MAX_LEAF_SIZE, MAX_TRIANGLES, Node};
use crate::shapes::Triangle;
use rayon::prelude::*;

/// Nodes with at least this many primitives build their children in parallel.
const PARALLEL_THRESHOLD: usize = 4096;
/// From this depth on, nodes are split at the median: halving guarantees the
/// rest of the tree fits in `MAX_DEPTH` for up to `MAX_TRIANGLES` triangles.
const MEDIAN_DEPTH: usize = MAX_DEPTH - 34;
const _: () = assert!(MAX_TRIANGLES <= 1 << 30 && MEDIAN_DEPTH + 32 <= MAX_DEPTH);

/// A binary node as stored by the builder: the 32 bytes of a [`Node`] as words
/// ([`store`], [`load`]). Arrays of words can be allocated zeroed, which the OS
/// does lazily, page by page, as the (parallel) build writes them — instead of a
/// serial pass over the whole array first (in a process's first build; later
/// ones may get reused memory, which `calloc` clears). An all-zero slot is an
/// interior node no one points to; the builder writes zeros to the slots no
/// node uses, as they may have served as a partition's scratch space.
pub(super) type Slot = [u32; 8];

/// The slot of `n`.
#[inline(always)]
fn store(n: &Node) -> Slot {
    let [a, b, c] = n.min.map(f32::to_bits);
    let [d, e, f] = n.max.map(f32::to_bits);
    [a, b, c, n.offset, d, e, f, n.count]
}

/// The node in slot `s`.
#[inline(always)]
pub(super) fn load(s: &Slot) -> Node {
    let f = f32::from_bits;
    Node { min: [f(s[0]), f(s[1]), f(s[2])], offset: s[3], max: [f(s[4]), f(s[5]), f(s[6])], count: s[7] }
}

/// Builds the BVH (see [`Bvh::build`]).
pub(super) fn build(triangles: &[Triangle]) -> Bvh {
    assert!(triangles.len() <= MAX_TRIANGLES, "BVH: more than {MAX_TRIANGLES} triangles");
    if triangles.is_empty() {
        return Bvh::default();
    }
    let Binary { nodes, mut ids, leaves } = binary_tree(triangles);
    let bounds = load(&nodes[0]).bounds();
    // The leaves' triangles are packed into blocks while the wide tree is
    // collapsed; then the wide leaves are pointed at their lanes.
    let (mut tree, (blocks, prim_ids, starts)) =
        rayon::join(|| super::wide::collapse(&nodes), || super::blocks::pack(&leaves, triangles, &ids));
    drop(nodes);
    // The leaf order is packed into the blocks' lane ids: its words can serve
    // as the leaves' lane map.
    super::wide::place_leaves(&mut tree, &leaves, &starts, &mut ids);
    drop(ids);
    let super::wide::Collapsed { wide, narrow } = tree;
    let mut bvh = Bvh {
        bounds,
        blocks,
        prim_ids,
        count: triangles.len(),
        wide,
        narrow,
        scalar_only: false,
        no_avx: false,
        prefetch: false,
    };
    bvh.prefetch = bvh.memory_bytes() >= super::PREFETCH_MIN_BYTES;
    bvh
}

/// What [`binary_tree`] makes.
pub(super) struct Binary {
    /// The binary tree (depth-first with unused slots, all zero; see the module docs).
    pub(super) nodes: Vec<Slot>,
    /// The input indices of the triangles in leaf order.
    pub(super) ids: Vec<u32>,
    /// The tree's leaves in leaf order: `(first, count)` in leaf order.
    pub(super) leaves: Vec<(u32, u32)>,
}

/// The binary tree over `triangles` and the leaf order (tests).
#[cfg(test)]
pub(super) fn binary(triangles: &[Triangle]) -> (Vec<Slot>, Vec<u32>) {
    let Binary { nodes, ids, .. } = binary_tree(triangles);
    (nodes, ids)
}

/// The binary tree over `triangles` (not empty), the leaf order and the leaves.
pub(super) fn binary_tree(triangles: &[Triangle]) -> Binary {
    let n = triangles.len();
    let mut prims: Vec<PrimRef> =
        triangles.par_iter().enumerate().map(|(i, t)| PrimRef::from_triangle(i as u32, t)).collect();
    let (geo, cent) = if n >= PARALLEL_MIN {
        prims
            .par_chunks(super::binning::CHUNK)
            .map(bounds_of)
            .reduce(|| (Box4::EMPTY, Box4::EMPTY), |a, b| (a.0.union(&b.0), a.1.union(&b.1)))
    } else {
        bounds_of(&prims)
    };
    let mut nodes: Vec<Slot> = vec![[0; 8]; 2 * n - 1];
    // marks[i]: the number of triangles of the leaf that starts at leaf-order
    // position i, else 0.
    let mut marks = vec![0u32; n];
    let root = Pos { index: 0, first: 0, depth: 0 };
    build_node(&mut prims, &mut nodes, &mut marks, root, geo, cent);
    let leaves = marks.iter().enumerate().filter(|&(_, &c)| c != 0).map(|(i, &c)| (i as u32, c)).collect();
    // The marks are read: their words take the leaf order (no fresh memory).
    let mut ids = marks;
    ids.par_iter_mut().zip(prims.par_iter()).for_each(|(id, p)| *id = p.id());
    Binary { nodes, ids, leaves }
}

/// Where a subtree goes.
#[derive(Clone, Copy, Debug)]
struct Pos {
    /// Index of its root in the whole node array.
    index: u32,
    /// Leaf-order index of its first primitive.
    first: u32,
    /// Depth of its root.
    depth: usize,
}

/// Builds the subtree over `prims` (box `geo`, centroid box `cent`) into `nodes`
/// (its `2n − 1` slots, root first; every one of them is written, unused ones
/// with zeros), marks its leaves in `marks` (as long as `prims`: a leaf's count
/// at its first position, 0 elsewhere) and returns its SAH cost in the wide
/// tree's model (times area).
///
/// Until its children are built, a node's slots hold nothing: a large node's
/// parallel partition uses its first `n` slots as scratch space (so the build
/// needs no separate scratch array), which the children then overwrite.
fn build_node(
    prims: &mut [PrimRef],
    nodes: &mut [Slot],
    marks: &mut [u32],
    at: Pos,
    geo: Box4,
    cent: Box4,
) -> f32 {
    let n = prims.len();
    debug_assert_eq!(nodes.len(), 2 * n - 1);
    let area = geo.area();
    let bounds = geo.to_aabb();
    let Some(sides) = choose_split(prims, &mut nodes[..n], &geo, &cent, at.depth) else {
        nodes[0] = store(&Node::leaf(&bounds, at.first, n as u32));
        // The other slots may hold an ancestor's scratch data.
        nodes[1..].fill([0; 8]);
        marks[0] = n as u32;
        return LEAF_COST * area;
    };
    let mid = sides.mid;
    let (left, right) = prims.split_at_mut(mid);
    let (head, rest) = nodes.split_first_mut().expect("a node has a slot");
    let (nodes_l, nodes_r) = rest.split_at_mut(2 * mid - 1);
    let (marks_l, marks_r) = marks.split_at_mut(mid);
    let second = at.index + 2 * mid as u32;
    let pos_l = Pos { index: at.index + 1, first: at.first, depth: at.depth + 1 };
    let pos_r = Pos { index: second, first: at.first + mid as u32, depth: at.depth + 1 };
    let [geo_l, geo_r] = sides.geo;
    let [cent_l, cent_r] = sides.cent;
    let (cost_l, cost_r) = if n >= PARALLEL_THRESHOLD {
        rayon::join(
            || build_node(left, nodes_l, marks_l, pos_l, geo_l, cent_l),
            || build_node(right, nodes_r, marks_r, pos_r, geo_r, cent_r),
        )
    } else {
        (
            build_node(left, nodes_l, marks_l, pos_l, geo_l, cent_l),
            build_node(right, nodes_r, marks_r, pos_r, geo_r, cent_r),
        )
    };
    let split = MERGE_TRAVERSAL_COST * area + cost_l + cost_r;
    let merged = LEAF_COST * area;
    if n <= MAX_LEAF_SIZE && merged <= split {
        *head = store(&Node::leaf(&bounds, at.first, n as u32));
        // The merged children are unreachable: clear them, so that every leaf
        // slot left in the array is a leaf of the tree, and their marks.
        nodes_l.fill([0; 8]);
        nodes_r.fill([0; 8]);
        marks_l.fill(0);
        marks_r.fill(0);
        marks_l[0] = n as u32;
        merged
    } else {
        *head = store(&Node::interior(&bounds, second));
        split
    }
}

/// Decides how to split `prims`; on a split, partitions them and returns the
/// sides (the left one always has `1..n` primitives). `None` means make a leaf.
/// `scratch` (as long as `prims`) is the parallel partition's scratch space.
fn choose_split(
    prims: &mut [PrimRef],
    scratch: &mut [Slot],
    geo: &Box4,
    cent: &Box4,
    depth: usize,
) -> Option<Sides> {
    let n = prims.len();
    if n <= 1 {
        return None;
    }
    if depth >= MEDIAN_DEPTH {
        return (n > MAX_LEAF_SIZE).then(|| median(prims, cent));
    }
    // Costs are SAH costs multiplied by the node's area, so that zero-area
    // nodes (all triangles degenerate and in one spot) compare without NaNs.
    let leaf_cost = n as f32 * geo.area();
    let commit = |cost| n > MAX_LEAF_SIZE || cost < leaf_cost;
    if n <= TINY_MAX {
        return split_tiny(prims, geo.area(), commit).map(|(_, s)| s);
    }
    if n <= SMALL_MAX {
        return split_small(prims, geo.area(), commit).map(|(_, s)| s);
    }
    let best = BinMap::new(cent).and_then(|map| Some((map, Bins::best_split(prims, &map)?)));
    match best {
        Some((map, split)) if n > MAX_LEAF_SIZE || split.cost < leaf_cost => {
            let sides = partition(prims, scratch, |c| map.goes_left(c, &split));
            // Binning and partitioning classify alike, so both sides are non-empty.
            debug_assert!(sides.mid > 0 && sides.mid < n);
            Some(if sides.mid == 0 || sides.mid == n { median(prims, cent) } else { sides })
        }
        _ if n > MAX_LEAF_SIZE => Some(median(prims, cent)),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Sampler;
    use glam::Vec3;

    /// Random small triangles in clusters, with duplicates and degenerate ones,
    /// enough of them for the parallel binning and partition paths.
    fn soup(n: usize) -> Vec<Triangle> {
        let mut next = Sampler::new(7, 7, 7, 7).stream();
        let mut tris = Vec::with_capacity(n);
        while tris.len() < n {
            let cluster = Vec3::new((tris.len() % 5) as f32 * 40.0, 0.0, (tris.len() % 3) as f32 * 25.0);
            let o = cluster + Vec3::new(next(), next(), next()) * 20.0;
            let t =
                Triangle { v: [o, o + Vec3::new(next(), next(), 0.0), o + Vec3::new(0.0, next(), next())] };
            tris.push(t);
            match tris.len() % 97 {
                0 => tris.push(t),                         // duplicate
                1 => tris.push(Triangle { v: [o, o, o] }), // degenerate
                _ => {}
            }
        }
        tris
    }

    #[test]
    fn parallel_build_is_the_one_thread_build() {
        let tris = soup(3 * PARALLEL_MIN + 123);
        let pool = |n| rayon::ThreadPoolBuilder::new().num_threads(n).build().expect("pool");
        let one = pool(1).install(|| binary_tree(&tris));
        for threads in [2, 3] {
            let other = pool(threads).install(|| binary_tree(&tris));
            assert!(other.nodes == one.nodes, "binary nodes differ on {threads} threads");
            assert!(other.ids == one.ids, "leaf order differs on {threads} threads");
            assert!(other.leaves == one.leaves, "leaves differ on {threads} threads");
        }
        // Large nodes partitioned through their own slots: every slot no node
        // uses was cleared again.
        let mut used = vec![false; one.nodes.len()];
        let mut todo = vec![0usize];
        while let Some(i) = todo.pop() {
            used[i] = true;
            let node = load(&one.nodes[i]);
            if !node.is_leaf() {
                todo.extend([i + 1, node.offset as usize]);
            }
        }
        let unused = used.iter().filter(|&&u| !u).count();
        assert!(unused > tris.len() / 2, "leaves hold several triangles: {unused} unused slots");
        for (slot, _) in one.nodes.iter().zip(&used).filter(|&(_, &u)| !u) {
            assert_eq!(*slot, [0; 8], "an unused slot kept scratch data");
        }
        let one = pool(1).install(|| Bvh::build(&tris));
        let two = pool(2).install(|| Bvh::build(&tris));
        one.validate().expect("valid");
        assert_eq!(one.memory_bytes(), two.memory_bytes());
        assert_eq!(one, two, "wide nodes, blocks and lane ids are the same");
    }

    #[test]
    fn builder_leaves_cover_every_triangle_once_in_order() {
        let tris = soup(5000);
        let Binary { nodes, ids, leaves } = binary_tree(&tris);
        // The leaf list is the leaf slots of the array, in order.
        let slots: Vec<(u32, u32)> =
            nodes.iter().filter(|s| s[7] != 0).map(|s| (load(s).offset, load(s).count)).collect();
        assert_eq!(leaves, slots);
        // Walk the reachable tree: leaves tile 0..n in depth-first order.
        let (mut next, mut todo) = (0u32, vec![0usize]);
        while let Some(i) = todo.pop() {
            let node = load(&nodes[i]);
            if node.is_leaf() {
                assert_eq!(node.offset, next, "leaves in depth-first order");
                assert!((1..=MAX_LEAF_SIZE as u32).contains(&node.count));
                next += node.count;
            } else {
                assert!(node.offset as usize > i + 1 && (node.offset as usize) < nodes.len());
                todo.push(node.offset as usize);
                todo.push(i + 1);
            }
        }
        assert_eq!(next as usize, tris.len());
        let mut sorted = ids.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..tris.len() as u32).collect::<Vec<_>>());
    }
}

//! Ray traversal: nearest hit and any hit.
//!
//! Both walk the tree with a fixed-size stack of (node, entry distance) pairs.
//! At an interior node both children's boxes are slab-tested; the nearer one is
//! visited next and the farther one pushed, and popped entries whose box starts
//! beyond the best hit so far are dropped. Leaves run Möller–Trumbore on their
//! precomputed triangles, shrinking the search interval on every hit.

use super::{Bvh, MAX_DEPTH, Node};
use crate::geometry::Ray;
use crate::shapes::{Hit, moller_trumbore, moller_trumbore_any};

/// Slab-test exits are scaled by this factor (1 + 2γ₃ rounded up, after Ize,
/// "Robust BVH Ray Traversal", JCGT 2013) so that rounding in the box test never
/// culls a box the exact ray passes through. It only ever visits slightly more.
const ROBUST_EXIT: f32 = 1.0 + 4.0 * f32::EPSILON;

/// A ray prepared for box tests: origin, reciprocal direction and, per axis,
/// whether the direction is negative (then the box's max plane is entered first).
#[derive(Clone, Copy, Debug)]
struct BoxRay {
    origin: [f32; 3],
    inv_dir: [f32; 3],
    negative: [bool; 3],
}

impl BoxRay {
    /// `1 / ±0` gives `±inf`, so axis-parallel rays need no special case.
    #[inline(always)]
    fn new(ray: &Ray) -> Self {
        let inv = ray.dir.recip();
        BoxRay {
            origin: ray.origin.to_array(),
            inv_dir: inv.to_array(),
            // Sign bit, not `< 0`: -0 gives -inf, whose near plane is the max.
            negative: [inv.x.is_sign_negative(), inv.y.is_sign_negative(), inv.z.is_sign_negative()],
        }
    }

    /// Distance at which the ray enters `node`'s box within `(t_min, t_max)`,
    /// or `f32::INFINITY` when it misses.
    ///
    /// `(plane - origin) * inv_dir` is NaN only when the origin lies exactly on a
    /// plane of an axis the ray is parallel to; the max/min helpers below then
    /// keep the running value (the ray interval), treating that slab as no
    /// constraint, which is conservative.
    #[inline(always)]
    fn entry(&self, node: &Node, t_min: f32, t_max: f32) -> f32 {
        let mut near = t_min;
        let mut far = t_max;
        for axis in 0..3 {
            let (lo, hi) = if self.negative[axis] {
                (node.max[axis], node.min[axis])
            } else {
                (node.min[axis], node.max[axis])
            };
            let t0 = (lo - self.origin[axis]) * self.inv_dir[axis];
            let t1 = (hi - self.origin[axis]) * self.inv_dir[axis];
            near = max_keep(t0, near);
            far = min_keep(t1, far);
        }
        if near <= far * ROBUST_EXIT { near } else { f32::INFINITY }
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

/// Fixed-size traversal stack of (node index, box entry distance).
struct Stack {
    items: [(u32, f32); MAX_DEPTH],
    len: usize,
}

impl Stack {
    #[inline(always)]
    fn new() -> Self {
        Stack { items: [(0, 0.0); MAX_DEPTH], len: 0 }
    }

    /// The build keeps every leaf within `MAX_DEPTH` (checked by `validate`),
    /// and a traversal pushes at most one entry per level, so this cannot overflow.
    #[inline(always)]
    fn push(&mut self, node: u32, t: f32) {
        self.items[self.len] = (node, t);
        self.len += 1;
    }

    #[inline(always)]
    fn pop(&mut self) -> Option<(u32, f32)> {
        self.len = self.len.checked_sub(1)?;
        Some(self.items[self.len])
    }
}

/// What to do after an interior node: descend into one child (having pushed the
/// other, if it is hit too) or pop.
#[inline(always)]
fn descend(
    nodes: &[Node],
    i: usize,
    ray: &BoxRay,
    t_min: f32,
    t_max: f32,
    stack: &mut Stack,
) -> Option<usize> {
    let (a, b) = (i + 1, nodes[i].offset as usize);
    let ta = ray.entry(&nodes[a], t_min, t_max);
    let tb = ray.entry(&nodes[b], t_min, t_max);
    let (near, t_near, far, t_far) = if tb < ta { (b, tb, a, ta) } else { (a, ta, b, tb) };
    if t_near == f32::INFINITY {
        return None;
    }
    if t_far != f32::INFINITY {
        stack.push(far as u32, t_far);
    }
    Some(near)
}

/// Pops the next node whose box starts no later than `t_max` (within the robust margin).
#[inline(always)]
fn next(stack: &mut Stack, t_max: f32) -> Option<usize> {
    while let Some((node, t)) = stack.pop() {
        if t <= t_max * ROBUST_EXIT {
            return Some(node as usize);
        }
    }
    None
}

/// Nearest hit (see [`Bvh::intersect`]).
pub(super) fn intersect(bvh: &Bvh, ray: &Ray, t_min: f32, t_max: f32) -> Option<Hit> {
    let nodes = &bvh.nodes[..];
    let root = nodes.first()?;
    let box_ray = BoxRay::new(ray);
    if box_ray.entry(root, t_min, t_max) == f32::INFINITY {
        return None;
    }
    let mut best_t = t_max;
    let mut best: Option<(usize, f32, f32)> = None;
    let mut stack = Stack::new();
    let mut current = Some(0usize);
    while let Some(i) = current {
        let node = &nodes[i];
        current = if node.is_leaf() {
            let first = node.offset as usize;
            let tris = &bvh.tris[first..first + node.count as usize];
            for (k, tri) in tris.iter().enumerate() {
                if let Some((t, u, v)) = moller_trumbore(tri.v0, tri.e1, tri.e2, ray, t_min, best_t) {
                    best_t = t;
                    best = Some((first + k, u, v));
                }
            }
            next(&mut stack, best_t)
        } else {
            descend(nodes, i, &box_ray, t_min, best_t, &mut stack).or_else(|| next(&mut stack, best_t))
        };
    }
    best.map(|(k, u, v)| Hit { t: best_t, u, v, prim: bvh.prim_ids[k] })
}

/// Any hit (see [`Bvh::occluded`]).
pub(super) fn occluded(bvh: &Bvh, ray: &Ray, t_min: f32, t_max: f32) -> bool {
    let nodes = &bvh.nodes[..];
    let Some(root) = nodes.first() else { return false };
    let box_ray = BoxRay::new(ray);
    if box_ray.entry(root, t_min, t_max) == f32::INFINITY {
        return false;
    }
    let mut stack = Stack::new();
    let mut current = Some(0usize);
    while let Some(i) = current {
        let node = &nodes[i];
        current = if node.is_leaf() {
            let first = node.offset as usize;
            let tris = &bvh.tris[first..first + node.count as usize];
            if tris.iter().any(|tri| moller_trumbore_any(tri.v0, tri.e1, tri.e2, ray, t_min, t_max)) {
                return true;
            }
            next(&mut stack, t_max)
        } else {
            descend(nodes, i, &box_ray, t_min, t_max, &mut stack).or_else(|| next(&mut stack, t_max))
        };
    }
    false
}

//! Shaft queries: can anything block a segment between a box and a light?
//!
//! Every shadow ray from a point inside a box `A` to a point of a light lies
//! inside the convex hull of `A` and the light's box `B`. [`Shaft::between`]
//! bounds that hull by its box and the planes that join the two boxes' edges
//! (Haines & Wallace's shaft culling: in each of the three axis-aligned
//! projections, the edges of the 2-D hull of the two rectangles that connect
//! one to the other), and [`Bvh::shaft_clear`] walks the tree with it, looking
//! for a triangle it cannot rule out. When there is none, no shadow ray from
//! inside `A` to the light can hit anything. When there is, [`Bvh::shaft_entry`]
//! gathers the few subtrees that hold every triangle overlapping the shaft,
//! where such rays can start their walk instead of at the root.
//!
//! **Surfaces the rays start from.** A box around a floor point contains the
//! floor, which would put the floor on every list. A triangle whose plane has
//! the whole light on one (closed) side cannot block a segment that starts
//! strictly on that side and ends short of the light: such a segment never
//! reaches the plane. The walk leaves those triangles out and records their
//! planes instead ([`SurfacePlanes::admit`]); the answer holds for a ray only
//! when its origin lies on the light's side of every recorded plane, by a
//! margin that covers the rounding of the plane test and of the triangle test. The caller
//! must stop its shadow rays short of the light, as the integrator does (by a
//! factor `1 − 10⁻³`); a lamp's own polygon, coplanar with the light, is then
//! never reached either, which the margin accounts for.
//!
//! **Conservative culling.** A node or triangle is dropped only when its box
//! or all three of its vertices lie outside one of the shaft's half-spaces,
//! which are widened by the caller's margin; the plane arithmetic decides only
//! what is tested, never the answer. `tests/shadows.rs` checks [`Bvh::occluded`]
//! on shadow rays from cells found clear in real scenes.

use super::Bvh;
use super::blocks::TriBlock;
use super::wide::{LEAF, NodeRef, Stack, W, WideNode, leaf_range};
use crate::geometry::Aabb;
use glam::{Vec2, Vec3};

/// Most half-spaces of a [`Shaft`] besides its box (four connecting planes in
/// each of the three projections).
pub const SHAFT_PLANES: usize = 12;

/// Most surface planes a [`SurfacePlanes`] records (see the module docs);
/// a shaft with more surfaces in it is not clear.
pub const SURFACE_PLANES: usize = 3;

/// A convex region: the points `x` with `n·x ≤ d` for each of its half-spaces
/// `(n, d)`, inside a bounding box. Built by [`Shaft::between`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shaft {
    /// Half-spaces `(n, d)`: unit normal pointing out of the region and offset.
    planes: [(Vec3, f32); SHAFT_PLANES],
    /// Number of half-spaces in use.
    count: usize,
    /// Bounding box of the region.
    bounds: Aabb,
    /// Centre of the box the segments start from.
    start: Vec3,
}

impl Shaft {
    /// A region containing the convex hull of boxes `a` (where segments
    /// start) and `b` (where they end, the light), widened by `margin` world
    /// units on every side. `None` when a box is empty or anything is not
    /// finite.
    pub fn between(a: &Aabb, b: &Aabb, margin: f32) -> Option<Shaft> {
        let finite = |x: &Aabb| x.min.is_finite() && x.max.is_finite() && x.min.cmple(x.max).all();
        if !(finite(a) && finite(b) && margin >= 0.0 && margin.is_finite()) {
            return None;
        }
        let union = a.union(b);
        let mut shaft = Shaft {
            planes: [(Vec3::ZERO, 0.0); SHAFT_PLANES],
            count: 0,
            bounds: Aabb { min: union.min - Vec3::splat(margin), max: union.max + Vec3::splat(margin) },
            start: (a.min + a.max) * 0.5,
        };
        // The largest `n·x` over a box's corners (each coordinate at the end
        // that maximises its term).
        let reach = |n: Vec3, x: &Aabb| (n * x.min).max(n * x.max).element_sum();
        // In each projection, the hull edges joining a corner of one rectangle
        // to a corner of the other (the rectangles' own edges are the box's).
        for (i, j) in [(0, 1), (1, 2), (2, 0)] {
            // A box's rectangle in this projection: its distinct corners.
            let rect = |x: &Aabb| {
                let mut r = [Vec2::ZERO; 4];
                let mut len = 0;
                for (u, v) in
                    [(x.min[i], x.min[j]), (x.max[i], x.min[j]), (x.min[i], x.max[j]), (x.max[i], x.max[j])]
                {
                    let p = Vec2::new(u, v);
                    if !r[..len].contains(&p) {
                        r[len] = p;
                        len += 1;
                    }
                }
                (r, len)
            };
            let ((ra, na), (rb, nb)) = (rect(a), rect(b));
            for &p in &ra[..na] {
                for &q in &rb[..nb] {
                    let e = q - p;
                    // Axis-aligned joins are faces of the bounding box already.
                    if e.x == 0.0 || e.y == 0.0 {
                        continue;
                    }
                    let n = Vec2::new(e.y, -e.x).normalize();
                    let side = |s: f32| ra[..na].iter().chain(&rb[..nb]).all(|&x| s * n.dot(x - p) <= 0.0);
                    let n = if side(1.0) {
                        n
                    } else if side(-1.0) {
                        -n
                    } else {
                        continue;
                    };
                    let mut n3 = Vec3::ZERO;
                    n3[i] = n.x;
                    n3[j] = n.y;
                    // The offset that keeps both boxes inside, whatever the
                    // rounding above (the margin covers this sum's own).
                    let d = reach(n3, a).max(reach(n3, b)) + margin;
                    let duplicate = shaft.planes[..shaft.count].iter().any(|&(m, e)| m == n3 && e == d);
                    if !duplicate && shaft.count < SHAFT_PLANES && d.is_finite() {
                        shaft.planes[shaft.count] = (n3, d);
                        shaft.count += 1;
                    }
                }
            }
        }
        Some(shaft)
    }

    /// True when the point lies inside the region (for tests).
    pub fn contains(&self, p: Vec3) -> bool {
        p.cmpge(self.bounds.min).all()
            && p.cmple(self.bounds.max).all()
            && self.planes[..self.count].iter().all(|&(n, d)| n.dot(p) <= d)
    }

    /// True when child `k` of `node` may overlap the region: its box meets
    /// the bounding box and, for every half-space, its corner deepest inside
    /// lies inside.
    fn overlaps(&self, node: NodeRef, k: usize) -> bool {
        let lo = Vec3::new(node.bound(0, k), node.bound(1, k), node.bound(2, k));
        let hi = Vec3::new(node.bound(3, k), node.bound(4, k), node.bound(5, k));
        if !(lo.cmple(self.bounds.max).all() && hi.cmpge(self.bounds.min).all()) {
            return false;
        }
        self.planes[..self.count].iter().all(|&(n, d)| {
            let deepest = Vec3::select(n.cmpge(Vec3::ZERO), lo, hi);
            n.dot(deepest) <= d
        })
    }

    /// True when the triangle with vertices `v` lies outside the region: all
    /// three vertices beyond one face of the box or one half-space.
    fn excludes(&self, v: &[Vec3; 3]) -> bool {
        let lo = v[0].min(v[1]).min(v[2]);
        let hi = v[0].max(v[1]).max(v[2]);
        lo.cmpgt(self.bounds.max).any()
            || hi.cmplt(self.bounds.min).any()
            || self.planes[..self.count].iter().any(|&(n, d)| v.iter().all(|&p| n.dot(p) > d))
    }
}

/// The surfaces a clear shaft ([`Bvh::shaft_clear`]) left out: planes
/// `n·x = d` with the light on their positive side.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfacePlanes {
    /// `[n.x, n.y, n.z, d + margin]`: rays must start where `n·o` exceeds the
    /// last. Unused rows are [`SurfacePlanes::NONE`], which every finite
    /// point clears, so [`SurfacePlanes::admit`] tests all rows.
    planes: [[f32; 4]; SURFACE_PLANES],
    /// Number of planes in use.
    count: u32,
}

impl Default for SurfacePlanes {
    fn default() -> Self {
        SurfacePlanes { planes: [Self::NONE; SURFACE_PLANES], count: 0 }
    }
}

impl SurfacePlanes {
    /// An unused row: `0·o > −∞` holds for every finite `o`.
    const NONE: [f32; 4] = [0.0, 0.0, 0.0, f32::NEG_INFINITY];

    /// True when a shadow ray from `origin` is covered: the origin lies on
    /// the light's side of every surface left out, clear of the margin.
    #[inline(always)]
    pub fn admit(&self, origin: Vec3) -> bool {
        // All rows, without branches (unused ones admit every finite point;
        // a point that is not finite is never admitted).
        self.planes
            .iter()
            .fold(true, |ok, p| ok & (p[0] * origin.x + p[1] * origin.y + p[2] * origin.z > p[3]))
    }

    /// Number of planes recorded.
    pub fn len(&self) -> usize {
        self.count as usize
    }

    /// True when no surface was left out.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Adds the plane `n·x = d` of a surface left out, which rays must clear
    /// by `margin`. A plane whose normal is within 10⁻⁷ of a recorded one
    /// (which moves the plane test at points of the scene by less than
    /// `slack / 6`) and whose threshold is within `slack` merges with it:
    /// the recorded threshold becomes the larger of the two, each raised by
    /// `slack / 2`. `false` when there is no room.
    fn add(&mut self, n: Vec3, d: f32, margin: f32, slack: f32) -> bool {
        let threshold = d + margin + 0.5 * slack;
        for p in &mut self.planes[..self.count as usize] {
            let m = Vec3::new(p[0], p[1], p[2]);
            if (m - n).abs().max_element() <= 1e-7 && (p[3] - threshold).abs() <= slack {
                p[3] = p[3].max(threshold);
                return true;
            }
        }
        if self.count as usize == SURFACE_PLANES {
            return false;
        }
        self.planes[self.count as usize] = [n.x, n.y, n.z, threshold];
        self.count += 1;
        true
    }
}

/// A shadow cell's entry node into the tree ([`Bvh::shaft_entry`]): up to
/// eight subtrees (or leaves) of the BVH, with their boxes, that together
/// hold every triangle that overlaps a shaft. A shadow ray inside the shaft
/// starts its walk here instead of at the root ([`Bvh::occluded_from`]).
#[derive(Clone, Debug, PartialEq)]
pub struct ShaftEntry(pub(super) WideNode);

/// See [`Bvh::shaft_entry`].
pub(super) fn shaft_entry(bvh: &Bvh, shaft: &Shaft) -> Option<ShaftEntry> {
    bvh.wide.first()?;
    // The frontier: (child word, box) of subtrees that overlap the shaft.
    let mut frontier: Vec<(u32, Aabb)> = Vec::with_capacity(W);
    let children = |word: u32, out: &mut Vec<(u32, Aabb)>| {
        let node = NodeRef::of(bvh, word);
        for (k, &child) in node.children().iter().enumerate() {
            if !shaft.overlaps(node, k) {
                continue;
            }
            if child & LEAF != 0 {
                // A leaf whose triangles all lie outside the shaft is left out.
                let (first, count) = leaf_range(child);
                let block = &bvh.blocks[(first / 4) as usize];
                if (first % 4..first % 4 + count).all(|l| shaft.excludes(&block.get(l as usize).vertices())) {
                    continue;
                }
            }
            let b = |a: usize| node.bound(a, k);
            out.push((child, Aabb { min: Vec3::new(b(0), b(1), b(2)), max: Vec3::new(b(3), b(4), b(5)) }));
        }
    };
    children(0, &mut frontier);
    // Open the subtree with the largest box while its overlapping children
    // fit in the remaining slots (ties: the first), as the collapse does.
    let mut expanded = Vec::with_capacity(W);
    let mut closed = 0u32;
    loop {
        let best = frontier
            .iter()
            .enumerate()
            .filter(|&(i, &(word, _))| word & LEAF == 0 && closed & (1 << i) == 0)
            .max_by(|a, b| a.1.1.half_area().total_cmp(&b.1.1.half_area()).then(b.0.cmp(&a.0)))
            .map(|(i, _)| i);
        let Some(i) = best else { break };
        expanded.clear();
        children(frontier[i].0, &mut expanded);
        if frontier.len() - 1 + expanded.len() > W {
            closed |= 1 << i;
            continue;
        }
        frontier.remove(i);
        frontier.extend_from_slice(&expanded);
        // Indices moved: reconsider every subtree.
        closed = 0;
        if frontier.is_empty() {
            break;
        }
    }
    let mut node = WideNode::EMPTY;
    for (k, &(word, b)) in frontier.iter().enumerate() {
        node.set_box(k, &b);
        node.child[k] = word;
    }
    Some(ShaftEntry(node))
}

/// See [`Bvh::shaft_clear`].
pub(super) fn shaft_clear(bvh: &Bvh, shaft: &Shaft, light: &[Vec3], margin: f32) -> Option<SurfacePlanes> {
    let mut planes = SurfacePlanes::default();
    if bvh.wide.is_empty() {
        return Some(planes);
    }
    if light.is_empty() || !(margin >= 0.0 && margin.is_finite()) {
        return None;
    }
    let mut stack = Stack::<u32>::new();
    let mut current = 0u32;
    loop {
        let node = NodeRef::of(bvh, current);
        for (k, &child) in node.children().iter().enumerate() {
            // Unused slots have empty boxes, which no shaft overlaps.
            if !shaft.overlaps(node, k) {
                continue;
            }
            if child & LEAF == 0 {
                stack.push(child);
                continue;
            }
            let (first, count) = leaf_range(child);
            let lanes = ((1u32 << count) - 1) << (first % 4);
            if !clear_lanes(&bvh.blocks[(first / 4) as usize], lanes, shaft, light, margin, &mut planes) {
                return None;
            }
        }
        match stack.pop() {
            Some(c) => current = c,
            None => return Some(planes),
        }
    }
}

/// True when none of the triangles in lanes `lanes` of `block` can block a
/// segment of the shaft: each lies outside it, or is a surface with the
/// light on one side, whose plane goes into `planes` (false when there is no
/// room for it).
fn clear_lanes(
    block: &TriBlock,
    lanes: u32,
    shaft: &Shaft,
    light: &[Vec3],
    margin: f32,
    planes: &mut SurfacePlanes,
) -> bool {
    let mut rest = lanes;
    while rest != 0 {
        let k = rest.trailing_zeros() as usize;
        rest &= rest - 1;
        let tri = block.get(k);
        let v = tri.vertices();
        if shaft.excludes(&v) {
            continue;
        }
        let n = tri.e1.cross(tri.e2);
        let len = n.length();
        if !(len > 0.0 && len.is_finite()) {
            // Degenerate: the intersection test never reports it.
            continue;
        }
        let n = n / len;
        let d = n.dot(tri.v0);
        let (lo, hi) = light
            .iter()
            .map(|&q| n.dot(q) - d)
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), s| (lo.min(s), hi.max(s)));
        // Which side of the plane the whole light lies on (closed), if one;
        // for a light in the plane, the side the segments start from.
        let (n, d, touch) = if lo >= -margin && (hi > margin || n.dot(shaft.start) >= d) {
            (n, d, lo)
        } else if hi <= margin {
            (-n, -d, -hi)
        } else {
            return false;
        };
        // A light on (or, by rounding, just across) the plane, such as a
        // lamp's own polygon: shadow rays end 10⁻³ of their length before it,
        // so the origin must be a thousand times farther off the plane than
        // the light can lie across it, and clear of the rounding.
        let plane_margin = if touch >= margin { margin } else { margin + 2e3 * (margin - touch.min(0.0)) };
        if !planes.add(n, d, plane_margin, margin) {
            return false;
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes::Triangle;

    /// Uniform numbers in [0, 1) from a xorshift generator seeded with `seed`.
    fn uniform(mut r: u64) -> impl FnMut() -> f32 {
        move || {
            r ^= r << 13;
            r ^= r >> 7;
            r ^= r << 17;
            (r >> 40) as f32 / (1u64 << 24) as f32
        }
    }

    fn quad(c: [Vec3; 4]) -> [Triangle; 2] {
        [Triangle { v: [c[0], c[1], c[2]] }, Triangle { v: [c[0], c[2], c[3]] }]
    }

    /// A floor (y = 0, 20 × 20), a 1 × 1 wall standing at x = 0 between
    /// y = 1.5 and 2.5, and a square lamp 2 wide at y = 5 over (0, 0).
    fn room() -> (Bvh, Vec<Vec3>) {
        let s = 10.0;
        let mut tris = quad([
            Vec3::new(-s, 0.0, -s),
            Vec3::new(-s, 0.0, s),
            Vec3::new(s, 0.0, s),
            Vec3::new(s, 0.0, -s),
        ])
        .to_vec();
        tris.extend(quad([
            Vec3::new(0.0, 1.5, -0.5),
            Vec3::new(0.0, 2.5, -0.5),
            Vec3::new(0.0, 2.5, 0.5),
            Vec3::new(0.0, 1.5, 0.5),
        ]));
        let lamp = vec![
            Vec3::new(-1.0, 5.0, -1.0),
            Vec3::new(1.0, 5.0, -1.0),
            Vec3::new(1.0, 5.0, 1.0),
            Vec3::new(-1.0, 5.0, 1.0),
        ];
        (Bvh::build(&tris), lamp)
    }

    fn lamp_box(lamp: &[Vec3]) -> Aabb {
        lamp.iter().fold(Aabb::EMPTY, |mut b, &p| {
            b.grow(p);
            b
        })
    }

    #[test]
    fn shaft_contains_every_segment_between_its_boxes() {
        let a = Aabb { min: Vec3::new(3.0, -0.2, 1.0), max: Vec3::new(3.5, 0.3, 1.4) };
        let b = Aabb { min: Vec3::new(-1.0, 5.0, -1.0), max: Vec3::new(1.0, 5.0, 1.0) };
        let shaft = Shaft::between(&a, &b, 1e-5).unwrap();
        assert!(shaft.count >= 4, "connecting planes: {}", shaft.count);
        let mut f = uniform(0x1234_5678_9abc_def0u64);
        for _ in 0..10_000 {
            let p = a.min + (a.max - a.min) * Vec3::new(f(), f(), f());
            let q = b.min + (b.max - b.min) * Vec3::new(f(), f(), f());
            assert!(shaft.contains(p.lerp(q, f())), "{p:?} → {q:?}");
        }
        // Points well off the hull are outside: beside the light, under the box.
        assert!(!shaft.contains(Vec3::new(-1.0, 5.0, 3.0)));
        assert!(!shaft.contains(Vec3::new(0.0, 2.0, 3.0)));
        assert!(!shaft.contains(Vec3::new(3.25, 2.5, -2.0)));
        assert!(Shaft::between(&Aabb::EMPTY, &b, 0.0).is_none());
    }

    #[test]
    fn floor_cells_are_clear_except_in_the_walls_shadow() {
        let (bvh, lamp) = room();
        let lb = lamp_box(&lamp);
        let cell =
            |x: f32, z: f32| Aabb { min: Vec3::new(x, -0.1, z), max: Vec3::new(x + 0.5, 0.4, z + 0.5) };
        // Far from the wall: clear, with the floor's two triangles as one plane.
        let planes = bvh.shaft_clear(&Shaft::between(&cell(6.0, 6.0), &lb, 1e-5).unwrap(), &lamp, 1e-5);
        let planes = planes.expect("clear");
        assert_eq!(planes.len(), 1);
        assert!(planes.admit(Vec3::new(6.2, 0.01, 6.2)), "above the floor");
        assert!(!planes.admit(Vec3::new(6.2, -0.01, 6.2)), "under the floor");
        assert!(!planes.admit(Vec3::new(6.2, 0.0, 6.2)), "on the floor");
        // Under the wall, which the lamp lies on both sides of: not clear.
        assert!(
            bvh.shaft_clear(&Shaft::between(&cell(-0.25, -0.25), &lb, 1e-5).unwrap(), &lamp, 1e-5).is_none()
        );
        // A cell above the wall, beside the lamp: clear, no surface in it.
        let high = Aabb { min: Vec3::new(0.6, 3.0, 0.6), max: Vec3::new(0.9, 3.3, 0.9) };
        let planes = bvh.shaft_clear(&Shaft::between(&high, &lb, 1e-5).unwrap(), &lamp, 1e-5).expect("clear");
        assert!(planes.is_empty());
    }

    #[test]
    fn a_walk_from_the_entry_node_answers_as_one_from_the_root() {
        let (bvh, lamp) = room();
        let lb = lamp_box(&lamp);
        let mut f = uniform(0x2545_f491_4f6c_dd1du64);
        let mut blocked = 0;
        // A cell under the wall (partly shadowed) and one far from it.
        for (x, z) in [(-0.3, -0.2), (6.0, 6.0)] {
            let cell = Aabb { min: Vec3::new(x, 0.0, z), max: Vec3::new(x + 0.5, 0.5, z + 0.5) };
            let entry = bvh.shaft_entry(&Shaft::between(&cell, &lb, 1e-5).unwrap()).expect("entry");
            for _ in 0..2000 {
                let o = cell.min + (cell.max - cell.min) * Vec3::new(f(), f(), f());
                let q = lb.min + (lb.max - lb.min) * Vec3::new(f(), 0.0, f());
                let d = q - o;
                let ray = crate::geometry::Ray::new(o, d.normalize());
                let t_max = d.length() * (1.0 - 1e-3);
                let expected = bvh.occluded(&ray, 0.0, t_max);
                assert_eq!(bvh.occluded_from(&entry, &ray, 0.0, t_max), expected, "{ray:?}");
                blocked += expected as usize;
            }
        }
        assert!(blocked > 100, "{blocked} blocked");
    }

    #[test]
    fn a_lamps_own_polygon_is_left_out_only_well_below_it() {
        let (bvh, lamp) = room();
        // The lamp drawn as two triangles in its own plane.
        let mut tris: Vec<Triangle> = quad([lamp[0], lamp[3], lamp[2], lamp[1]]).to_vec();
        tris.push(Triangle {
            v: [Vec3::new(9.0, 0.0, 9.0), Vec3::new(9.5, 0.0, 9.0), Vec3::new(9.0, 0.0, 9.5)],
        });
        let drawn = Bvh::build(&tris);
        let lb = lamp_box(&lamp);
        let cell = Aabb { min: Vec3::new(3.0, 1.0, 3.0), max: Vec3::new(3.5, 1.5, 3.5) };
        let planes =
            drawn.shaft_clear(&Shaft::between(&cell, &lb, 1e-5).unwrap(), &lamp, 1e-5).expect("clear");
        assert_eq!(planes.len(), 1);
        assert!(planes.admit(Vec3::new(3.2, 1.2, 3.2)));
        assert!(!planes.admit(Vec3::new(3.2, 5.0 - 1e-3, 3.2)), "a hair below the lamp");
        let _ = bvh;
    }
}

//! What the builder moves around: one 32-byte [`PrimRef`] per triangle (its box
//! and its input index), and the [`Box4`] arithmetic on them.
//!
//! Boxes are two `Vec4`s (one SSE register each where the machine has SSE);
//! only `x`, `y`, `z` mean anything, `w` is ignored by every computation that
//! reaches the tree (a primitive reference keeps its input index there).
//!
//! Determinism: the builder only ever feeds these boxes NaN-free coordinates
//! (see [`PrimRef::from_triangle`]), where vector and scalar min/max agree exactly and box
//! unions are associative and commutative — so any chunking of a parallel
//! reduction gives the same bits, on every machine.

#[cfg(test)]
use super::PreTriangle;
use crate::geometry::Aabb;
use crate::shapes::Triangle;
use glam::{Vec3, Vec4, Vec4Swizzles};

/// An axis-aligned box in `Vec4`s (`w` ignored).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Box4 {
    /// Lower corner (`w` meaningless).
    pub min: Vec4,
    /// Upper corner (`w` meaningless).
    pub max: Vec4,
}

impl Box4 {
    /// The box that contains nothing: the identity of [`Box4::union`].
    pub const EMPTY: Box4 = Box4 { min: Vec4::INFINITY, max: Vec4::NEG_INFINITY };

    /// The smallest box containing both.
    #[inline(always)]
    pub fn union(&self, o: &Box4) -> Box4 {
        Box4 { min: self.min.min(o.min), max: self.max.max(o.max) }
    }

    /// Grows the box to contain the box `min..max`.
    #[inline(always)]
    pub fn grow_box(&mut self, min: Vec4, max: Vec4) {
        self.min = self.min.min(min);
        self.max = self.max.max(max);
    }

    /// Grows the box to contain point `p`.
    #[inline(always)]
    pub fn grow(&mut self, p: Vec4) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }

    /// Edge lengths in `x`, `y`, `z` (0 on the empty box's axes).
    #[inline(always)]
    pub fn extent(&self) -> Vec3 {
        let e = (self.max - self.min).truncate();
        Vec3::select(e.cmpgt(Vec3::ZERO), e, Vec3::ZERO)
    }

    /// Surface area; 0 for the empty box. `2 · ((x·y + y·z) + z·x)` of the edge
    /// lengths, the three products in one vector multiplication. An edge that is
    /// negative or NaN (`inf − inf`) counts as 0 — by an explicit comparison, as
    /// vector `max` treats NaN differently on different architectures.
    #[inline(always)]
    pub fn area(&self) -> f32 {
        let e = self.max - self.min;
        let e = Vec4::select(e.cmpgt(Vec4::ZERO), e, Vec4::ZERO);
        let p = e * e.yzxw();
        2.0 * ((p.x + p.y) + p.z)
    }

    /// The areas of three boxes at once: lane `a` of the result is exactly
    /// `boxes[a].area()` (the same operations in the same order, lane by lane:
    /// the boxes' edge lengths transposed so that one vector holds the three `x`
    /// lengths, one the `y` and one the `z`); lane `w` is meaningless.
    #[inline(always)]
    pub fn area3(boxes: &[Box4; 3]) -> Vec4 {
        let edge = |b: &Box4| {
            let e = b.max - b.min;
            Vec4::select(e.cmpgt(Vec4::ZERO), e, Vec4::ZERO)
        };
        let [e0, e1, e2] = [edge(&boxes[0]), edge(&boxes[1]), edge(&boxes[2])];
        let x = Vec4::new(e0.x, e1.x, e2.x, 0.0);
        let y = Vec4::new(e0.y, e1.y, e2.y, 0.0);
        let z = Vec4::new(e0.z, e1.z, e2.z, 0.0);
        2.0 * ((x * y + y * z) + z * x)
    }

    /// As an [`Aabb`].
    pub fn to_aabb(self) -> Aabb {
        Aabb { min: self.min.truncate(), max: self.max.truncate() }
    }
}

/// A triangle as the builder sees it: its box, with its input index in `min.w`
/// (32 bytes, so partitioning moves two SSE registers).
#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
pub(super) struct PrimRef {
    /// Lower corner; `w` holds the input index's bits.
    min: Vec4,
    /// Upper corner (`w` meaningless).
    max: Vec4,
}

const _: () = assert!(std::mem::size_of::<PrimRef>() == 32);

/// Centroids are clamped to ±this, so that they are finite.
const BIG: f32 = f32::MAX;

/// Set in the bits of `min.w` above the input index (< 2^27), which makes `w`
/// a normal float in 2..65536: the `w` lanes of box and centroid arithmetic then
/// never meet subnormal numbers, which cost x86 CPUs a microcode assist each.
const ID_TAG: u32 = 0x4000_0000;
const ID_MASK: u32 = (1 << 27) - 1;
const _: () = assert!(super::MAX_TRIANGLES <= ID_MASK as usize + 1);

impl PrimRef {
    /// A placeholder (scratch space).
    pub const ZERO: PrimRef = PrimRef { min: Vec4::ZERO, max: Vec4::ZERO };

    /// The reference of triangle `id` (`tri`, precomputed as `pre`) as
    /// [`PrimRef::from_triangle`] makes it, in the straightforward form tests
    /// compare it with.
    #[cfg(test)]
    pub fn new(id: u32, tri: &Triangle, pre: &PreTriangle) -> Self {
        debug_assert!(id <= ID_MASK);
        let mut min = Vec4::INFINITY;
        let mut max = Vec4::NEG_INFINITY;
        for p in tri.v.into_iter().chain(pre.vertices()) {
            // Comparisons are false on NaN: a NaN coordinate leaves the box as it is.
            let p = p.extend(0.0);
            min = Vec4::select(p.cmplt(min), p, min);
            max = Vec4::select(p.cmpgt(max), p, max);
        }
        let empty = min.cmpgt(max);
        let (min, max) = (Vec4::select(empty, Vec4::ZERO, min), Vec4::select(empty, Vec4::ZERO, max));
        PrimRef { min: min.with_w(f32::from_bits(ID_TAG | id)), max: max.with_w(0.0) }
    }

    /// The reference of triangle `id` (`tri`).
    ///
    /// The box covers both the input vertices and the ones the intersection test
    /// reconstructs (`v0 + e1`, `v0 + e2`, see [`PreTriangle`](super::PreTriangle)),
    /// so leaf boxes contain either exactly. It is free of NaNs — NaN coordinates
    /// are ignored (such a triangle can never be hit) and an axis with no number at
    /// all collapses to 0 — because the box unions that follow are only
    /// order-independent on NaN-free boxes.
    ///
    /// In 4-lane vector arithmetic: the edges and reconstructed vertices are the
    /// single-precision subtractions and additions `PreTriangle::new` performs,
    /// lane by lane, so they have the same bits (a test compares with the
    /// straightforward form).
    #[inline(always)]
    pub fn from_triangle(id: u32, tri: &Triangle) -> Self {
        debug_assert!(id <= ID_MASK);
        let [a, b, c] = tri.v.map(|v| v.extend(0.0));
        let (e1, e2) = (b - a, c - a);
        let mut min = Vec4::INFINITY;
        let mut max = Vec4::NEG_INFINITY;
        for p in [a, b, c, a, a + e1, a + e2] {
            // Comparisons are false on NaN: a NaN coordinate leaves the box as it is.
            min = Vec4::select(p.cmplt(min), p, min);
            max = Vec4::select(p.cmpgt(max), p, max);
        }
        let empty = min.cmpgt(max);
        let (min, max) = (Vec4::select(empty, Vec4::ZERO, min), Vec4::select(empty, Vec4::ZERO, max));
        PrimRef { min: min.with_w(f32::from_bits(ID_TAG | id)), max: max.with_w(0.0) }
    }

    /// The 32 bytes as words (for scratch space that is allocated zeroed).
    #[inline(always)]
    pub fn to_slot(self) -> [u32; 8] {
        let [a, b, c, d] = self.min.to_array().map(f32::to_bits);
        let [e, f, g, h] = self.max.to_array().map(f32::to_bits);
        [a, b, c, d, e, f, g, h]
    }

    /// The reference stored by [`PrimRef::to_slot`].
    #[inline(always)]
    pub fn from_slot(s: &[u32; 8]) -> Self {
        let f = f32::from_bits;
        PrimRef {
            min: Vec4::new(f(s[0]), f(s[1]), f(s[2]), f(s[3])),
            max: Vec4::new(f(s[4]), f(s[5]), f(s[6]), f(s[7])),
        }
    }

    /// The input index.
    #[inline(always)]
    pub fn id(&self) -> u32 {
        self.min.w.to_bits() & ID_MASK
    }

    /// Lower corner (`w` meaningless).
    #[inline(always)]
    pub fn min(&self) -> Vec4 {
        self.min
    }

    /// Upper corner (`w` meaningless).
    #[inline(always)]
    pub fn max(&self) -> Vec4 {
        self.max
    }

    /// The box's centre, clamped to finite values (`w` meaningless): `+inf` and
    /// NaN (a box from −inf to +inf) become `BIG`, `−inf` becomes `−BIG`. Explicit
    /// comparisons (false on NaN) rather than `min`/`max`, whose NaN handling
    /// differs between SSE, NEON and scalar code.
    #[inline(always)]
    pub fn centroid(&self) -> Vec4 {
        let c = (self.min + self.max) * 0.5;
        let c = Vec4::select(c.cmple(Vec4::splat(BIG)), c, Vec4::splat(BIG));
        Vec4::select(c.cmpge(Vec4::splat(-BIG)), c, Vec4::splat(-BIG))
    }
}

/// Box and centroid box of `prims`.
pub(super) fn bounds_of(prims: &[PrimRef]) -> (Box4, Box4) {
    let (mut geo, mut cent) = (Box4::EMPTY, Box4::EMPTY);
    for p in prims {
        geo.grow_box(p.min, p.max);
        cent.grow(p.centroid());
    }
    (geo, cent)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn prim_refs_keep_their_index_and_have_finite_centroids() {
        let tri = Triangle {
            v: [Vec3::new(f32::NEG_INFINITY, 0.0, 1.0), Vec3::new(f32::INFINITY, 2.0, 3.0), Vec3::ONE],
        };
        let p = PrimRef::new(123_456, &tri, &PreTriangle::new(&tri));
        assert_eq!(p.id(), 123_456);
        let c = p.centroid().truncate();
        assert!(c.is_finite(), "{c:?}");
        assert_eq!(c.y, 1.0);
        let nan = Triangle { v: [Vec3::new(f32::NAN, 0.0, 0.0), Vec3::new(f32::NAN, 1.0, 0.0), Vec3::Z] };
        let q = PrimRef::new(7, &nan, &PreTriangle::new(&nan));
        assert!(!q.min().is_nan() && !q.max().truncate().is_nan());
        assert_eq!(q.id(), 7);
    }

    #[test]
    fn from_triangle_is_new_bit_for_bit() {
        let mut next = crate::sampling::Sampler::new(4, 4, 4, 4).stream();
        let specials = [0.0, -0.0, 1e-30, -1e38, 3e38, f32::INFINITY, f32::NEG_INFINITY, f32::NAN];
        let bits = |p: &PrimRef| (p.min.to_array().map(f32::to_bits), p.max.to_array().map(f32::to_bits));
        for i in 0..20_000u32 {
            let mut v = [0; 3].map(|_| Vec3::new(next(), next(), next()) * 200.0 - Vec3::splat(100.0));
            if i % 3 == 0 {
                // Coordinates that make the edges round, overflow or turn NaN.
                let k = (next() * 3.0) as usize % 3;
                let a = (next() * 3.0) as usize % 3;
                v[k][a] = specials[i as usize / 3 % specials.len()];
            }
            if i % 7 == 0 {
                v[1] = v[0]; // degenerate
            }
            let tri = Triangle { v };
            assert_eq!(
                bits(&PrimRef::from_triangle(i, &tri)),
                bits(&PrimRef::new(i, &tri, &PreTriangle::new(&tri)))
            );
        }
    }

    #[test]
    fn three_areas_at_once_are_the_areas() {
        let mut uniform = crate::sampling::Sampler::new(2, 3, 4, 5).stream();
        let mut next = || uniform() * 20.0 - 10.0;
        let specials = [0.0, -0.0, 1e-30, 3e38, -3e38, f32::INFINITY, f32::NEG_INFINITY];
        for i in 0..20_000usize {
            let boxes: [Box4; 3] = std::array::from_fn(|k| {
                let a = Vec4::new(next(), next(), next(), next());
                let mut b = a + Vec4::new(next(), next(), next(), 0.0).abs() * 0.3;
                if (i + k) % 5 == 0 {
                    b[(i / 5) % 3] = specials[(i / 15) % specials.len()];
                }
                if (i + k) % 11 == 0 {
                    return Box4::EMPTY;
                }
                Box4 { min: a, max: b }
            });
            let v = Box4::area3(&boxes);
            for k in 0..3 {
                assert_eq!(v[k].to_bits(), boxes[k].area().to_bits(), "case {i} box {k}: {:?}", boxes[k]);
            }
        }
    }

    #[test]
    fn box_area_and_union() {
        let a = Box4 { min: Vec4::ZERO, max: Vec4::new(1.0, 2.0, 3.0, 99.0) };
        assert_eq!(a.area(), 2.0 * (2.0 + 6.0 + 3.0));
        assert_eq!(Box4::EMPTY.area(), 0.0);
        let odd = Box4 { min: Vec4::new(0.5, -2.0, 1.0, 0.0), max: Vec4::new(1.25, 3.0, 7.0, 0.0) };
        assert_eq!(odd.area(), odd.to_aabb().area(), "as Aabb::area computes it");
        let b = Box4 { min: Vec4::splat(-1.0), max: Vec4::ZERO };
        let u = a.union(&b);
        assert_eq!(u.to_aabb(), Aabb { min: Vec3::splat(-1.0), max: Vec3::new(1.0, 2.0, 3.0) });
    }
}

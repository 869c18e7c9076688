//! Eight-ray packets: nearest hit for camera rays, any hit for shadow rays,
//! traversing the tree once per packet.
//!
//! **Traversal.** A packet whose rays have, per axis, direction components of
//! one sign is bounded by interval arithmetic: per axis the smallest and largest
//! origin coordinate and inverse direction. At each wide node one AVX sequence
//! gives, for all eight children, a lower bound of every ray's entry distance
//! and an upper bound of every ray's exit distance (a "frustum" test); children
//! are visited nearest (lowest bound) first and culled against the largest
//! nearest-hit distance of the packet. At a leaf each ray runs the single-ray
//! box test on its own (eight rays in the eight lanes), and the rays that pass
//! run Möller–Trumbore against each of the leaf's triangles, eight rays at once.
//!
//! **Same answers as single rays.** The packet query returns, for every ray,
//! exactly what [`Bvh::intersect`] / [`Bvh::occluded`] return for it (tests
//! compare them field by field, bit for bit):
//!
//! * The frustum bounds never cull a box a ray's own test passes. A ray's
//!   slab distance is `round(round(plane − o) · inv)`; rounding is monotonic, so
//!   for `o` in `[o_lo, o_hi]` and `inv` in `[inv_lo, inv_hi]` (one sign) it lies
//!   between the same expressions evaluated at the interval ends, which is what
//!   the frustum test computes. So its entry bound is ≤ the ray's entry, its
//!   exit bound ≥ the ray's exit, and `near ≤ far · ROBUST_EXIT` passes
//!   whenever the ray's test does.
//! * A leaf's triangles are tested for a ray only if the ray's own box test
//!   (the same operations as the single-ray one) passes. A child box lies
//!   inside its parent's (checked by [`Bvh::validate`]), so by the same
//!   monotonicity a ray that passes a leaf's box passes all its ancestors':
//!   a single ray visits exactly the leaves whose own box test it passes. For
//!   any-hit queries (fixed interval) the packet tests the same leaves for each
//!   ray as the single ray does, hence the same answer.
//! * Nearest hit: triangles are tested with exactly the single-ray operations
//!   (no FMA), so every `t`, `u`, `v` is the same; the packet keeps, per ray,
//!   the smallest `t`. The single-ray query also returns the smallest `t` (the
//!   robust box test visits every leaf that can hold a nearer hit; the brute
//!   force tests in `tests/bvh.rs` check this), but among hits at a
//!   bit-identical `t` it keeps the first one in its own traversal order, which
//!   a packet does not reproduce. So the packet also notices a second hit at a
//!   ray's current nearest `t` ("tie"); a ray whose final nearest hit is tied
//!   is answered by the single-ray query instead. Ties are rare (a ray exactly
//!   through a shared edge or vertex, or duplicate triangles).
//! * Rays the interval bounds cannot handle (a non-finite origin or direction,
//!   a zero direction component, NaN interval ends, directions of both signs
//!   on one axis within the packet) make the packet fall back to single-ray
//!   queries, as does a machine without AVX or a tree with SIMD switched off
//!   ([`Bvh::set_simd`], [`Bvh::set_avx`]). The answers are the same in every case.

use super::Bvh;
use crate::geometry::Ray;
use crate::shapes::Hit;

/// Rays in a packet.
pub const LANES: usize = 8;

/// Per-ray inputs of a packet query.
struct Packet<'a> {
    rays: &'a [Ray; LANES],
    t_min: [f32; LANES],
    t_max: [f32; LANES],
    /// Rays to answer.
    active: u8,
}

/// See [`Bvh::intersect8`].
pub(super) fn intersect8(
    bvh: &Bvh,
    rays: &[Ray; LANES],
    t_min: [f32; LANES],
    t_max: [f32; LANES],
    active: u8,
) -> [Option<Hit>; LANES] {
    let mut out = [None; LANES];
    let p = Packet { rays, t_min, t_max, active };
    let mut single = active;
    #[cfg(target_arch = "x86_64")]
    if !bvh.wide.is_empty() && active.count_ones() > 1 && bvh.avx_active() {
        // SAFETY: `avx_active` checked that this CPU has AVX.
        if let Some(tied) = unsafe { avx::intersect(bvh, &p, &mut out) } {
            single = tied;
        }
    }
    while single != 0 {
        let j = single.trailing_zeros() as usize;
        single &= single - 1;
        out[j] = bvh.intersect(&rays[j], t_min[j], t_max[j]);
    }
    out
}

/// See [`Bvh::occluded8`].
pub(super) fn occluded8(
    bvh: &Bvh,
    rays: &[Ray; LANES],
    t_min: [f32; LANES],
    t_max: [f32; LANES],
    active: u8,
) -> u8 {
    let p = Packet { rays, t_min, t_max, active };
    #[cfg(target_arch = "x86_64")]
    if !bvh.wide.is_empty() && active.count_ones() > 1 && bvh.avx_active() {
        // SAFETY: `avx_active` checked that this CPU has AVX.
        if let Some(hit) = unsafe { avx::occluded(bvh, &p) } {
            return hit;
        }
    }
    let mut out = 0;
    let mut todo = p.active;
    while todo != 0 {
        let j = todo.trailing_zeros() as usize;
        todo &= todo - 1;
        if bvh.occluded(&rays[j], t_min[j], t_max[j]) {
            out |= 1 << j;
        }
    }
    out
}

#[cfg(target_arch = "x86_64")]
mod avx {
    //! The AVX packet traversal. Every function here either is compiled for AVX
    //! or is `#[inline(always)]` into one that is, and is only reached after
    //! `is_x86_feature_detected!("avx")` (through [`Bvh::avx_active`]).

    use super::{LANES, Packet};
    use crate::bvh::Bvh;
    use crate::bvh::blocks::{RaySse, TriBlock, hits_sse};
    use crate::bvh::wide::{NodeRef, ROBUST_EXIT, Stack, W, descend_nearest, leaf_range};
    use crate::geometry::Ray;
    use crate::shapes::Hit;
    use std::arch::x86_64::*;

    /// The packet in structure-of-arrays form, plus its interval bounds.
    struct Lanes {
        /// Origins, per axis, one ray per lane (inactive lanes copy an active ray).
        o: [__m256; 3],
        /// Directions.
        d: [__m256; 3],
        /// `1 / d`, as the single-ray query computes it.
        inv: [__m256; 3],
        /// Interval starts.
        t_min: __m256,
        /// Interval ends of the active rays, `-inf` in inactive lanes (which
        /// then pass no box test and record no hit).
        t_max: __m256,
        /// All bits set in the lanes of active rays.
        active: __m256,
        /// Per axis: true when every direction component is negative (the
        /// near plane is then the box's max plane).
        neg: [bool; 3],
        /// Per axis, the origin bound to subtract from the near planes: the
        /// largest origin coordinate for positive directions, else the smallest.
        o_near: [__m256; 3],
        /// The origin bound for the far planes (the other end).
        o_far: [__m256; 3],
        /// Smallest inverse direction per axis (broadcast).
        inv_lo: [__m256; 3],
        /// Largest inverse direction per axis.
        inv_hi: [__m256; 3],
        /// Smallest interval start of the active rays.
        t_min_lo: f32,
    }

    /// Builds [`Lanes`], or `None` when the interval bounds cannot handle the
    /// active rays: a non-finite origin, a NaN interval end, a zero or
    /// non-finite `1 / d`, or direction components of both signs on one axis.
    ///
    /// # Safety
    /// The CPU must support AVX.
    #[inline(always)]
    unsafe fn lanes(p: &Packet) -> Option<Lanes> {
        let full = p.active == 0xff;
        let first = p.active.trailing_zeros() as usize;
        // Inactive lanes copy an active ray, so that they do not widen the bounds.
        let src = |j: usize| if full || p.active & (1 << j) != 0 { j } else { first };
        let picked: [Ray; LANES];
        let rays = if full {
            p.rays
        } else {
            picked = std::array::from_fn(|j| p.rays[src(j)]);
            &picked
        };
        let t_min: [f32; LANES] = if full { p.t_min } else { std::array::from_fn(|j| p.t_min[src(j)]) };
        let t_max: [f32; LANES] = if full { p.t_max } else { std::array::from_fn(|j| p.t_max[src(j)]) };
        let bits: [i32; LANES] = std::array::from_fn(|j| -(((p.active >> j) & 1) as i32));
        // SAFETY: the caller guarantees AVX; the loads read 32-byte arrays
        // and (in `transpose`) the 192 bytes of `rays`.
        unsafe {
            let v = |a: &[f32; LANES]| _mm256_loadu_ps(a.as_ptr());
            let (o, d) = transpose(rays);
            // `1 / d` per lane: the IEEE division `WideRay::new` (`recip`) does.
            let one = _mm256_set1_ps(1.0);
            let inv = [_mm256_div_ps(one, d[0]), _mm256_div_ps(one, d[1]), _mm256_div_ps(one, d[2])];
            let (t_min, t_max) = (v(&t_min), v(&t_max));
            let active = _mm256_castsi256_ps(_mm256_loadu_si256(bits.as_ptr().cast()));
            // |x| < inf is false for NaN and infinities.
            let abs = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fff_ffff));
            let inf = _mm256_set1_ps(f32::INFINITY);
            let finite = |x: __m256| _mm256_cmp_ps::<_CMP_LT_OQ>(_mm256_and_ps(x, abs), inf);
            let zero = _mm256_setzero_ps();
            let mut ok = _mm256_cmp_ps::<_CMP_ORD_Q>(t_min, t_max);
            for a in 0..3 {
                ok = _mm256_and_ps(ok, _mm256_and_ps(finite(o[a]), finite(inv[a])));
                ok = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_NEQ_OQ>(inv[a], zero));
            }
            if _mm256_movemask_ps(ok) != 0xff {
                return None;
            }
            let signs = [_mm256_movemask_ps(inv[0]), _mm256_movemask_ps(inv[1]), _mm256_movemask_ps(inv[2])];
            if signs.iter().any(|&m| m != 0 && m != 0xff) {
                return None;
            }
            let neg = [signs[0] == 0xff, signs[1] == 0xff, signs[2] == 0xff];
            let (lo, hi) = (|x: __m256| splat_min(x), |x: __m256| splat_max(x));
            let (o_lo, o_hi) = ([lo(o[0]), lo(o[1]), lo(o[2])], [hi(o[0]), hi(o[1]), hi(o[2])]);
            let pick = |a: usize, near: bool| if neg[a] == near { o_lo[a] } else { o_hi[a] };
            Some(Lanes {
                o,
                d,
                inv,
                t_min,
                t_max: _mm256_blendv_ps(_mm256_set1_ps(f32::NEG_INFINITY), t_max, active),
                active,
                neg,
                o_near: [pick(0, true), pick(1, true), pick(2, true)],
                o_far: [pick(0, false), pick(1, false), pick(2, false)],
                inv_lo: [lo(inv[0]), lo(inv[1]), lo(inv[2])],
                inv_hi: [hi(inv[0]), hi(inv[1]), hi(inv[2])],
                t_min_lo: _mm256_cvtss_f32(splat_min(t_min)),
            })
        }
    }

    /// The origins and directions of `rays`, one ray per lane.
    ///
    /// # Safety
    /// The CPU must support AVX.
    #[inline(always)]
    unsafe fn transpose(rays: &[Ray; LANES]) -> ([__m256; 3], [__m256; 3]) {
        use std::mem::{offset_of, size_of};
        let packed = offset_of!(Ray, origin) == 0 && offset_of!(Ray, dir) == 12 && size_of::<Ray>() == 24;
        if !packed {
            let (mut o, mut d) = ([[0.0f32; LANES]; 3], [[0.0f32; LANES]; 3]);
            for (j, r) in rays.iter().enumerate() {
                for a in 0..3 {
                    o[a][j] = r.origin[a];
                    d[a][j] = r.dir[a];
                }
            }
            // SAFETY: the caller guarantees AVX; the loads read 32-byte arrays.
            return unsafe {
                let v = |a: &[f32; LANES]| _mm256_loadu_ps(a.as_ptr());
                ([v(&o[0]), v(&o[1]), v(&o[2])], [v(&d[0]), v(&d[1]), v(&d[2])])
            };
        }
        // SAFETY: the caller guarantees AVX. `rays` is 8 × 24 bytes of f32
        // (`packed`: origin x y z, then dir x y z); the 16-byte loads at float
        // offsets 6k and 6k + 2 (k < 8) end at most at float 48, its end.
        unsafe {
            let f = rays.as_ptr().cast::<f32>();
            let [ox, oy, oz, dx] = transpose4([pair(f, 0, 0), pair(f, 1, 0), pair(f, 2, 0), pair(f, 3, 0)]);
            let [_, _, dy, dz] = transpose4([pair(f, 0, 2), pair(f, 1, 2), pair(f, 2, 2), pair(f, 3, 2)]);
            ([ox, oy, oz], [dx, dy, dz])
        }
    }

    /// Floats `6k + at .. 6k + at + 4` of `f` in the low half, those of
    /// `6(k + 4) + at ..` in the high half.
    ///
    /// # Safety
    /// The CPU must support AVX and `f` must hold `6(k + 4) + at + 4` floats.
    #[inline(always)]
    unsafe fn pair(f: *const f32, k: usize, at: usize) -> __m256 {
        // SAFETY: the caller guarantees AVX and the length.
        unsafe {
            let lo = _mm256_castps128_ps256(_mm_loadu_ps(f.add(6 * k + at)));
            _mm256_insertf128_ps::<1>(lo, _mm_loadu_ps(f.add(6 * (k + 4) + at)))
        }
    }

    /// 4 × 4 transposes within each 128-bit half: lane `j` of row `i` of the
    /// result is lane `i` of row `j` of `a` (in the same half).
    ///
    /// # Safety
    /// The CPU must support AVX.
    #[inline(always)]
    unsafe fn transpose4(a: [__m256; 4]) -> [__m256; 4] {
        // SAFETY: the caller guarantees AVX.
        unsafe {
            let (t0, t1) = (_mm256_unpacklo_ps(a[0], a[1]), _mm256_unpackhi_ps(a[0], a[1]));
            let (t2, t3) = (_mm256_unpacklo_ps(a[2], a[3]), _mm256_unpackhi_ps(a[2], a[3]));
            [
                _mm256_shuffle_ps::<0x44>(t0, t2),
                _mm256_shuffle_ps::<0xee>(t0, t2),
                _mm256_shuffle_ps::<0x44>(t1, t3),
                _mm256_shuffle_ps::<0xee>(t1, t3),
            ]
        }
    }

    /// The smallest lane of `v` in every lane.
    ///
    /// # Safety
    /// The CPU must support AVX.
    #[inline(always)]
    unsafe fn splat_min(v: __m256) -> __m256 {
        // SAFETY: the caller guarantees AVX.
        unsafe {
            let m = _mm256_min_ps(v, _mm256_permute2f128_ps::<1>(v, v));
            let m = _mm256_min_ps(m, _mm256_permute_ps::<0b0100_1110>(m));
            _mm256_min_ps(m, _mm256_permute_ps::<0b1011_0001>(m))
        }
    }

    /// The largest lane of `v` in every lane.
    ///
    /// # Safety
    /// The CPU must support AVX.
    #[inline(always)]
    unsafe fn splat_max(v: __m256) -> __m256 {
        // SAFETY: the caller guarantees AVX.
        unsafe {
            let m = _mm256_max_ps(v, _mm256_permute2f128_ps::<1>(v, v));
            let m = _mm256_max_ps(m, _mm256_permute_ps::<0b0100_1110>(m));
            _mm256_max_ps(m, _mm256_permute_ps::<0b1011_0001>(m))
        }
    }

    /// Frustum test of all eight children of `node`: per child, a lower bound
    /// of the entry distance of every ray (`+inf` where culled) and the mask of
    /// children some ray may enter before `t_far`.
    ///
    /// # Safety
    /// The CPU must support AVX.
    #[inline(always)]
    unsafe fn frustum(node: NodeRef, l: &Lanes, t_far: f32) -> ([f32; W], u32) {
        // SAFETY: the caller guarantees AVX; the store writes the 32 bytes of `out`.
        unsafe {
            let load = |a: usize| row(node, a);
            let mut near = _mm256_set1_ps(l.t_min_lo);
            let mut far = _mm256_set1_ps(t_far);
            for a in 0..3 {
                let (rn, rf) = if l.neg[a] { (a + 3, a) } else { (a, a + 3) };
                let dn = _mm256_sub_ps(load(rn), l.o_near[a]);
                let df = _mm256_sub_ps(load(rf), l.o_far[a]);
                // min(dn · inv_lo, dn · inv_hi) is the product with inv_lo where
                // dn ≥ 0 (sign bit clear) and with inv_hi where dn < 0; the
                // max of the exit products the other way round.
                let t0 = _mm256_mul_ps(dn, _mm256_blendv_ps(l.inv_lo[a], l.inv_hi[a], dn));
                let t1 = _mm256_mul_ps(df, _mm256_blendv_ps(l.inv_hi[a], l.inv_lo[a], df));
                near = _mm256_max_ps(t0, near);
                far = _mm256_min_ps(t1, far);
            }
            let hit = _mm256_cmp_ps::<_CMP_LE_OQ>(near, _mm256_mul_ps(far, _mm256_set1_ps(ROBUST_EXIT)));
            let mut out = [0.0f32; W];
            _mm256_storeu_ps(out.as_mut_ptr(), near);
            (out, _mm256_movemask_ps(hit) as u32)
        }
    }

    /// Row `a` of `node`'s boxes (see `wide::Slots`) in eight lanes: a narrow
    /// node's four, then four empty slots' (`+inf` lower, `-inf` upper
    /// corners), exactly as if it were a wide node.
    ///
    /// # Safety
    /// The CPU must support AVX.
    #[inline(always)]
    unsafe fn row(node: NodeRef, a: usize) -> __m256 {
        // SAFETY: the caller guarantees AVX; the loads read the 32 bytes of a
        // `[f32; 8]` row or the 16 bytes of a `[f32; 4]` one.
        unsafe {
            match node {
                NodeRef::Wide(n) => _mm256_loadu_ps(n.bounds[a].as_ptr()),
                NodeRef::Narrow(n) => {
                    let empty = _mm_set1_ps(if a < 3 { f32::INFINITY } else { f32::NEG_INFINITY });
                    _mm256_insertf128_ps::<1>(
                        _mm256_castps128_ps256(_mm_loadu_ps(n.bounds[a].as_ptr())),
                        empty,
                    )
                }
            }
        }
    }

    /// Bit `k` set where child `k` of `node` is a leaf (bit 31 of its word).
    ///
    /// # Safety
    /// The CPU must support AVX.
    #[inline(always)]
    unsafe fn leaf_mask(node: NodeRef) -> u32 {
        // SAFETY: the caller guarantees AVX; the loads read the 32 or 16 bytes of `child`.
        unsafe {
            match node {
                NodeRef::Wide(n) => {
                    _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_loadu_si256(n.child.as_ptr().cast())))
                        as u32
                }
                NodeRef::Narrow(n) => {
                    _mm_movemask_ps(_mm_castsi128_ps(_mm_loadu_si128(n.child.as_ptr().cast()))) as u32
                }
            }
        }
    }

    /// Each ray's own box test of child `k` of `node` (the single-ray
    /// operations, one ray per lane) within `(t_min, t_far)`: all bits set in
    /// the lanes that pass.
    ///
    /// # Safety
    /// The CPU must support AVX.
    #[inline(always)]
    unsafe fn box_rays(node: NodeRef, k: usize, l: &Lanes, t_far: __m256) -> __m256 {
        // SAFETY: the caller guarantees AVX.
        unsafe {
            let mut near = l.t_min;
            let mut far = t_far;
            for a in 0..3 {
                let (rn, rf) = if l.neg[a] { (a + 3, a) } else { (a, a + 3) };
                let t0 = _mm256_mul_ps(_mm256_sub_ps(_mm256_set1_ps(node.bound(rn, k)), l.o[a]), l.inv[a]);
                let t1 = _mm256_mul_ps(_mm256_sub_ps(_mm256_set1_ps(node.bound(rf, k)), l.o[a]), l.inv[a]);
                near = _mm256_max_ps(t0, near);
                far = _mm256_min_ps(t1, far);
            }
            _mm256_cmp_ps::<_CMP_LE_OQ>(near, _mm256_mul_ps(far, _mm256_set1_ps(ROBUST_EXIT)))
        }
    }

    /// Möller–Trumbore of triangle `lane` of `block` against every ray, with the
    /// operations of `moller_trumbore` in its order: returns the lanes whose
    /// hit is valid apart from the upper bound (`u`, `v` inside, `t > t_min`),
    /// and `t`, `u`, `v`.
    ///
    /// The scalar test's `det == 0` early-out needs no lane of its own: then
    /// `1 / det` is infinite and `u` is infinite or NaN, which fails `0 ≤ u ≤ 1`
    /// (as a NaN `det` does).
    ///
    /// # Safety
    /// The CPU must support AVX.
    #[inline(always)]
    unsafe fn triangle(block: &TriBlock, lane: usize, l: &Lanes) -> (__m256, __m256, __m256, __m256) {
        let tri = block.get(lane);
        // SAFETY: the caller guarantees AVX.
        unsafe {
            let s = _mm256_set1_ps;
            let (add, sub, mul) = (_mm256_add_ps, _mm256_sub_ps, _mm256_mul_ps);
            let [ox, oy, oz] = l.o;
            let [dx, dy, dz] = l.d;
            let (v0x, v0y, v0z) = (s(tri.v0.x), s(tri.v0.y), s(tri.v0.z));
            let (e1x, e1y, e1z) = (s(tri.e1.x), s(tri.e1.y), s(tri.e1.z));
            let (e2x, e2y, e2z) = (s(tri.e2.x), s(tri.e2.y), s(tri.e2.z));
            // p = dir × e2
            let px = sub(mul(dy, e2z), mul(e2y, dz));
            let py = sub(mul(dz, e2x), mul(e2z, dx));
            let pz = sub(mul(dx, e2y), mul(e2x, dy));
            // det = e1 · p
            let det = add(add(mul(e1x, px), mul(e1y, py)), mul(e1z, pz));
            let inv = _mm256_div_ps(s(1.0), det);
            // s = origin - v0; u = (s · p) * inv
            let (sx, sy, sz) = (sub(ox, v0x), sub(oy, v0y), sub(oz, v0z));
            let u = mul(add(add(mul(sx, px), mul(sy, py)), mul(sz, pz)), inv);
            // q = s × e1; v = (dir · q) * inv; t = (e2 · q) * inv
            let qx = sub(mul(sy, e1z), mul(e1y, sz));
            let qy = sub(mul(sz, e1x), mul(e1z, sx));
            let qz = sub(mul(sx, e1y), mul(e1x, sy));
            let v = mul(add(add(mul(dx, qx), mul(dy, qy)), mul(dz, qz)), inv);
            let t = mul(add(add(mul(e2x, qx), mul(e2y, qy)), mul(e2z, qz)), inv);
            let (zero, one) = (_mm256_setzero_ps(), s(1.0));
            // Ordered comparisons: false on NaN, as the scalar ones.
            let mut ok = _mm256_cmp_ps::<_CMP_GE_OQ>(u, zero);
            ok = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_LE_OQ>(u, one));
            ok = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_GE_OQ>(v, zero));
            ok = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_LE_OQ>(add(u, v), one));
            ok = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_GT_OQ>(t, l.t_min));
            (ok, t, u, v)
        }
    }

    /// All bits set in lane `j` only.
    ///
    /// # Safety
    /// The CPU must support AVX.
    #[inline(always)]
    unsafe fn lane_mask(j: usize) -> __m256 {
        const MASKS: [[i32; LANES]; LANES] = {
            let mut m = [[0; LANES]; LANES];
            let mut j = 0;
            while j < LANES {
                m[j][j] = -1;
                j += 1;
            }
            m
        };
        // SAFETY: the caller guarantees AVX; the load reads the 32 bytes of a row.
        unsafe { _mm256_castsi256_ps(_mm256_loadu_si256(MASKS[j].as_ptr().cast())) }
    }

    /// Largest lane.
    ///
    /// # Safety
    /// The CPU must support AVX.
    #[inline(always)]
    unsafe fn hmax(v: __m256) -> f32 {
        // SAFETY: the caller guarantees AVX.
        unsafe {
            let m = _mm_max_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps::<1>(v));
            let m = _mm_max_ps(m, _mm_movehl_ps(m, m));
            let m = _mm_max_ss(m, _mm_shuffle_ps::<1>(m, m));
            _mm_cvtss_f32(m)
        }
    }

    /// Nearest hits of the packet `p` into `out`; returns the rays whose nearest
    /// hit is tied (to be answered by the single-ray query), or `None` when
    /// the packet cannot be bounded (see [`lanes`]; `out` is then untouched).
    ///
    /// # Safety
    /// The CPU must support AVX.
    #[target_feature(enable = "avx")]
    pub(super) unsafe fn intersect(bvh: &Bvh, p: &Packet, out: &mut [Option<Hit>; LANES]) -> Option<u8> {
        // SAFETY: this function is compiled for AVX and the caller checked the CPU.
        unsafe {
            let l = lanes(p)?;
            let blocks = &bvh.blocks[..];
            // Per lane: nearest t so far (starting at the interval end, -inf
            // for inactive lanes), its u, v and triangle lane, whether there
            // is a hit and whether a second hit at the same t was seen.
            let mut best = l.t_max;
            let (mut bu, mut bv, mut bid) = (_mm256_setzero_ps(), _mm256_setzero_ps(), _mm256_setzero_ps());
            let (mut has, mut tie) = (_mm256_setzero_ps(), _mm256_setzero_ps());
            let mut best_hi = hmax(best);
            let mut stack = Stack::<(u32, f32)>::new();
            let mut current = 0u32;
            loop {
                let node = NodeRef::of(bvh, current);
                let children = node.children();
                let (e, mask) = frustum(node, &l, best_hi);
                let leaf = leaf_mask(node);
                let (mut leaves, inner) = (mask & leaf, mask & !leaf);
                while leaves != 0 {
                    let k = leaves.trailing_zeros() as usize;
                    leaves &= leaves - 1;
                    if e[k] > best_hi * ROBUST_EXIT {
                        continue;
                    }
                    // Inactive lanes have best = -inf and fail.
                    let rays = box_rays(node, k, &l, best);
                    if _mm256_movemask_ps(rays) == 0 {
                        continue;
                    }
                    let (first, count) = leaf_range(children[k]);
                    let block = &blocks[(first / 4) as usize];
                    let mut improved = false;
                    for lane in (first % 4)..(first % 4 + count) {
                        let (ok, t, u, v) = triangle(block, lane as usize, &l);
                        let ok = _mm256_and_ps(_mm256_and_ps(ok, rays), _mm256_cmp_ps::<_CMP_LE_OQ>(t, best));
                        if _mm256_movemask_ps(ok) == 0 {
                            continue;
                        }
                        let lt = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_LT_OQ>(t, best));
                        let eq = _mm256_and_ps(_mm256_and_ps(ok, has), _mm256_cmp_ps::<_CMP_EQ_OQ>(t, best));
                        tie = _mm256_or_ps(_mm256_andnot_ps(lt, tie), eq);
                        if _mm256_movemask_ps(lt) != 0 {
                            let at = (first & !3) + lane;
                            if bvh.prefetch {
                                // The hit's primitive index is read when the
                                // walk ends: start loading it (a hint).
                                let p = bvh.prim_ids.as_ptr().wrapping_add(at as usize);
                                _mm_prefetch::<_MM_HINT_T0>(p.cast());
                            }
                            let id = _mm256_castsi256_ps(_mm256_set1_epi32(at as i32));
                            best = _mm256_blendv_ps(best, t, lt);
                            bu = _mm256_blendv_ps(bu, u, lt);
                            bv = _mm256_blendv_ps(bv, v, lt);
                            bid = _mm256_blendv_ps(bid, id, lt);
                            has = _mm256_or_ps(has, lt);
                            improved = true;
                        }
                    }
                    if improved {
                        best_hi = hmax(best);
                    }
                }
                // Interior children still in front of the packet's farthest
                // nearest hit, nearest bound first (stable on ties).
                let limit = best_hi * ROBUST_EXIT;
                if let Some(nearest) = descend_nearest(children, &e, inner, limit, &mut stack) {
                    current = nearest;
                    continue;
                }
                current = loop {
                    match stack.pop() {
                        None => {
                            let has = _mm256_movemask_ps(has) as u8;
                            let tie = _mm256_movemask_ps(tie) as u8 & has;
                            let mut todo = has & !tie;
                            if todo != 0 {
                                let mut ts = [0.0f32; LANES];
                                let (mut us, mut vs, mut ids) =
                                    ([0.0f32; LANES], [0.0f32; LANES], [0u32; LANES]);
                                _mm256_storeu_ps(ts.as_mut_ptr(), best);
                                _mm256_storeu_ps(us.as_mut_ptr(), bu);
                                _mm256_storeu_ps(vs.as_mut_ptr(), bv);
                                _mm256_storeu_si256(ids.as_mut_ptr().cast(), _mm256_castps_si256(bid));
                                while todo != 0 {
                                    let j = todo.trailing_zeros() as usize;
                                    todo &= todo - 1;
                                    let prim = bvh.prim_ids[ids[j] as usize];
                                    out[j] = Some(Hit { t: ts[j], u: us[j], v: vs[j], prim });
                                }
                            }
                            return Some(tie);
                        }
                        Some((c, t)) if t <= best_hi * ROBUST_EXIT => break c,
                        Some(_) => {}
                    }
                };
            }
        }
    }

    /// Any-hit answers of the packet `p` (bit `j` for ray `j`), or `None` when
    /// the packet cannot be bounded (see [`lanes`]).
    ///
    /// # Safety
    /// The CPU must support AVX.
    #[target_feature(enable = "avx")]
    pub(super) unsafe fn occluded(bvh: &Bvh, p: &Packet) -> Option<u8> {
        // SAFETY: this function is compiled for AVX and the caller checked the CPU.
        unsafe {
            let l = lanes(p)?;
            let blocks = &bvh.blocks[..];
            // Lanes still to answer (all bits set), and the largest interval end among them.
            let mut open = l.active;
            let mut far_hi = hmax(l.t_max);
            let mut stack = Stack::<u32>::new();
            let mut current = 0u32;
            loop {
                let node = NodeRef::of(bvh, current);
                let children = node.children();
                let (_, mask) = frustum(node, &l, far_hi);
                let leaf = leaf_mask(node);
                let (mut leaves, mut inner) = (mask & leaf, mask & !leaf);
                while leaves != 0 {
                    let k = leaves.trailing_zeros() as usize;
                    leaves &= leaves - 1;
                    // The exact single-ray test with each ray's own interval.
                    let rays = _mm256_and_ps(box_rays(node, k, &l, l.t_max), open);
                    if _mm256_movemask_ps(rays) == 0 {
                        continue;
                    }
                    let (first, count) = leaf_range(children[k]);
                    let block = &blocks[(first / 4) as usize];
                    let alone = _mm256_movemask_ps(rays) as u32;
                    let done = if alone.is_power_of_two() {
                        // One ray: the single-ray four-triangle test.
                        let j = alone.trailing_zeros() as usize;
                        let lanes = ((1u32 << count) - 1) << (first % 4);
                        let h = hits_sse(block, &RaySse::new(&p.rays[j]), p.t_min[j], p.t_max[j], lanes);
                        if h.mask != 0 { lane_mask(j) } else { _mm256_setzero_ps() }
                    } else {
                        let mut hit = _mm256_setzero_ps();
                        for lane in (first % 4)..(first % 4 + count) {
                            let (ok, t, _, _) = triangle(block, lane as usize, &l);
                            hit =
                                _mm256_or_ps(hit, _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_LT_OQ>(t, l.t_max)));
                        }
                        _mm256_and_ps(hit, rays)
                    };
                    if _mm256_movemask_ps(done) != 0 {
                        open = _mm256_andnot_ps(done, open);
                        if _mm256_movemask_ps(open) == 0 {
                            return Some(p.active);
                        }
                        far_hi = hmax(_mm256_blendv_ps(_mm256_set1_ps(f32::NEG_INFINITY), l.t_max, open));
                    }
                }
                let mut next = None;
                while inner != 0 {
                    let k = inner.trailing_zeros() as usize;
                    inner &= inner - 1;
                    if next.is_none() {
                        next = Some(children[k]);
                    } else {
                        stack.push(children[k]);
                    }
                }
                current = match next.or_else(|| stack.pop()) {
                    Some(c) => c,
                    None => return Some(p.active & !(_mm256_movemask_ps(open) as u8)),
                };
            }
        }
    }
}

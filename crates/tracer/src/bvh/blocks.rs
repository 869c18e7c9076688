//! Leaf triangles in blocks of four, structure-of-arrays, so that one SSE
//! instruction sequence runs Möller–Trumbore on all four at once.
//!
//! **Layout.** A [`TriBlock`] holds four precomputed triangles `(v0, e1, e2)`
//! as nine rows of four lanes (`v0.x` of all four, then `v0.y`, …): 144 bytes.
//! Triangle `t` of the BVH lives in block `t / 4`, lane `t % 4`. A leaf is a
//! run of 1..=4 lanes inside one block ([`pack`] fits the leaves into blocks
//! best-fit, so few lanes stay empty); empty lanes hold a zero triangle, whose
//! determinant is 0, so it can never be hit.
//!
//! **Same bits as the scalar test.** [`hits_sse`] performs, on every lane, the
//! operations of [`moller_trumbore`] in the same order (glam's `cross` and
//! `dot` written out: `a.y*b.z - b.y*a.z`, …, `(x*x' + y*y') + z*z'`; `1/det`
//! by a true division; no fused multiply-add), and the same comparisons, which
//! are false on NaN in both. [`hits_scalar`] calls [`moller_trumbore`] itself.
//! So both return the same hit lanes with bit-identical `t`, `u`, `v`; tests
//! compare them on random and degenerate triangles and rays.

use super::PreTriangle;
use crate::geometry::Ray;
use crate::shapes::{Triangle, moller_trumbore};
use glam::Vec3;

/// Four precomputed triangles, structure-of-arrays (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(16))]
pub(super) struct TriBlock {
    /// Rows `v0.x, v0.y, v0.z, e1.x, e1.y, e1.z, e2.x, e2.y, e2.z`, one lane per triangle.
    rows: [[f32; 4]; 9],
}

const _: () = assert!(std::mem::size_of::<TriBlock>() == 144);

impl TriBlock {
    /// Four zero triangles (never hit).
    pub(super) const EMPTY: TriBlock = TriBlock { rows: [[0.0; 4]; 9] };

    /// Stores `tri` in lane `lane`.
    pub(super) fn set(&mut self, lane: usize, tri: &PreTriangle) {
        for a in 0..3 {
            self.rows[a][lane] = tri.v0[a];
            self.rows[3 + a][lane] = tri.e1[a];
            self.rows[6 + a][lane] = tri.e2[a];
        }
    }

    /// The triangle in lane `lane`.
    #[inline(always)]
    pub(super) fn get(&self, lane: usize) -> PreTriangle {
        let r = &self.rows;
        PreTriangle {
            v0: Vec3::new(r[0][lane], r[1][lane], r[2][lane]),
            e1: Vec3::new(r[3][lane], r[4][lane], r[5][lane]),
            e2: Vec3::new(r[6][lane], r[7][lane], r[8][lane]),
        }
    }
}

/// Hits of one ray on the lanes of a block: bit `k` of `mask` is set where lane
/// `k` is hit with `t_min < t < t_max`; `t`, `u`, `v` are meaningful there.
#[derive(Clone, Copy, Debug)]
pub(super) struct Hits4 {
    /// Hit lanes.
    pub mask: u32,
    /// Ray parameter per lane.
    pub t: [f32; 4],
    /// Barycentric `u` per lane.
    pub u: [f32; 4],
    /// Barycentric `v` per lane.
    pub v: [f32; 4],
}

/// Scalar reference: [`moller_trumbore`] on the lanes in `lanes` (a bit mask).
#[inline(always)]
pub(super) fn hits_scalar(block: &TriBlock, ray: &Ray, t_min: f32, t_max: f32, lanes: u32) -> Hits4 {
    let mut h = Hits4 { mask: 0, t: [0.0; 4], u: [0.0; 4], v: [0.0; 4] };
    let mut todo = lanes & 0xf;
    while todo != 0 {
        let k = todo.trailing_zeros() as usize;
        todo &= todo - 1;
        let tri = block.get(k);
        if let Some((t, u, v)) = moller_trumbore(tri.v0, tri.e1, tri.e2, ray, t_min, t_max) {
            h.mask |= 1 << k;
            (h.t[k], h.u[k], h.v[k]) = (t, u, v);
        }
    }
    h
}

/// A ray broadcast to four lanes for [`hits_sse`].
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy, Debug)]
pub(super) struct RaySse {
    o: [std::arch::x86_64::__m128; 3],
    d: [std::arch::x86_64::__m128; 3],
}

#[cfg(target_arch = "x86_64")]
impl RaySse {
    /// Broadcasts `ray`.
    #[inline(always)]
    pub(super) fn new(ray: &Ray) -> Self {
        use std::arch::x86_64::_mm_set1_ps;
        // SAFETY: SSE is part of the x86_64 baseline; `_mm_set1_ps` only builds a register.
        unsafe {
            RaySse {
                o: [_mm_set1_ps(ray.origin.x), _mm_set1_ps(ray.origin.y), _mm_set1_ps(ray.origin.z)],
                d: [_mm_set1_ps(ray.dir.x), _mm_set1_ps(ray.dir.y), _mm_set1_ps(ray.dir.z)],
            }
        }
    }
}

/// [`hits_scalar`] on all four lanes at once with SSE (see the module docs for
/// why the bits are the same); lanes outside `lanes` are dropped from the mask.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(super) fn hits_sse(block: &TriBlock, r: &RaySse, t_min: f32, t_max: f32, lanes: u32) -> Hits4 {
    use std::arch::x86_64::*;
    // SAFETY: SSE and SSE2 are part of the x86_64 baseline, so these
    // instructions exist on every machine this code is compiled for; the loads
    // read the 16 bytes of a `[f32; 4]` row of `block` and the stores write the
    // 16 bytes of a local `[f32; 4]` (unaligned access is allowed).
    unsafe {
        let row = |i: usize| _mm_loadu_ps(block.rows[i].as_ptr());
        let (add, sub, mul) = (_mm_add_ps, _mm_sub_ps, _mm_mul_ps);
        let [ox, oy, oz] = r.o;
        let [dx, dy, dz] = r.d;
        let (v0x, v0y, v0z) = (row(0), row(1), row(2));
        let (e1x, e1y, e1z) = (row(3), row(4), row(5));
        let (e2x, e2y, e2z) = (row(6), row(7), row(8));
        // p = dir × e2
        let px = sub(mul(dy, e2z), mul(e2y, dz));
        let py = sub(mul(dz, e2x), mul(e2z, dx));
        let pz = sub(mul(dx, e2y), mul(e2x, dy));
        // det = e1 · p
        let det = add(add(mul(e1x, px), mul(e1y, py)), mul(e1z, pz));
        let inv = _mm_div_ps(_mm_set1_ps(1.0), det);
        // s = origin - v0; u = (s · p) * inv
        let (sx, sy, sz) = (sub(ox, v0x), sub(oy, v0y), sub(oz, v0z));
        let u = mul(add(add(mul(sx, px), mul(sy, py)), mul(sz, pz)), inv);
        // q = s × e1; v = (dir · q) * inv; t = (e2 · q) * inv
        let qx = sub(mul(sy, e1z), mul(e1y, sz));
        let qy = sub(mul(sz, e1x), mul(e1z, sx));
        let qz = sub(mul(sx, e1y), mul(e1x, sy));
        let v = mul(add(add(mul(dx, qx), mul(dy, qy)), mul(dz, qz)), inv);
        let t = mul(add(add(mul(e2x, qx), mul(e2y, qy)), mul(e2z, qz)), inv);
        let (zero, one) = (_mm_setzero_ps(), _mm_set1_ps(1.0));
        // Ordered comparisons (false on NaN) except det != 0, which is true on
        // NaN just like the scalar `det == 0.0` is false; a NaN det makes u NaN.
        let mut ok = _mm_cmpneq_ps(det, zero);
        ok = _mm_and_ps(ok, _mm_cmpge_ps(u, zero));
        ok = _mm_and_ps(ok, _mm_cmple_ps(u, one));
        ok = _mm_and_ps(ok, _mm_cmpge_ps(v, zero));
        ok = _mm_and_ps(ok, _mm_cmple_ps(add(u, v), one));
        ok = _mm_and_ps(ok, _mm_cmpgt_ps(t, _mm_set1_ps(t_min)));
        ok = _mm_and_ps(ok, _mm_cmplt_ps(t, _mm_set1_ps(t_max)));
        let mask = _mm_movemask_ps(ok) as u32 & lanes;
        let mut h = Hits4 { mask, t: [0.0; 4], u: [0.0; 4], v: [0.0; 4] };
        if mask != 0 {
            _mm_storeu_ps(h.t.as_mut_ptr(), t);
            _mm_storeu_ps(h.u.as_mut_ptr(), u);
            _mm_storeu_ps(h.v.as_mut_ptr(), v);
        }
        h
    }
}

/// Lays the leaves' triangles out in blocks: `leaves` lists each leaf's
/// `(first, count)` in leaf order (`ids[i]` is the index in `triangles` of the
/// `i`-th triangle in leaf order), in the order the leaves should be placed.
/// The precomputed form is made here, so no leaf-ordered copy of the triangles
/// is ever held. Returns the blocks, the input id of every lane (`u32::MAX` for an
/// empty lane) and each leaf's first lane (`4 · block + lane`).
///
/// Best fit: a leaf goes into the most recently opened block with the fewest
/// free lanes that still holds it, else into a new block; a pure function of
/// its input. The placement is one cheap sequential pass over the leaves;
/// the blocks themselves (gathering and precomputing the triangles, most of
/// the work) are then made in parallel, each from its four lane ids.
pub(super) fn pack(
    leaves: &[(u32, u32)],
    triangles: &[Triangle],
    ids: &[u32],
) -> (Vec<TriBlock>, Vec<u32>, Vec<u32>) {
    use rayon::prelude::*;
    let mut lane_ids: Vec<u32> = Vec::with_capacity((ids.len() / 3 + 1) * 4);
    let mut starts = Vec::with_capacity(leaves.len());
    // open[f]: blocks with exactly f free lanes (at the end), most recent last.
    let mut open: [Vec<u32>; 4] = Default::default();
    for &(first, count) in leaves {
        let count = count as usize;
        debug_assert!((1..=4).contains(&count));
        let found = (count..4).find_map(|f| open[f].pop().map(|b| (b, f)));
        let (block, free) = found.unwrap_or_else(|| {
            lane_ids.extend([u32::MAX; 4]);
            (lane_ids.len() as u32 / 4 - 1, 4)
        });
        let lane = 4 - free;
        let at = block as usize * 4 + lane;
        lane_ids[at..at + count].copy_from_slice(&ids[first as usize..first as usize + count]);
        if free > count {
            open[free - count].push(block);
        }
        starts.push(block * 4 + lane as u32);
    }
    let blocks = lane_ids
        .par_chunks(4)
        .map(|lanes| {
            let mut block = TriBlock::EMPTY;
            for (lane, &id) in lanes.iter().enumerate() {
                if id != u32::MAX {
                    block.set(lane, &PreTriangle::new(&triangles[id as usize]));
                }
            }
            block
        })
        .collect();
    (blocks, lane_ids, starts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Sampler;

    #[test]
    fn packing_keeps_leaves_in_one_block_and_fills_blocks() {
        let tri = |i: usize| Triangle { v: [Vec3::splat(i as f32), Vec3::X, Vec3::Y] };
        let sizes = [3u32, 1, 2, 2, 4, 1, 3, 1, 2];
        let mut leaves = Vec::new();
        let mut first = 0;
        for &c in &sizes {
            leaves.push((first, c));
            first += c;
        }
        // Triangle 100 + i of the input is the i-th in leaf order.
        let tris: Vec<_> = (0..100 + first as usize).map(tri).collect();
        let ids: Vec<u32> = (0..first).map(|i| 100 + i).collect();
        let (blocks, lane_ids, starts) = pack(&leaves, &tris, &ids);
        assert_eq!(blocks.len(), (first as usize).div_ceil(4), "19 triangles fit in 5 blocks");
        for (&(first, count), &start) in leaves.iter().zip(&starts) {
            assert!(start % 4 + count <= 4, "a leaf stays inside one block");
            for i in 0..count {
                let lane = (start + i) as usize;
                assert_eq!(lane_ids[lane], 100 + first + i);
                assert_eq!(
                    blocks[lane / 4].get(lane % 4),
                    PreTriangle::new(&tris[(100 + first + i) as usize])
                );
            }
        }
        assert_eq!(lane_ids.iter().filter(|&&i| i == u32::MAX).count(), 1);
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn sse_and_scalar_triangle_tests_agree_bit_for_bit() {
        let mut uniform = Sampler::new(5, 6, 7, 8).stream();
        let mut next = || uniform() * 4.0 - 2.0;
        let (mut hits, mut edge_cases) = (0, 0);
        for i in 0..40_000 {
            let mut block = TriBlock::EMPTY;
            let base = Vec3::new(next(), next(), next());
            for lane in 0..4 {
                let mut v =
                    [base, base + Vec3::new(next(), next(), next()), base + Vec3::new(next(), next(), 0.0)];
                match (i + lane) % 9 {
                    0 => v[2] = v[1],                       // degenerate
                    1 => v[1].x = f32::NAN,                 // NaN vertex
                    2 => v[2] = v[0] + (v[1] - v[0]) * 3.0, // collinear
                    _ => {}
                }
                if i % 11 == 0 && lane == 3 {
                    continue; // empty lane
                }
                block.set(lane, &PreTriangle::new(&Triangle { v }));
            }
            // Rays aimed at a lane's vertex or edge midpoint now and then, to hit edges exactly.
            let o = Vec3::new(next(), next(), next()) * 3.0;
            let tri = block.get(i % 4);
            let target = match i % 4 {
                0 => tri.v0,
                1 => tri.v0 + tri.e1 * 0.5,
                _ => base + Vec3::new(next(), next(), next()) * 0.5,
            };
            let mut dir = target - o;
            if i % 13 == 0 {
                dir[i % 3] = if i % 2 == 0 { 0.0 } else { -0.0 };
            }
            let ray = Ray::new(o, dir);
            let (t_min, t_max) = if i % 3 == 0 { (0.0, f32::INFINITY) } else { (0.1, next().abs() * 2.0) };
            let lanes = if i % 5 == 0 { 0b0110 } else { 0b1111 };
            let a = hits_sse(&block, &RaySse::new(&ray), t_min, t_max, lanes);
            let b = hits_scalar(&block, &ray, t_min, t_max, lanes);
            assert_eq!(a.mask, b.mask, "case {i}");
            for k in 0..4 {
                if a.mask & (1 << k) != 0 {
                    let bits = |h: &Hits4| (h.t[k].to_bits(), h.u[k].to_bits(), h.v[k].to_bits());
                    assert_eq!(bits(&a), bits(&b), "case {i} lane {k}");
                    hits += 1;
                    if a.u[k] == 0.0 || a.v[k] == 0.0 || a.u[k] + a.v[k] == 1.0 {
                        edge_cases += 1;
                    }
                }
            }
        }
        assert!(hits > 5_000, "{hits} hits");
        assert!(edge_cases > 100, "{edge_cases} hits exactly on an edge or vertex");
    }
}

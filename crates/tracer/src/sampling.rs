//! Deterministic random numbers: every sample is a hash of (pixel, sample
//! index, dimension, seed), never thread state.
//!
//! A [`Sampler`] is a 64-bit key derived from `(pixel x, pixel y, camera sample
//! index, seed)` with the splitmix64 finaliser; asking it for dimension `d`
//! hashes `(key, d)` once more. It is `Copy` and holds no mutable state, so the
//! value of any sample depends only on its coordinates — whatever tile, thread
//! or machine computes it.
//!
//! **Stratification.** Both camera samples and area-light samples use the same
//! scheme ([`stratified_square`]): `N` samples over the unit square are placed
//! in an `m × m` grid of strata with `m = ⌈√N⌉`; sample `i` takes stratum
//! `π(i)` of a hashed permutation `π` of the `m²` strata ([`permute`]: a
//! shuffled table for small sets, Kensler's cycle-walking permutation for
//! large ones; no allocation) and is jittered uniformly inside
//! it. When `N` is a square every stratum holds exactly one sample; otherwise
//! `N` distinct, randomly chosen strata are used.

use glam::Vec2;

/// The splitmix64 finaliser: a bijective, well-mixing 64-bit hash.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Maps a 32-bit hash to a float in `[0, 1)` using its top 24 bits.
#[inline]
pub fn to_unit(bits: u32) -> f32 {
    (bits >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// A stateless source of samples for one camera sample of one pixel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sampler {
    key: u64,
}

impl Sampler {
    /// The key of pixel `(x, y)` under `seed`, shared by all its camera samples.
    #[inline]
    pub fn pixel(x: u32, y: u32, seed: u64) -> Sampler {
        let k = mix64(seed ^ 0x9e37_79b9_7f4a_7c15);
        Sampler { key: mix64(k ^ (((x as u64) << 32) | y as u64)) }
    }

    /// The sampler of camera sample `sample` of pixel `(x, y)`.
    #[inline]
    pub fn new(x: u32, y: u32, sample: u32, seed: u64) -> Sampler {
        Sampler::pixel(x, y, seed).child(sample)
    }

    /// An independent sub-stream, e.g. one per (depth, light) for shadow rays.
    #[inline]
    pub fn child(&self, tag: u32) -> Sampler {
        Sampler { key: mix64(self.key ^ mix64(tag as u64 ^ 0x632b_e59b_d9b4_e019)) }
    }

    /// 32 random bits for dimension `dim`.
    #[inline]
    pub fn bits(&self, dim: u32) -> u32 {
        (mix64(self.key ^ (dim as u64).wrapping_mul(0xd6e8_feb8_6659_fd93)) >> 32) as u32
    }

    /// A uniform float in `[0, 1)` for dimension `dim`.
    #[inline]
    pub fn get(&self, dim: u32) -> f32 {
        to_unit(self.bits(dim))
    }

    /// Dimensions 1, 2, 3, … one per call: a fixed stream of uniform floats
    /// in `[0, 1)` for tests that need many random inputs.
    #[cfg(test)]
    pub(crate) fn stream(self) -> impl FnMut() -> f32 {
        let mut dim = 0;
        move || {
            dim += 1;
            self.get(dim)
        }
    }

    /// Two uniform floats in `[0, 1)` for dimension `dim`, from the two halves
    /// of one 64-bit hash (half the work of two [`Sampler::get`] calls).
    #[inline]
    pub fn pair(&self, dim: u32) -> (f32, f32) {
        let h = mix64(self.key ^ (dim as u64).wrapping_mul(0xd6e8_feb8_6659_fd93));
        (to_unit((h >> 32) as u32), to_unit(h as u32))
    }
}

/// A hashed permutation: maps `i` in `0..len` to a distinct value in `0..len`,
/// chosen by `key`, without memory. Sets of up to [`SHUFFLED_MAX`] elements (a
/// pixel's light samples, typically) are shuffled once by Fisher–Yates driven
/// by a hash of `key`, the table packed into one `u64`; larger ones use
/// Kensler's cycle-walking permutation ("Correlated Multi-Jittered Sampling",
/// 2013), which walks only when `len` is not a power of two.
#[inline]
pub fn permute(i: u32, len: u32, key: u32) -> u32 {
    Permutation::new(len, key).apply(i)
}

/// Sets up to this size are permuted through a shuffled table (see [`permute`]).
pub const SHUFFLED_MAX: u32 = 16;

/// [`permute`] for one `(len, key)`, with the per-set work (the shuffled table,
/// or the walk mask and the final offset `key mod len`) done once: the same
/// values, cheaper when a set of samples shares its permutation.
#[derive(Clone, Copy, Debug)]
pub struct Permutation {
    len: u32,
    key: u32,
    /// `len − 1` with every bit below its highest set.
    mask: u32,
    /// `key mod len` (Kensler's permutation only).
    offset: u32,
    /// The image of `i` in bits `4i..4i + 4` (shuffled sets only).
    table: u64,
}

impl Permutation {
    /// The permutation of `0..len` chosen by `key`.
    #[inline]
    pub fn new(len: u32, key: u32) -> Self {
        if len <= SHUFFLED_MAX {
            return Permutation { len, key, mask: 0, offset: 0, table: shuffled(len, key) };
        }
        let mut w = len - 1;
        w |= w >> 1;
        w |= w >> 2;
        w |= w >> 4;
        w |= w >> 8;
        w |= w >> 16;
        Permutation { len, key, mask: w, offset: key % len, table: 0 }
    }

    /// The image of `i` (`i < len`).
    #[inline]
    pub fn apply(&self, mut i: u32) -> u32 {
        let (len, p, w) = (self.len, self.key, self.mask);
        if len <= SHUFFLED_MAX {
            return ((self.table >> (4 * (i & 15))) & 15) as u32;
        }
        loop {
            i ^= p;
            i = i.wrapping_mul(0xe170_893d);
            i ^= p >> 16;
            i ^= (i & w) >> 4;
            i ^= p >> 8;
            i = i.wrapping_mul(0x0929_eb3f);
            i ^= p >> 23;
            i ^= (i & w) >> 1;
            i = i.wrapping_mul(1 | (p >> 27));
            i = i.wrapping_mul(0x6935_fa69);
            i ^= (i & w) >> 11;
            i = i.wrapping_mul(0x74dc_b303);
            i ^= (i & w) >> 2;
            i = i.wrapping_mul(0x9e50_1cc3);
            i ^= (i & w) >> 2;
            i = i.wrapping_mul(0xc860_a3df);
            i &= w;
            i ^= i >> 5;
            if i < len {
                break;
            }
        }
        // (i + key) mod len with i < len: one conditional subtraction.
        let r = i + self.offset;
        if r >= len { r - len } else { r }
    }
}

/// A Fisher–Yates shuffle of `0..len` (`len ≤ 16`) driven by a 64-bit linear
/// congruential generator seeded with a hash of `key`, as 4-bit entries of a
/// `u64` (entry `i` in bits `4i..4i + 4`).
#[inline]
fn shuffled(len: u32, key: u32) -> u64 {
    let mut table = 0xfedc_ba98_7654_3210u64;
    let mut r = mix64(key as u64 ^ 0x5851_f42d_4c95_7f2d);
    let mut i = len;
    while i > 1 {
        i -= 1;
        r = r.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        // j uniform in 0..=i from the generator's high 32 bits.
        let j = (((r >> 32) * (i as u64 + 1)) >> 32) as u32;
        let (a, b) = (4 * i, 4 * j);
        let x = ((table >> a) ^ (table >> b)) & 15;
        table ^= (x << a) | (x << b);
    }
    table
}

/// Exact division and remainder of any `u32` by a divisor fixed in advance,
/// by multiplication (Lemire, Kaser & Kurz 2019): for loops that would
/// otherwise divide by the same run-time value again and again.
#[derive(Clone, Copy, Debug)]
pub struct Divisor {
    d: u32,
    /// `⌈2⁶⁴ / d⌉` (0 for `d = 1`, which is handled apart).
    m: u64,
}

impl Divisor {
    /// Division by `d` (at least 1; 0 is treated as 1).
    #[inline]
    pub fn new(d: u32) -> Self {
        let d = d.max(1);
        let m = if d == 1 { 0 } else { u64::MAX / d as u64 + 1 };
        Divisor { d, m }
    }

    /// `n / d`.
    #[inline]
    pub fn div(&self, n: u32) -> u32 {
        if self.d == 1 { n } else { ((self.m as u128 * n as u128) >> 64) as u32 }
    }

    /// `n % d`.
    #[inline]
    pub fn rem(&self, n: u32) -> u32 {
        n - self.div(n) * self.d
    }
}

/// `⌈√n⌉`, exactly.
#[inline]
pub fn ceil_sqrt(n: u32) -> u32 {
    let mut m = (n as f64).sqrt() as u32;
    while (m as u64) * (m as u64) < n as u64 {
        m += 1;
    }
    while m > 0 && ((m - 1) as u64) * ((m - 1) as u64) >= n as u64 {
        m -= 1;
    }
    m
}

/// Sample `i` of `n` stratified, jittered samples over the unit square (see the
/// module docs), drawn from `sampler`. All samples of one set must share the
/// sampler. Dimension 0 of the sampler keys the permutation; dimensions
/// `1 + 2i` and `2 + 2i` jitter sample `i`. [`Strata`] prepares a set once for
/// many samples.
#[inline]
pub fn stratified_square(i: u32, n: u32, sampler: &Sampler) -> Vec2 {
    Strata::new(ceil_sqrt(n.max(1)), sampler.bits(0)).point(i, sampler)
}

/// One set of stratified samples over an `m × m` grid ([`stratified_square`]),
/// its permutation and divisions prepared once for all its samples.
#[derive(Clone, Copy, Debug)]
pub struct Strata {
    perm: Permutation,
    side: Divisor,
    inv: f32,
}

impl Strata {
    /// The set on an `m × m` grid (`m ≥ 1`) whose strata are permuted by `key`
    /// (`sampler.bits(0)` for [`stratified_square`]'s sets).
    #[inline]
    pub fn new(m: u32, key: u32) -> Self {
        let m = m.max(1);
        Strata { perm: Permutation::new(m * m, key), side: Divisor::new(m), inv: 1.0 / m as f32 }
    }

    /// The same grid with its strata permuted by `key` instead (cheaper than
    /// [`Strata::new`]: the grid's divisions are kept).
    #[inline]
    pub fn with_key(&self, key: u32) -> Self {
        Strata { perm: Permutation::new(self.perm.len, key), ..*self }
    }

    /// The stratum `(column, row)` of sample `i` of the set.
    #[inline]
    pub fn stratum(&self, i: u32) -> (u32, u32) {
        let s = self.perm.apply(i);
        let sy = self.side.div(s);
        (s - sy * self.side.d, sy)
    }

    /// Sample `i` of the set, jittered by `sampler` (dimension `1 + i`, [`Sampler::pair`]).
    #[inline]
    pub fn point(&self, i: u32, sampler: &Sampler) -> Vec2 {
        let (sx, sy) = self.stratum(i);
        let (jx, jy) = sampler.pair(1 + i);
        // Clamp below 1: (m-1 + 0.99999994)/m can round up to exactly 1.
        Vec2::new(
            ((sx as f32 + jx) * self.inv).min(ONE_MINUS_EPS),
            ((sy as f32 + jy) * self.inv).min(ONE_MINUS_EPS),
        )
    }
}

/// The largest f32 below one.
pub const ONE_MINUS_EPS: f32 = 1.0 - f32::EPSILON / 2.0;

/// Maps the unit square to barycentric coordinates `(b1, b2)` of a triangle,
/// uniformly and with low distortion (Heitz 2019, "A Low-Distortion Map Between
/// Triangle and Square"), so strata of the square stay compact on the triangle.
/// The point is `(1 − b1 − b2)·v0 + b1·v1 + b2·v2`.
#[inline]
pub fn square_to_triangle(u: Vec2) -> (f32, f32) {
    if u.y > u.x {
        let b1 = u.x * 0.5;
        (b1, u.y - b1)
    } else {
        let b2 = u.y * 0.5;
        (u.x - b2, b2)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn permute_is_a_permutation() {
        for len in [1u32, 2, 3, 7, 9, 16, 25, 100, 1000] {
            for key in [0u32, 1, 0xdead_beef, 12345] {
                let mut seen = vec![false; len as usize];
                for i in 0..len {
                    let j = permute(i, len, key) as usize;
                    assert!(j < len as usize);
                    assert!(!seen[j], "len {len} key {key}: {j} twice");
                    seen[j] = true;
                }
            }
        }
    }

    #[test]
    fn permutation_and_divisor_match_the_plain_arithmetic() {
        fn reference(mut i: u32, len: u32, p: u32) -> u32 {
            // Kensler's listing, with the final `(i + p) % len` in 64 bits.
            let mut w = len - 1;
            for s in [1, 2, 4, 8, 16] {
                w |= w >> s;
            }
            loop {
                i ^= p;
                i = i.wrapping_mul(0xe170_893d);
                i ^= p >> 16;
                i ^= (i & w) >> 4;
                i ^= p >> 8;
                i = i.wrapping_mul(0x0929_eb3f);
                i ^= p >> 23;
                i ^= (i & w) >> 1;
                i = i.wrapping_mul(1 | (p >> 27));
                i = i.wrapping_mul(0x6935_fa69);
                i ^= (i & w) >> 11;
                i = i.wrapping_mul(0x74dc_b303);
                i ^= (i & w) >> 2;
                i = i.wrapping_mul(0x9e50_1cc3);
                i ^= (i & w) >> 2;
                i = i.wrapping_mul(0xc860_a3df);
                i &= w;
                i ^= i >> 5;
                if i < len {
                    return ((i as u64 + p as u64) % len as u64) as u32;
                }
            }
        }
        for len in [17u32, 25, 100, 4096, 1 << 24] {
            for key in [0u32, 1, 0xdead_beef, u32::MAX, 12345] {
                let perm = Permutation::new(len, key);
                for i in (0..len).step_by((len as usize / 300).max(1)) {
                    assert_eq!(perm.apply(i), reference(i, len, key), "len {len} key {key} i {i}");
                }
            }
        }
        let mut n = 0x9e37_79b9u32;
        for d in [1u32, 2, 3, 7, 10, 64, 4095, 65_537, u32::MAX] {
            let div = Divisor::new(d);
            for k in 0..2000u32 {
                n = n.wrapping_mul(0x2c1b_3c6d).wrapping_add(0x297a_2d39);
                for x in [n, k, u32::MAX - k] {
                    assert_eq!((div.div(x), div.rem(x)), (x / d, x % d), "{x} / {d}");
                }
            }
        }
    }

    #[test]
    fn ceil_sqrt_is_exact() {
        for n in 0..2000u32 {
            let m = ceil_sqrt(n);
            assert!(m * m >= n && (m == 0 || (m - 1) * (m - 1) < n), "n {n} m {m}");
        }
    }

    #[test]
    fn samples_are_uniform_in_unit_interval_and_depend_on_every_input() {
        let s = Sampler::new(3, 4, 5, 6);
        let mut sum = 0.0f64;
        for d in 0..10_000 {
            let x = s.get(d);
            assert!((0.0..1.0).contains(&x));
            sum += x as f64;
        }
        assert!((sum / 10_000.0 - 0.5).abs() < 0.02, "mean {}", sum / 10_000.0);
        let base = s.get(0);
        for other in [
            Sampler::new(4, 4, 5, 6),
            Sampler::new(3, 5, 5, 6),
            Sampler::new(3, 4, 6, 6),
            Sampler::new(3, 4, 5, 7),
        ] {
            assert_ne!(other.get(0), base);
        }
        assert_eq!(Sampler::new(3, 4, 5, 6).get(0), base, "same inputs, same sample");
    }

    #[test]
    fn square_counts_fill_every_stratum_once() {
        for n in [4u32, 9, 16, 64] {
            let m = ceil_sqrt(n);
            let s = Sampler::new(10, 20, 0, 99);
            let mut count = vec![0; (m * m) as usize];
            for i in 0..n {
                let p = stratified_square(i, n, &s);
                assert!(p.x >= 0.0 && p.x < 1.0 && p.y >= 0.0 && p.y < 1.0);
                let (cx, cy) = ((p.x * m as f32) as u32, (p.y * m as f32) as u32);
                count[(cy * m + cx) as usize] += 1;
            }
            assert!(count.iter().all(|&c| c == 1), "n {n}: {count:?}");
        }
        // Non-square counts use distinct strata.
        let n = 5;
        let s = Sampler::new(1, 2, 3, 4);
        let mut cells: Vec<_> = (0..n)
            .map(|i| stratified_square(i, n, &s))
            .map(|p| ((p.x * 3.0) as u32, (p.y * 3.0) as u32))
            .collect();
        cells.sort();
        cells.dedup();
        assert_eq!(cells.len(), n as usize);
    }

    #[test]
    fn square_to_triangle_stays_inside_and_is_uniform() {
        let s = Sampler::new(0, 0, 0, 1);
        let n = 4096;
        let mut mean = (0.0f64, 0.0f64);
        for i in 0..n {
            let (b1, b2) = square_to_triangle(stratified_square(i, n, &s));
            assert!(b1 >= 0.0 && b2 >= 0.0 && b1 + b2 <= 1.0);
            mean.0 += b1 as f64;
            mean.1 += b2 as f64;
        }
        // The centroid of a uniform distribution on the triangle is (1/3, 1/3).
        assert!((mean.0 / n as f64 - 1.0 / 3.0).abs() < 0.01);
        assert!((mean.1 / n as f64 - 1.0 / 3.0).abs() < 0.01);
    }
}

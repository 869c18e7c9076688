//! Textures: procedural checker and mip-mapped image textures with bilinear
//! filtering, so distant textured floors do not alias.
//!
//! Conventions: UV `(0, 0)` is the top-left corner of an image (row 0), `u`
//! grows to the right and `v` downwards; both wrap (repeat). A lookup carries a
//! filter footprint `width` in UV units (from the integrator's ray cones):
//!
//! * images pick the mip level `lod = log2(width × max(W, H))` and blend the two
//!   nearest levels (trilinear), each sampled bilinearly;
//! * the checker is box-filtered analytically over a `width × width` square:
//!   the integral of the ±1 square wave is a triangle wave, and the checker is
//!   the product of two square waves, so its box-filtered value is exact. A
//!   checker floor receding to the horizon converges to the mean of its two
//!   colours instead of aliasing.

use crate::math;
use glam::{Vec2, Vec3, Vec3A};

/// A texture, evaluated at a UV coordinate with a filter footprint.
#[derive(Clone, Debug, PartialEq)]
pub enum Texture {
    /// Alternating squares of `even` and `odd`; `scale` squares per UV unit.
    Checker {
        /// Colour of squares where `floor(u*s) + floor(v*s)` is even (linear RGB).
        even: Vec3,
        /// Colour of the other squares (linear RGB).
        odd: Vec3,
        /// Squares per UV unit.
        scale: f32,
    },
    /// An image with its mip-map pyramid.
    Image(MipMap),
}

/// An image and its successively halved, box-filtered levels, in linear RGB.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct MipMap {
    levels: Vec<Level>,
}

#[derive(Clone, Debug, PartialEq, Default)]
struct Level {
    width: u32,
    height: u32,
    /// Stored as [`Vec3A`] (16 bytes, SIMD-aligned): a lookup loads each texel
    /// with one instruction and blends all three channels at once, with the
    /// same operations per channel as on a `Vec3`, so the same bits.
    texels: Vec<Vec3A>,
}

/// Largest accepted image side, to bound allocations from untrusted input.
pub const MAX_TEXTURE_SIZE: u32 = 16_384;

/// The sRGB electro-optical transfer function (decode to linear), exact.
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 { c / 12.92 } else { math::powf((c + 0.055) / 1.055, 2.4) }
}

/// Decoding table for 8-bit sRGB values.
fn srgb8_table() -> [f32; 256] {
    let mut t = [0.0; 256];
    for (i, v) in t.iter_mut().enumerate() {
        *v = srgb_to_linear(i as f32 / 255.0);
    }
    t
}

impl MipMap {
    /// Builds the pyramid from an sRGB-encoded RGBA8 image (alpha ignored),
    /// `rgba.len() == width * height * 4`. Invalid input (a zero or oversized
    /// dimension, too few bytes) gives a 1 × 1 magenta image rather than a
    /// panic; use [`MipMap::try_from_srgb8`] to detect it.
    pub fn from_srgb8(width: u32, height: u32, rgba: &[u8]) -> Self {
        Self::try_from_srgb8(width, height, rgba)
            .unwrap_or_else(|| MipMap::from_linear(1, 1, vec![Vec3::X + Vec3::Z]))
    }

    /// Like [`MipMap::from_srgb8`], but `None` for invalid input.
    pub fn try_from_srgb8(width: u32, height: u32, rgba: &[u8]) -> Option<Self> {
        if width == 0 || height == 0 || width > MAX_TEXTURE_SIZE || height > MAX_TEXTURE_SIZE {
            return None;
        }
        let n = width as usize * height as usize;
        if rgba.len() < n * 4 {
            return None;
        }
        let table = srgb8_table();
        let texels = rgba[..n * 4]
            .chunks_exact(4)
            .map(|p| Vec3A::new(table[p[0] as usize], table[p[1] as usize], table[p[2] as usize]))
            .collect();
        Some(Self::from_texels(width, height, texels))
    }

    /// Builds the pyramid from linear RGB texels, row-major, row 0 on top.
    /// Each level halves each side (rounding down, never below 1); odd sides
    /// are reduced with an exact area-weighted box filter (each new texel
    /// averages the source area it covers), so every level keeps the mean.
    ///
    /// # Panics
    /// If `texels.len() != width * height` or a side is zero.
    pub fn from_linear(width: u32, height: u32, texels: Vec<Vec3>) -> Self {
        Self::from_texels(width, height, texels.into_iter().map(Vec3A::from).collect())
    }

    /// [`MipMap::from_linear`] on texels already in their stored form.
    fn from_texels(width: u32, height: u32, texels: Vec<Vec3A>) -> Self {
        assert!(width > 0 && height > 0 && texels.len() == width as usize * height as usize);
        let mut levels = vec![Level { width, height, texels }];
        loop {
            let last = levels.last().expect("at least one level");
            if last.width == 1 && last.height == 1 {
                break;
            }
            let next = last.downsample();
            levels.push(next);
        }
        MipMap { levels }
    }

    /// Number of levels (1 for a 1 × 1 image).
    pub fn level_count(&self) -> usize {
        self.levels.len()
    }

    /// Bytes the texels of every level take.
    pub fn memory_bytes(&self) -> usize {
        self.levels.iter().map(|l| l.texels.len() * std::mem::size_of::<Vec3A>()).sum()
    }

    /// Size of level `level`.
    pub fn level_size(&self, level: usize) -> (u32, u32) {
        self.levels.get(level).map_or((0, 0), |l| (l.width, l.height))
    }

    /// Texel `(x, y)` of level `level` (linear RGB).
    pub fn texel(&self, level: usize, x: u32, y: u32) -> Vec3 {
        let l = &self.levels[level];
        l.texels[(y * l.width + x) as usize].into()
    }

    /// Trilinear lookup with a footprint `width` UV units wide.
    pub fn eval(&self, uv: Vec2, width: f32) -> Vec3 {
        self.eval_with(uv, width, Level::bilinear)
    }

    /// [`MipMap::eval`] where the axes marked in `clamp` do not wrap: a
    /// lookup past an edge reads the edge's texels (for glTF's clamp and
    /// mirrored-repeat samplers, whose coordinates arrive in `0..=1`).
    pub fn eval_clamped(&self, uv: Vec2, width: f32, clamp: [bool; 2]) -> Vec3 {
        self.eval_with(uv, width, |level, uv| level.bilinear_clamped(uv, clamp))
    }

    #[inline]
    fn eval_with(&self, uv: Vec2, width: f32, bilinear: impl Fn(&Level, Vec2) -> Vec3A) -> Vec3 {
        let Some(base) = self.levels.first() else { return Vec3::ZERO };
        let size = base.width.max(base.height) as f32;
        let texels_wide = width * size;
        if texels_wide.is_nan() || texels_wide <= 1.0 {
            return bilinear(base, uv).into();
        }
        let lod = math::log2(texels_wide).min((self.levels.len() - 1) as f32);
        let l0 = lod as usize; // lod > 0 here
        let f = lod - l0 as f32;
        let a = bilinear(&self.levels[l0], uv);
        if f <= 0.0 || l0 + 1 >= self.levels.len() {
            return a.into();
        }
        let b = bilinear(&self.levels[l0 + 1], uv);
        (a * (1.0 - f) + b * f).into()
    }
}

/// `x.floor()`, bit for bit (signed zeros, NaN and infinities included),
/// inlined: without SSE4.1 in the target baseline `f32::floor` is a call into
/// the runtime's `floorf`, which showed in the frame profile.
#[inline(always)]
pub fn floor_f32(x: f32) -> f32 {
    // From 2^23 up every float is an integer (NaN fails the test too).
    if x.abs() < 8_388_608.0 {
        let t = (x as i32) as f32; // truncation, exact in this range
        let f = if t > x { t - 1.0 } else { t };
        // Integral inputs (and −0) come back unchanged, as floor returns them.
        if f == x { x } else { f }
    } else {
        x
    }
}

/// `x.floor()` for `f64`, bit for bit, inlined (see [`floor_f32`]).
#[inline(always)]
pub fn floor_f64(x: f64) -> f64 {
    if x.abs() < 4_503_599_627_370_496.0 {
        let t = (x as i64) as f64;
        let f = if t > x { t - 1.0 } else { t };
        if f == x { x } else { f }
    } else {
        x
    }
}

/// Wraps a coordinate into `[0, 1)`; non-finite values become 0.
#[inline]
fn wrap(x: f32) -> f32 {
    if !x.is_finite() {
        return 0.0;
    }
    let f = x - floor_f32(x);
    if f >= 1.0 { 0.0 } else { f }
}

impl Level {
    #[inline]
    fn at(&self, x: u32, y: u32) -> Vec3A {
        self.texels[(y * self.width + x) as usize]
    }

    /// Bilinear lookup with repeat wrapping; texel centres are at
    /// `((i + ½)/W, (j + ½)/H)`.
    fn bilinear(&self, uv: Vec2) -> Vec3A {
        let (w, h) = (self.width, self.height);
        let x = wrap(uv.x) * w as f32 - 0.5;
        let y = wrap(uv.y) * h as f32 - 0.5;
        let (xf, yf) = (floor_f32(x), floor_f32(y));
        let (fx, fy) = (x - xf, y - yf);
        // xf is in -1..=w-1.
        let x0 = if xf < 0.0 { w - 1 } else { (xf as u32).min(w - 1) };
        let y0 = if yf < 0.0 { h - 1 } else { (yf as u32).min(h - 1) };
        let x1 = if x0 + 1 >= w { 0 } else { x0 + 1 };
        let y1 = if y0 + 1 >= h { 0 } else { y0 + 1 };
        let top = self.at(x0, y0) * (1.0 - fx) + self.at(x1, y0) * fx;
        let bottom = self.at(x0, y1) * (1.0 - fx) + self.at(x1, y1) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// [`Level::bilinear`] with the axes marked in `clamp` clamped to the
    /// texel centres at the edges instead of wrapping.
    fn bilinear_clamped(&self, uv: Vec2, clamp: [bool; 2]) -> Vec3A {
        let (w, h) = (self.width, self.height);
        let axis = |c: f32, n: u32, clamped: bool| -> (u32, u32, f32) {
            if !clamped {
                let x = wrap(c) * n as f32 - 0.5;
                let xf = floor_f32(x);
                let x0 = if xf < 0.0 { n - 1 } else { (xf as u32).min(n - 1) };
                return (x0, if x0 + 1 >= n { 0 } else { x0 + 1 }, x - xf);
            }
            let c = if c.is_finite() { c.clamp(0.0, 1.0) } else { 0.0 };
            let x = (c * n as f32 - 0.5).clamp(0.0, (n - 1) as f32);
            let x0 = (floor_f32(x) as u32).min(n - 1);
            ((x0), (x0 + 1).min(n - 1), x - x0 as f32)
        };
        let (x0, x1, fx) = axis(uv.x, w, clamp[0]);
        let (y0, y1, fy) = axis(uv.y, h, clamp[1]);
        let top = self.at(x0, y0) * (1.0 - fx) + self.at(x1, y0) * fx;
        let bottom = self.at(x0, y1) * (1.0 - fx) + self.at(x1, y1) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// The next level: each side halved (rounded down, at least 1).
    fn downsample(&self) -> Level {
        let (w, h) = (self.width, self.height);
        let (nw, nh) = ((w / 2).max(1), (h / 2).max(1));
        let wx = box_weights(w, nw);
        let wy = box_weights(h, nh);
        // Horizontal pass: h rows × nw.
        let mut tmp = vec![Vec3A::ZERO; (nw * h) as usize];
        for y in 0..h {
            for (nx, taps) in wx.iter().enumerate() {
                let mut acc = Vec3A::ZERO;
                for &(x, wgt) in taps {
                    acc += self.at(x, y) * wgt;
                }
                tmp[(y * nw) as usize + nx] = acc;
            }
        }
        let mut texels = vec![Vec3A::ZERO; (nw * nh) as usize];
        for (ny, taps) in wy.iter().enumerate() {
            for nx in 0..nw as usize {
                let mut acc = Vec3A::ZERO;
                for &(y, wgt) in taps {
                    acc += tmp[(y * nw) as usize + nx] * wgt;
                }
                texels[ny * nw as usize + nx] = acc;
            }
        }
        Level { width: nw, height: nh, texels }
    }
}

/// For each of `dst` output texels, the source texels it covers and their
/// weights: output `i` covers `[i·src/dst, (i+1)·src/dst)` of the source.
fn box_weights(src: u32, dst: u32) -> Vec<Vec<(u32, f32)>> {
    let ratio = src as f64 / dst as f64;
    (0..dst)
        .map(|i| {
            let (a, b) = (i as f64 * ratio, (i + 1) as f64 * ratio);
            let mut taps = Vec::new();
            let mut x = a.floor() as u32;
            while (x as f64) < b && x < src {
                let overlap = (b.min(x as f64 + 1.0) - a.max(x as f64)).max(0.0);
                if overlap > 0.0 {
                    taps.push((x, (overlap / ratio) as f32));
                }
                x += 1;
            }
            taps
        })
        .collect()
}

/// Box-filtered mean of the ±1 square wave (`+1` where `floor(x)` is even) over
/// `[x − w/2, x + w/2]`: the difference of its integral, a triangle wave.
#[inline]
fn filtered_square_wave(x: f64, w: f64) -> f64 {
    // g(x) = −2 |fract(x/2) − ½| has slope +1 on even cells and −1 on odd ones.
    let g = |x: f64| -2.0 * ((x * 0.5 - floor_f64(x * 0.5)) - 0.5).abs();
    (g(x + 0.5 * w) - g(x - 0.5 * w)) / w
}

/// Mean of the ±1 square wave over a box of width `w` centred on `x`, falling
/// back to a point sample for tiny widths (where the difference quotient loses
/// precision) and to 0 for infinite ones.
#[inline]
fn square_wave_axis(x: f64, w: f64) -> f64 {
    if !w.is_finite() {
        0.0
    } else if w > 1e-6 {
        filtered_square_wave(x, w)
    } else if floor_f64(x).rem_euclid(2.0) == 0.0 {
        1.0
    } else {
        -1.0
    }
}

/// The checker's colour at `uv` box-filtered over a `footprint.x × footprint.y`
/// rectangle (UV units). Exact: the checker is the product of a square wave in
/// `u` and one in `v`, and a box filter is separable.
fn checker(even: Vec3, odd: Vec3, scale: f32, uv: Vec2, footprint: Vec2) -> Vec3 {
    let (u, v) = (uv.x as f64 * scale as f64, uv.y as f64 * scale as f64);
    if !u.is_finite() || !v.is_finite() {
        return (even + odd) * 0.5;
    }
    let (wu, wv) = ((footprint.x as f64 * scale as f64).abs(), (footprint.y as f64 * scale as f64).abs());
    let p = square_wave_axis(u, wu) * square_wave_axis(v, wv);
    // p is the mean of (+1 even, −1 odd): the fraction of `even` is (1 + p)/2.
    let fe = (0.5 + 0.5 * p).clamp(0.0, 1.0) as f32;
    even * fe + odd * (1.0 - fe)
}

impl Texture {
    /// The texture's colour at `uv`, filtered over a square footprint `width`
    /// UV units wide (0 for a point sample).
    pub fn eval(&self, uv: Vec2, width: f32) -> Vec3 {
        self.eval_rect(uv, Vec2::splat(width))
    }

    /// The texture's colour at `uv`, filtered over an axis-aligned footprint
    /// `footprint.x` wide in `u` and `footprint.y` in `v` (the bounding box of
    /// an elliptical pixel footprint). The checker filters each axis exactly;
    /// images are isotropic and use the larger side.
    pub fn eval_rect(&self, uv: Vec2, footprint: Vec2) -> Vec3 {
        let clean = |w: f32| if w.is_nan() { 0.0 } else { w.max(0.0) };
        let footprint = Vec2::new(clean(footprint.x), clean(footprint.y));
        match self {
            Texture::Checker { even, odd, scale } => checker(*even, *odd, *scale, uv, footprint),
            Texture::Image(m) => m.eval(uv, footprint.x.max(footprint.y)),
        }
    }

    /// [`Texture::eval_rect`] where the axes marked in `clamp` do not wrap
    /// ([`MipMap::eval_clamped`]); the checker is procedural and unbounded.
    pub fn eval_rect_clamped(&self, uv: Vec2, footprint: Vec2, clamp: [bool; 2]) -> Vec3 {
        match self {
            Texture::Image(m) if clamp != [false; 2] => {
                let w = footprint.x.max(footprint.y);
                m.eval_clamped(uv, if w.is_nan() { 0.0 } else { w.max(0.0) }, clamp)
            }
            _ => self.eval_rect(uv, footprint),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inline_floors_equal_the_std_ones_bit_for_bit() {
        let mut xs: Vec<f32> = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            1.5,
            -1.5,
            0.999_999_94,
            -0.999_999_94,
            1e-45,
            -1e-45,
            8_388_607.5,
            -8_388_607.5,
            8_388_608.0,
            -8_388_608.0,
            16_777_217.0,
            3e9,
            -3e9,
            f32::MAX,
            f32::MIN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
        ];
        // A deterministic spread of bit patterns over the whole range.
        let mut z = 0x9e37_79b9_7f4a_7c15u64;
        for _ in 0..200_000 {
            z = crate::sampling::mix64(z);
            xs.push(f32::from_bits(z as u32));
            xs.push((z >> 40) as f32 / 1024.0 - 8192.0);
        }
        for x in xs {
            if x.is_nan() {
                assert!(floor_f32(x).is_nan() && floor_f64(x as f64).is_nan());
                continue;
            }
            assert_eq!(floor_f32(x).to_bits(), x.floor().to_bits(), "floor({x:e})");
            let d = x as f64 * 1.000_000_1;
            assert_eq!(floor_f64(d).to_bits(), d.floor().to_bits(), "floor({d:e})");
        }
        for d in [4_503_599_627_370_495.5f64, -4_503_599_627_370_495.5, 9.1e18, -9.3e18, -0.0, 0.25] {
            assert_eq!(floor_f64(d).to_bits(), d.floor().to_bits(), "floor({d:e})");
        }
    }

    fn close(a: Vec3, b: Vec3, tol: f32) -> bool {
        (a - b).abs().max_element() <= tol
    }

    #[test]
    fn srgb_table_endpoints_and_midpoint() {
        let t = srgb8_table();
        assert_eq!(t[0], 0.0);
        assert!((t[255] - 1.0).abs() < 1e-6);
        // sRGB 188 is about linear 0.5 (a well-known value).
        assert!((t[188] - 0.5).abs() < 0.005, "{}", t[188]);
        assert!(t.windows(2).all(|w| w[0] < w[1]));
    }

    #[test]
    fn checker_point_samples_follow_the_convention() {
        let c = Texture::Checker { even: Vec3::ONE, odd: Vec3::ZERO, scale: 4.0 };
        assert_eq!(c.eval(Vec2::new(0.1, 0.1), 0.0), Vec3::ONE);
        assert_eq!(c.eval(Vec2::new(0.3, 0.1), 0.0), Vec3::ZERO);
        assert_eq!(c.eval(Vec2::new(0.3, 0.3), 0.0), Vec3::ONE);
        assert_eq!(c.eval(Vec2::new(-0.1, 0.1), 0.0), Vec3::ZERO, "floor(-0.4) = -1 is odd");
        // A small footprint inside one square does not blur.
        assert!(close(c.eval(Vec2::new(0.125, 0.125), 0.05), Vec3::ONE, 1e-5));
    }

    #[test]
    fn checker_far_away_footprint_gives_the_average() {
        let even = Vec3::new(0.9, 0.8, 0.1);
        let odd = Vec3::new(0.1, 0.0, 0.5);
        let c = Texture::Checker { even, odd, scale: 10.0 };
        let avg = (even + odd) * 0.5;
        for &(u, v) in &[(0.013, 0.77), (5.5, -3.25), (100.01, 0.3)] {
            let got = c.eval(Vec2::new(u, v), 37.3);
            assert!(close(got, avg, 0.02), "{got:?} vs {avg:?}");
        }
        // An exact multiple of two squares integrates to exactly the mean.
        assert!(close(c.eval(Vec2::new(0.37, 0.61), 0.2), avg, 1e-4));
        // Half a square-width footprint centred on an edge: half and half in u.
        let edge = c.eval(Vec2::new(0.1, 0.05), 0.05);
        assert!(close(edge, avg, 1e-4), "{edge:?}");
    }

    #[test]
    fn checker_filters_each_axis_separately() {
        let c = Texture::Checker { even: Vec3::ONE, odd: Vec3::ZERO, scale: 1.0 };
        // Wide in v only: along v the squares alternate, so the mean is grey
        // even though the footprint is a point in u…
        let grey = c.eval_rect(Vec2::new(0.5, 0.5), Vec2::new(0.0, 40.0));
        assert!((grey.x - 0.5).abs() < 1e-3, "{grey:?}");
        // …but a footprint narrow in both stays crisp, and one thin in u but
        // spanning exactly one square in v gives the exact half/half mix.
        assert_eq!(c.eval_rect(Vec2::new(0.5, 0.5), Vec2::new(0.1, 0.1)), Vec3::ONE);
        let half = c.eval_rect(Vec2::new(0.5, 1.0), Vec2::new(0.1, 1.0));
        assert!((half.x - 0.5).abs() < 1e-6);
        // Shape matters: a footprint 0.5 × 0.1 centred at (1.0, 0.5) straddles
        // the u edge evenly (grey) while 0.1 × 0.5 at the same point does not.
        let a = c.eval_rect(Vec2::new(1.0, 0.5), Vec2::new(0.5, 0.1));
        let b = c.eval_rect(Vec2::new(1.1, 0.5), Vec2::new(0.1, 0.5));
        assert!((a.x - 0.5).abs() < 1e-6 && b.x == 0.0, "{a:?} {b:?}");
        assert_eq!(c.eval(Vec2::new(0.3, 0.7), 0.2), c.eval_rect(Vec2::new(0.3, 0.7), Vec2::splat(0.2)));
    }

    fn two_colour(w: u32, h: u32) -> (MipMap, Vec3, Vec3) {
        let (a, b) = ([255u8, 0, 0, 255], [0u8, 0, 255, 255]);
        let mut rgba = Vec::new();
        for y in 0..h {
            for x in 0..w {
                rgba.extend_from_slice(if (x + y) % 2 == 0 { &a } else { &b });
            }
        }
        (MipMap::from_srgb8(w, h, &rgba), Vec3::X, Vec3::Z)
    }

    #[test]
    fn bilinear_at_texel_centres_returns_the_texel() {
        let mut rgba = Vec::new();
        for i in 0..(5 * 3) {
            rgba.extend_from_slice(&[(i * 17) as u8, (255 - i * 13) as u8, (i * 7) as u8, 255]);
        }
        let m = MipMap::from_srgb8(5, 3, &rgba);
        let t = Texture::Image(m.clone());
        for y in 0..3 {
            for x in 0..5 {
                let uv = Vec2::new((x as f32 + 0.5) / 5.0, (y as f32 + 0.5) / 3.0);
                assert!(close(t.eval(uv, 0.0), m.texel(0, x, y), 1e-5), "texel {x},{y}");
                // Repeat wrapping.
                assert!(close(t.eval(uv + Vec2::new(2.0, -1.0), 0.0), m.texel(0, x, y), 1e-4));
            }
        }
        // Row 0 is v near 0 (top).
        let i = 2; // texel (2, 0)
        assert!((m.texel(0, 2, 0).x - srgb_to_linear((i * 17) as f32 / 255.0)).abs() < 1e-6);
        // Halfway between two texels is their mean.
        let mid = t.eval(Vec2::new(1.0 / 5.0, 0.5 / 3.0), 0.0);
        assert!(close(mid, (m.texel(0, 0, 0) + m.texel(0, 1, 0)) * 0.5, 1e-5));
    }

    #[test]
    fn mip_levels_of_a_two_colour_image_average() {
        for (w, h) in [(8, 8), (7, 5), (16, 3)] {
            let (m, a, b) = two_colour(w, h);
            let last = m.level_count() - 1;
            assert_eq!(m.level_size(last), (1, 1));
            let n = (w * h) as f32;
            let na = ((w * h).div_ceil(2)) as f32;
            let mean = (a * na + b * (n - na)) / n;
            assert!(close(m.texel(last, 0, 0), mean, 1e-5), "{w}x{h}: {:?}", m.texel(last, 0, 0));
            if w % 2 == 0 && h % 2 == 0 {
                // Level 1 of a 1-pixel checker is uniformly the 50/50 mix.
                for y in 0..h / 2 {
                    for x in 0..w / 2 {
                        assert!(close(m.texel(1, x, y), (a + b) * 0.5, 1e-6));
                    }
                }
            }
            // A far-away footprint returns the mean.
            let far = Texture::Image(m).eval(Vec2::new(0.3, 0.6), 100.0);
            assert!(close(far, mean, 1e-5));
        }
    }

    #[test]
    fn trilinear_blends_between_levels() {
        let (m, a, b) = two_colour(8, 8);
        let t = Texture::Image(m.clone());
        let uv = Vec2::new(0.5 / 8.0, 0.5 / 8.0); // centre of texel (0,0) = a
        let sharp = t.eval(uv, 0.0);
        assert!(close(sharp, a, 1e-6));
        let half = t.eval(uv, 1.0 / 8.0 * std::f32::consts::SQRT_2); // lod 0.5
        let lvl1 = m.eval(uv, 2.0 / 8.0);
        assert!(close(lvl1, (a + b) * 0.5, 1e-5));
        assert!(close(half, (sharp + lvl1) * 0.5, 1e-3), "{half:?}");
    }

    #[test]
    fn invalid_images_do_not_panic() {
        assert!(MipMap::try_from_srgb8(0, 4, &[]).is_none());
        assert!(MipMap::try_from_srgb8(2, 2, &[0; 15]).is_none());
        let m = MipMap::from_srgb8(2, 2, &[0; 3]);
        assert_eq!(m.level_count(), 1);
        assert_eq!(Texture::Image(m).eval(Vec2::new(f32::NAN, 0.5), f32::NAN), Vec3::new(1.0, 0.0, 1.0));
    }
}

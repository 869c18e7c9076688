//! The displayed image: tiles land in it as they arrive, and successive passes
//! of the same view are averaged in linear light.
//!
//! Every pixel remembers which *view* (camera generation) its samples belong
//! to. A tile of a new view replaces the pixel's samples; a tile of the same
//! view adds to them, weighted by its samples per pixel. Pixels no tile of the
//! new view has reached yet keep showing the previous image — so a move never
//! flashes black, it paints over the old frame tile by tile.
//!
//! Tiles of a pass rendered at a lower resolution ([`Accumulator::add_tile_of`])
//! are enlarged with bilinear filtering. The low-resolution pixels received so
//! far are kept, so a tile's border is filtered with its neighbours' pixels once
//! they arrive (and with its own until then): whatever the order of the tiles,
//! the complete pass shows as one bilinear enlargement.

use isin_tracer::Tile;
use std::sync::OnceLock;

/// Why a tile was refused.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum TileError {
    /// The tile does not lie inside the image.
    #[error("tile {0:?} lies outside the {1}x{2} image")]
    OutOfBounds(Tile, u32, u32),
    /// The payload is not `w * h * 3` bytes.
    #[error("tile {tile:?} carries {got} bytes, expected {expected}")]
    WrongLength {
        /// The tile.
        tile: Tile,
        /// Bytes received.
        got: usize,
        /// Bytes expected.
        expected: usize,
    },
    /// A lower-resolution tile claims an image size that is empty or larger than the image.
    #[error("a {size:?} image cannot be shown in the {width}x{height} image")]
    BadSize {
        /// The claimed size of the tile's image.
        size: (u32, u32),
        /// Width of the displayed image.
        width: u32,
        /// Height of the displayed image.
        height: u32,
    },
}

/// sRGB byte → linear value.
fn srgb_to_linear_table() -> &'static [f32; 256] {
    static TABLE: OnceLock<[f32; 256]> = OnceLock::new();
    TABLE.get_or_init(|| std::array::from_fn(|i| srgb_to_linear(i as f32 / 255.0)))
}

/// Linear values at which the nearest sRGB byte changes: entry `b` is the
/// linear value of sRGB `(b + ½)/255`.
fn linear_thresholds() -> &'static [f32; 255] {
    static TABLE: OnceLock<[f32; 255]> = OnceLock::new();
    TABLE.get_or_init(|| std::array::from_fn(|b| srgb_to_linear((b as f32 + 0.5) / 255.0)))
}

fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
}

/// Encodes a linear value as the nearest sRGB byte.
fn linear_to_srgb_byte(v: f32) -> u8 {
    linear_thresholds().partition_point(|&t| t <= v) as u8
}

/// Packs RGB bytes into softbuffer's `0x00RRGGBB`.
#[inline]
pub fn pack_rgb(r: u8, g: u8, b: u8) -> u32 {
    (r as u32) << 16 | (g as u32) << 8 | b as u32
}

/// The image being shown, at render resolution.
#[derive(Clone, Debug)]
pub struct Accumulator {
    width: u32,
    height: u32,
    /// Linear RGB sums, 3 per pixel.
    sum: Vec<f32>,
    /// Sum of weights per pixel.
    weight: Vec<f32>,
    /// View generation each pixel's samples belong to.
    view: Vec<u32>,
    /// Encoded pixels, `0x00RRGGBB`.
    display: Vec<u32>,
    /// The low-resolution pass being enlarged, if any.
    low: Option<LowRes>,
}

/// The pixels of a low-resolution pass received so far.
#[derive(Clone, Debug)]
struct LowRes {
    view: u32,
    size: (u32, u32),
    /// RGB8, `size.0 * size.1 * 3` bytes.
    rgb: Vec<u8>,
    /// Whether each pixel has arrived.
    have: Vec<bool>,
}

/// How one destination column (or row) samples a low-resolution axis:
/// bilinear between `lo` and `hi` with weight `frac`/256 on `hi`, and the
/// pixel holding its centre, `nearest`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Taps {
    lo: u32,
    hi: u32,
    frac: u32,
    nearest: u32,
}

/// The taps of destination pixel `v` of a `full`-pixel axis enlarged from
/// `small` pixels: its centre `(v + ½)·small/full − ½` in source pixel
/// coordinates, in 1/256ths (integer arithmetic).
fn taps(v: u32, small: u32, full: u32) -> Taps {
    let (v, small, full) = (v as u64, small as u64, full as u64);
    let nearest = ((2 * v + 1) * small / (2 * full)) as u32;
    // Rounded to the nearest 1/256th.
    let u = (((2 * v + 1) * small * 256 + full) / (2 * full)) as i64 - 128;
    let last = small as u32 - 1;
    if u <= 0 {
        return Taps { lo: 0, hi: 0, frac: 0, nearest };
    }
    let lo = (u >> 8) as u32;
    if lo >= last {
        return Taps { lo: last, hi: last, frac: 0, nearest };
    }
    Taps { lo, hi: lo + 1, frac: (u & 255) as u32, nearest }
}

impl Accumulator {
    /// A black `width × height` image with no samples.
    pub fn new(width: u32, height: u32) -> Self {
        let n = width as usize * height as usize;
        Self {
            width,
            height,
            sum: vec![0.0; n * 3],
            weight: vec![0.0; n],
            view: vec![u32::MAX; n],
            display: vec![0; n],
            low: None,
        }
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Adds a tile of sRGB RGB8 pixels rendered for view `view` with `weight`
    /// samples per pixel. Checks the tile against the image first: tiles come
    /// over the network.
    pub fn add_tile(&mut self, view: u32, weight: f32, tile: Tile, rgb: &[u8]) -> Result<(), TileError> {
        let fits = tile.x.checked_add(tile.w).is_some_and(|r| r <= self.width)
            && tile.y.checked_add(tile.h).is_some_and(|b| b <= self.height);
        if !fits {
            return Err(TileError::OutOfBounds(tile, self.width, self.height));
        }
        let expected = tile.pixel_count() * 3;
        if rgb.len() != expected {
            return Err(TileError::WrongLength { tile, got: rgb.len(), expected });
        }
        let lin = srgb_to_linear_table();
        let weight = weight.max(f32::MIN_POSITIVE);
        for j in 0..tile.h as usize {
            let row = (tile.y as usize + j) * self.width as usize + tile.x as usize;
            for i in 0..tile.w as usize {
                let p = row + i;
                let s = &rgb[(j * tile.w as usize + i) * 3..][..3];
                let sum = &mut self.sum[p * 3..p * 3 + 3];
                if self.view[p] != view {
                    // First samples of this view here: the tile's bytes are exact.
                    self.view[p] = view;
                    self.weight[p] = weight;
                    for c in 0..3 {
                        sum[c] = lin[s[c] as usize] * weight;
                    }
                    self.display[p] = pack_rgb(s[0], s[1], s[2]);
                } else {
                    self.weight[p] += weight;
                    let w = self.weight[p];
                    let mut out = [0u8; 3];
                    for c in 0..3 {
                        sum[c] += lin[s[c] as usize] * weight;
                        out[c] = linear_to_srgb_byte(sum[c] / w);
                    }
                    self.display[p] = pack_rgb(out[0], out[1], out[2]);
                }
            }
        }
        Ok(())
    }

    /// Adds a tile of view `view` rendered at a lower resolution, `size`
    /// (`width × height`, each at most this image's), enlarged with bilinear
    /// filtering over the whole image — any size, also non-integer fractions
    /// such as 1/2.5. It paints the pixels whose centres fall in the tile (see
    /// [`map_tile`]) and repaints its neighbours' pixels next to it, which can
    /// now be filtered across the border; a neighbour's pixel not received yet
    /// is replaced by the nearest received one. These pixels' samples are
    /// replaced, not averaged (a low-resolution pass is a view's only pass of
    /// its kind). `size` equal to this image's is [`Accumulator::add_tile`].
    pub fn add_tile_of(
        &mut self,
        view: u32,
        weight: f32,
        tile: Tile,
        rgb: &[u8],
        size: (u32, u32),
    ) -> Result<(), TileError> {
        let (lw, lh) = size;
        if size == (self.width, self.height) {
            return self.add_tile(view, weight, tile, rgb);
        }
        if lw == 0 || lh == 0 || lw > self.width || lh > self.height {
            return Err(TileError::BadSize { size, width: self.width, height: self.height });
        }
        let fits = tile.x.checked_add(tile.w).is_some_and(|r| r <= lw)
            && tile.y.checked_add(tile.h).is_some_and(|b| b <= lh);
        if !fits {
            return Err(TileError::OutOfBounds(tile, lw, lh));
        }
        let expected = tile.pixel_count() * 3;
        if rgb.len() != expected {
            return Err(TileError::WrongLength { tile, got: rgb.len(), expected });
        }
        let n = lw as usize * lh as usize;
        let mut low = match self.low.take() {
            Some(l) if l.view == view && l.size == size => l,
            _ => LowRes { view, size, rgb: vec![0; n * 3], have: vec![false; n] },
        };
        for j in 0..tile.h as usize {
            let at = (tile.y as usize + j) * lw as usize + tile.x as usize;
            let row = &rgb[j * tile.w as usize * 3..(j + 1) * tile.w as usize * 3];
            low.rgb[at * 3..at * 3 + row.len()].copy_from_slice(row);
            low.have[at..at + tile.w as usize].fill(true);
        }
        // Destination pixels that filter this tile's pixels: those whose
        // nearest low-resolution pixel is in the tile or next to it.
        let grown = {
            let (x0, y0) = (tile.x.saturating_sub(1), tile.y.saturating_sub(1));
            let (x1, y1) = ((tile.x + tile.w + 1).min(lw), (tile.y + tile.h + 1).min(lh));
            Tile { x: x0, y: y0, w: x1 - x0, h: y1 - y0 }
        };
        let big = map_tile(grown, size, (self.width, self.height));
        let cols: Vec<Taps> = (big.x..big.x + big.w).map(|x| taps(x, lw, self.width)).collect();
        let lin = srgb_to_linear_table();
        let weight = weight.max(f32::MIN_POSITIVE);
        for y in big.y..big.y + big.h {
            let r = taps(y, lh, self.height);
            for (i, c) in cols.iter().enumerate() {
                let nearest = (r.nearest * lw + c.nearest) as usize;
                if !low.have[nearest] {
                    continue; // nothing of it here yet: keep the older image
                }
                let sample = |sx: u32, sy: u32| {
                    let k = (sy * lw + sx) as usize;
                    let k = if low.have[k] { k } else { nearest };
                    &low.rgb[k * 3..k * 3 + 3]
                };
                let (a, b) = (sample(c.lo, r.lo), sample(c.hi, r.lo));
                let (d, e) = (sample(c.lo, r.hi), sample(c.hi, r.hi));
                let (fx, fy) = (c.frac, r.frac);
                let mut out = [0u8; 3];
                for ch in 0..3 {
                    let top = a[ch] as u32 * (256 - fx) + b[ch] as u32 * fx;
                    let bottom = d[ch] as u32 * (256 - fx) + e[ch] as u32 * fx;
                    out[ch] = ((top * (256 - fy) + bottom * fy + (1 << 15)) >> 16) as u8;
                }
                let p = y as usize * self.width as usize + big.x as usize + i;
                self.view[p] = view;
                self.weight[p] = weight;
                for ch in 0..3 {
                    self.sum[p * 3 + ch] = lin[out[ch] as usize] * weight;
                }
                self.display[p] = pack_rgb(out[0], out[1], out[2]);
            }
        }
        self.low = Some(low);
        Ok(())
    }

    /// The encoded pixels, row-major `0x00RRGGBB`.
    pub fn display(&self) -> &[u32] {
        &self.display
    }

    /// Total weight (samples per pixel) accumulated at pixel `(x, y)`.
    pub fn weight_at(&self, x: u32, y: u32) -> f32 {
        self.weight[(y * self.width + x) as usize]
    }

    /// The displayed image as RGB8 bytes (for screenshots).
    pub fn to_rgb8(&self) -> Vec<u8> {
        self.display.iter().flat_map(|&p| [(p >> 16) as u8, (p >> 8) as u8, p as u8]).collect()
    }
}

/// The region of a `full` (`width × height`) image covered by `tile` of the
/// same image rendered at the lower resolution `small`: the pixels whose
/// centres fall in the tile, i.e. destination `x` with `⌊(x + ½)·small_w/full_w⌋`
/// inside the tile (so neighbouring tiles share no pixel and leave none out).
pub fn map_tile(tile: Tile, small: (u32, u32), full: (u32, u32)) -> Tile {
    // First destination pixel x whose centre reaches low-resolution index v:
    // (x + ½)·small/full ≥ v, i.e. x ≥ (2·v·full − small) / (2·small).
    let edge = |v: u32, small: u32, full: u32| -> u32 {
        let (v, small, full) = (v as u64, small as u64, full as u64);
        if small == 0 || 2 * v * full <= small {
            return 0;
        }
        (2 * v * full - small).div_ceil(2 * small).min(full) as u32
    };
    let x = edge(tile.x, small.0, full.0);
    let y = edge(tile.y, small.1, full.1);
    let r = edge(tile.x.saturating_add(tile.w), small.0, full.0);
    let b = edge(tile.y.saturating_add(tile.h), small.1, full.1);
    Tile { x, y, w: r.saturating_sub(x), h: b.saturating_sub(y) }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn solid(tile: Tile, v: u8) -> Vec<u8> {
        vec![v; tile.pixel_count() * 3]
    }

    #[test]
    fn srgb_round_trip_is_exact_for_every_byte() {
        for b in 0..=255u8 {
            assert_eq!(linear_to_srgb_byte(srgb_to_linear_table()[b as usize]), b);
        }
        assert_eq!(linear_to_srgb_byte(-1.0), 0);
        assert_eq!(linear_to_srgb_byte(7.0), 255);
    }

    #[test]
    fn tiles_land_where_they_belong_and_keep_the_old_image_elsewhere() {
        let mut a = Accumulator::new(8, 4);
        let all = Tile { x: 0, y: 0, w: 8, h: 4 };
        a.add_tile(0, 1.0, all, &solid(all, 10)).unwrap();
        let t = Tile { x: 2, y: 1, w: 3, h: 2 };
        let mut rgb = solid(t, 0);
        rgb[0] = 200; // red of the tile's first pixel
        a.add_tile(1, 1.0, t, &rgb).unwrap();
        assert_eq!(a.display()[8 + 2], pack_rgb(200, 0, 0));
        assert_eq!(a.display()[8 + 3], 0);
        assert_eq!(a.display()[0], pack_rgb(10, 10, 10), "untouched pixels keep the previous view");
        assert_eq!(a.display()[2 * 8 + 5], pack_rgb(10, 10, 10));
        assert_eq!(a.to_rgb8()[(8 + 2) * 3..(8 + 2) * 3 + 3], [200, 0, 0]);
    }

    #[test]
    fn passes_of_one_view_average_in_linear_light() {
        let mut a = Accumulator::new(2, 1);
        let t = Tile { x: 0, y: 0, w: 2, h: 1 };
        a.add_tile(5, 1.0, t, &solid(t, 0)).unwrap();
        a.add_tile(5, 1.0, t, &solid(t, 255)).unwrap();
        // Half of full intensity in linear light is sRGB 188, not 128.
        let v = (a.display()[0] & 0xff) as u8;
        assert!((187..=188).contains(&v), "got {v}");
        assert_eq!(a.weight_at(1, 0), 2.0);
        // Weighted: one 3-spp white pass against the black one.
        let mut b = Accumulator::new(2, 1);
        b.add_tile(0, 1.0, t, &solid(t, 0)).unwrap();
        b.add_tile(0, 3.0, t, &solid(t, 255)).unwrap();
        let w = (b.display()[1] & 0xff) as u8;
        let expect = 255.0 * (1.055 * 0.75f32.powf(1.0 / 2.4) - 0.055);
        assert!((w as f32 - expect).abs() <= 1.0, "got {w}, expected about {expect}");
        // A new view restarts the average.
        b.add_tile(1, 1.0, t, &solid(t, 40)).unwrap();
        assert_eq!(b.display()[1], pack_rgb(40, 40, 40));
        assert_eq!(b.weight_at(1, 0), 1.0);
    }

    #[test]
    fn bad_tiles_are_refused() {
        let mut a = Accumulator::new(8, 4);
        let out = Tile { x: 6, y: 0, w: 4, h: 1 };
        assert!(matches!(a.add_tile(0, 1.0, out, &solid(out, 1)), Err(TileError::OutOfBounds(..))));
        let huge = Tile { x: u32::MAX, y: 0, w: 2, h: 1 };
        assert!(matches!(a.add_tile(0, 1.0, huge, &[]), Err(TileError::OutOfBounds(..))));
        let t = Tile { x: 0, y: 0, w: 2, h: 2 };
        assert!(matches!(a.add_tile(0, 1.0, t, &[0; 11]), Err(TileError::WrongLength { .. })));
        assert!(a.display().iter().all(|&p| p == 0));
    }

    /// Bilinear enlargement of a whole `small` image to `full`, in f64, from
    /// the definition: destination pixel centre `(v + ½)·small/full − ½` in
    /// source pixel coordinates, clamped to the edge pixels.
    fn reference(img: &[u8], small: (u32, u32), full: (u32, u32), x: u32, y: u32) -> [f64; 3] {
        let coord = |v: u32, s: u32, f: u32| {
            let u = ((v as f64 + 0.5) * s as f64 / f as f64 - 0.5).clamp(0.0, (s - 1) as f64);
            let lo = u.floor() as u32;
            (lo, (lo + 1).min(s - 1), u - lo as f64)
        };
        let (x0, x1, fx) = coord(x, small.0, full.0);
        let (y0, y1, fy) = coord(y, small.1, full.1);
        let px = |sx: u32, sy: u32, c: usize| img[((sy * small.0 + sx) * 3) as usize + c] as f64;
        std::array::from_fn(|c| {
            let top = px(x0, y0, c) * (1.0 - fx) + px(x1, y0, c) * fx;
            let bottom = px(x0, y1, c) * (1.0 - fx) + px(x1, y1, c) * fx;
            top * (1.0 - fy) + bottom * fy
        })
    }

    /// Asserts every pixel of `a` is within 1 of the bilinear reference of `img`.
    fn assert_bilinear(a: &Accumulator, img: &[u8], small: (u32, u32)) {
        let full = (a.width(), a.height());
        for y in 0..full.1 {
            for x in 0..full.0 {
                let want = reference(img, small, full, x, y);
                let p = a.display()[(y * full.0 + x) as usize];
                let got = [(p >> 16) & 255, (p >> 8) & 255, p & 255];
                for c in 0..3 {
                    assert!(
                        (got[c] as f64 - want[c]).abs() <= 1.0,
                        "pixel ({x}, {y}) channel {c}: {} instead of {:.2}",
                        got[c],
                        want[c]
                    );
                }
            }
        }
    }

    /// A `w × h` RGB8 test image with structure in every channel.
    fn pattern(w: u32, h: u32) -> Vec<u8> {
        (0..h)
            .flat_map(|y| {
                (0..w).flat_map(move |x| [(x * 37 % 256) as u8, (y * 53 % 256) as u8, ((x ^ y) * 11) as u8])
            })
            .collect()
    }

    /// The part of a whole `w`-wide RGB8 image under `t`.
    fn cut(img: &[u8], w: u32, t: Tile) -> Vec<u8> {
        (t.y..t.y + t.h)
            .flat_map(|y| {
                img[((y * w + t.x) * 3) as usize..((y * w + t.x + t.w) * 3) as usize].iter().copied()
            })
            .collect()
    }

    #[test]
    fn low_resolution_tiles_are_enlarged_bilinearly_and_checked() {
        // 5 × 3 at half resolution is rendered as 3 × 2: one tile of the whole.
        let mut a = Accumulator::new(5, 3);
        let all = Tile { x: 0, y: 0, w: 3, h: 2 };
        let img = pattern(3, 2);
        a.add_tile_of(0, 1.0, all, &img, (3, 2)).unwrap();
        assert_bilinear(&a, &img, (3, 2));
        // Pixels whose centre is a low-resolution pixel centre get it exactly:
        // on 2 → 6 columns, (x + ½)·2/6 − ½ = 0 at x = 1.
        let mut b = Accumulator::new(6, 2);
        let grey: Vec<u8> = [0u8, 0, 0, 240, 240, 240].to_vec();
        b.add_tile_of(0, 1.0, Tile { x: 0, y: 0, w: 2, h: 1 }, &grey, (2, 1)).unwrap();
        let row: Vec<u32> = b.display()[..6].iter().map(|p| p & 255).collect();
        // u = (x + ½)/3 − ½: −⅓, 0, ⅓, ⅔, 1, 1⅓ (clamped to 0 and 1).
        assert_eq!(row, [0, 0, 80, 160, 240, 240], "a ramp between the two pixels, flat beyond them");
        let t = Tile { x: 1, y: 0, w: 2, h: 2 };
        let out = Tile { x: 2, y: 1, w: 2, h: 1 };
        assert!(matches!(a.add_tile_of(0, 1.0, out, &[0; 6], (3, 2)), Err(TileError::OutOfBounds(..))));
        assert!(matches!(a.add_tile_of(0, 1.0, t, &[0; 12], (6, 2)), Err(TileError::BadSize { .. })));
        assert!(matches!(a.add_tile_of(0, 1.0, t, &[0; 12], (0, 2)), Err(TileError::BadSize { .. })));
        assert!(matches!(a.add_tile_of(0, 1.0, t, &[0; 11], (3, 2)), Err(TileError::WrongLength { .. })));
        assert_eq!(
            map_tile(Tile { x: 2, y: 1, w: 1, h: 1 }, (3, 2), (5, 3)),
            Tile { x: 3, y: 1, w: 2, h: 2 }
        );
        assert_eq!(map_tile(t, (5, 3), (5, 3)), t, "full size maps to itself");
    }

    #[test]
    fn a_tile_whose_neighbour_is_missing_keeps_the_old_image_there_and_no_black_bleeds_in() {
        // 8 × 2 from 4 × 1: the right half arrives first, all white.
        let mut a = Accumulator::new(8, 2);
        let old = Tile { x: 0, y: 0, w: 8, h: 2 };
        a.add_tile(0, 1.0, old, &solid(old, 30)).unwrap();
        let right = Tile { x: 2, y: 0, w: 2, h: 1 };
        a.add_tile_of(1, 1.0, right, &solid(right, 255), (4, 1)).unwrap();
        let row: Vec<u32> = a.display()[..8].iter().map(|p| p & 255).collect();
        assert_eq!(row, [30, 30, 30, 30, 255, 255, 255, 255], "its own pixels only; the rest as before");
        // The left half (black) lands: the border is filtered across both.
        let left = Tile { x: 0, y: 0, w: 2, h: 1 };
        a.add_tile_of(1, 1.0, left, &solid(left, 0), (4, 1)).unwrap();
        let row: Vec<u32> = a.display()[8..16].iter().map(|p| p & 255).collect();
        assert_eq!(row, [0, 0, 0, 64, 191, 255, 255, 255]);
    }

    #[test]
    fn tiles_in_any_order_give_the_bilinear_enlargement_of_the_whole_pass() {
        // 640 × 480 at 1/2.5 is 256 × 192, in 40 × 32 tiles (the last column
        // narrower): every pixel is in exactly one tile's region, and the
        // finished image is the bilinear enlargement whatever the tile order.
        let (w, h, lw, lh) = (640u32, 480u32, 256u32, 192u32);
        let img = pattern(lw, lh);
        let mut tiles = Vec::new();
        for ty in (0..lh).step_by(32) {
            for tx in (0..lw).step_by(40) {
                tiles.push(Tile { x: tx, y: ty, w: 40.min(lw - tx), h: 32.min(lh - ty) });
            }
        }
        let mut painted = vec![0u32; (w * h) as usize];
        for &t in &tiles {
            let big = map_tile(t, (lw, lh), (w, h));
            for y in big.y..big.y + big.h {
                for x in big.x..big.x + big.w {
                    painted[(y * w + x) as usize] += 1;
                }
            }
        }
        assert!(painted.iter().all(|&n| n == 1), "some pixel painted {:?} times", painted.iter().max());
        let mut forward = Accumulator::new(w, h);
        for &t in &tiles {
            forward.add_tile_of(1, 1.0, t, &cut(&img, lw, t), (lw, lh)).unwrap();
        }
        assert_bilinear(&forward, &img, (lw, lh));
        // Shuffled (a fixed permutation): the same bytes.
        let mut shuffled = Accumulator::new(w, h);
        let n = tiles.len();
        for i in 0..n {
            let t = tiles[(i * 17 + 5) % n];
            shuffled.add_tile_of(1, 1.0, t, &cut(&img, lw, t), (lw, lh)).unwrap();
        }
        assert_eq!(shuffled.display(), forward.display());
        // A new view at another size starts afresh.
        let whole = Tile { x: 0, y: 0, w: 128, h: 96 };
        forward.add_tile_of(2, 1.0, whole, &solid(whole, 9), (128, 96)).unwrap();
        assert!(forward.display().iter().all(|&p| p == pack_rgb(9, 9, 9)));
    }
}

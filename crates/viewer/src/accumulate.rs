//! The displayed image: tiles land in it as they arrive, and successive passes
//! of the same view are averaged in linear light.
//!
//! Every pixel remembers which *view* (camera generation) its samples belong
//! to. A tile of a new view replaces the pixel's samples; a tile of the same
//! view adds to them, weighted by its samples per pixel. Pixels no tile of the
//! new view has reached yet keep showing the previous image — so a move never
//! flashes black, it paints over the old frame tile by tile.

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

    /// Adds a tile of the same view rendered at a lower resolution, `size`
    /// (`width × height`, each at most this image's): every pixel of the tile
    /// covers the block of this image's pixels whose centres fall in it, so
    /// any size — also non-integer fractions such as 1/2.5 — is shown
    /// enlarged over the whole image (nearest neighbour). `size` equal to
    /// this image's is [`Accumulator::add_tile`].
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
        let big = map_tile(tile, size, (self.width, self.height));
        // Source column of every destination column, and source row per row.
        // The low-resolution pixel holding the centre of pixel `v`: ⌊(v + ½)·small/full⌋.
        let src =
            |v: u32, small: u32, full: u32| ((2 * v as u64 + 1) * small as u64 / (2 * full as u64)) as u32;
        let cols: Vec<usize> =
            (big.x..big.x + big.w).map(|x| (src(x, lw, self.width) - tile.x) as usize).collect();
        let mut up = Vec::with_capacity(big.pixel_count() * 3);
        for y in big.y..big.y + big.h {
            let row = (src(y, lh, self.height) - tile.y) as usize * tile.w as usize;
            for &c in &cols {
                let i = (row + c) * 3;
                up.extend_from_slice(&rgb[i..i + 3]);
            }
        }
        self.add_tile(view, weight, big, &up)
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

    #[test]
    fn low_resolution_tiles_cover_blocks_clipped_at_the_edge() {
        // 5 × 3 at half resolution is rendered as 3 × 2.
        let mut a = Accumulator::new(5, 3);
        let t = Tile { x: 1, y: 0, w: 2, h: 2 };
        let rgb: Vec<u8> = [10u8, 20, 30, 40].iter().flat_map(|&v| [v, v, v]).collect();
        a.add_tile_of(0, 1.0, t, &rgb, (3, 2)).unwrap();
        let grey = |v: u8| pack_rgb(v, v, v);
        let d = a.display();
        // Pixel centres: columns 2, 3, 4 at 2.5/5, 3.5/5, 4.5/5 → low-resolution
        // columns 1, 2, 2; rows 0, 1, 2 at 0.5/3, 1.5/3, 2.5/3 → rows 0, 1, 1.
        assert_eq!(&d[0..5], [0, 0, grey(10), grey(20), grey(20)]);
        assert_eq!(&d[5..10], [0, 0, grey(30), grey(40), grey(40)]);
        assert_eq!(&d[10..15], [0, 0, grey(30), grey(40), grey(40)]);
        let out = Tile { x: 2, y: 1, w: 2, h: 1 };
        assert!(matches!(a.add_tile_of(0, 1.0, out, &[0; 6], (3, 2)), Err(TileError::OutOfBounds(..))));
        assert!(matches!(a.add_tile_of(0, 1.0, t, &rgb, (6, 2)), Err(TileError::BadSize { .. })));
        assert!(matches!(a.add_tile_of(0, 1.0, t, &rgb, (0, 2)), Err(TileError::BadSize { .. })));
        assert_eq!(
            map_tile(Tile { x: 2, y: 1, w: 1, h: 1 }, (3, 2), (5, 3)),
            Tile { x: 3, y: 1, w: 2, h: 2 }
        );
        assert_eq!(map_tile(t, (5, 3), (5, 3)), t, "full size maps to itself");
    }

    #[test]
    fn non_integer_fractions_tile_the_image_exactly() {
        // 640 × 480 at 1/2.5 is 256 × 192, split into 32-pixel tiles (the
        // last column and row narrower): every pixel is painted exactly once,
        // by the low-resolution pixel whose area holds its centre.
        let (w, h, lw, lh) = (640u32, 480u32, 256u32, 192u32);
        let mut a = Accumulator::new(w, h);
        let mut painted = vec![0u32; (w * h) as usize];
        for ty in (0..lh).step_by(32) {
            for tx in (0..lw).step_by(40) {
                let t = Tile { x: tx, y: ty, w: 40.min(lw - tx), h: 32.min(lh - ty) };
                // Each low-resolution pixel carries its own coordinates.
                let rgb: Vec<u8> = (0..t.h)
                    .flat_map(|j| (0..t.w).flat_map(move |i| [(tx + i) as u8, (ty + j) as u8, 7]))
                    .collect();
                a.add_tile_of(1, 1.0, t, &rgb, (lw, lh)).unwrap();
                let big = map_tile(t, (lw, lh), (w, h));
                for y in big.y..big.y + big.h {
                    for x in big.x..big.x + big.w {
                        painted[(y * w + x) as usize] += 1;
                    }
                }
            }
        }
        assert!(painted.iter().all(|&n| n == 1), "some pixel painted {:?} times", painted.iter().max());
        for (x, y) in [(0, 0), (1, 1), (2, 2), (3, 4), (639, 479), (321, 100), (5, 7)] {
            // Pixel centre (x + ½)/640 lies in low-resolution pixel ⌊(x + ½)·256/640⌋.
            let sx = ((x as f64 + 0.5) * lw as f64 / w as f64) as u32;
            let sy = ((y as f64 + 0.5) * lh as f64 / h as f64) as u32;
            let p = a.display()[(y * w + x) as usize];
            assert_eq!(p, pack_rgb(sx as u8, sy as u8, 7), "pixel ({x}, {y})");
        }
    }
}

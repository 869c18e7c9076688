//! Drawing into the window's `0x00RRGGBB` buffer: the image scaled to fit,
//! tile borders for the ownership overlay, and status text in an 8 × 8 bitmap
//! font (the public-domain `font8x8` glyphs).

use font8x8::legacy::BASIC_LEGACY;
use isin_tracer::Tile;

/// Colour of the window around the image when aspect ratios differ.
pub const LETTERBOX: u32 = 0x0020_2020;

/// A mutable view of a `width × height` pixel buffer.
pub struct Canvas<'a> {
    /// Pixels, row-major `0x00RRGGBB`.
    pub pixels: &'a mut [u32],
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
}

/// Where the image lands in the window: scaled uniformly to fit, centred.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    /// Left edge in window pixels.
    pub x: u32,
    /// Top edge in window pixels.
    pub y: u32,
    /// Scaled width in window pixels.
    pub w: u32,
    /// Scaled height in window pixels.
    pub h: u32,
}

impl Placement {
    /// Fits a `src_w × src_h` image into a `dst_w × dst_h` window, keeping its
    /// aspect ratio.
    pub fn fit(src_w: u32, src_h: u32, dst_w: u32, dst_h: u32) -> Self {
        if src_w == 0 || src_h == 0 || dst_w == 0 || dst_h == 0 {
            return Self { x: 0, y: 0, w: 0, h: 0 };
        }
        // Compare dst_w/src_w with dst_h/src_h without rounding.
        let (w, h) = if dst_w as u64 * src_h as u64 <= dst_h as u64 * src_w as u64 {
            (dst_w, ((src_h as u64 * dst_w as u64) / src_w as u64).max(1) as u32)
        } else {
            (((src_w as u64 * dst_h as u64) / src_h as u64).max(1) as u32, dst_h)
        };
        Self { x: (dst_w - w) / 2, y: (dst_h - h) / 2, w, h }
    }

    /// The window rectangle `(x0, y0, x1, y1)` (exclusive end) covering a tile
    /// of a `src_w × src_h` image.
    pub fn map_tile(&self, tile: Tile, src_w: u32, src_h: u32) -> (u32, u32, u32, u32) {
        let sx = |v: u32| self.x + (v as u64 * self.w as u64 / src_w.max(1) as u64) as u32;
        let sy = |v: u32| self.y + (v as u64 * self.h as u64 / src_h.max(1) as u64) as u32;
        (sx(tile.x), sy(tile.y), sx(tile.x + tile.w), sy(tile.y + tile.h))
    }
}

impl Canvas<'_> {
    /// Fills the canvas with the letterbox colour and draws `src` (`src_w ×
    /// src_h`, row-major) scaled with nearest-neighbour sampling into `at`.
    pub fn draw_image(&mut self, src: &[u32], src_w: u32, src_h: u32, at: Placement) {
        self.pixels.fill(LETTERBOX);
        if at.w == 0 || at.h == 0 || src.len() < src_w as usize * src_h as usize {
            return;
        }
        let n = (at.w as usize).min(self.width.saturating_sub(at.x) as usize);
        if (at.w, at.h) == (src_w, src_h) {
            // 1:1 (the window at the render size): row copies.
            for y in 0..at.h.min(self.height.saturating_sub(at.y)) {
                let start = ((at.y + y) * self.width + at.x) as usize;
                let row = y as usize * src_w as usize;
                self.pixels[start..start + n].copy_from_slice(&src[row..row + n]);
            }
            return;
        }
        let xs: Vec<usize> = (0..at.w).map(|x| ((x as u64 * src_w as u64) / at.w as u64) as usize).collect();
        for y in 0..at.h.min(self.height.saturating_sub(at.y)) {
            let sy = ((y as u64 * src_h as u64) / at.h as u64) as usize;
            let src_row = &src[sy * src_w as usize..(sy + 1) * src_w as usize];
            let start = ((at.y + y) * self.width + at.x) as usize;
            for (d, &sx) in self.pixels[start..start + n].iter_mut().zip(&xs) {
                *d = src_row[sx];
            }
        }
    }

    /// Sets one pixel, ignoring coordinates outside the canvas.
    #[inline]
    pub fn put(&mut self, x: u32, y: u32, colour: u32) {
        if x < self.width && y < self.height {
            self.pixels[(y * self.width + x) as usize] = colour;
        }
    }

    /// Fills the rectangle `x0..x1 × y0..y1` (clipped).
    pub fn fill_rect(&mut self, x0: u32, y0: u32, x1: u32, y1: u32, colour: u32) {
        let (x1, y1) = (x1.min(self.width), y1.min(self.height));
        for y in y0..y1 {
            let row = (y * self.width) as usize;
            for p in &mut self.pixels[row + x0.min(x1) as usize..row + x1 as usize] {
                *p = colour;
            }
        }
    }

    /// Draws the one-pixel outline of `x0..x1 × y0..y1` (clipped).
    pub fn outline(&mut self, x0: u32, y0: u32, x1: u32, y1: u32, colour: u32) {
        if x1 <= x0 || y1 <= y0 {
            return;
        }
        for x in x0..x1 {
            self.put(x, y0, colour);
            self.put(x, y1 - 1, colour);
        }
        for y in y0..y1 {
            self.put(x0, y, colour);
            self.put(x1 - 1, y, colour);
        }
    }

    /// Draws `text` with its top-left corner at `(x, y)`, each glyph `8·scale`
    /// pixels square, over a dark backing box. Characters outside ASCII show as
    /// `?`. Returns the height used.
    pub fn text(&mut self, x: u32, y: u32, text: &str, colour: u32, scale: u32) -> u32 {
        let scale = scale.max(1);
        let cell = 8 * scale;
        let width = text.chars().count() as u32 * cell;
        self.fill_rect(x, y, x + width + 2 * scale, y + cell + 2 * scale, 0x0010_1010);
        for (i, ch) in text.chars().enumerate() {
            let glyph = BASIC_LEGACY[if ch.is_ascii() { ch as usize } else { b'?' as usize }];
            let gx = x + scale + i as u32 * cell;
            for (row, bits) in glyph.iter().enumerate() {
                for col in 0..8 {
                    // Bit 0 is the leftmost pixel.
                    if bits >> col & 1 == 1 {
                        let px = gx + col * scale;
                        let py = y + scale + row as u32 * scale;
                        self.fill_rect(px, py, px + scale, py + scale, colour);
                    }
                }
            }
        }
        cell + 2 * scale
    }
}

/// `line` broken into pieces of at most `columns` characters: at spaces
/// where it can, inside a word longer than a piece where it must. Nothing is
/// dropped but the spaces the line breaks at.
pub fn wrap(line: &str, columns: usize) -> Vec<String> {
    let columns = columns.max(1);
    let mut out = Vec::new();
    let mut current = String::new();
    for word in line.split(' ') {
        let mut word: Vec<char> = word.chars().collect();
        let len = current.chars().count();
        if len > 0 && len + 1 + word.len() <= columns {
            current.push(' ');
            current.extend(word.iter());
            continue;
        }
        if len > 0 {
            out.push(std::mem::take(&mut current));
        }
        while word.len() > columns {
            out.push(word.drain(..columns).collect());
        }
        current = word.into_iter().collect();
    }
    if !current.is_empty() || out.is_empty() {
        out.push(current);
    }
    out
}

/// A distinct, bright colour for worker `owner` (golden-ratio hue steps).
pub fn owner_colour(owner: u32) -> u32 {
    let hue = (owner as f32 * 0.618_034).fract() * 6.0;
    let f = hue.fract();
    let (r, g, b) = match hue as u32 {
        0 => (1.0, f, 0.0),
        1 => (1.0 - f, 1.0, 0.0),
        2 => (0.0, 1.0, f),
        3 => (0.0, 1.0 - f, 1.0),
        4 => (f, 0.0, 1.0),
        _ => (1.0, 0.0, 1.0 - f),
    };
    let byte = |v: f32| (64.0 + v * 191.0) as u32;
    byte(r) << 16 | byte(g) << 8 | byte(b)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_text_wraps_at_spaces_and_inside_long_words_without_losing_any() {
        assert_eq!(wrap("2 live slaves  0.12 MB/s  tcp", 40), ["2 live slaves  0.12 MB/s  tcp"]);
        assert_eq!(wrap("2 live slaves  0.12 MB/s  tcp", 14), ["2 live slaves ", "0.12 MB/s  tcp"]);
        let hint = "no slaves: start one with `isin slave --connect isin://0123456789abcdef@127.0.0.1:1`";
        let parts = wrap(hint, 20);
        assert!(parts.iter().all(|p| p.chars().count() <= 20), "{parts:?}");
        assert_eq!(parts.concat().replace(' ', ""), hint.replace(' ', ""), "nothing dropped: {parts:?}");
        assert_eq!(wrap("", 5), [""]);
        assert_eq!(wrap("abc", 0), ["a", "b", "c"]);
    }

    #[test]
    fn fit_keeps_aspect_and_centres() {
        assert_eq!(Placement::fit(320, 240, 640, 480), Placement { x: 0, y: 0, w: 640, h: 480 });
        assert_eq!(Placement::fit(320, 240, 800, 480), Placement { x: 80, y: 0, w: 640, h: 480 });
        assert_eq!(Placement::fit(320, 240, 640, 600), Placement { x: 0, y: 60, w: 640, h: 480 });
        assert_eq!(Placement::fit(320, 240, 0, 10).w, 0);
    }

    #[test]
    fn draw_image_scales_with_nearest_neighbour_and_letterboxes() {
        let src = [1, 2, 3, 4]; // 2 × 2
        let mut px = vec![0u32; 6 * 4];
        let mut c = Canvas { pixels: &mut px, width: 6, height: 4 };
        let at = Placement::fit(2, 2, 6, 4);
        assert_eq!(at, Placement { x: 1, y: 0, w: 4, h: 4 });
        c.draw_image(&src, 2, 2, at);
        let rows: Vec<&[u32]> = px.chunks(6).collect();
        assert_eq!(rows[0], [LETTERBOX, 1, 1, 2, 2, LETTERBOX]);
        assert_eq!(rows[3], [LETTERBOX, 3, 3, 4, 4, LETTERBOX]);
    }

    #[test]
    fn draw_image_at_its_own_size_copies_it() {
        let src: Vec<u32> = (0..12).collect(); // 4 × 3
        let mut px = vec![0u32; 6 * 3];
        let mut c = Canvas { pixels: &mut px, width: 6, height: 3 };
        let at = Placement::fit(4, 3, 6, 3);
        assert_eq!(at, Placement { x: 1, y: 0, w: 4, h: 3 });
        c.draw_image(&src, 4, 3, at);
        let rows: Vec<&[u32]> = px.chunks(6).collect();
        assert_eq!(rows[0], [LETTERBOX, 0, 1, 2, 3, LETTERBOX]);
        assert_eq!(rows[2], [LETTERBOX, 8, 9, 10, 11, LETTERBOX]);
    }

    #[test]
    fn text_sets_glyph_pixels() {
        let mut px = vec![0u32; 40 * 12];
        let mut c = Canvas { pixels: &mut px, width: 40, height: 12 };
        let h = c.text(0, 0, "I", 0xffffff, 1);
        assert_eq!(h, 10);
        let lit = px.iter().filter(|&&p| p == 0xffffff).count();
        let expect: u32 = BASIC_LEGACY[b'I' as usize].iter().map(|b| b.count_ones()).sum();
        assert!(expect > 0);
        assert_eq!(lit as u32, expect);
        // Text running off the right edge is clipped, not a panic.
        let mut c = Canvas { pixels: &mut px, width: 40, height: 12 };
        c.text(30, 6, "clipped", 0xff, 2);
    }

    #[test]
    fn outline_and_tile_mapping() {
        let at = Placement::fit(100, 50, 200, 100);
        assert_eq!(at.map_tile(Tile { x: 10, y: 5, w: 20, h: 10 }, 100, 50), (20, 10, 60, 30));
        let mut px = vec![0u32; 10 * 10];
        let mut c = Canvas { pixels: &mut px, width: 10, height: 10 };
        c.outline(2, 2, 5, 6, 7);
        assert_eq!(px.iter().filter(|&&p| p == 7).count(), 3 * 2 + 4 * 2 - 4);
    }

    #[test]
    fn owners_get_different_colours() {
        let colours: Vec<u32> = (0..8).map(owner_colour).collect();
        for i in 0..8 {
            for j in i + 1..8 {
                assert_ne!(colours[i], colours[j], "owners {i} and {j}");
            }
        }
    }
}

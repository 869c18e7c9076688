//! Where a frame's render time goes: a coarse map of render cost per pixel
//! over the image, learnt from the slaves' reported render times, so that the
//! next frame hands out its most expensive tiles first.
//!
//! A frame ends when its slowest tile returns. Handed out in grid order, an
//! expensive region (mirrors, many lights) met last leaves every other slave
//! idle while one renders it. Consecutive frames of a moving camera cost
//! nearly the same where they look alike, so the scheduler orders each new
//! frame's tiles by the cost the previous frames measured there, largest first
//! (the classic longest-processing-time rule): the tail of a frame is then made
//! of cheap tiles. The map lives in normalised image coordinates, so frames of
//! another resolution (a viewer's dynamic resolution) use it too.

use isin_tracer::Tile;

/// Cells along each axis of the map.
pub const CELLS: u32 = 64;

/// Render cost per pixel over the image, in cells of `1/CELLS` of each side.
#[derive(Clone, Debug)]
pub struct CostMap {
    /// Microseconds per pixel of each cell, row-major; `None` until measured.
    cells: Vec<Option<f32>>,
}

impl Default for CostMap {
    fn default() -> Self {
        Self { cells: vec![None; (CELLS * CELLS) as usize] }
    }
}

impl CostMap {
    /// The cells `tile` of a `width × height` image touches: `(x0..x1, y0..y1)`.
    fn span(tile: Tile, width: u32, height: u32) -> Option<(std::ops::Range<u32>, std::ops::Range<u32>)> {
        if width == 0 || height == 0 || tile.w == 0 || tile.h == 0 {
            return None;
        }
        let cell = |v: u32, size: u32| (u64::from(v) * u64::from(CELLS) / u64::from(size)).min(63) as u32;
        let end = |v: u32, size: u32| {
            (u64::from(v) * u64::from(CELLS)).div_ceil(u64::from(size)).clamp(1, u64::from(CELLS)) as u32
        };
        let (x0, y0) = (cell(tile.x, width), cell(tile.y, height));
        let x1 = end(tile.x.saturating_add(tile.w), width).max(x0 + 1);
        let y1 = end(tile.y.saturating_add(tile.h), height).max(y0 + 1);
        Some((x0..x1, y0..y1))
    }

    /// Records that `tile` of a `width × height` image took `micros` to render.
    pub fn record(&mut self, tile: Tile, width: u32, height: u32, micros: u64) {
        let Some((xs, ys)) = Self::span(tile, width, height) else { return };
        let per_pixel = micros as f32 / tile.pixel_count().max(1) as f32;
        if !per_pixel.is_finite() {
            return;
        }
        for y in ys {
            for x in xs.clone() {
                self.cells[(y * CELLS + x) as usize] = Some(per_pixel);
            }
        }
    }

    /// The expected render time of `tile` of a `width × height` image, in
    /// microseconds (0 where nothing was measured yet).
    pub fn estimate(&self, tile: Tile, width: u32, height: u32) -> f32 {
        let Some((xs, ys)) = Self::span(tile, width, height) else { return 0.0 };
        let (mut sum, mut n) = (0.0f32, 0u32);
        for y in ys {
            for x in xs.clone() {
                if let Some(c) = self.cells[(y * CELLS + x) as usize] {
                    sum += c;
                    n += 1;
                }
            }
        }
        if n == 0 { 0.0 } else { sum / n as f32 * tile.pixel_count() as f32 }
    }

    /// Orders `ids` (indices into `tiles`) by expected cost, largest first;
    /// tiles of equal (or unknown) cost keep their order.
    pub fn order(&self, ids: &mut [u32], tiles: &[Tile], width: u32, height: u32) {
        let cost: Vec<f32> = ids
            .iter()
            .map(|&i| tiles.get(i as usize).map_or(0.0, |t| self.estimate(*t, width, height)))
            .collect();
        let mut keyed: Vec<(f32, u32)> = cost.into_iter().zip(ids.iter().copied()).collect();
        keyed.sort_by(|a, b| b.0.total_cmp(&a.0));
        for (slot, (_, id)) in ids.iter_mut().zip(keyed) {
            *slot = id;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(x: u32, y: u32, w: u32, h: u32) -> Tile {
        Tile { x, y, w, h }
    }

    #[test]
    fn unknown_costs_are_zero_and_keep_the_order() {
        let map = CostMap::default();
        assert_eq!(map.estimate(t(0, 0, 32, 32), 320, 240), 0.0);
        let tiles = Tile::grid(320, 240, 32);
        let mut ids: Vec<u32> = (0..tiles.len() as u32).collect();
        map.order(&mut ids, &tiles, 320, 240);
        assert!(ids.windows(2).all(|w| w[0] < w[1]));
    }

    #[test]
    fn measured_cost_scales_with_the_tile_and_carries_across_resolutions() {
        let mut map = CostMap::default();
        // 10 µs per pixel over the right half of a 320×240 image, 1 µs on the left.
        for tile in Tile::grid(320, 240, 32) {
            let per_pixel = if tile.x >= 160 { 10 } else { 1 };
            map.record(tile, 320, 240, per_pixel * tile.pixel_count() as u64);
        }
        let right = map.estimate(t(192, 96, 32, 32), 320, 240);
        assert!((right - 10.0 * 1024.0).abs() < 1.0, "{right}");
        let left = map.estimate(t(0, 0, 16, 16), 320, 240);
        assert!((left - 256.0).abs() < 0.1, "{left}");
        // The same place in a 640×480 frame: per pixel the same, four times the pixels.
        let big = map.estimate(t(384, 192, 64, 64), 640, 480);
        assert!((big - 10.0 * 4096.0).abs() < 4.0, "{big}");
    }

    #[test]
    fn order_puts_the_expensive_tiles_first() {
        let mut map = CostMap::default();
        let tiles = Tile::grid(320, 240, 32);
        // The last tile in grid order is the expensive one.
        let hot = tiles.len() as u32 - 1;
        for (i, tile) in tiles.iter().enumerate() {
            let us = if i as u32 == hot { 50_000 } else { 1_000 };
            map.record(*tile, 320, 240, us);
        }
        let mut ids: Vec<u32> = (0..tiles.len() as u32).collect();
        map.order(&mut ids, &tiles, 320, 240);
        assert_eq!(ids[0], hot);
        let mut sorted = ids.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..tiles.len() as u32).collect::<Vec<_>>(), "a permutation");
    }

    #[test]
    fn degenerate_inputs_are_ignored() {
        let mut map = CostMap::default();
        map.record(t(0, 0, 0, 10), 320, 240, 5);
        map.record(t(0, 0, 10, 10), 0, 240, 5);
        map.record(t(400, 400, 10, 10), 320, 240, u64::MAX);
        assert_eq!(map.estimate(t(0, 0, 10, 10), 320, 240), 0.0, "empty tiles and images record nothing");
        assert!(map.estimate(t(300, 220, 20, 20), 320, 240).is_finite());
        assert_eq!(map.estimate(t(0, 0, 10, 10), 0, 0), 0.0);
    }
}

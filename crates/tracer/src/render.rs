//! Tiles and frames: [`render_tile`] is the unit of work the cluster hands out;
//! [`render_frame`] renders a whole image on a rayon thread pool.
//!
//! OWNER: shading helper.

use crate::cameras::Camera;
use crate::scene::Scene;
use serde::{Deserialize, Serialize};

/// How to render: resolution, sampling and recursion limits.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RenderSettings {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Camera samples per pixel (stratified, jittered).
    pub spp: u32,
    /// Shadow rays per area light per shading point (stratified over the light).
    pub light_samples: u32,
    /// Maximum recursion depth for mirror and refraction rays.
    pub max_depth: u32,
    /// Seed mixed into every sample's hash.
    pub seed: u64,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self { width: 640, height: 480, spp: 1, light_samples: 4, max_depth: 6, seed: 0 }
    }
}

/// A rectangle of pixels, `x..x+w` × `y..y+h`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Tile {
    /// Left column.
    pub x: u32,
    /// Top row.
    pub y: u32,
    /// Width in pixels.
    pub w: u32,
    /// Height in pixels.
    pub h: u32,
}

impl Tile {
    /// Splits a `width × height` image into tiles of at most `size × size`,
    /// row by row.
    pub fn grid(width: u32, height: u32, size: u32) -> Vec<Tile> {
        let size = size.max(1);
        let mut tiles = Vec::new();
        for y in (0..height).step_by(size as usize) {
            for x in (0..width).step_by(size as usize) {
                tiles.push(Tile { x, y, w: size.min(width - x), h: size.min(height - y) });
            }
        }
        tiles
    }

    /// Number of pixels.
    pub fn pixel_count(&self) -> usize {
        self.w as usize * self.h as usize
    }
}

/// A rendered image: sRGB-encoded RGB8, row-major, 3 bytes per pixel.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Frame {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width * height * 3` bytes.
    pub rgb: Vec<u8>,
}

impl Frame {
    /// A black frame.
    pub fn new(width: u32, height: u32) -> Self {
        Self { width, height, rgb: vec![0; width as usize * height as usize * 3] }
    }

    /// Copies a tile's pixels (as returned by [`render_tile`]) into place.
    pub fn blit(&mut self, tile: Tile, rgb: &[u8]) {
        let row = tile.w as usize * 3;
        for j in 0..tile.h as usize {
            let dst = ((tile.y as usize + j) * self.width as usize + tile.x as usize) * 3;
            self.rgb[dst..dst + row].copy_from_slice(&rgb[j * row..(j + 1) * row]);
        }
    }
}

/// Renders the pixels of `tile` (which must lie inside the `settings` image):
/// `tile.w * tile.h * 3` bytes of sRGB RGB8, row-major. Bit-identical for a
/// pixel whatever the tiling, thread or machine.
pub fn render_tile(scene: &Scene, camera: &Camera, settings: &RenderSettings, tile: Tile) -> Vec<u8> {
    let _ = (scene, camera, settings, tile);
    todo!("shading helper")
}

/// Renders a whole frame, tiles spread over the current rayon pool; `progress`
/// is called with the number of pixels finished after each tile.
pub fn render_frame(
    scene: &Scene,
    camera: &Camera,
    settings: &RenderSettings,
    tile_size: u32,
    progress: &(dyn Fn(u64) + Sync),
) -> Frame {
    let _ = (scene, camera, settings, tile_size, progress);
    todo!("shading helper")
}

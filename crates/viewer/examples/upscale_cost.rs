//! What enlarging a low-resolution moving frame costs the viewer: every tile
//! of a 640 × 480 image rendered at 1/2 … 1/8 goes through
//! `Accumulator::add_tile_of` (bilinear, filtered across tile borders), and
//! the time per frame is printed next to a full-resolution frame's
//! `add_tile`.
//!
//! `cargo run --release -p isin-viewer --example upscale_cost`

use isin_tracer::Tile;
use isin_viewer::Divisor;
use isin_viewer::accumulate::Accumulator;
use std::time::Instant;

fn main() {
    let (w, h) = (640u32, 480u32);
    let mut acc = Accumulator::new(w, h);
    let rounds = 50u32;
    for d in [1u32, 2, 3, 4, 6, 8] {
        let (lw, lh) = Divisor::whole(d).apply(w, h);
        let tiles = Tile::grid(lw, lh, 32);
        let payload: Vec<Vec<u8>> =
            tiles.iter().map(|t| (0..t.pixel_count() * 3).map(|i| (i * 7 % 251) as u8).collect()).collect();
        let t0 = Instant::now();
        for round in 0..rounds {
            for (t, rgb) in tiles.iter().zip(&payload) {
                acc.add_tile_of(round + 10 * d, 1.0, *t, rgb, (lw, lh)).expect("tiles fit");
            }
        }
        let ms = t0.elapsed().as_secs_f64() * 1e3 / rounds as f64;
        println!("1/{d} ({lw}x{lh}, {} tiles): {ms:.2} ms per frame to show at {w}x{h}", tiles.len());
    }
}

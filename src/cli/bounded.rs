//! Command-line parsers that hold options to the bounds of
//! `isin_tracer::limits` — the same bounds the scene loader, the master and
//! the slave check — so an out-of-range option is refused before any work,
//! naming the limit and why.

use isin_tracer::limits;

/// Pixels on a side of the image.
pub fn side(s: &str) -> Result<u32, String> {
    limits::IMAGE_SIDE.parse(s).map(|v| v as u32)
}

/// Samples per pixel.
pub fn spp(s: &str) -> Result<u32, String> {
    limits::SPP.parse(s).map(|v| v as u32)
}

/// Render threads (0: one per core, for every command).
pub fn threads(s: &str) -> Result<usize, String> {
    limits::THREADS.parse(s).map(|v| v as usize)
}

/// Tile edge.
pub fn tile(s: &str) -> Result<u32, String> {
    limits::TILE.parse(s).map(|v| v as u32)
}

/// Tiles queued per slave beyond its threads.
pub fn queue_depth(s: &str) -> Result<u32, String> {
    limits::QUEUE_DEPTH.parse(s).map(|v| v as u32)
}

/// Heartbeat timeout in milliseconds.
pub fn heartbeat_ms(s: &str) -> Result<u64, String> {
    limits::HEARTBEAT_TIMEOUT_MS.parse(s)
}

/// A cluster client's `--timeout` in seconds.
pub fn timeout(s: &str) -> Result<u64, String> {
    limits::CLIENT_TIMEOUT_S.parse(s)
}

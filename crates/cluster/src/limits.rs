//! What the master accepts, and how much of it: frame requests' bounds and
//! the budgets every peer lives within, each with the reason for its value.
//!
//! The request limits bound the work one request can ask for; the budgets
//! bound what peers can make the master hold. Both are checked before any
//! work or allocation starts.

use crate::codec;
use crate::protocol::HANDSHAKE_MAX_FRAME;
use isin_tracer::{Camera, RenderSettings};

/// Largest image a viewer may request, in pixels per side (a 16k² frame is
/// 768 MiB of RGB8 at the viewer: beyond that a request is a mistake).
pub const MAX_IMAGE_SIDE: u32 = 16384;
/// Largest samples per pixel a viewer may request (the viewer's refinement
/// stops at 64; stills rarely need more than a few thousand).
pub const MAX_SPP: u32 = 65536;
/// Largest shadow-ray count per area light a viewer may request.
pub const MAX_LIGHT_SAMPLES: u32 = 4096;
/// Largest recursion depth a viewer may request (a mirror hall needs a few
/// dozen bounces; the tracer stops far earlier in any real scene).
pub const MAX_DEPTH: u32 = 64;

/// Bytes of a tile message besides its pixels: ids, rectangle, timings and
/// MessagePack framing take under a hundred; this leaves room for an error
/// message of a slave's.
pub const TILE_MESSAGE_OVERHEAD: usize = 4 << 10;

/// Largest frame a logged-in viewer may send: its messages are frame requests
/// (a camera and settings, ~200 bytes) and heartbeats.
pub const VIEWER_MAX_FRAME: usize = 16 << 10;

/// How much each peer, and all peers together, may make the master hold.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Budgets {
    /// Peers connected at once, of every role and state. A thousand slaves
    /// plus viewers fit; a connection beyond it is refused at once.
    pub max_peers: usize,
    /// Peers connected but not yet authenticated. Each holds little (a nonce,
    /// a [`HANDSHAKE_MAX_FRAME`] read buffer) but costs a TLS handshake; a
    /// flood of them is refused rather than queued.
    pub max_handshaking: usize,
    /// Bytes all connections together may hold in frames still being read
    /// (announced, not yet complete). A connection whose next frame would
    /// exceed it is closed, never waited for. The transport enforces it.
    pub buffered_bytes: usize,
    /// Results for tiles a slave was never handed, tolerated before it is
    /// disconnected (an honest slave sends none; a few could only come from a
    /// bug, not a race).
    pub foreign_results: u32,
}

impl Default for Budgets {
    fn default() -> Self {
        Self { max_peers: 2048, max_handshaking: 128, buffered_bytes: 256 << 20, foreign_results: 8 }
    }
}

/// Largest frame a logged-in slave may send when tiles are at most `edge`
/// pixels on a side: one tile's encoded bytes at worst, plus its message.
pub fn slave_max_frame(edge: u32) -> usize {
    (TILE_MESSAGE_OVERHEAD + codec::max_encoded_len(edge, edge)).max(HANDSHAKE_MAX_FRAME)
}

/// Checks a frame request against the limits above and the camera's own
/// validity.
pub fn validate_request(camera: &Camera, s: &RenderSettings) -> Result<(), String> {
    camera.validate().map_err(|e| format!("bad camera: {e}"))?;
    if s.width == 0 || s.height == 0 || s.width > MAX_IMAGE_SIDE || s.height > MAX_IMAGE_SIDE {
        return Err(format!("image size {}x{} out of range 1..={MAX_IMAGE_SIDE}", s.width, s.height));
    }
    if s.spp == 0 || s.spp > MAX_SPP {
        return Err(format!("samples per pixel {} out of range 1..={MAX_SPP}", s.spp));
    }
    if s.light_samples > MAX_LIGHT_SAMPLES || s.max_depth > MAX_DEPTH {
        return Err(format!(
            "light samples {} / depth {} above the limits {MAX_LIGHT_SAMPLES} / {MAX_DEPTH}",
            s.light_samples, s.max_depth
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_slave_frame_holds_its_largest_tile_and_little_more() {
        let n = slave_max_frame(32);
        assert!(n >= 32 * 32 * 4 + 22, "{n}");
        assert!(n < 64 << 10, "{n}");
        assert!(slave_max_frame(256) > 256 * 256 * 4);
    }

    #[test]
    fn requests_beyond_the_limits_are_refused_with_the_limit_named() {
        let cam = Camera::default();
        let ok = RenderSettings { width: 64, height: 48, ..RenderSettings::default() };
        assert!(validate_request(&cam, &ok).is_ok());
        let wide = RenderSettings { width: MAX_IMAGE_SIDE + 1, ..ok };
        assert!(validate_request(&cam, &wide).unwrap_err().contains("16384"));
        let spp = RenderSettings { spp: 0, ..ok };
        assert!(validate_request(&cam, &spp).unwrap_err().contains("samples per pixel"));
        let deep = RenderSettings { max_depth: MAX_DEPTH + 1, ..ok };
        assert!(validate_request(&cam, &deep).unwrap_err().contains("depth"));
    }
}

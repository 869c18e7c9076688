//! What the master accepts, and how much of it: the bounds of every number
//! (the tracer's table, [`isin_tracer::limits`], re-exported here: the same
//! for the command line, scene files, the master and the slave) and the
//! budgets every peer lives within, each with the reason for its value.
//!
//! The bounds limit the work one request can ask for; the budgets limit what
//! peers can make the master hold. Both are checked before any work or
//! allocation starts.

use crate::codec;
use crate::protocol::HANDSHAKE_MAX_FRAME;
use isin_tracer::{Camera, RenderSettings};

pub use isin_tracer::limits::*;

/// Bytes of a tile message besides its pixels: ids, rectangle, timings and
/// MessagePack framing take under a hundred; this leaves room for an error
/// message of a slave's.
pub const TILE_MESSAGE_OVERHEAD: usize = 4 << 10;

/// Largest frame a logged-in viewer may send: its messages are frame requests
/// (a camera and settings, ~200 bytes), job descriptions and heartbeats. A
/// scene it uploads is the exception: announced first, its chunks come in
/// frames of up to [`SCENE_CHUNK_FRAME`].
pub const VIEWER_MAX_FRAME: usize = 16 << 10;

/// Largest frame of a scene chunk: [`SCENE_CHUNK_BYTES`] and its message.
pub const SCENE_CHUNK_FRAME: usize = SCENE_CHUNK_BYTES + TILE_MESSAGE_OVERHEAD;

/// Bytes of the compressed scene stream per [`crate::protocol::Message::SceneChunk`]:
/// large enough that a chunk's message overhead is noise, small enough that a
/// window of them in flight is a few megabytes per slave.
pub const SCENE_CHUNK_BYTES: usize = 256 << 10;

/// Largest scene bundle, encoded and decompressed, that a slave (or the
/// master, reading its state directory) accepts: a receiver refuses a
/// [`crate::protocol::SceneHeader`] declaring more before it holds a byte.
/// Four times the largest frame of protocol 6's one-message scenes.
pub const MAX_SCENE_RAW_BYTES: u64 = 2 << 30;

/// Largest compressed scene stream accepted (zstd never expands a stream by
/// more than a little; this leaves room for incompressible assets).
pub const MAX_SCENE_COMPRESSED_BYTES: u64 = MAX_SCENE_RAW_BYTES + (MAX_SCENE_RAW_BYTES >> 7) + (1 << 20);

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
    /// Bytes of scenes the master holds (packed as slaves receive them,
    /// compressed: its default scene and those clients uploaded). Idle scenes are evicted to make room;
    /// scenes of open frames never are.
    pub scene_bytes: usize,
    /// Largest scene one client may upload (its bundle's bytes, unpacked).
    pub scene_upload_bytes: usize,
    /// Bytes of scenes all clients together may be uploading at once (as
    /// their headers declare them, unpacked): what partial uploads may make
    /// the master hold. An upload beyond it is refused until others finish.
    pub uploading_bytes: usize,
    /// Scenes sent to one slave connection: one per scene it is handed tiles
    /// of, again only if it evicted one. Far above what an honest slave asks.
    pub scene_sends: u32,
    /// Batch jobs the master remembers (running, or waiting for their client
    /// to return); the oldest one nobody runs is forgotten first.
    pub max_jobs: usize,
}

impl Default for Budgets {
    fn default() -> Self {
        Self {
            max_peers: 2048,
            max_handshaking: 128,
            buffered_bytes: 256 << 20,
            foreign_results: 8,
            scene_bytes: 2 << 30,
            scene_upload_bytes: 192 << 20,
            uploading_bytes: 512 << 20,
            scene_sends: 256,
            max_jobs: 256,
        }
    }
}

/// Largest frame a logged-in slave may send when tiles are at most `edge`
/// pixels on a side: one tile's encoded bytes at worst, plus its message.
pub fn slave_max_frame(edge: u32) -> usize {
    (TILE_MESSAGE_OVERHEAD + codec::max_encoded_len(edge, edge)).max(HANDSHAKE_MAX_FRAME)
}

/// Checks a frame request against the bounds and the camera's own validity.
pub fn validate_request(camera: &Camera, s: &RenderSettings) -> Result<(), String> {
    camera.validate().map_err(|e| format!("bad camera: {e}"))?;
    check_settings(s).map_err(|e| e.to_string())
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
        let wide = RenderSettings { width: IMAGE_SIDE.max as u32 + 1, ..ok };
        assert!(validate_request(&cam, &wide).unwrap_err().contains("16384"));
        let spp = RenderSettings { spp: 0, ..ok };
        assert!(validate_request(&cam, &spp).unwrap_err().contains("samples per pixel"));
        let deep = RenderSettings { max_depth: DEPTH.max as u32 + 1, ..ok };
        assert!(validate_request(&cam, &deep).unwrap_err().contains("depth"));
    }
}

//! What goes on the QUIC streams, and which frames may overtake which.
//!
//! A connection has one long-lived bidirectional **control stream** (opened by
//! the client, which first writes [`PREAMBLE`]) carrying *ordered* frames in
//! send order, and one short **unidirectional stream per independent frame**.
//!
//! Control stream records:
//! - frame: `[0u8][indep_before: u64 BE][len: u32 BE][len bytes]`
//! - end:   `[1u8][indep_total: u64 BE]`, then the stream finishes.
//!
//! Frame stream: `[ordered_before: u64 BE][len: u32 BE][len bytes]`, then the
//! stream finishes.
//!
//! `indep_before` / `ordered_before` count the frames of the *other* kind sent
//! before this one. The receiver delivers a frame only once everything it
//! depends on has been delivered:
//! - an ordered frame waits for every frame sent before it (both kinds);
//! - an independent frame waits for the ordered frames sent before it, but not
//!   for other independent frames: tiles overtake each other freely, and a
//!   lost packet delays only the tile it belonged to.
//!
//! So the only reordering the application can observe is among independent
//! frames sent since the last ordered one. Which frames are independent is the
//! [`Classifier`]'s decision; [`protocol_classifier`] marks isin's tile
//! messages (`TileResult`, `FrameTile`) and nothing else.

use isin_cluster::protocol::{self, FrameTile, Message, TileResult};
use isin_tracer::Tile;
use std::sync::OnceLock;

/// First bytes the client writes on the control stream (makes the stream
/// visible to the server and names the framing version).
pub const PREAMBLE: &[u8; 8] = b"isinQ\x00\x00\x01";

/// Tag of a frame record on the control stream.
pub const TAG_FRAME: u8 = 0;
/// Tag of the end record on the control stream.
pub const TAG_END: u8 = 1;
/// Bytes of a control frame record before the payload.
pub const CONTROL_HEADER: usize = 1 + 8 + 4;
/// Bytes of the end record.
pub const END_RECORD: usize = 1 + 8;
/// Bytes of a frame stream before the payload.
pub const STREAM_HEADER: usize = 8 + 4;

/// How a frame travels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Delivery {
    /// On the control stream, never overtaking nor overtaken by anything sent before it.
    Ordered,
    /// On its own stream; may overtake other independent frames.
    Independent,
}

/// Decides how each outgoing frame travels.
pub type Classifier = fn(&[u8]) -> Delivery;

/// Every frame ordered: one stream, TCP-like delivery.
pub fn all_ordered(_: &[u8]) -> Delivery {
    Delivery::Ordered
}

/// isin's protocol: tile payloads (`TileResult` from slaves, `FrameTile` to
/// viewers) are independent, every other message is ordered.
///
/// Both tile messages may overtake only each other: a tile still never arrives
/// before the `Ready`/`FrameRequest` that preceded it, nor after the
/// `FrameDone` that follows it.
pub fn protocol_classifier(frame: &[u8]) -> Delivery {
    let prefixes = tile_prefixes();
    if prefixes.iter().any(|p| frame.starts_with(p)) { Delivery::Independent } else { Delivery::Ordered }
}

/// The encoded prefixes shared by every `TileResult` and every `FrameTile`
/// frame, learnt from the protocol's own encoder (the common prefix of two
/// messages of the kind that differ in their first field), so that a change of
/// encoding cannot silently break the classification.
fn tile_prefixes() -> &'static [Vec<u8>] {
    static PREFIXES: OnceLock<Vec<Vec<u8>>> = OnceLock::new();
    PREFIXES.get_or_init(|| {
        let result = |frame| {
            Message::TileResult(TileResult {
                frame,
                id: 0,
                tile: Tile { x: 0, y: 0, w: 1, h: 1 },
                render_micros: 0,
                codec: Default::default(),
                pixels: Default::default(),
            })
        };
        let tile = |request| {
            Message::FrameTile(FrameTile {
                request,
                slave: 0,
                slave_name: String::new(),
                tile: Tile { x: 0, y: 0, w: 1, h: 1 },
                codec: Default::default(),
                pixels: Default::default(),
            })
        };
        [(result(1), result(2)), (tile(1), tile(2))]
            .iter()
            .filter_map(|(a, b)| {
                let (a, b) = (protocol::encode(a).ok()?, protocol::encode(b).ok()?);
                let n = a.iter().zip(&b).take_while(|(x, y)| x == y).count();
                // Version prefix plus at least a tag byte, or the rule is useless.
                (n > 3).then(|| a[..n].to_vec())
            })
            .collect()
    })
}

/// The header of a frame record on the control stream.
pub fn control_header(indep_before: u64, len: u32) -> [u8; CONTROL_HEADER] {
    let mut h = [0u8; CONTROL_HEADER];
    h[0] = TAG_FRAME;
    h[1..9].copy_from_slice(&indep_before.to_be_bytes());
    h[9..13].copy_from_slice(&len.to_be_bytes());
    h
}

/// The end record of the control stream.
pub fn end_record(indep_total: u64) -> [u8; END_RECORD] {
    let mut h = [0u8; END_RECORD];
    h[0] = TAG_END;
    h[1..9].copy_from_slice(&indep_total.to_be_bytes());
    h
}

/// The header of a frame stream.
pub fn stream_header(ordered_before: u64, len: u32) -> [u8; STREAM_HEADER] {
    let mut h = [0u8; STREAM_HEADER];
    h[..8].copy_from_slice(&ordered_before.to_be_bytes());
    h[8..].copy_from_slice(&len.to_be_bytes());
    h
}

/// Splits a frame stream header into `(ordered_before, len)`.
pub fn parse_stream_header(h: &[u8; STREAM_HEADER]) -> (u64, u32) {
    let mut a = [0u8; 8];
    a.copy_from_slice(&h[..8]);
    let mut b = [0u8; 4];
    b.copy_from_slice(&h[8..]);
    (u64::from_be_bytes(a), u32::from_be_bytes(b))
}

#[cfg(test)]
mod tests {
    use super::*;
    use isin_cluster::protocol::{FrameStats, Hello, Role};
    use isin_tracer::{Camera, RenderSettings};
    use serde_bytes::ByteBuf;

    #[test]
    fn tiles_are_independent_and_everything_else_is_ordered() {
        let independent = [
            Message::TileResult(TileResult {
                frame: 77,
                id: 123_456,
                tile: Tile { x: 64, y: 0, w: 64, h: 64 },
                render_micros: 9,
                codec: isin_cluster::codec::Codec::Qoi,
                pixels: ByteBuf::from(vec![1u8; 12_288]),
            }),
            Message::FrameTile(FrameTile {
                request: u64::MAX,
                slave: u64::MAX,
                slave_name: "TileResult#9".into(),
                tile: Tile { x: 64, y: 128, w: 64, h: 64 },
                codec: isin_cluster::codec::Codec::Lz4,
                pixels: ByteBuf::from(vec![2u8; 12_288]),
            }),
        ];
        let ordered = [
            Message::Heartbeat,
            Message::Challenge { nonce: [0; 32] },
            Message::Hello(Hello {
                role: Role::Slave,
                name: "TileResult".into(),
                threads: 1,
                client_nonce: [0; 32],
                proof: [0; 32],
                cached_scene: None,
                codecs: isin_cluster::codec::offer(),
                work: Default::default(),
            }),
            Message::Ready { hash: [0; 32] },
            Message::Cancel { frame: 1, tiles: vec![1] },
            Message::FrameDone { request: 1, stats: FrameStats::default() },
            Message::FrameRequest {
                request: 1,
                camera: Camera::default(),
                settings: RenderSettings::default(),
            },
            Message::Error { message: "FrameTile".into() },
        ];
        for m in &independent {
            assert_eq!(
                protocol_classifier(&protocol::encode(m).unwrap()),
                Delivery::Independent,
                "{}",
                m.kind()
            );
        }
        for m in &ordered {
            assert_eq!(protocol_classifier(&protocol::encode(m).unwrap()), Delivery::Ordered, "{}", m.kind());
        }
        assert_eq!(protocol_classifier(&[]), Delivery::Ordered);
        assert_eq!(tile_prefixes().len(), 2);
    }

    #[test]
    fn headers_round_trip() {
        let h = stream_header(u64::MAX - 3, 70_000);
        assert_eq!(parse_stream_header(&h), (u64::MAX - 3, 70_000));
        let c = control_header(5, 9);
        assert_eq!(c[0], TAG_FRAME);
        assert_eq!(end_record(3)[0], TAG_END);
    }
}

//! The tile messages read and written in place: a [`TileResult`] whose
//! pixels stay in the frame they arrived in, a [`FrameTile`] written
//! straight into its outgoing frame, and a [`TileAssignment`] whose frame,
//! scene, camera and settings are encoded once per frame
//! ([`AssignmentHead`]), not once per assignment.
//!
//! A tile's pixels are most of the master's traffic. Read through
//! [`decode`](super::decode) they are copied into a `ByteBuf`, and the
//! `FrameTile` built from them is written out through a growing buffer;
//! [`TileResultRef`] borrows them from the frame instead, and
//! [`encode_frame_tile`] writes one exactly-sized buffer. Both speak the
//! same bytes as [`Message::TileResult`] and [`Message::FrameTile`] (rmp-serde
//! writes an enum variant as a one-entry map from its name; structs as
//! arrays of their fields in order), which the tests check both ways.
//!
//! [`TileResult`]: super::TileResult
//! [`FrameTile`]: super::FrameTile
//! [`TileAssignment`]: super::TileAssignment
//! [`Message::TileResult`]: super::Message::TileResult
//! [`Message::FrameTile`]: super::Message::FrameTile

use super::{
    DirectRoute, FrameId, Message, PROTOCOL_VERSION, ProtocolError, SceneHash, TileAssignment, TileId,
    TileJob, TileResult,
};
use crate::codec::Codec;
use isin_tracer::{Camera, RenderSettings, Tile};
use serde::{Deserialize, Serialize};

/// A [`TileResult`] whose pixels are borrowed from the frame it was read from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
pub struct TileResultRef<'a> {
    /// The frame it belongs to.
    pub frame: FrameId,
    /// The tile's id.
    pub id: TileId,
    /// The tile's rectangle.
    pub tile: Tile,
    /// Time spent rendering it, in microseconds (see [`TileResult::render_micros`]).
    pub render_micros: u64,
    /// How `pixels` is encoded.
    pub codec: Codec,
    /// The encoded pixels, in the frame.
    #[serde(borrow, with = "serde_bytes")]
    pub pixels: &'a [u8],
}

impl TileResult {
    /// The message with its pixels borrowed.
    pub fn borrowed(&self) -> TileResultRef<'_> {
        TileResultRef {
            frame: self.frame,
            id: self.id,
            tile: self.tile,
            render_micros: self.render_micros,
            codec: self.codec,
            pixels: &self.pixels,
        }
    }
}

impl TileResultRef<'_> {
    /// The owned message.
    pub fn owned(&self) -> TileResult {
        TileResult {
            frame: self.frame,
            id: self.id,
            tile: self.tile,
            render_micros: self.render_micros,
            codec: self.codec,
            pixels: serde_bytes::ByteBuf::from(self.pixels),
        }
    }
}

/// The only variant this module reads: a body of another kind fails to
/// decode as it (an unknown variant) without being looked at further.
#[derive(Deserialize)]
enum TileResultOnly<'a> {
    #[serde(borrow)]
    TileResult(TileResultRef<'a>),
}

/// The start of every `TileResult` body: a one-entry map (`0x81`) whose key
/// is the ten-byte string (`0xaa`) "TileResult".
const TILE_RESULT_TAG: &[u8] = b"\x81\xaaTileResult";

/// Reads `frame` as a [`TileResultRef`] if it is one: `None` for a frame of
/// another message kind (to be read with [`decode`](super::decode)); an
/// error for a frame that says it is a `TileResult` but is not a valid one,
/// or is longer than `max`. Never panics.
pub fn decode_tile_result(frame: &[u8], max: usize) -> Option<Result<TileResultRef<'_>, ProtocolError>> {
    let body = frame.strip_prefix(&PROTOCOL_VERSION.to_be_bytes()[..])?;
    if !body.starts_with(TILE_RESULT_TAG) {
        return None;
    }
    if frame.len() > max {
        return Some(Err(ProtocolError::TooLarge { len: frame.len(), max }));
    }
    let mut de = rmp_serde::Deserializer::from_read_ref(body);
    let read = match TileResultOnly::deserialize(&mut de) {
        Ok(TileResultOnly::TileResult(r)) => r,
        Err(e) => return Some(Err(ProtocolError::Decode(e.to_string()))),
    };
    // The pixels are the body's last field: what follows them is trailing.
    let end = read.pixels.as_ptr() as usize + read.pixels.len();
    let rest = (body.as_ptr() as usize + body.len()).saturating_sub(end);
    if rest != 0 {
        return Some(Err(ProtocolError::Decode(format!("{rest} trailing bytes after the message"))));
    }
    Some(Ok(read))
}

/// A [`FrameTile`](super::FrameTile) as written: the same fields, borrowed.
#[derive(Serialize)]
struct FrameTileRef<'a> {
    request: u64,
    slave: u64,
    slave_name: &'a str,
    tile: Tile,
    codec: Codec,
    #[serde(with = "serde_bytes")]
    pixels: &'a [u8],
}

#[derive(Serialize)]
enum FrameTileOnly<'a> {
    FrameTile(FrameTileRef<'a>),
}

/// The wire frame of a [`Message::FrameTile`](super::Message::FrameTile)
/// with these fields, written into one buffer of its final size.
pub fn encode_frame_tile(
    request: u64,
    slave: u64,
    slave_name: &str,
    tile: Tile,
    codec: Codec,
    pixels: &[u8],
) -> Result<Vec<u8>, ProtocolError> {
    // Version, the map and variant name, five small fields, the name and
    // the binary's header: well under 96 bytes besides the two strings.
    let mut buf = Vec::with_capacity(96 + slave_name.len() + pixels.len());
    buf.extend_from_slice(&PROTOCOL_VERSION.to_be_bytes());
    let message = FrameTileOnly::FrameTile(FrameTileRef { request, slave, slave_name, tile, codec, pixels });
    rmp_serde::encode::write(&mut buf, &message).map_err(|e| ProtocolError::Encode(e.to_string()))?;
    Ok(buf)
}

/// The wire bytes every [`TileAssignment`] of one frame starts with: the
/// version, the variant, and the frame, scene, camera and settings fields
/// (the master hands out a frame's tiles in hundreds of assignments).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AssignmentHead(Vec<u8>);

impl AssignmentHead {
    /// The head of `frame`'s assignments.
    pub fn new(
        frame: FrameId,
        scene: SceneHash,
        camera: Camera,
        settings: RenderSettings,
    ) -> Result<Self, ProtocolError> {
        let empty = TileAssignment { frame, scene, camera, settings, tiles: Vec::new(), direct: None };
        let whole = super::encode(&Message::TileAssignment(empty))?;
        // The last two fields, an empty list and no route, end it.
        match whole.strip_suffix(&[0x90, 0xc0]) {
            Some(head) => Ok(Self(head.to_vec())),
            None => Err(ProtocolError::Encode("a TileAssignment that does not end in its tiles".into())),
        }
    }
}

/// The wire frame of the [`Message::TileAssignment`] of `head`'s frame with
/// these tiles and route: the head's bytes, then the two fields.
pub fn encode_assignment(
    head: &AssignmentHead,
    tiles: &[TileJob],
    direct: Option<&DirectRoute>,
) -> Result<Vec<u8>, ProtocolError> {
    let route = direct.map_or(1, |d| 64 + d.via_master.len() * 5);
    let mut buf = Vec::with_capacity(head.0.len() + 4 + tiles.len() * 24 + route);
    buf.extend_from_slice(&head.0);
    let encode = |e: rmp_serde::encode::Error| ProtocolError::Encode(e.to_string());
    rmp_serde::encode::write(&mut buf, tiles).map_err(encode)?;
    rmp_serde::encode::write(&mut buf, &direct).map_err(encode)?;
    Ok(buf)
}

#[cfg(test)]
mod tests {
    use super::super::{DirectOffer, FrameTile, decode, encode};
    use super::*;
    use serde_bytes::ByteBuf;

    fn result(codec: Codec, pixels: Vec<u8>) -> TileResult {
        TileResult {
            frame: 7,
            id: u32::MAX - 3,
            tile: Tile { x: 16, y: 32, w: 4, h: 2 },
            render_micros: 1234,
            codec,
            pixels: ByteBuf::from(pixels),
        }
    }

    #[test]
    fn a_tile_result_reads_in_place_as_it_reads_owned() {
        for (codec, pixels) in
            [(Codec::Raw, vec![9u8; 24]), (Codec::Lz4, vec![1, 2, 3]), (Codec::Qoi, vec![])]
        {
            let owned = result(codec, pixels);
            let frame = encode(&Message::TileResult(owned.clone())).unwrap();
            let read = decode_tile_result(&frame, frame.len()).expect("a TileResult").unwrap();
            assert_eq!(read.owned(), owned);
            // The pixels are the frame's own bytes, not a copy.
            let range = frame.as_ptr_range();
            assert!(read.pixels.is_empty() || range.contains(&read.pixels.as_ptr()));
        }
    }

    #[test]
    fn other_messages_are_left_to_the_full_decoder() {
        for m in [
            Message::Heartbeat,
            Message::Ready { hash: None },
            Message::Reject { reason: "TileResult".into() },
        ] {
            let frame = encode(&m).unwrap();
            assert!(decode_tile_result(&frame, frame.len()).is_none(), "{m:?}");
        }
        assert!(decode_tile_result(&[], 100).is_none());
        // Another protocol version is the full decoder's to explain.
        let mut frame = encode(&Message::TileResult(result(Codec::Raw, vec![0; 24]))).unwrap();
        frame[1] ^= 1;
        assert!(decode_tile_result(&frame, frame.len()).is_none());
    }

    #[test]
    fn a_broken_or_oversized_tile_result_is_an_error() {
        let frame = encode(&Message::TileResult(result(Codec::Raw, vec![0; 24]))).unwrap();
        assert!(matches!(
            decode_tile_result(&frame, frame.len() - 1),
            Some(Err(ProtocolError::TooLarge { .. }))
        ));
        for cut in [TILE_RESULT_TAG.len() + 2, frame.len() - 1] {
            let r = decode_tile_result(&frame[..cut], frame.len());
            assert!(matches!(r, Some(Err(ProtocolError::Decode(_)))), "cut at {cut}: {r:?}");
            assert!(decode(&frame[..cut], frame.len()).is_err());
        }
        let mut longer = frame.clone();
        longer.push(0);
        assert!(matches!(decode_tile_result(&longer, longer.len()), Some(Err(ProtocolError::Decode(_)))));
        assert!(decode(&longer, longer.len()).is_err());
        // A binary that claims more bytes than the frame holds.
        let at = frame.len() - 24 - 1;
        assert_eq!(frame[at], 24, "the binary's length byte");
        let mut lying = frame.clone();
        lying[at] = 200;
        assert!(matches!(decode_tile_result(&lying, lying.len()), Some(Err(ProtocolError::Decode(_)))));
    }

    #[test]
    fn an_assignment_from_its_frames_head_is_the_bytes_the_message_is() {
        let camera = Camera::default();
        let settings =
            RenderSettings { width: 640, height: 480, seed: u64::MAX - 5, ..RenderSettings::default() };
        let frame = 1 << 40;
        let head = AssignmentHead::new(frame, [7; 32], camera, settings).unwrap();
        let job = |id: u32| TileJob { id, tile: Tile { x: id * 32, y: 64, w: 32, h: 16 } };
        let offer = DirectOffer { addr: "10.0.0.1:7000".into(), fingerprint: None, key: [3; 32] };
        let routes = [
            None,
            Some(DirectRoute { viewer: 9, request: 300, offer: Some(offer), via_master: vec![1, 70_000] }),
            Some(DirectRoute { viewer: 9, request: 301, offer: None, via_master: vec![] }),
        ];
        for tiles in [vec![], vec![job(0)], (0..40).map(job).collect()] {
            for route in &routes {
                let whole = Message::TileAssignment(TileAssignment {
                    frame,
                    scene: [7; 32],
                    camera,
                    settings,
                    tiles: tiles.clone(),
                    direct: route.clone().map(Box::new),
                });
                let ours = encode_assignment(&head, &tiles, route.as_ref()).unwrap();
                assert_eq!(ours, encode(&whole).unwrap(), "{} tiles, route {route:?}", tiles.len());
                assert_eq!(decode(&ours, ours.len()).unwrap(), whole);
            }
        }
    }

    #[test]
    fn a_frame_tile_writes_the_bytes_the_message_does() {
        for (codec, pixels) in [(Codec::Raw, vec![5u8; 24]), (Codec::Qoi, vec![1; 300]), (Codec::Lz4, vec![])]
        {
            let tile = Tile { x: 1, y: 2, w: 4, h: 2 };
            let owned = FrameTile {
                request: 99,
                slave: 3,
                slave_name: "slave-ü".into(),
                tile,
                codec,
                pixels: ByteBuf::from(pixels.clone()),
            };
            let want = encode(&Message::FrameTile(owned)).unwrap();
            let got = encode_frame_tile(99, 3, "slave-ü", tile, codec, &pixels).unwrap();
            assert_eq!(got, want);
            assert!(got.capacity() >= got.len() && got.capacity() <= got.len() + 96, "one allocation");
        }
    }
}

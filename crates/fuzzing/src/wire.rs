//! Targets for what peers send: bytes off a socket, frames, messages, tiles,
//! and the join tickets users paste.

use crate::cluster::{Carried, Wire, core_config};
use arbitrary::Unstructured;
use isin_cluster::codec::{self, Codec};
use isin_cluster::protocol::{self, HANDSHAKE_MAX_FRAME, Message, ProtocolError};
use isin_cluster::{Cluster, PeerId};
use isin_transport::stream::{self, Counting};
use isin_transport::{ConnShared, Fingerprint, MemoryBudget, Ticket, TransportError, TransportKind};
use std::time::Duration;

/// How a byte stream ends, by the frame format alone.
#[derive(Debug, PartialEq, Eq)]
enum StreamEnd {
    /// Between two frames.
    Clean,
    /// A length prefix above the maximum.
    TooLarge(u64),
    /// Inside a length prefix, or inside the body of a frame of this length.
    Truncated(Option<u64>),
}

/// The frames of `stream` as `[len: u32 BE][len bytes]` read them, and how
/// the stream ends: the model the codec is checked against.
fn model_frames(mut stream: &[u8], max_frame: usize) -> (Vec<&[u8]>, StreamEnd) {
    let mut frames = Vec::new();
    loop {
        let Some((len, rest)) = stream.split_first_chunk::<4>() else {
            let end = if stream.is_empty() { StreamEnd::Clean } else { StreamEnd::Truncated(None) };
            return (frames, end);
        };
        let len = u64::from(u32::from_be_bytes(*len));
        if len > max_frame as u64 {
            return (frames, StreamEnd::TooLarge(len));
        }
        let Some((body, rest)) = rest.split_at_checked(len as usize) else {
            return (frames, StreamEnd::Truncated(Some(len)));
        };
        frames.push(body);
        stream = rest;
    }
}

/// The length-delimited stream codec (`isin_transport::stream`, what TCP and
/// TLS connections read frames with) over a byte stream: `[max frame: u16]
/// [budget in 256-byte units, 0 for none: u8][stream…]`. The frames it yields
/// must be the format's, it must end the way the format says (clean, too
/// large, truncated — or over the budget, which refuses a frame before it is
/// read), and the budget must be whole again once every frame is taken.
pub fn framing(data: &[u8]) {
    let [a, b, c, stream @ ..] = data else { return };
    let max_frame = usize::from(u16::from_be_bytes([*a, *b]));
    let budget = (*c != 0).then(|| MemoryBudget::new(usize::from(*c) * 256));
    let (want, want_end) = model_frames(stream, max_frame);
    thread_local! {
        // One runtime for every input: building one costs more than a run.
        static RUNTIME: tokio::runtime::Runtime =
            tokio::runtime::Builder::new_current_thread().enable_time().build().expect("a runtime");
    }
    let bytes = stream.to_vec();
    let (got, end, stats) = RUNTIME.with(|runtime| {
        runtime.block_on(async {
            let shared = ConnShared::new(max_frame);
            shared.set_budget(budget.clone());
            let reader = std::io::Cursor::new(bytes);
            let mut conn =
                stream::spawn_with(reader, tokio::io::sink(), "fuzz".into(), shared, Counting::Frames);
            let mut got = Vec::new();
            let mut end = None;
            while let Some(item) = conn.receiver.recv().await {
                match item {
                    Ok(frame) => got.push(frame),
                    Err(e) => {
                        end = Some(e);
                        break;
                    }
                }
            }
            if end.is_some() {
                assert!(conn.receiver.recv().await.is_none(), "an error is the connection's last item");
            }
            (got, end, conn.sender.stats())
        })
    });
    assert!(got.len() <= want.len() && got.iter().zip(&want).all(|(g, w)| g == w), "frames differ");
    match (&end, &want_end) {
        (None, StreamEnd::Clean) | (Some(TransportError::Io(_)), StreamEnd::Truncated(_)) => {
            assert_eq!(got.len(), want.len(), "frames lost before the end");
        }
        (Some(TransportError::FrameTooLarge { len, max }), StreamEnd::TooLarge(want_len)) => {
            assert_eq!(got.len(), want.len());
            assert_eq!((*len, *max), (*want_len, max_frame));
        }
        (Some(TransportError::OverBudget { len, .. }), end) => {
            let limit = budget.as_ref().map(|b| b.limit()).expect("over a budget there is none of");
            // The budget is reserved before the body is read: a frame cut
            // short can be refused too.
            let next = match (want.get(got.len()), end) {
                (Some(frame), _) => Some(frame.len() as u64),
                (None, StreamEnd::Truncated(announced)) => *announced,
                (None, _) => None,
            };
            assert_eq!(Some(*len), next, "refused a frame that is not the next one");
            // Only frames queued unread may hold the budget.
            assert!(*len > 0 && *len <= max_frame as u64 && limit > 0);
        }
        (end, want_end) => panic!("the stream ended with {end:?}, the format says {want_end:?}"),
    }
    let wire: u64 = got.iter().map(|f| 4 + f.len() as u64).sum();
    assert_eq!((stats.frames_received, stats.bytes_received), (got.len() as u64, wire), "counters");
    if let Some(b) = budget {
        assert_eq!(b.in_use(), 0, "reservations outlived their frames");
    }
}

/// Largest unpacked size the [`scene_stream`] target lets a header declare:
/// far below the real limit, so that a stream that unpacks to all of it
/// stays within the fuzzer's memory.
pub const SCENE_STREAM_MAX_RAW: u32 = 16 << 20;

/// A scene as a slave (or the master, from a client) receives it: a header
/// and its chunks into a [`Receiver`](isin_cluster::scene_stream::Receiver).
/// The input is the scene's hash (32 bytes), its declared unpacked size
/// (4 bytes, little-endian, at most [`SCENE_STREAM_MAX_RAW`]) and the
/// compressed stream, cut into chunks as a master cuts it. The receiver
/// refuses or unpacks without panicking, and a scene it unpacks is the one
/// its hash names.
pub fn scene_stream(data: &[u8]) {
    use isin_cluster::limits::SCENE_CHUNK_BYTES;
    use isin_cluster::protocol::SceneHeader;
    use isin_cluster::scene_stream::Receiver;
    let (Some(hash), Some(raw), Some(stream)) = (data.get(..32), data.get(32..36), data.get(36..)) else {
        return;
    };
    let (Ok(hash), Ok(raw)) = (<[u8; 32]>::try_from(hash), <[u8; 4]>::try_from(raw)) else { return };
    let raw = u32::from_le_bytes(raw);
    if raw > SCENE_STREAM_MAX_RAW {
        return;
    }
    let chunks = stream.len().div_ceil(SCENE_CHUNK_BYTES) as u32;
    let header = SceneHeader {
        hash,
        name: "fuzz.toml".into(),
        raw_bytes: u64::from(raw),
        compressed_bytes: stream.len() as u64,
        chunks,
    };
    let Ok(mut rx) = Receiver::new(header) else { return };
    for (i, chunk) in stream.chunks(SCENE_CHUNK_BYTES).enumerate() {
        if rx.push(&hash, i as u32, chunk).is_err() {
            return;
        }
    }
    if let Ok(bundle) = rx.finish() {
        assert_eq!(protocol::scene_hash(&bundle), hash, "an unpacked scene is its hash's");
    }
}

/// One protocol frame (`protocol::decode`, what every peer runs on every
/// frame it receives): a message decoded re-encodes to a frame that decodes
/// to the same message, the length limit is applied before anything else, and
/// the pixels a tile carries decode (or fail) without panicking.
pub fn message(data: &[u8]) {
    if !data.is_empty() {
        let short = protocol::decode(data, data.len() - 1);
        assert!(matches!(short, Err(ProtocolError::TooLarge { .. })), "{short:?}");
    }
    let Ok(msg) = protocol::decode(data, usize::MAX) else { return };
    let bytes = protocol::encode(&msg).expect("a decoded message encodes");
    let again = protocol::decode(&bytes, bytes.len()).expect("a re-encoded message decodes");
    assert_eq!(protocol::encode(&again).expect("encodes"), bytes, "the round trip changed the message");
    match &msg {
        Message::TileResult(r) => {
            let _ = r.decoded_pixels();
        }
        Message::FrameTile(t) => {
            let _ = t.decoded_pixels();
        }
        _ => {}
    }
}

/// The master's core as an unauthenticated peer meets it
/// (`Cluster::handle_connected` then `handle_frame`): several connections
/// send arbitrary frames, close, fail and let time pass. Without the token
/// nobody gets past the challenge: every peer hears only `Challenge` and
/// `Reject`, no limit is raised, no peer is spoken to once closed, and the
/// core counts exactly the connections still open.
pub fn handshake(data: &[u8]) {
    let mut u = Unstructured::new(data);
    let mut core = Cluster::new(core_config(4, 2)).expect("the scene encodes");
    let mut wire = Wire::default();
    let mut now = Duration::ZERO;
    let mut next: PeerId = 1;
    while !u.is_empty() {
        let Ok(op) = u.int_in_range(0..=4u8) else { break };
        let peer = u.int_in_range(1..=next).unwrap_or(1);
        match op {
            0 => {
                core.handle_connected(now, next, "fuzz");
                wire.connect(next);
                next += 1;
            }
            1 => {
                let len = u.arbitrary_len::<u8>().unwrap_or(0);
                let frame = u.bytes(len).unwrap_or_default();
                if frame.len() > HANDSHAKE_MAX_FRAME {
                    core.handle_transport_error(now, peer, "frame too large");
                } else {
                    core.handle_frame(now, peer, frame);
                }
            }
            2 => {
                now += Duration::from_millis(u64::from(u.arbitrary::<u16>().unwrap_or(0)) * 10);
                core.handle_timeout(now);
            }
            3 => {
                core.handle_closed(now, peer);
                wire.gone(peer);
            }
            _ => core.handle_transport_error(now, peer, "broken stream"),
        }
        while let Some(t) = core.poll_transmit() {
            match wire.carry(t) {
                Carried::Message(peer, msg) => assert!(
                    matches!(msg, Message::Challenge { .. } | Message::Reject { .. }),
                    "{} sent to peer {peer} without the token",
                    msg.kind()
                ),
                Carried::Limit(peer, max) => {
                    panic!("frame limit of peer {peer} raised to {max} without the token")
                }
                Carried::Closed(..) | Carried::Stored => {}
            }
        }
        assert_eq!(core.status().peers, wire.open(), "the core's peers are not the open connections");
    }
}

/// Tile checking and decoding (`codec::check`, what the master runs on
/// every slave's tile, and `codec::decode`, what the viewer runs on every
/// tile it is sent): `[codec: u8, high bit scales the size by 16][w: u8][h:
/// u8][bytes…]`. A tile that passes the check decodes; decoded pixels are
/// exactly `w × h × 3` bytes, re-encode within the codec's worst case, pass
/// the check and decode back to themselves; decoding into a used buffer
/// gives the same result.
pub fn tile_codec(data: &[u8]) {
    let [c, w, h, bytes @ ..] = data else { return };
    let codec = Codec::ALL[usize::from(*c & 0x7f) % Codec::ALL.len()];
    let scale = if *c & 0x80 != 0 { 16 } else { 1 };
    let (w, h) = (u32::from(*w) * scale, u32::from(*h) * scale);
    let checked = codec::check(codec, w, h, bytes);
    let decoded = codec::decode(codec, w, h, bytes);
    if checked.is_ok() {
        assert!(decoded.is_ok(), "{codec} passed the check but does not decode: {decoded:?}");
    }
    let mut reused = vec![0xa5; 77];
    let again = codec::decode_into(codec, w, h, bytes, &mut reused);
    assert_eq!(decoded.as_ref().err(), again.as_ref().err(), "decode and decode_into disagree");
    let Ok(pixels) = decoded else { return };
    assert_eq!(pixels, reused, "decode and decode_into disagree");
    assert_eq!(pixels.len(), w as usize * h as usize * 3);
    let encoded = codec::encode(codec, w, &pixels);
    assert!(encoded.len() <= codec::max_encoded_len(w, h), "{codec} exceeds its worst case");
    assert_eq!(codec::check(codec, w, h, &encoded), Ok(()), "{codec}: its own encoding fails the check");
    assert_eq!(codec::decode(codec, w, h, &encoded).as_ref(), Ok(&pixels), "{codec} round trip");
}

/// Join tickets, fingerprints and transport names (`FromStr`, what the
/// command line parses): whatever parses displays as text that parses back
/// to the same value and displays the same.
pub fn ticket(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else { return };
    if let Ok(t) = text.parse::<Ticket>() {
        let shown = t.to_string();
        let again: Ticket = shown.parse().expect("a ticket's own text parses");
        assert!(again == t, "`{text}` → `{shown}` → {again:?}");
        assert_eq!(again.to_string(), shown);
        assert_eq!(t.pinned().is_ok(), t.transport.is_encrypted());
        let _ = format!("{t:?}");
    }
    if let Ok(fp) = text.parse::<Fingerprint>() {
        assert_eq!(fp.to_string().parse::<Fingerprint>(), Ok(fp));
    }
    if let Ok(kind) = text.parse::<TransportKind>() {
        assert_eq!(kind.name(), text);
    }
}

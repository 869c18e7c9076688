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
//! sender's choice ([`isin_transport::Delivery`], given to
//! `FrameSender::send_as`); this crate never looks inside a frame.

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

    #[test]
    fn headers_round_trip() {
        let h = stream_header(u64::MAX - 3, 70_000);
        assert_eq!(parse_stream_header(&h), (u64::MAX - 3, 70_000));
        let c = control_header(5, 9);
        assert_eq!(c[0], TAG_FRAME);
        assert_eq!(end_record(3)[0], TAG_END);
    }
}

//! Lossless compression of tile pixels on the wire.
//!
//! A tile is `w * h * 3` bytes of RGB8. Its [`Codec`] is agreed at join: the
//! peer's `Hello` lists the codecs it can decode and encode, the master's
//! `Welcome` picks one ([`negotiate`]), and every `TileResult` / `FrameTile`
//! names the codec of its bytes. [`Codec::Raw`] is always available.
//!
//! The codecs were chosen by measuring real rendered tiles (bytes, and CPU time
//! to encode and decode): `examples/tile_codecs.rs` renders the shipped scenes
//! and prints the table that docs/performance-notes.md ("Tile compression")
//! quotes, against zstd levels 1–3, left-delta and median predictors before
//! LZ4 and zstd. [`Codec::Qoi`] (the
//! "Quite OK Image" format: runs, a 64-colour cache and small per-channel
//! differences, pure safe Rust) is the default: on 1-sample tiles it had the
//! best ratio of all (2.1–2.9×, vs 1.3–1.8× for LZ4 and 1.7–2.4× for zstd-3)
//! at the CPU cost of LZ4 (5–30 µs per tile to encode, a tenth of zstd's).
//! [`Codec::Lz4`] is the cheapest to decode; raw costs nothing at all.
//!
//! Decoding takes untrusted bytes: the decoded size is known from the tile
//! (`w * h * 3`), is checked against [`MAX_TILE_BYTES`] before anything is
//! allocated, and must come out exactly; every failure is a [`CodecError`],
//! never a panic.

use serde::{Deserialize, Serialize};

mod walk;

/// Largest decoded tile accepted, in bytes (a 1024 × 1024 tile).
pub const MAX_TILE_BYTES: usize = 1024 * 1024 * 3;

/// How a tile's pixels are encoded.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Codec {
    /// `w * h * 3` bytes of RGB8, row-major.
    #[default]
    Raw,
    /// LZ4 block of the raw bytes.
    Lz4,
    /// A QOI image (header, RGB, no alpha): see the [module docs](self).
    Qoi,
}

impl Codec {
    /// Every codec this build can encode and decode, best first (the order
    /// `auto` prefers).
    pub const ALL: [Codec; 3] = [Codec::Qoi, Codec::Lz4, Codec::Raw];

    /// The name used on the command line and in the [`Hello`](crate::protocol::Hello) offer.
    pub fn name(self) -> &'static str {
        match self {
            Codec::Raw => "raw",
            Codec::Lz4 => "lz4",
            Codec::Qoi => "qoi",
        }
    }

    /// The codec called `name`, if this build has it.
    pub fn from_name(name: &str) -> Option<Codec> {
        Codec::ALL.into_iter().find(|c| c.name() == name)
    }
}

impl std::fmt::Display for Codec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// What the master's `--compression` asks for.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Compression {
    /// The best codec the peer offers (the first of [`Codec::ALL`] it has).
    #[default]
    Auto,
    /// This codec when the peer offers it, raw otherwise.
    Use(Codec),
}

impl std::str::FromStr for Compression {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        if s == "auto" {
            return Ok(Compression::Auto);
        }
        Codec::from_name(s).map(Compression::Use).ok_or_else(|| {
            let names: Vec<&str> = Codec::ALL.iter().map(|c| c.name()).collect();
            format!("unknown compression `{s}` (available: auto, {})", names.join(", "))
        })
    }
}

/// The codec for a peer that offered `offered` (codec names; unknown ones,
/// from newer builds, are ignored): raw when nothing offered is acceptable,
/// e.g. an older peer that offers nothing.
pub fn negotiate(wanted: Compression, offered: &[String]) -> Codec {
    let has = |c: Codec| c == Codec::Raw || offered.iter().any(|o| o == c.name());
    match wanted {
        Compression::Auto => Codec::ALL.into_iter().find(|&c| has(c)).unwrap_or(Codec::Raw),
        Compression::Use(c) if has(c) => c,
        Compression::Use(_) => Codec::Raw,
    }
}

/// The names of every codec this build supports, as a `Hello` offers them.
pub fn offer() -> Vec<String> {
    Codec::ALL.iter().map(|c| c.name().to_string()).collect()
}

/// Why encoded tile bytes could not be decoded.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum CodecError {
    /// The tile itself is too large to accept.
    #[error("a {w}x{h} tile is larger than the {MAX_TILE_BYTES}-byte limit")]
    TooLarge {
        /// Width.
        w: u32,
        /// Height.
        h: u32,
    },
    /// The bytes decode to the wrong size, or not at all.
    #[error("{codec} tile data is corrupt: {reason}")]
    Corrupt {
        /// The codec.
        codec: Codec,
        /// What went wrong.
        reason: String,
    },
}

/// The most bytes any codec of this build can encode a `w × h` tile to (QOI's
/// worst case, four bytes a pixel plus its header and end marker, is the
/// largest). A slave's tile message is bounded by it before it is read.
pub fn max_encoded_len(w: u32, h: u32) -> usize {
    let pixels = w as usize * h as usize;
    let raw = pixels * 3;
    let qoi = 14 + 8 + pixels * 4;
    raw.max(lz4_flex::block::get_maximum_output_size(raw)).max(qoi)
}

/// Encodes `rgb` (`w * h * 3` bytes, row-major) with `codec`. An empty tile
/// encodes to nothing; if a codec cannot take a tile (QOI and a length that is
/// not whole rows) the result is raw — which the decoder, knowing the tile's
/// size, would refuse: callers pass whole tiles.
pub fn encode(codec: Codec, w: u32, rgb: &[u8]) -> Vec<u8> {
    if rgb.is_empty() {
        return Vec::new();
    }
    match codec {
        Codec::Raw => rgb.to_vec(),
        Codec::Lz4 => lz4_flex::block::compress(rgb),
        Codec::Qoi => {
            let h = if w == 0 { 0 } else { rgb.len() / 3 / w as usize };
            u32::try_from(h)
                .ok()
                .and_then(|h| qoi::encode_to_vec(rgb, w, h).ok())
                .unwrap_or_else(|| rgb.to_vec())
        }
    }
}

/// Decodes a `w × h` tile's bytes encoded with `codec` into `w * h * 3` bytes
/// of RGB8. Never allocates more than that, never panics.
pub fn decode(codec: Codec, w: u32, h: u32, data: &[u8]) -> Result<Vec<u8>, CodecError> {
    let mut out = Vec::new();
    decode_into(codec, w, h, data, &mut out)?;
    Ok(out)
}

/// [`decode`] into `out` (resized to `w * h * 3` bytes; its allocation is
/// reused, so a caller that only validates tiles — the master — allocates
/// nothing per tile). On error `out` holds no meaningful pixels.
pub fn decode_into(codec: Codec, w: u32, h: u32, data: &[u8], out: &mut Vec<u8>) -> Result<(), CodecError> {
    let len = tile_bytes(w, h)?;
    let corrupt = |reason: String| CodecError::Corrupt { codec, reason };
    out.clear();
    if len == 0 {
        return if data.is_empty() { Ok(()) } else { Err(corrupt("data for an empty tile".into())) };
    }
    match codec {
        Codec::Raw if data.len() == len => out.extend_from_slice(data),
        Codec::Raw => return Err(corrupt(format!("{} bytes, {len} expected", data.len()))),
        Codec::Lz4 => {
            out.resize(len, 0);
            let n = lz4_flex::block::decompress_into(data, out).map_err(|e| corrupt(e.to_string()))?;
            if n != len {
                return Err(corrupt(format!("{n} bytes decoded, {len} expected")));
            }
        }
        Codec::Qoi => {
            // The header must name this tile before anything is allocated.
            qoi_header(w, h, data)?;
            out.resize(len, 0);
            qoi::decode_to_buf(&mut out[..], data).map_err(|e| corrupt(e.to_string()))?;
        }
    }
    Ok(())
}

/// Checks that `data` is a valid `w × h` tile in `codec` the way the
/// master must before counting it, without decoding it: raw tiles by their
/// length alone (every byte string of the right length is an image), QOI by
/// its header and a walk over its ops, LZ4 by a walk over its sequences
/// (see `codec/walk.rs`). A tile that passes decodes with
/// [`decode_into`]. Allocates nothing, never panics.
pub fn check(codec: Codec, w: u32, h: u32, data: &[u8]) -> Result<(), CodecError> {
    let len = tile_bytes(w, h)?;
    let corrupt = |reason: String| CodecError::Corrupt { codec, reason };
    if len == 0 {
        return if data.is_empty() { Ok(()) } else { Err(corrupt("data for an empty tile".into())) };
    }
    match codec {
        Codec::Raw if data.len() == len => Ok(()),
        Codec::Raw => Err(corrupt(format!("{} bytes, {len} expected", data.len()))),
        Codec::Lz4 => walk::lz4(data, len).map_err(corrupt),
        Codec::Qoi => {
            qoi_header(w, h, data)?;
            walk::qoi(data, len / 3).map_err(corrupt)
        }
    }
}

/// Checks that a QOI stream's header names a `w × h` RGB image.
fn qoi_header(w: u32, h: u32, data: &[u8]) -> Result<(), CodecError> {
    let corrupt = |reason: String| CodecError::Corrupt { codec: Codec::Qoi, reason };
    let header = qoi::decode_header(data).map_err(|e| corrupt(e.to_string()))?;
    if (header.width, header.height) != (w, h) || header.channels != qoi::Channels::Rgb {
        return Err(corrupt(format!(
            "a {}x{} image with {:?} channels, for a {w}x{h} RGB tile",
            header.width, header.height, header.channels
        )));
    }
    Ok(())
}

/// `w * h * 3`, if that is within [`MAX_TILE_BYTES`].
fn tile_bytes(w: u32, h: u32) -> Result<usize, CodecError> {
    let len = (w as usize).checked_mul(h as usize).and_then(|n| n.checked_mul(3));
    len.filter(|&n| n <= MAX_TILE_BYTES).ok_or(CodecError::TooLarge { w, h })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_agrees_with_decode() {
        let (w, h) = (5u32, 3u32);
        let rgb: Vec<u8> = (0..w * h * 3).map(|i| (i * 13 % 256) as u8).collect();
        for codec in [Codec::Raw, Codec::Lz4, Codec::Qoi] {
            let data = encode(codec, w, &rgb);
            let mut bad = data.clone();
            bad.pop();
            for (bytes, tw, th) in [(&data, w, h), (&bad, w, h), (&data, w + 1, h), (&data, 1 << 20, 1 << 20)]
            {
                let checked = check(codec, tw, th, bytes);
                assert_eq!(checked.is_ok(), decode(codec, tw, th, bytes).is_ok(), "{codec:?} {tw}x{th}");
            }
        }
    }

    /// Streams the decoders take leniently, which no encoder writes: the
    /// check refuses them.
    #[test]
    fn the_check_is_stricter_than_the_decoders_where_they_are_lenient() {
        let rgb = tile(4, 2, 9);
        let qoi = encode(Codec::Qoi, 4, &rgb);
        let (body, end) = qoi.split_at(qoi.len() - 8);
        // A run one past the last pixel; an RGBA op; a byte after the end.
        let mut long_run = body[..14].to_vec();
        long_run.push(0xc0 | 8);
        long_run.extend_from_slice(end);
        let mut rgba = body.to_vec();
        rgba.extend([0xff, 1, 2, 3, 4]);
        rgba.extend_from_slice(end);
        let trailing = [&qoi[..], &[0]].concat();
        for bad in [&long_run, &rgba, &trailing] {
            assert!(check(Codec::Qoi, 4, 2, bad).is_err());
        }
        assert!(decode(Codec::Qoi, 4, 2, &long_run).is_ok(), "the decoder cuts the run short");
        assert!(decode(Codec::Qoi, 4, 2, &trailing).is_ok(), "the decoder ignores what follows the end");
        // LZ4: a match 0 bytes back; a block ending on a match.
        let zero = [0x10, 7, 0, 0, 0x00];
        assert!(check(Codec::Lz4, 3, 1, &zero).is_err());
        assert!(check(Codec::Lz4, 3, 1, &[0x50, 1, 2, 3, 4, 5, 5, 0]).is_err());
        // Five literals, 18 bytes from 5 back, four literals: 27 bytes.
        let good = [0x5e, 1, 2, 3, 4, 5, 5, 0, 0x40, 9, 8, 7, 6];
        assert_eq!(check(Codec::Lz4, 3, 3, &good), Ok(()));
        assert_eq!(decode(Codec::Lz4, 3, 3, &good).unwrap().len(), 27);
    }

    #[test]
    fn decode_into_reuses_its_buffer_and_matches_decode() {
        let (w, h) = (16u32, 8u32);
        let rgb: Vec<u8> = (0..w * h * 3).map(|i| (i * 7 % 251) as u8).collect();
        let mut out = vec![9u8; 10_000];
        for codec in [Codec::Raw, Codec::Lz4, Codec::Qoi] {
            let data = encode(codec, w, &rgb);
            decode_into(codec, w, h, &data, &mut out).unwrap();
            assert_eq!(out, rgb, "{codec}");
            assert_eq!(decode(codec, w, h, &data).unwrap(), rgb, "{codec}");
            // A smaller tile into the same buffer: only its own bytes.
            let small = encode(codec, 2, &rgb[..12]);
            decode_into(codec, 2, 2, &small, &mut out).unwrap();
            assert_eq!(out, &rgb[..12], "{codec}");
            assert!(decode_into(codec, w, h, &data[..data.len() / 2], &mut out).is_err(), "{codec}");
        }
    }
    #[test]
    fn no_codec_encodes_noise_beyond_the_bound() {
        let mut x = 0x9e37_79b9_u32;
        for (w, h) in [(1, 1), (7, 3), (32, 32), (64, 17)] {
            let rgb: Vec<u8> = (0..w * h * 3)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 17;
                    x ^= x << 5;
                    x as u8
                })
                .collect();
            for codec in Codec::ALL {
                let n = encode(codec, w, &rgb).len();
                assert!(n <= max_encoded_len(w, h), "{codec} {w}x{h}: {n} > {}", max_encoded_len(w, h));
            }
        }
    }

    use proptest::prelude::*;

    /// A tile with gradients, flat areas and noise, like a rendered one.
    fn tile(w: u32, h: u32, seed: u32) -> Vec<u8> {
        let mut out = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let noise = (x.wrapping_mul(2_654_435_761) ^ y.wrapping_mul(40503) ^ seed) >> 29;
                let flat = x < w / 2;
                for c in 0..3u32 {
                    let v = if flat { 40 + c * 10 } else { x * 4 + y + c * 30 + noise };
                    out.push(v as u8);
                }
            }
        }
        out
    }

    #[test]
    fn every_codec_round_trips_tiles_of_every_shape() {
        for (w, h) in [(1, 1), (1, 7), (7, 1), (32, 32), (64, 64), (33, 17), (640, 3)] {
            let rgb = tile(w, h, w * h);
            for codec in Codec::ALL {
                let enc = encode(codec, w, &rgb);
                assert_eq!(decode(codec, w, h, &enc).unwrap(), rgb, "{codec} {w}x{h}");
            }
        }
    }

    #[test]
    fn compressing_codecs_shrink_smooth_tiles() {
        let rgb = tile(64, 64, 1);
        let lz4 = encode(Codec::Lz4, 64, &rgb).len();
        let qoi = encode(Codec::Qoi, 64, &rgb).len();
        assert!(lz4 < rgb.len(), "lz4 {lz4} of {}", rgb.len());
        // The gradient half is all small, equal differences: QOI's strength.
        assert!(qoi < lz4, "qoi {qoi} vs lz4 {lz4}");
    }

    #[test]
    fn wrong_sizes_and_huge_tiles_are_errors() {
        let rgb = tile(8, 8, 3);
        for codec in Codec::ALL {
            let enc = encode(codec, 8, &rgb);
            // Declared one row taller or shorter than what was encoded.
            assert!(decode(codec, 8, 9, &enc).is_err(), "{codec}");
            assert!(decode(codec, 8, 7, &enc).is_err(), "{codec}");
            assert_eq!(
                decode(codec, 100_000, 100_000, &enc),
                Err(CodecError::TooLarge { w: 100_000, h: 100_000 })
            );
            assert!(decode(codec, u32::MAX, u32::MAX, &enc).is_err());
        }
    }

    #[test]
    fn names_parse_and_negotiation_falls_back_to_raw() {
        for c in Codec::ALL {
            assert_eq!(Codec::from_name(c.name()), Some(c));
            assert_eq!(c.name().parse::<Compression>(), Ok(Compression::Use(c)));
        }
        assert_eq!("auto".parse::<Compression>(), Ok(Compression::Auto));
        assert!("zip".parse::<Compression>().unwrap_err().contains("qoi"));
        let all = offer();
        assert_eq!(negotiate(Compression::Auto, &all), Codec::ALL[0]);
        assert_eq!(negotiate(Compression::Use(Codec::Lz4), &all), Codec::Lz4);
        assert_eq!(negotiate(Compression::Use(Codec::Raw), &all), Codec::Raw);
        // An old peer offers nothing; a newer one offers names we do not know.
        for offered in [vec![], vec!["zstd-9".to_string(), "future".to_string()]] {
            assert_eq!(negotiate(Compression::Auto, &offered), Codec::Raw);
            assert_eq!(negotiate(Compression::Use(Codec::Qoi), &offered), Codec::Raw);
        }
        assert_eq!(negotiate(Compression::Auto, &["lz4".to_string()]), Codec::Lz4);
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

        /// Random bytes, as an attacker would send: an error or a tile of
        /// exactly the declared size, never a panic.
        #[test]
        fn garbage_never_panics(data in proptest::collection::vec(any::<u8>(), 0..4096),
                                w in 0u32..80, h in 0u32..80) {
            for codec in Codec::ALL {
                if let Ok(out) = decode(codec, w, h, &data) {
                    prop_assert_eq!(out.len(), w as usize * h as usize * 3);
                }
            }
        }

        /// Valid encodings with bytes flipped: same guarantee.
        #[test]
        fn corrupted_tiles_never_panic(w in 1u32..40, h in 1u32..40, seed in any::<u32>(),
                                       flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..8)) {
            let rgb = tile(w, h, seed);
            for codec in Codec::ALL {
                let mut enc = encode(codec, w, &rgb);
                for &(at, v) in &flips {
                    if !enc.is_empty() {
                        let i = at % enc.len();
                        enc[i] = v;
                    }
                }
                if let Ok(out) = decode(codec, w, h, &enc) {
                    prop_assert_eq!(out.len(), rgb.len());
                }
            }
        }

        /// The master's check without decoding: every encoding passes it, and
        /// whatever passes it (valid or with bytes flipped, cut or added)
        /// decodes to the tile's size.
        #[test]
        fn what_the_check_passes_decodes(w in 1u32..40, h in 1u32..40, seed in any::<u32>(),
                                          flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 0..6),
                                          cut in 0usize..3, extra in proptest::collection::vec(any::<u8>(), 0..3)) {
            let rgb = tile(w, h, seed);
            for codec in Codec::ALL {
                let mut enc = encode(codec, w, &rgb);
                prop_assert_eq!(check(codec, w, h, &enc), Ok(()), "{}", codec);
                for &(at, v) in &flips {
                    let i = at % enc.len();
                    enc[i] = v;
                }
                enc.truncate(enc.len().saturating_sub(cut));
                enc.extend_from_slice(&extra);
                if check(codec, w, h, &enc).is_ok() {
                    let out = decode(codec, w, h, &enc);
                    prop_assert!(out.is_ok(), "{} passed the check, then {:?}", codec, out);
                }
            }
        }

        /// Random bytes pass the check only if they decode.
        #[test]
        fn checked_garbage_decodes(data in proptest::collection::vec(any::<u8>(), 0..600),
                                   w in 0u32..12, h in 0u32..12) {
            for codec in Codec::ALL {
                if check(codec, w, h, &data).is_ok() {
                    prop_assert!(decode(codec, w, h, &data).is_ok(), "{}", codec);
                }
            }
        }

        /// A valid QOI image of another size or shape than the tile is refused.
        #[test]
        fn qoi_headers_must_name_the_tile(w in 1u32..30, h in 1u32..30, dw in 0u32..3, dh in 0u32..3) {
            let rgb = tile(w, h, 5);
            let enc = encode(Codec::Qoi, w, &rgb);
            let got = decode(Codec::Qoi, w + dw, h + dh, &enc);
            prop_assert_eq!(got.is_ok(), dw == 0 && dh == 0);
            let rgba: Vec<u8> = rgb.chunks(3).flat_map(|p| [p[0], p[1], p[2], 255]).collect();
            let four = qoi::encode_to_vec(&rgba, w, h).unwrap();
            prop_assert!(decode(Codec::Qoi, w, h, &four).is_err());
        }
    }
}

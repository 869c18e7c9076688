//! Lossless compression of tile pixels on the wire.
//!
//! A tile is `w * h * 3` bytes of RGB8. Its [`Codec`] is agreed at join: the
//! peer's `Hello` lists the codecs it can decode and encode, the master's
//! `Welcome` picks one ([`negotiate`]), and every `TileResult` / `FrameTile`
//! names the codec of its bytes. [`Codec::Raw`] is always available.
//!
//! The codecs were chosen by measuring real rendered tiles (bytes, and CPU time
//! to encode and decode): `examples/tile_codecs.rs` renders the shipped scenes
//! and prints the table that BENCHMARKS.md quotes. [`Codec::DeltaLz4`] — each
//! byte replaced by its difference to the same channel of the left neighbour
//! (the pixel above for the first column), then LZ4 — is the default: the
//! differences of smooth shading and flat walls are runs of small numbers and
//! zeros, which LZ4 finds at over a gigabyte per second.
//!
//! Decoding takes untrusted bytes: the decoded size is known from the tile
//! (`w * h * 3`), is checked against [`MAX_TILE_BYTES`] before anything is
//! allocated, and must come out exactly; every failure is a [`CodecError`],
//! never a panic.

use serde::{Deserialize, Serialize};

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
    /// Left-neighbour delta per channel (the pixel above for column 0), then
    /// an LZ4 block: see the [module docs](self).
    DeltaLz4,
}

impl Codec {
    /// Every codec this build can encode and decode, best first (the order
    /// `auto` prefers).
    pub const ALL: [Codec; 3] = [Codec::DeltaLz4, Codec::Lz4, Codec::Raw];

    /// The name used on the command line and in the [`Hello`](crate::protocol::Hello) offer.
    pub fn name(self) -> &'static str {
        match self {
            Codec::Raw => "raw",
            Codec::Lz4 => "lz4",
            Codec::DeltaLz4 => "delta-lz4",
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

/// Encodes `rgb` (`w * h * 3` bytes, row-major) with `codec`.
pub fn encode(codec: Codec, w: u32, rgb: &[u8]) -> Vec<u8> {
    match codec {
        Codec::Raw => rgb.to_vec(),
        Codec::Lz4 => lz4_flex::block::compress(rgb),
        Codec::DeltaLz4 => lz4_flex::block::compress(&delta_encode(w, rgb)),
    }
}

/// Decodes a `w × h` tile's bytes encoded with `codec` into `w * h * 3` bytes
/// of RGB8. Never allocates more than that, never panics.
pub fn decode(codec: Codec, w: u32, h: u32, data: &[u8]) -> Result<Vec<u8>, CodecError> {
    let len = (w as usize).checked_mul(h as usize).and_then(|n| n.checked_mul(3));
    let len = len.filter(|&n| n <= MAX_TILE_BYTES).ok_or(CodecError::TooLarge { w, h })?;
    let corrupt = |reason: String| CodecError::Corrupt { codec, reason };
    let lz4 = |data: &[u8]| -> Result<Vec<u8>, CodecError> {
        let mut out = vec![0u8; len];
        let n = lz4_flex::block::decompress_into(data, &mut out).map_err(|e| corrupt(e.to_string()))?;
        if n != len {
            return Err(corrupt(format!("{n} bytes decoded, {len} expected")));
        }
        Ok(out)
    };
    match codec {
        Codec::Raw if data.len() == len => Ok(data.to_vec()),
        Codec::Raw => Err(corrupt(format!("{} bytes, {len} expected", data.len()))),
        Codec::Lz4 => lz4(data),
        Codec::DeltaLz4 => {
            let mut out = lz4(data)?;
            delta_decode(w, &mut out);
            Ok(out)
        }
    }
}

/// Replaces each byte of an RGB8 image `w` pixels wide by its wrapping
/// difference to the same channel of the pixel on its left (the pixel above
/// for the first column; the first pixel stays as is).
pub fn delta_encode(w: u32, rgb: &[u8]) -> Vec<u8> {
    let row = w as usize * 3;
    let mut out = Vec::with_capacity(rgb.len());
    for (i, &b) in rgb.iter().enumerate() {
        let pred = if row == 0 {
            0
        } else if i % row >= 3 {
            rgb[i - 3]
        } else if i >= row {
            rgb[i - row]
        } else {
            0
        };
        out.push(b.wrapping_sub(pred));
    }
    out
}

/// Undoes [`delta_encode`] in place.
pub fn delta_decode(w: u32, data: &mut [u8]) {
    let row = w as usize * 3;
    if row == 0 {
        return;
    }
    for i in 0..data.len() {
        let pred = if i % row >= 3 {
            data[i - 3]
        } else if i >= row {
            data[i - row]
        } else {
            0
        };
        data[i] = data[i].wrapping_add(pred);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
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
        let delta = encode(Codec::DeltaLz4, 64, &rgb).len();
        assert!(lz4 < rgb.len(), "lz4 {lz4} of {}", rgb.len());
        // The gradient half is all small, equal differences.
        assert!(delta < lz4, "delta-lz4 {delta} vs lz4 {lz4}");
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
        assert!("zip".parse::<Compression>().unwrap_err().contains("delta-lz4"));
        let all = offer();
        assert_eq!(negotiate(Compression::Auto, &all), Codec::ALL[0]);
        assert_eq!(negotiate(Compression::Use(Codec::Lz4), &all), Codec::Lz4);
        assert_eq!(negotiate(Compression::Use(Codec::Raw), &all), Codec::Raw);
        // An old peer offers nothing; a newer one offers names we do not know.
        for offered in [vec![], vec!["zstd-9".to_string(), "future".to_string()]] {
            assert_eq!(negotiate(Compression::Auto, &offered), Codec::Raw);
            assert_eq!(negotiate(Compression::Use(Codec::DeltaLz4), &offered), Codec::Raw);
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

        /// Any image round-trips through the delta predictor.
        #[test]
        fn delta_round_trips(w in 1u32..50, rows in 0u32..20, seed in any::<u64>()) {
            let n = (w * rows * 3) as usize;
            let rgb: Vec<u8> = (0..n).map(|i| (seed.wrapping_mul(i as u64 + 7) >> 17) as u8).collect();
            let mut d = delta_encode(w, &rgb);
            delta_decode(w, &mut d);
            prop_assert_eq!(d, rgb);
        }
    }
}

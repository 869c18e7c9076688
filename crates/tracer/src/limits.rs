//! Every number isin takes from a user or a peer, bounded: one table, each
//! bound with the reason for its value.
//!
//! The command line, the scene loader, the master and the slave check the
//! same bounds, so a value accepted in one place is accepted everywhere and
//! refused everywhere else in the same words, before any work starts. The
//! cluster's own budgets (frame sizes, peers) are in `isin_cluster::limits`.

use crate::render::RenderSettings;

/// An inclusive range a number must lie in, and why.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Bound {
    /// What the number is, as a user names it.
    pub name: &'static str,
    /// The smallest value accepted.
    pub min: u64,
    /// The largest value accepted.
    pub max: u64,
    /// Why these values.
    pub why: &'static str,
}

/// A number outside its [`Bound`].
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{name} {value} is {side} the limit of {limit} ({why})")]
pub struct LimitError {
    /// What the number is.
    pub name: &'static str,
    /// The value given.
    pub value: u64,
    /// `below` or `above`.
    pub side: &'static str,
    /// The bound it crossed.
    pub limit: u64,
    /// Why the bound is there.
    pub why: &'static str,
}

impl Bound {
    /// `value` if it lies within the bound.
    pub fn check(&self, value: u64) -> Result<u64, LimitError> {
        let out = |side, limit| LimitError { name: self.name, value, side, limit, why: self.why };
        if value < self.min {
            Err(out("below", self.min))
        } else if value > self.max {
            Err(out("above", self.max))
        } else {
            Ok(value)
        }
    }

    /// Parses a decimal number and checks it (for command-line options): a
    /// value that does not fit 64 bits is refused as above the bound.
    pub fn parse(&self, text: &str) -> Result<u64, String> {
        let value = match text.trim().parse::<u64>() {
            Ok(v) => v,
            Err(_) if !text.trim().is_empty() && text.trim().bytes().all(|b| b.is_ascii_digit()) => u64::MAX,
            Err(_) => return Err(format!("`{text}` is not a whole number")),
        };
        self.check(value).map_err(|e| e.to_string())
    }
}

/// Pixels on either side of an image.
pub const IMAGE_SIDE: Bound =
    Bound { name: "image side", min: 1, max: 16_384, why: "16k is four times a cinema 4K frame's width" };
/// Pixels of an image in all.
pub const IMAGE_PIXELS: Bound = Bound {
    name: "image pixels",
    min: 1,
    max: 1 << 26,
    why: "64 Mpixels: the frame and its accumulation buffers stay under 2 GiB",
};
/// Samples per pixel.
pub const SPP: Bound = Bound {
    name: "samples per pixel",
    min: 1,
    max: 65_536,
    why: "the viewer refines to 64; stills converge long before",
};
/// Shadow rays per area light and sample.
pub const LIGHT_SAMPLES: Bound = Bound {
    name: "light samples",
    min: 0,
    max: 4_096,
    why: "a 64×64 grid of shadow rays a light: more is invisible, and costs minutes a frame",
};
/// Recursion depth of reflection and refraction. Deeper scene settings are
/// clamped to it (with a warning), as the integrator would.
pub const DEPTH: Bound = Bound {
    name: "depth",
    min: 0,
    max: 64,
    why: "a mirror hall needs a few dozen bounces; each adds a ray per pixel",
};
/// Render threads of a process; 0 means one per core.
pub const THREADS: Bound = Bound {
    name: "threads",
    min: 0,
    max: 256,
    why: "0 is one per core; more threads than 256 cores only contend",
};
/// Edge of the tiles a frame is cut into.
pub const TILE: Bound = Bound {
    name: "tile edge",
    min: 8,
    max: 512,
    why: "below 8 pixels a tile costs more to send than to render; a 512² tile is a slave's whole message",
};
/// Tiles a slave keeps queued beyond one per render thread.
pub const QUEUE_DEPTH: Bound = Bound {
    name: "queue depth",
    min: 0,
    max: 64,
    why: "enough to hide any LAN's latency; more only delays frame ends",
};
/// Milliseconds a silent peer is given before it is declared dead.
pub const HEARTBEAT_TIMEOUT_MS: Bound = Bound {
    name: "heartbeat timeout (ms)",
    min: 1_000,
    max: 3_600_000,
    why: "peers heartbeat every 500 ms: below two heartbeats healthy peers die; above an hour nothing is noticed",
};

/// Seconds a cluster client waits in all (`--timeout`).
pub const CLIENT_TIMEOUT_S: Bound = Bound {
    name: "timeout (s)",
    min: 1,
    max: 604_800,
    why: "a week covers any overnight or weekend job; 0 would give up before starting",
};

/// Frames a keyframed camera path may be sampled into.
pub const PATH_FRAMES: Bound = Bound {
    name: "camera path frames",
    min: 1,
    max: 100_000,
    why: "over an hour at 24 fps; a key's time typed in milliseconds instead of seconds would ask for millions",
};

/// Every bound, for documentation and `isin --help`.
pub const ALL: &[Bound] = &[
    IMAGE_SIDE,
    IMAGE_PIXELS,
    SPP,
    LIGHT_SAMPLES,
    DEPTH,
    THREADS,
    TILE,
    QUEUE_DEPTH,
    HEARTBEAT_TIMEOUT_MS,
    CLIENT_TIMEOUT_S,
    PATH_FRAMES,
];

/// Checks a frame's settings against the bounds: size, samples, light
/// samples and depth.
pub fn check_settings(s: &RenderSettings) -> Result<(), LimitError> {
    IMAGE_SIDE.check(u64::from(s.width))?;
    IMAGE_SIDE.check(u64::from(s.height))?;
    IMAGE_PIXELS.check(u64::from(s.width) * u64::from(s.height))?;
    SPP.check(u64::from(s.spp))?;
    LIGHT_SAMPLES.check(u64::from(s.light_samples))?;
    DEPTH.check(u64::from(s.max_depth))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_bound_has_a_reason_and_a_range() {
        for b in ALL {
            assert!(b.min <= b.max && !b.why.is_empty(), "{b:?}");
        }
    }

    #[test]
    fn values_outside_say_which_limit_and_why() {
        let e = IMAGE_SIDE.parse("100000").unwrap_err();
        assert!(e.contains("image side 100000 is above the limit of 16384"), "{e}");
        assert!(THREADS.parse("99999999999999999999999").unwrap_err().contains("above the limit of 256"));
        assert!(TILE.parse("0").unwrap_err().contains("below the limit of 8"));
        assert!(SPP.parse("many").unwrap_err().contains("not a whole number"));
        assert_eq!(QUEUE_DEPTH.parse("3"), Ok(3));
        let s = RenderSettings { width: 16_384, height: 16_384, ..RenderSettings::default() };
        assert_eq!(check_settings(&s).unwrap_err().name, "image pixels");
        let s = RenderSettings { light_samples: 1_000_000_000, ..RenderSettings::default() };
        assert_eq!(check_settings(&s).unwrap_err().name, "light samples");
        assert!(check_settings(&RenderSettings::default()).is_ok());
    }
}

//! Tiles that skip the master: what a viewer offers, what the master tells
//! slaves, and what slave and viewer say to each other.
//!
//! A viewer that listens for slaves sends a [`DirectOffer`] in its
//! [`Hello`](super::Hello): where it listens, the fingerprint of the
//! certificate it presents there, and a fresh random key. The master passes
//! them on in a [`DirectRoute`] with every assignment of that viewer's frames
//! (the offer itself only in the first route to that viewer a slave gets),
//! with the tiles it wants to see itself ([`DirectRoute::via_master`]: a
//! sample it checks, chosen with a secret the slaves do not know). A slave
//! dials the viewer (pinning the fingerprint), proves it was sent by the
//! master with [`Message::DirectHello`](super::Message::DirectHello) (the key,
//! over the encrypted connection), and sends each other tile there as a
//! [`DirectTile`]. The viewer checks it like the master would (a request of
//! its own, a rectangle inside the frame, pixels that decode), shows it,
//! tells the master ([`TileReceived`]: the tile without its pixels) and
//! acknowledges it to the slave. The master counts a direct tile done on the
//! viewer's word, not the slave's: a slave cannot claim a tile delivered
//! that never was, a frame the master calls done has all its tiles at the
//! viewer, and the viewer hears its `FrameDone` after them. A tile the slave
//! cannot deliver (no link yet, the link broke, no acknowledgement in time)
//! goes through the master as before.

use super::{FrameId, FrameTile, TileId};
use isin_tracer::Tile;
use serde::{Deserialize, Serialize};

/// Longest address in a [`DirectOffer`].
pub const MAX_DIRECT_ADDR: usize = 128;

/// Longest fingerprint text in a [`DirectOffer`] (hex of 32 bytes).
pub const MAX_DIRECT_FINGERPRINT: usize = 64;

/// One tile in this many (on average) of a frame delivered direct goes
/// through the master, which checks its pixels as it checks every tile of a
/// frame that is not: enough to catch a slave that sends garbage within a
/// frame or two, few enough to leave the master's link to the others.
pub const VERIFY_ONE_IN: u64 = 16;

/// A viewer's offer to take its tiles straight from slaves
/// ([`Hello::direct`](super::Hello::direct)).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct DirectOffer {
    /// `HOST:PORT` where it listens, as slaves can reach it (at most
    /// [`MAX_DIRECT_ADDR`] bytes).
    pub addr: String,
    /// The fingerprint of the certificate it presents there, as a ticket
    /// writes it (`None`: plaintext, for a master that speaks plaintext).
    pub fingerprint: Option<String>,
    /// The secret a slave shows to be let in: random, for this connection only.
    pub key: [u8; 32],
}

/// Master → slave, with an assignment: deliver these tiles straight to the
/// frame's viewer ([`TileAssignment::direct`](super::TileAssignment::direct)).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct DirectRoute {
    /// The viewer's id at the master (its [`Welcome::id`](super::Welcome::id)).
    pub viewer: u64,
    /// The viewer's request number for the frame.
    pub request: u64,
    /// Where and how to reach it, and the key to show: in the first route
    /// to this viewer a slave is sent (assignments are ordered), `None` in
    /// the others (the slave keeps it by [`DirectRoute::viewer`]).
    pub offer: Option<DirectOffer>,
    /// Tiles of the assignment to send to the master instead, in full.
    pub via_master: Vec<TileId>,
}

/// Slave → viewer: a tile of one of its frames.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DirectTile {
    /// The master's frame.
    pub frame: FrameId,
    /// The tile's id in it.
    pub id: TileId,
    /// The tile as the master would have forwarded it.
    pub tile: FrameTile,
    /// Time spent rendering it, in microseconds (as in
    /// [`TileResult::render_micros`](super::TileResult::render_micros)).
    pub render_micros: u64,
}

/// Viewer → master: a tile of one of its direct frames arrived straight
/// from its slave.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct TileReceived {
    /// The frame it belongs to.
    pub frame: FrameId,
    /// The tile's id.
    pub id: TileId,
    /// The slave that sent it (as its link's [`DirectHello`](super::Message::DirectHello) said).
    pub slave: u64,
    /// The tile's rectangle (checked against the one assigned).
    pub tile: Tile,
    /// The render time its slave gave, in microseconds.
    pub render_micros: u64,
}

/// Whether the master wants tile `id` of `frame` itself: a keyed hash of
/// both, so that a slave cannot tell which of its tiles will be checked.
pub fn via_master(secret: &[u8; 32], frame: FrameId, id: TileId) -> bool {
    use sha2::{Digest, Sha256};
    let mut h = Sha256::new();
    h.update(secret);
    h.update(frame.to_le_bytes());
    h.update(id.to_le_bytes());
    let d = h.finalize();
    let mut first = [0u8; 8];
    first.copy_from_slice(&d[..8]);
    u64::from_le_bytes(first) % VERIFY_ONE_IN == 0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn about_one_tile_in_sixteen_goes_through_the_master_and_which_depends_on_the_secret() {
        let ids = 0..16_000u32;
        let a = ids.clone().filter(|&i| via_master(&[1; 32], 7, i)).count();
        assert!((800..1200).contains(&a), "{a} of 16000");
        let same = ids.filter(|&i| via_master(&[1; 32], 7, i) == via_master(&[2; 32], 7, i)).count();
        assert!(same < 15_800, "another secret picks other tiles: {same} of 16000 agree");
    }
}

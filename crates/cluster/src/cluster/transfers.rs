//! Scenes on their way to slaves: per slave, one transfer at a time (others
//! queue behind it), at most a window of chunks beyond what the slave has
//! acknowledged in flight ([`Message::SceneAck`]). A slave that stalls holds
//! up only its own transfer, and the master never queues more than a window
//! of any scene for it. Every transfer shares the scene's [`Packed`] frames.
//!
//! [`Message::SceneAck`]: crate::protocol::Message::SceneAck

use super::PeerId;
use crate::protocol::{SceneHash, short_hash};
use crate::scene_stream::{Packed, ProgressLog};
use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;
use std::time::Duration;

/// One scene going to one slave.
#[derive(Debug)]
struct Transfer {
    packed: Arc<Packed>,
    /// Chunks sent.
    sent: u32,
    /// Chunks the slave acknowledged.
    acked: u32,
    log: ProgressLog,
}

/// A slave's transfers.
#[derive(Debug, Default)]
struct Queue {
    active: Option<Transfer>,
    waiting: VecDeque<Arc<Packed>>,
}

/// What a slave's acknowledgement did.
#[derive(Debug, Default)]
pub(super) struct Acked {
    /// Frames to send now, in order.
    pub frames: Vec<Arc<Vec<u8>>>,
    /// The scene whose transfer completed, if one did.
    pub finished: Option<SceneHash>,
}

/// Why an acknowledgement was refused.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum AckError {
    /// No transfer of that scene is running to this slave.
    #[error("acknowledged scene {0}, which is not being sent to it")]
    NotSending(String),
    /// More chunks than were sent, or fewer than before.
    #[error("acknowledged {got} chunks; {acked} were acknowledged and {sent} sent")]
    Count {
        /// Its count.
        got: u32,
        /// The count before.
        acked: u32,
        /// Chunks sent.
        sent: u32,
    },
}

/// Every transfer (see the [module docs](self)).
#[derive(Debug)]
pub(super) struct Transfers {
    by_peer: BTreeMap<PeerId, Queue>,
    window: u32,
}

impl Transfers {
    /// No transfers; `window` chunks (at least one) in flight per slave.
    pub(super) fn new(window: u32) -> Self {
        Self { by_peer: BTreeMap::new(), window: window.max(1) }
    }

    /// Sends `packed` to `peer` (after its running transfer, if any; not
    /// twice). Returns the frames to send now.
    pub(super) fn start(&mut self, now: Duration, peer: PeerId, packed: Arc<Packed>) -> Vec<Arc<Vec<u8>>> {
        let q = self.by_peer.entry(peer).or_default();
        let hash = packed.header.hash;
        let queued = q.active.as_ref().is_some_and(|t| t.packed.header.hash == hash)
            || q.waiting.iter().any(|p| p.header.hash == hash);
        if queued {
            return Vec::new();
        }
        q.waiting.push_back(packed);
        if q.active.is_some() {
            return Vec::new();
        }
        Self::next(q, now, peer, self.window)
    }

    /// Starts `q`'s next waiting transfer, if any.
    fn next(q: &mut Queue, now: Duration, peer: PeerId, window: u32) -> Vec<Arc<Vec<u8>>> {
        let Some(packed) = q.waiting.pop_front() else { return Vec::new() };
        let h = &packed.header;
        let what = format!("scene {} ({}) to peer #{peer}", h.name, short_hash(&h.hash));
        let log = ProgressLog::new(what, h.compressed_bytes, now);
        let mut t = Transfer { packed, sent: 0, acked: 0, log };
        let mut frames = vec![t.packed.begin_frame()];
        frames.extend(Self::fill(&mut t, window));
        q.active = Some(t);
        frames
    }

    /// The chunks that fit in `t`'s window now.
    fn fill(t: &mut Transfer, window: u32) -> Vec<Arc<Vec<u8>>> {
        let mut frames = Vec::new();
        let end = t.acked.saturating_add(window).min(t.packed.header.chunks);
        while t.sent < end {
            if let Some(f) = t.packed.chunk_frame(t.sent) {
                frames.push(f);
            }
            t.sent += 1;
        }
        frames
    }

    /// `peer` has `chunks` chunks of `hash`: its window moves on (and its
    /// next transfer starts once one completes).
    pub(super) fn ack(
        &mut self,
        now: Duration,
        peer: PeerId,
        hash: SceneHash,
        chunks: u32,
    ) -> Result<Acked, AckError> {
        let window = self.window;
        let running = |q: &&mut Queue| q.active.as_ref().is_some_and(|t| t.packed.header.hash == hash);
        let Some(q) = self.by_peer.get_mut(&peer).filter(running) else {
            return Err(AckError::NotSending(short_hash(&hash)));
        };
        Self::ack_active(q, now, peer, chunks, window)
    }

    fn ack_active(
        q: &mut Queue,
        now: Duration,
        peer: PeerId,
        chunks: u32,
        window: u32,
    ) -> Result<Acked, AckError> {
        let Some(t) = q.active.as_mut() else { return Ok(Acked::default()) };
        if chunks < t.acked || chunks > t.sent {
            return Err(AckError::Count { got: chunks, acked: t.acked, sent: t.sent });
        }
        t.acked = chunks;
        let h = &t.packed.header;
        let done_bytes =
            (u64::from(chunks) * crate::limits::SCENE_CHUNK_BYTES as u64).min(h.compressed_bytes);
        t.log.update(now, done_bytes);
        let mut out = Acked { frames: Self::fill(t, window), finished: None };
        if t.acked == t.packed.header.chunks {
            out.finished = Some(t.packed.header.hash);
            q.active = None;
            out.frames.extend(Self::next(q, now, peer, window));
        }
        Ok(out)
    }

    /// Forgets `peer`'s transfers (it left).
    pub(super) fn remove(&mut self, peer: PeerId) {
        self.by_peer.remove(&peer);
    }
}

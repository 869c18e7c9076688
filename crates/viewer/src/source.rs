//! The interface between the window and whatever renders its frames.
//!
//! The window never renders anything itself: it hands a [`FrameRequest`] to a
//! [`FrameSource`] and shows the [`TileUpdate`]s that come back. A newer request
//! supersedes every older one: a source may drop tiles of superseded frames it has
//! not rendered yet, and the window ignores tiles of frames it no longer wants.
//!
//! The binary's source is cluster-backed (`src/cli/remote.rs`): it forwards
//! requests to the master — a remote one, or the one `isin view SCENE` starts
//! in-process with a local slave — and relays the tiles its slaves return.
//! Sources are all the window knows about (tests and the `pattern` example
//! bring their own).
//!
//! # Writing a source
//!
//! The window runs on the main thread and must never block, so a networked
//! source runs its async side (e.g. an actix system) on a thread of its own.
//! [`crate::channel_source`] packages the pattern below; by hand:
//!
//! - [`FrameSource::request`] only posts the request to that thread (e.g.
//!   `Addr::do_send`) and remembers `frame_id` so replies can be tagged with it;
//! - the thread pushes [`SourceEvent`]s into a `std::sync::mpsc` channel and
//!   calls [`Waker::wake`] after each (wakes are coalesced, so once per tile is
//!   fine); [`FrameSource::try_next`] is `try_recv` on that channel;
//! - [`FrameSource::status`] reads counters the thread keeps in an
//!   `Arc<Mutex<SourceStatus>>`; [`TileUpdate::owner`] is the slave's id, which
//!   colours the tile-ownership overlay.

use isin_tracer::{Camera, RenderSettings, Tile};
use std::fmt;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

/// Identifies a frame request; strictly increasing over a viewer's lifetime.
pub type FrameId = u64;

/// One frame the window wants rendered.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameRequest {
    /// The frame's id: larger than every earlier request's.
    pub frame_id: FrameId,
    /// Where to look from.
    pub camera: Camera,
    /// Resolution, samples and seed of this pass.
    pub settings: RenderSettings,
}

/// A rendered tile of a requested frame.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TileUpdate {
    /// The frame this tile belongs to.
    pub frame_id: FrameId,
    /// Where the tile lies in the image.
    pub tile: Tile,
    /// `tile.w * tile.h * 3` bytes of sRGB RGB8, row-major (as returned by
    /// [`isin_tracer::render_tile`]).
    pub rgb: Vec<u8>,
    /// Who rendered it: a slave id. Used for the tile-ownership overlay and
    /// the tiles-per-slave status.
    pub owner: u32,
}

/// What a source reports back to the window.
#[derive(Clone, Debug, PartialEq)]
pub enum SourceEvent {
    /// A tile landed.
    Tile(TileUpdate),
    /// Every tile of `frame_id` has been delivered (sent after its last
    /// [`SourceEvent::Tile`]). Not sent for superseded frames.
    FrameComplete {
        /// The completed frame.
        frame_id: FrameId,
        /// Time from the request to the last tile.
        elapsed: Duration,
    },
    /// The source cannot go on (e.g. the master refused it); the window shows
    /// it in the status line and keeps the last image.
    Failed(String),
    /// The source lost its renderers and is trying to get them back (e.g. the
    /// master went away and the source reconnects); the message says so on
    /// screen until [`SourceEvent::Reconnected`].
    Lost(String),
    /// The source is back after [`SourceEvent::Lost`]: the frames in flight
    /// were lost with it, so the window asks for the current view again and
    /// clears its errors.
    Reconnected,
}

/// Counters describing the source, for the on-screen status line.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SourceStatus {
    /// Number of workers currently able to render (slaves).
    pub live_slaves: usize,
    /// Tiles delivered so far per worker, as `(owner id, count)`: the
    /// [`SourceStatus::workers`] in their order, then any other owner.
    pub tiles_per_slave: Vec<(u32, u64)>,
    /// Total tile payload bytes received so far.
    pub bytes_received: u64,
    /// Name of the transport the tiles travel over (`in-process`, `tcp`, `quic`).
    pub transport: String,
    /// The workers the source knows of (a cluster's slaves as its master
    /// lists them, live ones first); empty when the source does not say.
    pub workers: Vec<Worker>,
    /// Something to say on screen until it no longer holds, e.g. that no
    /// slave is connected and how to start one.
    pub notice: Option<String>,
}

/// A worker of a source: a slave of the cluster.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Worker {
    /// Its owner id, as in [`TileUpdate::owner`].
    pub id: u32,
    /// Its name.
    pub name: String,
    /// Its render threads.
    pub threads: u32,
    /// False once it is known to be dead.
    pub alive: bool,
}

/// Wakes the window's event loop when a source has events waiting.
///
/// Calls are coalesced: after the first wake, further calls do nothing until the
/// window has drained the events ([`Waker::rearm`]), so a source may call
/// [`Waker::wake`] once per tile without flooding the event loop.
#[derive(Clone)]
pub struct Waker {
    pending: Arc<AtomicBool>,
    notify: Arc<dyn Fn() + Send + Sync>,
}

impl Waker {
    /// A waker that calls `notify` (e.g. posts a user event to the event loop).
    pub fn new(notify: impl Fn() + Send + Sync + 'static) -> Self {
        Self { pending: Arc::new(AtomicBool::new(false)), notify: Arc::new(notify) }
    }

    /// A waker that does nothing, for sources polled without an event loop.
    pub fn noop() -> Self {
        Self::new(|| {})
    }

    /// Signals that events are waiting.
    pub fn wake(&self) {
        if !self.pending.swap(true, Ordering::AcqRel) {
            (self.notify)();
        }
    }

    /// Called by the window before it drains the source, so that events that
    /// arrive afterwards wake it again.
    pub fn rearm(&self) {
        self.pending.store(false, Ordering::Release);
    }
}

impl fmt::Debug for Waker {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Waker").field("pending", &self.pending.load(Ordering::Relaxed)).finish()
    }
}

/// Something that renders frames for the window.
///
/// The window calls [`FrameSource::request`] for every new camera or refinement
/// pass, then drains [`FrameSource::try_next`] whenever the [`Waker`] it gave
/// the source fires. Implementations must not block in either call.
pub trait FrameSource: Send {
    /// Installs the waker to call when events become available. Called once,
    /// before the first request.
    fn set_waker(&mut self, waker: Waker);

    /// Asks for a frame. Supersedes all earlier requests: their tiles that have
    /// not started rendering should be dropped, and no
    /// [`SourceEvent::FrameComplete`] is due for them.
    fn request(&mut self, request: FrameRequest);

    /// The next waiting event, if any (never blocks).
    fn try_next(&mut self) -> Option<SourceEvent>;

    /// Current counters for the status line.
    fn status(&self) -> SourceStatus;
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicUsize;

    #[test]
    fn waker_coalesces_until_rearmed() {
        let calls = Arc::new(AtomicUsize::new(0));
        let c = calls.clone();
        let w = Waker::new(move || {
            c.fetch_add(1, Ordering::SeqCst);
        });
        w.wake();
        w.wake();
        w.clone().wake();
        assert_eq!(calls.load(Ordering::SeqCst), 1);
        w.rearm();
        w.wake();
        assert_eq!(calls.load(Ordering::SeqCst), 2);
    }
}

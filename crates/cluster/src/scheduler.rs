//! The master's scheduling core: a plain state machine with no actors, no
//! sockets and no clock.
//!
//! Like quinn-proto's `Connection`, it is driven from outside: inputs are
//! `handle_*` methods, outputs come out of [`Scheduler::poll_output`], and time
//! is an argument (`now`, a [`Duration`] since any fixed origin). The master
//! actor feeds it network events and a periodic tick; tests feed it a virtual
//! clock and simulated slaves, so "a slave went silent and its tiles were
//! re-rendered elsewhere" runs in microseconds.
//!
//! What it decides:
//! - **Work distribution.** A frame is cut into tiles ([`SchedulerConfig::tile_size`]);
//!   each slave keeps up to `threads + queue_depth` tiles in flight, so network
//!   latency hides behind queued work and faster slaves take more tiles (dynamic
//!   load balancing rather than a static split).
//! - **Enough tiles for the cluster.** A frame is cut into tiles of
//!   [`SchedulerConfig::tile_size`], halved (down to 16 px) while that would
//!   give fewer than 8 tiles per render thread in the cluster — except a
//!   queued frame (pipelining, below): its end is filled by the next frame's
//!   tiles, so it keeps the full edge and the per-tile round trips stay few.
//! - **Expensive tiles first.** Slaves report each tile's render time
//!   ([`Scheduler::record_render_time`]); a new frame hands out its tiles in
//!   order of the cost measured there in earlier frames, largest first
//!   ([`cost`]), so a frame's tail is cheap tiles, not the one expensive region
//!   that grid order happened to meet last.
//! - **Smaller tiles at the end.** When fewer tiles remain queued than the
//!   cluster has threads, the next tile is split in four (down to
//!   [`SchedulerConfig::min_tile_size`]) so the frame does not wait on one big tile.
//! - **No queues at the end.** Once no more tiles are queued than the cluster
//!   has threads, slaves are only topped up to one tile per thread (no
//!   `queue_depth`), and when the queue is empty a slave with an idle thread
//!   takes over the newest tile still waiting behind busy threads on another
//!   slave (that slave is told to cancel it; its queued jobs are skipped). A
//!   tile waiting on one slave while another idles is the frame's tail.
//! - **Stragglers.** When the queue is empty but the frame is open, a slave with
//!   an idle thread gets a copy of the oldest outstanding tile that has been
//!   out longer than the frame's mean turnaround; the first result wins and the
//!   other holder is told to cancel.
//! - **Liveness.** Every message from a slave counts as a heartbeat; one silent
//!   for [`SchedulerConfig::heartbeat_timeout`] is declared dead, as is one whose
//!   connection closed, and its tiles go back to the front of the queue.
//! - **Superseding.** A newer frame ([`Scheduler::submit_frame`]) replaces the
//!   open ones; the old frames' tiles are cancelled and their late results are
//!   reported [`ResultOutcome::Stale`]. Frames opened for a client
//!   ([`Scheduler::open_for`]) supersede only that client's own.
//! - **Interactive before batch.** Frames are interactive (a viewer waits) or
//!   batch (stills and animations): interactive tiles go out first, but one
//!   tile in [`BATCH_FLOOR`] goes to batch work when both are queued, and
//!   batch tiles go only to idle threads, never into a slave's queue, so an
//!   interactive frame arriving waits for no batch tiles but those being
//!   rendered.
//! - **Fair share between clients.** Several clients (viewers) may have frames
//!   open at once. Each client is charged the pixel-samples (pixels × samples
//!   per pixel) delivered to it; the next tile goes to the least charged
//!   client with a tile queued, its oldest frame first. So clients that all
//!   keep work queued share the cluster evenly whatever their frame sizes, a
//!   client that asks for less gets all it asks for, and none starves. A
//!   client returning after a pause starts level with the least charged one
//!   still at work, without credit for the pause.
//! - **Pipelining.** A frame queued with [`Scheduler::queue_frame`] waits behind
//!   the open ones instead: its tiles go out as soon as the older frames have
//!   none left to hand out, so no slave idles through the end of one frame
//!   (a replayed camera path). The end-of-frame measures above (no queues,
//!   smaller tiles, moving and duplicating tiles) apply only to the end of
//!   the last open frame. Each frame still completes on its own.
//!
//! Polling order for a driver: after any `handle_*` call (and on every timer
//! tick, after [`Scheduler::handle_timeout`]), drain [`Scheduler::poll_output`].

pub mod cost;
pub mod workload;

use crate::protocol::{FrameId, FrameStats, TileId, TileJob};
use isin_tracer::Tile;
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::time::Duration;

/// Identifies a slave (assigned by the master at join).
pub type SlaveId = u64;

/// Identifies a client (a viewer, a render job): its frames are one stream,
/// and a new frame of its supersedes only its own.
pub type ClientId = u64;

/// What kind of work a frame is (a client says so when it joins).
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize,
)]
pub enum Work {
    /// Someone is waiting at a window: latency first.
    #[default]
    Interactive,
    /// A still or an animation nobody watches tile by tile: fills what
    /// interactive work leaves.
    Batch,
}

/// One tile in this many goes to batch work while interactive work is
/// queued too, so a batch job finishes even while people fly.
pub const BATCH_FLOOR: u64 = 10;

/// A frame as a client asks for it ([`Scheduler::open`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameOrder {
    /// Whose frame.
    pub client: ClientId,
    /// Its kind of work.
    pub work: Work,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Samples per pixel: what each pixel costs the client's share.
    pub samples: u32,
    /// Wait behind the client's open frames instead of superseding them.
    pub queue: bool,
}

/// Scheduling knobs.
#[derive(Clone, Debug, PartialEq)]
pub struct SchedulerConfig {
    /// Edge of the tiles a frame is cut into.
    pub tile_size: u32,
    /// Tiles are split near the end of a frame down to this edge.
    pub min_tile_size: u32,
    /// Tiles queued per slave beyond one per render thread.
    pub queue_depth: u32,
    /// A slave silent for this long is declared dead.
    pub heartbeat_timeout: Duration,
    /// Whether idle slaves may duplicate straggling tiles.
    pub duplicate_stragglers: bool,
    /// Most frames open at once: the one being rendered plus those queued
    /// behind it with [`Scheduler::queue_frame`].
    pub max_open_frames: u32,
}

impl FrameOrder {
    /// One interactive client's frame (the [`Scheduler::submit_frame`] and
    /// [`Scheduler::queue_frame`] streams).
    fn single(width: u32, height: u32, queue: bool) -> Self {
        Self { client: 0, work: Work::Interactive, width, height, samples: 1, queue }
    }
}

impl Default for SchedulerConfig {
    fn default() -> Self {
        Self {
            tile_size: 32,
            min_tile_size: 8,
            queue_depth: 2,
            heartbeat_timeout: Duration::from_secs(5),
            duplicate_stragglers: true,
            max_open_frames: 4,
        }
    }
}

/// Why a slave was declared dead.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DeathCause {
    /// Nothing heard within the heartbeat timeout.
    Timeout,
    /// Its connection closed or broke.
    Disconnected,
}

/// What the driver must do next.
#[derive(Clone, Debug, PartialEq)]
pub enum Output {
    /// Send these tiles of `frame` to `slave`.
    Assign {
        /// The slave.
        slave: SlaveId,
        /// The frame.
        frame: FrameId,
        /// The tiles, in the order they should be rendered.
        tiles: Vec<TileJob>,
        /// How many of them had belonged to a slave that died.
        reassigned: u32,
    },
    /// Tell `slave` to drop these tiles if it has not started them.
    Cancel {
        /// The slave.
        slave: SlaveId,
        /// The frame.
        frame: FrameId,
        /// The tiles.
        tiles: Vec<TileId>,
    },
    /// `slave` was declared dead; `requeued` of its tiles went back to the queue.
    SlaveDead {
        /// The slave.
        slave: SlaveId,
        /// Its name.
        name: String,
        /// Why.
        cause: DeathCause,
        /// How many tiles are now waiting for someone else.
        requeued: u32,
    },
    /// Every pixel of `frame` has been delivered.
    FrameDone {
        /// The frame.
        frame: FrameId,
        /// How it went.
        stats: FrameStats,
    },
}

/// What became of a tile result.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResultOutcome {
    /// First result for this tile: deliver its pixels.
    Accepted {
        /// Where the pixels go.
        tile: Tile,
    },
    /// Another copy of the tile already won: drop it.
    Duplicate,
    /// The frame is no longer the open one: drop it.
    Stale,
    /// No such tile in the frame (or it was split after being handed out): drop it.
    Unknown,
    /// `slave` was never handed this tile: refused, nothing changed.
    Foreign,
}

/// Whether a slave's result for a tile may be taken, asked before its pixels
/// are looked at ([`Scheduler::check_result`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResultCheck {
    /// The slave was handed this tile, which is still outstanding: decode
    /// the pixels (they must cover this rectangle) and pass them to
    /// [`Scheduler::handle_result`].
    Held {
        /// The tile's rectangle.
        tile: Tile,
    },
    /// The slave was handed this tile, but it is already delivered (another
    /// copy won) or split: drop the result.
    Finished,
    /// The frame is no longer known (superseded or long completed): drop it.
    Stale,
    /// The frame is known but this slave was never handed this tile (or no
    /// such tile exists): a result that is not the slave's to give.
    Foreign,
}

/// Why a frame could not be started.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum SchedulerError {
    /// Frame ids must increase.
    #[error("frame {new} is not newer than frame {current}")]
    NotNewer {
        /// The rejected id.
        new: FrameId,
        /// The latest id.
        current: FrameId,
    },
    /// Zero-sized image.
    #[error("empty image {0}x{1}")]
    Empty(u32, u32),
    /// [`Scheduler::queue_frame`] with this many frames open already.
    #[error("{0} frames already open: wait for one to complete before queueing another")]
    TooManyFrames(u32),
}

/// A slave as the scheduler sees it.
#[derive(Clone, Debug, PartialEq)]
pub struct SlaveInfo {
    /// Its id.
    pub id: SlaveId,
    /// Its name.
    pub name: String,
    /// Its render threads.
    pub threads: u32,
    /// Tiles it holds now.
    pub in_flight: usize,
    /// Tiles of its that were accepted, over its life.
    pub tiles_done: u64,
    /// Pixels of its that were accepted, over its life.
    pub pixels_done: u64,
    /// Results it sent that lost to another copy or came too late.
    pub wasted: u64,
}

#[derive(Debug)]
struct SlaveState {
    name: String,
    threads: u32,
    last_seen: Duration,
    /// Tiles it holds, of any open frame.
    in_flight: BTreeSet<(FrameId, TileId)>,
    tiles_done: u64,
    pixels_done: u64,
    wasted: u64,
}

impl SlaveState {
    /// Takes every tile of `frame` this slave holds.
    fn take_frame(&mut self, frame: FrameId) -> Vec<TileId> {
        let tiles: Vec<TileId> =
            self.in_flight.range((frame, 0)..=(frame, TileId::MAX)).map(|&(_, t)| t).collect();
        for t in &tiles {
            self.in_flight.remove(&(frame, *t));
        }
        tiles
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum TileState {
    Queued,
    InFlight,
    Done,
    Split,
}

#[derive(Debug)]
struct TileRec {
    tile: Tile,
    state: TileState,
    holders: Vec<SlaveId>,
    /// Every slave this tile was ever handed to in this frame (holders past
    /// and present): only their results are the tile's.
    assigned: Vec<SlaveId>,
    assigned_at: Duration,
    /// Put back in the queue by a death and not handed out since.
    requeued: bool,
}

impl TileRec {
    /// Hands the tile to `slave` (as a holder, and for good as an assignee).
    fn hand_to(&mut self, slave: SlaveId) {
        self.holders.push(slave);
        if !self.assigned.contains(&slave) {
            self.assigned.push(slave);
        }
    }
}

#[derive(Debug)]
struct FrameState {
    id: FrameId,
    client: ClientId,
    work: Work,
    /// Samples per pixel: a pixel of this frame costs this much of its
    /// client's share.
    samples: u64,
    width: u32,
    height: u32,
    tiles: Vec<TileRec>,
    queue: VecDeque<TileId>,
    remaining_pixels: u64,
    started: Duration,
    done: bool,
    turnaround_sum: Duration,
    turnaround_n: u32,
    stats: FrameStats,
    /// The tiles out with one holder only, by when they were handed out
    /// (`TileRec::assigned_at`): the candidates a straggler copy is taken
    /// from, oldest first. Built at the first search for a straggler (the
    /// frame's end: until all its tiles are out there is none to copy) and
    /// from then kept exact as tiles are handed out, copied, moved,
    /// delivered and requeued, so finding a straggler costs a few steps
    /// however many tiles are out, and a frame pays nothing for it before.
    sole_held: Option<BTreeSet<(Duration, TileId)>>,
}

impl FrameState {
    /// The straggler candidates ([`FrameState::sole_held`]), built now if
    /// this is the first search, with the tiles they index.
    fn straggler_index(&mut self) -> (&BTreeSet<(Duration, TileId)>, &[TileRec]) {
        let tiles = &self.tiles;
        (self.sole_held.get_or_insert_with(|| sole_held_now(tiles)), tiles)
    }
}

/// The tiles of `tiles` out with one holder, by hand-out time: what
/// [`FrameState::sole_held`] holds once built.
fn sole_held_now(tiles: &[TileRec]) -> BTreeSet<(Duration, TileId)> {
    tiles
        .iter()
        .enumerate()
        .filter(|(_, r)| r.state == TileState::InFlight && r.holders.len() == 1)
        .map(|(t, r)| (r.assigned_at, t as TileId))
        .collect()
}

/// Notes in a frame's straggler candidates ([`FrameState::sole_held`], if
/// built) that the tile handed out at `at` is out with one holder (`sole`) or
/// no longer is.
fn note_sole(index: &mut Option<BTreeSet<(Duration, TileId)>>, at: Duration, tile: TileId, sole: bool) {
    if let Some(set) = index {
        if sole {
            set.insert((at, tile));
        } else {
            set.remove(&(at, tile));
        }
    }
}

/// The scheduling state machine. See the [module docs](self).
#[derive(Debug)]
pub struct Scheduler {
    config: SchedulerConfig,
    slaves: BTreeMap<SlaveId, SlaveState>,
    /// Open frames, oldest first; the newest may be a completed one (kept so
    /// that late copies of its tiles count as duplicates, not stale).
    frames: VecDeque<FrameState>,
    last_frame: Option<FrameId>,
    outputs: VecDeque<Output>,
    /// Render cost per pixel measured so far, for ordering new frames' tiles.
    costs: cost::CostMap,
    /// Pixel-samples delivered to each client with open frames (fair share).
    served: BTreeMap<ClientId, u64>,
    /// Tiles handed out, for [`BATCH_FLOOR`].
    handed: u64,
    /// Slaves that may have room since work was last handed out (a result,
    /// a cancel, a join), possibly more than once: only they are offered
    /// tiles, so handing out a tile does not cost a pass over every slave of
    /// a large cluster.
    dirty: Vec<SlaveId>,
    /// Every slave may have room or there is new work (a frame opened or
    /// closed, tiles requeued): offer tiles to all.
    all_dirty: bool,
    /// When every idle slave was last looked at, at the end of the work.
    last_tail_pass: Duration,
    /// Render threads of all slaves together.
    total_threads: usize,
    /// The longest a slave declared dead for its silence had been silent.
    longest_silence: Duration,
    /// When the latest slave was declared dead for its silence.
    last_timeout_death: Option<Duration>,
    /// Buffers of [`Scheduler::schedule`], kept between calls.
    scratch: Scratch,
}

/// The working lists of one pass of [`Scheduler::schedule`], empty between
/// passes and kept with their capacity: a result at a time, a pass hands out
/// a tile or two, and its lists would otherwise be most of its allocations.
#[derive(Debug, Default)]
struct Scratch {
    /// The slaves offered tiles, least loaded first, with their load.
    keyed: Vec<(usize, SlaveId)>,
    /// The same slaves, in that order.
    order: Vec<SlaveId>,
    /// Open frames with tiles queued, in the order they are served.
    frames: Vec<usize>,
    /// Tiles handed out in this pass, by slave and frame, in the order
    /// handed out.
    batches: Vec<((SlaveId, FrameId), TileJob)>,
}

/// How often, at the end of the work, every idle slave is looked at for a
/// tile to move to it or copy (slaves whose results come in are looked at
/// at once).
const TAIL_PASS: Duration = Duration::from_millis(1);

impl Scheduler {
    /// An idle scheduler with no slaves and no frame.
    pub fn new(config: SchedulerConfig) -> Self {
        let mut config = config;
        config.tile_size = config.tile_size.max(1);
        config.min_tile_size = config.min_tile_size.clamp(1, config.tile_size);
        config.max_open_frames = config.max_open_frames.max(1);
        Self {
            config,
            slaves: BTreeMap::new(),
            frames: VecDeque::new(),
            last_frame: None,
            outputs: VecDeque::new(),
            costs: cost::CostMap::default(),
            served: BTreeMap::new(),
            handed: 0,
            dirty: Vec::new(),
            all_dirty: false,
            scratch: Scratch::default(),
            last_tail_pass: Duration::ZERO,
            total_threads: 0,
            longest_silence: Duration::ZERO,
            last_timeout_death: None,
        }
    }

    // ---- getters -------------------------------------------------------

    /// The configuration in force.
    pub fn config(&self) -> &SchedulerConfig {
        &self.config
    }

    /// The longest any slave declared dead for its silence had been silent
    /// when it was declared: the heartbeat timeout plus how late the
    /// declaration came (zero before the first such death).
    pub fn longest_silence(&self) -> Duration {
        self.longest_silence
    }

    /// When the latest slave declared dead for its silence was declared
    /// (its tiles went back to the queue in that same step).
    pub fn last_timeout_death(&self) -> Option<Duration> {
        self.last_timeout_death
    }

    /// The oldest open frame, if any (a completed frame is not open).
    pub fn open_frame(&self) -> Option<FrameId> {
        self.frames.iter().find(|f| !f.done).map(|f| f.id)
    }

    /// Every open frame, oldest first: the one being rendered, then those
    /// queued behind it ([`Scheduler::queue_frame`]).
    pub fn open_frames(&self) -> Vec<FrameId> {
        self.frames.iter().filter(|f| !f.done).map(|f| f.id).collect()
    }

    /// The rectangle of tile `id` of `frame`, if `frame` is still known
    /// (open, or the latest completed one).
    pub fn tile(&self, frame: FrameId, id: TileId) -> Option<Tile> {
        let f = self.frames.iter().find(|f| f.id == frame)?;
        f.tiles.get(id as usize).map(|r| r.tile)
    }

    /// Whether a result from `slave` for tile `id` of `frame` may be taken:
    /// only a slave that was handed the tile may deliver it. Changes nothing.
    pub fn check_result(&self, slave: SlaveId, frame: FrameId, id: TileId) -> ResultCheck {
        let Some(f) = self.frames.iter().find(|f| f.id == frame) else { return ResultCheck::Stale };
        let Some(rec) = f.tiles.get(id as usize) else { return ResultCheck::Foreign };
        if !rec.assigned.contains(&slave) {
            return ResultCheck::Foreign;
        }
        match rec.state {
            TileState::Queued | TileState::InFlight => ResultCheck::Held { tile: rec.tile },
            TileState::Done | TileState::Split => ResultCheck::Finished,
        }
    }

    /// Whether `slave` is alive in the scheduler's eyes.
    pub fn has_slave(&self, slave: SlaveId) -> bool {
        self.slaves.contains_key(&slave)
    }

    /// How many slaves are alive.
    pub fn slave_count(&self) -> usize {
        self.slaves.len()
    }

    /// The live slaves, by id.
    pub fn slaves(&self) -> Vec<SlaveInfo> {
        self.slaves
            .iter()
            .map(|(&id, s)| SlaveInfo {
                id,
                name: s.name.clone(),
                threads: s.threads,
                in_flight: s.in_flight.len(),
                tiles_done: s.tiles_done,
                pixels_done: s.pixels_done,
                wasted: s.wasted,
            })
            .collect()
    }

    /// The earliest time at which [`Scheduler::handle_timeout`] has work to do.
    pub fn poll_timeout(&self) -> Option<Duration> {
        self.slaves.values().map(|s| s.last_seen + self.config.heartbeat_timeout).min()
    }

    // ---- inputs ---------------------------------------------------------

    /// A slave is ready for work (it may join in the middle of a frame).
    pub fn handle_join(&mut self, now: Duration, slave: SlaveId, name: impl Into<String>, threads: u32) {
        let state = SlaveState {
            name: name.into(),
            threads: threads.clamp(1, 1024),
            last_seen: now,
            in_flight: BTreeSet::new(),
            tiles_done: 0,
            pixels_done: 0,
            wasted: 0,
        };
        self.total_threads += state.threads as usize;
        if let Some(old) = self.slaves.insert(slave, state) {
            // Rejoining under the same id: forget what it held before.
            tracing::debug!(slave, "slave re-joined under the same id");
            self.total_threads -= old.threads as usize;
        }
        self.dirty.push(slave);
    }

    /// Any sign of life from a slave.
    pub fn handle_heartbeat(&mut self, now: Duration, slave: SlaveId) {
        if let Some(s) = self.slaves.get_mut(&slave) {
            s.last_seen = s.last_seen.max(now);
        }
    }

    /// A slave's connection closed: declare it dead now.
    pub fn handle_disconnect(&mut self, _now: Duration, slave: SlaveId) {
        self.kill(slave, DeathCause::Disconnected);
    }

    /// Declares dead every slave silent for the heartbeat timeout.
    pub fn handle_timeout(&mut self, now: Duration) {
        let timeout = self.config.heartbeat_timeout;
        let dead: Vec<(SlaveId, Duration)> = self
            .slaves
            .iter()
            .filter(|(_, s)| now >= s.last_seen + timeout)
            .map(|(&id, s)| (id, now - s.last_seen))
            .collect();
        for (id, silence) in dead {
            self.longest_silence = self.longest_silence.max(silence);
            self.last_timeout_death = Some(now);
            self.kill(id, DeathCause::Timeout);
        }
    }

    /// Starts a frame of `width × height`, superseding every open frame (the
    /// one being rendered and any queued behind it), whoever's it was.
    pub fn submit_frame(
        &mut self,
        now: Duration,
        frame: FrameId,
        width: u32,
        height: u32,
    ) -> Result<(), SchedulerError> {
        self.check_new(frame, width, height)?;
        self.abandon_frame();
        self.open(now, frame, FrameOrder::single(width, height, false))
    }

    /// Queues a frame of `width × height` behind the open ones instead of
    /// superseding them: its tiles go out as soon as the older frames have no
    /// tile left to hand out, so slaves roll from one frame straight into the
    /// next (a replayed camera path). Frames still complete one by one, each
    /// with its own [`Output::FrameDone`]. At most
    /// [`SchedulerConfig::max_open_frames`] frames may be open.
    pub fn queue_frame(
        &mut self,
        now: Duration,
        frame: FrameId,
        width: u32,
        height: u32,
    ) -> Result<(), SchedulerError> {
        self.open(now, frame, FrameOrder::single(width, height, true))
    }

    /// Starts frame `frame` as `order` says. It supersedes the client's own
    /// open frames (other clients' frames go on), or with
    /// [`FrameOrder::queue`] waits behind them, as [`Scheduler::queue_frame`]
    /// does; a client may have at most [`SchedulerConfig::max_open_frames`]
    /// open. Between clients, tiles go out by kind of work and fair share
    /// (see [`Scheduler::served`]).
    pub fn open(&mut self, now: Duration, frame: FrameId, order: FrameOrder) -> Result<(), SchedulerError> {
        let FrameOrder { client, width, height, queue, .. } = order;
        self.check_new(frame, width, height)?;
        let mine: Vec<FrameId> =
            self.frames.iter().filter(|f| !f.done && f.client == client).map(|f| f.id).collect();
        if queue && mine.len() >= self.config.max_open_frames as usize {
            return Err(SchedulerError::TooManyFrames(self.config.max_open_frames));
        }
        if !queue {
            for id in mine {
                self.abandon(id);
            }
        }
        self.frames.retain(|f| !f.done);
        // A client coming back to work starts level with the least served
        // one still at work: no credit for the time it was away.
        if !self.frames.iter().any(|f| f.client == client) {
            let floor =
                self.frames.iter().filter_map(|f| self.served.get(&f.client)).min().copied().unwrap_or(0);
            let served = self.served.entry(client).or_default();
            *served = (*served).max(floor);
        }
        // A frame that waits behind others keeps full-size tiles: its end
        // is filled by the next frame's tiles (and the last one is split at
        // its end). Otherwise the edge suits the cluster's size.
        let edge = if queue {
            self.config.tile_size
        } else {
            let threads: u32 = self.slaves.values().map(|s| s.threads).sum();
            frame_tile_size(&self.config, width, height, threads)
        };
        self.push_frame(now, frame, order, edge);
        Ok(())
    }

    /// Pixel-samples delivered so far to each client that has open frames.
    /// The next tile goes to interactive work before batch work (but one in
    /// [`BATCH_FLOOR`] to batch work when both are queued), and within a
    /// kind to the least served client with a tile queued; a client whose
    /// frames all completed leaves the table, and returns level with the
    /// least served client then at work.
    pub fn served(&self) -> &BTreeMap<ClientId, u64> {
        &self.served
    }

    /// Drops every open frame (its requester went away, or a newer request
    /// supersedes it): slaves are told to cancel their tiles.
    pub fn abandon_frame(&mut self) {
        let ids: Vec<FrameId> = self.frames.iter().map(|f| f.id).collect();
        for id in ids {
            self.abandon(id);
        }
    }

    /// Drops `frame` alone (open or queued): slaves are told to cancel its tiles.
    pub fn abandon(&mut self, frame: FrameId) {
        let Some(i) = self.frames.iter().position(|f| f.id == frame) else { return };
        let Some(f) = self.frames.remove(i) else { return };
        if f.done {
            return;
        }
        for (&id, s) in self.slaves.iter_mut() {
            let tiles = s.take_frame(frame);
            if !tiles.is_empty() {
                self.outputs.push_back(Output::Cancel { slave: id, frame, tiles });
            }
        }
        self.all_dirty = true;
        self.forget_if_idle(f.client);
    }

    /// Drops `client` from the fair-share table once it has no open frame.
    fn forget_if_idle(&mut self, client: ClientId) {
        if !self.frames.iter().any(|f| !f.done && f.client == client) {
            self.served.remove(&client);
        }
    }

    /// A slave reports that tile `tile` of `frame` took `micros` to render (its
    /// own measure, untrusted: it only orders later frames' tiles). Call it
    /// for every result of a known frame, before [`Scheduler::handle_result`].
    pub fn record_render_time(&mut self, frame: FrameId, tile: TileId, micros: u64) {
        let Some(f) = self.frames.iter().find(|f| f.id == frame) else { return };
        let Some(rec) = f.tiles.get(tile as usize) else { return };
        self.costs.record(rec.tile, f.width, f.height, micros);
    }

    /// The render time expected for `tile` of a `width × height` frame from
    /// what was measured so far, in microseconds (0: nothing known there).
    pub fn expected_render_micros(&self, tile: Tile, width: u32, height: u32) -> f32 {
        self.costs.estimate(tile, width, height)
    }

    /// A slave returned tile `tile` of `frame`. Counts as a heartbeat.
    pub fn handle_result(
        &mut self,
        now: Duration,
        slave: SlaveId,
        frame: FrameId,
        tile: TileId,
    ) -> ResultOutcome {
        self.handle_heartbeat(now, slave);
        let Some(f) = self.frames.iter_mut().find(|f| f.id == frame) else {
            self.waste(slave);
            return ResultOutcome::Stale;
        };
        if f.tiles.get(tile as usize).is_some_and(|rec| !rec.assigned.contains(&slave)) {
            return ResultOutcome::Foreign;
        }
        if let Some(s) = self.slaves.get_mut(&slave) {
            s.in_flight.remove(&(frame, tile));
            self.dirty.push(slave);
        }
        let Some(rec) = f.tiles.get_mut(tile as usize) else {
            self.waste(slave);
            return ResultOutcome::Unknown;
        };
        match rec.state {
            TileState::Done => {
                self.waste(slave);
                return ResultOutcome::Duplicate;
            }
            TileState::Split => {
                self.waste(slave);
                return ResultOutcome::Unknown;
            }
            TileState::Queued | TileState::InFlight => {}
        }
        rec.state = TileState::Done;
        let rect = rec.tile;
        let pixels = rect.pixel_count() as u64;
        if rec.holders.contains(&slave) {
            f.turnaround_sum += now.saturating_sub(rec.assigned_at);
            f.turnaround_n += 1;
        }
        note_sole(&mut f.sole_held, rec.assigned_at, tile, false);
        for other in std::mem::take(&mut rec.holders) {
            if other == slave {
                continue;
            }
            if let Some(s) = self.slaves.get_mut(&other)
                && s.in_flight.remove(&(frame, tile))
            {
                self.dirty.push(other);
                self.outputs.push_back(Output::Cancel { slave: other, frame, tiles: vec![tile] });
            }
        }
        f.remaining_pixels -= pixels.min(f.remaining_pixels);
        f.stats.tiles += 1;
        let client = f.client;
        if let Some(served) = self.served.get_mut(&client) {
            *served += pixels * f.samples;
        }
        if let Some(s) = self.slaves.get_mut(&slave) {
            s.tiles_done += 1;
            s.pixels_done += pixels;
            *f.stats.per_slave.entry(s.name.clone()).or_default() += 1;
        }
        if f.remaining_pixels == 0 {
            f.done = true;
            f.stats.micros = now.saturating_sub(f.started).as_micros() as u64;
            let stats = f.stats.clone();
            self.outputs.push_back(Output::FrameDone { frame, stats });
            for (&id, s) in self.slaves.iter_mut() {
                let tiles = s.take_frame(frame);
                if !tiles.is_empty() {
                    self.outputs.push_back(Output::Cancel { slave: id, frame, tiles });
                }
            }
            self.all_dirty = true;
            // Keep a completed frame only while it is the newest one.
            let newest = self.frames.back().map(|f| f.id);
            self.frames.retain(|f| !f.done || Some(f.id) == newest);
            self.forget_if_idle(client);
        }
        ResultOutcome::Accepted { tile: rect }
    }

    // ---- outputs --------------------------------------------------------

    /// The next thing to do, if any. Hands out work when slaves have room.
    pub fn poll_output(&mut self, now: Duration) -> Option<Output> {
        if self.outputs.is_empty() {
            self.schedule(now);
        }
        self.outputs.pop_front()
    }

    /// Checks the straggler index of every open frame against the tiles it
    /// indexes: exactly the tiles out with one holder, at their hand-out time.
    #[cfg(test)]
    pub(crate) fn assert_sole_held_exact(&self) {
        for f in self.frames.iter().filter(|f| !f.done) {
            if let Some(index) = &f.sole_held {
                assert_eq!(index, &sole_held_now(&f.tiles), "frame {}: straggler index", f.id);
            }
        }
    }

    // ---- internals ------------------------------------------------------

    fn check_new(&self, frame: FrameId, width: u32, height: u32) -> Result<(), SchedulerError> {
        if width == 0 || height == 0 {
            return Err(SchedulerError::Empty(width, height));
        }
        if let Some(current) = self.last_frame.filter(|&c| frame <= c) {
            return Err(SchedulerError::NotNewer { new: frame, current });
        }
        Ok(())
    }

    fn push_frame(&mut self, now: Duration, frame: FrameId, order: FrameOrder, edge: u32) {
        let FrameOrder { client, work, width, height, samples, .. } = order;
        let tiles: Vec<TileRec> = Tile::grid(width, height, edge)
            .into_iter()
            .map(|tile| TileRec {
                tile,
                state: TileState::Queued,
                holders: Vec::new(),
                assigned: Vec::new(),
                assigned_at: now,
                requeued: false,
            })
            .collect();
        // Most expensive first, by what earlier frames measured.
        let rects: Vec<Tile> = tiles.iter().map(|r| r.tile).collect();
        let mut queue: Vec<TileId> = (0..tiles.len() as TileId).collect();
        self.costs.order(&mut queue, &rects, width, height);
        self.frames.push_back(FrameState {
            id: frame,
            client,
            work,
            samples: u64::from(samples.max(1)),
            width,
            height,
            queue: queue.into(),
            tiles,
            remaining_pixels: width as u64 * height as u64,
            started: now,
            done: false,
            turnaround_sum: Duration::ZERO,
            turnaround_n: 0,
            stats: FrameStats::default(),
            sole_held: None,
        });
        self.last_frame = Some(frame);
        self.all_dirty = true;
    }

    fn waste(&mut self, slave: SlaveId) {
        if let Some(s) = self.slaves.get_mut(&slave) {
            s.wasted += 1;
        }
    }

    fn kill(&mut self, slave: SlaveId, cause: DeathCause) {
        let Some(s) = self.slaves.remove(&slave) else { return };
        self.total_threads -= s.threads as usize;
        let mut requeued = 0;
        for f in self.frames.iter_mut().filter(|f| !f.done) {
            let mut n = 0;
            // Back to the front, in their original order.
            for &(_, tile) in s.in_flight.range((f.id, 0)..=(f.id, TileId::MAX)).rev() {
                let Some(rec) = f.tiles.get_mut(tile as usize) else { continue };
                rec.holders.retain(|&h| h != slave);
                if rec.state != TileState::InFlight {
                    continue;
                }
                match rec.holders.len() {
                    0 => {
                        rec.state = TileState::Queued;
                        rec.requeued = true;
                        note_sole(&mut f.sole_held, rec.assigned_at, tile, false);
                        f.queue.push_front(tile);
                        n += 1;
                    }
                    // A copy's other holder is left: it may be copied again.
                    1 => {
                        note_sole(&mut f.sole_held, rec.assigned_at, tile, true);
                    }
                    _ => {}
                }
            }
            f.stats.requeued += n;
            requeued += n;
        }
        self.all_dirty = true;
        self.outputs.push_back(Output::SlaveDead { slave, name: s.name, cause, requeued });
    }

    fn schedule(&mut self, now: Duration) {
        if self.frames.iter().all(|f| f.done) {
            // A frame that opens offers tiles to every slave.
            self.dirty.clear();
            return;
        }
        let cfg = &self.config;
        let total_threads = self.total_threads;
        // Tiles go to the slaves that may have room (those whose results or
        // cancels came in since), not past every slave of a large cluster;
        // all of them after a change that concerns all (a frame opened or
        // done, a death). At the end of the work (nothing queued), idle
        // slaves wait for tiles to move or copy, which depends on time too:
        // all of them are looked at again every `TAIL_PASS`.
        let tail = !self.frames.iter().any(|f| !f.done && !f.queue.is_empty());
        let tail_pass = tail && now >= self.last_tail_pass + TAIL_PASS;
        if tail_pass {
            self.last_tail_pass = now;
        }
        let Scratch { mut keyed, mut order, frames: mut frame_order, mut batches } =
            std::mem::take(&mut self.scratch);
        // Least-loaded slaves first, then round-robin one tile at a time.
        let load = |s: &SlaveState| s.in_flight.len() * 1000 / (s.threads + cfg.queue_depth) as usize;
        if std::mem::take(&mut self.all_dirty) || tail_pass {
            keyed.extend(self.slaves.iter().map(|(&id, s)| (load(s), id)));
        } else {
            self.dirty.sort_unstable();
            self.dirty.dedup();
            keyed.extend(self.dirty.iter().filter_map(|id| self.slaves.get(id).map(|s| (load(s), *id))));
        }
        self.dirty.clear();
        keyed.sort_unstable();
        order.extend(keyed.iter().map(|&(_, id)| id));
        let mut reassigned: BTreeMap<(SlaveId, FrameId), u32> = BTreeMap::new();
        'rounds: loop {
            let mut progressed = false;
            for id in &order {
                let s = self.slaves.get_mut(id).expect("ordered ids are live");
                // Tiles still to hand out, of every open frame: a frame queued
                // behind this one means it has no end (no tail) to prepare for.
                let queued: usize = self.frames.iter().filter(|f| !f.done).map(|f| f.queue.len()).sum();
                let depth = if queued > total_threads { cfg.queue_depth } else { 0 };
                if s.in_flight.len() >= (s.threads + depth) as usize {
                    continue;
                }
                // Batch tiles only to idle threads, never queued behind busy
                // ones: interactive work arriving waits for no batch queue.
                let batch = s.in_flight.len() < s.threads as usize;
                let next = next_open_tile(
                    &mut self.frames,
                    cfg,
                    total_threads,
                    &self.served,
                    self.handed,
                    batch,
                    &mut frame_order,
                );
                let Some((fi, tile)) = next else {
                    if batch {
                        break 'rounds;
                    }
                    continue;
                };
                self.handed += 1;
                let f = &mut self.frames[fi];
                let rec = &mut f.tiles[tile as usize];
                rec.state = TileState::InFlight;
                rec.hand_to(*id);
                rec.assigned_at = now;
                note_sole(&mut f.sole_held, now, tile, true);
                if std::mem::take(&mut rec.requeued) {
                    *reassigned.entry((*id, f.id)).or_default() += 1;
                }
                s.in_flight.insert((f.id, tile));
                batches.push(((*id, f.id), TileJob { id: tile, tile: rec.tile }));
                progressed = true;
            }
            if !progressed {
                break;
            }
        }
        let all_handed_out = self.frames.iter().filter(|f| !f.done).all(|f| f.queue.is_empty());
        if all_handed_out {
            move_waiting_tiles(
                &mut self.slaves,
                &mut self.frames,
                &order,
                now,
                &mut batches,
                &mut self.outputs,
            );
        }
        if cfg.duplicate_stragglers && all_handed_out {
            for id in &order {
                let s = self.slaves.get_mut(id).expect("ordered ids are live");
                while s.in_flight.len() < s.threads as usize {
                    // The oldest tile out longer than its frame's mean turnaround.
                    let straggler = self
                        .frames
                        .iter_mut()
                        .enumerate()
                        .filter(|(_, f)| !f.done && f.turnaround_n > 0)
                        .filter_map(|(fi, f)| oldest_straggler(f, *id, now).map(|(at, t)| (at, fi, t)))
                        .min();
                    let Some((_, fi, tile)) = straggler else { break };
                    let f = &mut self.frames[fi];
                    note_sole(&mut f.sole_held, f.tiles[tile as usize].assigned_at, tile, false);
                    let rec = &mut f.tiles[tile as usize];
                    rec.hand_to(*id);
                    s.in_flight.insert((f.id, tile));
                    f.stats.duplicated += 1;
                    batches.push(((*id, f.id), TileJob { id: tile, tile: rec.tile }));
                }
            }
        }
        // One assignment per slave and frame, in that order, its tiles in
        // the order they were handed out (the sort is stable).
        batches.sort_by_key(|&(key, _)| key);
        for batch in batches.chunk_by(|a, b| a.0 == b.0) {
            let (slave, frame) = batch[0].0;
            let tiles = batch.iter().map(|&(_, job)| job).collect();
            let reassigned = reassigned.get(&(slave, frame)).copied().unwrap_or(0);
            self.outputs.push_back(Output::Assign { slave, frame, tiles, reassigned });
        }
        keyed.clear();
        order.clear();
        frame_order.clear();
        batches.clear();
        self.scratch = Scratch { keyed, order, frames: frame_order, batches };
    }
}

/// Tiles a frame needs per render thread in the cluster before the tile edge
/// stops shrinking: fewer, and the last round of tiles leaves threads idle.
const TILES_PER_THREAD: u32 = 8;

/// Smallest edge [`frame_tile_size`] shrinks to: below it the per-tile cost
/// (a message, a stream, a round trip) outweighs the finer balance.
const SMALLEST_FRAME_TILE: u32 = 16;

/// The tile edge for a `width × height` frame on a cluster of `threads` render
/// threads: [`SchedulerConfig::tile_size`], halved while the frame would have
/// fewer than [`TILES_PER_THREAD`] tiles per thread.
fn frame_tile_size(cfg: &SchedulerConfig, width: u32, height: u32, threads: u32) -> u32 {
    let floor = SMALLEST_FRAME_TILE.max(cfg.min_tile_size);
    let mut edge = cfg.tile_size;
    let count = |e: u32| u64::from(width.div_ceil(e)) * u64::from(height.div_ceil(e));
    while edge / 2 >= floor && count(edge) < u64::from(TILES_PER_THREAD) * u64::from(threads) {
        edge /= 2;
    }
    edge
}

/// The oldest tile of `f` out longer than the frame's mean turnaround and
/// held by one slave only, not `slave` (with when it was handed out). Only
/// `slave`'s own tiles are stepped over, so the cost is bounded by what one
/// slave holds, not by the tiles out.
fn oldest_straggler(f: &mut FrameState, slave: SlaveId, now: Duration) -> Option<(Duration, TileId)> {
    let mean = f.turnaround_sum / f.turnaround_n.max(1);
    let (index, tiles) = f.straggler_index();
    index
        .iter()
        .take_while(|&&(at, _)| now.saturating_sub(at) > mean)
        .find(|&&(_, t)| tiles.get(t as usize).is_some_and(|r| !r.holders.contains(&slave)))
        .copied()
}

/// Gives each slave with an idle thread the newest tile waiting behind busy
/// threads on another slave (the most backed-up one first), and tells that
/// slave to cancel it.
fn move_waiting_tiles(
    slaves: &mut BTreeMap<SlaveId, SlaveState>,
    frames: &mut VecDeque<FrameState>,
    order: &[SlaveId],
    now: Duration,
    batches: &mut Vec<((SlaveId, FrameId), TileJob)>,
    outputs: &mut VecDeque<Output>,
) {
    // Tiles waiting beyond their slave's threads, the most backed-up slave
    // on top (kept up to date as tiles move: one pass over the slaves).
    let waiting = |s: &SlaveState| s.in_flight.len().saturating_sub(s.threads as usize);
    let mut victims: std::collections::BinaryHeap<(usize, SlaveId)> =
        slaves.iter().map(|(&v, s)| (waiting(s), v)).filter(|&(w, _)| w > 0).collect();
    for id in order {
        while slaves.get(id).is_some_and(|s| s.in_flight.len() < s.threads as usize) {
            // The slave with the most tiles beyond its threads, not this one.
            let mine = victims.peek().filter(|&&(_, v)| v == *id).copied();
            if mine.is_some() {
                victims.pop();
            }
            let top = victims.pop();
            victims.extend(mine);
            let Some((_, victim)) = top else { return };
            let vs = slaves.get_mut(&victim).expect("victim is live");
            // Its newest sole-held tile: the one furthest back in its queue.
            let newest = vs
                .in_flight
                .iter()
                .filter_map(|&(frame, t)| {
                    let fi = frames.iter().position(|f| f.id == frame && !f.done)?;
                    let r = frames[fi].tiles.get(t as usize)?;
                    let sole = r.state == TileState::InFlight && r.holders.as_slice() == [victim];
                    sole.then_some((r.assigned_at, frame, t, fi))
                })
                .max();
            let Some((_, frame, tile, fi)) = newest else { return };
            vs.in_flight.remove(&(frame, tile));
            if waiting(vs) > 0 {
                victims.push((waiting(vs), victim));
            }
            outputs.push_back(Output::Cancel { slave: victim, frame, tiles: vec![tile] });
            let f = &mut frames[fi];
            note_sole(&mut f.sole_held, f.tiles[tile as usize].assigned_at, tile, false);
            let rec = &mut f.tiles[tile as usize];
            rec.holders.clear();
            rec.hand_to(*id);
            rec.assigned_at = now;
            let job = TileJob { id: tile, tile: rec.tile };
            note_sole(&mut f.sole_held, now, tile, true);
            f.stats.moved += 1;
            let s = slaves.get_mut(id).expect("ordered ids are live");
            s.in_flight.insert((frame, tile));
            batches.push(((*id, frame), job));
        }
    }
}

/// Takes the next tile to hand out: interactive work first (but see
/// [`BATCH_FLOOR`]; `handed` counts the tiles handed out so far), then the
/// least served client (see [`Scheduler::served`]) that has a tile queued,
/// its oldest frame first (so with one client, the oldest open frame that
/// has one); batch work only if `batch`. Returns the frame's index in
/// `frames` and the tile.
fn next_open_tile(
    frames: &mut VecDeque<FrameState>,
    cfg: &SchedulerConfig,
    total_threads: usize,
    served: &BTreeMap<ClientId, u64>,
    handed: u64,
    batch: bool,
    order: &mut Vec<usize>,
) -> Option<(usize, TileId)> {
    // Tiles queued in the other frames: with enough of them, the end of a
    // frame is not the end of the work, and its tiles need no splitting.
    let queued: usize = frames.iter().filter(|f| !f.done).map(|f| f.queue.len()).sum();
    order.clear();
    order.extend((0..frames.len()).filter(|&i| {
        !frames[i].done && !frames[i].queue.is_empty() && (batch || frames[i].work != Work::Batch)
    }));
    // Interactive first, but one tile in BATCH_FLOOR to batch when both wait.
    let batch_turn = handed % BATCH_FLOOR == BATCH_FLOOR - 1;
    order.sort_by_key(|&i| {
        let f = &frames[i];
        let kind = if batch_turn { f.work != Work::Batch } else { f.work != Work::Interactive };
        (kind, served.get(&f.client).copied().unwrap_or(0), i)
    });
    for &i in order.iter() {
        let behind = queued - frames[i].queue.len();
        if let Some(tile) = next_tile(&mut frames[i], cfg, total_threads, behind) {
            return Some((i, tile));
        }
    }
    None
}

/// Takes the next queued tile of `f`, splitting it first when little work is
/// left (fewer tiles queued, here and in the `behind` tiles of later frames,
/// than the cluster has threads).
fn next_tile(
    f: &mut FrameState,
    cfg: &SchedulerConfig,
    total_threads: usize,
    behind: usize,
) -> Option<TileId> {
    loop {
        let id = f.queue.pop_front()?;
        let rec = &f.tiles[id as usize];
        if rec.state != TileState::Queued {
            continue; // delivered by another copy while queued, or split
        }
        let t = rec.tile;
        let splittable = t.w > cfg.min_tile_size || t.h > cfg.min_tile_size;
        if splittable && f.queue.len() + behind < total_threads {
            let children = split(t, cfg.min_tile_size);
            let requeued = rec.requeued;
            f.tiles[id as usize].state = TileState::Split;
            let first = f.tiles.len() as TileId;
            for i in (0..children.len()).rev() {
                f.queue.push_front(first + i as TileId);
            }
            for c in children {
                f.tiles.push(TileRec {
                    tile: c,
                    state: TileState::Queued,
                    holders: Vec::new(),
                    assigned: Vec::new(),
                    assigned_at: Duration::ZERO,
                    requeued,
                });
            }
            continue;
        }
        return Some(id);
    }
}

/// Halves a tile along each axis that is larger than `min`.
fn split(t: Tile, min: u32) -> Vec<Tile> {
    let halves = |start: u32, len: u32| -> Vec<(u32, u32)> {
        if len > min {
            let a = len.div_ceil(2);
            vec![(start, a), (start + a, len - a)]
        } else {
            vec![(start, len)]
        }
    };
    let mut out = Vec::with_capacity(4);
    for (y, h) in halves(t.y, t.h) {
        for (x, w) in halves(t.x, t.w) {
            out.push(Tile { x, y, w, h });
        }
    }
    out
}

#[cfg(test)]
mod tests;

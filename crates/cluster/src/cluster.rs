//! The master as a state machine: every peer, its handshake and its
//! liveness, the slave roster, the frames and their cameras, scene sync, the
//! superseding rule and the [`Scheduler`] — with no sockets, no clock and no
//! runtime.
//!
//! # Driving it
//!
//! quinn-proto's shape. The driver (the master actor) numbers connections and
//! reports what happens to them — [`Cluster::handle_connected`],
//! [`Cluster::handle_frame`] (or [`Cluster::handle_message`] with a decoded
//! one), [`Cluster::handle_transport_error`], [`Cluster::handle_closed`] — and
//! calls [`Cluster::handle_timeout`] when [`Cluster::poll_timeout`] says (or on
//! a periodic tick). After each call it drains [`Cluster::poll_transmit`]:
//! messages to send, each with its delivery [`Class`], frame limits to apply,
//! connections to close. Time is an argument (`now`, a [`Duration`] since any
//! fixed origin), so tests run whole clusters on a virtual clock.
//!
//! # What it decides
//!
//! - **Who gets in.** A new connection is challenged with a fresh nonce; a
//!   peer proves the token by HMAC ([`crate::auth`]) and gets a proof back.
//!   Slaves then receive the scene (unless they hold one with its hash:
//!   then nothing) and say `Ready`; only then do they join the scheduler and
//!   the roster. A scene travels packed once ([`crate::scene_stream`]:
//!   compressed, in chunks whose frames every slave shares), with at most
//!   [`ClusterConfig::scene_window`] chunks in flight per slave beyond those
//!   it acknowledged ([`Message::SceneAck`]), so a stalled slave holds up
//!   only its own transfer; an acknowledgement of chunks never sent drops
//!   the slave.
//! - **Which tiles go where, who is dead**: the [`Scheduler`].
//! - **Which frames are open.** Every viewer is a client with its own stream
//!   of frames: its `FrameRequest` supersedes its own open frames and no one
//!   else's; a `QueueFrame` waits behind them. Between viewers, tiles go out
//!   by fair share of pixel-samples (the scheduler's docs say how), so two
//!   people flying through the scene each keep half the cluster. A viewer
//!   that leaves takes its frames.
//! - **Which scene a frame is of.** The master may serve a default scene;
//!   a client may upload its own ([`Message::SceneUpload`], then its
//!   chunks, within [`Budgets::uploading_bytes`] for all uploads at once),
//!   and every frame names its scene. Scenes are held by
//!   content hash within [`Budgets::scene_bytes`] (least recently used idle
//!   scenes evicted first; none of an open frame). A slave receives the
//!   default scene at join and any other the first time it is handed a tile
//!   of it and asks ([`Message::NeedScene`]); slaves keep scenes by hash, so
//!   switching back costs nothing. A frame's scene is part of its identity:
//!   its tiles are the bytes of a local render of that scene.
//! - **Batch jobs.** A client may declare that its frames are a job
//!   ([`Message::SubmitJob`]); the master records each frame of it that
//!   completes ([`Transmit::Store`], written by the driver before the frame's
//!   `FrameDone` goes out) so that a restarted master tells the returning
//!   client which frames are done ([`Message::JobAccepted`]).
//! - **What viewers hear**: tiles as they arrive (in a codec they decode),
//!   `FrameDone`, the slave list whenever it changes, once a `Notice` when
//!   their frames wait because no slave is connected, and the cluster's
//!   [`Status`] whenever a slave joins or dies and every second while frames
//!   are open.
//!
//! # What it trusts
//!
//! Nothing a peer sends before it has proved the token, and after that only
//! what its role may say:
//!
//! - **Tiles only from their slaves.** A result is taken only from a slave
//!   the tile was handed to ([`Scheduler::check_result`]), before its pixels
//!   are looked at; its rectangle must be the one handed out and its pixels
//!   must decode to exactly that size. A result for a tile the slave was never
//!   handed is refused and counted; past [`Budgets::foreign_results`] the
//!   slave is disconnected. So no slave can overwrite another's pixels.
//! - **Role-sized frames.** Until it has proved the token a peer may send
//!   [`HANDSHAKE_MAX_FRAME`] bytes a frame; then a viewer
//!   [`VIEWER_MAX_FRAME`] (a scene chunk's, [`limits::SCENE_CHUNK_FRAME`],
//!   while it uploads a scene it announced), a slave one tile's worst-case encoding
//!   ([`limits::slave_max_frame`]). The limit goes to the transport
//!   ([`Transmit::Limit`]), which refuses a longer announced frame before
//!   allocating it, and is checked again here.
//! - **Liveness for everyone.** A peer that has not proved the token within
//!   [`ClusterConfig::handshake_timeout`] is dropped; after login every peer
//!   must be heard from (any message; slaves and viewers heartbeat) within the
//!   scheduler's heartbeat timeout, and a slave must finish loading the scene
//!   within [`ClusterConfig::sync_timeout`]. A stalled peer of any role is
//!   dropped on any transport.
//! - **Bounded numbers of peers.** At most [`Budgets::max_peers`] connections
//!   and [`Budgets::max_handshaking`] unauthenticated ones; one more is
//!   refused at once, with a log line saying which limit.
//! - **Nothing of the master's file system on the wire.** Peers learn the
//!   scene's file name, never its path.
//!
//! # Budgets
//!
//! [`Budgets`] holds the numbers, each with its reason;
//! [`Budgets::buffered_bytes`] is the one the driver hands to the transport
//! (bytes of all frames still being read, together). With the defaults, 2,048
//! peers at their largest announced frames hold at most 256 MiB
//! (`buffered_bytes`) in partial frames, and each peer's frame is refused
//! above 16 KiB (handshake, viewers) or one tile's bytes (slaves, ~20 KiB for
//! 32-pixel tiles).

mod jobs;
mod roster;
mod scenes;
#[cfg(test)]
mod tests;
mod transfers;

pub use jobs::JobRecord;
pub use roster::DEAD_SLAVES_LISTED;
pub use scenes::StoreError;
pub use transfers::AckError;

use crate::auth::{self, Nonces};
use crate::codec::{self, Codec, Compression};
use crate::limits::{self, Budgets, VIEWER_MAX_FRAME};
use crate::protocol::{
    self, ClientStatus, DirectOffer, DirectRoute, FrameId, FrameStats, HANDSHAKE_MAX_FRAME, Hello, JobSpec,
    MAX_DIRECT_ADDR, MAX_DIRECT_FINGERPRINT, MAX_JOB_FRAMES, Message, ProtocolError, Role, SceneHash,
    SceneHeader, SceneInfo, SlaveStatus, Status, TileAssignment, TileReceived, TileResultRef, Welcome,
};
use crate::scene_stream::{Packed, ProgressLog, Receiver};
use crate::scheduler::{
    DeathCause, FrameOrder, Output, ResultCheck, ResultOutcome, Scheduler, SchedulerConfig, SlaveInfo, Work,
};
use isin_tracer::{Camera, RenderSettings, SceneBundle};
use jobs::Jobs;
use roster::Roster;
use scenes::Scenes;
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::sync::Arc;
use std::time::Duration;
use transfers::Transfers;

/// A connection, numbered by the driver (never reused).
pub type PeerId = u64;

/// How a message may travel relative to the others on its connection.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Class {
    /// In order with everything else.
    Control,
    /// A tile's pixels: may overtake other tiles (never a control message).
    Tile,
}

/// What the driver must do.
// Messages travel by value: the queue is drained at once, and boxing each
// would cost an allocation per tile.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq)]
pub enum Transmit {
    /// Send `message` to `peer`.
    Send {
        /// The connection.
        peer: PeerId,
        /// The message.
        message: Message,
        /// How it travels.
        class: Class,
    },
    /// Send a frame the core encoded itself (a forwarded tile written in
    /// place, or an assignment from its frame's encoded head).
    SendFrame {
        /// The connection.
        peer: PeerId,
        /// The frame.
        frame: Vec<u8>,
        /// How it travels.
        class: Class,
    },
    /// Send an already encoded frame (a scene's `SceneBegin` or one of its
    /// chunks, encoded once for every slave), in order.
    SendEncoded {
        /// The connection.
        peer: PeerId,
        /// The frame.
        frame: Arc<Vec<u8>>,
    },
    /// From now on, refuse frames longer than `max_frame` from `peer`
    /// before reading them.
    Limit {
        /// The connection.
        peer: PeerId,
        /// Largest frame accepted.
        max_frame: usize,
    },
    /// Close the connection once what was queued for it is sent. The core
    /// has forgotten the peer; later events about it are ignored.
    Close {
        /// The connection.
        peer: PeerId,
        /// Why, for logs.
        reason: String,
    },
    /// Keep this on disk, if the master has a state directory, before doing
    /// what follows it (the core acknowledges nothing stored until then).
    Store(Stored),
}

/// What the master keeps across restarts ([`Transmit::Store`]); read back
/// with [`Cluster::restore_scene`] and [`Cluster::restore_job`].
#[derive(Clone, Debug, PartialEq)]
pub enum Stored {
    /// A scene a client uploaded, packed ([`Packed::to_stored`]).
    Scene {
        /// Its hash (a file name for it).
        hash: SceneHash,
        /// The stored form.
        bytes: Arc<Vec<u8>>,
    },
    /// A scene no longer held.
    ForgetScene {
        /// Its hash.
        hash: SceneHash,
    },
    /// A batch job, as it stands now.
    Job(JobRecord),
}

impl Transmit {
    /// The connection it concerns.
    pub fn peer(&self) -> PeerId {
        match self {
            Transmit::Send { peer, .. }
            | Transmit::SendEncoded { peer, .. }
            | Transmit::SendFrame { peer, .. }
            | Transmit::Limit { peer, .. }
            | Transmit::Close { peer, .. } => *peer,
            Transmit::Store(_) => PeerId::MAX,
        }
    }
}

/// The scene a master serves to clients that name none.
#[derive(Clone, Debug)]
pub struct DefaultScene {
    /// The scene. Only its file name goes to peers.
    pub bundle: SceneBundle,
    /// The scene's own camera (offered to viewers).
    pub camera: Camera,
    /// The scene's own settings (offered to viewers).
    pub settings: RenderSettings,
}

/// How the master runs.
#[derive(Clone, Debug)]
pub struct ClusterConfig {
    /// The shared secret peers must prove.
    pub token: String,
    /// The scene served to clients that name none, if any.
    pub scene: Option<DefaultScene>,
    /// Scheduling knobs; its heartbeat timeout is every logged-in peer's.
    pub scheduler: SchedulerConfig,
    /// How often the master tells peers it is alive.
    pub heartbeat_interval: Duration,
    /// A peer that has not proved the token within this is dropped.
    pub handshake_timeout: Duration,
    /// A slave that has not loaded the scene (said `Ready`) within this of
    /// its login is dropped, heartbeats or not.
    pub sync_timeout: Duration,
    /// Which tile codec to pick among those a peer offers.
    pub compression: Compression,
    /// What peers may make the master hold.
    pub budgets: Budgets,
    /// Seed of the challenge nonces (32 random bytes; see [`Nonces`]).
    pub seed: [u8; 32],
    /// Chunks of a scene in flight to one slave beyond those it has
    /// acknowledged (at least 1): four 256 KiB chunks keep a 1 Gbit/s link
    /// with a few milliseconds of round trip busy.
    pub scene_window: u32,
}

impl ClusterConfig {
    /// Defaults around a token, a default scene (or none) and a nonce seed.
    pub fn new(token: String, scene: Option<DefaultScene>, seed: [u8; 32]) -> Self {
        Self {
            token,
            scene,
            scheduler: SchedulerConfig::default(),
            heartbeat_interval: Duration::from_millis(500),
            handshake_timeout: Duration::from_secs(10),
            sync_timeout: Duration::from_secs(600),
            compression: Compression::Auto,
            budgets: Budgets::default(),
            seed,
            scene_window: 4,
        }
    }
}

/// Counters of the whole master.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ClusterStatus {
    /// The live slaves.
    pub slaves: Vec<SlaveInfo>,
    /// Connections open now, of every role and state.
    pub peers: usize,
    /// Frame requests accepted from viewers.
    pub frames_requested: u64,
    /// Frames completed.
    pub frames_done: u64,
    /// Connections refused (bad token, bad protocol, garbage, over a limit).
    pub refused: u64,
    /// Slaves declared dead.
    pub deaths: u64,
    /// Tile results refused because their slave was never handed the tile.
    pub foreign_results: u64,
    /// Last completed frame's stats.
    pub last_frame: Option<FrameStats>,
    /// Scenes sent to slaves (at join or when they asked).
    pub scene_sends: u64,
    /// Bytes of the scene frames sent to slaves (`SceneBegin` and chunks).
    pub scene_bytes_sent: u64,
}

#[derive(Debug)]
enum PeerState {
    /// Challenged with this nonce; nothing proved yet.
    AwaitHello { nonce: [u8; 32] },
    /// A slave that proved the token, loading the scene since `since`.
    Syncing { threads: u32, since: Duration },
    /// A slave in the scheduler.
    Slave,
    /// A viewer (a client of its own).
    Viewer(Client),
}

/// A client's state.
#[derive(Debug, Default)]
struct Client {
    /// Its kind of work.
    work: Work,
    /// Its open frames.
    frames: BTreeSet<FrameId>,
    /// Whether it was told that its frames wait for slaves.
    told_waiting: bool,
    /// The scene it is uploading, and the log of its progress.
    upload: Option<Box<(Receiver, ProgressLog)>>,
    /// The job its frames belong to.
    job: Option<SceneHash>,
    /// Frames completed for it.
    frames_done: u64,
    /// Where slaves may send its tiles straight ([`Hello::direct`]).
    direct: Option<DirectOffer>,
}

#[derive(Debug)]
struct Peer {
    addr: String,
    name: String,
    state: PeerState,
    /// When it connected.
    since: Duration,
    /// When it last said anything.
    last_heard: Duration,
    /// Largest frame it may send now.
    max_frame: usize,
    /// The codec picked at join (the `Welcome` says it): slaves encode their
    /// tiles with it.
    codec: Codec,
    /// Viewers: every codec they offered (tiles in another are sent raw).
    decodes: Vec<Codec>,
    /// Results it sent for tiles it was never handed.
    foreign: u32,
    /// Scenes sent to it (slaves).
    scene_sends: u32,
    /// Viewers whose direct offer it was sent (slaves).
    offers_sent: BTreeSet<PeerId>,
}

/// A frame the master has open, as its viewer asked for it.
#[derive(Debug)]
struct FrameSpec {
    scene: SceneHash,
    job_frame: Option<u32>,
    camera: Camera,
    settings: RenderSettings,
    viewer: PeerId,
    request: u64,
    /// Bytes received when it was requested.
    bytes_at_start: u64,
    /// Where its slaves deliver its tiles straight (its viewer's offer).
    direct: Option<DirectOffer>,
    /// Tiles that went straight to the viewer.
    delivered: u32,
    /// What every assignment of the frame starts with, encoded once (`None`
    /// if it could not be: each assignment is then encoded whole).
    head: Option<protocol::AssignmentHead>,
}

/// The master's state machine. See the [module docs](self).
#[derive(Debug)]
pub struct Cluster {
    token: String,
    scene: Option<SceneInfo>,
    scenes: Scenes,
    transfers: Transfers,
    jobs: Jobs,
    heartbeat_interval: Duration,
    handshake_timeout: Duration,
    sync_timeout: Duration,
    compression: Compression,
    budgets: Budgets,
    slave_max_frame: usize,
    nonces: Nonces,
    sched: Scheduler,
    peers: BTreeMap<PeerId, Peer>,
    /// Peers in [`PeerState::AwaitHello`].
    handshaking: usize,
    frames: BTreeMap<FrameId, FrameSpec>,
    next_frame: FrameId,
    roster: Roster,
    /// When viewers are next told of joins and deaths (the roster and a
    /// status), if any are untold.
    roster_due: Option<Duration>,
    /// When viewers were last told of them.
    roster_told: Option<Duration>,
    out: VecDeque<Transmit>,
    last_heartbeat: Duration,
    /// Bytes of the uploads in progress, as their headers declare them.
    uploading: u64,
    /// Message bytes received from every peer so far.
    bytes_received: u64,
    /// Bytes received when the last frame completed: a pipelined frame counts
    /// the bytes from there (or from its request, if later).
    bytes_at_last_done: u64,
    status: ClusterStatus,
    /// Where tiles are decoded for a viewer that cannot decode their codec
    /// (reused: no allocation per tile).
    scratch: Vec<u8>,
    /// Picks the tiles of direct frames the master checks itself
    /// ([`protocol::via_master`]); slaves never learn it.
    verify_secret: [u8; 32],
    /// When the status was last pushed, and each slave's tiles then (for
    /// its rate).
    last_status: Duration,
    tiles_then: BTreeMap<PeerId, (u64, f32)>,
}

/// How often viewers are sent the [`Status`] while frames are open.
pub const STATUS_INTERVAL: Duration = Duration::from_secs(1);

/// Joins and deaths are told to viewers (a roster and a status, each the
/// size of the cluster) at most this often: a hundred slaves dying within a
/// few milliseconds are one list, not a hundred lists of a thousand slaves
/// that would hold up the master's work — the declaring of the later deaths
/// among it.
pub const ROSTER_INTERVAL: Duration = Duration::from_millis(50);

impl Cluster {
    /// A master for `cfg`; fails only if the scene cannot be encoded.
    pub fn new(cfg: ClusterConfig) -> Result<Self, ProtocolError> {
        let mut scenes = Scenes::new(cfg.budgets.scene_bytes);
        let scene = match cfg.scene {
            None => None,
            Some(DefaultScene { mut bundle, camera, settings }) => {
                bundle.name = protocol::served_name(&bundle.name).to_string();
                let hash = match scenes.insert(&bundle, true) {
                    Ok((hash, _)) => hash,
                    Err(e) => return Err(ProtocolError::Encode(e.to_string())),
                };
                Some(SceneInfo { name: bundle.name, hash, camera, settings })
            }
        };
        let jobs = Jobs::new(cfg.budgets.max_jobs);
        let sched = Scheduler::new(cfg.scheduler);
        let slave_max_frame = limits::slave_max_frame(sched.config().tile_size);
        Ok(Self {
            token: cfg.token,
            scene,
            scenes,
            transfers: Transfers::new(cfg.scene_window),
            jobs,
            heartbeat_interval: cfg.heartbeat_interval,
            handshake_timeout: cfg.handshake_timeout,
            sync_timeout: cfg.sync_timeout,
            compression: cfg.compression,
            budgets: cfg.budgets,
            slave_max_frame,
            nonces: Nonces::new(cfg.seed),
            verify_secret: auth::derive(&cfg.seed, b"isin direct tiles checked by the master"),
            sched,
            peers: BTreeMap::new(),
            handshaking: 0,
            frames: BTreeMap::new(),
            next_frame: 1,
            roster: Roster::default(),
            roster_due: None,
            roster_told: None,
            out: VecDeque::new(),
            last_heartbeat: Duration::ZERO,
            uploading: 0,
            bytes_received: 0,
            bytes_at_last_done: 0,
            status: ClusterStatus::default(),
            scratch: Vec::new(),
            last_status: Duration::ZERO,
            tiles_then: BTreeMap::new(),
        })
    }

    /// Holds a scene read back from a state directory (as
    /// [`Stored::Scene`] gave it); its hash is checked.
    pub fn restore_scene(&mut self, stored: &[u8]) -> Result<SceneHash, String> {
        self.scenes.insert_stored(stored)
    }

    /// Knows a job read back from a state directory: its client resumes it
    /// by submitting it again.
    pub fn restore_job(&mut self, now: Duration, record: JobRecord) {
        self.jobs.restore(now, record);
    }

    // ---- getters -------------------------------------------------------

    /// The default scene, as peers are told of it.
    pub fn scene(&self) -> Option<&SceneInfo> {
        self.scene.as_ref()
    }

    /// The budgets in force.
    pub fn budgets(&self) -> &Budgets {
        &self.budgets
    }

    /// The master's counters.
    pub fn status(&self) -> ClusterStatus {
        ClusterStatus { slaves: self.sched.slaves(), peers: self.peers.len(), ..self.status.clone() }
    }

    /// Slaves declared dead so far: [`ClusterStatus::deaths`] without
    /// building the rest of [`Cluster::status`] (its list of every slave).
    pub fn deaths(&self) -> u64 {
        self.status.deaths
    }

    /// The longest a slave declared dead for its silence had been silent
    /// when declared ([`Scheduler::longest_silence`]).
    pub fn longest_silence(&self) -> Duration {
        self.sched.longest_silence()
    }

    /// When the latest slave was declared dead for its silence
    /// ([`Scheduler::last_timeout_death`]).
    pub fn last_timeout_death(&self) -> Option<Duration> {
        self.sched.last_timeout_death()
    }

    /// The earliest time at which [`Cluster::handle_timeout`] has work to do.
    pub fn poll_timeout(&self) -> Option<Duration> {
        let liveness = self.sched.config().heartbeat_timeout;
        let peers = self.peers.values().map(|p| match p.state {
            PeerState::AwaitHello { .. } => p.since + self.handshake_timeout,
            PeerState::Syncing { since, .. } => (p.last_heard + liveness).min(since + self.sync_timeout),
            PeerState::Viewer { .. } => p.last_heard + liveness,
            // The scheduler's own deadline covers slaves.
            PeerState::Slave => Duration::MAX,
        });
        let heartbeat = (!self.peers.is_empty()).then(|| self.last_heartbeat + self.heartbeat_interval);
        let status = (!self.frames.is_empty()).then(|| self.last_status + STATUS_INTERVAL);
        peers
            .chain(heartbeat)
            .chain(status)
            .chain(self.roster_due)
            .chain(self.sched.poll_timeout())
            .filter(|&t| t != Duration::MAX)
            .min()
    }

    /// The next thing for the driver to do, if any.
    pub fn poll_transmit(&mut self) -> Option<Transmit> {
        self.out.pop_front()
    }

    // ---- inputs ---------------------------------------------------------

    /// A new connection `peer` (a number the driver never reuses) from
    /// `addr`. It is challenged, or refused at once when a peer limit is
    /// reached.
    pub fn handle_connected(&mut self, now: Duration, peer: PeerId, addr: &str) {
        if self.peers.contains_key(&peer) {
            tracing::error!(peer, "connection number reused; ignored");
            return;
        }
        let full = if self.peers.len() >= self.budgets.max_peers {
            Some(format!("{} peers connected, the most allowed", self.budgets.max_peers))
        } else if self.handshaking >= self.budgets.max_handshaking {
            Some(format!(
                "{} connections still in their handshake, the most allowed",
                self.budgets.max_handshaking
            ))
        } else {
            None
        };
        if let Some(why) = full {
            tracing::warn!(%addr, "refusing a connection from {addr}: {why}");
            self.status.refused += 1;
            self.send(peer, Message::Reject { reason: format!("master busy: {why}") });
            self.out.push_back(Transmit::Close { peer, reason: why });
            return;
        }
        let nonce = self.nonces.next_nonce();
        tracing::debug!(%addr, "connection #{peer}");
        self.peers.insert(
            peer,
            Peer {
                addr: addr.to_string(),
                name: format!("peer#{peer}"),
                state: PeerState::AwaitHello { nonce },
                since: now,
                last_heard: now,
                max_frame: HANDSHAKE_MAX_FRAME,
                codec: Codec::Raw,
                decodes: Vec::new(),
                foreign: 0,
                scene_sends: 0,
                offers_sent: BTreeSet::new(),
            },
        );
        self.handshaking += 1;
        self.send(peer, Message::Challenge { nonce });
    }

    /// A whole frame from `peer`: decoded within the peer's limit, then
    /// handled; anything undecodable closes the connection.
    pub fn handle_frame(&mut self, now: Duration, peer: PeerId, frame: &[u8]) {
        let Some(p) = self.peers.get(&peer) else { return };
        self.bytes_received += frame.len() as u64;
        if matches!(p.state, PeerState::Slave) {
            // Most of the traffic: read in place, its pixels never copied.
            match protocol::decode_tile_result(frame, p.max_frame) {
                Some(Ok(r)) => {
                    self.heard_from(now, peer);
                    return self.on_result(now, peer, r);
                }
                Some(Err(e)) => return self.refuse(now, peer, format!("bad frame: {e}")),
                None => {}
            }
        }
        match protocol::decode(frame, p.max_frame) {
            Ok(msg) => self.handle_message(now, peer, msg),
            Err(e) => self.refuse(now, peer, format!("bad frame: {e}")),
        }
    }

    /// The transport failed on `peer`'s connection (an oversized or
    /// over-budget frame, a broken stream): it is dropped.
    pub fn handle_transport_error(&mut self, now: Duration, peer: PeerId, error: &str) {
        if self.peers.contains_key(&peer) {
            self.refuse(now, peer, format!("bad frame: {error}"));
        }
    }

    /// `peer`'s connection ended.
    pub fn handle_closed(&mut self, now: Duration, peer: PeerId) {
        self.remove(now, peer, "peer closed".into());
    }

    /// Time passed: drops peers past their deadlines, sends heartbeats,
    /// declares silent slaves dead.
    pub fn handle_timeout(&mut self, now: Duration) {
        self.sched.handle_timeout(now);
        let liveness = self.sched.config().heartbeat_timeout;
        let late: Vec<(PeerId, String)> = self
            .peers
            .iter()
            .filter_map(|(&id, p)| {
                let why = match p.state {
                    PeerState::AwaitHello { .. } if now >= p.since + self.handshake_timeout => {
                        "handshake timed out".to_string()
                    }
                    PeerState::Syncing { since, .. } if now >= since + self.sync_timeout => {
                        format!("did not load the scene within {:?}", self.sync_timeout)
                    }
                    PeerState::Syncing { .. } | PeerState::Viewer { .. }
                        if now >= p.last_heard + liveness =>
                    {
                        format!("silent for {liveness:?}")
                    }
                    _ => return None,
                };
                Some((id, why))
            })
            .collect();
        for (id, why) in late {
            self.refuse(now, id, why);
        }
        if now >= self.last_heartbeat + self.heartbeat_interval {
            self.last_heartbeat = now;
            let live: Vec<PeerId> = self
                .peers
                .iter()
                .filter(|(_, p)| !matches!(p.state, PeerState::AwaitHello { .. }))
                .map(|(&id, _)| id)
                .collect();
            for id in live {
                self.send(id, Message::Heartbeat);
            }
        }
        if !self.frames.is_empty() && now >= self.last_status + STATUS_INTERVAL {
            self.push_status(now);
        }
        self.drain(now);
    }

    /// A decoded message from `peer`.
    pub fn handle_message(&mut self, now: Duration, peer: PeerId, msg: Message) {
        self.heard_from(now, peer);
        let Some(p) = self.peers.get_mut(&peer) else { return };
        match (&p.state, msg) {
            (PeerState::AwaitHello { nonce }, Message::Hello(hello)) => {
                let nonce = *nonce;
                self.on_hello(now, peer, nonce, hello);
            }
            (PeerState::AwaitHello { .. }, other) => {
                self.refuse(now, peer, format!("expected Hello, got {}", other.kind()));
            }
            (PeerState::Syncing { threads, .. }, Message::Ready { hash }) => {
                if hash != self.scenes.default_hash() {
                    return self.refuse(now, peer, "slave loaded a different scene".into());
                }
                let threads = *threads;
                p.state = PeerState::Slave;
                let (name, addr) = (p.name.clone(), p.addr.clone());
                tracing::info!(slave = %name, threads, "slave {name} joined with {threads} threads");
                self.roster.join(peer, &name, &addr, threads);
                self.roster_changed(now);
                for p in self.peers.values_mut() {
                    if let PeerState::Viewer(c) = &mut p.state {
                        c.told_waiting = false;
                    }
                }
                self.sched.handle_join(now, peer, name, threads);
                self.drain(now);
            }
            (PeerState::Slave, Message::TileResult(r)) => self.on_result(now, peer, r.borrowed()),
            (PeerState::Viewer(_), Message::TileReceived(r)) => self.on_received(now, peer, r),
            (PeerState::Slave, Message::NeedScene { hash }) => self.send_scene(now, peer, hash),
            (PeerState::Slave | PeerState::Syncing { .. }, Message::SceneAck { hash, chunks_received }) => {
                self.on_scene_ack(now, peer, hash, chunks_received)
            }
            (PeerState::Slave, Message::SceneFailed { hash, reason }) => {
                self.on_scene_failed(now, peer, hash, reason)
            }
            (_, Message::Heartbeat) => {}
            (PeerState::Viewer(_), Message::FrameRequest { request, scene, camera, settings }) => {
                let order = Request { request, scene, camera, settings, queue: false, job_frame: None };
                self.request_frame(now, peer, order);
            }
            (PeerState::Viewer(_), Message::QueueFrame { request, scene, camera, settings, job_frame }) => {
                let order = Request { request, scene, camera, settings, queue: true, job_frame };
                self.request_frame(now, peer, order);
            }
            (PeerState::Viewer(_), Message::SceneUpload(header)) => self.on_scene_upload(now, peer, header),
            (PeerState::Viewer(_), Message::SceneChunk { hash, index, bytes }) => {
                self.on_scene_chunk(now, peer, hash, index, &bytes)
            }
            (PeerState::Viewer(_), Message::SubmitJob(spec)) => self.on_submit_job(now, peer, spec),
            (PeerState::Viewer(_), Message::StatusRequest) => {
                let status = self.report(now);
                self.send(peer, Message::Status(status));
            }
            (_, Message::Error { message }) => {
                let message: String = message.chars().take(200).collect();
                tracing::warn!(peer = %p.name, "peer reports: {message}");
            }
            (_, other) => {
                let kind = other.kind();
                self.refuse(now, peer, format!("unexpected {kind} message"));
            }
        }
    }

    // ---- internals ------------------------------------------------------

    fn send(&mut self, peer: PeerId, message: Message) {
        self.out.push_back(Transmit::Send { peer, message, class: Class::Control });
    }

    /// Notes a join or a death for viewers: told at the end of this step, or
    /// [`ROSTER_INTERVAL`] after they were last told, whichever is later.
    fn roster_changed(&mut self, now: Duration) {
        if self.roster_due.is_none() {
            self.roster_due = Some(self.roster_told.map_or(now, |t| now.max(t + ROSTER_INTERVAL)));
        }
    }

    /// Tells viewers of the joins and deaths noted, once they are due.
    fn tell_roster(&mut self, now: Duration) {
        if self.roster_due.is_some_and(|due| now >= due) {
            self.roster_due = None;
            self.roster_told = Some(now);
            self.send_roster();
            self.push_status(now);
        }
    }

    fn send_roster(&mut self) {
        let list = self.roster.message();
        let viewers: Vec<PeerId> = self
            .peers
            .iter()
            .filter(|(_, p)| matches!(p.state, PeerState::Viewer(_)))
            .map(|(&id, _)| id)
            .collect();
        for id in viewers {
            self.send(id, list.clone());
        }
    }

    /// The cluster as [`Message::Status`] tells it (each slave's rate is
    /// measured since the previous report).
    fn report(&mut self, now: Duration) -> Status {
        let elapsed = now.saturating_sub(self.last_status).as_secs_f32();
        let mut rates = BTreeMap::new();
        let slaves = self
            .sched
            .slaves()
            .into_iter()
            .map(|s| {
                let (then, rate) = self.tiles_then.get(&s.id).copied().unwrap_or((s.tiles_done, 0.0));
                let rate = if elapsed >= 0.5 { (s.tiles_done - then) as f32 / elapsed } else { rate };
                rates.insert(s.id, (if elapsed >= 0.5 { s.tiles_done } else { then }, rate));
                let last = self.peers.get(&s.id).map_or(now, |p| p.last_heard);
                SlaveStatus {
                    id: s.id,
                    name: roster::cut(&s.name),
                    threads: s.threads,
                    tiles_per_second: rate,
                    last_seen_ms: now.saturating_sub(last).as_millis() as u64,
                }
            })
            .collect();
        if elapsed >= 0.5 {
            self.last_status = now;
        }
        self.tiles_then = rates;
        let clients = self
            .peers
            .iter()
            .filter_map(|(&id, p)| match &p.state {
                PeerState::Viewer(c) => Some(ClientStatus {
                    id,
                    name: roster::cut(&p.name),
                    work: c.work,
                    open_frames: c.frames.len() as u32,
                    frames_done: c.frames_done,
                }),
                _ => None,
            })
            .collect();
        let jobs = self.jobs.by_key.values().map(|j| j.status()).collect();
        Status {
            slaves,
            clients,
            jobs,
            scenes: self.scenes.len() as u32,
            scene_bytes_sent: self.status.scene_bytes_sent,
        }
    }

    /// Pushes the status to every interactive viewer.
    fn push_status(&mut self, now: Duration) {
        let status = self.report(now);
        self.last_status = now;
        let viewers: Vec<PeerId> = self
            .peers
            .iter()
            .filter(|(_, p)| matches!(&p.state, PeerState::Viewer(c) if c.work == Work::Interactive))
            .map(|(&id, _)| id)
            .collect();
        for id in viewers {
            self.send(id, Message::Status(status.clone()));
        }
    }

    /// A slave asked for a scene: sent if held, within its budget of sends.
    fn send_scene(&mut self, now: Duration, slave: PeerId, hash: SceneHash) {
        let Some(packed) = self.scenes.packed(&hash) else {
            // Its frames are gone (a held scene is never evicted while used).
            return tracing::debug!(slave, "a slave asked for a scene no longer held");
        };
        let Some(p) = self.peers.get_mut(&slave) else { return };
        p.scene_sends += 1;
        if p.scene_sends > self.budgets.scene_sends {
            let n = p.scene_sends;
            return self.refuse(now, slave, format!("asked for scenes {n} times"));
        }
        tracing::info!(slave = %p.name, "sending scene {} to {}", self.scenes.name(&hash).unwrap_or("?"), p.name);
        self.start_transfer(now, slave, packed);
    }

    /// Starts (or queues) sending `packed` to `slave`.
    fn start_transfer(&mut self, now: Duration, slave: PeerId, packed: Arc<Packed>) {
        self.status.scene_sends += 1;
        let h = &packed.header;
        tracing::debug!(
            slave,
            "scene {}: {} bytes, {} compressed, in {} chunks",
            h.name,
            h.raw_bytes,
            h.compressed_bytes,
            h.chunks
        );
        let frames = self.transfers.start(now, slave, packed);
        self.send_scene_frames(slave, frames);
    }

    fn send_scene_frames(&mut self, peer: PeerId, frames: Vec<Arc<Vec<u8>>>) {
        for frame in frames {
            self.status.scene_bytes_sent += frame.len() as u64;
            self.out.push_back(Transmit::SendEncoded { peer, frame });
        }
    }

    /// A slave has this many chunks of a scene: more go out.
    fn on_scene_ack(&mut self, now: Duration, slave: PeerId, hash: SceneHash, chunks: u32) {
        match self.transfers.ack(now, slave, hash, chunks) {
            Ok(acked) => {
                if let Some(h) = acked.finished {
                    let name = self.peers.get(&slave).map_or("?", |p| p.name.as_str());
                    tracing::debug!(slave = %name, "scene {} sent to {name}", protocol::short_hash(&h));
                }
                self.send_scene_frames(slave, acked.frames);
            }
            Err(e) => self.refuse(now, slave, e.to_string()),
        }
    }

    /// A slave could not load a scene: every open frame of it fails, and
    /// the scene is forgotten (a client may upload it again).
    fn on_scene_failed(&mut self, now: Duration, slave: PeerId, hash: SceneHash, reason: String) {
        let reason: String = reason.chars().take(300).collect();
        let slave_name = self.peers.get(&slave).map(|p| p.name.clone()).unwrap_or_default();
        let scene = self.scenes.name(&hash).unwrap_or("?").to_string();
        tracing::warn!(slave = %slave_name, "{slave_name} cannot load scene {scene}: {reason}");
        if Some(hash) == self.scenes.default_hash() {
            return self.refuse(now, slave, format!("cannot load the default scene: {reason}"));
        }
        let failed: Vec<FrameId> =
            self.frames.iter().filter(|(_, f)| f.scene == hash).map(|(&id, _)| id).collect();
        let mut told = BTreeSet::new();
        for frame in failed {
            self.sched.abandon(frame);
            if let Some(spec) = self.close_frame(frame)
                && told.insert(spec.viewer)
            {
                let message = format!("scene {scene} could not be loaded by slave {slave_name}: {reason}");
                self.send(spec.viewer, Message::Error { message });
            }
        }
        if self.scenes.remove(&hash) {
            self.out.push_back(Transmit::Store(Stored::ForgetScene { hash }));
        }
        self.drain(now);
    }

    /// A client announced a scene: stored already, or it may send it now
    /// (within the budgets: checked before anything is held).
    fn on_scene_upload(&mut self, now: Duration, peer: PeerId, header: SceneHeader) {
        let hash = header.hash;
        if self.scenes.contains(&hash) {
            return self.send(peer, Message::SceneStored { hash });
        }
        let (max, bytes) = (self.budgets.scene_upload_bytes, header.raw_bytes);
        let busy = self.uploading;
        let refused = if bytes > max as u64 {
            Some(format!("the scene is {bytes} bytes; the master takes scenes of at most {max} bytes"))
        } else if busy + bytes > self.budgets.uploading_bytes as u64 {
            Some(format!("the master is receiving {busy} bytes of scenes already; try again later"))
        } else {
            None
        };
        if let Some(message) = refused {
            return self.send(peer, Message::Error { message });
        }
        let rx = match Receiver::new(header) {
            Ok(rx) => rx,
            Err(e) => return self.send(peer, Message::Error { message: e.to_string() }),
        };
        let Some(p) = self.peers.get_mut(&peer) else { return };
        let PeerState::Viewer(c) = &mut p.state else { return };
        if c.upload.is_some() {
            let message = "one scene at a time: the last one is not in yet".to_string();
            return self.send(peer, Message::Error { message });
        }
        let what = format!("receiving scene {} from {}", rx.header().name, p.name);
        let log = ProgressLog::new(what, rx.header().compressed_bytes, now);
        c.upload = Some(Box::new((rx, log)));
        self.uploading += bytes;
        // Chunks may come now; the limit drops back once the last is in.
        p.max_frame = limits::SCENE_CHUNK_FRAME;
        self.out.push_back(Transmit::Limit { peer, max_frame: limits::SCENE_CHUNK_FRAME });
        self.send(peer, Message::SceneWanted { hash });
    }

    /// A chunk of a client's scene: unpacked; a bad one (or one never
    /// announced) drops the client. With the last, the scene is checked
    /// against its hash and held.
    fn on_scene_chunk(&mut self, now: Duration, peer: PeerId, hash: SceneHash, index: u32, bytes: &[u8]) {
        let Some(p) = self.peers.get_mut(&peer) else { return };
        let PeerState::Viewer(c) = &mut p.state else { return };
        let Some(upload) = c.upload.as_mut() else {
            return self.refuse(now, peer, "sent a scene it had not announced".into());
        };
        let progress = match upload.0.push(&hash, index, bytes) {
            Ok(progress) => progress,
            Err(e) => return self.refuse(now, peer, format!("bad scene upload: {e}")),
        };
        upload.1.update(now, progress.bytes);
        if !progress.complete {
            return;
        }
        let Some(upload) = c.upload.take() else { return };
        let (rx, _) = *upload;
        self.uploading -= rx.header().raw_bytes;
        p.max_frame = VIEWER_MAX_FRAME;
        self.out.push_back(Transmit::Limit { peer, max_frame: VIEWER_MAX_FRAME });
        let bundle = match rx.finish() {
            Ok(bundle) => bundle,
            Err(e) => return self.refuse(now, peer, format!("bad scene upload: {e}")),
        };
        if bundle.name != protocol::served_name(&bundle.name) {
            let message = "a scene must be named by its file name alone, not a path".to_string();
            return self.send(peer, Message::Error { message });
        }
        match self.scenes.insert(&bundle, false) {
            Ok((hash, evicted)) => {
                for h in evicted {
                    self.out.push_back(Transmit::Store(Stored::ForgetScene { hash: h }));
                }
                match self.scenes.packed(&hash).map(|p| p.to_stored()) {
                    Some(Ok(bytes)) => {
                        self.out.push_back(Transmit::Store(Stored::Scene { hash, bytes: Arc::new(bytes) }))
                    }
                    Some(Err(e)) => tracing::error!("cannot store scene {}: {e}", bundle.name),
                    None => {}
                }
                tracing::info!(
                    "holding scene {} for {}",
                    bundle.name,
                    self.peers.get(&peer).map_or("?", |p| &p.name)
                );
                self.send(peer, Message::SceneStored { hash });
            }
            Err(e) => self.send(peer, Message::Error { message: e.to_string() }),
        }
    }

    /// A client's batch job: recorded (stored before it is acknowledged).
    fn on_submit_job(&mut self, now: Duration, peer: PeerId, spec: JobSpec) {
        let bad = if spec.frames == 0 || spec.frames > MAX_JOB_FRAMES {
            Some(format!("a job has 1 to {MAX_JOB_FRAMES} frames, not {}", spec.frames))
        } else if !self.scenes.contains(&spec.scene) {
            Some("the job's scene is not held: upload it first".to_string())
        } else {
            limits::check_settings(&spec.settings).err().map(|e| e.to_string())
        };
        if let Some(message) = bad {
            return self.send(peer, Message::Error { message });
        }
        let key = spec.key;
        let Some(job) = self.jobs.submit(now, spec, peer) else {
            let message = format!("the master runs {} jobs already", self.budgets.max_jobs);
            return self.send(peer, Message::Error { message });
        };
        let record = job.record();
        tracing::info!(
            "job {} ({} frames, {} done) from {}",
            record.spec.name,
            record.spec.frames,
            record.done.len(),
            self.peers.get(&peer).map_or("?", |p| &p.name)
        );
        let done = record.done.clone();
        self.out.push_back(Transmit::Store(Stored::Job(record)));
        if let Some(PeerState::Viewer(c)) = self.peers.get_mut(&peer).map(|p| &mut p.state) {
            c.job = Some(key);
        }
        self.send(peer, Message::JobAccepted { key, done });
    }

    /// Forgets an open frame (its scene is no longer used by it); the
    /// scheduler's side is the caller's.
    fn close_frame(&mut self, frame: FrameId) -> Option<FrameSpec> {
        let spec = self.frames.remove(&frame)?;
        self.scenes.release(&spec.scene);
        if let Some(PeerState::Viewer(c)) = self.peers.get_mut(&spec.viewer).map(|p| &mut p.state) {
            c.frames.remove(&frame);
        }
        Some(spec)
    }

    fn on_hello(&mut self, now: Duration, id: PeerId, nonce: [u8; 32], hello: Hello) {
        let expected = auth::client_proof(&self.token, hello.role, &nonce, &hello.client_nonce);
        if !auth::proofs_match(&expected, &hello.proof) {
            return self.refuse(now, id, "authentication failed: wrong token".into());
        }
        let Some(peer) = self.peers.get_mut(&id) else { return };
        self.handshaking -= 1;
        let name: String = hello.name.chars().filter(|c| !c.is_control()).take(48).collect();
        peer.name = format!("{name}#{id}");
        peer.codec = codec::negotiate(self.compression, &hello.codecs);
        peer.decodes = hello.codecs.iter().filter_map(|n| Codec::from_name(n)).collect();
        peer.max_frame = match hello.role {
            Role::Viewer => VIEWER_MAX_FRAME,
            Role::Slave => self.slave_max_frame,
        };
        let welcome = Welcome {
            id,
            name: peer.name.clone(),
            proof: auth::server_proof(&self.token, hello.role, &nonce, &hello.client_nonce),
            scene: self.scene.clone(),
            codec: peer.codec,
        };
        let max_frame = peer.max_frame;
        match hello.role {
            Role::Viewer => {
                let direct = hello.direct.map(|o| *o).filter(|o| {
                    o.addr.len() <= MAX_DIRECT_ADDR
                        && o.fingerprint.as_ref().is_none_or(|f| f.len() <= MAX_DIRECT_FINGERPRINT)
                });
                if let Some(o) = &direct {
                    tracing::info!(viewer = %peer.name, "viewer {} takes its tiles from slaves at {}", peer.name, o.addr);
                }
                peer.state = PeerState::Viewer(Client { work: hello.work, direct, ..Client::default() });
                tracing::info!(viewer = %peer.name, addr = %peer.addr, "viewer {} connected", peer.name);
                self.out.push_back(Transmit::Limit { peer: id, max_frame });
                self.send(id, Message::Welcome(welcome));
                self.send(id, self.roster.message());
            }
            Role::Slave => {
                peer.state = PeerState::Syncing { threads: hello.threads, since: now };
                let default = self.scenes.default_hash();
                let cached = default.is_none_or(|h| hello.cached_scenes.contains(&h));
                tracing::info!(
                    slave = %peer.name,
                    addr = %peer.addr,
                    threads = hello.threads,
                    codec = %peer.codec,
                    "slave {} authenticated, tiles in {}{}",
                    peer.name,
                    peer.codec,
                    if cached { " (scene cached)" } else { "; sending scene" }
                );
                self.out.push_back(Transmit::Limit { peer: id, max_frame });
                self.send(id, Message::Welcome(welcome));
                if let Some(packed) = default.filter(|_| !cached).and_then(|h| self.scenes.packed(&h)) {
                    if let Some(p) = self.peers.get_mut(&id) {
                        p.scene_sends += 1;
                    }
                    self.start_transfer(now, id, packed);
                }
            }
        }
    }

    /// Any message is a sign of life; a slave's tells the scheduler too.
    fn heard_from(&mut self, now: Duration, peer: PeerId) {
        let Some(p) = self.peers.get_mut(&peer) else { return };
        p.last_heard = now;
        if matches!(p.state, PeerState::Slave) {
            self.sched.handle_heartbeat(now, peer);
        }
    }

    fn on_result(&mut self, now: Duration, id: PeerId, r: TileResultRef<'_>) {
        tracing::trace!(slave = id, frame = r.frame, tile = r.id, "tile result");
        let rect = match self.sched.check_result(id, r.frame, r.id) {
            ResultCheck::Held { tile } => tile,
            // Late, or another copy won: drop it (counted as waste).
            ResultCheck::Finished => {
                self.sched.handle_result(now, id, r.frame, r.id);
                return;
            }
            ResultCheck::Stale => return,
            ResultCheck::Foreign => return self.on_foreign(now, id, &r),
        };
        if r.tile != rect {
            let got = r.tile;
            return self.refuse(now, id, format!("tile {} is {got:?}, but {rect:?} was assigned", r.id));
        }
        // Untrusted: checked (raw by its length, the others by a walk over
        // their ops, nothing decoded) before it counts, even when it is
        // forwarded still encoded.
        if let Err(e) = codec::check(r.codec, r.tile.w, r.tile.h, r.pixels) {
            return self.refuse(now, id, format!("tile {}: {e}", r.id));
        }
        // A viewer that cannot decode the slave's codec is sent raw pixels:
        // decoded here, before the tile counts.
        let as_sent = self.viewer_decodes(r.frame, r.codec);
        if !as_sent
            && let Err(e) = codec::decode_into(r.codec, r.tile.w, r.tile.h, r.pixels, &mut self.scratch)
        {
            return self.refuse(now, id, format!("tile {}: {e}", r.id));
        }
        self.sched.record_render_time(r.frame, r.id, r.render_micros);
        match self.sched.handle_result(now, id, r.frame, r.id) {
            ResultOutcome::Accepted { tile } => self.forward(id, r, tile, as_sent),
            outcome => tracing::trace!(?outcome, "tile result dropped"),
        }
        self.drain(now);
    }

    /// A viewer says a tile of one of its direct frames came straight from
    /// `r.slave`: counted done for that slave, nothing forwarded (the
    /// master takes its viewers' word on their own frames, never a slave's
    /// on anyone's). A frame that is not the viewer's own direct frame gets
    /// the viewer refused; a frame closed since, a slave gone or a tile the
    /// slave no longer holds (another copy won) is only the race it looks
    /// like. A tile the master wanted to see itself, or of another rectangle
    /// than assigned, its slave should not have sent so: the slave goes, and
    /// its tiles are handed out again.
    fn on_received(&mut self, now: Duration, viewer: PeerId, r: TileReceived) {
        let Some(spec) = self.frames.get(&r.frame) else { return };
        if spec.viewer != viewer || spec.direct.is_none() {
            let why = format!("reported a tile of frame {}, which is not its own direct frame", r.frame);
            return self.refuse(now, viewer, why);
        }
        let slave = r.slave;
        if !self.peers.get(&slave).is_some_and(|p| matches!(p.state, PeerState::Slave)) {
            return;
        }
        let rect = match self.sched.check_result(slave, r.frame, r.id) {
            ResultCheck::Held { tile } => tile,
            ResultCheck::Finished => {
                self.sched.handle_result(now, slave, r.frame, r.id);
                return;
            }
            ResultCheck::Stale | ResultCheck::Foreign => return,
        };
        if protocol::via_master(&self.verify_secret, r.frame, r.id) {
            return self.refuse(now, slave, format!("tile {} was to come through the master", r.id));
        }
        if r.tile != rect {
            let got = r.tile;
            return self.refuse(now, slave, format!("tile {} is {got:?}, but {rect:?} was assigned", r.id));
        }
        self.sched.record_render_time(r.frame, r.id, r.render_micros);
        if let ResultOutcome::Accepted { .. } = self.sched.handle_result(now, slave, r.frame, r.id)
            && let Some(spec) = self.frames.get_mut(&r.frame)
        {
            spec.delivered += 1;
        }
        self.drain(now);
    }

    /// A result for a tile `id` was never handed: refused and counted; past
    /// the budget, the slave goes.
    fn on_foreign(&mut self, now: Duration, id: PeerId, r: &TileResultRef<'_>) {
        self.status.foreign_results += 1;
        let Some(p) = self.peers.get_mut(&id) else { return };
        p.foreign += 1;
        tracing::warn!(slave = %p.name, frame = r.frame, tile = r.id, "refused a result for a tile {} was never handed", p.name);
        if p.foreign > self.budgets.foreign_results {
            let n = p.foreign;
            self.refuse(now, id, format!("{n} results for tiles it was never handed"));
        }
    }

    /// Whether the viewer of `frame` decodes tiles in `codec` (raw, every
    /// viewer does); true for a frame or viewer gone (nothing to send).
    fn viewer_decodes(&self, frame: FrameId, codec: Codec) -> bool {
        let viewer = self.frames.get(&frame).and_then(|spec| self.peers.get(&spec.viewer));
        codec == Codec::Raw || viewer.is_none_or(|v| v.decodes.contains(&codec))
    }

    /// Sends an accepted tile to the viewer of its frame, written straight
    /// into its outgoing frame: `as_sent` in the slave's codec, else raw (the
    /// pixels `on_result` decoded into the scratch buffer).
    fn forward(&mut self, slave: PeerId, r: TileResultRef<'_>, tile: isin_tracer::Tile, as_sent: bool) {
        let Some(spec) = self.frames.get(&r.frame) else { return };
        if !self.peers.contains_key(&spec.viewer) {
            return;
        }
        let slave_name = self.peers.get(&slave).map_or("", |p| p.name.as_str());
        let (codec, pixels) = if as_sent { (r.codec, r.pixels) } else { (Codec::Raw, &self.scratch[..]) };
        match protocol::encode_frame_tile(spec.request, slave, slave_name, tile, codec, pixels) {
            Ok(frame) => {
                self.out.push_back(Transmit::SendFrame { peer: spec.viewer, frame, class: Class::Tile })
            }
            Err(e) => tracing::error!("cannot encode a FrameTile: {e}"),
        }
    }

    /// A viewer's frame request: supersedes the open frames, or with `queue`
    /// waits behind them (the scheduler pipelines it).
    fn request_frame(&mut self, now: Duration, viewer: PeerId, r: Request) {
        let Request { request, scene, camera, settings, queue, job_frame } = r;
        if let Err(message) = limits::validate_request(&camera, &settings) {
            return self.send(viewer, Message::Error { message });
        }
        let Some(PeerState::Viewer(client)) = self.peers.get(&viewer).map(|p| &p.state) else { return };
        let scene = match scene.or(self.scenes.default_hash()) {
            Some(h) if self.scenes.contains(&h) => h,
            Some(_) => {
                let message = "unknown scene: upload it first (SceneUpload)".to_string();
                return self.send(viewer, Message::Error { message });
            }
            None => {
                let message = "the master serves no scene of its own: name one                                (isin view SCENE --connect TICKET)"
                    .to_string();
                return self.send(viewer, Message::Error { message });
            }
        };
        if let Some(i) = job_frame {
            let in_job = client.job.and_then(|k| self.jobs.by_key.get(&k)).is_some_and(|j| i < j.spec.frames);
            if !in_job {
                let message = format!("frame {i} is not a frame of this client's job");
                return self.send(viewer, Message::Error { message });
            }
        }
        let frame = self.next_frame;
        let (w, h) = (settings.width, settings.height);
        let order = FrameOrder {
            client: viewer,
            work: client.work,
            width: w,
            height: h,
            samples: settings.spp,
            queue,
        };
        if let Err(e) = self.sched.open(now, frame, order) {
            return self.send(viewer, Message::Error { message: e.to_string() });
        }
        self.next_frame += 1;
        if !queue {
            // The scheduler dropped this viewer's open frames (and no one else's).
            let old = match self.peers.get_mut(&viewer).map(|p| &mut p.state) {
                Some(PeerState::Viewer(c)) => std::mem::take(&mut c.frames),
                _ => BTreeSet::new(),
            };
            for f in old {
                self.close_frame(f);
            }
        }
        if let Some(PeerState::Viewer(c)) = self.peers.get_mut(&viewer).map(|p| &mut p.state) {
            c.frames.insert(frame);
        }
        self.tell_if_waiting();
        self.status.frames_requested += 1;
        self.scenes.acquire(&scene);
        let direct = match self.peers.get(&viewer).map(|p| &p.state) {
            Some(PeerState::Viewer(c)) => c.direct.clone(),
            _ => None,
        };
        let spec = FrameSpec {
            scene,
            job_frame,
            camera,
            settings,
            viewer,
            request,
            bytes_at_start: self.bytes_received,
            direct,
            delivered: 0,
            head: protocol::AssignmentHead::new(frame, scene, camera, settings)
                .inspect_err(|e| {
                    tracing::error!("cannot encode the head of frame {frame}'s assignments: {e}")
                })
                .ok(),
        };
        self.frames.insert(frame, spec);
        tracing::debug!(frame, request, queue, "frame requested {w}x{h}");
        self.drain(now);
    }

    /// With no slave in the cluster, tells each viewer whose frames now wait
    /// — once, until a slave joins.
    fn tell_if_waiting(&mut self) {
        if self.sched.slave_count() > 0 {
            return;
        }
        let mut told = Vec::new();
        for (&id, p) in self.peers.iter_mut() {
            if let PeerState::Viewer(c) = &mut p.state
                && !c.frames.is_empty()
                && !c.told_waiting
            {
                c.told_waiting = true;
                told.push(id);
            }
        }
        for id in told {
            let message = "no slaves connected: the frame waits, and starts as soon as one joins \
                           (start one with: isin slave --connect TICKET)"
                .to_string();
            self.send(id, Message::Notice { message });
        }
    }

    /// Refuses `peer`: tells it why, then drops it.
    fn refuse(&mut self, now: Duration, peer: PeerId, reason: String) {
        let Some(p) = self.peers.get(&peer) else { return };
        tracing::warn!(addr = %p.addr, "refused {}: {reason}", p.name);
        self.status.refused += 1;
        self.send(peer, Message::Reject { reason: reason.clone() });
        self.remove(now, peer, reason);
    }

    /// Forgets `peer` (its tiles go back to the queue, its frames are
    /// abandoned) and has its connection closed.
    fn remove(&mut self, now: Duration, id: PeerId, reason: String) {
        let Some(p) = self.peers.remove(&id) else { return };
        tracing::debug!(peer = %p.name, addr = %p.addr, "connection closed: {reason}");
        if matches!(p.state, PeerState::Viewer(_)) {
            tracing::info!(viewer = %p.name, "viewer {} left ({reason})", p.name);
        }
        self.out.push_back(Transmit::Close { peer: id, reason });
        self.transfers.remove(id);
        match p.state {
            PeerState::AwaitHello { .. } => self.handshaking -= 1,
            PeerState::Syncing { .. } => {}
            PeerState::Slave => self.sched.handle_disconnect(now, id),
            PeerState::Viewer(c) => {
                if let Some(upload) = c.upload {
                    self.uploading -= upload.0.header().raw_bytes;
                }
                for f in c.frames {
                    self.sched.abandon(f);
                    self.close_frame(f);
                }
                self.jobs.detach(id);
            }
        }
        self.drain(now);
    }

    /// Turns the scheduler's decisions into transmissions.
    fn drain(&mut self, now: Duration) {
        while let Some(out) = self.sched.poll_output(now) {
            match out {
                Output::Assign { slave, frame, tiles, reassigned } => {
                    let Some(spec) = self.frames.get(&frame) else { continue };
                    if reassigned > 0 {
                        let name = self.peers.get(&slave).map_or("?", |p| p.name.as_str());
                        tracing::debug!(
                            slave = name,
                            frame,
                            "reassigned {reassigned} tiles of dead slaves to {name}"
                        );
                    }
                    tracing::trace!(slave, frame, "assigning {} tiles", tiles.len());
                    let first = |peers: &mut BTreeMap<PeerId, Peer>| {
                        peers.get_mut(&slave).is_some_and(|p| p.offers_sent.insert(spec.viewer))
                    };
                    let direct = spec.direct.as_ref().map(|offer| {
                        Box::new(DirectRoute {
                            viewer: spec.viewer,
                            request: spec.request,
                            offer: first(&mut self.peers).then(|| offer.clone()),
                            via_master: tiles
                                .iter()
                                .map(|t| t.id)
                                .filter(|&id| protocol::via_master(&self.verify_secret, frame, id))
                                .collect(),
                        })
                    });
                    let encoded = spec
                        .head
                        .as_ref()
                        .map(|head| protocol::encode_assignment(head, &tiles, direct.as_deref()));
                    match encoded {
                        Some(Ok(frame)) => self.out.push_back(Transmit::SendFrame {
                            peer: slave,
                            frame,
                            class: Class::Control,
                        }),
                        _ => {
                            let message = Message::TileAssignment(TileAssignment {
                                frame,
                                scene: spec.scene,
                                camera: spec.camera,
                                settings: spec.settings,
                                tiles,
                                direct,
                            });
                            self.send(slave, message);
                        }
                    }
                }
                Output::Cancel { slave, frame, tiles } => self.send(slave, Message::Cancel { frame, tiles }),
                Output::SlaveDead { slave, name, cause, requeued } => {
                    self.status.deaths += 1;
                    if self.roster.death(slave) {
                        self.roster_changed(now);
                    }
                    self.tell_if_waiting();
                    tracing::warn!(slave = %name, "slave {name} dead ({cause:?}); {requeued} tiles requeued");
                    if cause == DeathCause::Timeout && self.peers.remove(&slave).is_some() {
                        self.transfers.remove(slave);
                        let reason = format!("silent for {:?}", self.sched.config().heartbeat_timeout);
                        self.out.push_back(Transmit::Close { peer: slave, reason });
                    }
                }
                Output::FrameDone { frame, mut stats } => {
                    let from =
                        self.frames.get(&frame).map_or(0, |s| s.bytes_at_start).max(self.bytes_at_last_done);
                    stats.bytes_in = self.bytes_received.saturating_sub(from);
                    self.bytes_at_last_done = self.bytes_received;
                    self.status.frames_done += 1;
                    stats.direct = self.frames.get(&frame).map_or(0, |s| s.delivered);
                    self.status.last_frame = Some(stats.clone());
                    let Some(spec) = self.close_frame(frame) else { continue };
                    tracing::debug!(
                        frame,
                        "frame done in {:.1} ms: {} tiles, {} moved, {} duplicated, {} requeued",
                        stats.micros as f64 / 1e3,
                        stats.tiles,
                        stats.moved,
                        stats.duplicated,
                        stats.requeued
                    );
                    let job = match self.peers.get_mut(&spec.viewer).map(|p| &mut p.state) {
                        Some(PeerState::Viewer(c)) => {
                            c.frames_done += 1;
                            c.job
                        }
                        _ => None,
                    };
                    // A job's frame is stored done before its client hears so.
                    if let (Some(i), Some(job)) =
                        (spec.job_frame, job.and_then(|k| self.jobs.by_key.get_mut(&k)))
                        && job.complete(now, i)
                    {
                        let record = job.record();
                        if job.finished() {
                            tracing::info!(
                                "job {} finished: {} frames",
                                record.spec.name,
                                record.spec.frames
                            );
                        }
                        self.out.push_back(Transmit::Store(Stored::Job(record)));
                    }
                    self.send(spec.viewer, Message::FrameDone { request: spec.request, stats });
                }
            }
        }
        self.tell_roster(now);
    }
}

/// A frame request as a viewer sent it.
struct Request {
    request: u64,
    scene: Option<SceneHash>,
    camera: Camera,
    settings: RenderSettings,
    queue: bool,
    job_frame: Option<u32>,
}

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
//!   Slaves then receive the scene (unless they hold one with its hash) and
//!   say `Ready`; only then do they join the scheduler and the roster.
//! - **Which tiles go where, who is dead**: the [`Scheduler`].
//! - **Which frames are open.** Every viewer is a client with its own stream
//!   of frames: its `FrameRequest` supersedes its own open frames and no one
//!   else's; a `QueueFrame` waits behind them. Between viewers, tiles go out
//!   by fair share of pixel-samples (the scheduler's docs say how), so two
//!   people flying through the scene each keep half the cluster. A viewer
//!   that leaves takes its frames.
//! - **What viewers hear**: tiles as they arrive (in a codec they decode),
//!   `FrameDone`, the slave list whenever it changes, and once, a `Notice`
//!   when their frames wait because no slave is connected.
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
//!   [`VIEWER_MAX_FRAME`], a slave one tile's worst-case encoding
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

mod roster;
#[cfg(test)]
mod tests;

pub use roster::DEAD_SLAVES_LISTED;

use crate::auth::{self, Nonces};
use crate::codec::{self, Codec, Compression};
use crate::limits::{self, Budgets, VIEWER_MAX_FRAME};
use crate::protocol::{
    self, FrameId, FrameStats, FrameTile, HANDSHAKE_MAX_FRAME, Hello, Message, ProtocolError, Role,
    SceneInfo, TileAssignment, TileResult, Welcome, WireBundle,
};
use crate::scheduler::{
    DeathCause, FrameOrder, Output, ResultCheck, ResultOutcome, Scheduler, SchedulerConfig, SlaveInfo, Work,
};
use isin_tracer::{Camera, RenderSettings, SceneBundle};
use roster::Roster;
use serde_bytes::ByteBuf;
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::sync::Arc;
use std::time::Duration;

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
    /// Send an already encoded frame (the scene, encoded once for every
    /// slave), in order.
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
}

impl Transmit {
    /// The connection it concerns.
    pub fn peer(&self) -> PeerId {
        match self {
            Transmit::Send { peer, .. }
            | Transmit::SendEncoded { peer, .. }
            | Transmit::Limit { peer, .. }
            | Transmit::Close { peer, .. } => *peer,
        }
    }
}

/// How the master runs.
#[derive(Clone, Debug)]
pub struct ClusterConfig {
    /// The shared secret peers must prove.
    pub token: String,
    /// The scene to serve. Only its file name goes to peers.
    pub scene: SceneBundle,
    /// The scene's own camera (offered to viewers).
    pub camera: Camera,
    /// The scene's own settings (offered to viewers).
    pub settings: RenderSettings,
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
}

impl ClusterConfig {
    /// Defaults around a scene, a token and a nonce seed.
    pub fn new(
        token: String,
        scene: SceneBundle,
        camera: Camera,
        settings: RenderSettings,
        seed: [u8; 32],
    ) -> Self {
        Self {
            token,
            scene,
            camera,
            settings,
            scheduler: SchedulerConfig::default(),
            heartbeat_interval: Duration::from_millis(500),
            handshake_timeout: Duration::from_secs(10),
            sync_timeout: Duration::from_secs(600),
            compression: Compression::Auto,
            budgets: Budgets::default(),
            seed,
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
}

#[derive(Debug)]
enum PeerState {
    /// Challenged with this nonce; nothing proved yet.
    AwaitHello { nonce: [u8; 32] },
    /// A slave that proved the token, loading the scene since `since`.
    Syncing { threads: u32, since: Duration },
    /// A slave in the scheduler.
    Slave,
    /// A viewer (a client of its own), with its kind of work, its open
    /// frames, and whether it was told that they wait for slaves.
    Viewer { work: Work, frames: BTreeSet<FrameId>, told_waiting: bool },
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
}

/// A frame the master has open, as its viewer asked for it.
#[derive(Debug)]
struct FrameSpec {
    camera: Camera,
    settings: RenderSettings,
    viewer: PeerId,
    request: u64,
    /// Bytes received when it was requested.
    bytes_at_start: u64,
}

/// The master's state machine. See the [module docs](self).
#[derive(Debug)]
pub struct Cluster {
    token: String,
    scene: SceneInfo,
    scene_sync: Arc<Vec<u8>>,
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
    out: VecDeque<Transmit>,
    last_heartbeat: Duration,
    /// Message bytes received from every peer so far.
    bytes_received: u64,
    /// Bytes received when the last frame completed: a pipelined frame counts
    /// the bytes from there (or from its request, if later).
    bytes_at_last_done: u64,
    status: ClusterStatus,
    /// Where tiles are decoded to be checked (reused: no allocation per tile).
    scratch: Vec<u8>,
}

impl Cluster {
    /// A master for `cfg`; fails only if the scene cannot be encoded.
    pub fn new(cfg: ClusterConfig) -> Result<Self, ProtocolError> {
        let mut bundle = cfg.scene;
        bundle.name = protocol::served_name(&bundle.name).to_string();
        let hash = protocol::scene_hash(&bundle);
        let scene_sync =
            Arc::new(protocol::encode(&Message::SceneSync { hash, bundle: WireBundle::from(&bundle) })?);
        let scene = SceneInfo { name: bundle.name, hash, camera: cfg.camera, settings: cfg.settings };
        let sched = Scheduler::new(cfg.scheduler);
        let slave_max_frame = limits::slave_max_frame(sched.config().tile_size);
        Ok(Self {
            token: cfg.token,
            scene,
            scene_sync,
            heartbeat_interval: cfg.heartbeat_interval,
            handshake_timeout: cfg.handshake_timeout,
            sync_timeout: cfg.sync_timeout,
            compression: cfg.compression,
            budgets: cfg.budgets,
            slave_max_frame,
            nonces: Nonces::new(cfg.seed),
            sched,
            peers: BTreeMap::new(),
            handshaking: 0,
            frames: BTreeMap::new(),
            next_frame: 1,
            roster: Roster::default(),
            out: VecDeque::new(),
            last_heartbeat: Duration::ZERO,
            bytes_received: 0,
            bytes_at_last_done: 0,
            status: ClusterStatus::default(),
            scratch: Vec::new(),
        })
    }

    // ---- getters -------------------------------------------------------

    /// The scene being served, as peers are told of it.
    pub fn scene(&self) -> &SceneInfo {
        &self.scene
    }

    /// The budgets in force.
    pub fn budgets(&self) -> &Budgets {
        &self.budgets
    }

    /// The master's counters.
    pub fn status(&self) -> ClusterStatus {
        ClusterStatus { slaves: self.sched.slaves(), peers: self.peers.len(), ..self.status.clone() }
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
        peers.chain(heartbeat).chain(self.sched.poll_timeout()).filter(|&t| t != Duration::MAX).min()
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
        self.drain(now);
    }

    /// A decoded message from `peer`.
    pub fn handle_message(&mut self, now: Duration, peer: PeerId, msg: Message) {
        let Some(p) = self.peers.get_mut(&peer) else { return };
        p.last_heard = now;
        if matches!(p.state, PeerState::Slave) {
            // Every message from a slave is a sign of life.
            self.sched.handle_heartbeat(now, peer);
        }
        match (&p.state, msg) {
            (PeerState::AwaitHello { nonce }, Message::Hello(hello)) => {
                let nonce = *nonce;
                self.on_hello(now, peer, nonce, hello);
            }
            (PeerState::AwaitHello { .. }, other) => {
                self.refuse(now, peer, format!("expected Hello, got {}", other.kind()));
            }
            (PeerState::Syncing { threads, .. }, Message::Ready { hash }) => {
                if hash != self.scene.hash {
                    return self.refuse(now, peer, "slave loaded a different scene".into());
                }
                let threads = *threads;
                p.state = PeerState::Slave;
                let (name, addr) = (p.name.clone(), p.addr.clone());
                tracing::info!(slave = %name, threads, "slave {name} joined with {threads} threads");
                self.roster.join(peer, &name, &addr, threads);
                self.send_roster();
                for p in self.peers.values_mut() {
                    if let PeerState::Viewer { told_waiting, .. } = &mut p.state {
                        *told_waiting = false;
                    }
                }
                self.sched.handle_join(now, peer, name, threads);
                self.drain(now);
            }
            (PeerState::Slave, Message::TileResult(r)) => self.on_result(now, peer, r),
            (_, Message::Heartbeat) => {}
            (PeerState::Viewer { .. }, Message::FrameRequest { request, camera, settings }) => {
                self.request_frame(now, peer, request, camera, settings, false);
            }
            (PeerState::Viewer { .. }, Message::QueueFrame { request, camera, settings }) => {
                self.request_frame(now, peer, request, camera, settings, true);
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

    fn send_roster(&mut self) {
        let list = self.roster.message();
        let viewers: Vec<PeerId> = self
            .peers
            .iter()
            .filter(|(_, p)| matches!(p.state, PeerState::Viewer { .. }))
            .map(|(&id, _)| id)
            .collect();
        for id in viewers {
            self.send(id, list.clone());
        }
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
                peer.state =
                    PeerState::Viewer { work: hello.work, frames: BTreeSet::new(), told_waiting: false };
                tracing::info!(viewer = %peer.name, addr = %peer.addr, "viewer {} connected", peer.name);
                self.out.push_back(Transmit::Limit { peer: id, max_frame });
                self.send(id, Message::Welcome(welcome));
                self.send(id, self.roster.message());
            }
            Role::Slave => {
                peer.state = PeerState::Syncing { threads: hello.threads, since: now };
                let cached = hello.cached_scene == Some(self.scene.hash);
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
                if !cached {
                    self.out.push_back(Transmit::SendEncoded { peer: id, frame: self.scene_sync.clone() });
                }
            }
        }
    }

    fn on_result(&mut self, now: Duration, id: PeerId, r: TileResult) {
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
        // Untrusted: decoded (size checked before allocating) before it
        // counts, even when it is forwarded still encoded.
        if let Err(e) = codec::decode_into(r.codec, r.tile.w, r.tile.h, &r.pixels, &mut self.scratch) {
            return self.refuse(now, id, format!("tile {}: {e}", r.id));
        }
        self.sched.record_render_time(r.frame, r.id, r.render_micros);
        match self.sched.handle_result(now, id, r.frame, r.id) {
            ResultOutcome::Accepted { tile } => self.forward(id, r, tile),
            outcome => tracing::trace!(?outcome, "tile result dropped"),
        }
        self.drain(now);
    }

    /// A result for a tile `id` was never handed: refused and counted; past
    /// the budget, the slave goes.
    fn on_foreign(&mut self, now: Duration, id: PeerId, r: &TileResult) {
        self.status.foreign_results += 1;
        let Some(p) = self.peers.get_mut(&id) else { return };
        p.foreign += 1;
        tracing::warn!(slave = %p.name, frame = r.frame, tile = r.id, "refused a result for a tile {} was never handed", p.name);
        if p.foreign > self.budgets.foreign_results {
            let n = p.foreign;
            self.refuse(now, id, format!("{n} results for tiles it was never handed"));
        }
    }

    /// Sends an accepted tile to the viewer of its frame, in a codec it decodes.
    fn forward(&mut self, slave: PeerId, r: TileResult, tile: isin_tracer::Tile) {
        let Some(spec) = self.frames.get(&r.frame) else { return };
        let Some(viewer) = self.peers.get(&spec.viewer) else { return };
        let slave_name = self.peers.get(&slave).map(|p| p.name.clone()).unwrap_or_default();
        let (codec, pixels) = if viewer.decodes.contains(&r.codec) || r.codec == Codec::Raw {
            (r.codec, r.pixels)
        } else {
            (Codec::Raw, ByteBuf::from(self.scratch.clone()))
        };
        let message =
            Message::FrameTile(FrameTile { request: spec.request, slave, slave_name, tile, codec, pixels });
        self.out.push_back(Transmit::Send { peer: spec.viewer, message, class: Class::Tile });
    }

    /// A viewer's frame request: supersedes the open frames, or with `queue`
    /// waits behind them (the scheduler pipelines it).
    fn request_frame(
        &mut self,
        now: Duration,
        viewer: PeerId,
        request: u64,
        camera: Camera,
        settings: RenderSettings,
        queue: bool,
    ) {
        if let Err(message) = limits::validate_request(&camera, &settings) {
            return self.send(viewer, Message::Error { message });
        }
        let frame = self.next_frame;
        let (w, h) = (settings.width, settings.height);
        let work = match self.peers.get(&viewer).map(|p| &p.state) {
            Some(PeerState::Viewer { work, .. }) => *work,
            _ => return,
        };
        let order = FrameOrder { client: viewer, work, width: w, height: h, samples: settings.spp, queue };
        if let Err(e) = self.sched.open(now, frame, order) {
            return self.send(viewer, Message::Error { message: e.to_string() });
        }
        self.next_frame += 1;
        if let Some(PeerState::Viewer { frames, .. }) = self.peers.get_mut(&viewer).map(|p| &mut p.state) {
            if !queue {
                // The scheduler dropped this viewer's open frames (and no one else's).
                for old in std::mem::take(frames) {
                    self.frames.remove(&old);
                }
            }
            frames.insert(frame);
        }
        self.tell_if_waiting();
        self.status.frames_requested += 1;
        let spec = FrameSpec { camera, settings, viewer, request, bytes_at_start: self.bytes_received };
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
            if let PeerState::Viewer { frames, told_waiting, .. } = &mut p.state
                && !frames.is_empty()
                && !*told_waiting
            {
                *told_waiting = true;
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
        if matches!(p.state, PeerState::Viewer { .. }) {
            tracing::info!(viewer = %p.name, "viewer {} left ({reason})", p.name);
        }
        self.out.push_back(Transmit::Close { peer: id, reason });
        match p.state {
            PeerState::AwaitHello { .. } => self.handshaking -= 1,
            PeerState::Syncing { .. } => {}
            PeerState::Slave => self.sched.handle_disconnect(now, id),
            PeerState::Viewer { frames, .. } => {
                for f in frames {
                    self.sched.abandon(f);
                    self.frames.remove(&f);
                }
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
                        tracing::info!(
                            slave = name,
                            frame,
                            "reassigned {reassigned} tiles of dead slaves to {name}"
                        );
                    }
                    tracing::trace!(slave, frame, "assigning {} tiles", tiles.len());
                    let message = Message::TileAssignment(TileAssignment {
                        frame,
                        camera: spec.camera,
                        settings: spec.settings,
                        tiles,
                    });
                    self.send(slave, message);
                }
                Output::Cancel { slave, frame, tiles } => self.send(slave, Message::Cancel { frame, tiles }),
                Output::SlaveDead { slave, name, cause, requeued } => {
                    self.status.deaths += 1;
                    if self.roster.death(slave) {
                        self.send_roster();
                    }
                    self.tell_if_waiting();
                    tracing::warn!(slave = %name, "slave {name} dead ({cause:?}); {requeued} tiles requeued");
                    if cause == DeathCause::Timeout && self.peers.remove(&slave).is_some() {
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
                    self.status.last_frame = Some(stats.clone());
                    let Some(spec) = self.frames.remove(&frame) else { continue };
                    tracing::debug!(
                        frame,
                        "frame done in {:.1} ms: {} tiles, {} moved, {} duplicated, {} requeued",
                        stats.micros as f64 / 1e3,
                        stats.tiles,
                        stats.moved,
                        stats.duplicated,
                        stats.requeued
                    );
                    if let Some(PeerState::Viewer { frames, .. }) =
                        self.peers.get_mut(&spec.viewer).map(|p| &mut p.state)
                    {
                        frames.remove(&frame);
                    }
                    self.send(spec.viewer, Message::FrameDone { request: spec.request, stats });
                }
            }
        }
    }
}

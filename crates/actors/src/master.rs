//! The master actor: accepts slaves and viewers, authenticates them, ships the
//! scene, and turns the [`Scheduler`]'s decisions into messages.
//!
//! Everything time-dependent is the scheduler's; the actor only owns the clock
//! (a periodic tick feeds `now` into it) and the connections. Inputs arrive as
//! actix messages from per-connection reader tasks (`Inbound`, `Closed`),
//! so a connection that sends garbage is closed without disturbing the others.

use actix::prelude::*;
use isin_cluster::auth;
use isin_cluster::codec::{self, Codec, Compression};
use isin_cluster::protocol::{
    self, DEFAULT_MAX_FRAME, FrameId, FrameStats, FrameTile, HANDSHAKE_MAX_FRAME, MAX_SLAVE_TEXT,
    MAX_SLAVES_LISTED, Message, Role, SceneHash, SceneInfo, SlaveEntry, TileAssignment, Welcome, WireBundle,
};
use isin_cluster::scheduler::{DeathCause, Output, ResultOutcome, Scheduler, SchedulerConfig, SlaveInfo};
use isin_tracer::{Camera, RenderSettings, SceneBundle};
use isin_transport::{ConnStats, Connection, FrameSender, Listener};
use serde_bytes::ByteBuf;
use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Largest image a viewer may request, in pixels per side.
pub const MAX_IMAGE_SIDE: u32 = 16384;
/// Largest samples per pixel a viewer may request.
pub const MAX_SPP: u32 = 65536;
/// Largest shadow-ray count per area light a viewer may request.
pub const MAX_LIGHT_SAMPLES: u32 = 4096;
/// Largest recursion depth a viewer may request.
pub const MAX_DEPTH: u32 = 64;
/// Dead slaves still listed to viewers (the most recent ones).
pub const DEAD_SLAVES_LISTED: usize = 16;

/// How the master runs.
#[derive(Clone, Debug)]
pub struct MasterConfig {
    /// The shared secret peers must prove.
    pub token: String,
    /// The scene to serve.
    pub bundle: Arc<SceneBundle>,
    /// The scene's own camera (offered to viewers).
    pub camera: Camera,
    /// The scene's own settings (offered to viewers).
    pub settings: RenderSettings,
    /// Scheduling knobs.
    pub scheduler: SchedulerConfig,
    /// Period of the clock tick (timeouts, heartbeats).
    pub tick: Duration,
    /// How often the master tells peers it is alive.
    pub heartbeat_interval: Duration,
    /// A peer that has not authenticated within this is dropped.
    pub handshake_timeout: Duration,
    /// Largest frame accepted from an authenticated peer.
    pub max_frame: usize,
    /// Which tile codec to pick among those a peer offers.
    pub compression: Compression,
}

impl MasterConfig {
    /// Defaults around a scene and a token.
    pub fn new(token: String, bundle: SceneBundle, camera: Camera, settings: RenderSettings) -> Self {
        Self {
            token,
            bundle: Arc::new(bundle),
            camera,
            settings,
            scheduler: SchedulerConfig::default(),
            tick: Duration::from_millis(50),
            heartbeat_interval: Duration::from_millis(500),
            handshake_timeout: Duration::from_secs(10),
            max_frame: DEFAULT_MAX_FRAME,
            compression: Compression::Auto,
        }
    }
}

#[derive(Debug)]
enum PeerState {
    AwaitHello { nonce: [u8; 32] },
    Syncing { threads: u32 },
    Slave,
    Viewer,
}

#[derive(Debug)]
struct Peer {
    sender: FrameSender,
    name: String,
    addr: String,
    state: PeerState,
    since: Duration,
    /// The codec picked at join (the `Welcome` says it): slaves encode their
    /// tiles with it. (Viewers get tiles in any codec they offered.)
    codec: Codec,
    /// Viewers: every codec they offered (tiles in another are sent raw).
    decodes: Vec<Codec>,
}

struct FrameSpec {
    id: FrameId,
    bytes_in_at_start: u64,
    camera: Camera,
    settings: RenderSettings,
    viewer: u64,
    request: u64,
}

/// Counters of the whole master, for `isin bench` and the embedded default.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MasterStatus {
    /// The live slaves.
    pub slaves: Vec<SlaveInfo>,
    /// Frame requests accepted from viewers.
    pub frames_requested: u64,
    /// Frames completed.
    pub frames_done: u64,
    /// Bytes on all connections (closed ones included).
    pub wire: ConnStats,
    /// Connections refused (bad token, bad protocol, garbage).
    pub refused: u64,
    /// Slaves declared dead.
    pub deaths: u64,
    /// Last completed frame's stats.
    pub last_frame: Option<FrameStats>,
}

/// The master actor.
pub struct Master {
    cfg: MasterConfig,
    sched: Scheduler,
    epoch: Instant,
    next_peer: u64,
    peers: HashMap<u64, Peer>,
    /// Open frames, oldest first (more than one when a viewer queues frames).
    frames: Vec<FrameSpec>,
    next_frame: FrameId,
    /// Bytes received when the last frame completed: a pipelined frame counts
    /// the bytes from there (or from its request, if later), not those of the
    /// frame before it.
    bytes_in_at_last_done: u64,
    scene_hash: SceneHash,
    scene_sync: Arc<Vec<u8>>,
    last_heartbeat: Duration,
    status: MasterStatus,
    closed_wire: ConnStats,
    /// The slaves viewers are told about ([`Message::Slaves`]), by id.
    roster: std::collections::BTreeMap<u64, SlaveEntry>,
    /// Where tiles are decoded to be checked (reused: no allocation per tile).
    scratch: Vec<u8>,
}

impl Master {
    /// A master for `cfg`; fails only if the scene cannot be encoded.
    pub fn new(cfg: MasterConfig) -> Result<Self, protocol::ProtocolError> {
        let scene_hash = protocol::scene_hash(&cfg.bundle);
        let scene_sync = Arc::new(protocol::encode(&Message::SceneSync {
            hash: scene_hash,
            bundle: WireBundle::from(cfg.bundle.as_ref()),
        })?);
        Ok(Self {
            sched: Scheduler::new(cfg.scheduler.clone()),
            cfg,
            epoch: Instant::now(),
            next_peer: 1,
            peers: HashMap::new(),
            frames: Vec::new(),
            next_frame: 1,
            bytes_in_at_last_done: 0,
            scene_hash,
            scene_sync,
            last_heartbeat: Duration::ZERO,
            status: MasterStatus::default(),
            closed_wire: ConnStats::default(),
            roster: std::collections::BTreeMap::new(),
            scratch: Vec::new(),
        })
    }

    /// Starts the master and an accept loop on `listener`.
    pub fn serve(self, mut listener: Box<dyn Listener>) -> Addr<Master> {
        let addr = self.start();
        let target = addr.clone();
        tokio::spawn(async move {
            loop {
                match listener.accept().await {
                    Ok(conn) => target.do_send(Accepted(conn)),
                    Err(e) => {
                        tracing::warn!("accept failed: {e}");
                        if !target.connected() {
                            return;
                        }
                        tokio::time::sleep(Duration::from_millis(50)).await;
                    }
                }
            }
        });
        addr
    }

    /// Counters of every connection, open or closed.
    fn wire(&self) -> ConnStats {
        let mut wire = self.closed_wire;
        for p in self.peers.values() {
            let s = p.sender.stats();
            wire.bytes_sent += s.bytes_sent;
            wire.bytes_received += s.bytes_received;
            wire.frames_sent += s.frames_sent;
            wire.frames_received += s.frames_received;
        }
        wire
    }

    fn now(&self) -> Duration {
        self.epoch.elapsed()
    }

    fn send(&self, peer: u64, msg: &Message) {
        let Some(p) = self.peers.get(&peer) else { return };
        match protocol::encode(msg) {
            Ok(bytes) => {
                let _ = p.sender.send(bytes);
            }
            Err(e) => tracing::error!("cannot encode {}: {e}", msg.kind()),
        }
    }

    /// The slave list as viewers get it: the live slaves, then the most
    /// recently dead (bounded by [`MAX_SLAVES_LISTED`]).
    fn roster_message(&self) -> Message {
        let live = self.roster.values().filter(|e| e.alive);
        let dead = self.roster.values().rev().filter(|e| !e.alive);
        let slaves = live.chain(dead).take(MAX_SLAVES_LISTED).cloned().collect();
        Message::Slaves { slaves }
    }

    /// Tells every viewer the slave list.
    fn send_roster(&self) {
        let bytes = match protocol::encode(&self.roster_message()) {
            Ok(b) => b,
            Err(e) => return tracing::error!("cannot encode the slave list: {e}"),
        };
        for p in self.peers.values().filter(|p| matches!(p.state, PeerState::Viewer)) {
            let _ = p.sender.send(bytes.clone());
        }
    }

    /// A slave joined: list it and tell the viewers.
    fn roster_join(&mut self, id: u64, name: &str, addr: &str, threads: u32) {
        // At most MAX_SLAVE_TEXT bytes, cut at a character boundary.
        let cut = |s: &str| {
            let mut out = String::new();
            for c in s.chars().filter(|c| !c.is_control()) {
                if out.len() + c.len_utf8() > MAX_SLAVE_TEXT {
                    break;
                }
                out.push(c);
            }
            out
        };
        self.roster.insert(id, SlaveEntry { id, name: cut(name), addr: cut(addr), threads, alive: true });
        self.send_roster();
    }

    /// A slave died: keep it listed as dead (the latest few) and tell the viewers.
    fn roster_death(&mut self, id: u64) {
        let Some(e) = self.roster.get_mut(&id) else { return };
        e.alive = false;
        let dead: Vec<u64> = self.roster.values().filter(|e| !e.alive).map(|e| e.id).collect();
        for old in dead.iter().take(dead.len().saturating_sub(DEAD_SLAVES_LISTED)) {
            self.roster.remove(old);
        }
        self.send_roster();
    }

    fn drop_peer(&mut self, id: u64, why: &str) {
        if let Some(p) = self.peers.remove(&id) {
            self.retire(&p);
            tracing::debug!(peer = %p.name, addr = %p.addr, "connection closed: {why}");
            match p.state {
                PeerState::Slave => {
                    let now = self.now();
                    self.sched.handle_disconnect(now, id);
                }
                PeerState::Viewer => {
                    for f in self.frames.iter().filter(|f| f.viewer == id) {
                        self.sched.abandon(f.id);
                    }
                    self.frames.retain(|f| f.viewer != id);
                }
                PeerState::AwaitHello { .. } | PeerState::Syncing { .. } => {}
            }
        }
        self.drain();
    }

    /// Closes a removed peer's connection, keeping its byte counts.
    fn retire(&mut self, p: &Peer) {
        let s = p.sender.stats();
        self.closed_wire.bytes_sent += s.bytes_sent;
        self.closed_wire.bytes_received += s.bytes_received;
        self.closed_wire.frames_sent += s.frames_sent;
        self.closed_wire.frames_received += s.frames_received;
        p.sender.close();
    }

    fn refuse(&mut self, id: u64, reason: String) {
        if let Some(p) = self.peers.get(&id) {
            tracing::warn!(addr = %p.addr, "refused {}: {reason}", p.name);
        }
        self.status.refused += 1;
        self.send(id, &Message::Reject { reason });
        self.drop_peer(id, "refused");
    }

    fn drain(&mut self) {
        let now = self.now();
        while let Some(out) = self.sched.poll_output(now) {
            match out {
                Output::Assign { slave, frame, tiles, reassigned } => {
                    let Some(spec) = self.frames.iter().find(|f| f.id == frame) else { continue };
                    if reassigned > 0 {
                        let name = self.peers.get(&slave).map_or("?", |p| p.name.as_str());
                        tracing::info!(
                            slave = name,
                            frame,
                            "reassigned {reassigned} tiles of dead slaves to {name}"
                        );
                    }
                    tracing::trace!(slave, frame, "assigning {} tiles", tiles.len());
                    let msg = Message::TileAssignment(TileAssignment {
                        frame,
                        camera: spec.camera,
                        settings: spec.settings,
                        tiles,
                    });
                    self.send(slave, &msg);
                }
                Output::Cancel { slave, frame, tiles } => self.send(slave, &Message::Cancel { frame, tiles }),
                Output::SlaveDead { slave, name, cause, requeued } => {
                    self.status.deaths += 1;
                    self.roster_death(slave);
                    tracing::warn!(slave = %name, "slave {name} dead ({cause:?}); {requeued} tiles requeued");
                    if cause == DeathCause::Timeout
                        && let Some(p) = self.peers.remove(&slave)
                    {
                        self.retire(&p);
                    }
                }
                Output::FrameDone { frame, mut stats } => {
                    let received = self.wire().bytes_received;
                    if let Some(spec) = self.frames.iter().find(|f| f.id == frame) {
                        let from = spec.bytes_in_at_start.max(self.bytes_in_at_last_done);
                        stats.bytes_in = received.saturating_sub(from);
                    }
                    self.bytes_in_at_last_done = received;
                    self.status.frames_done += 1;
                    self.status.last_frame = Some(stats.clone());
                    let spec = self.frames.iter().position(|f| f.id == frame).map(|i| self.frames.remove(i));
                    if let Some(spec) = spec {
                        tracing::info!(
                            frame,
                            "frame done in {:.1} ms: {} tiles, {} moved, {} duplicated, {} requeued",
                            stats.micros as f64 / 1e3,
                            stats.tiles,
                            stats.moved,
                            stats.duplicated,
                            stats.requeued
                        );
                        self.send(spec.viewer, &Message::FrameDone { request: spec.request, stats });
                    }
                }
            }
        }
    }

    fn on_message(&mut self, id: u64, msg: Message) {
        let now = self.now();
        let Some(peer) = self.peers.get_mut(&id) else { return };
        match (&peer.state, msg) {
            (PeerState::AwaitHello { nonce }, Message::Hello(hello)) => {
                let nonce = *nonce;
                let expected = auth::client_proof(&self.cfg.token, hello.role, &nonce, &hello.client_nonce);
                if !auth::proofs_match(&expected, &hello.proof) {
                    return self.refuse(id, "authentication failed: wrong token".into());
                }
                let name: String = hello.name.chars().filter(|c| !c.is_control()).take(48).collect();
                peer.name = format!("{name}#{id}");
                peer.sender.set_max_frame(self.cfg.max_frame);
                peer.codec = codec::negotiate(self.cfg.compression, &hello.codecs);
                peer.decodes = hello.codecs.iter().filter_map(|n| Codec::from_name(n)).collect();
                let welcome = Welcome {
                    id,
                    name: peer.name.clone(),
                    proof: auth::server_proof(&self.cfg.token, hello.role, &nonce, &hello.client_nonce),
                    scene: SceneInfo {
                        name: self.cfg.bundle.name.clone(),
                        hash: self.scene_hash,
                        camera: self.cfg.camera,
                        settings: self.cfg.settings,
                    },
                    codec: peer.codec,
                };
                match hello.role {
                    Role::Viewer => {
                        peer.state = PeerState::Viewer;
                        tracing::info!(viewer = %peer.name, addr = %peer.addr, "viewer {} connected", peer.name);
                        self.send(id, &Message::Welcome(welcome));
                        self.send(id, &self.roster_message());
                    }
                    Role::Slave => {
                        peer.state = PeerState::Syncing { threads: hello.threads };
                        let cached = hello.cached_scene == Some(self.scene_hash);
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
                        self.send(id, &Message::Welcome(welcome));
                        if !cached && let Some(p) = self.peers.get(&id) {
                            let _ = p.sender.send(self.scene_sync.as_ref().clone());
                        }
                    }
                }
            }
            (PeerState::AwaitHello { .. }, other) => {
                self.refuse(id, format!("expected Hello, got {}", other.kind()));
            }
            (PeerState::Syncing { threads }, Message::Ready { hash }) => {
                if hash != self.scene_hash {
                    return self.refuse(id, "slave loaded a different scene".into());
                }
                let threads = *threads;
                peer.state = PeerState::Slave;
                let name = peer.name.clone();
                let addr = peer.addr.clone();
                tracing::info!(slave = %name, threads, "slave {name} joined with {threads} threads");
                self.roster_join(id, &name, &addr, threads);
                self.sched.handle_join(now, id, name, threads);
                self.drain();
            }
            (PeerState::Slave, Message::TileResult(r)) => {
                tracing::trace!(slave = id, frame = r.frame, tile = r.id, "tile result");
                let Some(rect) = self.sched.tile(r.frame, r.id) else {
                    // Not the current frame: stale, drop quietly.
                    self.sched.handle_heartbeat(now, id);
                    return;
                };
                if r.tile != rect {
                    let got = r.tile;
                    return self.refuse(id, format!("tile {} is {got:?}, but {rect:?} was assigned", r.id));
                }
                // Untrusted: decoded (size checked before allocating) before it
                // counts, even when it is forwarded still encoded.
                if let Err(e) = codec::decode_into(r.codec, r.tile.w, r.tile.h, &r.pixels, &mut self.scratch)
                {
                    return self.refuse(id, format!("tile {}: {e}", r.id));
                }
                self.sched.record_render_time(r.frame, r.id, r.render_micros);
                match self.sched.handle_result(now, id, r.frame, r.id) {
                    ResultOutcome::Accepted { tile } => {
                        if let Some(spec) = self.frames.iter().find(|f| f.id == r.frame) {
                            let slave_name = self.peers.get(&id).map(|p| p.name.clone()).unwrap_or_default();
                            let viewer_decodes =
                                self.peers.get(&spec.viewer).is_some_and(|v| v.decodes.contains(&r.codec));
                            let (codec, pixels) = if viewer_decodes || r.codec == Codec::Raw {
                                (r.codec, r.pixels)
                            } else {
                                (Codec::Raw, ByteBuf::from(self.scratch.clone()))
                            };
                            let msg = Message::FrameTile(FrameTile {
                                request: spec.request,
                                slave: id,
                                slave_name,
                                tile,
                                codec,
                                pixels,
                            });
                            self.send(spec.viewer, &msg);
                        }
                    }
                    outcome => tracing::trace!(?outcome, "tile result dropped"),
                }
                self.drain();
            }
            (PeerState::Slave | PeerState::Syncing { .. }, Message::Heartbeat) => {
                self.sched.handle_heartbeat(now, id);
            }
            (PeerState::Viewer, Message::FrameRequest { request, camera, settings }) => {
                self.request_frame(id, request, camera, settings, false);
            }
            (PeerState::Viewer, Message::QueueFrame { request, camera, settings }) => {
                self.request_frame(id, request, camera, settings, true);
            }
            (PeerState::Viewer, Message::Heartbeat) => {}
            (_, Message::Error { message }) => {
                tracing::warn!(peer = %peer.name, "peer reports: {message}");
            }
            (_, other) => {
                let kind = other.kind();
                self.refuse(id, format!("unexpected {kind} message"));
            }
        }
    }

    /// A viewer's frame request: supersedes the open frames, or with `queue`
    /// waits behind them (the scheduler pipelines it).
    fn request_frame(
        &mut self,
        id: u64,
        request: u64,
        camera: Camera,
        settings: RenderSettings,
        queue: bool,
    ) {
        let now = self.now();
        if let Err(e) = validate_request(&camera, &settings) {
            return self.send(id, &Message::Error { message: e });
        }
        let frame = self.next_frame;
        self.next_frame += 1;
        let (w, h) = (settings.width, settings.height);
        let started = if queue {
            self.sched.queue_frame(now, frame, w, h)
        } else {
            self.sched.submit_frame(now, frame, w, h)
        };
        if let Err(e) = started {
            return self.send(id, &Message::Error { message: e.to_string() });
        }
        if !queue {
            for old in std::mem::take(&mut self.frames).into_iter().filter(|f| f.viewer != id) {
                let message = format!("request {} superseded by another viewer's request", old.request);
                self.send(old.viewer, &Message::Error { message });
            }
        }
        self.status.frames_requested += 1;
        let bytes_in_at_start = self.wire().bytes_received;
        self.frames.push(FrameSpec { id: frame, bytes_in_at_start, camera, settings, viewer: id, request });
        tracing::debug!(frame, request, queue, "frame requested {w}x{h}");
        self.drain();
    }

    fn on_tick(&mut self) {
        let now = self.now();
        self.sched.handle_timeout(now);
        let late: Vec<u64> = self
            .peers
            .iter()
            .filter(|(_, p)| {
                matches!(p.state, PeerState::AwaitHello { .. }) && now > p.since + self.cfg.handshake_timeout
            })
            .map(|(&id, _)| id)
            .collect();
        for id in late {
            self.refuse(id, "handshake timed out".into());
        }
        if now >= self.last_heartbeat + self.cfg.heartbeat_interval {
            self.last_heartbeat = now;
            if let Ok(hb) = protocol::encode(&Message::Heartbeat) {
                for p in self.peers.values() {
                    if !matches!(p.state, PeerState::AwaitHello { .. }) {
                        let _ = p.sender.send(hb.clone());
                    }
                }
            }
        }
        self.drain();
    }
}

fn validate_request(camera: &Camera, s: &RenderSettings) -> Result<(), String> {
    camera.validate().map_err(|e| format!("bad camera: {e}"))?;
    if s.width == 0 || s.height == 0 || s.width > MAX_IMAGE_SIDE || s.height > MAX_IMAGE_SIDE {
        return Err(format!("image size {}x{} out of range 1..={MAX_IMAGE_SIDE}", s.width, s.height));
    }
    if s.spp == 0 || s.spp > MAX_SPP {
        return Err(format!("samples per pixel {} out of range 1..={MAX_SPP}", s.spp));
    }
    if s.light_samples > MAX_LIGHT_SAMPLES || s.max_depth > MAX_DEPTH {
        return Err(format!(
            "light samples {} / depth {} above the limits {MAX_LIGHT_SAMPLES} / {MAX_DEPTH}",
            s.light_samples, s.max_depth
        ));
    }
    Ok(())
}

impl Actor for Master {
    type Context = Context<Self>;

    fn started(&mut self, ctx: &mut Self::Context) {
        ctx.run_interval(self.cfg.tick, |m, _| m.on_tick());
    }
}

/// A new connection from the listener.
#[derive(Message)]
#[rtype(result = "()")]
pub struct Accepted(pub Connection);

/// A frame (or a transport error) from connection `peer`.
#[derive(Message)]
#[rtype(result = "()")]
struct Inbound {
    peer: u64,
    frame: Result<Vec<u8>, isin_transport::TransportError>,
}

/// Connection `peer` ended.
#[derive(Message)]
#[rtype(result = "()")]
struct Closed {
    peer: u64,
}

/// Asks for the master's counters.
#[derive(Message)]
#[rtype(result = "MasterStatus")]
pub struct GetStatus;

impl Handler<Accepted> for Master {
    type Result = ();

    fn handle(&mut self, Accepted(conn): Accepted, ctx: &mut Self::Context) {
        let id = self.next_peer;
        self.next_peer += 1;
        let Ok(nonce) = auth::random_bytes::<32>() else {
            tracing::error!("no randomness: refusing connection");
            conn.sender.close();
            return;
        };
        let Connection { peer: addr, sender, mut receiver } = conn;
        sender.set_max_frame(HANDSHAKE_MAX_FRAME);
        let me = ctx.address();
        tokio::spawn(async move {
            while let Some(frame) = receiver.recv().await {
                me.do_send(Inbound { peer: id, frame });
            }
            me.do_send(Closed { peer: id });
        });
        let now = self.now();
        tracing::debug!(%addr, "connection #{id}");
        self.peers.insert(
            id,
            Peer {
                sender,
                name: format!("peer#{id}"),
                addr,
                state: PeerState::AwaitHello { nonce },
                since: now,
                codec: Codec::Raw,
                decodes: Vec::new(),
            },
        );
        self.send(id, &Message::Challenge { nonce });
    }
}

impl Handler<Inbound> for Master {
    type Result = ();

    fn handle(&mut self, msg: Inbound, _: &mut Self::Context) {
        let Some(peer) = self.peers.get(&msg.peer) else { return };
        let max = if matches!(peer.state, PeerState::AwaitHello { .. }) {
            HANDSHAKE_MAX_FRAME
        } else {
            self.cfg.max_frame
        };
        match msg
            .frame
            .map_err(|e| e.to_string())
            .and_then(|f| protocol::decode(&f, max).map_err(|e| e.to_string()))
        {
            Ok(m) => self.on_message(msg.peer, m),
            Err(e) => self.refuse(msg.peer, format!("bad frame: {e}")),
        }
    }
}

impl Handler<Closed> for Master {
    type Result = ();

    fn handle(&mut self, msg: Closed, _: &mut Self::Context) {
        self.drop_peer(msg.peer, "peer closed");
    }
}

impl Handler<GetStatus> for Master {
    type Result = MessageResult<GetStatus>;

    fn handle(&mut self, _: GetStatus, _: &mut Self::Context) -> Self::Result {
        let mut status = self.status.clone();
        status.slaves = self.sched.slaves();
        status.wire = self.wire();
        MessageResult(status)
    }
}

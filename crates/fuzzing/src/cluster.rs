//! The structure-aware target: the master's core (`isin_cluster::Cluster`)
//! driven by simulated slaves and viewers that speak the real protocol —
//! encoded frames in, [`Transmit`]s out through a simulated transport that
//! applies the frame limits the core sets — in an order and with lies the
//! fuzzer picks ([`Step`], built from its bytes with `arbitrary`).
//!
//! Peers answer the challenge with a right (or wrong) proof, load the scene
//! and heartbeat on their own; the fuzzer connects and disconnects them, has
//! viewers request and queue frames within the limits, has slaves return
//! their tiles right, with the wrong rectangle, truncated, corrupt, late,
//! twice, or results for tiles they were never handed, sends garbage, falls
//! silent and moves the virtual clock. After every step the invariants hold:
//!
//! - every tile a viewer gets belongs to one of its live requests, decodes in
//!   a codec it offered, holds the render every slave agrees on, and covers
//!   pixels not delivered before; every `FrameDone` finds each pixel of its
//!   frame delivered exactly once;
//! - nobody without the token gets in, the master's proof is right, a slave
//!   holding the scene is not sent it again, each role hears only its
//!   messages, nobody is spoken to after being closed or closed twice;
//! - the core's peers are exactly the open connections, within
//!   `max_peers` and `max_handshaking`; its slaves are exactly the open ready
//!   ones; it counts no more foreign results than were forged, and refuses an
//!   honest peer only for silence or a full house, a forger only past its
//!   budget, and never a slave for what a viewer claims of it (a receipt of
//!   a tile straight from a slave, for a frame that is not direct).
//!
//! At the end every slave turns honest (and one joins if none is left): each
//! request still live must then complete — no tile is lost for good.

use arbitrary::{Arbitrary, Unstructured};
use isin_cluster::auth;
use isin_cluster::codec::{self, Codec};
use isin_cluster::limits::Budgets;
use isin_cluster::protocol::{
    self, FrameId, HANDSHAKE_MAX_FRAME, Hello, Message, Role, SceneHash, TileId, TileReceived, TileResult,
};
use isin_cluster::scheduler::{SchedulerConfig, Work};
use isin_cluster::{Cluster, ClusterConfig, DefaultScene, PeerId, Transmit};
use isin_tracer::{Camera, RenderSettings, SceneBundle, Tile};
use serde_bytes::ByteBuf;
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::time::Duration;

/// The token honest peers know.
const TOKEN: &str = "fuzz-token";

/// How often simulated peers say they are alive.
const HEARTBEAT: Duration = Duration::from_millis(500);

/// The clock's step while time passes.
const TICK: Duration = Duration::from_millis(100);

/// Most steps one input runs.
const MAX_STEPS: usize = 256;

/// A core around a tiny fake scene (the core never loads it), admitting at
/// most `max_peers` connections, `max_handshaking` of them unauthenticated.
pub(crate) fn core_config(max_peers: usize, max_handshaking: usize) -> ClusterConfig {
    let mut assets = BTreeMap::new();
    assets.insert("mesh.bin".to_string(), vec![42u8; 64]);
    let scene = SceneBundle { name: "fuzz.toml".into(), source: "fake scene".into(), assets };
    let scene =
        DefaultScene { bundle: scene, camera: Camera::default(), settings: RenderSettings::default() };
    let mut cfg = ClusterConfig::new(TOKEN.into(), Some(scene), [7; 32]);
    cfg.budgets = Budgets { max_peers, max_handshaking, ..Budgets::default() };
    cfg
}

/// What the simulated transport did with one [`Transmit`].
#[derive(Debug)]
pub(crate) enum Carried {
    /// A message reached `peer` (encoded and decoded, as on a real wire).
    Message(PeerId, Message),
    /// `peer` may now send frames of `max_frame` bytes.
    Limit(PeerId, usize),
    /// `peer`'s connection was closed by the core.
    Closed(PeerId, String),
    /// Something for the state directory (no peer concerned).
    Stored,
}

#[derive(Debug)]
struct Conn {
    limit: usize,
    closed: Option<String>,
    gone: bool,
}

/// The connections between the core and its peers, as a transport keeps
/// them: frame limits, and who is closed.
#[derive(Debug, Default)]
pub(crate) struct Wire {
    conns: BTreeMap<PeerId, Conn>,
}

impl Wire {
    /// A new connection, at the handshake's frame limit.
    pub(crate) fn connect(&mut self, id: PeerId) {
        self.conns.insert(id, Conn { limit: HANDSHAKE_MAX_FRAME, closed: None, gone: false });
    }

    /// The peer closed its end.
    pub(crate) fn gone(&mut self, id: PeerId) {
        if let Some(c) = self.conns.get_mut(&id) {
            c.gone = true;
        }
    }

    /// Connections neither side has closed.
    pub(crate) fn open(&self) -> usize {
        self.conns.values().filter(|c| c.is_open()).count()
    }

    fn is_open(&self, id: PeerId) -> bool {
        self.conns.get(&id).is_some_and(Conn::is_open)
    }

    fn is_gone(&self, id: PeerId) -> bool {
        self.conns.get(&id).is_some_and(|c| c.gone)
    }

    fn limit(&self, id: PeerId) -> usize {
        self.conns.get(&id).map_or(HANDSHAKE_MAX_FRAME, |c| c.limit)
    }

    /// Carries out `t`. Panics if the core speaks to a peer it never had, or
    /// after the peer or the core closed the connection, or closes it twice.
    pub(crate) fn carry(&mut self, t: Transmit) -> Carried {
        if let Transmit::Store(_) = t {
            return Carried::Stored;
        }
        let peer = t.peer();
        let conn = self.conns.get_mut(&peer).unwrap_or_else(|| panic!("transmission to unknown peer {peer}"));
        let deliver = |frame: &[u8]| {
            assert!(conn.closed.is_none(), "sent to peer {peer} after closing it");
            assert!(!conn.gone, "sent to peer {peer} after it closed");
            let msg = protocol::decode(frame, usize::MAX).expect("the core's frames decode");
            Carried::Message(peer, msg)
        };
        match t {
            Transmit::Send { message, .. } => {
                deliver(&protocol::encode(&message).expect("the core's messages encode"))
            }
            Transmit::SendEncoded { frame, .. } => deliver(&frame),
            Transmit::SendFrame { frame, .. } => deliver(&frame),
            Transmit::Limit { max_frame, .. } => {
                assert!(conn.closed.is_none() && !conn.gone, "limit set on closed peer {peer}");
                conn.limit = max_frame;
                Carried::Limit(peer, max_frame)
            }
            Transmit::Close { reason, .. } => {
                assert!(conn.closed.is_none(), "peer {peer} closed twice");
                conn.closed = Some(reason.clone());
                Carried::Closed(peer, reason)
            }
            Transmit::Store(_) => Carried::Stored,
        }
    }
}

impl Conn {
    fn is_open(&self) -> bool {
        self.closed.is_none() && !self.gone
    }
}

/// The core's configuration, as the fuzzer picks it.
#[derive(Arbitrary, Debug)]
struct Setup {
    max_peers: u8,
    max_handshaking: u8,
    foreign_results: u8,
    tile_size: u8,
    queue_depth: u8,
    heartbeat_timeout_s: u8,
    duplicate_stragglers: bool,
    max_open_frames: u8,
}

/// What a slave returns for a tile.
#[derive(Arbitrary, Clone, Copy, Debug, PartialEq, Eq)]
enum How {
    /// The right pixels in the codec the master picked.
    Right,
    /// The right pixels, encoded and labelled with another codec.
    OtherCodec,
    /// Another rectangle than the one assigned.
    WrongRect,
    /// Pixels cut short.
    Truncated,
    /// Bytes that are no valid encoding.
    Corrupt,
}

/// One step of the script.
#[derive(Arbitrary, Debug)]
enum Step {
    /// A slave connects.
    Slave { threads: u8, codecs: u8, cached: bool, wrong_token: bool },
    /// A viewer connects.
    Viewer { batch: bool, codecs: u8, wrong_token: bool },
    /// A peer connects and never says a word.
    Mute,
    /// A viewer requests (or queues) a frame, within the limits.
    Request { viewer: u8, width: u8, height: u8, spp: u8, seed: u8, queue: bool },
    /// A slave returns results for the first `tiles` tiles it holds.
    Render { slave: u8, tiles: u8, how: How },
    /// A slave returns a tile it was told to drop, rendered anyway.
    Late { slave: u8 },
    /// A slave sends its last result again.
    Replay { slave: u8 },
    /// A slave sends a result for a tile it was never handed.
    Forge { slave: u8, frame: u8, tile: u16 },
    /// A peer heartbeats out of turn.
    Heartbeat { peer: u8 },
    /// A peer stops heartbeating (and rendering) for good.
    Silence { peer: u8 },
    /// A peer sends a frame that is no message it may send.
    Garbage { peer: u8, frame: Vec<u8> },
    /// A peer closes its connection.
    Disconnect { peer: u8 },
    /// Time passes, in tenths of a second.
    Advance { tenths: u8 },
    /// A viewer claims a tile of a frame came to it straight from a slave
    /// (its frames are never direct: it is lying, and no slave may pay for it).
    Receipt { viewer: u8, frame: u8, tile: u16, slave: u8 },
}

/// A tile a slave holds.
#[derive(Clone, Copy, Debug)]
struct Job {
    frame: FrameId,
    id: TileId,
    tile: Tile,
    seed: u64,
}

#[derive(Debug, Default)]
struct SlaveSim {
    threads: u32,
    cached: bool,
    /// The codec the master picked ([`Message::Welcome`]).
    codec: Option<Codec>,
    ready: bool,
    syncs: u32,
    /// The scene coming in.
    incoming: Option<Box<isin_cluster::scene_stream::Receiver>>,
    queue: VecDeque<Job>,
    cancelled: Vec<Job>,
    last_result: Option<Vec<u8>>,
    /// Every tile it was ever handed, by frame.
    handed: BTreeMap<FrameId, BTreeSet<TileId>>,
    forged: u32,
}

#[derive(Debug)]
struct Request {
    settings: RenderSettings,
    writes: Vec<u8>,
    /// Accepted, not superseded, not done.
    live: bool,
    done: bool,
}

#[derive(Debug, Default)]
struct ViewerSim {
    next_request: u64,
    requests: BTreeMap<u64, Request>,
    errors: u32,
}

#[derive(Debug)]
enum Kind {
    Slave(SlaveSim),
    Viewer(ViewerSim),
    Mute,
}

#[derive(Debug)]
struct SimPeer {
    kind: Kind,
    role: Role,
    offered: Vec<Codec>,
    work: Work,
    token: &'static str,
    /// The challenge, once heard, and the nonce it answered with.
    nonces: Option<([u8; 32], [u8; 32])>,
    welcomed: bool,
    /// Stopped heartbeating and rendering.
    silent: bool,
    /// Sent something no honest peer sends: it may be refused for anything.
    misbehaved: bool,
    next_heartbeat: Duration,
}

impl SimPeer {
    fn honest(&self) -> bool {
        !self.misbehaved && self.token == TOKEN
    }
}

/// The core, its simulated peers and the virtual clock.
struct Net {
    core: Cluster,
    wire: Wire,
    now: Duration,
    peers: BTreeMap<PeerId, SimPeer>,
    next_peer: PeerId,
    /// Frames to the core, in order.
    outbox: VecDeque<(PeerId, Vec<u8>)>,
    budgets: Budgets,
    scene_hash: SceneHash,
    /// Every frame some slave was assigned tiles of, with their rectangles.
    frames: BTreeMap<FrameId, BTreeMap<TileId, Tile>>,
    forged: u64,
}

/// The render every slave agrees on: a hash of the frame's seed and the pixel.
fn shade(seed: u64, x: u32, y: u32) -> [u8; 3] {
    let mut h = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ (u64::from(x) << 32 | u64::from(y));
    h ^= h >> 29;
    h = h.wrapping_mul(0xbf58_476d_1ce4_e5b9);
    h ^= h >> 32;
    [h as u8, (h >> 8) as u8, (h >> 16) as u8]
}

fn render(seed: u64, t: Tile) -> Vec<u8> {
    let mut rgb = Vec::with_capacity(t.pixel_count() * 3);
    for y in t.y..t.y + t.h {
        for x in t.x..t.x + t.w {
            rgb.extend_from_slice(&shade(seed, x, y));
        }
    }
    rgb
}

/// The codecs named by the low bits of `mask`.
fn codecs(mask: u8) -> Vec<Codec> {
    Codec::ALL.iter().enumerate().filter(|(i, _)| mask & (1 << i) != 0).map(|(_, &c)| c).collect()
}

/// Reasons the core may give for closing a peer that did nothing wrong.
fn full_house(reason: &str) -> bool {
    reason.contains("the most allowed")
}

impl Net {
    fn new(setup: &Setup) -> Self {
        let mut cfg =
            core_config(1 + usize::from(setup.max_peers % 8), 1 + usize::from(setup.max_handshaking % 4));
        cfg.budgets.foreign_results = u32::from(setup.foreign_results % 4);
        cfg.scheduler = SchedulerConfig {
            tile_size: [8, 16, 32][usize::from(setup.tile_size % 3)],
            min_tile_size: 8,
            queue_depth: u32::from(setup.queue_depth % 3),
            heartbeat_timeout: Duration::from_secs(1 + u64::from(setup.heartbeat_timeout_s % 5)),
            duplicate_stragglers: setup.duplicate_stragglers,
            max_open_frames: 1 + u32::from(setup.max_open_frames % 4),
        };
        let budgets = cfg.budgets.clone();
        let core = Cluster::new(cfg).expect("the scene encodes");
        let scene_hash = core.scene().expect("a default scene").hash;
        Self {
            core,
            wire: Wire::default(),
            now: Duration::ZERO,
            peers: BTreeMap::new(),
            next_peer: 1,
            outbox: VecDeque::new(),
            budgets,
            scene_hash,
            frames: BTreeMap::new(),
            forged: 0,
        }
    }

    fn connect(&mut self, kind: Kind, offered: Vec<Codec>, work: Work, token: &'static str) -> PeerId {
        let id = self.next_peer;
        self.next_peer += 1;
        let role = if matches!(kind, Kind::Viewer(_)) { Role::Viewer } else { Role::Slave };
        let peer = SimPeer {
            kind,
            role,
            offered,
            work,
            token,
            nonces: None,
            welcomed: false,
            silent: false,
            misbehaved: false,
            next_heartbeat: self.now + HEARTBEAT,
        };
        self.peers.insert(id, peer);
        self.wire.connect(id);
        self.core.handle_connected(self.now, id, &format!("fuzz:{id}"));
        self.pump();
        id
    }

    /// The `n`-th (modulo their number) of the connected peers `which` picks.
    fn pick_where(&self, n: u8, which: impl Fn(&SimPeer) -> bool) -> Option<PeerId> {
        let ids: Vec<PeerId> = self
            .peers
            .iter()
            .filter(|(id, p)| self.wire.is_open(**id) && which(p))
            .map(|(&id, _)| id)
            .collect();
        (!ids.is_empty()).then(|| ids[usize::from(n) % ids.len()])
    }

    fn pick(&self, n: u8) -> Option<PeerId> {
        self.pick_where(n, |_| true)
    }

    /// A connected slave that has loaded the scene.
    fn pick_slave(&self, n: u8) -> Option<PeerId> {
        self.pick_where(n, |p| matches!(&p.kind, Kind::Slave(s) if s.ready))
    }

    fn pick_viewer(&self, n: u8) -> Option<PeerId> {
        self.pick_where(n, |p| matches!(p.kind, Kind::Viewer(_)))
    }

    fn slave_mut(&mut self, id: PeerId) -> &mut SlaveSim {
        match &mut self.peers.get_mut(&id).expect("known peer").kind {
            Kind::Slave(s) => s,
            _ => panic!("{id} is not a slave"),
        }
    }

    fn send(&mut self, id: PeerId, msg: &Message) {
        self.outbox.push_back((id, protocol::encode(msg).expect("encodes")));
    }

    /// Moves frames both ways until nothing is left to move.
    fn pump(&mut self) {
        loop {
            while let Some(t) = self.core.poll_transmit() {
                let carried = self.wire.carry(t);
                self.on_carried(carried);
            }
            let Some((id, frame)) = self.outbox.pop_front() else { return };
            if !self.wire.is_open(id) {
                continue;
            }
            if frame.len() > self.wire.limit(id) {
                // What the transport does: refused before it is read.
                self.core.handle_transport_error(self.now, id, "frame too large");
            } else {
                self.core.handle_frame(self.now, id, &frame);
            }
        }
    }

    fn on_carried(&mut self, carried: Carried) {
        match carried {
            Carried::Message(id, msg) => self.deliver(id, msg),
            Carried::Limit(id, _) => {
                let p = &self.peers[&id];
                assert!(p.token == TOKEN, "limit raised for peer {id} without the token");
            }
            Carried::Stored => {}
            Carried::Closed(id, _) if self.wire.is_gone(id) => {}
            Carried::Closed(id, reason) => {
                let p = &self.peers[&id];
                let forged = match &p.kind {
                    Kind::Slave(s) => s.forged,
                    _ => 0,
                };
                if reason.contains("never handed") {
                    assert!(forged > self.budgets.foreign_results, "refused after {forged} forged results");
                } else if p.honest() && !full_house(&reason) {
                    let silent = p.silent && reason.contains("silent");
                    let mute = matches!(p.kind, Kind::Mute) && reason.contains("handshake timed out");
                    assert!(silent || mute, "honest peer {id} refused: {reason}");
                }
            }
        }
    }

    fn deliver(&mut self, id: PeerId, msg: Message) {
        let scene_hash = self.scene_hash;
        let p = self.peers.get_mut(&id).expect("known peer");
        let kind = msg.kind();
        let allowed: &[&str] = match (&p.kind, p.welcomed) {
            (_, false) => &["Challenge", "Welcome", "Reject"],
            (Kind::Mute, true) => &[],
            (Kind::Slave(_), true) => {
                &["SceneBegin", "SceneChunk", "TileAssignment", "Cancel", "Heartbeat", "Reject"]
            }
            (Kind::Viewer(_), true) => {
                &["Slaves", "Status", "FrameTile", "FrameDone", "Error", "Notice", "Heartbeat", "Reject"]
            }
        };
        assert!(allowed.contains(&kind), "peer {id} ({:?}) sent {kind}", p.role);
        let mut reply = Vec::new();
        match msg {
            Message::Challenge { nonce } => {
                assert!(p.nonces.is_none(), "challenged twice");
                let client_nonce = [id as u8; 32];
                p.nonces = Some((nonce, client_nonce));
                if !matches!(p.kind, Kind::Mute) {
                    let (threads, cached) = match &p.kind {
                        Kind::Slave(s) => (s.threads, s.cached.then_some(scene_hash).into_iter().collect()),
                        _ => (0, Vec::new()),
                    };
                    reply.push(Message::Hello(Hello {
                        role: p.role,
                        name: format!("fuzz{id}"),
                        threads,
                        client_nonce,
                        proof: auth::client_proof(p.token, p.role, &nonce, &client_nonce),
                        cached_scenes: cached,
                        codecs: p.offered.iter().map(|c| c.name().to_string()).collect(),
                        work: p.work,
                        direct: None,
                    }));
                }
            }
            Message::Welcome(w) => {
                assert!(p.token == TOKEN, "peer {id} welcomed without the token");
                assert!(!p.welcomed, "welcomed twice");
                let (nonce, client_nonce) = p.nonces.expect("welcomed before the challenge");
                let proof = auth::server_proof(TOKEN, p.role, &nonce, &client_nonce);
                assert!(w.proof == proof, "the master's proof is wrong");
                assert_eq!(w.scene.map(|s| s.hash), Some(scene_hash));
                assert!(
                    w.codec == Codec::Raw || p.offered.contains(&w.codec),
                    "codec {} not offered",
                    w.codec
                );
                p.welcomed = true;
                if let Kind::Slave(s) = &mut p.kind {
                    s.codec = Some(w.codec);
                    if s.cached {
                        s.ready = true;
                        reply.push(Message::Ready { hash: Some(scene_hash) });
                    }
                }
            }
            Message::SceneBegin(header) => {
                let Kind::Slave(s) = &mut p.kind else { unreachable!("checked above") };
                assert!(!s.cached && s.syncs == 0, "the scene was sent to a slave holding it");
                assert!(s.incoming.is_none(), "a second scene began before the first ended");
                let rx =
                    isin_cluster::scene_stream::Receiver::new(header).expect("the master's header is sound");
                s.incoming = Some(Box::new(rx));
            }
            Message::SceneChunk { hash, index, bytes } => {
                let Kind::Slave(s) = &mut p.kind else { unreachable!("checked above") };
                let rx = s.incoming.as_mut().expect("a chunk after its SceneBegin");
                let progress = rx.push(&hash, index, &bytes).expect("the master's chunks are sound");
                reply.push(Message::SceneAck { hash, chunks_received: progress.chunks });
                if progress.complete {
                    let bundle = s.incoming.take().map(|rx| rx.finish());
                    let bundle = bundle.expect("receiving").expect("the scene unpacks and is its hash's");
                    assert_eq!(protocol::scene_hash(&bundle), hash, "the scene is its hash's");
                    s.syncs += 1;
                    s.ready = true;
                    reply.push(Message::Ready { hash: Some(hash) });
                }
            }
            Message::TileAssignment(a) => {
                let Kind::Slave(s) = &mut p.kind else { unreachable!("checked above") };
                assert!(s.ready, "tiles before the slave was ready");
                let (w, h) = (a.settings.width, a.settings.height);
                let known = self.frames.entry(a.frame).or_default();
                for job in &a.tiles {
                    let t = job.tile;
                    assert!(
                        t.w > 0 && t.h > 0 && t.x + t.w <= w && t.y + t.h <= h,
                        "tile {t:?} of a {w}x{h} frame"
                    );
                    assert!(
                        known.insert(job.id, t).is_none_or(|old| old == t),
                        "tile {} changed shape",
                        job.id
                    );
                    s.handed.entry(a.frame).or_default().insert(job.id);
                    s.queue.push_back(Job { frame: a.frame, id: job.id, tile: t, seed: a.settings.seed });
                }
            }
            Message::Cancel { frame, tiles } => {
                let Kind::Slave(s) = &mut p.kind else { unreachable!("checked above") };
                let (dropped, kept) =
                    s.queue.drain(..).partition(|j| j.frame == frame && tiles.contains(&j.id));
                s.queue = kept;
                s.cancelled.extend(dropped);
            }
            Message::FrameTile(t) => {
                let Kind::Viewer(v) = &mut p.kind else { unreachable!("checked above") };
                let r = v.requests.get_mut(&t.request).expect("a tile for a request never made");
                assert!(r.live, "a tile for request {} (done: {})", t.request, r.done);
                assert!(t.codec == Codec::Raw || p.offered.contains(&t.codec), "tile in {}", t.codec);
                let (w, h) = (r.settings.width, r.settings.height);
                let rect = t.tile;
                assert!(rect.x + rect.w <= w && rect.y + rect.h <= h, "tile {rect:?} off a {w}x{h} frame");
                let rgb = t.decoded_pixels().expect("forwarded tiles decode");
                assert!(rgb == render(r.settings.seed, rect), "tile {rect:?} is not the render");
                for y in rect.y..rect.y + rect.h {
                    for x in rect.x..rect.x + rect.w {
                        let n = &mut r.writes[(y * w + x) as usize];
                        assert_eq!(*n, 0, "pixel ({x}, {y}) of request {} delivered twice", t.request);
                        *n = 1;
                    }
                }
            }
            Message::FrameDone { request, .. } => {
                let Kind::Viewer(v) = &mut p.kind else { unreachable!("checked above") };
                let r = v.requests.get_mut(&request).expect("done for a request never made");
                assert!(r.live, "request {request} done twice or after it was superseded");
                if let Some(i) = r.writes.iter().position(|&n| n != 1) {
                    panic!("request {request} done with pixel {i} delivered {} times", r.writes[i]);
                }
                r.live = false;
                r.done = true;
            }
            Message::Error { .. } => {
                let Kind::Viewer(v) = &mut p.kind else { unreachable!("checked above") };
                v.errors += 1;
            }
            _ => {}
        }
        for m in reply {
            self.send(id, &m);
        }
    }

    fn request(&mut self, id: PeerId, settings: RenderSettings, queue: bool) {
        let Some(Kind::Viewer(v)) = self.peers.get_mut(&id).map(|p| &mut p.kind) else { return };
        v.next_request += 1;
        let request = v.next_request;
        let writes = vec![0; (settings.width * settings.height) as usize];
        v.requests.insert(request, Request { settings, writes, live: false, done: false });
        let errors = v.errors;
        let camera = Camera::default();
        let msg = if queue {
            Message::QueueFrame { request, scene: None, camera, settings, job_frame: None }
        } else {
            Message::FrameRequest { request, scene: None, camera, settings }
        };
        self.send(id, &msg);
        self.pump();
        if !self.wire.is_open(id) {
            return;
        }
        let Some(Kind::Viewer(v)) = self.peers.get_mut(&id).map(|p| &mut p.kind) else { return };
        // The core answers a request it refuses at once, with an error.
        if v.errors == errors {
            for (&n, r) in v.requests.iter_mut() {
                if n == request {
                    r.live = !r.done;
                } else if !queue {
                    r.live = false;
                }
            }
        }
    }

    fn result(&mut self, id: PeerId, job: Job, how: How) {
        let s = self.slave_mut(id);
        let codec = s.codec.unwrap_or(Codec::Raw);
        let rgb = render(job.seed, job.tile);
        let (codec, mut tile, pixels) = match how {
            How::Right => (codec, job.tile, codec::encode(codec, job.tile.w, &rgb)),
            How::OtherCodec => {
                let other = Codec::ALL[(Codec::ALL.iter().position(|&c| c == codec).unwrap_or(0) + 1) % 3];
                (other, job.tile, codec::encode(other, job.tile.w, &rgb))
            }
            How::WrongRect => (codec, job.tile, codec::encode(codec, job.tile.w, &rgb)),
            How::Truncated => {
                let mut p = codec::encode(codec, job.tile.w, &rgb);
                p.truncate(p.len() / 2);
                (codec, job.tile, p)
            }
            How::Corrupt => (codec, job.tile, vec![0xff; 7]),
        };
        if how == How::WrongRect {
            tile.w += 1;
        }
        let r = TileResult {
            frame: job.frame,
            id: job.id,
            tile,
            render_micros: 1,
            codec,
            pixels: ByteBuf::from(pixels),
        };
        let frame = protocol::encode(&Message::TileResult(r)).expect("encodes");
        s.last_result = Some(frame.clone());
        if !matches!(how, How::Right | How::OtherCodec) {
            self.peers.get_mut(&id).expect("known").misbehaved = true;
        }
        self.outbox.push_back((id, frame));
        self.pump();
    }

    fn step(&mut self, step: Step) {
        match step {
            Step::Slave { threads, codecs: mask, cached, wrong_token } => {
                let sim = SlaveSim { threads: 1 + u32::from(threads % 4), cached, ..SlaveSim::default() };
                let token = if wrong_token { "wrong" } else { TOKEN };
                self.connect(Kind::Slave(sim), codecs(mask), Work::Interactive, token);
            }
            Step::Viewer { batch, codecs: mask, wrong_token } => {
                let work = if batch { Work::Batch } else { Work::Interactive };
                let token = if wrong_token { "wrong" } else { TOKEN };
                self.connect(Kind::Viewer(ViewerSim::default()), codecs(mask), work, token);
            }
            Step::Mute => {
                self.connect(Kind::Mute, Vec::new(), Work::Interactive, TOKEN);
            }
            Step::Request { viewer, width, height, spp, seed, queue } => {
                let Some(id) = self.pick_viewer(viewer) else { return };
                let settings = RenderSettings {
                    width: 1 + u32::from(width % 96),
                    height: 1 + u32::from(height % 96),
                    spp: 1 + u32::from(spp % 2),
                    seed: u64::from(seed),
                    ..RenderSettings::default()
                };
                self.request(id, settings, queue);
            }
            Step::Render { slave, tiles, how } => {
                let Some(id) = self.pick_slave(slave) else { return };
                for _ in 0..1 + tiles % 8 {
                    if !self.wire.is_open(id) {
                        break;
                    }
                    let Some(job) = self.slave_mut(id).queue.pop_front() else { break };
                    self.result(id, job, how);
                }
            }
            Step::Late { slave } => {
                let Some(id) = self.pick_slave(slave) else { return };
                if let Some(job) = self.slave_mut(id).cancelled.pop() {
                    self.result(id, job, How::Right);
                }
            }
            Step::Replay { slave } => {
                let Some(id) = self.pick_slave(slave) else { return };
                if let Some(frame) = self.slave_mut(id).last_result.clone() {
                    self.outbox.push_back((id, frame));
                    self.pump();
                }
            }
            Step::Forge { slave, frame, tile } => self.forge(slave, frame, tile),
            Step::Heartbeat { peer } => {
                let Some(id) = self.pick(peer) else { return };
                let p = self.peers.get_mut(&id).expect("known");
                // Before its Hello, a heartbeat is a protocol error.
                p.misbehaved |= !p.welcomed;
                self.send(id, &Message::Heartbeat);
                self.pump();
            }
            Step::Silence { peer } => {
                let Some(id) = self.pick(peer) else { return };
                self.peers.get_mut(&id).expect("known").silent = true;
            }
            Step::Garbage { peer, frame } => self.garbage(peer, frame),
            Step::Receipt { viewer, frame, tile, slave } => self.receipt(viewer, frame, tile, slave),
            Step::Disconnect { peer } => {
                let Some(id) = self.pick(peer) else { return };
                self.wire.gone(id);
                self.core.handle_closed(self.now, id);
                self.pump();
            }
            Step::Advance { tenths } => {
                for _ in 0..tenths {
                    self.tick(TICK, false);
                }
            }
        }
    }

    fn forge(&mut self, slave: u8, frame: u8, tile: u16) {
        let Some(id) = self.pick_slave(slave) else { return };
        let frames: Vec<FrameId> = self.frames.keys().copied().collect();
        let Some(&frame) = frames.get(usize::from(frame) % frames.len().max(1)) else { return };
        let tile = TileId::from(tile);
        let handed = self.slave_mut(id).handed.get(&frame).is_some_and(|t| t.contains(&tile));
        if handed {
            return;
        }
        let rect = self.frames[&frame].get(&tile).copied().unwrap_or(Tile { x: 0, y: 0, w: 8, h: 8 });
        let pixels = ByteBuf::from(vec![255u8; rect.pixel_count() * 3]);
        let r = TileResult { frame, id: tile, tile: rect, render_micros: 1, codec: Codec::Raw, pixels };
        self.slave_mut(id).forged += 1;
        self.forged += 1;
        self.send(id, &Message::TileResult(r));
        self.pump();
    }

    fn receipt(&mut self, viewer: u8, frame: u8, tile: u16, slave: u8) {
        let (Some(v), Some(s)) = (self.pick_viewer(viewer), self.pick_slave(slave)) else { return };
        let frames: Vec<FrameId> = self.frames.keys().copied().collect();
        let Some(&frame) = frames.get(usize::from(frame) % frames.len().max(1)) else { return };
        let id = TileId::from(tile);
        let rect = self.frames[&frame].get(&id).copied().unwrap_or(Tile { x: 0, y: 0, w: 8, h: 8 });
        self.peers.get_mut(&v).expect("known").misbehaved = true;
        let r = TileReceived { frame, id, slave: s, tile: rect, render_micros: 1 };
        self.send(v, &Message::TileReceived(r));
        self.pump();
    }

    fn garbage(&mut self, peer: u8, frame: Vec<u8>) {
        let Some(id) = self.pick(peer) else { return };
        // Messages that would make a request, a join or a result the
        // simulation does not know of are the structured steps' business.
        if let Ok(m) = protocol::decode(&frame, usize::MAX)
            && matches!(
                m,
                Message::Hello(_)
                    | Message::Ready { .. }
                    | Message::FrameRequest { .. }
                    | Message::QueueFrame { .. }
                    | Message::TileResult(_)
            )
        {
            return;
        }
        self.peers.get_mut(&id).expect("known").misbehaved = true;
        self.outbox.push_back((id, frame));
        self.pump();
    }

    /// `d` passes: peers heartbeat when due (and, with `render`, slaves
    /// return every tile they hold, right), then the core keeps time.
    fn tick(&mut self, d: Duration, render: bool) {
        self.now += d;
        let now = self.now;
        let ids: Vec<PeerId> = self.peers.keys().copied().filter(|&id| self.wire.is_open(id)).collect();
        for id in ids {
            let p = self.peers.get_mut(&id).expect("listed");
            if p.silent || !p.welcomed {
                continue;
            }
            let renders = render && matches!(p.kind, Kind::Slave(_));
            if now >= p.next_heartbeat {
                p.next_heartbeat = now + HEARTBEAT;
                self.send(id, &Message::Heartbeat);
            }
            while renders
                && self.wire.is_open(id)
                && let Some(job) = self.slave_mut(id).queue.pop_front()
            {
                self.result(id, job, How::Right);
            }
        }
        self.pump();
        self.core.handle_timeout(now);
        self.pump();
    }

    /// The invariants that hold after every step.
    fn check(&self) {
        let st = self.core.status();
        assert_eq!(st.peers, self.wire.open(), "the core's peers are not the open connections");
        assert!(st.peers <= self.budgets.max_peers, "{} peers, at most {}", st.peers, self.budgets.max_peers);
        let open = |id: &PeerId| self.wire.is_open(*id);
        let handshaking = self.peers.iter().filter(|(id, p)| open(id) && !p.welcomed).count();
        assert!(handshaking <= self.budgets.max_handshaking, "{handshaking} peers in their handshake");
        let ready: BTreeSet<PeerId> = self
            .peers
            .iter()
            .filter(|(id, p)| open(id) && matches!(&p.kind, Kind::Slave(s) if s.ready))
            .map(|(&id, _)| id)
            .collect();
        let slaves: BTreeSet<PeerId> = st.slaves.iter().map(|s| s.id).collect();
        assert_eq!(slaves, ready, "the core's slaves are not the open ready ones");
        assert!(
            st.foreign_results <= self.forged,
            "{} foreign results of {} forged",
            st.foreign_results,
            self.forged
        );
    }

    /// Every slave turns honest and renders what it holds, one joins if none
    /// is left; every live request of every open viewer must then complete.
    fn finish(&mut self) {
        for p in self.peers.values_mut() {
            p.silent = false;
        }
        if self.core.status().slaves.is_empty() {
            let sim = SlaveSim { threads: 2, ..SlaveSim::default() };
            let id = self.connect(Kind::Slave(sim), Codec::ALL.to_vec(), Work::Interactive, TOKEN);
            if !self.wire.is_open(id) {
                // A full house: no slave can join, so nothing need finish.
                return;
            }
        }
        let pending = |net: &Net| {
            net.peers.iter().any(|(id, p)| {
                net.wire.is_open(*id)
                    && matches!(&p.kind, Kind::Viewer(v) if v.requests.values().any(|r| r.live))
            })
        };
        for _ in 0..3000 {
            if !pending(self) {
                return;
            }
            self.tick(Duration::from_millis(10), true);
            self.check();
        }
        let left: Vec<(PeerId, Vec<u64>)> = self
            .peers
            .iter()
            .filter(|(id, _)| self.wire.is_open(**id))
            .filter_map(|(&id, p)| match &p.kind {
                Kind::Viewer(v) => {
                    Some((id, v.requests.iter().filter(|(_, r)| r.live).map(|(&n, _)| n).collect()))
                }
                _ => None,
            })
            .collect();
        panic!("requests never completed with honest slaves: {left:?}; status {:?}", self.core.status());
    }
}

/// The structure-aware target: a [`Setup`] and up to [`MAX_STEPS`] steps
/// from the fuzzer's bytes, the invariants checked after each (see the
/// module docs).
pub fn run(data: &[u8]) {
    let mut u = Unstructured::new(data);
    let Ok(setup) = Setup::arbitrary(&mut u) else { return };
    let mut net = Net::new(&setup);
    let mut steps = 0;
    while !u.is_empty() && steps < MAX_STEPS {
        let Ok(step) = Step::arbitrary(&mut u) else { break };
        net.step(step);
        net.check();
        steps += 1;
    }
    net.finish();
}

#[cfg(test)]
mod tests {
    use super::*;

    fn setup() -> Setup {
        Setup {
            max_peers: 7,
            max_handshaking: 3,
            foreign_results: 1,
            tile_size: 0,
            queue_depth: 1,
            heartbeat_timeout_s: 1,
            duplicate_stragglers: true,
            max_open_frames: 3,
        }
    }

    fn viewer_requests(net: &Net, id: PeerId) -> &BTreeMap<u64, Request> {
        match &net.peers[&id].kind {
            Kind::Viewer(v) => &v.requests,
            _ => panic!("{id} is not a viewer"),
        }
    }

    /// The simulation does what the checks assume: two slaves render a frame
    /// for a viewer through the core, a forger within its budget stays, the
    /// frame completes with every pixel once.
    #[test]
    fn a_scripted_cluster_completes_its_frames() {
        let mut net = Net::new(&setup());
        for step in [
            Step::Slave { threads: 1, codecs: 0b111, cached: false, wrong_token: false },
            Step::Slave { threads: 0, codecs: 0b010, cached: true, wrong_token: false },
            Step::Viewer { batch: false, codecs: 0b001, wrong_token: false },
            Step::Request { viewer: 0, width: 40, height: 20, spp: 0, seed: 3, queue: false },
            Step::Render { slave: 0, tiles: 2, how: How::Right },
            Step::Forge { slave: 1, frame: 0, tile: 999 },
            Step::Render { slave: 1, tiles: 1, how: How::OtherCodec },
            Step::Replay { slave: 0 },
            Step::Advance { tenths: 3 },
        ] {
            net.step(step);
            net.check();
        }
        let v = 3;
        assert!(viewer_requests(&net, v)[&1].live);
        net.finish();
        assert!(viewer_requests(&net, v)[&1].done, "the frame completed");
        assert!(net.wire.is_open(2), "a forger within its budget stays");
        assert_eq!(net.core.status().foreign_results, 1);
    }

    /// The checks can fail: a wrong token does not get in, and a tile
    /// delivered twice is caught.
    #[test]
    #[should_panic(expected = "delivered twice")]
    fn a_pixel_delivered_twice_is_caught() {
        let mut net = Net::new(&setup());
        net.step(Step::Slave { threads: 1, codecs: 0, cached: false, wrong_token: true });
        assert!(!net.wire.is_open(1), "a wrong token is refused");
        net.step(Step::Viewer { batch: false, codecs: 0, wrong_token: false });
        net.step(Step::Request { viewer: 0, width: 8, height: 8, spp: 0, seed: 1, queue: false });
        let rect = Tile { x: 0, y: 0, w: 2, h: 2 };
        let tile = isin_cluster::protocol::FrameTile {
            request: 1,
            slave: 9,
            slave_name: "x".into(),
            tile: rect,
            codec: Codec::Raw,
            pixels: ByteBuf::from(render(1, rect)),
        };
        net.deliver(2, Message::FrameTile(tile.clone()));
        net.deliver(2, Message::FrameTile(tile));
    }
}

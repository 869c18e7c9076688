//! Simulated peers and the transport between them and the core.
//!
//! Peers are driven by the messages they receive and by the virtual clock:
//! slaves answer the challenge, load the scene, render their tiles in
//! `threads` lanes at a chosen speed (pixels from [`shade`], so any slave
//! renders any pixel to the same bytes) and heartbeat; viewers request
//! frames and assemble the tiles they get — through the master, or straight
//! from the slaves for a direct viewer ([`Net::direct_viewer`]: its link to
//! each slave delivers and acknowledges at once). Hostile [`Behaviour`]s
//! speak the same protocol and lie in it.

use super::super::*;
use super::MS;
use crate::protocol::{
    DirectOffer, FrameTile, JobSpec, SceneHash, Status, TileId, TileJob, TileReceived, TileResult,
};
use isin_tracer::Tile;
use serde_bytes::ByteBuf;

/// The token honest peers know.
pub const TOKEN: &str = "secret";

/// Heartbeat period of simulated peers.
const HEARTBEAT: Duration = Duration::from_millis(500);

/// A small fake scene of `bytes` asset bytes (noise: it packs to about as
/// many).
pub fn fake_scene(name: &str, bytes: usize) -> SceneBundle {
    let mut rng =
        Rng(name.bytes().fold(0x51_7cc1_b727_220a, |h, b| (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3)));
    let noise = (0..bytes).map(|_| rng.next() as u8).collect();
    let mut assets = BTreeMap::new();
    assets.insert("mesh.bin".to_string(), noise);
    SceneBundle { name: name.into(), source: format!("fake scene {name}"), assets }
}

/// A core around a small fake default scene.
pub fn config() -> ClusterConfig {
    let scene = DefaultScene {
        bundle: fake_scene("fake.toml", 5000),
        camera: Camera::default(),
        settings: RenderSettings::default(),
    };
    ClusterConfig::new(TOKEN.into(), Some(scene), [7; 32])
}

/// What a scene adds to a frame's seed: slaves "render" each scene differently.
fn scene_seed(scene: &SceneHash) -> u64 {
    u64::from_le_bytes([scene[0], scene[1], scene[2], scene[3], scene[4], scene[5], scene[6], scene[7]])
}

/// The "render" every slave agrees on: a hash of the frame's seed and the pixel.
pub fn shade(seed: u64, x: u32, y: u32) -> [u8; 3] {
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

pub use crate::testing::Rng;

/// How a simulated peer behaves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Behaviour {
    /// Does what the protocol says.
    Honest,
    /// Connected, never says anything again (a hung process, a cut cable).
    Silent,
    /// Renders its own tiles, and sends white results for every other tile
    /// of each frame it hears of.
    Forger,
    /// Logs in, then says nothing: no `Ready`, no heartbeat.
    StallBeforeReady,
    /// Logs in and heartbeats, but never says `Ready`.
    HeartbeatNeverReady,
    /// Logs in, then announces a frame longer than its limit.
    Oversized,
    /// Returns its first tile with another rectangle.
    WrongRect,
    /// Loads the default scene, but fails every other one.
    FailsScenes,
    /// Takes a scene's chunks but never acknowledges them (heartbeats on).
    NeverAcks,
    /// Sends every tile of a direct frame straight, the master's sample too.
    SkipsSample,
}

/// A simulated slave.
#[derive(Clone, Debug)]
pub struct SlaveSpec {
    /// The token it proves.
    pub token: String,
    /// Render lanes.
    pub threads: u32,
    /// Virtual microseconds a pixel.
    pub us_per_pixel: u64,
    /// What it does.
    pub behaviour: Behaviour,
    /// The scene it holds already.
    pub cached: Option<SceneHash>,
}

impl Default for SlaveSpec {
    fn default() -> Self {
        Self { token: TOKEN.into(), threads: 2, us_per_pixel: 5, behaviour: Behaviour::Honest, cached: None }
    }
}

/// A tile to render: its frame, itself, the render's seed, and the direct
/// viewer and request to deliver it to (unless the master wants it).
type Job = (FrameId, TileJob, u64, Option<(PeerId, u64)>);

#[derive(Debug, Default)]
struct SlaveSim {
    threads: u32,
    us_per_pixel: u64,
    /// Scenes it holds.
    held: BTreeSet<SceneHash>,
    /// Scenes it asked for.
    asked: BTreeSet<SceneHash>,
    /// Assignments waiting for their scene.
    parked: Vec<TileAssignment>,
    ready: bool,
    codec: Codec,
    queue: VecDeque<Job>,
    lanes: Vec<Option<(Job, Duration)>>,
    syncs: u32,
    /// The scene coming in.
    incoming: Option<Box<crate::scene_stream::Receiver>>,
    /// Scene chunks received.
    chunks: u32,
    assignments: u32,
    cancels: u32,
    forged: BTreeSet<FrameId>,
}

impl SlaveSim {
    /// Takes an assignment of a scene it holds.
    fn assign(
        &mut self,
        a: TileAssignment,
        behaviour: Behaviour,
        limit: Option<usize>,
        out: &mut Vec<Message>,
    ) {
        let s = self;
        s.assignments += 1;
        let seed = a.settings.seed ^ scene_seed(&a.scene);
        match behaviour {
            Behaviour::Forger if s.forged.insert(a.frame) => {
                let edge = a.tiles.first().map_or(32, |t| t.tile.w.max(t.tile.h));
                let mine: BTreeSet<TileId> = a.tiles.iter().map(|t| t.id).collect();
                let grid = Tile::grid(a.settings.width, a.settings.height, edge);
                for (i, tile) in grid.into_iter().enumerate() {
                    let id = i as TileId;
                    if !mine.contains(&id) {
                        let pixels = ByteBuf::from(vec![255u8; tile.pixel_count() * 3]);
                        let r = TileResult {
                            frame: a.frame,
                            id,
                            tile,
                            render_micros: 1,
                            codec: Codec::Raw,
                            pixels,
                        };
                        out.push(Message::TileResult(r));
                    }
                }
            }
            Behaviour::WrongRect => {
                if let Some(job) = a.tiles.first() {
                    let mut tile = job.tile;
                    tile.w += 1;
                    let pixels = ByteBuf::from(vec![0u8; tile.pixel_count() * 3]);
                    out.push(Message::TileResult(TileResult {
                        frame: a.frame,
                        id: job.id,
                        tile,
                        render_micros: 1,
                        codec: Codec::Raw,
                        pixels,
                    }));
                }
            }
            Behaviour::Oversized => {
                let huge = "x".repeat(limit.unwrap_or(HANDSHAKE_MAX_FRAME) + 1);
                out.push(Message::Error { message: huge });
            }
            _ => {}
        }
        let route = a.direct.as_deref().map(|r| (r.viewer, r.request, r.via_master.clone()));
        let to = |id: TileId| match &route {
            Some((viewer, request, via_master))
                if behaviour == Behaviour::SkipsSample || !via_master.contains(&id) =>
            {
                Some((*viewer, *request))
            }
            _ => None,
        };
        s.queue.extend(a.tiles.into_iter().map(|t| (a.frame, t, seed, to(t.id))));
    }
}

#[derive(Debug)]
struct ViewFrame {
    settings: RenderSettings,
    scene: Option<SceneHash>,
    requested: Duration,
    took: Option<Duration>,
    image: Vec<u8>,
    writes: Vec<u8>,
    done: bool,
    /// Tiles shown (a direct viewer's).
    shown: std::collections::HashSet<Tile>,
}

#[derive(Debug, Default)]
struct ViewerSim {
    next_request: u64,
    frames: BTreeMap<u64, ViewFrame>,
    errors: Vec<String>,
    notices: Vec<String>,
    /// A scene announced, to send when the master wants it.
    upload: Option<Arc<crate::scene_stream::Packed>>,
    stored: BTreeSet<SceneHash>,
    statuses: Vec<Status>,
    accepted: Option<Vec<u32>>,
    /// Offers to take tiles straight from the slaves.
    direct: bool,
    direct_tiles: u32,
    /// Decodes raw tiles only (offers no codec), as an old viewer.
    raw_only: bool,
    /// The codecs of the tiles it was sent, and how many of each.
    codecs_seen: BTreeMap<&'static str, u32>,
}

impl ViewerSim {
    /// Writes a tile into its frame, counting each pixel's writes. A direct
    /// viewer shows a tile once: a second copy (straight, or straight and
    /// through the master, from two slaves) is dropped, as the viewer drops it.
    fn paste(&mut self, t: &FrameTile) {
        let f = self
            .frames
            .get_mut(&t.request)
            .unwrap_or_else(|| panic!("tile for unknown request {}", t.request));
        assert!(!f.done, "tile after FrameDone");
        if self.direct && !f.shown.insert(t.tile) {
            return;
        }
        *self.codecs_seen.entry(t.codec.name()).or_default() += 1;
        let rgb = t.decoded_pixels().expect("tiles decode");
        let w = f.settings.width;
        for (row, y) in (t.tile.y..t.tile.y + t.tile.h).enumerate() {
            for (col, x) in (t.tile.x..t.tile.x + t.tile.w).enumerate() {
                let i = (y * w + x) as usize;
                let s = (row * t.tile.w as usize + col) * 3;
                f.image[i * 3..i * 3 + 3].copy_from_slice(&rgb[s..s + 3]);
                f.writes[i] += 1;
            }
        }
    }
}

#[derive(Debug)]
enum Kind {
    Slave(SlaveSim),
    Viewer(ViewerSim),
    /// Says only what the test makes it say.
    Raw,
}

#[derive(Debug)]
struct SimPeer {
    kind: Kind,
    work: Work,
    behaviour: Behaviour,
    token: String,
    logged_in: bool,
    received: Vec<Message>,
    outbox: Vec<Vec<u8>>,
    /// Closed by the core (with its reason).
    closed: Option<String>,
    /// Disconnected by the test.
    gone: bool,
    rejection: Option<String>,
    limit: Option<usize>,
    next_heartbeat: Duration,
}

/// The core, its peers and the virtual clock.
pub struct Net {
    /// The master's state machine under test.
    pub core: Cluster,
    /// Virtual time.
    pub now: Duration,
    peers: BTreeMap<PeerId, SimPeer>,
    next_peer: PeerId,
    /// Lane-milliseconds of live slaves, and of those the busy ones.
    lane_ms: u64,
    busy_lane_ms: u64,
    /// What the core asked to be stored.
    pub disk: Disk,
    config: ClusterConfig,
}

/// The master's state directory, as the core filled it.
#[derive(Debug, Default)]
pub struct Disk {
    /// Stored scenes by hash.
    pub scenes: BTreeMap<SceneHash, Vec<u8>>,
    /// Jobs by key.
    pub jobs: BTreeMap<SceneHash, JobRecord>,
}

impl Net {
    /// A core for `cfg` with no peers, at time zero.
    pub fn new(cfg: ClusterConfig) -> Self {
        Self {
            core: Cluster::new(cfg.clone()).expect("scene encodes"),
            disk: Disk::default(),
            config: cfg,
            now: Duration::ZERO,
            peers: BTreeMap::new(),
            next_peer: 1,
            lane_ms: 0,
            busy_lane_ms: 0,
        }
    }

    fn add(&mut self, kind: Kind, behaviour: Behaviour, token: String, work: Work) -> PeerId {
        let id = self.next_peer;
        self.next_peer += 1;
        let peer = SimPeer {
            kind,
            work,
            behaviour,
            token,
            logged_in: false,
            received: Vec::new(),
            outbox: Vec::new(),
            closed: None,
            gone: false,
            rejection: None,
            limit: None,
            next_heartbeat: self.now + HEARTBEAT,
        };
        self.peers.insert(id, peer);
        self.core.handle_connected(self.now, id, &format!("sim:{id}"));
        self.pump();
        id
    }

    /// Connects a slave.
    pub fn slave(&mut self, spec: SlaveSpec) -> PeerId {
        let sim = SlaveSim {
            threads: spec.threads,
            us_per_pixel: spec.us_per_pixel,
            held: spec.cached.into_iter().collect(),
            lanes: vec![None; spec.threads as usize],
            ..SlaveSim::default()
        };
        self.add(Kind::Slave(sim), spec.behaviour, spec.token, Work::Interactive)
    }

    /// Connects an honest interactive viewer.
    pub fn viewer(&mut self) -> PeerId {
        self.viewer_of(Work::Interactive)
    }

    /// Connects an honest viewer whose frames are `work`.
    pub fn viewer_of(&mut self, work: Work) -> PeerId {
        self.add(Kind::Viewer(ViewerSim::default()), Behaviour::Honest, TOKEN.into(), work)
    }

    /// Connects an honest interactive viewer that decodes raw tiles only.
    pub fn raw_only_viewer(&mut self) -> PeerId {
        let sim = ViewerSim { raw_only: true, ..ViewerSim::default() };
        self.add(Kind::Viewer(sim), Behaviour::Honest, TOKEN.into(), Work::Interactive)
    }

    /// The codecs of the tiles viewer `v` was sent, with their counts.
    pub fn codecs_seen(&self, v: PeerId) -> BTreeMap<&'static str, u32> {
        self.viewer_sim(v).codecs_seen.clone()
    }

    /// Connects an honest interactive viewer that takes its tiles straight
    /// from the slaves.
    pub fn direct_viewer(&mut self) -> PeerId {
        let sim = ViewerSim { direct: true, ..ViewerSim::default() };
        self.add(Kind::Viewer(sim), Behaviour::Honest, TOKEN.into(), Work::Interactive)
    }

    /// Connects a peer that says nothing unless told to.
    pub fn raw_peer(&mut self) -> PeerId {
        self.add(Kind::Raw, Behaviour::Honest, TOKEN.into(), Work::Interactive)
    }

    /// Has `peer` send `frame` as it is.
    pub fn send_raw(&mut self, peer: PeerId, frame: Vec<u8>) {
        self.peers.get_mut(&peer).expect("known peer").outbox.push(frame);
        self.pump();
    }

    /// Has viewer `v` request (or queue) a frame; returns its request number.
    pub fn request(&mut self, v: PeerId, settings: RenderSettings, queue: bool) -> u64 {
        self.request_of(v, settings, queue, None, None)
    }

    /// [`Net::request`] of a frame of `scene` (`None`: the default), as
    /// frame `job_frame` of the viewer's job if given.
    pub fn request_of(
        &mut self,
        v: PeerId,
        settings: RenderSettings,
        queue: bool,
        scene: Option<SceneHash>,
        job_frame: Option<u32>,
    ) -> u64 {
        let expected = scene.or(self.core.scene().map(|s| s.hash));
        let p = self.peers.get_mut(&v).expect("known peer");
        let Kind::Viewer(sim) = &mut p.kind else { panic!("{v} is not a viewer") };
        sim.next_request += 1;
        let request = sim.next_request;
        let n = (settings.width * settings.height) as usize;
        let requested = self.now;
        let frame = ViewFrame {
            settings,
            scene: expected,
            requested,
            took: None,
            image: vec![0; n * 3],
            writes: vec![0; n],
            done: false,
            shown: Default::default(),
        };
        sim.frames.insert(request, frame);
        let camera = Camera::default();
        let msg = if queue {
            Message::QueueFrame { request, scene, camera, settings, job_frame }
        } else {
            Message::FrameRequest { request, scene, camera, settings }
        };
        p.outbox.push(protocol::encode(&msg).expect("encodes"));
        self.pump();
        request
    }

    /// Has viewer `v` announce `bundle` (sent when the master wants it);
    /// returns its hash.
    pub fn upload(&mut self, v: PeerId, bundle: SceneBundle) -> SceneHash {
        let packed = Arc::new(crate::scene_stream::pack(&bundle).expect("packs"));
        let (hash, header) = (packed.header.hash, packed.header.clone());
        let p = self.peers.get_mut(&v).expect("known peer");
        let Kind::Viewer(sim) = &mut p.kind else { panic!("{v} is not a viewer") };
        sim.upload = Some(packed);
        p.outbox.push(protocol::encode(&Message::SceneUpload(header)).expect("encodes"));
        self.pump();
        hash
    }

    /// Whether viewer `v` was told the master holds `hash`.
    pub fn stored(&self, v: PeerId, hash: SceneHash) -> bool {
        self.viewer_sim(v).stored.contains(&hash)
    }

    /// Has viewer `v` submit a job; its answer is [`Net::accepted`].
    pub fn submit_job(&mut self, v: PeerId, spec: JobSpec) {
        let p = self.peers.get_mut(&v).expect("known peer");
        p.outbox.push(protocol::encode(&Message::SubmitJob(spec)).expect("encodes"));
        self.pump();
    }

    /// The frames viewer `v`'s job had done, once the master accepted it.
    pub fn accepted(&self, v: PeerId) -> Option<Vec<u32>> {
        self.viewer_sim(v).accepted.clone()
    }

    /// The statuses viewer `v` was pushed or answered.
    pub fn statuses(&self, v: PeerId) -> &[Status] {
        &self.viewer_sim(v).statuses
    }

    /// Has `peer` send `msg`.
    pub fn say(&mut self, peer: PeerId, msg: &Message) {
        self.send_raw(peer, protocol::encode(msg).expect("encodes"));
    }

    /// The master dies (every connection with it) and a new one starts from
    /// the same configuration and what was stored.
    pub fn restart_master(&mut self) {
        for p in self.peers.values_mut() {
            p.gone = true;
        }
        self.core = Cluster::new(self.config.clone()).expect("scene encodes");
        for sync in self.disk.scenes.values() {
            self.core.restore_scene(sync).expect("stored scenes reload");
        }
        for record in self.disk.jobs.values() {
            self.core.restore_job(self.now, record.clone());
        }
    }

    /// Closes `peer`'s connection from its side.
    pub fn disconnect(&mut self, peer: PeerId) {
        self.peers.get_mut(&peer).expect("known peer").gone = true;
        self.core.handle_closed(self.now, peer);
        self.pump();
    }

    /// Changes how `peer` behaves from now on.
    pub fn set_behaviour(&mut self, peer: PeerId, behaviour: Behaviour) {
        self.peers.get_mut(&peer).expect("known peer").behaviour = behaviour;
    }

    /// Moves frames both ways until nothing is left to move.
    pub fn pump(&mut self) {
        loop {
            let mut progressed = false;
            let ids: Vec<PeerId> = self.peers.keys().copied().collect();
            for id in ids {
                let p = self.peers.get_mut(&id).expect("listed");
                let outbox = std::mem::take(&mut p.outbox);
                if p.gone || p.closed.is_some() {
                    continue;
                }
                for frame in outbox {
                    progressed = true;
                    let limit = self.peers[&id].limit.unwrap_or(HANDSHAKE_MAX_FRAME);
                    if frame.len() > limit {
                        // What the transport does: refused before it is read.
                        let error = format!("frame of {} bytes too large (max {limit})", frame.len());
                        self.core.handle_transport_error(self.now, id, &error);
                    } else {
                        self.core.handle_frame(self.now, id, &frame);
                    }
                    if self.peers[&id].closed.is_some() {
                        break;
                    }
                    self.drain_core();
                }
            }
            progressed |= self.drain_core();
            if !progressed {
                return;
            }
        }
    }

    /// Carries out the core's transmissions; true if there were any.
    fn drain_core(&mut self) -> bool {
        let mut any = false;
        while let Some(t) = self.core.poll_transmit() {
            any = true;
            match t {
                Transmit::Send { peer, message, .. } => {
                    // Through the codec, as on a real wire.
                    let frame = protocol::encode(&message).expect("the core's messages encode");
                    let decoded = protocol::decode(&frame, usize::MAX).expect("and decode");
                    self.deliver(peer, decoded);
                }
                Transmit::SendEncoded { peer, frame } => {
                    let decoded = protocol::decode(&frame, usize::MAX).expect("pre-encoded frames decode");
                    self.deliver(peer, decoded);
                }
                Transmit::SendFrame { peer, frame, .. } => {
                    let decoded = protocol::decode(&frame, usize::MAX).expect("frames the core wrote decode");
                    self.deliver(peer, decoded);
                }
                Transmit::Limit { peer, max_frame } => {
                    if let Some(p) = self.peers.get_mut(&peer) {
                        p.limit = Some(max_frame);
                    }
                }
                Transmit::Close { peer, reason } => {
                    if let Some(p) = self.peers.get_mut(&peer) {
                        assert!(p.closed.is_none(), "peer {peer} closed twice");
                        p.closed = Some(reason);
                    }
                }
                Transmit::Store(Stored::Scene { hash, bytes }) => {
                    self.disk.scenes.insert(hash, bytes.as_ref().clone());
                }
                Transmit::Store(Stored::ForgetScene { hash }) => {
                    self.disk.scenes.remove(&hash);
                }
                Transmit::Store(Stored::Job(record)) => {
                    self.disk.jobs.insert(record.spec.key, record);
                }
            }
        }
        any
    }

    fn deliver(&mut self, id: PeerId, msg: Message) {
        let now = self.now;
        let Some(p) = self.peers.get_mut(&id) else { panic!("message to unknown peer {id}") };
        assert!(p.closed.is_none(), "{} sent to peer {id} after closing it", msg.kind());
        p.received.push(msg.clone());
        if p.gone {
            return;
        }
        let behaviour = p.behaviour;
        let mut out: Vec<Message> = Vec::new();
        match (&mut p.kind, msg) {
            (_, Message::Reject { reason }) => p.rejection = Some(reason),
            (Kind::Raw, _) => {}
            (Kind::Slave(_) | Kind::Viewer(_), Message::Challenge { nonce }) => {
                let (role, threads, cached, codecs) = match &p.kind {
                    Kind::Slave(s) => {
                        (Role::Slave, s.threads, s.held.iter().copied().collect(), codec::offer())
                    }
                    Kind::Viewer(v) if v.raw_only => (Role::Viewer, 0, Vec::new(), Vec::new()),
                    _ => (Role::Viewer, 0, Vec::new(), codec::offer()),
                };
                let direct = match &p.kind {
                    Kind::Viewer(v) if v.direct => Some(Box::new(DirectOffer {
                        addr: format!("sim:{id}"),
                        fingerprint: None,
                        key: [id as u8; 32],
                    })),
                    _ => None,
                };
                let client_nonce = [id as u8; 32];
                let proof = auth::client_proof(&p.token, role, &nonce, &client_nonce);
                let name = format!("sim{id}");
                out.push(Message::Hello(Hello {
                    role,
                    name,
                    threads,
                    client_nonce,
                    proof,
                    cached_scenes: cached,
                    codecs,
                    work: p.work,
                    direct,
                }));
            }
            (Kind::Slave(s), Message::Welcome(w)) => {
                p.logged_in = true;
                s.codec = w.codec;
                let default = w.scene.map(|i| i.hash);
                if default.is_none_or(|h| s.held.contains(&h)) {
                    s.ready = true;
                    out.extend(ready(behaviour, default));
                }
            }
            (Kind::Viewer(_), Message::Welcome(_)) => p.logged_in = true,
            (Kind::Slave(s), Message::SceneBegin(header)) => {
                assert!(s.incoming.is_none(), "one scene at a time");
                s.incoming =
                    Some(Box::new(crate::scene_stream::Receiver::new(header).expect("sound header")));
            }
            (Kind::Slave(s), Message::SceneChunk { hash, index, bytes }) => {
                let rx = s.incoming.as_mut().expect("a chunk after its SceneBegin");
                let progress = rx.push(&hash, index, &bytes).expect("the master's chunks are sound");
                s.chunks += 1;
                if behaviour != Behaviour::NeverAcks {
                    out.push(Message::SceneAck { hash, chunks_received: progress.chunks });
                }
                if !progress.complete {
                    // More to come.
                } else if let Err(e) = s.incoming.take().map(|rx| rx.finish()).expect("receiving") {
                    panic!("the scene does not unpack: {e}");
                } else if !s.ready {
                    s.syncs += 1;
                    s.ready = true;
                    s.held.insert(hash);
                    out.extend(ready(behaviour, Some(hash)));
                } else if behaviour == Behaviour::FailsScenes {
                    s.syncs += 1;
                    out.push(Message::SceneFailed { hash, reason: "no memory".into() });
                    s.parked.retain(|a| a.scene != hash);
                } else {
                    s.syncs += 1;
                    s.held.insert(hash);
                    let (now, rest): (Vec<_>, Vec<_>) =
                        std::mem::take(&mut s.parked).into_iter().partition(|a| a.scene == hash);
                    s.parked = rest;
                    for a in now {
                        s.assign(a, behaviour, p.limit, &mut out);
                    }
                }
            }
            (Kind::Slave(s), Message::TileAssignment(a)) => {
                if s.held.contains(&a.scene) {
                    s.assign(a, behaviour, p.limit, &mut out);
                } else {
                    // Not held: asked for once, rendered when it comes.
                    if s.asked.insert(a.scene) {
                        out.push(Message::NeedScene { hash: a.scene });
                    }
                    s.parked.push(a);
                }
            }
            (Kind::Slave(s), Message::Cancel { frame, tiles }) => {
                s.cancels += 1;
                s.queue.retain(|(f, job, ..)| !(*f == frame && tiles.contains(&job.id)));
            }
            (Kind::Viewer(v), Message::FrameTile(t)) => v.paste(&t),
            (Kind::Viewer(v), Message::FrameDone { request, .. }) => {
                let f = v.frames.get_mut(&request).expect("done for a known request");
                f.done = true;
                f.took = Some(now - f.requested);
            }
            (Kind::Viewer(v), Message::Error { message }) => v.errors.push(message),
            (Kind::Viewer(v), Message::SceneWanted { hash }) => {
                // (A test that announced a scene itself sends it itself.)
                if let Some(packed) = v.upload.take() {
                    assert_eq!(packed.header.hash, hash);
                    for i in 0..packed.header.chunks {
                        let frame = packed.chunk_frame(i).expect("a chunk");
                        out.push(protocol::decode(&frame, usize::MAX).expect("decodes"));
                    }
                }
            }
            (Kind::Viewer(v), Message::SceneStored { hash }) => {
                v.stored.insert(hash);
            }
            (Kind::Viewer(v), Message::Status(st)) => v.statuses.push(st),
            (Kind::Viewer(v), Message::JobAccepted { done, .. }) => v.accepted = Some(done),
            (Kind::Viewer(v), Message::Notice { message }) => v.notices.push(message),
            _ => {}
        }
        let p = self.peers.get_mut(&id).expect("still here");
        p.outbox.extend(out.iter().map(|m| protocol::encode(m).expect("encodes")));
    }

    /// One millisecond: peers heartbeat and render, the core keeps time.
    pub fn step(&mut self) {
        self.now += MS;
        let now = self.now;
        // Tiles slaves deliver straight: to which viewer, of which frame.
        let mut straight: Vec<(PeerId, FrameId, TileId, FrameTile)> = Vec::new();
        for (&slave, p) in self.peers.iter_mut().filter(|(_, p)| !p.gone && p.closed.is_none()) {
            let speaks = !matches!(p.behaviour, Behaviour::Silent | Behaviour::StallBeforeReady);
            if p.logged_in && speaks && now >= p.next_heartbeat {
                p.next_heartbeat = now + HEARTBEAT;
                p.outbox.push(protocol::encode(&Message::Heartbeat).expect("encodes"));
            }
            let Kind::Slave(s) = &mut p.kind else { continue };
            if !speaks {
                continue;
            }
            self.lane_ms += s.lanes.len() as u64;
            self.busy_lane_ms += s.lanes.iter().filter(|l| l.is_some()).count() as u64;
            for lane in 0..s.lanes.len() {
                if let Some(((frame, job, seed, to), at)) = s.lanes[lane]
                    && at <= now
                {
                    let pixels = codec::encode(s.codec, job.tile.w, &render(seed, job.tile));
                    if let Some((viewer, request)) = to {
                        let tile = FrameTile {
                            request,
                            slave,
                            slave_name: String::new(),
                            tile: job.tile,
                            codec: s.codec,
                            pixels: ByteBuf::from(pixels),
                        };
                        straight.push((viewer, frame, job.id, tile));
                        s.lanes[lane] = None;
                    }
                }
                if let Some(((frame, job, seed, None), at)) = s.lanes[lane]
                    && at <= now
                {
                    let pixels = codec::encode(s.codec, job.tile.w, &render(seed, job.tile));
                    let r = TileResult {
                        frame,
                        id: job.id,
                        tile: job.tile,
                        render_micros: job.tile.pixel_count() as u64 * s.us_per_pixel,
                        codec: s.codec,
                        pixels: ByteBuf::from(pixels),
                    };
                    p.outbox.push(protocol::encode(&Message::TileResult(r)).expect("encodes"));
                    s.lanes[lane] = None;
                }
                if s.lanes[lane].is_none()
                    && let Some(job) = s.queue.pop_front()
                {
                    let took = Duration::from_micros(job.1.tile.pixel_count() as u64 * s.us_per_pixel);
                    s.lanes[lane] = Some((job, now + took.max(MS)));
                }
            }
        }
        // The link delivers at once, and the viewer tells the master once
        // the tile is in: before its frame's FrameDone.
        for (viewer, frame, id, tile) in straight {
            let Some(p) = self.peers.get_mut(&viewer).filter(|p| !p.gone && p.closed.is_none()) else {
                continue;
            };
            let Kind::Viewer(v) = &mut p.kind else { continue };
            v.paste(&tile);
            v.direct_tiles += 1;
            let r = TileReceived { frame, id, slave: tile.slave, tile: tile.tile, render_micros: 1 };
            p.outbox.push(protocol::encode(&Message::TileReceived(r)).expect("encodes"));
        }
        self.pump();
        self.core.handle_timeout(now);
        self.pump();
    }

    /// The first tile assigned to slave `s`, if any, with its frame.
    pub fn assigned(&self, s: PeerId) -> Option<(FrameId, TileJob)> {
        self.peers[&s].received.iter().find_map(|m| match m {
            Message::TileAssignment(a) => a.tiles.first().map(|t| (a.frame, *t)),
            _ => None,
        })
    }

    /// Tiles viewer `v` took straight from slaves.
    pub fn direct_tiles(&self, v: PeerId) -> u32 {
        self.viewer_sim(v).direct_tiles
    }

    /// Steps until `done` holds (at most ten virtual minutes).
    pub fn run_until(&mut self, mut done: impl FnMut(&Net) -> bool) {
        for _ in 0..600_000 {
            if done(self) {
                return;
            }
            self.step();
        }
        panic!("condition never held; now {:?}, status {:?}", self.now, self.core.status());
    }

    /// Steps for `d`.
    pub fn run_for(&mut self, d: Duration) {
        let end = self.now + d;
        while self.now < end {
            self.step();
        }
    }

    fn viewer_sim(&self, v: PeerId) -> &ViewerSim {
        match &self.peers[&v].kind {
            Kind::Viewer(sim) => sim,
            _ => panic!("{v} is not a viewer"),
        }
    }

    fn slave_sim(&self, s: PeerId) -> &SlaveSim {
        match &self.peers[&s].kind {
            Kind::Slave(sim) => sim,
            _ => panic!("{s} is not a slave"),
        }
    }

    /// Whether viewer `v` got `FrameDone` for `request`.
    pub fn viewer_done(&self, v: PeerId, request: u64) -> bool {
        self.viewer_sim(v).frames.get(&request).is_some_and(|f| f.done)
    }

    /// Lane-milliseconds of live slaves so far, and how many of them were busy.
    pub fn lanes(&self) -> (u64, u64) {
        (self.lane_ms, self.busy_lane_ms)
    }

    /// The mean time viewer `v`'s requests took, from request to
    /// `FrameDone`, among those done.
    pub fn mean_frame_time(&self, v: PeerId) -> Duration {
        let took: Vec<Duration> = self.viewer_sim(v).frames.values().filter_map(|f| f.took).collect();
        took.iter().sum::<Duration>() / took.len().max(1) as u32
    }

    /// Requests of viewer `v` done so far.
    pub fn done_requests(&self, v: PeerId) -> usize {
        self.viewer_sim(v).frames.values().filter(|f| f.done).count()
    }

    /// Requests of viewer `v` not yet done.
    pub fn open_requests(&self, v: PeerId) -> usize {
        self.viewer_sim(v).frames.values().filter(|f| !f.done).count()
    }

    /// Pixels delivered to viewer `v`, over all its requests.
    pub fn delivered(&self, v: PeerId) -> u64 {
        self.viewer_sim(v).frames.values().map(|f| f.writes.iter().map(|&n| u64::from(n)).sum::<u64>()).sum()
    }

    /// Asserts that `request`'s image is every slave's render, each pixel
    /// delivered exactly once.
    pub fn assert_exact(&self, v: PeerId, request: u64) {
        let f = &self.viewer_sim(v).frames[&request];
        assert!(f.done, "request {request} not done");
        let s = f.settings;
        let scene = f.scene.expect("a frame of a known scene");
        let want = render(s.seed ^ scene_seed(&scene), Tile { x: 0, y: 0, w: s.width, h: s.height });
        if let Some(i) = f.writes.iter().position(|&n| n != 1) {
            panic!("request {request}: pixel {i} delivered {} times", f.writes[i]);
        }
        assert!(f.image == want, "request {request}: the image is not the render");
    }

    /// Whether `peer`'s connection is closed (by the core or by the peer).
    pub fn is_closed(&self, peer: PeerId) -> bool {
        let p = &self.peers[&peer];
        p.gone || p.closed.is_some()
    }

    /// Why the core refused `peer`, if it did.
    pub fn rejection(&self, peer: PeerId) -> Option<String> {
        self.peers[&peer].rejection.clone()
    }

    /// The frame limit the core set for `peer`, if any.
    pub fn limit(&self, peer: PeerId) -> Option<usize> {
        self.peers[&peer].limit
    }

    /// Every message `peer` received.
    pub fn received(&self, peer: PeerId) -> &[Message] {
        &self.peers[&peer].received
    }

    /// The `Error` messages viewer `v` got.
    pub fn errors(&self, v: PeerId) -> Vec<String> {
        self.viewer_sim(v).errors.clone()
    }

    /// The `Notice` messages viewer `v` got.
    pub fn notices(&self, v: PeerId) -> Vec<String> {
        self.viewer_sim(v).notices.clone()
    }

    /// Scene chunks slave `s` received.
    pub fn scene_chunks(&self, s: PeerId) -> u32 {
        self.slave_sim(s).chunks
    }

    /// How many times slave `s` received a scene whole.
    pub fn scene_syncs(&self, s: PeerId) -> u32 {
        self.slave_sim(s).syncs
    }

    /// How many assignments slave `s` got.
    pub fn assignments(&self, s: PeerId) -> u32 {
        self.slave_sim(s).assignments
    }

    /// How many cancels slave `s` got.
    pub fn cancels(&self, s: PeerId) -> u32 {
        self.slave_sim(s).cancels
    }

    fn honest(&self) -> Vec<PeerId> {
        self.peers
            .iter()
            .filter(|(_, p)| matches!(p.kind, Kind::Slave(_)) && p.behaviour == Behaviour::Honest)
            .filter(|(_, p)| !p.gone && p.closed.is_none())
            .map(|(&id, _)| id)
            .collect()
    }

    /// Connected honest slaves.
    pub fn honest_slaves(&self) -> usize {
        self.honest().len()
    }

    /// One connected honest slave, at random.
    pub fn live_honest_slave(&self, rng: &mut Rng) -> Option<PeerId> {
        let honest = self.honest();
        (!honest.is_empty()).then(|| honest[rng.below(honest.len() as u64) as usize])
    }
}

/// What a slave says once it holds the default scene.
fn ready(behaviour: Behaviour, hash: Option<SceneHash>) -> Option<Message> {
    match behaviour {
        Behaviour::StallBeforeReady | Behaviour::HeartbeatNeverReady => None,
        _ => Some(Message::Ready { hash }),
    }
}

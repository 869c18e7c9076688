//! The slave: joins a master, renders assigned tiles on its own rayon pool
//! and streams the results back.
//!
//! Scenes are kept by content hash in a [`SceneCache`] (least recently used
//! out first, within a byte budget), across reconnections: the master's
//! default scene comes at join unless cached; any other scene is asked for
//! ([`Message::NeedScene`]) the first time an assignment names it, and loaded
//! beside the rendering of other scenes' tiles — its tiles wait, nothing
//! else does.
//!
//! The actor never renders: each tile is a job on the pool, and the job sends
//! its encoded result straight into the connection (a [`FrameSender`] works
//! from any thread), so no per-tile round trip through the actor is awaited.
//! Queued jobs of a cancelled tile (another slave won it, or its frame was
//! superseded: the master cancels every tile of a superseded frame) are skipped
//! when their turn comes, and a job already rendering one stops between bands
//! of rows ([`Renderer::render_cancellable`]): a move that supersedes a
//! refinement pass waits for a few rows, not for whole tiles. A newer frame's
//! tiles do not make an older frame's stale by themselves: the master may
//! pipeline frames, handing out the next frame's tiles while the older frame's
//! are still queued here.
//!
//! A tile of a viewer that takes its tiles straight
//! ([`protocol::DirectRoute`]) goes to that viewer over a link of its own
//! (`slave/direct.rs`), and through the master when the link cannot take it.

mod direct;
mod incoming;

pub use direct::{ACK_TIMEOUT, Dialer, REDIAL_AFTER};

use crate::client::{self, JoinError};
use actix::prelude::*;
use direct::Links;
use incoming::Incoming;
use isin_cluster::codec::{self, Codec};
use isin_cluster::protocol::{self, FrameId, Message, SceneHash, TileAssignment, TileId, TileResult};
use isin_tracer::{Camera, RenderSettings, Scene, SceneBundle, Tile};
use isin_transport::{FrameSender, Ticket, Transport, TransportError};
use serde_bytes::ByteBuf;
use std::collections::{HashMap, HashSet};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::oneshot;

/// How a slave runs.
#[derive(Clone, Debug)]
pub struct SlaveOptions {
    /// Name shown in the master's logs.
    pub name: String,
    /// Render threads.
    pub threads: usize,
    /// How often to tell the master we are alive.
    pub heartbeat_interval: Duration,
    /// A master silent for this long is presumed dead (we reconnect).
    pub master_timeout: Duration,
    /// Longest wait between reconnection attempts.
    pub max_backoff: Duration,
    /// Give up after this many failed attempts in a row (`None`: never).
    pub max_attempts: Option<u32>,
    /// Tile codecs offered to the master, which picks one (raw if none suits).
    pub codecs: Vec<Codec>,
    /// Bytes of loaded scenes kept (as [`Renderer::footprint`] counts them);
    /// the least recently used go first, the one in use never.
    pub scene_cache_bytes: usize,
    /// How to reach viewers that take their tiles straight
    /// ([`protocol::DirectRoute`]); `None`: all tiles go through the master.
    pub direct: Option<Dialer>,
}

impl Default for SlaveOptions {
    fn default() -> Self {
        Self {
            name: "slave".into(),
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
            heartbeat_interval: Duration::from_millis(500),
            master_timeout: Duration::from_secs(10),
            max_backoff: Duration::from_secs(5),
            max_attempts: None,
            codecs: Codec::ALL.to_vec(),
            scene_cache_bytes: 4 << 30,
            direct: None,
        }
    }
}

/// Frames a cancellation is remembered for: cancellations of frames this much
/// older than the newest assigned one are forgotten (those of tiles rendered
/// before their cancel came are never consumed). Forgetting one costs at most
/// a tile rendered for nothing. A tile is never skipped for its frame's age:
/// frame numbers count every client's frames, and a batch frame stays open
/// while viewers run through hundreds of newer ones, so a tile of it handed
/// out again (its slave died) is far older than what this slave renders —
/// and still wanted.
const CANCEL_MEMORY: u64 = 256;

/// What a slave renders with: loads a shipped scene, renders a tile of it.
/// [`Tracer`] is the real one; tests plug in cheap fakes.
pub trait Renderer: Send + Sync + 'static {
    /// A loaded, renderable scene.
    type Scene: Send + Sync + 'static;
    /// Builds the scene from its bundle (runs on a blocking thread, while
    /// the bundle's hash is checked beside it).
    fn load(&self, bundle: &SceneBundle) -> Result<Self::Scene, String>;
    /// `tile.w * tile.h * 3` bytes of RGB8.
    fn render(&self, scene: &Self::Scene, camera: &Camera, settings: &RenderSettings, tile: Tile) -> Vec<u8>;

    /// Bytes a loaded scene holds, roughly, for the cache's budget; the
    /// default is its bundle's size.
    fn footprint(&self, _scene: &Self::Scene, bundle_bytes: usize) -> usize {
        bundle_bytes
    }

    /// [`Renderer::render`] that gives up (`None`) once `cancelled()` answers
    /// true: the slave asks between bands of rows, so a tile of a superseded
    /// frame stops within a few rows instead of running to its end. The
    /// default checks once, before rendering the whole tile.
    fn render_cancellable(
        &self,
        scene: &Self::Scene,
        camera: &Camera,
        settings: &RenderSettings,
        tile: Tile,
        cancelled: &dyn Fn() -> bool,
    ) -> Option<Vec<u8>> {
        if cancelled() {
            return None;
        }
        Some(self.render(scene, camera, settings, tile))
    }
}

/// Rows rendered between two cancel checks of [`Tracer`].
pub const ROWS_PER_CANCEL_CHECK: u32 = 4;

/// The isin ray tracer.
#[derive(Clone, Copy, Debug, Default)]
pub struct Tracer;

/// A renderer that needs no tracer: every pixel is a hash of its coordinates
/// and the camera ([`Pattern::pixel`]), so a frame's expected bytes are known
/// without rendering. It counts scene loads and tiles. For tests of the
/// cluster and of transports, and for measuring the network alone.
#[derive(Debug, Default)]
pub struct Pattern {
    /// Scenes loaded.
    pub loads: std::sync::atomic::AtomicU64,
    /// Tiles rendered.
    pub tiles: std::sync::atomic::AtomicU64,
}

impl Pattern {
    /// The RGB8 value of pixel `(x, y)` seen by `camera`.
    pub fn pixel(camera: &Camera, x: u32, y: u32) -> [u8; 3] {
        let h = (x as u64).wrapping_mul(0x9e37_79b9)
            ^ (y as u64).wrapping_mul(0x85eb_ca6b)
            ^ camera.eye.z.to_bits() as u64;
        [h as u8, (h >> 8) as u8, (h >> 16) as u8]
    }
}

impl Renderer for Pattern {
    type Scene = String;

    fn load(&self, bundle: &SceneBundle) -> Result<String, String> {
        self.loads.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        Ok(bundle.source.clone())
    }

    fn render(&self, _: &String, camera: &Camera, _: &RenderSettings, t: Tile) -> Vec<u8> {
        self.tiles.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let mut out = Vec::with_capacity(t.pixel_count() * 3);
        for y in t.y..t.y + t.h {
            for x in t.x..t.x + t.w {
                out.extend_from_slice(&Self::pixel(camera, x, y));
            }
        }
        out
    }
}

impl Renderer for Tracer {
    type Scene = Scene;

    fn load(&self, bundle: &SceneBundle) -> Result<Scene, String> {
        let t0 = Instant::now();
        let scene = bundle.load().map_err(|e| e.to_string())?;
        let loaded = t0.elapsed();
        // A slave renders many frames of this scene: fill its shadow cells
        // now, not in the first frames of the session.
        scene.fill_shadow_cells();
        tracing::info!(
            "loaded scene {} ({} triangles) in {:.0} ms, shadow cells ({}) in {:.0} ms",
            bundle.name,
            scene.triangle_count(),
            loaded.as_secs_f64() * 1e3,
            scene.shadow_cells_filled(),
            (t0.elapsed() - loaded).as_secs_f64() * 1e3
        );
        Ok(scene)
    }

    fn render(&self, scene: &Scene, camera: &Camera, settings: &RenderSettings, tile: Tile) -> Vec<u8> {
        isin_tracer::render_tile(scene, camera, settings, tile)
    }

    /// The bundle (textures are decoded from it) plus the BVH and triangle
    /// data: about 100 bytes a triangle.
    fn footprint(&self, scene: &Scene, bundle_bytes: usize) -> usize {
        bundle_bytes.saturating_mul(2).saturating_add(scene.triangle_count().saturating_mul(100))
    }

    /// Renders the tile in bands of [`ROWS_PER_CANCEL_CHECK`] rows, asking
    /// `cancelled` before each: the bytes are those of one
    /// [`isin_tracer::render_tile`] call (a pixel's value does not depend on
    /// the tiling).
    fn render_cancellable(
        &self,
        scene: &Scene,
        camera: &Camera,
        settings: &RenderSettings,
        tile: Tile,
        cancelled: &dyn Fn() -> bool,
    ) -> Option<Vec<u8>> {
        let mut out = Vec::with_capacity(tile.pixel_count() * 3);
        let mut y = tile.y;
        while y < tile.y + tile.h {
            if cancelled() {
                return None;
            }
            let h = ROWS_PER_CANCEL_CHECK.min(tile.y + tile.h - y);
            out.extend_from_slice(&isin_tracer::render_tile(scene, camera, settings, Tile { y, h, ..tile }));
            y += h;
        }
        Some(out)
    }
}

/// CPU time of the calling thread, where the platform has a thread clock.
pub fn thread_cpu_time() -> Option<Duration> {
    #[cfg(unix)]
    {
        let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
        // SAFETY: clock_gettime writes one timespec through a valid pointer.
        if unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) } == 0 {
            return Some(Duration::new(ts.tv_sec.max(0) as u64, ts.tv_nsec.clamp(0, 999_999_999) as u32));
        }
    }
    None
}

/// Loaded scenes by content hash, least recently used out first.
pub struct SceneCache<S> {
    entries: Vec<CachedScene<S>>,
    budget: usize,
    clock: u64,
}

struct CachedScene<S> {
    hash: SceneHash,
    scene: Arc<S>,
    bytes: usize,
    used: u64,
}

impl<S> SceneCache<S> {
    /// An empty cache of `budget` bytes.
    pub fn new(budget: usize) -> Self {
        Self { entries: Vec::new(), budget, clock: 0 }
    }

    /// The scene of `hash`, if held (now the most recently used).
    pub fn get(&mut self, hash: &SceneHash) -> Option<Arc<S>> {
        self.clock += 1;
        let e = self.entries.iter_mut().find(|e| &e.hash == hash)?;
        e.used = self.clock;
        Some(e.scene.clone())
    }

    /// Keeps `scene`, evicting the least recently used others until it fits
    /// (it is kept even if it alone is over the budget). Returns the hashes
    /// evicted.
    pub fn insert(&mut self, hash: SceneHash, scene: Arc<S>, bytes: usize) -> Vec<SceneHash> {
        self.entries.retain(|e| e.hash != hash);
        let mut evicted = Vec::new();
        while !self.entries.is_empty() && self.held_bytes() + bytes > self.budget {
            let Some(oldest) = self.entries.iter().enumerate().min_by_key(|(_, e)| e.used).map(|(i, _)| i)
            else {
                break;
            };
            evicted.push(self.entries.remove(oldest).hash);
        }
        self.clock += 1;
        self.entries.push(CachedScene { hash, scene, bytes, used: self.clock });
        evicted
    }

    /// The hashes held, most recently used first.
    pub fn hashes(&self) -> Vec<SceneHash> {
        let mut e: Vec<(u64, SceneHash)> = self.entries.iter().map(|e| (e.used, e.hash)).collect();
        e.sort_unstable_by_key(|x| std::cmp::Reverse(x.0));
        e.into_iter().map(|(_, h)| h).collect()
    }

    fn held_bytes(&self) -> usize {
        self.entries.iter().map(|e| e.bytes).sum()
    }
}

/// A shared [`SceneCache`]: the session's actor and the reconnection loop use it.
pub type SharedScenes<S> = Arc<Mutex<SceneCache<S>>>;

/// Decodes and loads a scene that came in whole on a thread of its own (it
/// builds a BVH: never on the async thread), its hash checked beside the
/// load; a panicking loader is reported as an error.
fn load_in_background<R: Renderer>(
    renderer: Arc<R>,
    incoming: Incoming,
) -> oneshot::Receiver<Result<(R::Scene, usize), String>> {
    let (tx, rx) = oneshot::channel();
    std::thread::spawn(move || {
        let load = |bundle: &SceneBundle| {
            let out = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| renderer.load(bundle)));
            out.unwrap_or_else(|_| Err("scene loader panicked".into()))
        };
        let out = match incoming.finish_with(load) {
            Ok((bundle, loaded)) => loaded.map(|scene| {
                let bytes = bundle.source.len() + bundle.assets.values().map(Vec::len).sum::<usize>();
                let footprint = renderer.footprint(&scene, bytes);
                (scene, footprint)
            }),
            Err(e) => Err(format!("bad scene from the master: {e}")),
        };
        let _ = tx.send(out);
    });
    rx
}

/// Counters shared with the render jobs.
#[derive(Debug, Default)]
pub struct SlaveCounters {
    /// Tiles rendered and sent.
    pub tiles: AtomicU64,
    /// Tiles skipped, or stopped part-way, because cancelled or superseded.
    pub skipped: AtomicU64,
}

/// Runs a slave until it is refused or gives up: joins, serves, and on any
/// network failure joins again with exponential backoff.
pub async fn run<R: Renderer>(
    transport: Arc<dyn Transport>,
    ticket: Ticket,
    opts: SlaveOptions,
    renderer: Arc<R>,
) -> Result<(), JoinError> {
    let pool = Arc::new(
        rayon::ThreadPoolBuilder::new()
            .num_threads(opts.threads.max(1))
            .thread_name(|i| format!("isin-render-{i}"))
            .build()
            .map_err(|e| JoinError::Scene(format!("cannot start render threads: {e}")))?,
    );
    let counters = Arc::new(SlaveCounters::default());
    let cache: SharedScenes<R::Scene> = Arc::new(Mutex::new(SceneCache::new(opts.scene_cache_bytes)));
    let mut backoff = Duration::from_millis(100);
    let (mut failures, mut unresolved) = (0u32, 0u32);
    // Retrying is said once a minute, not at every attempt.
    let mut said: Option<std::time::Instant> = None;
    loop {
        match join(transport.as_ref(), &ticket, &opts, &renderer, &cache).await {
            Ok(session) => {
                backoff = Duration::from_millis(100);
                (failures, unresolved, said) = (0, 0, None);
                let why =
                    serve(session, renderer.clone(), pool.clone(), counters.clone(), cache.clone(), &opts)
                        .await;
                tracing::warn!("lost the master ({why}); reconnecting");
            }
            Err(e) if !e.is_retryable() => return Err(e),
            Err(e) => {
                failures += 1;
                unresolved = if matches!(e, JoinError::Transport(TransportError::Unresolvable { .. })) {
                    unresolved + 1
                } else {
                    0
                };
                if opts.max_attempts.is_some_and(|m| failures >= m) || unresolved >= MAX_UNRESOLVED {
                    return Err(e);
                }
                if said.is_none_or(|at| at.elapsed() >= RETRY_REPORT) {
                    said = Some(std::time::Instant::now());
                    tracing::warn!(
                        "cannot join {} yet ({e}); retrying (every {:?} at most; said again in a minute)",
                        ticket.addr,
                        opts.max_backoff
                    );
                } else {
                    tracing::debug!("cannot join {} yet ({e}); retrying in {backoff:?}", ticket.addr);
                }
                tokio::time::sleep(backoff).await;
                backoff = (backoff * 2).min(opts.max_backoff);
            }
        }
    }
}

/// Consecutive attempts on a host name that resolves to nothing before a
/// slave gives up (with the default backoff, about 20 s: a name server that is
/// down for a moment is waited for, a mistyped name is not).
pub const MAX_UNRESOLVED: u32 = 10;

/// How often a slave that cannot join says it is still trying.
pub const RETRY_REPORT: Duration = Duration::from_secs(60);

/// An authenticated connection with the master's default scene loaded,
/// ready for tiles.
pub struct Session {
    conn: isin_transport::Connection,
    id: u64,
    name: String,
    codec: Codec,
}

fn lock<S>(cache: &SharedScenes<S>) -> std::sync::MutexGuard<'_, SceneCache<S>> {
    // A panic while holding it cannot leave the cache half-changed.
    cache.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Connects, authenticates, and makes sure the master's default scene (if
/// any) is loaded.
pub async fn join<R: Renderer>(
    transport: &dyn Transport,
    ticket: &Ticket,
    opts: &SlaveOptions,
    renderer: &Arc<R>,
    cache: &SharedScenes<R::Scene>,
) -> Result<Session, JoinError> {
    let cached = lock(cache).hashes();
    let join = client::Join::slave(&opts.name, opts.threads as u32, &cached, &opts.codecs);
    let (mut conn, welcome) = client::handshake(transport, ticket, join).await?;
    if welcome.codec != Codec::Raw && !opts.codecs.contains(&welcome.codec) {
        conn.sender.close();
        return Err(JoinError::Rejected(format!(
            "master picked tile codec {}, which was not offered",
            welcome.codec
        )));
    }
    // The master holds every logged-in peer to its heartbeat, and receiving
    // and loading a large scene takes longer than that: say alive meanwhile.
    let heartbeats = tokio::spawn(heartbeat_until_dropped(conn.sender.clone(), opts.heartbeat_interval));
    let _stop_heartbeats = AbortOnDrop(heartbeats);
    let default = welcome.scene.as_ref().map(|s| s.hash);
    if let Some(hash) = default.filter(|h| lock(cache).get(h).is_none()) {
        let incoming = receive_chunks(&mut conn, hash).await?;
        let (scene, bytes) = load_in_background(renderer.clone(), incoming)
            .await
            .map_err(|_| JoinError::Scene("scene loader vanished".into()))?
            .map_err(JoinError::Scene)?;
        lock(cache).insert(hash, Arc::new(scene), bytes);
    }
    client::send_message(&conn, &Message::Ready { hash: default })?;
    tracing::info!(
        master = %ticket.addr,
        "joined master {} as {} (tiles in {})",
        ticket.addr,
        welcome.name,
        welcome.codec
    );
    Ok(Session { conn, id: welcome.id, name: welcome.name, codec: welcome.codec })
}

/// Receives the scene `hash` on a connection that just logged in as a slave
/// (heartbeats and all): its chunks are unpacked as they come and
/// acknowledged (the master sends a window of them ahead), and the bundle is
/// whole, its hash checked, with the last one.
pub async fn receive_scene(
    conn: &mut isin_transport::Connection,
    hash: SceneHash,
) -> Result<SceneBundle, JoinError> {
    let incoming = receive_chunks(conn, hash).await?;
    incoming.finish().map_err(|e| JoinError::Scene(format!("bad scene: {e}")))
}

/// [`receive_scene`] up to its last chunk: the scene whole, not yet decoded.
async fn receive_chunks(
    conn: &mut isin_transport::Connection,
    hash: SceneHash,
) -> Result<Incoming, JoinError> {
    let bad = |e: isin_cluster::scene_stream::StreamError| JoinError::Scene(format!("bad scene: {e}"));
    let mut incoming: Option<Incoming> = None;
    loop {
        match client::recv_message(conn, protocol::DEFAULT_MAX_FRAME, Duration::from_secs(120)).await? {
            Message::SceneBegin(header) if header.hash == hash && incoming.is_none() => {
                incoming = Some(Incoming::begin(header).map_err(bad)?);
            }
            Message::SceneChunk { hash: of, index, bytes } => {
                let Some(rx) = incoming.as_mut() else { return Err(JoinError::Unexpected("SceneChunk")) };
                let p = rx.chunk(&of, index, bytes.into_vec()).map_err(bad)?;
                client::send_message(conn, &Message::SceneAck { hash: of, chunks_received: p.chunks })?;
                if p.complete
                    && let Some(rx) = incoming.take()
                {
                    return Ok(rx);
                }
            }
            Message::Heartbeat => continue,
            Message::Reject { reason } => return Err(JoinError::Rejected(reason)),
            other => return Err(JoinError::Unexpected(other.kind())),
        }
    }
}

/// Sends a heartbeat every `interval` until the connection closes (or the
/// task is aborted).
async fn heartbeat_until_dropped(sender: isin_transport::FrameSender, interval: Duration) {
    let Ok(hb) = protocol::encode(&Message::Heartbeat) else { return };
    loop {
        tokio::time::sleep(interval).await;
        if sender.send(hb.clone()).is_err() {
            return;
        }
    }
}

/// Aborts a task when dropped.
struct AbortOnDrop(tokio::task::JoinHandle<()>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}

/// Serves one session until the connection ends; returns why it ended.
pub async fn serve<R: Renderer>(
    session: Session,
    renderer: Arc<R>,
    pool: Arc<rayon::ThreadPool>,
    counters: Arc<SlaveCounters>,
    scenes: SharedScenes<R::Scene>,
    opts: &SlaveOptions,
) -> String {
    let (done_tx, done_rx) = oneshot::channel();
    let isin_transport::Connection { sender, mut receiver, .. } = session.conn;
    let links = Links::new(opts.direct.clone(), sender.clone(), session.id, session.name.clone());
    let actor = SlaveActor {
        sender,
        links,
        scenes,
        incoming: None,
        parked: HashMap::new(),
        renderer,
        pool,
        latest: 0,
        cancelled: Arc::default(),
        counters,
        last_heard: Instant::now(),
        heartbeat_interval: opts.heartbeat_interval,
        master_timeout: opts.master_timeout,
        done: Some(done_tx),
        name: session.name,
        codec: session.codec,
    };
    let addr = actor.start();
    tokio::spawn(async move {
        while let Some(frame) = receiver.recv().await {
            addr.do_send(Inbound(frame));
        }
        addr.do_send(Inbound(Err(TransportError::Closed)));
    });
    done_rx.await.unwrap_or_else(|_| "slave actor stopped".into())
}

/// The slave actor (see the [module docs](self)).
pub struct SlaveActor<R: Renderer> {
    sender: FrameSender,
    /// Links to viewers that take their tiles straight.
    links: Arc<Links>,
    scenes: SharedScenes<R::Scene>,
    /// A scene coming in (one at a time: the master queues the others).
    incoming: Option<Incoming>,
    /// Assignments waiting for their scene (asked for once), by scene.
    parked: HashMap<SceneHash, Vec<TileAssignment>>,
    renderer: Arc<R>,
    pool: Arc<rayon::ThreadPool>,
    /// The newest frame assigned (for forgetting old cancellations).
    latest: FrameId,
    cancelled: Arc<Mutex<HashSet<(FrameId, TileId)>>>,
    counters: Arc<SlaveCounters>,
    last_heard: Instant,
    heartbeat_interval: Duration,
    master_timeout: Duration,
    done: Option<oneshot::Sender<String>>,
    name: String,
    codec: Codec,
}

impl<R: Renderer> SlaveActor<R> {
    fn finish(&mut self, why: String, ctx: &mut Context<Self>) {
        self.links.close();
        self.sender.close();
        if let Some(done) = self.done.take() {
            let _ = done.send(why);
        }
        ctx.stop();
    }

    /// An assignment: rendered if its scene is here, else parked and the
    /// scene asked for.
    fn assign(&mut self, a: TileAssignment) {
        let held = lock(&self.scenes).get(&a.scene);
        if let Some(scene) = held {
            return self.render(a, scene);
        }
        let parked_tiles: usize = self.parked.values().flatten().map(|a| a.tiles.len()).sum();
        if parked_tiles + a.tiles.len() > MAX_PARKED_TILES {
            return tracing::error!("more than {MAX_PARKED_TILES} tiles wait for scenes; assignment dropped");
        }
        let waiting = self.parked.entry(a.scene).or_default();
        if waiting.is_empty() {
            tracing::info!("fetching a scene ({}) for frame {}", protocol::short_hash(&a.scene), a.frame);
            if let Ok(m) = protocol::encode(&Message::NeedScene { hash: a.scene }) {
                let _ = self.sender.send(m);
            }
        }
        waiting.push(a);
    }

    /// A scene came in whole: decoded, checked and loaded off the actor,
    /// then its parked tiles go.
    fn scene_arrived(&mut self, incoming: Incoming, ctx: &mut Context<Self>) {
        let hash = incoming.hash();
        if !self.parked.contains_key(&hash) {
            return tracing::warn!("the master sent a scene no assignment waits for; ignored");
        }
        let rx = load_in_background(self.renderer.clone(), incoming);
        let me = ctx.address();
        tokio::spawn(async move {
            let result = rx.await.unwrap_or_else(|_| Err("scene loader vanished".into()));
            me.do_send(SceneLoaded { hash, result });
        });
    }

    /// A chunk of the scene coming in: acknowledged, and the scene loaded
    /// once it is whole. A bad one ends the session (the master is lying or
    /// broken).
    fn scene_chunk(&mut self, hash: SceneHash, index: u32, bytes: Vec<u8>, ctx: &mut Context<Self>) {
        let Some(rx) = self.incoming.as_mut() else {
            return self.finish("a scene chunk before its SceneBegin".into(), ctx);
        };
        let progress = match rx.chunk(&hash, index, bytes) {
            Ok(p) => p,
            Err(e) => return self.finish(format!("bad scene from the master: {e}"), ctx),
        };
        if let Ok(m) = protocol::encode(&Message::SceneAck { hash, chunks_received: progress.chunks }) {
            let _ = self.sender.send(m);
        }
        if !progress.complete {
            return;
        }
        if let Some(rx) = self.incoming.take() {
            self.scene_arrived(rx, ctx);
        }
    }

    fn scene_failed(&mut self, hash: SceneHash, reason: String) {
        tracing::error!("cannot load a scene: {reason}");
        self.parked.remove(&hash);
        if let Ok(m) = protocol::encode(&Message::SceneFailed { hash, reason }) {
            let _ = self.sender.send(m);
        }
    }

    /// Queues an assignment's tiles on the pool.
    fn render(&mut self, a: TileAssignment, scene: Arc<R::Scene>) {
        if a.frame > self.latest {
            self.latest = a.frame;
            // Cancellations of tiles that were already rendered are never
            // consumed by a job: forget those of frames long gone.
            if let Ok(mut c) = self.cancelled.lock() {
                c.retain(|(f, _)| f.saturating_add(CANCEL_MEMORY) >= a.frame);
            }
        }
        let (w, h) = (a.settings.width, a.settings.height);
        let route: Option<Arc<protocol::DirectRoute>> = a.direct.map(Arc::from);
        if let Some(r) = &route {
            self.links.prepare(r);
        }
        for job in a.tiles {
            let t = job.tile;
            let inside = t.w > 0
                && t.h > 0
                && t.x.checked_add(t.w).is_some_and(|r| r <= w)
                && t.y.checked_add(t.h).is_some_and(|b| b <= h);
            if !inside {
                tracing::error!(?t, "master assigned a tile outside the {w}x{h} image; skipped");
                continue;
            }
            let (renderer, scene, sender, cancelled, counters, links, route) = (
                self.renderer.clone(),
                scene.clone(),
                self.sender.clone(),
                self.cancelled.clone(),
                self.counters.clone(),
                self.links.clone(),
                route.clone(),
            );
            let (frame, camera, settings, tile_codec) = (a.frame, a.camera, a.settings, self.codec);
            self.pool.spawn_fifo(move || {
                // Skip (or stop, between bands of rows) cancelled tiles and
                // the leftovers of a session whose connection is gone.
                let stop = || {
                    sender.is_closed()
                        || cancelled.lock().map(|mut c| c.remove(&(frame, job.id))).unwrap_or(false)
                };
                let (t0, cpu0) = (Instant::now(), thread_cpu_time());
                let pixels = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                    renderer.render_cancellable(&scene, &camera, &settings, t, &stop)
                }));
                let Ok(pixels) = pixels else {
                    tracing::error!(
                        ?t,
                        frame,
                        "render_tile panicked; tile dropped (the master will reassign it)"
                    );
                    return;
                };
                let Some(pixels) = pixels else {
                    counters.skipped.fetch_add(1, Ordering::Relaxed);
                    return;
                };
                if pixels.len() != t.pixel_count() * 3 {
                    tracing::error!(
                        ?t,
                        len = pixels.len(),
                        "renderer returned the wrong number of bytes; dropped"
                    );
                    return;
                }
                let took = match (cpu0, thread_cpu_time()) {
                    (Some(a), Some(b)) => b.saturating_sub(a),
                    _ => t0.elapsed(),
                };
                let rendered = TileResult {
                    frame,
                    id: job.id,
                    tile: t,
                    render_micros: took.as_micros() as u64,
                    codec: tile_codec,
                    pixels: ByteBuf::from(codec::encode(tile_codec, t.w, &pixels)),
                };
                // Tiles may overtake each other (over QUIC a lost packet
                // then delays only its own tile), never the ordered
                // messages around them.
                match &route {
                    Some(r) => links.deliver(r, rendered),
                    None => {
                        direct::send_result(&sender, rendered);
                    }
                }
                counters.tiles.fetch_add(1, Ordering::Relaxed);
            });
        }
    }
}

impl<R: Renderer> Actor for SlaveActor<R> {
    type Context = Context<Self>;

    fn started(&mut self, ctx: &mut Self::Context) {
        ctx.run_interval(self.heartbeat_interval, |s, ctx| {
            s.links.expire();
            if s.last_heard.elapsed() > s.master_timeout {
                let why = format!("master silent for {:?}", s.master_timeout);
                return s.finish(why, ctx);
            }
            if let Ok(hb) = protocol::encode(&Message::Heartbeat)
                && s.sender.send(hb).is_err()
            {
                s.finish("connection closed".into(), ctx);
            }
        });
    }
}

#[derive(Message)]
#[rtype(result = "()")]
struct Inbound(Result<Vec<u8>, TransportError>);

/// Tiles that may wait for their scenes at once (far more than a master
/// keeps in flight on one slave).
const MAX_PARKED_TILES: usize = 65_536;

/// A scene finished loading (or failed to).
#[derive(Message)]
#[rtype(result = "()")]
struct SceneLoaded<S: Send + 'static> {
    hash: SceneHash,
    result: Result<(S, usize), String>,
}

impl<R: Renderer> Handler<SceneLoaded<R::Scene>> for SlaveActor<R> {
    type Result = ();

    fn handle(&mut self, msg: SceneLoaded<R::Scene>, _: &mut Self::Context) {
        match msg.result {
            Ok((scene, bytes)) => {
                let scene = Arc::new(scene);
                let evicted = lock(&self.scenes).insert(msg.hash, scene.clone(), bytes);
                if !evicted.is_empty() {
                    tracing::info!("{} scenes evicted from the cache", evicted.len());
                }
                for a in self.parked.remove(&msg.hash).unwrap_or_default() {
                    self.render(a, scene.clone());
                }
            }
            Err(reason) => self.scene_failed(msg.hash, reason),
        }
    }
}

impl<R: Renderer> Handler<Inbound> for SlaveActor<R> {
    type Result = ();

    fn handle(&mut self, Inbound(frame): Inbound, ctx: &mut Self::Context) {
        self.last_heard = Instant::now();
        let msg = match frame {
            Ok(f) => protocol::decode(&f, protocol::DEFAULT_MAX_FRAME),
            Err(e) => return self.finish(e.to_string(), ctx),
        };
        match msg {
            Ok(Message::TileAssignment(a)) => self.assign(a),
            Ok(Message::SceneBegin(header)) => {
                if self.incoming.is_some() {
                    return self.finish("the master began a scene before the last one ended".into(), ctx);
                }
                match Incoming::begin(header) {
                    Ok(rx) => self.incoming = Some(rx),
                    Err(e) => self.finish(format!("bad scene from the master: {e}"), ctx),
                }
            }
            Ok(Message::SceneChunk { hash, index, bytes }) => {
                self.scene_chunk(hash, index, bytes.into_vec(), ctx)
            }
            Ok(Message::Cancel { frame, tiles }) => {
                if let Ok(mut c) = self.cancelled.lock() {
                    c.extend(tiles.into_iter().map(|t| (frame, t)));
                }
            }
            Ok(Message::Heartbeat) => {}
            Ok(Message::Error { message }) => tracing::warn!("master reports: {message}"),
            Ok(Message::Reject { reason }) => {
                self.finish(format!("master dropped {}: {reason}", self.name), ctx)
            }
            Ok(other) => tracing::warn!("ignoring unexpected {} from the master", other.kind()),
            Err(e) => self.finish(format!("bad frame from the master: {e}"), ctx),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_scene_cache_evicts_the_least_recently_used_and_keeps_the_newest_whatever_its_size() {
        let mut c: SceneCache<u8> = SceneCache::new(100);
        assert!(c.insert([1; 32], Arc::new(1), 40).is_empty());
        assert!(c.insert([2; 32], Arc::new(2), 40).is_empty());
        assert!(c.get(&[1; 32]).is_some(), "1 is now the most recent");
        assert_eq!(c.insert([3; 32], Arc::new(3), 40), vec![[2; 32]]);
        assert_eq!(c.hashes(), vec![[3; 32], [1; 32]]);
        // One scene over the whole budget is still kept, alone.
        assert_eq!(c.insert([4; 32], Arc::new(4), 500), vec![[1; 32], [3; 32]]);
        assert_eq!(c.get(&[4; 32]).as_deref(), Some(&4));
        assert!(c.get(&[1; 32]).is_none());
    }

    #[test]
    fn thread_cpu_time_counts_work_not_sleep() {
        let Some(c0) = thread_cpu_time() else {
            println!("skipped: no thread CPU clock on this platform");
            return;
        };
        std::thread::sleep(Duration::from_millis(50));
        let slept = thread_cpu_time().unwrap().saturating_sub(c0);
        // The wall clock brackets the CPU clock's readings.
        let w1 = Instant::now();
        let c1 = thread_cpu_time().unwrap();
        let mut x = 1u64;
        while w1.elapsed() < Duration::from_millis(100) {
            x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
        }
        let worked = thread_cpu_time().unwrap().saturating_sub(c1);
        let wall = w1.elapsed();
        assert!(slept < Duration::from_millis(25), "sleeping cost {slept:?} of CPU");
        // 100 ms of spinning: most of it on a CPU, unless the machine is very
        // busy, and never more than the wall time (give or take the two
        // clocks' granularity).
        assert!(
            worked > Duration::from_millis(5) && worked <= wall + Duration::from_millis(1),
            "spinning cost {worked:?} of CPU in {wall:?}"
        );
    }
}

//! The slave: joins a master, receives the scene once (cached by hash across
//! reconnections), renders assigned tiles on its own rayon pool and streams
//! the results back.
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

use crate::client::{self, JoinError};
use actix::prelude::*;
use isin_cluster::codec::{self, Codec};
use isin_cluster::protocol::{self, FrameId, Message, SceneHash, TileAssignment, TileId, TileResult};
use isin_tracer::{Camera, RenderSettings, Scene, SceneBundle, Tile};
use isin_transport::{Delivery, FrameSender, Ticket, Transport, TransportError};
use serde_bytes::ByteBuf;
use std::collections::HashSet;
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
        }
    }
}

/// Frames a cancellation is remembered for: a queued job of a frame this much
/// older than the newest assigned one is skipped outright (the master keeps
/// far fewer frames open at once), and cancellations of older frames are
/// forgotten.
const CANCEL_MEMORY: u64 = 16;

/// What a slave renders with: loads a shipped scene, renders a tile of it.
/// [`Tracer`] is the real one; tests plug in cheap fakes.
pub trait Renderer: Send + Sync + 'static {
    /// A loaded, renderable scene.
    type Scene: Send + Sync + 'static;
    /// Builds the scene from its bundle (runs on a blocking thread).
    fn load(&self, bundle: SceneBundle) -> Result<Self::Scene, String>;
    /// `tile.w * tile.h * 3` bytes of RGB8.
    fn render(&self, scene: &Self::Scene, camera: &Camera, settings: &RenderSettings, tile: Tile) -> Vec<u8>;

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

    fn load(&self, bundle: SceneBundle) -> Result<String, String> {
        self.loads.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        Ok(bundle.source)
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

    fn load(&self, bundle: SceneBundle) -> Result<Scene, String> {
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

/// A loaded scene and the hash of the bundle it came from.
pub struct SceneCache<S> {
    /// Content hash.
    pub hash: SceneHash,
    /// The built scene.
    pub scene: Arc<S>,
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
    let mut cache: Option<SceneCache<R::Scene>> = None;
    let mut backoff = Duration::from_millis(100);
    let (mut failures, mut unresolved) = (0u32, 0u32);
    // Retrying is said once a minute, not at every attempt.
    let mut said: Option<std::time::Instant> = None;
    loop {
        match join(transport.as_ref(), &ticket, &opts, &renderer, &mut cache).await {
            Ok(session) => {
                backoff = Duration::from_millis(100);
                (failures, unresolved, said) = (0, 0, None);
                let why = serve(session, renderer.clone(), pool.clone(), counters.clone(), &opts).await;
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

/// An authenticated, scene-synced connection, ready for tiles.
pub struct Session<S> {
    conn: isin_transport::Connection,
    scene: Arc<S>,
    name: String,
    codec: Codec,
}

/// Connects, authenticates, and makes sure the master's scene is loaded.
pub async fn join<R: Renderer>(
    transport: &dyn Transport,
    ticket: &Ticket,
    opts: &SlaveOptions,
    renderer: &Arc<R>,
    cache: &mut Option<SceneCache<R::Scene>>,
) -> Result<Session<R::Scene>, JoinError> {
    let cached = cache.as_ref().map(|c| c.hash);
    let join = client::Join::slave(&opts.name, opts.threads as u32, cached, &opts.codecs);
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
    if cached != Some(welcome.scene.hash) {
        let (hash, bundle) = loop {
            match client::recv_message(&mut conn, protocol::DEFAULT_MAX_FRAME, Duration::from_secs(120))
                .await?
            {
                Message::SceneSync { hash, bundle } => break (hash, bundle),
                Message::Heartbeat => continue,
                Message::Reject { reason } => return Err(JoinError::Rejected(reason)),
                other => return Err(JoinError::Unexpected(other.kind())),
            }
        };
        let bundle: SceneBundle = bundle.into();
        if protocol::scene_hash(&bundle) != hash {
            return Err(JoinError::Scene("scene bundle does not match its hash".into()));
        }
        // Loading builds a BVH: keep it off the async thread. A panicking
        // loader is reported, not propagated.
        let (tx, rx) = oneshot::channel();
        let r = renderer.clone();
        std::thread::spawn(move || {
            let out = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| r.load(bundle)));
            let _ = tx.send(out.unwrap_or_else(|_| Err("scene loader panicked".into())));
        });
        let scene = rx
            .await
            .map_err(|_| JoinError::Scene("scene loader vanished".into()))?
            .map_err(JoinError::Scene)?;
        *cache = Some(SceneCache { hash, scene: Arc::new(scene) });
    }
    let scene = cache.as_ref().map(|c| c.scene.clone()).ok_or(JoinError::Closed)?;
    client::send_message(&conn, &Message::Ready { hash: welcome.scene.hash })?;
    tracing::info!(
        master = %ticket.addr,
        "joined master {} as {} (tiles in {})",
        ticket.addr,
        welcome.name,
        welcome.codec
    );
    Ok(Session { conn, scene, name: welcome.name, codec: welcome.codec })
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
    session: Session<R::Scene>,
    renderer: Arc<R>,
    pool: Arc<rayon::ThreadPool>,
    counters: Arc<SlaveCounters>,
    opts: &SlaveOptions,
) -> String {
    let (done_tx, done_rx) = oneshot::channel();
    let isin_transport::Connection { sender, mut receiver, .. } = session.conn;
    let actor = SlaveActor {
        sender,
        scene: session.scene,
        renderer,
        pool,
        latest: Arc::new(AtomicU64::new(0)),
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
    scene: Arc<R::Scene>,
    renderer: Arc<R>,
    pool: Arc<rayon::ThreadPool>,
    latest: Arc<AtomicU64>,
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
        self.sender.close();
        if let Some(done) = self.done.take() {
            let _ = done.send(why);
        }
        ctx.stop();
    }

    fn assign(&mut self, a: TileAssignment) {
        if a.frame > self.latest.load(Ordering::Acquire) {
            self.latest.store(a.frame, Ordering::Release);
            // Cancellations of tiles that were already rendered are never
            // consumed by a job: forget those of frames long gone.
            if let Ok(mut c) = self.cancelled.lock() {
                c.retain(|(f, _)| f.saturating_add(CANCEL_MEMORY) >= a.frame);
            }
        }
        let (w, h) = (a.settings.width, a.settings.height);
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
            let (renderer, scene, sender, latest, cancelled, counters) = (
                self.renderer.clone(),
                self.scene.clone(),
                self.sender.clone(),
                self.latest.clone(),
                self.cancelled.clone(),
                self.counters.clone(),
            );
            let (frame, camera, settings, tile_codec) = (a.frame, a.camera, a.settings, self.codec);
            self.pool.spawn_fifo(move || {
                // Skip (or stop, between bands of rows) cancelled tiles, tiles
                // of frames long gone, and the leftovers of a session whose
                // connection is gone.
                let stop = || {
                    sender.is_closed()
                        || latest.load(Ordering::Acquire) > frame.saturating_add(CANCEL_MEMORY)
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
                let render_micros = took.as_micros() as u64;
                let msg = Message::TileResult(TileResult {
                    frame,
                    id: job.id,
                    tile: t,
                    render_micros,
                    codec: tile_codec,
                    pixels: ByteBuf::from(codec::encode(tile_codec, t.w, &pixels)),
                });
                match protocol::encode(&msg) {
                    Ok(bytes) => {
                        // Tiles may overtake each other (over QUIC a lost
                        // packet then delays only its own tile), never the
                        // ordered messages around them.
                        let _ = sender.send_as(bytes, Delivery::Independent);
                        counters.tiles.fetch_add(1, Ordering::Relaxed);
                    }
                    Err(e) => tracing::error!("cannot encode tile: {e}"),
                }
            });
        }
    }
}

impl<R: Renderer> Actor for SlaveActor<R> {
    type Context = Context<Self>;

    fn started(&mut self, ctx: &mut Self::Context) {
        ctx.run_interval(self.heartbeat_interval, |s, ctx| {
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

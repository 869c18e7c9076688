//! The viewer: a client that asks the master for frames and receives their
//! tiles as they finish. A GUI draws each [`ViewerEvent::Tile`] as it arrives;
//! [`collect_frame`] collects one whole frame (used by `isin render --cluster`).
//! A viewer connected with [`connect_direct`] also takes tiles straight from
//! slaves ([`DirectListener`]), shows each tile once however its copies
//! come, and tells the master of each one it took straight.

mod direct;

pub use direct::DirectListener;

use crate::client::{self, JoinError};
use actix::prelude::*;
use isin_cluster::protocol::{
    self, DirectTile, FrameStats, JobSpec, Message, SceneHash, SceneInfo, SlaveEntry, Status, TileReceived,
};
use isin_cluster::scene_stream;
use isin_cluster::scheduler::Work;
use isin_tracer::{Camera, Frame, RenderSettings, SceneBundle, Tile};
use isin_transport::{ConnStats, FrameSender, Ticket, Transport, TransportError};
use std::collections::{BTreeMap, HashSet};
use std::time::Duration;
use tokio::sync::mpsc;

/// Requests whose sizes (and direct tiles seen) a viewer remembers.
const REQUESTS_REMEMBERED: usize = 256;

/// What the viewer reports to whoever drives it.
#[derive(Clone, Debug, PartialEq)]
pub enum ViewerEvent {
    /// A finished tile of request `request`.
    Tile {
        /// The request it answers.
        request: u64,
        /// The id of the slave that rendered it.
        slave: u64,
        /// That slave's name.
        slave_name: String,
        /// Where it goes.
        tile: Tile,
        /// `w * h * 3` bytes of RGB8.
        pixels: Vec<u8>,
    },
    /// Every tile of request `request` has arrived.
    FrameDone {
        /// The request.
        request: u64,
        /// How it went on the master.
        stats: FrameStats,
    },
    /// The master could not serve a request.
    Error(String),
    /// The master says something worth showing (e.g. that the frames wait
    /// for a slave to join).
    Notice(String),
    /// The connection ended.
    Closed(String),
}

/// The viewer actor: forwards the master's tiles to a channel, and keeps the
/// master's latest slave list ([`GetSlaves`]).
pub struct ViewerActor {
    sender: FrameSender,
    sink: mpsc::UnboundedSender<ViewerEvent>,
    next_request: u64,
    slaves: Option<Vec<SlaveEntry>>,
    slaves_version: u64,
    /// The scene every request names (`None`: the master's default).
    scene: Option<SceneHash>,
    status: Option<Status>,
    /// Recent requests: their image sizes, and the tiles of each passed on
    /// so far (a tile two slaves rendered can come twice, straight or
    /// straight and through the master).
    requests: BTreeMap<u64, Sent>,
}

/// A request as the viewer remembers it, for checking direct tiles.
#[derive(Debug, Default)]
struct Sent {
    width: u32,
    height: u32,
    done: bool,
    seen: HashSet<Tile>,
}

/// A tile straight from a slave; answers whether it is one of this viewer's
/// (a tile of a finished request, or one seen already, is, and is dropped).
#[derive(Message)]
#[rtype(result = "bool")]
struct DirectIn(DirectTile);

/// Asks for the cluster's status as the master last pushed it.
#[derive(Message)]
#[rtype(result = "Option<Status>")]
pub struct GetClusterStatus;

/// The master's slaves as it last told them (live ones and the latest dead
/// ones), with a version that grows with every update.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SlaveList {
    /// Number of updates received (0: none yet).
    pub version: u64,
    /// The slaves, if the master has sent its list.
    pub slaves: Option<Vec<SlaveEntry>>,
}

/// Asks for the master's slave list.
#[derive(Message)]
#[rtype(result = "SlaveList")]
pub struct GetSlaves;

/// Asks for a frame; answers with the request number its tiles will carry.
/// The actor numbers these requests itself, above every number used so far
/// (callers that cannot await the answer use [`RequestFrameAs`]). A newer
/// request supersedes an older one: the older one's remaining tiles never come.
#[derive(Message)]
#[rtype(result = "u64")]
pub struct RequestFrame {
    /// Camera.
    pub camera: Camera,
    /// Resolution, samples and so on.
    pub settings: RenderSettings,
}

/// Asks for a frame to be rendered after those already requested, without
/// superseding them (answers with its request number, numbered like
/// [`RequestFrame`]): a replayed camera path keeps the next frame queued at the
/// master so that slaves roll from one frame straight into the next. Each
/// frame comes back with its own tiles and `FrameDone`. The master keeps a few
/// frames open at most; beyond that it answers with an error.
#[derive(Message)]
#[rtype(result = "u64")]
pub struct QueueFrame {
    /// Camera.
    pub camera: Camera,
    /// Resolution, samples and so on.
    pub settings: RenderSettings,
    /// Its index in the client's job, if the client submitted one.
    pub job_frame: Option<u32>,
}

/// Asks for a frame under the caller's own request number (e.g. a window's
/// frame id), which its tiles and `FrameDone` will carry: nothing to count or
/// map, so a GUI thread can post it with `do_send`. Numbers should increase;
/// later [`RequestFrame`]s are numbered above it.
#[derive(Message)]
#[rtype(result = "()")]
pub struct RequestFrameAs {
    /// The request number.
    pub request: u64,
    /// Camera.
    pub camera: Camera,
    /// Resolution, samples and so on.
    pub settings: RenderSettings,
}

/// Closes the connection to the master and stops the actor (the master and
/// its slaves stay up for the next viewer).
#[derive(Message)]
#[rtype(result = "()")]
pub struct Disconnect;

/// Asks for the connection's byte counters.
#[derive(Message)]
#[rtype(result = "ConnStats")]
pub struct GetWireStats;

#[derive(Message)]
#[rtype(result = "()")]
struct Inbound(Result<Vec<u8>, TransportError>);

impl Actor for ViewerActor {
    type Context = Context<Self>;

    fn started(&mut self, ctx: &mut Self::Context) {
        ctx.run_interval(Duration::from_millis(500), |v, _| {
            if let Ok(hb) = protocol::encode(&Message::Heartbeat) {
                let _ = v.sender.send(hb);
            }
        });
    }
}

impl ViewerActor {
    fn request(
        &mut self,
        request: u64,
        camera: Camera,
        settings: RenderSettings,
        queue: Option<Option<u32>>,
    ) {
        self.next_request = self.next_request.max(request);
        let sent = Sent { width: settings.width, height: settings.height, ..Sent::default() };
        self.requests.insert(request, sent);
        while self.requests.len() > REQUESTS_REMEMBERED {
            self.requests.pop_first();
        }
        let scene = self.scene;
        let m = match queue {
            Some(job_frame) => Message::QueueFrame { request, scene, camera, settings, job_frame },
            None => Message::FrameRequest { request, scene, camera, settings },
        };
        match protocol::encode(&m) {
            Ok(bytes) => {
                let _ = self.sender.send(bytes);
            }
            Err(e) => {
                let _ = self.sink.send(ViewerEvent::Error(e.to_string()));
            }
        }
    }
}

impl Handler<RequestFrame> for ViewerActor {
    type Result = u64;

    fn handle(&mut self, msg: RequestFrame, _: &mut Self::Context) -> u64 {
        let request = self.next_request + 1;
        self.request(request, msg.camera, msg.settings, None);
        request
    }
}

impl Handler<QueueFrame> for ViewerActor {
    type Result = u64;

    fn handle(&mut self, msg: QueueFrame, _: &mut Self::Context) -> u64 {
        let request = self.next_request + 1;
        self.request(request, msg.camera, msg.settings, Some(msg.job_frame));
        request
    }
}

impl Handler<RequestFrameAs> for ViewerActor {
    type Result = ();

    fn handle(&mut self, msg: RequestFrameAs, _: &mut Self::Context) {
        self.request(msg.request, msg.camera, msg.settings, None);
    }
}

impl Handler<Disconnect> for ViewerActor {
    type Result = ();

    fn handle(&mut self, _: Disconnect, ctx: &mut Self::Context) {
        self.sender.close();
        ctx.stop();
    }
}

impl Handler<GetWireStats> for ViewerActor {
    type Result = MessageResult<GetWireStats>;

    fn handle(&mut self, _: GetWireStats, _: &mut Self::Context) -> Self::Result {
        MessageResult(self.sender.stats())
    }
}

impl Handler<GetClusterStatus> for ViewerActor {
    type Result = MessageResult<GetClusterStatus>;

    fn handle(&mut self, _: GetClusterStatus, _: &mut Self::Context) -> Self::Result {
        MessageResult(self.status.clone())
    }
}

impl Handler<GetSlaves> for ViewerActor {
    type Result = MessageResult<GetSlaves>;

    fn handle(&mut self, _: GetSlaves, _: &mut Self::Context) -> Self::Result {
        MessageResult(SlaveList { version: self.slaves_version, slaves: self.slaves.clone() })
    }
}

impl Handler<DirectIn> for ViewerActor {
    type Result = bool;

    fn handle(&mut self, DirectIn(d): DirectIn, _: &mut Self::Context) -> bool {
        let t = d.tile;
        let Some(sent) = self.requests.get_mut(&t.request) else {
            // Older than what is remembered: a request of this viewer's, long gone.
            return t.request <= self.next_request;
        };
        let r = t.tile;
        let inside = r.w > 0
            && r.h > 0
            && r.x.checked_add(r.w).is_some_and(|x| x <= sent.width)
            && r.y.checked_add(r.h).is_some_and(|y| y <= sent.height);
        if !inside {
            return false;
        }
        if sent.done || sent.seen.contains(&r) {
            return true;
        }
        let Ok(pixels) = t.decoded_pixels() else { return false };
        sent.seen.insert(r);
        let event = ViewerEvent::Tile {
            request: t.request,
            slave: t.slave,
            slave_name: t.slave_name,
            tile: r,
            pixels,
        };
        let _ = self.sink.send(event);
        // Shown first, then the master told: its FrameDone comes after.
        let received = TileReceived {
            frame: d.frame,
            id: d.id,
            slave: t.slave,
            tile: r,
            render_micros: d.render_micros,
        };
        if let Ok(bytes) = protocol::encode(&Message::TileReceived(received)) {
            let _ = self.sender.send(bytes);
        }
        true
    }
}

impl Handler<Inbound> for ViewerActor {
    type Result = ();

    fn handle(&mut self, Inbound(frame): Inbound, ctx: &mut Self::Context) {
        let msg = frame.map_err(|e| e.to_string()).and_then(|f| {
            protocol::decode(&f, protocol::DEFAULT_MAX_FRAME)
                .map_err(|e| format!("bad frame from the master: {e}"))
        });
        let event = match msg {
            // A tile shown already (it came straight too) is not shown again.
            Ok(Message::FrameTile(t))
                if self.requests.get_mut(&t.request).is_some_and(|s| !s.seen.insert(t.tile)) =>
            {
                None
            }
            Ok(Message::FrameTile(t)) => match t.decoded_pixels() {
                Err(e) => Some(ViewerEvent::Error(format!("tile {:?}: {e}", t.tile))),
                Ok(pixels) => Some(ViewerEvent::Tile {
                    request: t.request,
                    slave: t.slave,
                    slave_name: t.slave_name,
                    tile: t.tile,
                    pixels,
                }),
            },
            Ok(Message::FrameDone { request, stats }) => {
                if let Some(sent) = self.requests.get_mut(&request) {
                    sent.done = true;
                    sent.seen = HashSet::new();
                }
                Some(ViewerEvent::FrameDone { request, stats })
            }
            Ok(Message::Slaves { slaves }) => {
                // Kept for GetSlaves rather than sent as an event: drivers that
                // only want frames need not hear about it.
                self.slaves = Some(slaves);
                self.slaves_version += 1;
                None
            }
            Ok(Message::Error { message }) => Some(ViewerEvent::Error(message)),
            Ok(Message::Notice { message }) => Some(ViewerEvent::Notice(message)),
            Ok(Message::Reject { reason }) => Some(ViewerEvent::Closed(format!("master refused: {reason}"))),
            Ok(Message::Status(status)) => {
                self.status = Some(status);
                None
            }
            Ok(Message::Heartbeat) => None,
            Ok(other) => Some(ViewerEvent::Error(format!("unexpected {} from the master", other.kind()))),
            Err(e) => {
                self.sender.close();
                ctx.stop();
                Some(ViewerEvent::Closed(e))
            }
        };
        if let Some(e) = event {
            let _ = self.sink.send(e);
        }
    }
}

/// Connects a viewer actor to the master of `ticket`. Must run inside an actix
/// system. Returns the actor, the master's default scene (if it has one) and
/// the event stream.
pub async fn connect(
    transport: &dyn Transport,
    ticket: &Ticket,
    name: &str,
) -> Result<(Addr<ViewerActor>, Option<SceneInfo>, mpsc::UnboundedReceiver<ViewerEvent>), JoinError> {
    connect_as(transport, ticket, name, Work::Interactive).await
}

/// [`connect`] as a client whose frames are `work`: a batch client's frames
/// fill what interactive clients leave (a still or an animation rendered
/// while others fly).
pub async fn connect_as(
    transport: &dyn Transport,
    ticket: &Ticket,
    name: &str,
    work: Work,
) -> Result<(Addr<ViewerActor>, Option<SceneInfo>, mpsc::UnboundedReceiver<ViewerEvent>), JoinError> {
    let c = connect_with(transport, ticket, Setup { name, work, scene: None, job: None }).await?;
    Ok((c.addr, c.default_scene, c.events))
}

/// What a client brings when it connects ([`connect_with`]).
#[derive(Clone, Copy, Debug)]
pub struct Setup<'a> {
    /// Name for the master's logs and status.
    pub name: &'a str,
    /// Interactive or batch.
    pub work: Work,
    /// Its own scene (uploaded unless the master holds it); `None`: the
    /// master's default.
    pub scene: Option<&'a SceneBundle>,
    /// Its batch job, if its frames are one.
    pub job: Option<&'a JobSpec>,
}

/// A connected client ([`connect_with`]).
pub struct Connected {
    /// The viewer actor: every frame it requests is of the client's scene.
    pub addr: Addr<ViewerActor>,
    /// The master's default scene, if it has one.
    pub default_scene: Option<SceneInfo>,
    /// The frames of the job done before (by an earlier run of it).
    pub done: Vec<u32>,
    /// The event stream.
    pub events: mpsc::UnboundedReceiver<ViewerEvent>,
}

/// How long the master may take to answer a scene upload or a job: a
/// large scene over a slow link.
pub const SETUP_TIMEOUT: Duration = Duration::from_secs(600);

/// Waits for the answer `pick` takes, skipping what a master says meanwhile
/// but its slave list (kept in `slaves`: it is sent once, on joining).
async fn answer<T>(
    conn: &mut isin_transport::Connection,
    slaves: &mut Option<Vec<SlaveEntry>>,
    mut pick: impl FnMut(Message) -> Option<Result<T, JoinError>>,
) -> Result<T, JoinError> {
    loop {
        match client::recv_message(conn, protocol::DEFAULT_MAX_FRAME, SETUP_TIMEOUT).await? {
            Message::Error { message } => return Err(JoinError::Rejected(message)),
            Message::Reject { reason } => return Err(JoinError::Rejected(reason)),
            Message::Slaves { slaves: list } => *slaves = Some(list),
            m => {
                if let Some(out) = pick(m) {
                    return out;
                }
            }
        }
    }
}

/// Connects a client: the handshake, then its scene (sent only if the
/// master does not hold it) and its job. Must run inside an actix system.
pub async fn connect_with(
    transport: &dyn Transport,
    ticket: &Ticket,
    setup: Setup<'_>,
) -> Result<Connected, JoinError> {
    connect_client(transport, ticket, setup, None).await
}

/// [`connect_with`] for a client that takes its tiles straight from the
/// slaves where it can: they dial `direct` (the master still schedules every
/// tile, and sees a sample of them itself).
pub async fn connect_direct(
    transport: &dyn Transport,
    ticket: &Ticket,
    setup: Setup<'_>,
    direct: DirectListener,
) -> Result<Connected, JoinError> {
    connect_client(transport, ticket, setup, Some(direct)).await
}

async fn connect_client(
    transport: &dyn Transport,
    ticket: &Ticket,
    setup: Setup<'_>,
    direct: Option<DirectListener>,
) -> Result<Connected, JoinError> {
    let join = client::Join {
        direct: direct.as_ref().map(|d| d.offer()),
        ..client::Join::viewer(setup.name, setup.work)
    };
    let (mut conn, welcome) = client::handshake(transport, ticket, join).await?;
    let mut slaves = None;
    let scene = match setup.scene {
        None => None,
        Some(bundle) => {
            let mut bundle = bundle.clone();
            bundle.name = protocol::served_name(&bundle.name).to_string();
            // Packed as the master sends scenes to slaves: compressed, in chunks.
            let packed = scene_stream::pack(&bundle).map_err(|e| JoinError::Scene(e.to_string()))?;
            let hash = packed.header.hash;
            client::send_message(&conn, &Message::SceneUpload(packed.header.clone()))?;
            let mut packed = Some(packed);
            let sender = conn.sender.clone();
            answer(&mut conn, &mut slaves, |m| match m {
                Message::SceneStored { hash: h } if h == hash => Some(Ok(())),
                Message::SceneWanted { hash: h } if h == hash => {
                    let p = packed.take()?;
                    let h = &p.header;
                    tracing::info!(
                        "sending scene {} to the master: {} bytes, {} compressed",
                        bundle.name,
                        h.raw_bytes,
                        h.compressed_bytes
                    );
                    let sent = (0..h.chunks)
                        .filter_map(|i| p.chunk_frame(i))
                        .try_for_each(|f| sender.send(f.to_vec()));
                    sent.err().map(|e| Err(e.into()))
                }
                _ => None,
            })
            .await?;
            Some(hash)
        }
    };
    let done = match setup.job {
        None => Vec::new(),
        Some(job) => {
            client::send_message(&conn, &Message::SubmitJob(job.clone()))?;
            answer(&mut conn, &mut slaves, |m| match m {
                Message::JobAccepted { key, done } if key == job.key => Some(Ok(done)),
                _ => None,
            })
            .await?
        }
    };
    let (sink, events) = mpsc::unbounded_channel();
    let isin_transport::Connection { sender, mut receiver, .. } = conn;
    let slaves_version = u64::from(slaves.is_some());
    let actor = ViewerActor {
        sender,
        sink,
        next_request: 0,
        slaves,
        slaves_version,
        scene,
        status: None,
        requests: BTreeMap::new(),
    };
    let addr = actor.start();
    if let Some(d) = direct {
        d.serve(addr.clone());
    }
    let target = addr.clone();
    tokio::spawn(async move {
        while let Some(frame) = receiver.recv().await {
            target.do_send(Inbound(frame));
        }
        target.do_send(Inbound(Err(TransportError::Closed)));
    });
    Ok(Connected { addr, default_scene: welcome.scene, done, events })
}

/// Why a cluster frame failed.
#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    /// Could not join.
    #[error(transparent)]
    Join(#[from] JoinError),
    /// The master answered with an error.
    #[error("{0}")]
    Master(String),
    /// The connection to the master was lost (worth reconnecting).
    #[error("lost the master: {0}")]
    Lost(String),
    /// The viewer actor is gone.
    #[error("viewer actor stopped")]
    Mailbox,
}

/// Requests one frame through `viewer` and waits until all its tiles arrived.
pub async fn collect_frame(
    viewer: &Addr<ViewerActor>,
    events: &mut mpsc::UnboundedReceiver<ViewerEvent>,
    camera: Camera,
    settings: RenderSettings,
) -> Result<(Frame, FrameStats), ViewerError> {
    let request = viewer.send(RequestFrame { camera, settings }).await.map_err(|_| ViewerError::Mailbox)?;
    let mut frame = Frame::new(settings.width, settings.height);
    let mut covered = 0usize;
    while let Some(ev) = events.recv().await {
        match ev {
            ViewerEvent::Tile { request: r, tile, pixels, .. } if r == request => {
                let inside = tile.x as u64 + tile.w as u64 <= settings.width as u64
                    && tile.y as u64 + tile.h as u64 <= settings.height as u64;
                if !inside {
                    return Err(ViewerError::Master(format!("tile {tile:?} outside the image")));
                }
                frame.blit(tile, &pixels);
                covered += tile.pixel_count();
            }
            ViewerEvent::FrameDone { request: r, stats } if r == request => {
                if covered != settings.width as usize * settings.height as usize {
                    return Err(ViewerError::Master(format!("frame done with {covered} pixels delivered")));
                }
                return Ok((frame, stats));
            }
            ViewerEvent::Tile { .. } | ViewerEvent::FrameDone { .. } => {}
            ViewerEvent::Notice(m) => tracing::warn!("master: {m}"),
            ViewerEvent::Error(e) => return Err(ViewerError::Master(e)),
            ViewerEvent::Closed(e) => return Err(ViewerError::Lost(e)),
        }
    }
    Err(ViewerError::Lost("connection closed".into()))
}

/// Renders one frame per camera of `cameras` through `viewer`, keeping up to
/// `depth` of them queued at the master ([`QueueFrame`]) so that slaves roll
/// from one frame straight into the next, and hands each to `done` (with its
/// index in `cameras`) as it completes — in the order they complete. Stops at
/// the first error, `done`'s included.
///
/// With `job_frames`, camera `i` is frame `job_frames[i]` of the client's job
/// (the master records it done).
pub async fn collect_frames<E: std::fmt::Display>(
    viewer: &Addr<ViewerActor>,
    events: &mut mpsc::UnboundedReceiver<ViewerEvent>,
    cameras: &[Camera],
    job_frames: Option<&[u32]>,
    settings: RenderSettings,
    depth: usize,
    mut done: impl FnMut(usize, Frame, FrameStats) -> Result<(), E>,
) -> Result<(), ViewerError> {
    // Requests in flight: request number → (camera index, frame, pixels so far).
    let mut open: std::collections::BTreeMap<u64, (usize, Frame, usize)> = std::collections::BTreeMap::new();
    let mut next = 0;
    let all = settings.width as usize * settings.height as usize;
    while next < cameras.len() || !open.is_empty() {
        while next < cameras.len() && open.len() < depth.max(1) {
            let job_frame = job_frames.and_then(|j| j.get(next).copied());
            let queue = QueueFrame { camera: cameras[next], settings, job_frame };
            let request = viewer.send(queue).await.map_err(|_| ViewerError::Mailbox)?;
            open.insert(request, (next, Frame::new(settings.width, settings.height), 0));
            next += 1;
        }
        let Some(ev) = events.recv().await else {
            return Err(ViewerError::Lost("connection closed".into()));
        };
        match ev {
            ViewerEvent::Tile { request, tile, pixels, .. } => {
                let Some((_, frame, covered)) = open.get_mut(&request) else { continue };
                let inside = tile.x as u64 + tile.w as u64 <= settings.width as u64
                    && tile.y as u64 + tile.h as u64 <= settings.height as u64;
                if !inside {
                    return Err(ViewerError::Master(format!("tile {tile:?} outside the image")));
                }
                frame.blit(tile, &pixels);
                *covered += tile.pixel_count();
            }
            ViewerEvent::FrameDone { request, stats } => {
                let Some((index, frame, covered)) = open.remove(&request) else { continue };
                if covered != all {
                    return Err(ViewerError::Master(format!("frame done with {covered} pixels delivered")));
                }
                done(index, frame, stats).map_err(|e| ViewerError::Master(e.to_string()))?;
            }
            ViewerEvent::Notice(m) => tracing::warn!("master: {m}"),
            ViewerEvent::Error(e) => return Err(ViewerError::Master(e)),
            ViewerEvent::Closed(e) => return Err(ViewerError::Lost(e)),
        }
    }
    Ok(())
}

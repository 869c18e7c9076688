//! The master actor: the accept loop, a reader task per connection, the clock
//! and the sending — around [`Cluster`], which decides everything else.
//!
//! Connections are numbered as they are accepted; their frames reach the
//! core as actix messages from per-connection reader tasks (`Inbound`,
//! `Closed`), and after every event the actor carries out what the core
//! asks ([`Transmit`]): encode and send, raise a frame limit, close, and
//! — with a state directory — keep on disk ([`crate::state`]) before going on.

use crate::state::{StateDir, StateError};
use actix::prelude::*;
use isin_cluster::auth::{self, AuthError};
use isin_cluster::protocol::{self, FrameStats};
use isin_cluster::scheduler::SlaveInfo;
use isin_cluster::{Class, Cluster, ClusterConfig, DefaultScene, PeerId, Transmit};
use isin_tracer::{Camera, RenderSettings, SceneBundle};
use isin_transport::{ConnStats, Connection, Delivery, FrameSender, Listener, MemoryBudget, TransportError};
use std::collections::HashMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// How the master runs.
#[derive(Clone, Debug)]
pub struct MasterConfig {
    /// What the core decides with.
    pub cluster: ClusterConfig,
    /// Longest sleep between two looks at the core's timeouts (it wakes
    /// earlier at the core's own deadlines).
    pub tick: Duration,
    /// Where uploaded scenes and batch jobs are kept across restarts.
    pub state: Option<PathBuf>,
}

impl MasterConfig {
    /// Defaults around a default scene and a token, with fresh randomness
    /// for the core's challenge nonces.
    pub fn new(
        token: String,
        bundle: SceneBundle,
        camera: Camera,
        settings: RenderSettings,
    ) -> Result<Self, AuthError> {
        Self::serving(token, Some(DefaultScene { bundle, camera, settings }))
    }

    /// Defaults around a token and a default scene, or none (clients then
    /// bring their own).
    pub fn serving(token: String, scene: Option<DefaultScene>) -> Result<Self, AuthError> {
        let seed = auth::random_bytes::<32>()?;
        let cluster = ClusterConfig::new(token, scene, seed);
        Ok(Self { cluster, tick: Duration::from_millis(50), state: None })
    }
}

/// Why a master could not start.
#[derive(Debug, thiserror::Error)]
pub enum MasterError {
    /// The default scene could not be encoded.
    #[error(transparent)]
    Protocol(#[from] protocol::ProtocolError),
    /// The state directory could not be used.
    #[error(transparent)]
    State(#[from] StateError),
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
    /// Connections refused (bad token, bad protocol, garbage, over a limit).
    pub refused: u64,
    /// Slaves declared dead.
    pub deaths: u64,
    /// Tile results refused because their slave was never handed the tile.
    pub foreign_results: u64,
    /// Connections open now.
    pub peers: usize,
    /// Last completed frame's stats.
    pub last_frame: Option<FrameStats>,
}

/// The master actor.
pub struct Master {
    core: Cluster,
    tick: Duration,
    epoch: Instant,
    next_peer: PeerId,
    senders: HashMap<PeerId, FrameSender>,
    /// Byte counts of connections already closed.
    closed_wire: ConnStats,
    state: Option<StateDir>,
}

impl Master {
    /// A master for `cfg`, with what its state directory holds; fails if the
    /// scene cannot be encoded or the state directory cannot be used.
    pub fn new(cfg: MasterConfig) -> Result<Self, MasterError> {
        let mut core = Cluster::new(cfg.cluster)?;
        let epoch = Instant::now();
        let state = match &cfg.state {
            None => None,
            Some(root) => {
                let (dir, loaded) = StateDir::open(root)?;
                for (path, sync) in loaded.scenes {
                    if let Err(e) = core.restore_scene(&sync) {
                        tracing::warn!("ignoring scene {}: {e}", path.display());
                    }
                }
                let jobs = loaded.jobs.len();
                for job in loaded.jobs {
                    core.restore_job(Duration::ZERO, job);
                }
                tracing::info!("state {}: {jobs} jobs", root.display());
                Some(dir)
            }
        };
        Ok(Self {
            core,
            tick: cfg.tick,
            epoch,
            next_peer: 1,
            senders: HashMap::new(),
            closed_wire: ConnStats::default(),
            state,
        })
    }

    /// Starts the master and an accept loop on `listener`, whose connections
    /// together may hold the core's [`buffered_bytes`] in frames being read.
    ///
    /// [`buffered_bytes`]: isin_cluster::limits::Budgets::buffered_bytes
    pub fn serve(self, mut listener: Box<dyn Listener>) -> Addr<Master> {
        listener.set_budget(MemoryBudget::new(self.core.budgets().buffered_bytes));
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

    fn now(&self) -> Duration {
        self.epoch.elapsed()
    }

    /// Counters of every connection, open or closed.
    fn wire(&self) -> ConnStats {
        let mut wire = self.closed_wire;
        for s in self.senders.values().map(FrameSender::stats) {
            add_stats(&mut wire, s);
        }
        wire
    }

    /// Carries out everything the core asked for.
    fn flush(&mut self) {
        while let Some(t) = self.core.poll_transmit() {
            if let Transmit::Store(what) = &t {
                // Before anything that follows it goes out.
                if let Some(dir) = &self.state
                    && let Err(e) = dir.store(what)
                {
                    tracing::error!("cannot keep state: {e}");
                }
                continue;
            }
            let Some(sender) = self.senders.get(&t.peer()) else { continue };
            match t {
                Transmit::Send { message, class, .. } => match protocol::encode(&message) {
                    Ok(bytes) => {
                        let _ = sender.send_as(bytes, delivery(class));
                    }
                    Err(e) => tracing::error!("cannot encode {}: {e}", message.kind()),
                },
                Transmit::SendFrame { frame, class, .. } => {
                    let _ = sender.send_as(frame, delivery(class));
                }
                Transmit::SendEncoded { frame, .. } => {
                    let _ = sender.send(frame.as_ref().clone());
                }
                Transmit::Limit { max_frame, .. } => sender.set_max_frame(max_frame),
                Transmit::Close { peer, .. } => {
                    if let Some(sender) = self.senders.remove(&peer) {
                        add_stats(&mut self.closed_wire, sender.stats());
                        sender.close();
                    }
                }
                Transmit::Store(_) => {}
            }
        }
    }

    /// Runs the core's timeouts at its next deadline ([`Cluster::poll_timeout`]),
    /// or after one tick if that comes first, then arms itself again.
    ///
    /// Deadlines only move later between wakes (a heartbeat pushes a slave's
    /// back) or appear at least a tick ahead (a new peer's handshake, the
    /// status interval), so a dead slave is declared dead at its deadline, not
    /// up to a tick after it. A roster held back by
    /// [`isin_cluster::ROSTER_INTERVAL`] may wait up to a tick more.
    fn wake_at_deadline(&mut self, ctx: &mut Context<Self>) {
        let now = self.now();
        let next = self.core.poll_timeout().map_or(now + self.tick, |d| d.min(now + self.tick));
        ctx.run_later(next.saturating_sub(now), |m, ctx| {
            let now = m.now();
            m.core.handle_timeout(now);
            m.flush();
            m.wake_at_deadline(ctx);
        });
    }
}

/// How a class of message travels.
fn delivery(class: Class) -> Delivery {
    match class {
        Class::Control => Delivery::Ordered,
        Class::Tile => Delivery::Independent,
    }
}

fn add_stats(total: &mut ConnStats, s: ConnStats) {
    total.bytes_sent += s.bytes_sent;
    total.bytes_received += s.bytes_received;
    total.frames_sent += s.frames_sent;
    total.frames_received += s.frames_received;
}

impl Actor for Master {
    type Context = Context<Self>;

    fn started(&mut self, ctx: &mut Self::Context) {
        self.wake_at_deadline(ctx);
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
    peer: PeerId,
    frame: Result<Vec<u8>, TransportError>,
}

/// Connection `peer` ended.
#[derive(Message)]
#[rtype(result = "()")]
struct Closed {
    peer: PeerId,
}

/// Asks for the master's counters.
#[derive(Message)]
#[rtype(result = "MasterStatus")]
pub struct GetStatus;

/// Asks for the slaves declared dead so far ([`Deaths`]): a poll that costs
/// the master nothing, where [`GetStatus`] builds the list of every slave.
#[derive(Message)]
#[rtype(result = "Deaths")]
pub struct GetDeaths;

/// The answer to [`GetDeaths`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, MessageResponse)]
pub struct Deaths {
    /// Slaves declared dead so far.
    pub count: u64,
    /// The longest any slave declared dead for its silence had been silent
    /// when declared, by the master's clock ([`Cluster::longest_silence`]):
    /// the heartbeat timeout plus how late the master was.
    pub longest_silence: Duration,
    /// When the latest slave was declared dead for its silence, its tiles
    /// handed back in the same step ([`Cluster::last_timeout_death`]).
    pub last_timeout_death: Option<Instant>,
}

impl Handler<GetDeaths> for Master {
    type Result = Deaths;

    fn handle(&mut self, _: GetDeaths, _: &mut Self::Context) -> Deaths {
        Deaths {
            count: self.core.deaths(),
            longest_silence: self.core.longest_silence(),
            last_timeout_death: self.core.last_timeout_death().map(|d| self.epoch + d),
        }
    }
}

impl Handler<Accepted> for Master {
    type Result = ();

    fn handle(&mut self, Accepted(conn): Accepted, ctx: &mut Self::Context) {
        let id = self.next_peer;
        self.next_peer += 1;
        let Connection { peer: addr, sender, mut receiver } = conn;
        let me = ctx.address();
        tokio::spawn(async move {
            while let Some(frame) = receiver.recv().await {
                me.do_send(Inbound { peer: id, frame });
            }
            me.do_send(Closed { peer: id });
        });
        self.senders.insert(id, sender);
        let now = self.now();
        self.core.handle_connected(now, id, &addr);
        self.flush();
    }
}

impl Handler<Inbound> for Master {
    type Result = ();

    fn handle(&mut self, msg: Inbound, _: &mut Self::Context) {
        let now = self.now();
        match msg.frame {
            Ok(frame) => self.core.handle_frame(now, msg.peer, &frame),
            Err(e) => self.core.handle_transport_error(now, msg.peer, &e.to_string()),
        }
        self.flush();
    }
}

impl Handler<Closed> for Master {
    type Result = ();

    fn handle(&mut self, msg: Closed, _: &mut Self::Context) {
        let now = self.now();
        self.core.handle_closed(now, msg.peer);
        self.flush();
    }
}

impl Handler<GetStatus> for Master {
    type Result = MessageResult<GetStatus>;

    fn handle(&mut self, _: GetStatus, _: &mut Self::Context) -> Self::Result {
        let s = self.core.status();
        MessageResult(MasterStatus {
            slaves: s.slaves,
            frames_requested: s.frames_requested,
            frames_done: s.frames_done,
            wire: self.wire(),
            refused: s.refused,
            deaths: s.deaths,
            foreign_results: s.foreign_results,
            peers: s.peers,
            last_frame: s.last_frame,
        })
    }
}

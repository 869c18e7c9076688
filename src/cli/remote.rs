//! The cluster-backed frame source: the viewer window drawing what a master's
//! slaves render (`isin view --connect TICKET` and the default `isin`).
//!
//! winit needs the main thread, so the actix system that holds the viewer
//! actor runs on a thread of its own. The window's requests cross over through
//! [`isin_viewer::channel_source`]: each [`FrameRequest`] becomes a
//! [`RequestFrameAs`] carrying the window's frame id, so the master's replies
//! come back tagged with it (nothing to map). Tiles become
//! [`SourceEvent::Tile`]s owned by the slave that rendered them; `FrameDone`
//! becomes [`SourceEvent::FrameComplete`] after the status counters (live
//! slaves, tiles per slave, bytes received on the connection) are updated.
//! The slaves are those the master lists ([`GetSlaves`]: it tells its viewers
//! whenever a slave joins or dies), each with the tiles this viewer received
//! from it.
//!
//! When the window closes, its end of the channel is dropped; the thread then
//! disconnects from the master (which keeps its slaves for the next viewer)
//! and stops its system.

use super::cluster;
use anyhow::Context;
use isin_actors::client::HANDSHAKE_TIMEOUT;
use isin_actors::viewer::{
    self, Disconnect, GetSlaves, GetWireStats, RequestFrameAs, SlaveList, ViewerActor, ViewerEvent,
};
use isin_cluster::protocol::SceneInfo;
use isin_cluster::scheduler::Work;
use isin_tracer::SceneBundle;
use isin_transport::Ticket;
use isin_viewer::{ChannelSource, FrameRequest, SourceEvent, SourceFeed, SourceStatus, TileUpdate, Worker};
use std::collections::BTreeMap;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use tokio::sync::mpsc;

/// How often the bytes-received counter is refreshed between frames.
const WIRE_POLL: Duration = Duration::from_millis(250);

/// A viewer connected to a master; its source goes to the window.
pub struct Remote {
    /// The producing end, for reading the counters (e.g. `--print-frames`).
    pub feed: SourceFeed,
    /// What the master serves: the starting camera and settings.
    pub scene: SceneInfo,
    thread: JoinHandle<()>,
}

impl Remote {
    /// Connects to the master of `ticket` as viewer `name`, flying `own` (a
    /// scene of the user's, sent to the master unless it holds it) or the
    /// master's default scene; returns once the master has welcomed us, with
    /// the source to give the window.
    pub fn connect(
        ticket: Ticket,
        name: String,
        own: Option<(SceneInfo, SceneBundle)>,
    ) -> anyhow::Result<(Remote, ChannelSource)> {
        let addr = ticket.addr.clone();
        let (requests, request_rx) = mpsc::unbounded_channel::<FrameRequest>();
        let (source, feed) = isin_viewer::channel_source(move |r| {
            let _ = requests.send(r);
        });
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let thread_feed = feed.clone();
        let thread = std::thread::Builder::new()
            .name("isin-viewer-link".into())
            .spawn(move || {
                actix::System::new().block_on(async move {
                    let transport = match cluster::client_transport(&ticket) {
                        Ok(t) => t,
                        Err(e) => {
                            let _ = ready_tx.send(Err(e));
                            return;
                        }
                    };
                    let setup = viewer::Setup {
                        name: &name,
                        work: Work::Interactive,
                        scene: own.as_ref().map(|(_, b)| b),
                        job: None,
                    };
                    let connected = viewer::connect_with(transport.as_ref(), &ticket, setup).await;
                    let scene = match connected {
                        Ok(c) => match own.map(|(info, _)| info).or(c.default_scene.clone()) {
                            Some(scene) => Ok((c, scene)),
                            None => Err(anyhow::anyhow!(
                                "the master serves no scene of its own: name one (isin view SCENE --connect TICKET)"
                            )),
                        },
                        Err(e) => Err(anyhow::Error::new(e)),
                    };
                    let (connected, scene) = match scene {
                        Ok(v) => v,
                        Err(e) => {
                            let _ = ready_tx.send(Err(e));
                            return;
                        }
                    };
                    let (viewer, events) = (connected.addr, connected.events);
                    let _ = ready_tx.send(Ok(scene));
                    let link = Link {
                        viewer,
                        feed: thread_feed,
                        transport: ticket.transport.to_string(),
                        current: None,
                        tiles: BTreeMap::new(),
                    };
                    link.run(request_rx, events).await;
                    actix::System::current().stop();
                });
            })
            .context("cannot start the viewer's network thread")?;
        let scene = match ready_rx.recv_timeout(HANDSHAKE_TIMEOUT * 2) {
            Ok(Ok(scene)) => scene,
            Ok(Err(e)) => return Err(e.context(format!("cannot join the master at {addr}"))),
            Err(_) => anyhow::bail!("the master did not welcome the viewer in time"),
        };
        tracing::info!(scene = %scene.name, "viewer connected");
        Ok((Remote { feed, scene, thread }, source))
    }

    /// Waits for the network thread to finish (call after the window, and
    /// with it the source, is gone: that is what ends the link).
    pub fn finish(self) {
        if self.thread.join().is_err() {
            tracing::error!("the viewer's network thread panicked");
        }
    }
}

/// The network side of a [`Remote`].
struct Link {
    viewer: actix::Addr<ViewerActor>,
    feed: SourceFeed,
    transport: String,
    /// The latest request and when it was posted.
    current: Option<(u64, Instant)>,
    /// Tiles received per slave id, over the whole session.
    tiles: BTreeMap<u32, u64>,
}

/// The status line's counters from the master's slave list and the tiles
/// received per slave: every listed slave (live first, with 0 tiles if it sent
/// none yet), then any other slave that sent tiles (one since forgotten).
fn status_of(
    list: &SlaveList,
    tiles: &BTreeMap<u32, u64>,
    bytes_received: u64,
    transport: &str,
) -> SourceStatus {
    let owner = |id: u64| u32::try_from(id).unwrap_or(u32::MAX);
    let listed = list.slaves.as_deref().unwrap_or_default();
    let mut workers: Vec<Worker> = listed
        .iter()
        .map(|e| Worker { id: owner(e.id), name: e.name.clone(), threads: e.threads, alive: e.alive })
        .collect();
    workers.sort_by_key(|w| (!w.alive, w.id));
    let mut tiles_per_slave: Vec<(u32, u64)> =
        workers.iter().map(|w| (w.id, tiles.get(&w.id).copied().unwrap_or(0))).collect();
    for (&id, &n) in tiles {
        if !workers.iter().any(|w| w.id == id) {
            tiles_per_slave.push((id, n));
        }
    }
    SourceStatus {
        live_slaves: workers.iter().filter(|w| w.alive).count(),
        tiles_per_slave,
        bytes_received,
        transport: transport.to_string(),
        workers,
    }
}

impl Link {
    async fn run(
        mut self,
        mut requests: mpsc::UnboundedReceiver<FrameRequest>,
        mut events: mpsc::UnboundedReceiver<ViewerEvent>,
    ) {
        let mut poll = tokio::time::interval(WIRE_POLL);
        poll.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        self.update_status().await;
        loop {
            tokio::select! {
                r = requests.recv() => {
                    let Some(r) = r else { break }; // the window closed
                    self.current = Some((r.frame_id, Instant::now()));
                    self.viewer.do_send(RequestFrameAs {
                        request: r.frame_id,
                        camera: r.camera,
                        settings: r.settings,
                    });
                }
                ev = events.recv() => {
                    let Some(ev) = ev else {
                        self.feed.send(SourceEvent::Failed("the connection to the master closed".into()));
                        break;
                    };
                    if !self.on_event(ev).await {
                        break;
                    }
                }
                _ = poll.tick() => self.update_status().await,
            }
        }
        // Closes the connection: the master drops this viewer and keeps its slaves.
        let _ = self.viewer.send(Disconnect).await;
    }

    /// Handles one event of the viewer actor; false when the link is over.
    async fn on_event(&mut self, ev: ViewerEvent) -> bool {
        match ev {
            ViewerEvent::Tile { request, slave, tile, pixels, .. } => {
                let owner = u32::try_from(slave).unwrap_or(u32::MAX);
                *self.tiles.entry(owner).or_default() += 1;
                self.feed.send(SourceEvent::Tile(TileUpdate { frame_id: request, tile, rgb: pixels, owner }))
            }
            ViewerEvent::FrameDone { request, stats } => {
                let elapsed = match self.current {
                    Some((id, at)) if id == request => at.elapsed(),
                    _ => Duration::from_micros(stats.micros),
                };
                self.update_status().await;
                self.feed.send(SourceEvent::FrameComplete { frame_id: request, elapsed })
            }
            ViewerEvent::Error(message) => self.feed.send(SourceEvent::Failed(message)),
            // The status line shows the slave count; the terminal says why frames wait.
            ViewerEvent::Notice(message) => {
                tracing::warn!("master: {message}");
                true
            }
            ViewerEvent::Closed(message) => {
                self.feed.send(SourceEvent::Failed(message));
                false
            }
        }
    }

    async fn update_status(&self) {
        let bytes_received = match self.viewer.send(GetWireStats).await {
            Ok(wire) => wire.bytes_received,
            Err(_) => self.feed.status().bytes_received,
        };
        let list = self.viewer.send(GetSlaves).await.unwrap_or_default();
        self.feed.set_status(status_of(&list, &self.tiles, bytes_received, &self.transport));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use isin_cluster::protocol::SlaveEntry;

    fn entry(id: u64, alive: bool) -> SlaveEntry {
        SlaveEntry { id, name: format!("s#{id}"), addr: "127.0.0.1:1".into(), threads: 2, alive }
    }

    #[test]
    fn the_status_counts_the_masters_live_slaves_and_lists_each_with_its_tiles() {
        let list =
            SlaveList { version: 2, slaves: Some(vec![entry(7, false), entry(5, true), entry(3, true)]) };
        // Slave 5 has not sent a tile yet; 9 sent some but is no longer listed.
        let tiles = BTreeMap::from([(3, 40), (7, 12), (9, 1)]);
        let s = status_of(&list, &tiles, 1234, "tcp");
        assert_eq!(s.live_slaves, 2);
        assert_eq!(s.tiles_per_slave, [(3, 40), (5, 0), (7, 12), (9, 1)]);
        let ids: Vec<(u32, bool)> = s.workers.iter().map(|w| (w.id, w.alive)).collect();
        assert_eq!(ids, [(3, true), (5, true), (7, false)], "live first, then the dead");
        assert_eq!((s.bytes_received, s.transport.as_str()), (1234, "tcp"));
        // Before the master's list arrives: no live slaves claimed.
        let none = status_of(&SlaveList::default(), &tiles, 0, "quic");
        assert_eq!(none.live_slaves, 0);
        assert_eq!(none.tiles_per_slave.len(), 3);
    }
}

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
//! The status comes from what the master pushes (the slave list when a slave
//! joins or dies, and the connection's byte counters kept by the viewer
//! actor): nothing is asked of the master. When it lists no live slave, the
//! status carries the hint to start one (`isin slave --connect TICKET`).
//!
//! When the connection to the master is lost (a restart, a crash), the link
//! says "reconnecting…" ([`SourceEvent::Lost`]) and reconnects with capped
//! backoff ([`cluster::connect_client`], as slaves do), bringing its scene
//! again; once back it sends [`SourceEvent::Reconnected`], on which the window
//! clears its errors and asks for the current view again.
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
use isin_transport::{Ticket, Transport};
use isin_viewer::{ChannelSource, FrameRequest, SourceEvent, SourceFeed, SourceStatus, TileUpdate, Worker};
use std::collections::BTreeMap;
use std::sync::Arc;
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
    /// master's default scene, taking tiles straight from the slaves at
    /// `direct` if given; returns once the master has welcomed us, with the
    /// source to give the window.
    pub fn connect(
        ticket: Ticket,
        name: String,
        own: Option<(SceneInfo, SceneBundle)>,
        direct: Option<String>,
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
                    let (own_info, own) = own.map_or((None, None), |(info, bundle)| (Some(info), Some(bundle)));
                    let setup =
                        viewer::Setup { name: &name, work: Work::Interactive, scene: own.as_ref(), job: None };
                    let connected =
                        cluster::connect_once(transport.as_ref(), &ticket, setup, direct.as_deref()).await;
                    let scene = match connected {
                        Err(e) => Err(e),
                        Ok(Ok(c)) => match own_info.or(c.default_scene.clone()) {
                            Some(scene) => Ok((c, scene)),
                            None => Err(anyhow::anyhow!(
                                "the master serves no scene of its own: name one (isin view SCENE --connect TICKET)"
                            )),
                        },
                        Ok(Err(e)) => Err(anyhow::Error::new(e)),
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
                        transport_name: ticket.transport.to_string(),
                        hint: format!("no slaves: start one with `{}`", super::ticket::join_hint(&ticket)),
                        transport,
                        ticket,
                        name,
                        own,
                        direct,
                        current: None,
                        tiles: BTreeMap::new(),
                        told_waiting: false,
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
    /// The transport's name, for the status line.
    transport_name: String,
    /// What to say when the master has no slave.
    hint: String,
    /// What a reconnection needs: how, where, as whom and with which scene.
    transport: Arc<dyn Transport>,
    ticket: Ticket,
    name: String,
    own: Option<SceneBundle>,
    /// Where slaves deliver tiles straight, if they do.
    direct: Option<String>,
    /// The latest request and when it was posted.
    current: Option<(u64, Instant)>,
    /// Tiles received per slave id since the connection was made.
    tiles: BTreeMap<u32, u64>,
    /// The master said that frames wait for a slave to join.
    told_waiting: bool,
}

/// What ended a connection: the window closed, or the master went away.
enum Ended {
    WindowClosed,
    Lost(String),
}

/// The status line's counters from the master's slave list and the tiles
/// received per slave: every listed slave (live first, with 0 tiles if it sent
/// none yet), then any other slave that sent tiles (one since forgotten).
/// `hint` is the notice for a master that lists no live slave (or said
/// frames wait for one, before its list arrived).
fn status_of(
    list: &SlaveList,
    tiles: &BTreeMap<u32, u64>,
    bytes_received: u64,
    transport: &str,
    (hint, told_waiting): (&str, bool),
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
    let live_slaves = workers.iter().filter(|w| w.alive).count();
    let none = match &list.slaves {
        Some(_) => live_slaves == 0,
        None => told_waiting,
    };
    SourceStatus {
        live_slaves,
        tiles_per_slave,
        bytes_received,
        transport: transport.to_string(),
        workers,
        notice: none.then(|| hint.to_string()),
    }
}

impl Link {
    async fn run(
        mut self,
        mut requests: mpsc::UnboundedReceiver<FrameRequest>,
        mut events: mpsc::UnboundedReceiver<ViewerEvent>,
    ) {
        loop {
            match self.serve(&mut requests, &mut events).await {
                Ended::WindowClosed => break,
                Ended::Lost(why) => {
                    // The old master's slaves are not this one's: nothing is known until it is back.
                    self.feed.update_status(|s| {
                        *s = SourceStatus {
                            bytes_received: s.bytes_received,
                            transport: s.transport.clone(),
                            ..SourceStatus::default()
                        }
                    });
                    let addr = &self.ticket.addr;
                    self.feed
                        .send(SourceEvent::Lost(format!("lost the master at {addr} ({why}); reconnecting…")));
                    match self.reconnect(&mut requests).await {
                        Some(e) => {
                            events = e;
                            tracing::info!("reconnected to the master at {}", self.ticket.addr);
                            self.feed.send(SourceEvent::Reconnected);
                        }
                        None => return,
                    }
                }
            }
        }
        // Closes the connection: the master drops this viewer and keeps its slaves.
        let _ = self.viewer.send(Disconnect).await;
    }

    /// Relays one connection until it ends.
    async fn serve(
        &mut self,
        requests: &mut mpsc::UnboundedReceiver<FrameRequest>,
        events: &mut mpsc::UnboundedReceiver<ViewerEvent>,
    ) -> Ended {
        let mut poll = tokio::time::interval(WIRE_POLL);
        poll.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        self.update_status().await;
        loop {
            tokio::select! {
                r = requests.recv() => {
                    let Some(r) = r else { return Ended::WindowClosed };
                    self.current = Some((r.frame_id, Instant::now()));
                    self.viewer.do_send(RequestFrameAs {
                        request: r.frame_id,
                        camera: r.camera,
                        settings: r.settings,
                    });
                }
                ev = events.recv() => {
                    let Some(ev) = ev else { return Ended::Lost("the connection closed".into()) };
                    if let Some(end) = self.on_event(ev).await {
                        return end;
                    }
                }
                _ = poll.tick() => self.update_status().await,
            }
        }
    }

    /// Connects again, with capped backoff, until the master is back (the
    /// new connection's events), the window closes or the master refuses
    /// for good (`None` for both; a refusal is shown).
    async fn reconnect(
        &mut self,
        requests: &mut mpsc::UnboundedReceiver<FrameRequest>,
    ) -> Option<mpsc::UnboundedReceiver<ViewerEvent>> {
        let setup =
            viewer::Setup { name: &self.name, work: Work::Interactive, scene: self.own.as_ref(), job: None };
        let connected = {
            let direct = self.direct.as_deref();
            let connect = cluster::connect_client(self.transport.as_ref(), &self.ticket, setup, direct);
            tokio::pin!(connect);
            loop {
                tokio::select! {
                    c = &mut connect => break c,
                    // Requests meanwhile are dropped: the window asks again once back.
                    r = requests.recv() => {
                        r?; // the window closed
                    }
                }
            }
        };
        match connected {
            Ok(c) => {
                self.viewer = c.addr;
                // The restarted master numbers its slaves anew.
                self.tiles.clear();
                self.told_waiting = false;
                self.current = None;
                Some(c.events)
            }
            Err(e) => {
                self.feed.send(SourceEvent::Failed(format!("{e:#}")));
                None
            }
        }
    }

    /// Handles one event of the viewer actor; `Some` when the connection is over.
    async fn on_event(&mut self, ev: ViewerEvent) -> Option<Ended> {
        let open = match ev {
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
            // The window shows the hint (the status's notice) until a slave joins.
            ViewerEvent::Notice(message) => {
                tracing::warn!("master: {message}");
                self.told_waiting = true;
                self.update_status().await;
                true
            }
            ViewerEvent::Closed(message) => return Some(Ended::Lost(message)),
        };
        (!open).then_some(Ended::WindowClosed)
    }

    async fn update_status(&self) {
        let bytes_received = match self.viewer.send(GetWireStats).await {
            Ok(wire) => wire.bytes_received,
            Err(_) => self.feed.status().bytes_received,
        };
        let list = self.viewer.send(GetSlaves).await.unwrap_or_default();
        let hint = (self.hint.as_str(), self.told_waiting);
        self.feed.set_status(status_of(&list, &self.tiles, bytes_received, &self.transport_name, hint));
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
        let s = status_of(&list, &tiles, 1234, "tcp", ("start one", false));
        assert_eq!(s.live_slaves, 2);
        assert_eq!(s.tiles_per_slave, [(3, 40), (5, 0), (7, 12), (9, 1)]);
        let ids: Vec<(u32, bool)> = s.workers.iter().map(|w| (w.id, w.alive)).collect();
        assert_eq!(ids, [(3, true), (5, true), (7, false)], "live first, then the dead");
        assert_eq!((s.bytes_received, s.transport.as_str()), (1234, "tcp"));
        // Before the master's list arrives: no live slaves claimed.
        assert_eq!(s.notice, None, "no hint while slaves are live");
        let none = status_of(&SlaveList::default(), &tiles, 0, "quic", ("start one", false));
        assert_eq!(none.live_slaves, 0);
        assert_eq!(none.tiles_per_slave.len(), 3);
        assert_eq!(none.notice, None, "the list has not come yet: nothing known");
        let waiting = status_of(&SlaveList::default(), &tiles, 0, "quic", ("start one", true));
        assert_eq!(waiting.notice.as_deref(), Some("start one"), "the master said frames wait");
        // Every slave dead: the hint.
        let dead = SlaveList { version: 3, slaves: Some(vec![entry(7, false)]) };
        let s = status_of(&dead, &BTreeMap::new(), 0, "tcp", ("start one", false));
        assert_eq!((s.live_slaves, s.notice.as_deref()), (0, Some("start one")));
    }
}

//! A slave's links to viewers that take their tiles straight
//! ([`isin_cluster::protocol::DirectRoute`]).
//!
//! One link per viewer, dialled when the first assignment routed to it
//! comes (the master sends its offer once; it is kept by viewer id). A
//! render job delivers a tile over the link if it is up, else through the
//! master as usual; a delivered tile waits on the link until the viewer
//! acknowledges it (the viewer tells the master itself). When a link
//! breaks, or a viewer leaves a tile unacknowledged for [`ACK_TIMEOUT`],
//! what waits goes to the master in full: no tile is lost to a viewer that
//! went away or stalled (one that did arrive is then a second copy, which
//! the master drops). Waiting tiles are taken out under the lock by whoever
//! sends them on, so each goes on once.

use isin_cluster::protocol::{
    self, DirectOffer, DirectRoute, DirectTile, FrameId, FrameTile, Message, TileId, TileResult,
};
use isin_transport::{Delivery, FrameSender, Transport};
use std::collections::{BTreeMap, HashMap};
use std::fmt;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

/// How long a viewer may leave a delivered tile unacknowledged before the
/// slave gives up on the link and sends what waits through the master.
pub const ACK_TIMEOUT: Duration = Duration::from_secs(2);

/// How long after a link failed before it is dialled again.
pub const REDIAL_AFTER: Duration = Duration::from_secs(1);

/// Most tiles that may wait for acknowledgement on one link; beyond it tiles
/// go through the master.
const MAX_PENDING: usize = 4096;

/// Viewers whose offers (and links) a slave keeps; the oldest go first (a
/// viewer whose offer was dropped gets its tiles through the master).
const MAX_VIEWERS: usize = 256;

/// Makes the transport a slave reaches a viewer's offer with: TLS pinning
/// the offer's fingerprint (its text, as a ticket writes it), or plaintext
/// for an offer without one from a master that speaks plaintext.
#[derive(Clone)]
pub struct Dialer(Arc<MakeTransport>);

/// What a [`Dialer`] calls: the offer's fingerprint in, a transport out.
type MakeTransport = dyn Fn(Option<&str>) -> Result<Arc<dyn Transport>, String> + Send + Sync;

impl Dialer {
    /// A dialer around `make`.
    pub fn new(
        make: impl Fn(Option<&str>) -> Result<Arc<dyn Transport>, String> + Send + Sync + 'static,
    ) -> Self {
        Self(Arc::new(make))
    }
}

impl fmt::Debug for Dialer {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Dialer")
    }
}

/// Sends a full tile result to the master (tiles may overtake each other).
pub(crate) fn send_result(master: &FrameSender, r: TileResult) -> bool {
    match protocol::encode(&Message::TileResult(r)) {
        Ok(bytes) => master.send_as(bytes, Delivery::Independent).is_ok(),
        Err(e) => {
            tracing::error!("cannot encode tile: {e}");
            false
        }
    }
}

/// A viewer, by its id at the master.
type Key = u64;

enum State {
    Dialling,
    Up(Arc<Up>),
    Down(Instant),
}

struct Pending {
    at: Instant,
    tile: TileResult,
}

#[derive(Default)]
struct Waiting {
    /// Set once the link is given up: nothing more is added.
    closed: bool,
    tiles: HashMap<(FrameId, TileId), Pending>,
}

struct Up {
    sender: FrameSender,
    waiting: Mutex<Waiting>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

impl Up {
    /// Gives the link up: it closes, and what waits goes to the master.
    fn give_up(&self, master: &FrameSender) -> usize {
        self.sender.close();
        let tiles: Vec<Pending> = {
            let mut w = lock(&self.waiting);
            w.closed = true;
            w.tiles.drain().map(|(_, p)| p).collect()
        };
        let n = tiles.len();
        for p in tiles {
            send_result(master, p.tile);
        }
        n
    }
}

/// A slave's links to viewers (see the [module docs](self)).
pub(crate) struct Links {
    dialer: Option<Dialer>,
    master: FrameSender,
    slave: u64,
    slave_name: String,
    /// Viewers' offers, as the master sent them.
    offers: Mutex<BTreeMap<Key, DirectOffer>>,
    links: Mutex<HashMap<Key, State>>,
}

impl Links {
    /// No links yet; `dialer` `None`: every tile goes through the master.
    pub fn new(dialer: Option<Dialer>, master: FrameSender, slave: u64, slave_name: String) -> Arc<Self> {
        Arc::new(Self {
            dialer,
            master,
            slave,
            slave_name,
            offers: Mutex::default(),
            links: Mutex::default(),
        })
    }

    /// Dials `route`'s viewer unless a link to it is up or being dialled
    /// (or failed less than [`REDIAL_AFTER`] ago). Call from the runtime.
    pub fn prepare(self: &Arc<Self>, route: &DirectRoute) {
        let Some(dialer) = self.dialer.clone() else { return };
        let key = route.viewer;
        let offer = {
            let mut offers = lock(&self.offers);
            if let Some(o) = &route.offer {
                offers.insert(key, o.clone());
                while offers.len() > MAX_VIEWERS {
                    if let Some((old, _)) = offers.pop_first() {
                        lock(&self.links).remove(&old);
                    }
                }
            }
            offers.get(&key).cloned()
        };
        let Some(offer) = offer else { return };
        {
            let mut links = lock(&self.links);
            match links.get(&key) {
                Some(State::Dialling | State::Up(_)) => return,
                Some(State::Down(at)) if at.elapsed() < REDIAL_AFTER => return,
                _ => {}
            }
            links.insert(key, State::Dialling);
        }
        let me = self.clone();
        tokio::spawn(async move {
            match me.dial(&dialer, &offer).await {
                Ok(conn) => me.run(key, conn).await,
                Err(e) => {
                    tracing::warn!(
                        "cannot reach the viewer at {}: {e}; its tiles go through the master",
                        offer.addr
                    );
                    lock(&me.links).insert(key, State::Down(Instant::now()));
                }
            }
        });
    }

    async fn dial(&self, dialer: &Dialer, offer: &DirectOffer) -> Result<isin_transport::Connection, String> {
        let transport = (dialer.0)(offer.fingerprint.as_deref())?;
        let conn = tokio::time::timeout(crate::client::HANDSHAKE_TIMEOUT, transport.connect(&offer.addr))
            .await
            .map_err(|_| format!("no answer within {:?}", crate::client::HANDSHAKE_TIMEOUT))?
            .map_err(|e| e.to_string())?;
        let hello = protocol::encode(&Message::DirectHello { key: offer.key, slave: self.slave })
            .map_err(|e| e.to_string())?;
        conn.sender.send(hello).map_err(|e| e.to_string())?;
        tracing::info!("delivering tiles straight to the viewer at {}", offer.addr);
        Ok(conn)
    }

    /// Serves an established link: acknowledged tiles stop waiting; when it
    /// ends, what waits goes to the master.
    async fn run(self: Arc<Self>, key: Key, conn: isin_transport::Connection) {
        let isin_transport::Connection { sender, mut receiver, .. } = conn;
        let up = Arc::new(Up { sender, waiting: Mutex::default() });
        lock(&self.links).insert(key, State::Up(up.clone()));
        while let Some(Ok(frame)) = receiver.recv().await {
            match protocol::decode(&frame, protocol::HANDSHAKE_MAX_FRAME) {
                Ok(Message::DirectAck { frame, id }) => self.acknowledged(&up, frame, id),
                Ok(Message::Heartbeat) => {}
                Ok(other) => {
                    tracing::warn!("viewer #{key} sent {}; link closed", other.kind());
                    break;
                }
                Err(e) => {
                    tracing::warn!("bad frame from viewer #{key}: {e}; link closed");
                    break;
                }
            }
        }
        let mut links = lock(&self.links);
        if matches!(links.get(&key), Some(State::Up(u)) if Arc::ptr_eq(u, &up)) {
            links.insert(key, State::Down(Instant::now()));
        }
        drop(links);
        let n = up.give_up(&self.master);
        if n > 0 {
            tracing::info!("{n} tiles the viewer did not acknowledge go through the master");
        }
    }

    fn acknowledged(&self, up: &Up, frame: FrameId, id: TileId) {
        lock(&up.waiting).tiles.remove(&(frame, id));
    }

    /// Delivers a tile of `route`'s frame to its viewer if the link is up;
    /// otherwise (or if it is a tile the master wants itself) sends it to
    /// the master. Runs on render threads.
    pub fn deliver(&self, route: &DirectRoute, t: TileResult) {
        let up = match lock(&self.links).get(&route.viewer) {
            Some(State::Up(up)) if !route.via_master.contains(&t.id) => up.clone(),
            _ => {
                send_result(&self.master, t);
                return;
            }
        };
        let msg = Message::DirectTile(DirectTile {
            frame: t.frame,
            id: t.id,
            tile: FrameTile {
                request: route.request,
                slave: self.slave,
                slave_name: self.slave_name.clone(),
                tile: t.tile,
                codec: t.codec,
                pixels: t.pixels.clone(),
            },
            render_micros: t.render_micros,
        });
        let Ok(bytes) = protocol::encode(&msg) else {
            send_result(&self.master, t);
            return;
        };
        let key = (t.frame, t.id);
        {
            let mut w = lock(&up.waiting);
            if w.closed || w.tiles.len() >= MAX_PENDING {
                drop(w);
                send_result(&self.master, t);
                return;
            }
            w.tiles.insert(key, Pending { at: Instant::now(), tile: t });
        }
        if up.sender.send_as(bytes, Delivery::Independent).is_err() {
            // Whoever takes it out sends it on: here, or the link's end.
            let back = lock(&up.waiting).tiles.remove(&key);
            if let Some(p) = back {
                send_result(&self.master, p.tile);
            }
        }
    }

    /// Gives up links whose viewer left a tile unacknowledged for
    /// [`ACK_TIMEOUT`] (their tiles go to the master). Call now and then.
    pub fn expire(&self) {
        let stalled: Vec<(Key, Arc<Up>)> = lock(&self.links)
            .iter()
            .filter_map(|(&k, s)| match s {
                State::Up(up) if lock(&up.waiting).tiles.values().any(|p| p.at.elapsed() > ACK_TIMEOUT) => {
                    Some((k, up.clone()))
                }
                _ => None,
            })
            .collect();
        for (key, up) in stalled {
            lock(&self.links).insert(key, State::Down(Instant::now()));
            let n = up.give_up(&self.master);
            tracing::warn!("viewer #{key} left {n} tiles unacknowledged; they go through the master");
        }
    }

    /// Closes every link (the session ended); what waits goes to the
    /// master, if it is still there.
    pub fn close(&self) {
        let ups: Vec<Arc<Up>> = lock(&self.links)
            .drain()
            .filter_map(|(_, s)| match s {
                State::Up(up) => Some(up),
                _ => None,
            })
            .collect();
        for up in ups {
            up.give_up(&self.master);
        }
    }
}

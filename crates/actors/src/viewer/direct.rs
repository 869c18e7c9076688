//! A viewer's end of tiles that skip the master: it listens, lets in slaves
//! that show the key it gave the master, and acknowledges each tile once the
//! actor has passed it on (see [`isin_cluster::protocol::DirectRoute`] for the
//! whole exchange).

use super::{DirectIn, ViewerActor};
use actix::Addr;
use isin_cluster::auth;
use isin_cluster::limits::{self, TILE};
use isin_cluster::protocol::{self, DirectOffer, HANDSHAKE_MAX_FRAME, MAX_DIRECT_ADDR, Message};
use isin_transport::{Connection, Fingerprint, Listener, MemoryBudget, Transport, TransportError};
use std::time::Duration;

/// How long a slave has to show the key once connected.
const HELLO_TIMEOUT: Duration = Duration::from_secs(10);

/// Bytes all direct links together may hold in frames being read.
const LINKS_BUDGET: usize = 256 << 20;

/// Where a viewer listens for slaves, and the offer that tells the master.
pub struct DirectListener {
    listener: Box<dyn Listener>,
    offer: DirectOffer,
}

impl DirectListener {
    /// Listens on `addr` (`HOST:PORT`, port 0 for any), which slaves must
    /// be able to reach as it is written: a wildcard address (`0.0.0.0`,
    /// `[::]`) is refused. `fingerprint` is that of the certificate
    /// `transport` presents (`None` for plaintext).
    pub async fn bind(
        transport: &dyn Transport,
        addr: &str,
        fingerprint: Option<Fingerprint>,
    ) -> Result<Self, TransportError> {
        let refuse = |reason: &str| TransportError::Listen { addr: addr.to_string(), reason: reason.into() };
        let ip = addr.rsplit_once(':').map_or(addr, |(host, _)| host).trim_matches(['[', ']']);
        if ip.parse::<std::net::IpAddr>().is_ok_and(|ip| ip.is_unspecified()) {
            return Err(refuse("slaves dial this address: name one they can reach, not a wildcard"));
        }
        let mut listener = transport.listen(addr).await?;
        listener.set_budget(MemoryBudget::new(LINKS_BUDGET));
        let local = listener.local_addr();
        // A host name stays as given (the port is the one bound).
        let advertised = match local.rsplit_once(':') {
            Some((_, port)) if ip.parse::<std::net::IpAddr>().is_err() => format!("{ip}:{port}"),
            _ => local,
        };
        if advertised.len() > MAX_DIRECT_ADDR {
            return Err(refuse("address too long"));
        }
        let key = auth::random_bytes::<32>().map_err(|e| refuse(&e.to_string()))?;
        let offer = DirectOffer { addr: advertised, fingerprint: fingerprint.map(|f| f.to_string()), key };
        Ok(Self { listener, offer })
    }

    /// What the master is told.
    pub fn offer(&self) -> &DirectOffer {
        &self.offer
    }

    /// Accepts slaves for `viewer` until it stops.
    pub(crate) fn serve(self, viewer: Addr<ViewerActor>) {
        let Self { mut listener, offer } = self;
        tokio::spawn(async move {
            loop {
                let conn = tokio::select! {
                    c = listener.accept() => c,
                    _ = closed(&viewer) => return,
                };
                match conn {
                    Ok(conn) => {
                        tokio::spawn(link(conn, offer.key, viewer.clone()));
                    }
                    Err(e) => tracing::debug!("direct link not accepted: {e}"),
                }
            }
        });
    }
}

/// Resolves once the viewer actor has stopped.
async fn closed(viewer: &Addr<ViewerActor>) {
    while viewer.connected() {
        tokio::time::sleep(Duration::from_millis(250)).await;
    }
}

/// One slave's link: its key first, then tiles, each acknowledged once the
/// actor took it.
async fn link(mut conn: Connection, key: [u8; 32], viewer: Addr<ViewerActor>) {
    let first = tokio::time::timeout(HELLO_TIMEOUT, conn.receiver.recv()).await;
    let slave = match first {
        Ok(Some(Ok(f))) => match protocol::decode(&f, HANDSHAKE_MAX_FRAME) {
            Ok(Message::DirectHello { key: k, slave }) if auth::proofs_match(&k, &key) => slave,
            _ => return conn.sender.close(),
        },
        _ => return conn.sender.close(),
    };
    let max = limits::slave_max_frame(TILE.max as u32);
    conn.sender.set_max_frame(max);
    while let Some(Ok(frame)) = conn.receiver.recv().await {
        let tile = match protocol::decode(&frame, max) {
            Ok(Message::DirectTile(t)) if t.tile.slave == slave => t,
            Ok(Message::Heartbeat) => continue,
            _ => break,
        };
        let (frame, id) = (tile.frame, tile.id);
        match viewer.send(DirectIn(tile)).await {
            Ok(true) => {}
            Ok(false) => {
                tracing::warn!(
                    "slave {slave} sent a tile that is no part of this viewer's frames; link closed"
                );
                break;
            }
            Err(_) => break,
        }
        let Ok(ack) = protocol::encode(&Message::DirectAck { frame, id }) else { break };
        if conn.sender.send(ack).is_err() {
            break;
        }
    }
    conn.sender.close();
}

//! What QUIC really put on the wire: UDP bytes and datagrams, losses and
//! congestion events, summed over every connection a [`crate::QuicTransport`]
//! made or accepted (closed ones included). The interface's per-connection
//! counters count frames and their framing; these count packets, headers,
//! encryption overhead, acknowledgements and retransmissions too, so the two
//! can be cross-checked.

use std::collections::HashMap;
use std::sync::Mutex;

/// Totals of QUIC's own counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WireStats {
    /// Connections counted.
    pub connections: u64,
    /// UDP payload bytes sent.
    pub udp_tx_bytes: u64,
    /// UDP payload bytes received.
    pub udp_rx_bytes: u64,
    /// Datagrams sent.
    pub tx_datagrams: u64,
    /// Datagrams received.
    pub rx_datagrams: u64,
    /// Packets declared lost (and retransmitted if they carried data).
    pub lost_packets: u64,
    /// Bytes in the packets declared lost.
    pub lost_bytes: u64,
    /// Times the congestion controller backed off.
    pub congestion_events: u64,
    /// ACK frames sent.
    pub acks_sent: u64,
    /// ACK_FREQUENCY frames sent (our request for a shorter ACK delay).
    pub ack_frequency_sent: u64,
}

impl WireStats {
    fn add(&mut self, s: &quinn::ConnectionStats) {
        self.connections += 1;
        self.udp_tx_bytes += s.udp_tx.bytes;
        self.udp_rx_bytes += s.udp_rx.bytes;
        self.tx_datagrams += s.udp_tx.datagrams;
        self.rx_datagrams += s.udp_rx.datagrams;
        self.lost_packets += s.path.lost_packets;
        self.lost_bytes += s.path.lost_bytes;
        self.congestion_events += s.path.congestion_events;
        self.acks_sent += s.frame_tx.acks;
        self.ack_frequency_sent += s.frame_tx.ack_frequency;
    }
}

/// Live connections and the totals of the closed ones.
#[derive(Debug, Default)]
pub(crate) struct Registry {
    inner: Mutex<RegistryInner>,
}

#[derive(Debug, Default)]
struct RegistryInner {
    live: HashMap<usize, quinn::Connection>,
    closed: WireStats,
}

impl Registry {
    /// Starts counting `conn`.
    pub(crate) fn add(&self, conn: &quinn::Connection) {
        if let Ok(mut r) = self.inner.lock() {
            r.live.insert(conn.stable_id(), conn.clone());
        }
    }

    /// Moves `conn`'s final counters into the closed totals.
    pub(crate) fn remove(&self, conn: &quinn::Connection) {
        if let Ok(mut r) = self.inner.lock()
            && r.live.remove(&conn.stable_id()).is_some()
        {
            r.closed.add(&conn.stats());
        }
    }

    /// Closed totals plus the live connections' current counters.
    pub(crate) fn snapshot(&self) -> WireStats {
        let Ok(r) = self.inner.lock() else { return WireStats::default() };
        let mut total = r.closed;
        for c in r.live.values() {
            total.add(&c.stats());
        }
        total
    }
}

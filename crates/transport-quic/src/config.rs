//! QUIC tuning for tile traffic, and the UDP sockets under it.
//!
//! The numbers come from measurements on this project's machines (see the
//! crate docs): explicit 4 MiB socket buffers (the kernel's default 208 KiB
//! overflowed at high tile rates, and quinn took the drops for congestion), a
//! keep-alive and idle timeout short enough that a dead peer is noticed within
//! seconds, and a small requested ACK delay so a lost tail packet is probed
//! after a few milliseconds instead of 25 ms plus.

use quinn::{AckFrequencyConfig, IdleTimeout, TransportConfig, VarInt};
use socket2::{Domain, Protocol, Socket, Type};
use std::net::SocketAddr;
use std::time::Duration;

/// Tunable settings of a [`crate::QuicTransport`].
#[derive(Clone, Debug)]
pub struct QuicOptions {
    /// How often an otherwise idle connection sends a keep-alive.
    pub keep_alive: Duration,
    /// A connection that hears nothing for this long is closed (both sides'
    /// values are negotiated down to the smaller).
    pub idle_timeout: Duration,
    /// Requested UDP socket send and receive buffer size, bytes.
    pub socket_buffer: usize,
    /// ACK delay requested from the peer (ACK-frequency extension; quinn on
    /// both sides). `None` keeps the protocol default of 25 ms.
    pub max_ack_delay: Option<Duration>,
    /// Frame streams the peer may have open at once (tiles in flight).
    pub max_concurrent_streams: u32,
    /// Receive window of each stream, bytes (a tile is 12–100 KB).
    pub stream_window: u32,
    /// Receive window of the whole connection, bytes: what a peer can make
    /// this side buffer before it reads (quinn's default is unlimited, so a
    /// peer that has not even authenticated could fill every stream's window).
    pub connection_window: u32,
    /// Send buffer of the whole connection, bytes.
    pub send_window: u64,
    /// How long a graceful close may wait for the peer to acknowledge what was
    /// sent before the connection is closed anyway.
    pub linger: Duration,
    /// How long the server waits for a new connection's TLS handshake and
    /// control stream.
    pub handshake_timeout: Duration,
    /// Send every frame on the one control stream, in send order, whatever
    /// [`Delivery`](isin_transport::Delivery) its sender asked for: TCP-like
    /// delivery over QUIC, to measure what a stream per tile costs or gains.
    /// Only this side's sending is affected; the peer reads either way.
    pub single_stream: bool,
}

impl Default for QuicOptions {
    fn default() -> Self {
        Self {
            keep_alive: Duration::from_secs(1),
            idle_timeout: Duration::from_secs(3),
            socket_buffer: 4 << 20,
            max_ack_delay: Some(Duration::from_millis(5)),
            max_concurrent_streams: 256,
            stream_window: 2 << 20,
            connection_window: 32 << 20,
            send_window: 32 << 20,
            linger: Duration::from_secs(5),
            handshake_timeout: Duration::from_secs(10),
            single_stream: false,
        }
    }
}

impl QuicOptions {
    /// The quinn transport configuration these options describe.
    pub fn transport_config(&self) -> TransportConfig {
        let mut t = TransportConfig::default();
        t.keep_alive_interval(Some(self.keep_alive));
        // Larger than the VarInt range only if absurd; fall back to no timeout rather than panic.
        t.max_idle_timeout(IdleTimeout::try_from(self.idle_timeout).ok());
        // One bidirectional control stream, opened by the client.
        t.max_concurrent_bidi_streams(VarInt::from_u32(1));
        t.max_concurrent_uni_streams(VarInt::from_u32(self.max_concurrent_streams));
        t.stream_receive_window(VarInt::from_u32(self.stream_window));
        t.receive_window(VarInt::from_u32(self.connection_window.max(self.stream_window)));
        t.send_window(self.send_window);
        if let Some(delay) = self.max_ack_delay {
            let mut ack = AckFrequencyConfig::default();
            ack.max_ack_delay(Some(delay));
            t.ack_frequency_config(Some(ack));
        }
        t
    }
}

/// A UDP socket bound to `addr` with the requested buffer sizes (what the
/// kernel grants is logged; Linux caps it at `net.core.{r,w}mem_max`).
pub fn bind_udp(addr: SocketAddr, buffer: usize) -> std::io::Result<std::net::UdpSocket> {
    let sock = Socket::new(Domain::for_address(addr), Type::DGRAM, Some(Protocol::UDP))?;
    if addr.is_ipv6() && addr.ip().is_unspecified() {
        // Dual-stack where the platform allows it; not fatal where it does not.
        let _ = sock.set_only_v6(false);
    }
    if let Err(e) = sock.set_recv_buffer_size(buffer) {
        tracing::warn!("cannot set the UDP receive buffer to {buffer} bytes: {e}");
    }
    if let Err(e) = sock.set_send_buffer_size(buffer) {
        tracing::warn!("cannot set the UDP send buffer to {buffer} bytes: {e}");
    }
    // Linux reports twice the usable size it granted.
    let (rcv, snd) = (sock.recv_buffer_size().unwrap_or(0), sock.send_buffer_size().unwrap_or(0));
    if rcv < buffer || snd < buffer {
        tracing::warn!(
            rcv,
            snd,
            "UDP socket buffers smaller than the {buffer} bytes asked for (raise net.core.rmem_max/wmem_max)"
        );
    } else {
        tracing::debug!(rcv, snd, "UDP socket buffers");
    }
    sock.bind(&addr.into())?;
    Ok(sock.into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sockets_get_the_buffers_asked_for_where_the_kernel_allows() {
        let s = bind_udp("127.0.0.1:0".parse().unwrap(), 4 << 20).unwrap();
        let s = Socket::from(s);
        let max = std::fs::read_to_string("/proc/sys/net/core/rmem_max")
            .ok()
            .and_then(|t| t.trim().parse::<usize>().ok());
        match max {
            // Linux doubles the request (bookkeeping) up to twice the cap.
            Some(max) => assert!(s.recv_buffer_size().unwrap() >= (4 << 20).min(max)),
            None => println!("skipping the size check: no /proc/sys/net/core/rmem_max"),
        }
    }

    #[test]
    fn default_options_make_a_valid_transport_config() {
        let t = QuicOptions::default().transport_config();
        let text = format!("{t:?}");
        assert!(text.contains("keep_alive_interval: Some(1s)"), "{text}");
    }
}

//! # isin-actors — master, slaves and viewer
//!
//! The cluster: actix actors Master, Slave and Viewer exchanging FrameRequest /
//! TileResult messages (serde + rmp-serde), with heartbeats, hot-join and
//! reassignment of lost tiles. The decisions — which tile goes to whom, who is
//! dead — live in a plain state machine driven by explicit time, so tests run it
//! without sockets or clocks; the actors are thin shells around it.
//!
//! The decisions themselves — the protocol, codecs, authentication and the
//! scheduler — live in `isin-cluster`, which does no I/O; connections come
//! through the interface of `isin-transport` (TCP in `isin-transport-tcp`,
//! QUIC in `isin-transport-quic`).
//!
//! Modules: [`master`], [`slave`], [`viewer`]: the actors; [`client`]: the peer
//! side of the handshake that slaves and viewers share; [`state`]: the
//! master's state directory.
//!
//! Data flow: a viewer sends `FrameRequest`; the master's scheduler cuts the
//! frame into tiles and keeps every slave's window full with `TileAssignment`s;
//! slaves render on their own thread pools and stream `TileResult`s back; the
//! master forwards the first result for each tile to the viewer as a `FrameTile`
//! and ends with `FrameDone`.

pub mod client;
pub mod master;
pub mod slave;
pub mod state;
pub mod viewer;

// A fresh connection must carry the handshake, and no more.
const _: () = assert!(isin_transport::INITIAL_MAX_FRAME == isin_cluster::protocol::HANDSHAKE_MAX_FRAME);

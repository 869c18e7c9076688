//! # isin-actors — master, slaves and viewer
//!
//! The cluster: actix actors Master, Slave and Viewer exchanging FrameRequest /
//! TileResult messages (serde + rmp-serde), with heartbeats, hot-join and
//! reassignment of lost tiles. The decisions — which tile goes to whom, who is
//! dead — live in a plain state machine driven by explicit time, so tests run it
//! without sockets or clocks; the actors are thin shells around it.
//!
//! Modules:
//! - [`protocol`]: every message, the versioned wire encoding, scene hashes.
//! - [`auth`]: HMAC-SHA256 challenge–response over the shared token (never sent),
//!   join tickets (`isin://TOKEN@HOST:PORT?fp=CERT-SHA256`).
//! - [`codec`]: tile compression (QOI, LZ4, raw), negotiated at join; bounded,
//!   panic-free decoding of untrusted tiles.
//! - [`scheduler`]: the pure scheduling core (`handle_*` / `poll_*`, time as an argument).
//! - [`transport`]: the interface a transport implements — a connection is a pair
//!   of frame channels with byte counters — plus the length-delimited stream codec
//!   and an in-memory transport for tests. TCP (TLS or plaintext) lives in `isin-transport-tcp`,
//!   QUIC in `isin-transport-quic`.
//! - [`master`], [`slave`], [`viewer`]: the actors; [`client`]: the peer side of
//!   the handshake that slaves and viewers share.
//!
//! Data flow: a viewer sends `FrameRequest`; the master's scheduler cuts the
//! frame into tiles and keeps every slave's window full with `TileAssignment`s;
//! slaves render on their own thread pools and stream `TileResult`s back; the
//! master forwards the first result for each tile to the viewer as a `FrameTile`
//! and ends with `FrameDone`.

pub mod auth;
pub mod client;
pub mod codec;
pub mod master;
pub mod protocol;
pub mod scheduler;
pub mod slave;
pub mod transport;
pub mod viewer;

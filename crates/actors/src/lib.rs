//! # isin-actors — master, slaves and viewer
//!
//! The cluster: actix actors Master, Slave and Viewer exchanging FrameRequest /
//! TileResult messages (serde + rmp-serde), with heartbeats, hot-join and
//! reassignment of lost tiles. The decisions — which tile goes to whom, who is
//! dead — live in a plain state machine driven by explicit time, so tests run it
//! without sockets or clocks; the actors are thin shells around it.
//!
//! Modules: [`protocol`] (messages and their versioned encoding), [`auth`]
//! (challenge–response over the shared token, join tickets), [`scheduler`]
//! (the pure scheduling core), [`transport`] (the interface a transport
//! implements: connections as a pair of frame channels), and the actors.

pub mod auth;
pub mod client;
pub mod master;
pub mod protocol;
pub mod scheduler;
pub mod slave;
pub mod transport;
pub mod viewer;

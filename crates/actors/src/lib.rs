//! # isin-actors — master, slaves and viewer
//!
//! The cluster: actix actors Master, Slave and Viewer exchanging FrameRequest /
//! TileResult messages (serde + rmp-serde), with heartbeats, hot-join and
//! reassignment of lost tiles. The decisions — which tile goes to whom, who is
//! dead — live in a plain state machine driven by explicit time, so tests run it
//! without sockets or clocks; the actors are thin shells around it.

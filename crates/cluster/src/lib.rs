//! # isin-cluster — the cluster's decisions, with no I/O
//!
//! Everything the master decides, as plain state machines driven from
//! outside (quinn-proto's shape): inputs are `handle_*` calls with the time as
//! an argument, outputs are polled. Nothing here touches a socket, a file, a
//! clock or an async runtime — `Cargo.toml` has none of them — so tests drive
//! whole clusters of simulated peers on a virtual clock.
//!
//! Modules:
//! - [`protocol`]: every message, the versioned wire encoding, scene hashes.
//! - [`auth`]: HMAC-SHA256 challenge–response over the shared token (never
//!   sent); the join tickets carrying the token are `isin_transport::ticket`.
//! - [`codec`]: tile compression (QOI, LZ4, raw), negotiated at join; bounded,
//!   panic-free decoding of untrusted tiles.
//! - [`scheduler`]: which tile goes to which slave, who is dead.
//! - [`cluster`]: the whole master — peers, handshakes, liveness, frames, the
//!   roster — as one state machine around the scheduler; its docs say what it
//!   decides, what it trusts and what each budget is.
//! - [`limits`]: the bounds of a frame request and the budgets of peers.
//! - [`scene_stream`]: scenes packed (zstd, chunks) for slaves and unpacked
//!   as their chunks arrive, every size checked first.
pub mod auth;
pub mod cluster;
pub mod codec;
pub mod limits;
pub mod protocol;
pub mod scene_stream;
pub mod scheduler;
#[cfg(test)]
mod testing;

pub use cluster::{
    Class, Cluster, ClusterConfig, ClusterStatus, DefaultScene, JobRecord, PeerId, ROSTER_INTERVAL,
    STATUS_INTERVAL, Stored, Transmit,
};

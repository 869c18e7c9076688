//! # isin-transport-quic — the cluster transport over QUIC
//!
//! The same transport interface as TCP, on quinn, with each tile on its own
//! stream so one lost packet delays one tile, not all of them.

//! # isin-transport-tcp — the cluster transport over TCP
//!
//! Length-delimited frames over tokio TCP streams, implementing the transport
//! interface the actors use.

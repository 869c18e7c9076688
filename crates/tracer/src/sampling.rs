//! Deterministic random numbers: every sample is a hash of (pixel, sample
//! index, dimension, seed), never thread state.
//!
//! OWNER: shading helper.

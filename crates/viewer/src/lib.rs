//! # isin-viewer — the interactive window
//!
//! A winit + softbuffer window that shows frames as their tiles arrive and turns
//! keyboard and mouse input into camera moves.

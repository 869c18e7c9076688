//! # isin-viewer — the interactive window
//!
//! A winit + softbuffer window that shows frames as their tiles arrive and turns
//! keyboard and mouse input into camera moves, as in the paper: rotate the image
//! plane about the eye, move it along its normal, plus strafing and mouse-drag
//! look ([`input`]).
//!
//! The pieces, from the window inwards:
//!
//! - [`window`]: the winit 0.30 event loop and the softbuffer surface. Draws the
//!   image scaled to the window, the tile-ownership overlay and the status text
//!   ([`raster`]); saves screenshots; quits on Escape.
//! - [`session`]: everything the viewer does without a window — cameras, frame
//!   requests, progressive refinement of a still view, status counters,
//!   camera-path recording. Unit-tested with a fake source.
//! - [`accumulate`]: the displayed image; tiles land in it, passes of one view
//!   are averaged in linear light, a new view paints over the old one.
//! - [`source`]: the [`FrameSource`] interface between the window and whatever
//!   renders — always a cluster (`isin view SCENE` starts one in-process);
//!   [`ChannelSource`] ([`channel`]) is fed from another thread — the adapter
//!   for the cluster's viewer actor. The viewer renders nothing itself: it
//!   uses the tracer's camera, settings and tile types only.
//! - [`path`]: camera paths — recorded by `isin view --record` or keyframed, replayed by
//!   `isin fly` (headless) and `isin view --play` (in the window, measuring
//!   motion-to-photon latency); [`stats`] summarises the timings.
//!
//! - [`resolution`]: dynamic resolution while moving — a [`Divisor`] for the
//!   moving passes chosen from measured pass times to hold a target frame rate.
//!
//! The window renders at its own size (times a scale; again after a resize);
//! while the camera moves, passes are fast (1 sample, 1 shadow ray) and as
//! small as needed to hold `--target-fps`; when it stops, a fast pass at full
//! resolution sharpens the image, then passes with new seeds are averaged in
//! until [`Quality::max_spp`] — see [`session`].

pub mod accumulate;
pub mod channel;
pub mod error;
pub mod input;
pub mod path;
pub mod raster;
pub mod resolution;
pub mod session;
pub mod source;
pub mod stats;
pub mod window;

pub use channel::{ChannelSource, SourceFeed, channel_source};
pub use error::ViewerError;
pub use input::{Command, Controls, Move};
pub use path::{CameraPath, PathFrame, Recorder, Sampling};
pub use resolution::{Divisor, MovingResolution};
pub use session::{FrameReport, PassKind, Quality, Session, SessionConfig};
pub use source::{FrameId, FrameRequest, FrameSource, SourceEvent, SourceStatus, TileUpdate, Waker, Worker};
pub use window::{ScreenshotFormat, ViewerEvent, ViewerOptions, check_display, run, save_screenshot};

//! [`ChannelSource`]: a [`FrameSource`] fed from another thread, the
//! ready-made adapter for sources whose work happens elsewhere (the cluster's
//! viewer actor, a test harness).
//!
//! The window side holds the [`ChannelSource`]; the producing side holds a
//! [`SourceFeed`], which can be cloned and sent to any thread:
//!
//! ```
//! use isin_viewer::{FrameSource, SourceEvent, SourceStatus, channel_source};
//! use std::time::Duration;
//!
//! // Every request is forwarded (here: straight into a std channel).
//! let (requests, asked) = std::sync::mpsc::channel();
//! let (mut source, feed) = channel_source(move |r| {
//!     let _ = requests.send(r);
//! });
//! // … on the producing thread, answer with events and counters:
//! feed.send(SourceEvent::FrameComplete { frame_id: 1, elapsed: Duration::ZERO });
//! feed.set_status(SourceStatus { live_slaves: 3, transport: "tcp".into(), ..Default::default() });
//! assert!(source.try_next().is_some());
//! assert_eq!(source.status().live_slaves, 3);
//! # drop(asked);
//! ```

use crate::source::{FrameRequest, FrameSource, SourceEvent, SourceStatus, Waker};
use std::sync::mpsc::{Receiver, Sender, channel};
use std::sync::{Arc, Mutex, PoisonError};

/// The window's end of a channel-fed source. See [`channel_source`].
pub struct ChannelSource {
    forward: Box<dyn FnMut(FrameRequest) + Send>,
    events: Receiver<SourceEvent>,
    shared: Arc<Shared>,
}

/// The producer's end of a [`ChannelSource`]: delivers events and counters.
#[derive(Clone)]
pub struct SourceFeed {
    events: Sender<SourceEvent>,
    shared: Arc<Shared>,
}

#[derive(Default)]
struct Shared {
    waker: Mutex<Option<Waker>>,
    status: Mutex<SourceStatus>,
}

/// A source that hands every [`FrameRequest`] to `forward` (which must not
/// block: post it to the producing thread) and shows what the returned
/// [`SourceFeed`] delivers.
pub fn channel_source(forward: impl FnMut(FrameRequest) + Send + 'static) -> (ChannelSource, SourceFeed) {
    let (tx, rx) = channel();
    let shared = Arc::new(Shared::default());
    (
        ChannelSource { forward: Box::new(forward), events: rx, shared: shared.clone() },
        SourceFeed { events: tx, shared },
    )
}

impl SourceFeed {
    /// Delivers an event and wakes the window. Returns false once the window
    /// has dropped its end (the producer can stop).
    pub fn send(&self, event: SourceEvent) -> bool {
        let open = self.events.send(event).is_ok();
        if let Some(w) = self.shared.waker.lock().unwrap_or_else(PoisonError::into_inner).as_ref() {
            w.wake();
        }
        open
    }

    /// Replaces the counters shown in the status line.
    pub fn set_status(&self, status: SourceStatus) {
        *self.shared.status.lock().unwrap_or_else(PoisonError::into_inner) = status;
    }

    /// The counters as last set.
    pub fn status(&self) -> SourceStatus {
        self.shared.status.lock().unwrap_or_else(PoisonError::into_inner).clone()
    }

    /// Changes the counters in place.
    pub fn update_status(&self, update: impl FnOnce(&mut SourceStatus)) {
        update(&mut self.shared.status.lock().unwrap_or_else(PoisonError::into_inner));
    }
}

impl FrameSource for ChannelSource {
    fn set_waker(&mut self, waker: Waker) {
        *self.shared.waker.lock().unwrap_or_else(PoisonError::into_inner) = Some(waker);
    }

    fn request(&mut self, request: FrameRequest) {
        (self.forward)(request);
    }

    fn try_next(&mut self) -> Option<SourceEvent> {
        self.events.try_recv().ok()
    }

    fn status(&self) -> SourceStatus {
        self.shared.status.lock().unwrap_or_else(PoisonError::into_inner).clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::source::TileUpdate;
    use isin_tracer::{Camera, RenderSettings, Tile};
    use std::sync::atomic::{AtomicUsize, Ordering};

    #[test]
    fn requests_go_out_and_events_from_another_thread_come_back_with_a_wake() {
        let (req_tx, req_rx) = channel();
        let (mut source, feed) = channel_source(move |r| req_tx.send(r).unwrap());
        let wakes = Arc::new(AtomicUsize::new(0));
        let w = wakes.clone();
        let waker = Waker::new(move || {
            w.fetch_add(1, Ordering::SeqCst);
        });
        source.set_waker(waker.clone());
        let request =
            FrameRequest { frame_id: 7, camera: Camera::default(), settings: RenderSettings::default() };
        source.request(request);
        let got = req_rx.recv().unwrap();
        assert_eq!(got, request);
        // A producer thread answers with a tile and updates the counters.
        let producer = std::thread::spawn(move || {
            let tile = Tile { x: 0, y: 0, w: 1, h: 1 };
            assert!(feed.send(SourceEvent::Tile(TileUpdate {
                frame_id: got.frame_id,
                tile,
                rgb: vec![1, 2, 3],
                owner: 4
            })));
            feed.update_status(|s| {
                s.bytes_received += 3;
                s.tiles_per_slave.push((4, 1));
            });
            feed
        });
        let feed = producer.join().unwrap();
        assert_eq!(wakes.load(Ordering::SeqCst), 1);
        match source.try_next() {
            Some(SourceEvent::Tile(t)) => assert_eq!((t.frame_id, t.owner, t.rgb.len()), (7, 4, 3)),
            other => panic!("{other:?}"),
        }
        assert!(source.try_next().is_none());
        assert_eq!(source.status().bytes_received, 3);
        assert_eq!(source.status().tiles_per_slave, [(4, 1)]);
        assert_eq!(feed.status(), source.status(), "both ends see the same counters");
        drop(source);
        assert!(!feed.send(SourceEvent::Failed("gone".into())), "the producer learns the window is gone");
    }
}

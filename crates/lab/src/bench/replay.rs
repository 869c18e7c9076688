//! Replaying a camera path through a viewer connection, one frame at a time
//! or with the next frames queued at the master (pipelined), and timing each
//! frame as the viewer sees it.

use anyhow::Context;
use isin_actors::viewer::{self, ViewerActor, ViewerEvent};
use isin_cluster::protocol::FrameStats;
use isin_tracer::{Camera, RenderSettings};
use std::collections::VecDeque;
use std::time::Instant;
use tokio::sync::mpsc::UnboundedReceiver;

/// When one replayed frame was requested, began arriving and completed.
#[derive(Clone, Debug)]
pub struct FrameTiming {
    /// The request left the viewer.
    pub requested: Instant,
    /// Its first tile arrived.
    pub first_tile: Option<Instant>,
    /// Nine tenths of its pixels had arrived.
    pub nine_tenths: Option<Instant>,
    /// Its `FrameDone` arrived.
    pub done: Instant,
    /// The master's account of it.
    pub stats: FrameStats,
}

/// A replay: when it began and each frame's timing, in path order.
#[derive(Clone, Debug)]
pub struct Replay {
    /// The first request left the viewer.
    pub start: Instant,
    /// One per camera.
    pub frames: Vec<FrameTiming>,
}

impl Replay {
    /// Seconds between consecutive completions (the first from the start):
    /// the time each frame added to the replay — seconds per frame as
    /// throughput. One frame at a time, it is each frame's latency.
    pub fn intervals(&self) -> Vec<f64> {
        let mut prev = self.start;
        self.frames
            .iter()
            .map(|f| {
                let s = f.done.saturating_duration_since(prev).as_secs_f64();
                prev = prev.max(f.done);
                s
            })
            .collect()
    }

    /// Seconds from each request to its frame's completion.
    pub fn latencies(&self) -> Vec<f64> {
        self.frames.iter().map(|f| f.done.saturating_duration_since(f.requested).as_secs_f64()).collect()
    }

    /// Seconds from each request to its first tile (the cluster's ramp-up).
    pub fn first_tile(&self) -> Vec<f64> {
        let since = |f: &FrameTiming| f.first_tile.map(|t| t.saturating_duration_since(f.requested));
        self.frames.iter().filter_map(|f| since(f).map(|d| d.as_secs_f64())).collect()
    }

    /// Seconds each frame took to deliver its last tenth of pixels (its tail).
    pub fn last_tenth(&self) -> Vec<f64> {
        let tail = |f: &FrameTiming| f.nine_tenths.map(|t| f.done.saturating_duration_since(t));
        self.frames.iter().filter_map(|f| tail(f).map(|d| d.as_secs_f64())).collect()
    }
}

/// A requested frame not completed yet.
struct Pending {
    request: u64,
    /// Index into the cameras.
    index: usize,
    requested: Instant,
    first_tile: Option<Instant>,
    nine_tenths: Option<Instant>,
    /// Pixels received so far.
    pixels: usize,
}

impl Pending {
    fn new(request: u64, index: usize, requested: Instant) -> Self {
        Self { request, index, requested, first_tile: None, nine_tenths: None, pixels: 0 }
    }
}

/// Replays `cameras` at `settings`, keeping up to `open` frames requested and
/// not completed. With `open` = 1 each frame is requested when the previous one
/// completed (a frame barrier); above, frames are queued at the master
/// ([`viewer::QueueFrame`]) so that slaves roll from one into the next.
/// Fails if the master reports an error or a frame completes with pixels missing.
pub async fn replay(
    v: &actix::Addr<ViewerActor>,
    events: &mut UnboundedReceiver<ViewerEvent>,
    cameras: &[Camera],
    settings: RenderSettings,
    open: usize,
) -> anyhow::Result<Replay> {
    let open = open.max(1);
    let pixels = settings.width as usize * settings.height as usize;
    let mut pending: VecDeque<Pending> = VecDeque::new();
    let mut timings: Vec<Option<FrameTiming>> = vec![None; cameras.len()];
    let mut next = 0;
    let start = Instant::now();
    let send = |camera: Camera| async move {
        if open == 1 {
            v.send(viewer::RequestFrame { camera, settings }).await
        } else {
            v.send(viewer::QueueFrame { camera, settings, job_frame: None }).await
        }
    };
    while next < cameras.len() && pending.len() < open {
        let at = Instant::now();
        let request = send(cameras[next]).await.context("viewer actor stopped")?;
        pending.push_back(Pending::new(request, next, at));
        next += 1;
    }
    while !pending.is_empty() {
        let ev = events.recv().await.context("viewer connection closed")?;
        match ev {
            ViewerEvent::Tile { request, tile, .. } => {
                let Some(p) = pending.iter_mut().find(|p| p.request == request) else { continue };
                let now = Instant::now();
                p.first_tile.get_or_insert(now);
                p.pixels += tile.pixel_count();
                if p.nine_tenths.is_none() && p.pixels * 10 >= pixels * 9 {
                    p.nine_tenths = Some(now);
                }
            }
            ViewerEvent::FrameDone { request, stats } => {
                let Some(i) = pending.iter().position(|p| p.request == request) else { continue };
                let Some(p) = pending.remove(i) else { continue };
                let (idx, got) = (p.index, p.pixels);
                anyhow::ensure!(got == pixels, "frame {idx} done with {got} of {pixels} pixels delivered");
                timings[idx] = Some(FrameTiming {
                    requested: p.requested,
                    first_tile: p.first_tile,
                    nine_tenths: p.nine_tenths,
                    done: Instant::now(),
                    stats,
                });
                if next < cameras.len() {
                    let at = Instant::now();
                    let request = send(cameras[next]).await.context("viewer actor stopped")?;
                    pending.push_back(Pending::new(request, next, at));
                    next += 1;
                }
            }
            ViewerEvent::Notice(m) => tracing::warn!("master: {m}"),
            ViewerEvent::Error(e) | ViewerEvent::Closed(e) => anyhow::bail!("master: {e}"),
        }
    }
    let frames = timings.into_iter().collect::<Option<Vec<_>>>().context("a frame never completed")?;
    Ok(Replay { start, frames })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn timing(start: Instant, req: u64, first: u64, ninety: u64, done: u64) -> FrameTiming {
        let at = |ms| start + Duration::from_millis(ms);
        FrameTiming {
            requested: at(req),
            first_tile: Some(at(first)),
            nine_tenths: Some(at(ninety)),
            done: at(done),
            stats: FrameStats::default(),
        }
    }

    #[test]
    fn intervals_are_throughput_and_latencies_include_the_queue() {
        let start = Instant::now();
        // Pipelined: frame 2 requested at once, completes 100 ms after frame 1.
        let r =
            Replay { start, frames: vec![timing(start, 0, 20, 90, 110), timing(start, 0, 100, 190, 210)] };
        let ms = |v: Vec<f64>| v.iter().map(|s| (s * 1e3).round() as i64).collect::<Vec<_>>();
        assert_eq!(ms(r.intervals()), vec![110, 100]);
        assert_eq!(ms(r.latencies()), vec![110, 210]);
        assert_eq!(ms(r.first_tile()), vec![20, 100]);
        assert_eq!(ms(r.last_tenth()), vec![20, 20]);
        // Out of order: a frame done before the previous one adds nothing.
        let r = Replay { start, frames: vec![timing(start, 0, 1, 2, 100), timing(start, 0, 1, 2, 90)] };
        assert_eq!(ms(r.intervals()), vec![100, 0]);
    }
}

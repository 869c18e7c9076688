//! A synthetic workload for measuring the scheduler itself: `slaves` slaves
//! of `threads` threads each, frames queued two ahead, every tile answered
//! in the order it was handed out while a virtual clock advances a
//! microsecond a result. Used by `cargo bench -p isin-cluster` and
//! `isin bench master`.

use super::{FrameOrder, Output, Scheduler, SchedulerConfig, Work};
use std::collections::VecDeque;
use std::time::Duration;

/// Runs `frames` frames of `width × height` through a fresh scheduler;
/// returns the tile results it handled.
pub fn run(slaves: usize, threads: u32, width: u32, height: u32, frames: usize) -> u64 {
    let cfg = SchedulerConfig { heartbeat_timeout: Duration::from_secs(3600), ..SchedulerConfig::default() };
    let mut s = Scheduler::new(cfg);
    let mut now = Duration::ZERO;
    for id in 0..slaves as u64 {
        s.handle_join(now, id, format!("s{id}"), threads);
    }
    let order = FrameOrder { client: 1, work: Work::Interactive, width, height, samples: 1, queue: true };
    let (mut opened, mut done, mut tiles) = (0u64, 0usize, 0u64);
    let mut out: VecDeque<(u64, u64, u32)> = VecDeque::new();
    while done < frames {
        while opened < (done as u64 + 2).min(frames as u64) {
            opened += 1;
            let _ = s.open(now, opened, order);
        }
        while let Some(o) = s.poll_output(now) {
            match o {
                Output::Assign { slave, frame, tiles: t, .. } => {
                    out.extend(t.iter().map(|j| (slave, frame, j.id)))
                }
                Output::FrameDone { .. } => done += 1,
                _ => {}
            }
        }
        let Some((slave, frame, tile)) = out.pop_front() else { break };
        now += Duration::from_micros(1);
        s.handle_result(now, slave, frame, tile);
        tiles += 1;
    }
    tiles
}

#[cfg(test)]
mod tests {
    #[test]
    fn every_frame_opened_finishes() {
        // Every tile of three frames at least (end-of-frame splits add some).
        let tiles = super::run(50, 2, 320, 240, 3);
        assert!(tiles >= 3 * 80, "{tiles}");
    }
}

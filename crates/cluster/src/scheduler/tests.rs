//! Scheduler tests: a virtual clock (1 ms steps) and simulated slaves that
//! render tiles in `threads` parallel lanes at a chosen speed.

use super::*;
use std::collections::HashMap;

const MS: Duration = Duration::from_millis(1);
use crate::testing::Rng;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Mode {
    Alive,
    /// Still connected, never answers again (hung process, cut cable).
    Silent,
    /// Connection closed.
    Gone,
}

struct SimSlave {
    /// Microseconds of virtual time per pixel.
    us_per_pixel: u64,
    mode: Mode,
    queue: VecDeque<(FrameId, TileJob)>,
    /// Tile being rendered: frame, job, when it is done, how long it takes.
    lanes: Vec<Option<(FrameId, TileJob, Duration, Duration)>>,
    next_heartbeat: Duration,
    received: u32,
}

#[derive(Default)]
struct Log {
    /// Accepted tiles per frame.
    accepted: HashMap<FrameId, Vec<Tile>>,
    done: Vec<(FrameId, FrameStats)>,
    dead: Vec<(SlaveId, DeathCause, u32, Duration)>,
    reassigned: u32,
}

struct Sim {
    sched: Scheduler,
    now: Duration,
    slaves: BTreeMap<SlaveId, SimSlave>,
    log: Log,
    sizes: HashMap<FrameId, (u32, u32)>,
    next_id: SlaveId,
    /// Lane-milliseconds alive slaves spent with nothing to render.
    idle_lane_ms: u64,
    /// When each frame was first handed a tile, by frame.
    first_assigned: HashMap<FrameId, Duration>,
    /// Pixels inside this rectangle cost `hot.1` times as much to render.
    hot: Option<(Tile, u64)>,
    /// Report render times to the scheduler (as the master does).
    report_costs: bool,
}

impl Sim {
    fn new(config: SchedulerConfig) -> Self {
        Self {
            sched: Scheduler::new(config),
            now: Duration::ZERO,
            slaves: BTreeMap::new(),
            log: Log::default(),
            sizes: HashMap::new(),
            next_id: 1,
            idle_lane_ms: 0,
            first_assigned: HashMap::new(),
            hot: None,
            report_costs: true,
        }
    }

    fn join(&mut self, threads: u32, us_per_pixel: u64) -> SlaveId {
        let id = self.next_id;
        self.next_id += 1;
        self.slaves.insert(
            id,
            SimSlave {
                us_per_pixel,
                mode: Mode::Alive,
                queue: VecDeque::new(),
                lanes: vec![None; threads as usize],
                next_heartbeat: self.now,
                received: 0,
            },
        );
        self.sched.handle_join(self.now, id, format!("sim{id}"), threads);
        self.drain();
        id
    }

    fn frame(&mut self, id: FrameId, w: u32, h: u32) {
        self.sched.submit_frame(self.now, id, w, h).unwrap();
        self.sizes.insert(id, (w, h));
        self.drain();
    }

    /// Queues `id` behind the open frames (pipelining).
    fn queue(&mut self, id: FrameId, w: u32, h: u32) {
        self.sched.queue_frame(self.now, id, w, h).unwrap();
        self.sizes.insert(id, (w, h));
        self.drain();
    }

    fn drain(&mut self) {
        while let Some(out) = self.sched.poll_output(self.now) {
            match out {
                Output::Assign { slave, frame, tiles, reassigned } => {
                    let s = self.slaves.get_mut(&slave).expect("assigned to a known slave");
                    assert_ne!(s.mode, Mode::Gone, "work sent to a disconnected slave");
                    s.received += tiles.len() as u32;
                    self.log.reassigned += reassigned;
                    self.first_assigned.entry(frame).or_insert(self.now);
                    s.queue.extend(tiles.into_iter().map(|t| (frame, t)));
                }
                Output::Cancel { slave, frame, tiles } => {
                    if let Some(s) = self.slaves.get_mut(&slave) {
                        s.queue.retain(|(f, t)| !(*f == frame && tiles.contains(&t.id)));
                    }
                }
                Output::SlaveDead { slave, cause, requeued, .. } => {
                    self.log.dead.push((slave, cause, requeued, self.now))
                }
                Output::FrameDone { frame, stats } => self.log.done.push((frame, stats)),
            }
        }
    }

    fn step(&mut self) {
        self.now += MS;
        let now = self.now;
        let mut results = Vec::new();
        let hot = self.hot;
        for (&id, s) in self.slaves.iter_mut() {
            if s.mode != Mode::Alive {
                continue;
            }
            for lane in s.lanes.iter_mut() {
                if let Some((f, job, at, took)) = *lane
                    && at <= now
                {
                    results.push((id, f, job, took));
                    *lane = None;
                }
                if lane.is_none()
                    && let Some((f, job)) = s.queue.pop_front()
                {
                    let cost = render_cost(hot, job.tile, s.us_per_pixel);
                    *lane = Some((f, job, now + cost, cost));
                }
                if lane.is_none() {
                    self.idle_lane_ms += 1;
                }
            }
            if now >= s.next_heartbeat {
                s.next_heartbeat = now + Duration::from_millis(100);
                self.sched.handle_heartbeat(now, id);
            }
        }
        for (slave, frame, job, took) in results {
            if self.report_costs {
                self.sched.record_render_time(frame, job.id, took.as_micros() as u64);
            }
            match self.sched.handle_result(now, slave, frame, job.id) {
                ResultOutcome::Accepted { tile } => {
                    assert_eq!(tile, job.tile, "scheduler reports the rect it handed out");
                    self.log.accepted.entry(frame).or_default().push(tile);
                }
                ResultOutcome::Duplicate | ResultOutcome::Stale | ResultOutcome::Unknown => {}
                ResultOutcome::Foreign => {
                    panic!("slave {slave} refused for tile {} of frame {frame}", job.id)
                }
            }
            self.drain();
        }
        self.sched.handle_timeout(now);
        self.drain();
        self.sched.assert_sole_held_exact();
    }

    fn run_until(&mut self, limit: Duration, mut done: impl FnMut(&Sim) -> bool) {
        let end = self.now + limit;
        while !done(self) {
            assert!(self.now < end, "not done within {limit:?}");
            self.step();
        }
    }

    fn frame_done(&self, frame: FrameId) -> bool {
        self.log.done.iter().any(|(f, _)| *f == frame)
    }

    fn silence(&mut self, id: SlaveId) {
        self.slaves.get_mut(&id).unwrap().mode = Mode::Silent;
    }

    fn disconnect(&mut self, id: SlaveId) {
        self.slaves.get_mut(&id).unwrap().mode = Mode::Gone;
        self.sched.handle_disconnect(self.now, id);
        self.drain();
    }

    /// Every pixel of `frame` delivered exactly once.
    fn assert_exact_cover(&self, frame: FrameId) {
        let (w, h) = self.sizes[&frame];
        let mut count = vec![0u8; (w * h) as usize];
        for t in self.log.accepted.get(&frame).map(Vec::as_slice).unwrap_or(&[]) {
            for y in t.y..t.y + t.h {
                for x in t.x..t.x + t.w {
                    count[(y * w + x) as usize] += 1;
                }
            }
        }
        let missing = count.iter().filter(|&&c| c == 0).count();
        let twice = count.iter().filter(|&&c| c > 1).count();
        assert_eq!((missing, twice), (0, 0), "frame {frame}: pixels missing / delivered twice");
    }
}

/// Render time of `tile` on a slave at `us_per_pixel`; pixels inside the hot
/// spot `hot.0` cost `hot.1` times as much.
fn render_cost(hot: Option<(Tile, u64)>, tile: Tile, us_per_pixel: u64) -> Duration {
    let mut us = tile.pixel_count() as u64 * us_per_pixel;
    if let Some((h, factor)) = hot {
        let ox = (tile.x + tile.w).min(h.x + h.w).saturating_sub(tile.x.max(h.x));
        let oy = (tile.y + tile.h).min(h.y + h.h).saturating_sub(tile.y.max(h.y));
        us += u64::from(ox) * u64::from(oy) * us_per_pixel * (factor - 1);
    }
    Duration::from_micros(us).max(MS)
}

fn cfg() -> SchedulerConfig {
    SchedulerConfig { heartbeat_timeout: Duration::from_millis(500), ..SchedulerConfig::default() }
}

#[test]
fn one_slave_renders_a_whole_frame() {
    let mut sim = Sim::new(cfg());
    sim.join(2, 2);
    sim.frame(1, 100, 70);
    sim.run_until(Duration::from_secs(60), |s| s.frame_done(1));
    sim.assert_exact_cover(1);
}

#[test]
fn window_is_threads_plus_queue_depth() {
    let mut sim = Sim::new(cfg());
    let a = sim.join(3, 2);
    sim.frame(1, 640, 480);
    assert_eq!(sim.slaves[&a].queue.len(), 5);
    assert_eq!(sim.sched.slaves()[0].in_flight, 5);
}

#[test]
fn faster_slaves_take_more_tiles() {
    let mut sim = Sim::new(SchedulerConfig { duplicate_stragglers: false, ..cfg() });
    let fast = sim.join(1, 1);
    let slow = sim.join(1, 4);
    sim.frame(1, 320, 256);
    sim.run_until(Duration::from_secs(60), |s| s.frame_done(1));
    sim.assert_exact_cover(1);
    let by_id: BTreeMap<_, _> = sim.sched.slaves().into_iter().map(|s| (s.id, s.pixels_done)).collect();
    assert!(by_id[&fast] > 2 * by_id[&slow], "{by_id:?}");
}

#[test]
fn tiles_get_smaller_at_the_end_of_a_frame() {
    let mut sim = Sim::new(SchedulerConfig { duplicate_stragglers: false, ..cfg() });
    sim.join(2, 1);
    sim.join(2, 1);
    sim.frame(1, 256, 256);
    sim.run_until(Duration::from_secs(60), |s| s.frame_done(1));
    sim.assert_exact_cover(1);
    let tiles = &sim.log.accepted[&1];
    assert_eq!(tiles.first().unwrap().w, 32);
    assert!(tiles.iter().any(|t| t.w == 8 && t.h == 8), "no small tiles at the end");
    assert!(tiles.iter().all(|t| t.w >= 8 && t.h >= 8));
    // Small tiles only at the end: the first half are all full size.
    assert!(tiles[..tiles.len() / 2].iter().all(|t| t.w == 32));
}

#[test]
fn silent_slave_is_declared_dead_within_timeout_and_its_tiles_rerendered() {
    // Without straggler duplication, so that only the timeout can save the frame.
    let mut sim = Sim::new(SchedulerConfig { duplicate_stragglers: false, ..cfg() });
    let a = sim.join(2, 5);
    let b = sim.join(2, 5);
    let c = sim.join(2, 5);
    sim.frame(1, 320, 240);
    sim.run_until(Duration::from_secs(5), |s| s.log.accepted.get(&1).is_some_and(|v| v.len() > 10));
    sim.silence(b);
    let silenced_at = sim.now;
    sim.run_until(Duration::from_secs(60), |s| s.frame_done(1));
    sim.assert_exact_cover(1);
    let (slave, cause, requeued, at) = sim.log.dead[0];
    assert_eq!((slave, cause), (b, DeathCause::Timeout));
    assert!(requeued > 0, "the silent slave held tiles");
    // Its last heartbeat was at most 100 ms before it went silent.
    assert!(at <= silenced_at + Duration::from_millis(500) + MS, "declared dead at {at:?}");
    assert!(at >= silenced_at + Duration::from_millis(400), "declared dead too early: {at:?}");
    let alive: Vec<_> = sim.sched.slaves().into_iter().map(|s| s.id).collect();
    assert_eq!(alive, vec![a, c]);
}

#[test]
fn disconnected_slave_tiles_go_back_to_the_front_of_the_queue() {
    let mut sim = Sim::new(cfg());
    let a = sim.join(1, 5);
    let b = sim.join(1, 5);
    sim.frame(1, 640, 480);
    sim.step();
    let sb = &sim.slaves[&b];
    let held: BTreeSet<TileId> = sb
        .queue
        .iter()
        .map(|(_, j)| j.id)
        .chain(sb.lanes.iter().flatten().map(|(_, j, _, _)| j.id))
        .collect();
    assert_eq!(held.len(), 3);
    sim.disconnect(b);
    assert_eq!(sim.log.dead[0].1, DeathCause::Disconnected);
    assert_eq!(sim.log.dead[0].2, 3);
    assert_eq!(sim.log.reassigned, 0);
    // a gets b's tiles as soon as it has room, before the rest of the queue.
    sim.run_until(Duration::from_secs(5), |s| s.slaves[&a].received >= 6);
    let sa = &sim.slaves[&a];
    let next: Vec<TileId> = sa
        .queue
        .iter()
        .map(|(_, j)| j.id)
        .chain(sa.lanes.iter().flatten().map(|(_, j, _, _)| j.id))
        .collect();
    for id in &held {
        assert!(
            next.contains(id) || sim.log.accepted[&1].contains(&sim.sched.tile(1, *id).unwrap()),
            "tile {id} of the dead slave not reassigned first: {next:?}"
        );
    }
    assert_eq!(sim.log.reassigned, 3, "the survivor reports taking over the dead slave's tiles");
    sim.run_until(Duration::from_secs(120), |s| s.frame_done(1));
    sim.assert_exact_cover(1);
}

#[test]
fn joining_slave_gets_work_in_the_current_frame() {
    let mut sim = Sim::new(cfg());
    sim.join(1, 5);
    sim.frame(1, 320, 240);
    sim.run_until(Duration::from_secs(5), |s| s.log.accepted.get(&1).is_some_and(|v| v.len() > 5));
    let late = sim.join(2, 5);
    assert!(sim.slaves[&late].received > 0, "a joining slave gets tiles at once");
    sim.run_until(Duration::from_secs(60), |s| s.frame_done(1));
    sim.assert_exact_cover(1);
    let info = sim.sched.slaves().into_iter().find(|s| s.id == late).unwrap();
    assert!(info.tiles_done > 0);
    assert!(sim.log.done[0].1.per_slave.contains_key("sim2"));
}

#[test]
fn newer_frame_supersedes_and_stale_results_are_dropped() {
    let mut sim = Sim::new(cfg());
    let a = sim.join(2, 5);
    sim.frame(1, 320, 240);
    sim.run_until(Duration::from_secs(5), |s| s.log.accepted.get(&1).is_some_and(|v| v.len() > 3));
    // Frame 1 tiles in lanes will finish after frame 2 is submitted.
    sim.frame(2, 160, 120);
    assert!(sim.slaves[&a].queue.iter().all(|(f, _)| *f == 2), "queued frame-1 tiles cancelled");
    assert_eq!(sim.sched.handle_result(sim.now, a, 1, 0), ResultOutcome::Stale);
    let before = sim.log.accepted[&1].len();
    sim.run_until(Duration::from_secs(60), |s| s.frame_done(2));
    assert_eq!(sim.log.accepted[&1].len(), before, "no frame-1 tile accepted after frame 2 began");
    assert!(!sim.frame_done(1));
    sim.assert_exact_cover(2);
    assert!(sim.sched.submit_frame(sim.now, 2, 10, 10).is_err(), "frame ids must increase");
}

#[test]
fn tiles_waiting_on_a_busy_slave_move_to_an_idle_one() {
    // Whole 32 px tiles only (no shrinking, no end-of-frame splits).
    let mut sim = Sim::new(SchedulerConfig { duplicate_stragglers: false, min_tile_size: 32, ..cfg() });
    let _fast = sim.join(1, 1);
    let slow = sim.join(1, 100); // 102 ms per 32x32 tile
    sim.frame(1, 128, 64);
    let queued_on_slow = sim.slaves[&slow].queue.len();
    assert!(queued_on_slow > 1, "the slow slave starts with tiles queued: {queued_on_slow}");
    sim.run_until(Duration::from_secs(60), |s| s.frame_done(1));
    sim.assert_exact_cover(1);
    let stats = &sim.log.done[0].1;
    assert!(stats.moved as usize >= queued_on_slow - 1, "{stats:?}");
    assert_eq!(stats.per_slave.get(&format!("sim{slow}")), Some(&1), "{stats:?}");
    // One slow tile, not every tile the slow slave was first given.
    assert!(sim.now < Duration::from_millis(150), "took {:?}", sim.now);
}

#[test]
fn near_the_end_of_a_frame_slaves_get_one_tile_per_thread() {
    let no_split = SchedulerConfig { duplicate_stragglers: false, min_tile_size: 32, ..cfg() };
    let mut sim = Sim::new(no_split);
    let a = sim.join(2, 1);
    let b = sim.join(2, 1);
    sim.frame(1, 96, 64); // 6 tiles for 4 threads: the 2 left wait at the master
    let held: usize = [a, b].iter().map(|id| sim.slaves[id].queue.len()).sum();
    assert_eq!(held, 4, "one per thread, none queued behind one: {:?}", sim.sched.slaves());
    sim.run_until(Duration::from_secs(60), |s| s.frame_done(1));
    sim.assert_exact_cover(1);
}

#[test]
fn a_large_cluster_gets_smaller_tiles() {
    let edge_for = |slaves: u32| {
        let mut sim = Sim::new(SchedulerConfig { duplicate_stragglers: false, ..cfg() });
        let ids: Vec<SlaveId> = (0..slaves).map(|_| sim.join(1, 1)).collect();
        sim.frame(1, 320, 240);
        let first = sim.slaves[&ids[0]].queue.front().map(|(_, job)| job.tile).expect("work assigned");
        sim.run_until(Duration::from_secs(60), |s| s.frame_done(1));
        sim.assert_exact_cover(1);
        first.w
    };
    assert_eq!(edge_for(1), 32, "80 tiles are plenty for one thread");
    assert_eq!(edge_for(12), 16, "80 tiles of 32 px are under 8 per thread for 12 threads");
}

#[test]
fn queued_frames_keep_the_full_tile_edge_on_a_large_cluster() {
    let mut sim = Sim::new(SchedulerConfig { duplicate_stragglers: false, ..cfg() });
    let ids: Vec<SlaveId> = (0..12).map(|_| sim.join(1, 1)).collect();
    sim.queue(1, 320, 240);
    sim.queue(2, 320, 240);
    let first = sim.slaves[&ids[0]].queue.front().map(|(_, job)| job.tile).expect("work assigned");
    assert_eq!(first.w, 32, "a pipelined frame's end is filled by the next: no cluster-sized edge");
    sim.run_until(Duration::from_secs(60), |s| s.frame_done(2));
    sim.assert_exact_cover(1);
    sim.assert_exact_cover(2);
}

#[test]
fn idle_slave_duplicates_the_straggler_and_first_result_wins() {
    let mut sim = Sim::new(cfg());
    let fast = sim.join(1, 1);
    let slow = sim.join(1, 200);
    sim.frame(1, 64, 64);
    sim.run_until(Duration::from_secs(60), |s| s.frame_done(1));
    sim.assert_exact_cover(1);
    let stats = &sim.log.done[0].1;
    assert!(stats.duplicated > 0, "{stats:?}");
    // The slow slave's tiles were won by the fast one; the frame finished long
    // before the slow slave could render a single 32x32 tile (204 ms).
    assert!(sim.now < Duration::from_millis(150), "took {:?}", sim.now);
    assert!(!stats.per_slave.contains_key(&format!("sim{slow}")));
    let _ = fast;
}

/// A scheduler of 8×8 tiles, no queue beyond the threads, copying stragglers.
fn eight_pixel_tiles() -> Scheduler {
    Scheduler::new(SchedulerConfig {
        tile_size: 8,
        min_tile_size: 8,
        queue_depth: 0,
        duplicate_stragglers: true,
        ..cfg()
    })
}

/// The tiles handed out at `now`, as (slave, tile).
fn assigned(s: &mut Scheduler, now: Duration) -> Vec<(SlaveId, TileId)> {
    let mut got = Vec::new();
    while let Some(out) = s.poll_output(now) {
        if let Output::Assign { slave, tiles, .. } = out {
            got.extend(tiles.iter().map(|t| (slave, t.id)));
        }
    }
    got
}

#[test]
fn a_copy_whose_other_holder_dies_can_be_copied_again() {
    let mut s = eight_pixel_tiles();
    // Two tiles: `a` takes one, `b` the other and answers it at once.
    s.handle_join(Duration::ZERO, 1, "a", 1);
    s.submit_frame(Duration::ZERO, 1, 16, 8).unwrap();
    assert_eq!(assigned(&mut s, Duration::ZERO), [(1, 0)]);
    s.handle_join(Duration::ZERO, 2, "b", 1);
    assert_eq!(assigned(&mut s, Duration::ZERO), [(2, 1)]);
    assert!(matches!(s.handle_result(MS, 2, 1, 1), ResultOutcome::Accepted { .. }));
    // `a`'s tile is late: idle `b` copies it; a third slave finds nothing to copy.
    assert_eq!(assigned(&mut s, 3 * MS), [(2, 0)]);
    s.handle_join(4 * MS, 3, "c", 1);
    assert_eq!(assigned(&mut s, 4 * MS), []);
    // The copy's holder dies: `a` holds the tile alone again, and `c` copies it.
    s.handle_disconnect(5 * MS, 2);
    assert_eq!(assigned(&mut s, 5 * MS), [(3, 0)]);
    s.assert_sole_held_exact();
}

#[test]
fn a_tile_requeued_at_the_end_of_a_frame_can_be_copied_once_out_again() {
    let mut s = eight_pixel_tiles();
    // Three tiles for three slaves; `c` answers at once and copies `a`'s.
    for (id, name) in [(1, "a"), (2, "b"), (3, "c")] {
        s.handle_join(Duration::ZERO, id, name, 1);
    }
    s.submit_frame(Duration::ZERO, 1, 24, 8).unwrap();
    let mut first = assigned(&mut s, Duration::ZERO);
    first.sort_unstable();
    assert_eq!(first, [(1, 0), (2, 1), (3, 2)]);
    assert!(matches!(s.handle_result(MS, 3, 1, 2), ResultOutcome::Accepted { .. }));
    assert_eq!(assigned(&mut s, 3 * MS), [(3, 0)]);
    // `b` dies: its tile goes back to the queue, and out again to `d`.
    s.handle_disconnect(4 * MS, 2);
    assert_eq!(assigned(&mut s, 4 * MS), []);
    s.handle_join(5 * MS, 4, "d", 1);
    assert_eq!(assigned(&mut s, 5 * MS), [(4, 1)]);
    // Late again, it is copied to the next idle slave.
    s.handle_join(10 * MS, 5, "e", 1);
    assert_eq!(assigned(&mut s, 10 * MS), [(5, 1)]);
    s.assert_sole_held_exact();
}

#[test]
fn duplicate_result_is_reported_and_not_delivered_twice() {
    let mut s = Scheduler::new(SchedulerConfig { duplicate_stragglers: true, ..cfg() });
    s.handle_join(Duration::ZERO, 1, "a", 1);
    s.submit_frame(Duration::ZERO, 1, 8, 8).unwrap();
    while s.poll_output(Duration::ZERO).is_some() {}
    assert!(matches!(s.handle_result(MS, 1, 1, 0), ResultOutcome::Accepted { .. }));
    assert_eq!(s.handle_result(2 * MS, 1, 1, 0), ResultOutcome::Duplicate);
    assert_eq!(s.handle_result(2 * MS, 1, 1, 99), ResultOutcome::Unknown);
}

#[test]
fn a_result_from_a_slave_never_handed_the_tile_is_foreign_and_changes_nothing() {
    let mut s = Scheduler::new(SchedulerConfig { duplicate_stragglers: false, ..cfg() });
    s.handle_join(Duration::ZERO, 1, "a", 1);
    s.submit_frame(Duration::ZERO, 1, 8, 8).unwrap();
    while s.poll_output(Duration::ZERO).is_some() {}
    s.handle_join(Duration::ZERO, 2, "b", 1);
    let rect = s.tile(1, 0).unwrap();
    assert_eq!(s.check_result(2, 1, 0), ResultCheck::Foreign);
    assert_eq!(s.check_result(2, 1, 99), ResultCheck::Foreign);
    assert_eq!(s.check_result(1, 1, 0), ResultCheck::Held { tile: rect });
    assert_eq!(s.check_result(1, 7, 0), ResultCheck::Stale);
    assert_eq!(s.handle_result(MS, 2, 1, 0), ResultOutcome::Foreign);
    // Still outstanding: the holder's result is the one delivered.
    assert_eq!(s.open_frame(), Some(1));
    assert!(matches!(s.handle_result(2 * MS, 1, 1, 0), ResultOutcome::Accepted { .. }));
    assert_eq!(s.check_result(1, 1, 0), ResultCheck::Finished);
    assert_eq!(s.check_result(2, 1, 0), ResultCheck::Foreign);
    assert_eq!(s.slaves().iter().map(|i| i.tiles_done).collect::<Vec<_>>(), vec![1, 0]);
}

#[test]
fn slave_killed_with_nothing_left_in_the_cluster_then_rejoining_finishes() {
    let mut sim = Sim::new(cfg());
    let a = sim.join(2, 5);
    sim.frame(1, 200, 100);
    sim.step();
    sim.disconnect(a);
    for _ in 0..50 {
        sim.step();
    }
    assert!(!sim.frame_done(1));
    sim.join(2, 5);
    sim.run_until(Duration::from_secs(60), |s| s.frame_done(1));
    sim.assert_exact_cover(1);
}

/// Randomised: slaves of random speeds join, go silent, disconnect; frames are
/// superseded. Invariants: no work goes to a disconnected slave; every frame
/// that completes is covered exactly once; the last frame always completes.
#[test]
fn randomised_sessions_never_lose_or_duplicate_a_pixel() {
    for seed in 1..=40u64 {
        let mut rng = Rng(seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1);
        let config = SchedulerConfig {
            tile_size: [8, 16, 32, 48][rng.below(4) as usize],
            min_tile_size: [4, 8][rng.below(2) as usize],
            queue_depth: rng.below(4) as u32,
            heartbeat_timeout: Duration::from_millis(200 + rng.below(400)),
            duplicate_stragglers: rng.below(3) != 0,
            max_open_frames: 4,
        };
        let mut sim = Sim::new(config);
        for _ in 0..1 + rng.below(4) {
            sim.join(1 + rng.below(4) as u32, 1 + rng.below(20));
        }
        let mut frame = 0;
        let frames = 3 + rng.below(4);
        while frame < frames {
            frame += 1;
            let (w, h) = (1 + rng.below(200) as u32, 1 + rng.below(150) as u32);
            sim.frame(frame, w, h);
            // Sometimes the next frame is queued behind this one (pipelining).
            if frame < frames && rng.below(3) == 0 {
                frame += 1;
                let (w, h) = (1 + rng.below(200) as u32, 1 + rng.below(150) as u32);
                sim.queue(frame, w, h);
            }
            let superseded = frame < frames && rng.below(3) == 0;
            let steps = if superseded { rng.below(200) } else { u64::MAX };
            let mut n = 0;
            while !sim.frame_done(frame) && n < steps {
                match rng.below(400) {
                    0 => {
                        sim.join(1 + rng.below(4) as u32, 1 + rng.below(20));
                    }
                    1 | 2 => {
                        let live: Vec<_> = sim
                            .slaves
                            .iter()
                            .filter(|(_, s)| s.mode == Mode::Alive)
                            .map(|(&i, _)| i)
                            .collect();
                        if live.len() > 1 {
                            let victim = live[rng.below(live.len() as u64) as usize];
                            if rng.below(2) == 0 {
                                sim.silence(victim);
                            } else {
                                sim.disconnect(victim);
                            }
                        }
                    }
                    _ => {}
                }
                sim.step();
                n += 1;
                assert!(n < 2_000_000, "seed {seed}: frame {frame} stuck");
            }
            if sim.frame_done(frame) {
                sim.assert_exact_cover(frame);
            }
        }
        assert!(sim.frame_done(frames), "seed {seed}: last frame incomplete");
        let timeout = sim.sched.config().heartbeat_timeout;
        for _ in 0..timeout.as_millis() + 2 {
            sim.step();
        }
        // Every silent slave was eventually declared dead, by timeout.
        for (&id, s) in &sim.slaves {
            if s.mode == Mode::Silent {
                assert!(
                    sim.log.dead.iter().any(|&(d, c, _, _)| d == id && c == DeathCause::Timeout),
                    "seed {seed}: silent slave {id} never declared dead"
                );
                assert!(!sim.sched.has_slave(id));
            }
        }
        // Each accepted tile of a frame is unique (no double delivery even of
        // identical rectangles).
        for tiles in sim.log.accepted.values() {
            let set: BTreeSet<_> = tiles.iter().map(|t| (t.x, t.y, t.w, t.h)).collect();
            assert_eq!(set.len(), tiles.len(), "seed {seed}");
        }
    }
}

/// Renders `frames` frames of `w × h` on `slaves` one-thread slaves, either
/// one after another (each requested when the previous completes) or with
/// `ahead` frames queued ahead; returns the sim.
fn replay(slaves: usize, frames: u64, w: u32, h: u32, ahead: u64, config: SchedulerConfig) -> Sim {
    let mut sim = Sim::new(config);
    for _ in 0..slaves {
        sim.join(1, 3);
    }
    let mut requested = 0;
    for done in 0..frames {
        while requested < frames && requested < done + 1 + ahead {
            requested += 1;
            if ahead == 0 {
                sim.frame(requested, w, h);
            } else {
                sim.queue(requested, w, h);
            }
        }
        sim.run_until(Duration::from_secs(60), |s| s.frame_done(done + 1));
    }
    for f in 1..=frames {
        sim.assert_exact_cover(f);
    }
    sim
}

#[test]
fn queued_frame_goes_out_as_the_older_one_drains() {
    let mut sim = Sim::new(SchedulerConfig { duplicate_stragglers: false, ..cfg() });
    let a = sim.join(1, 5);
    let b = sim.join(1, 5);
    sim.queue(1, 128, 64);
    sim.queue(2, 128, 64);
    assert_eq!(sim.sched.open_frames(), vec![1, 2]);
    // Frame 1 goes out first, in full: no frame-2 tile while frame 1 has tiles to hand out.
    assert!([a, b].iter().all(|id| sim.slaves[id].queue.iter().all(|(f, _)| *f == 1)));
    sim.run_until(Duration::from_secs(60), |s| s.first_assigned.contains_key(&2));
    assert!(!sim.frame_done(1), "frame 2 starts before frame 1 completes");
    sim.run_until(Duration::from_secs(60), |s| s.frame_done(2));
    let order: Vec<FrameId> = sim.log.done.iter().map(|(f, _)| *f).collect();
    assert_eq!(order, vec![1, 2], "each frame completes, oldest first");
    sim.assert_exact_cover(1);
    sim.assert_exact_cover(2);
    // Stats are per frame: each counts its own tiles.
    let (t1, t2) = (sim.log.done[0].1.tiles, sim.log.done[1].1.tiles);
    assert_eq!(t1 as usize, sim.log.accepted[&1].len());
    assert_eq!(t2 as usize, sim.log.accepted[&2].len());
    assert_eq!(sim.sched.open_frames(), Vec::<FrameId>::new());
}

#[test]
fn pipelined_replay_keeps_slaves_busy_through_frame_ends() {
    let config = SchedulerConfig { duplicate_stragglers: false, ..cfg() };
    let (slaves, frames) = (12, 8);
    let barrier = replay(slaves, frames, 320, 240, 0, config.clone());
    let piped = replay(slaves, frames, 320, 240, 1, config);
    // The same work in less time, with fewer idle lanes: the tail of each
    // frame is filled with tiles of the next.
    assert!(piped.now < barrier.now, "pipelined {:?} vs one at a time {:?}", piped.now, barrier.now);
    assert!(
        piped.idle_lane_ms * 2 < barrier.idle_lane_ms,
        "idle lane-ms: pipelined {} vs one at a time {}",
        piped.idle_lane_ms,
        barrier.idle_lane_ms
    );
    // Busy lanes, end to end: above 90 % of 12 lanes × the run.
    let busy = 1.0 - piped.idle_lane_ms as f64 / (slaves as f64 * piped.now.as_millis() as f64);
    assert!(busy > 0.9, "lanes busy {busy:.3}");
}

#[test]
fn end_of_frame_measures_wait_for_the_last_queued_frame() {
    // With a frame queued behind, frame 1's end is not the cluster's: its
    // tiles are not split, copied or moved (the next frame's fill the gaps).
    let mut sim = Sim::new(cfg());
    for _ in 0..4 {
        sim.join(1, 3);
    }
    // 64 tiles of 32 px: 16 per thread, so the edge does not shrink for the cluster.
    sim.queue(1, 256, 256);
    sim.queue(2, 256, 256);
    sim.run_until(Duration::from_secs(60), |s| s.frame_done(2));
    let s1 = &sim.log.done[0].1;
    assert_eq!((s1.duplicated, s1.moved), (0, 0), "{s1:?}");
    assert!(sim.log.accepted[&1].iter().all(|t| t.w == 32 && t.h == 32), "frame 1 tiles split");
    // The last frame's end still gets them.
    assert!(sim.log.accepted[&2].iter().any(|t| t.w < 32), "last frame's tail not split");
}

#[test]
fn a_submitted_frame_supersedes_queued_ones_too() {
    let mut sim = Sim::new(cfg());
    let a = sim.join(2, 5);
    sim.queue(1, 320, 240);
    sim.queue(2, 320, 240);
    sim.run_until(Duration::from_secs(5), |s| s.log.accepted.get(&1).is_some_and(|v| v.len() > 3));
    sim.frame(3, 64, 64);
    assert_eq!(sim.sched.open_frames(), vec![3]);
    assert!(sim.slaves[&a].queue.iter().all(|(f, _)| *f == 3), "queued tiles of 1 and 2 cancelled");
    assert_eq!(sim.sched.handle_result(sim.now, a, 2, 0), ResultOutcome::Stale);
    sim.run_until(Duration::from_secs(60), |s| s.frame_done(3));
    assert!(!sim.frame_done(1) && !sim.frame_done(2));
    sim.assert_exact_cover(3);
}

#[test]
fn open_frames_are_bounded() {
    let mut s = Scheduler::new(SchedulerConfig { max_open_frames: 2, ..cfg() });
    s.handle_join(Duration::ZERO, 1, "a", 1);
    s.queue_frame(Duration::ZERO, 1, 8, 8).unwrap();
    s.queue_frame(Duration::ZERO, 2, 8, 8).unwrap();
    assert_eq!(s.queue_frame(Duration::ZERO, 3, 8, 8), Err(SchedulerError::TooManyFrames(2)));
    assert_eq!(s.queue_frame(Duration::ZERO, 2, 8, 8), Err(SchedulerError::NotNewer { new: 2, current: 2 }));
    // Completing frame 1 makes room.
    while s.poll_output(Duration::ZERO).is_some() {}
    assert!(matches!(s.handle_result(MS, 1, 1, 0), ResultOutcome::Accepted { .. }));
    s.queue_frame(MS, 3, 8, 8).unwrap();
    assert_eq!(s.open_frames(), vec![2, 3]);
}

#[test]
fn abandoning_one_frame_leaves_the_others() {
    let mut sim = Sim::new(cfg());
    let a = sim.join(1, 5);
    sim.queue(1, 64, 64);
    sim.queue(2, 64, 64);
    sim.sched.abandon(1);
    sim.drain();
    assert_eq!(sim.sched.open_frames(), vec![2]);
    assert!(sim.slaves[&a].queue.iter().all(|(f, _)| *f == 2), "frame 1's queued tiles cancelled");
    sim.run_until(Duration::from_secs(60), |s| s.frame_done(2));
    sim.assert_exact_cover(2);
    assert!(!sim.frame_done(1));
}

/// Renders `frames` frames of 320×240 one at a time on 12 one-thread slaves
/// with an expensive spot where grid order meets it last; returns how long
/// each frame took, in order.
fn hot_spot_frames(report_costs: bool, frames: u64) -> Vec<Duration> {
    let mut sim = Sim::new(SchedulerConfig { duplicate_stragglers: false, ..cfg() });
    sim.hot = Some((Tile { x: 256, y: 176, w: 64, h: 64 }, 12));
    sim.report_costs = report_costs;
    // 16 px tiles (the cluster-sized edge) take 7.7 ms, those of the spot 92 ms.
    for _ in 0..12 {
        sim.join(1, 30);
    }
    let mut took = Vec::new();
    for f in 1..=frames {
        let t0 = sim.now;
        sim.frame(f, 320, 240);
        sim.run_until(Duration::from_secs(60), |s| s.frame_done(f));
        sim.assert_exact_cover(f);
        took.push(sim.now - t0);
    }
    took
}

#[test]
fn expensive_tiles_go_out_first_once_measured() {
    let blind = hot_spot_frames(false, 3);
    let learnt = hot_spot_frames(true, 3);
    println!("frame times in grid order {blind:?}, expensive first {learnt:?}");
    // The first frame knows nothing either way.
    assert_eq!(blind[0], learnt[0]);
    // The work spread evenly over the 12 slaves.
    let hot = Some((Tile { x: 256, y: 176, w: 64, h: 64 }, 12));
    let ideal = Tile::grid(320, 240, 8).into_iter().map(|t| render_cost(hot, t, 30)).sum::<Duration>() / 12;
    // Later frames start with the hot spot's tiles and end on cheap ones.
    for f in 1..3 {
        assert!(learnt[f].as_secs_f64() < 1.1 * ideal.as_secs_f64(), "{:?} vs ideal {ideal:?}", learnt[f]);
        assert!(
            learnt[f].as_secs_f64() < 0.92 * blind[f].as_secs_f64(),
            "frame {}: {:?} with costs against {:?} in grid order",
            f + 1,
            learnt[f],
            blind[f]
        );
    }
}

#[test]
fn the_first_tiles_handed_out_are_the_measured_expensive_ones() {
    let mut sim = Sim::new(SchedulerConfig { duplicate_stragglers: false, ..cfg() });
    sim.hot = Some((Tile { x: 256, y: 176, w: 64, h: 64 }, 12));
    let a = sim.join(1, 3);
    sim.frame(1, 320, 240);
    sim.run_until(Duration::from_secs(60), |s| s.frame_done(1));
    assert!(sim.sched.expected_render_micros(Tile { x: 288, y: 208, w: 32, h: 32 }, 320, 240) > 0.0);
    sim.frame(2, 320, 240);
    let (_, first) = sim.slaves[&a].queue.front().copied().expect("frame 2 handed out");
    let hot = Tile { x: 256, y: 176, w: 64, h: 64 };
    let inside = first.tile.x + first.tile.w > hot.x && first.tile.y + first.tile.h > hot.y;
    assert!(inside, "first tile of frame 2 {:?} is not in the hot spot", first.tile);
}

#[test]
fn pipelined_frames_with_a_hot_spot_keep_slaves_busier_once_costs_are_known() {
    let run = |report_costs: bool| {
        let mut sim = Sim::new(SchedulerConfig { duplicate_stragglers: false, ..cfg() });
        sim.hot = Some((Tile { x: 256, y: 176, w: 64, h: 64 }, 12));
        sim.report_costs = report_costs;
        for _ in 0..12 {
            sim.join(1, 30);
        }
        let (frames, mut requested) = (8u64, 0u64);
        for done in 0..frames {
            while requested < frames && requested < done + 2 {
                requested += 1;
                sim.queue(requested, 320, 240);
            }
            sim.run_until(Duration::from_secs(60), |s| s.frame_done(done + 1));
        }
        (sim.now, sim.idle_lane_ms)
    };
    let (blind, learnt) = (run(false), run(true));
    println!("pipelined, 8 frames: grid order {blind:?}, expensive first {learnt:?} (time, idle lane-ms)");
    assert!(learnt.0 < blind.0 && learnt.1 < blind.1, "{learnt:?} vs {blind:?}");
}

fn order(client: ClientId, width: u32, height: u32, samples: u32) -> FrameOrder {
    FrameOrder { client, work: Work::Interactive, width, height, samples, queue: false }
}

#[test]
fn a_client_returning_after_a_pause_starts_level_with_the_least_served() {
    let mut s = Scheduler::new(SchedulerConfig { duplicate_stragglers: false, ..cfg() });
    s.handle_join(Duration::ZERO, 1, "a", 1);
    s.open(Duration::ZERO, 1, order(7, 8, 8, 4)).unwrap();
    s.open(Duration::ZERO, 2, order(9, 64, 64, 1)).unwrap();
    while s.poll_output(Duration::ZERO).is_some() {}
    // Client 7's frame (one 8x8 tile at 4 samples) completes: 256 served, then it leaves the table.
    assert!(matches!(s.handle_result(MS, 1, 1, 0), ResultOutcome::Accepted { .. }));
    assert!(!s.served().contains_key(&7));
    let nine = s.served()[&9];
    s.open(2 * MS, 3, order(7, 8, 8, 1)).unwrap();
    assert_eq!(s.served()[&7], nine, "level with the one still at work");
    // Superseding its own frame leaves client 9's alone.
    s.open(3 * MS, 4, order(7, 8, 8, 1)).unwrap();
    assert_eq!(s.open_frames(), vec![2, 4]);
}

#[test]
fn batch_work_gets_its_floor_while_interactive_work_is_backlogged() {
    let mut s = Scheduler::new(SchedulerConfig { duplicate_stragglers: false, queue_depth: 0, ..cfg() });
    s.handle_join(Duration::ZERO, 1, "a", 1);
    let interactive = FrameOrder { queue: true, ..order(1, 256, 256, 1) };
    let batch = FrameOrder { client: 2, work: Work::Batch, ..interactive };
    let mut next = 1;
    let mut work: BTreeMap<FrameId, Work> = BTreeMap::new();
    let (mut to_batch, mut handed) = (0u32, 0u32);
    while handed < 1000 {
        // Both clients always have work waiting: two interactive frames, one batch frame.
        for (o, want) in [(interactive, 2), (batch, 1)] {
            while s.open_frames().iter().filter(|f| work[f] == o.work).count() < want {
                s.open(Duration::ZERO, next, o).unwrap();
                work.insert(next, o.work);
                next += 1;
            }
        }
        let Some(out) = s.poll_output(Duration::ZERO) else { panic!("no work handed out") };
        if let Output::Assign { frame, tiles, .. } = out {
            for t in tiles {
                handed += 1;
                to_batch += u32::from(work[&frame] == Work::Batch);
                s.handle_result(Duration::ZERO, 1, frame, t.id);
            }
        }
    }
    let share = f64::from(to_batch) / f64::from(handed);
    assert!((0.09..=0.11).contains(&share), "batch got {share:.3} of the tiles");
}

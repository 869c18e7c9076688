//! Scheduler CPU time per tile at 12, 100 and 1,000 slaves (`cargo bench -p isin-cluster`).

use isin_cluster::scheduler::workload;
use std::time::Instant;

fn main() {
    for (slaves, w, h, frames) in [(12, 640, 480, 40), (100, 1920, 1080, 10), (1000, 1920, 1080, 4)] {
        // Best of three: the least disturbed run.
        let best = (0..3)
            .map(|_| {
                let t0 = Instant::now();
                let tiles = workload::run(slaves, 2, w, h, frames);
                (t0.elapsed().as_secs_f64() * 1e9 / tiles.max(1) as f64, tiles)
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .unwrap_or_default();
        println!(
            "scheduler, {slaves:>4} slaves × 2 threads, {w}x{h}: {:>8.0} ns a tile ({} tiles a run)",
            best.0, best.1
        );
    }
}

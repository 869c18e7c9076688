//! What the chaos soak found, and how it is written down: the faults as
//! injected, the viewer's frames and the batch job's rounds, the tally of
//! frames requested, completed, identical and lost, the recoveries after
//! master restarts, and the report (JSON, Markdown and a plot of memory
//! over time).

use super::super::{loadavg, modes, report};
use super::ChaosArgs;
use super::faults::{Fault, FaultKind};
use super::rss::{self, Sample};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::Path;

/// A fault as it was injected.
#[derive(Clone, Debug, Serialize)]
pub(super) struct Injected {
    /// The plan.
    #[serde(flatten)]
    pub(super) fault: Fault,
    /// Seconds from the start when it began.
    pub(super) began: f64,
    /// Seconds from the start when the new master process started (master restarts).
    pub(super) master_started: Option<f64>,
    /// What went wrong injecting or undoing it.
    pub(super) error: Option<String>,
}

/// One viewer frame.
#[derive(Clone, Debug, Serialize)]
pub(super) struct ViewerFrame {
    pub(super) camera: usize,
    /// Seconds from the start: first requested, completed.
    pub(super) requested: f64,
    pub(super) done: Option<f64>,
    /// Requests sent (more than one: re-requested after the master was lost).
    pub(super) attempts: u32,
    pub(super) identical: Option<bool>,
    pub(super) requeued: u32,
    pub(super) duplicated: u32,
    /// Errors the master answered, or why it was given up.
    pub(super) errors: Vec<String>,
}

impl ViewerFrame {
    pub(super) fn notable(&self) -> bool {
        self.done.is_none_or(|d| d - self.requested > 1.0)
            || self.identical != Some(true)
            || self.attempts > 1
            || !self.errors.is_empty()
    }
}

/// The name of this process in the memory readings.
pub(super) const BENCH_PROCESS: &str = "bench (viewer)";

/// One round of the batch job.
#[derive(Clone, Debug, Serialize)]
pub(super) struct BatchRound {
    /// The path's frames it renders.
    pub(super) first: usize,
    pub(super) frames: usize,
    pub(super) started: f64,
    pub(super) ended: f64,
    /// Seconds from the start at which `isin fly` reported each frame done.
    pub(super) done_at: Vec<f64>,
    /// Files written, and identical to the local render.
    pub(super) written: usize,
    pub(super) identical: usize,
    /// How `isin fly` ended (`exit status: 0`, or what it said last).
    pub(super) status: String,
}

impl BatchRound {
    /// The longest time from the round's start or a frame to the next frame.
    pub(super) fn longest_gap(&self) -> f64 {
        let mut prev = self.started;
        let mut longest = 0.0f64;
        for &d in &self.done_at {
            longest = longest.max(d - prev);
            prev = d;
        }
        longest
    }

    pub(super) fn notable(&self) -> bool {
        self.written < self.frames
            || self.identical < self.written
            || self.status != "exit status: 0"
            || self.longest_gap() > 1.0
    }
}

/// Frames of one client.
#[derive(Clone, Debug, Default, Serialize)]
pub(super) struct Tally {
    pub(super) requested: usize,
    pub(super) completed: usize,
    pub(super) identical: usize,
    pub(super) lost: usize,
    /// Seconds: the longest frame (viewer: first request to completion;
    /// batch: the longest time between two completed frames of a round).
    pub(super) longest_frame: f64,
}

/// From a master restart to the next completed frame.
#[derive(Clone, Debug, Serialize)]
pub(super) struct Recovery {
    pub(super) master_started: f64,
    pub(super) next_frame: Option<f64>,
    pub(super) seconds: Option<f64>,
}

#[derive(Serialize)]
pub(super) struct ChaosReport {
    pub(super) scene: String,
    pub(super) path: String,
    pub(super) transport: String,
    pub(super) slaves: usize,
    pub(super) width: u32,
    pub(super) height: u32,
    pub(super) seed: u64,
    pub(super) rate_mbit: u32,
    pub(super) throttled_mbit: u32,
    pub(super) planned_seconds: f64,
    pub(super) wall_seconds: f64,
    pub(super) faults: Vec<Injected>,
    pub(super) fault_counts: BTreeMap<FaultKind, usize>,
    pub(super) viewer: Tally,
    pub(super) batch: Tally,
    pub(super) batch_rounds: usize,
    pub(super) recoveries: Vec<Recovery>,
    /// Tiles handed out again, over the viewer's frames: their slave died, or
    /// a copy to an idle slave (`isin fly` does not report its frames' stats).
    pub(super) tiles_requeued: u64,
    pub(super) tiles_duplicated: u64,
    pub(super) rss: Vec<rss::RssSummary>,
    pub(super) rss_series: BTreeMap<String, Vec<Sample>>,
    /// Every master and slave flat (the bench's own process, which holds
    /// the soak's records, is shown but not judged).
    pub(super) rss_flat: bool,
    /// The viewer's frames worth a look: lost, differing, asked more than
    /// once, answered with an error, or longer than a second.
    pub(super) viewer_frames: Vec<ViewerFrame>,
    /// The batch rounds worth a look: frames lost or changed, `isin fly`
    /// failing, or more than a second between two frames.
    pub(super) rounds: Vec<BatchRound>,
    pub(super) notes: Vec<String>,
    pub(super) loadavg_before: String,
    pub(super) loadavg_after: String,
    pub(super) unix_time: u64,
}

impl ChaosReport {
    /// Frames lost over both clients.
    pub(super) fn lost(&self) -> usize {
        self.viewer.lost + self.batch.lost
    }

    /// Every completed frame identical to the local render.
    pub(super) fn all_identical(&self) -> bool {
        self.viewer.identical == self.viewer.completed && self.batch.identical == self.batch.completed
    }
}

#[allow(clippy::too_many_arguments)]
pub(super) fn make_report(
    args: &ChaosArgs,
    (width, height): (u32, u32),
    seconds: f64,
    wall: f64,
    faults: Vec<Injected>,
    viewer_frames: Vec<ViewerFrame>,
    rounds: Vec<BatchRound>,
    rss_series: BTreeMap<String, Vec<Sample>>,
    loadavg_before: String,
) -> ChaosReport {
    let mut fault_counts = BTreeMap::new();
    for f in &faults {
        *fault_counts.entry(f.fault.kind).or_insert(0) += 1;
    }
    let viewer = Tally {
        requested: viewer_frames.len(),
        completed: viewer_frames.iter().filter(|f| f.done.is_some()).count(),
        identical: viewer_frames.iter().filter(|f| f.identical == Some(true)).count(),
        lost: viewer_frames.iter().filter(|f| f.done.is_none()).count(),
        longest_frame: viewer_frames
            .iter()
            .filter_map(|f| f.done.map(|d| d - f.requested))
            .fold(0.0, f64::max),
    };
    let batch = Tally {
        requested: rounds.iter().map(|r| r.frames).sum(),
        completed: rounds.iter().map(|r| r.written).sum(),
        identical: rounds.iter().map(|r| r.identical).sum(),
        lost: rounds.iter().map(|r| r.frames - r.written).sum(),
        longest_frame: rounds.iter().map(BatchRound::longest_gap).fold(0.0, f64::max),
    };
    let completions: Vec<f64> = {
        let mut v: Vec<f64> = viewer_frames.iter().filter_map(|f| f.done).collect();
        v.extend(rounds.iter().flat_map(|r| r.done_at.iter().copied()));
        v.sort_by(f64::total_cmp);
        v
    };
    let recoveries = faults
        .iter()
        .filter_map(|f| f.master_started)
        .map(|t| {
            let next = completions.iter().copied().find(|&c| c > t);
            Recovery { master_started: t, next_frame: next, seconds: next.map(|n| n - t) }
        })
        .collect();
    let rss: Vec<rss::RssSummary> =
        rss_series.iter().map(|(name, s)| rss::summarize(name, s, wall)).collect();
    let rss_flat = rss.iter().filter(|r| r.process != BENCH_PROCESS).all(|r| r.flat);
    let mut notes = vec![
        "delay spikes: this kernel has no netem, so a spike drops every packet of the slave's cable, both \
         ways, for its span; the transports deliver what was sent then late (retransmitted)"
            .to_string(),
        format!(
            "memory flat: the last quarter's peak at most the second quarter's peak + {:.0} % + {} MiB \
             (peaks, since a restarted process starts small again)",
            rss::GROWTH * 100.0,
            rss::SLACK_KIB / 1024
        ),
    ];
    for f in faults.iter().filter(|f| f.error.is_some()) {
        notes.push(format!("fault at {:.1} s failed: {}", f.began, f.error.as_deref().unwrap_or("")));
    }
    let tiles_requeued = viewer_frames.iter().map(|f| u64::from(f.requeued)).sum();
    let tiles_duplicated = viewer_frames.iter().map(|f| u64::from(f.duplicated)).sum();
    ChaosReport {
        scene: args.scene.display().to_string(),
        path: args.path.display().to_string(),
        transport: args.transport.clone(),
        slaves: args.slaves,
        width,
        height,
        seed: args.seed,
        rate_mbit: args.rate,
        throttled_mbit: args.throttled,
        planned_seconds: seconds,
        wall_seconds: wall,
        faults,
        fault_counts,
        viewer,
        batch,
        batch_rounds: rounds.len(),
        recoveries,
        tiles_requeued,
        tiles_duplicated,
        rss,
        rss_series,
        rss_flat,
        viewer_frames: viewer_frames.into_iter().filter(ViewerFrame::notable).collect(),
        rounds: rounds.into_iter().filter(BatchRound::notable).collect(),
        notes,
        loadavg_before,
        loadavg_after: loadavg(),
        unix_time: crate::bench::report::unix_time(),
    }
}

pub(super) fn markdown(r: &ChaosReport) -> String {
    let mut out = format!(
        "Chaos soak: {:.0} s over {}, {} slave PCs (pc1 on {} Mbit/s, the others on {} Mbit/s), {}x{}, \
         seed {}; load average {} → {}.\n\n",
        r.planned_seconds,
        modes::transport_name(&r.transport),
        r.slaves,
        r.throttled_mbit,
        r.rate_mbit,
        r.width,
        r.height,
        r.seed,
        r.loadavg_before,
        r.loadavg_after
    );
    let tally = |name: &str, t: &Tally| {
        vec![
            name.to_string(),
            t.requested.to_string(),
            t.completed.to_string(),
            t.identical.to_string(),
            t.lost.to_string(),
            format!("{:.2}", t.longest_frame),
        ]
    };
    out.push_str(&report::table(
        &["client", "frames requested", "completed", "byte-identical", "lost", "longest frame s"],
        &[tally("viewer", &r.viewer), tally(&format!("batch ({} rounds)", r.batch_rounds), &r.batch)],
    ));
    let rec: Vec<f64> = r.recoveries.iter().filter_map(|x| x.seconds).collect();
    out.push_str(&format!(
        "\n**{} frames lost; {}; memory {}.** Tiles re-rendered (viewer frames): {} requeued from dead \
         slaves, {} copies to idle slaves. Master restarts: {}; recovery (new master started → next frame \
         completed) median {:.2} s, max {:.2} s{}.\n\n",
        r.lost(),
        if r.all_identical() { "every completed frame byte-identical" } else { "SOME FRAMES DIFFER" },
        if r.rss_flat { "flat" } else { "GROWS" },
        r.tiles_requeued,
        r.tiles_duplicated,
        r.recoveries.len(),
        report::median(&rec),
        rec.iter().copied().fold(0.0, f64::max),
        if rec.len() < r.recoveries.len() { " (some restarts were followed by no frame)" } else { "" }
    ));
    let counts: Vec<Vec<String>> =
        r.fault_counts.iter().map(|(k, n)| vec![k.describe().to_string(), n.to_string()]).collect();
    out.push_str(&report::table(&["fault", "injected"], &counts));
    let rss: Vec<Vec<String>> = r
        .rss
        .iter()
        .map(|s| {
            vec![
                s.process.clone(),
                format!("{:.1}", s.first_mib),
                format!("{:.1}", s.last_mib),
                format!("{:.1}", s.max_mib),
                format!("{:.1} → {:.1}", s.second_quarter_peak_mib, s.last_quarter_peak_mib),
                match (s.flat, s.process == BENCH_PROCESS) {
                    (_, true) => "not judged (holds the soak's records)".into(),
                    (true, false) => "flat".into(),
                    (false, false) => "grows".into(),
                },
            ]
        })
        .collect();
    out.push('\n');
    out.push_str(&report::table(
        &["process", "RSS first MiB", "last MiB", "max MiB", "peak 2nd → 4th quarter MiB", "verdict"],
        &rss,
    ));
    out.push_str("\nFaults (seconds from the start):\n\n");
    let rows: Vec<Vec<String>> = r
        .faults
        .iter()
        .map(|f| {
            vec![
                format!("{:.1}", f.began),
                f.fault.kind.describe().to_string(),
                f.fault.slave.map(|i| format!("pc{}", i + 1)).unwrap_or_else(|| "master".into()),
                format!("{:.2}", f.fault.secs),
                if f.fault.loss_per_mille > 0 {
                    format!("{:.1} %", f.fault.loss_per_mille as f64 / 10.0)
                } else {
                    String::new()
                },
                r.recoveries
                    .iter()
                    .find(|x| Some(x.master_started) == f.master_started)
                    .and_then(|x| x.seconds)
                    .map(|s| format!("{s:.2}"))
                    .unwrap_or_default(),
                f.error.clone().unwrap_or_default(),
            ]
        })
        .collect();
    out.push_str(&report::table(
        &["at s", "fault", "target", "span s", "loss", "recovery s", "error"],
        &rows,
    ));
    for n in &r.notes {
        out.push_str(&format!("\nNote: {n}.\n"));
    }
    out
}

/// Resident memory over time, one line per process.
pub(super) fn plot(path: &Path, r: &ChaosReport) -> anyhow::Result<()> {
    let series: Vec<report::Series> = r
        .rss_series
        .iter()
        .enumerate()
        .map(|(i, (name, s))| report::Series {
            name: name.clone(),
            points: s.iter().map(|x| (x.t, x.kib as f64 / 1024.0)).collect(),
            color: i,
            dashed: false,
        })
        .collect();
    report::line_plot(
        path,
        &report::Plot {
            title: "Resident memory during the chaos soak",
            x_label: "seconds from the start",
            y_label: "resident memory (MiB)",
            y_scale: report::YScale::Linear,
            x_names: None,
            series: &series,
        },
    )
}

//! Batch jobs: what a client said it will render ([`JobSpec`]) and which of
//! its frames are done, in a form the driver can write to disk and hand back
//! after a restart ([`JobRecord`]).

use crate::protocol::{JobSpec, JobStatus, SceneHash};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::time::Duration;

/// A job as it is stored: its spec and the frames done.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JobRecord {
    /// What the client submitted.
    pub spec: JobSpec,
    /// Frames completed, ascending.
    pub done: Vec<u32>,
}

/// Completions remembered for the rate (and so the ETA) of a job.
const RATE_WINDOW: usize = 16;

#[derive(Debug)]
pub(super) struct Job {
    pub(super) spec: JobSpec,
    pub(super) done: BTreeSet<u32>,
    /// The client running it now.
    pub(super) client: Option<u64>,
    /// When its latest frames completed (this run of the master).
    recent: VecDeque<Duration>,
    /// When it was last submitted or resumed (orders eviction).
    pub(super) touched: Duration,
}

impl Job {
    pub(super) fn record(&self) -> JobRecord {
        JobRecord { spec: self.spec.clone(), done: self.done.iter().copied().collect() }
    }

    pub(super) fn finished(&self) -> bool {
        self.done.len() as u64 >= u64::from(self.spec.frames)
    }

    /// Frame `index` completed at `now`; false if it was done already.
    pub(super) fn complete(&mut self, now: Duration, index: u32) -> bool {
        if !self.done.insert(index) {
            return false;
        }
        if self.recent.len() == RATE_WINDOW {
            self.recent.pop_front();
        }
        self.recent.push_back(now);
        true
    }

    pub(super) fn status(&self) -> JobStatus {
        let done = self.done.len() as u32;
        let left = self.spec.frames.saturating_sub(done);
        let eta_seconds = match (self.recent.front(), self.recent.back()) {
            (Some(a), Some(b)) if self.recent.len() >= 2 && b > a => {
                let per_frame = (*b - *a).as_secs_f32() / (self.recent.len() - 1) as f32;
                Some(per_frame * left as f32)
            }
            _ if left == 0 => Some(0.0),
            _ => None,
        };
        JobStatus {
            name: self.spec.name.clone(),
            done,
            frames: self.spec.frames,
            running: self.client.is_some(),
            eta_seconds,
        }
    }
}

/// Every job the master knows, by key, at most `max` of them.
#[derive(Debug)]
pub(super) struct Jobs {
    pub(super) by_key: BTreeMap<SceneHash, Job>,
    max: usize,
}

impl Jobs {
    pub(super) fn new(max: usize) -> Self {
        Self { by_key: BTreeMap::new(), max }
    }

    /// A job submitted (or resubmitted) by `client`: the existing one if its
    /// key is known, else a new one — making room by forgetting the oldest
    /// job nobody runs. `None` if there is no room.
    pub(super) fn submit(&mut self, now: Duration, spec: JobSpec, client: u64) -> Option<&mut Job> {
        if !self.by_key.contains_key(&spec.key) {
            if self.by_key.len() >= self.max {
                let oldest = self
                    .by_key
                    .iter()
                    .filter(|(_, j)| j.client.is_none())
                    .min_by_key(|(_, j)| (!j.finished(), j.touched))
                    .map(|(k, _)| *k)?;
                self.by_key.remove(&oldest);
            }
            let job = Job {
                spec: spec.clone(),
                done: BTreeSet::new(),
                client: None,
                recent: VecDeque::new(),
                touched: now,
            };
            self.by_key.insert(spec.key, job);
        }
        let job = self.by_key.get_mut(&spec.key)?;
        job.client = Some(client);
        job.touched = now;
        Some(job)
    }

    /// A job as read back from disk (its client is away until it returns).
    pub(super) fn restore(&mut self, now: Duration, record: JobRecord) {
        let job = Job {
            spec: record.spec,
            done: record.done.into_iter().collect(),
            client: None,
            recent: VecDeque::new(),
            touched: now,
        };
        if self.by_key.len() < self.max {
            self.by_key.insert(job.spec.key, job);
        }
    }

    /// `client` left: its job waits for it.
    pub(super) fn detach(&mut self, client: u64) {
        for j in self.by_key.values_mut().filter(|j| j.client == Some(client)) {
            j.client = None;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use isin_tracer::RenderSettings;

    fn spec(key: u8, frames: u32) -> JobSpec {
        JobSpec {
            key: [key; 32],
            name: format!("job{key}"),
            scene: [0; 32],
            frames,
            settings: RenderSettings::default(),
        }
    }

    #[test]
    fn a_resubmitted_job_keeps_its_done_frames_and_the_eta_follows_the_rate() {
        let mut jobs = Jobs::new(4);
        let s = Duration::from_secs(1);
        let j = jobs.submit(s, spec(1, 10), 7).unwrap();
        assert!(j.complete(s, 0) && j.complete(2 * s, 1) && !j.complete(3 * s, 1));
        assert_eq!(j.status().eta_seconds, Some(8.0));
        jobs.detach(7);
        assert!(!jobs.by_key[&[1; 32]].status().running);
        let again = jobs.submit(4 * s, spec(1, 10), 9).unwrap();
        assert_eq!(again.record().done, vec![0, 1]);
        assert_eq!(again.client, Some(9));
    }

    #[test]
    fn a_full_table_forgets_finished_jobs_nobody_runs_first_and_never_a_running_one() {
        let mut jobs = Jobs::new(2);
        let s = Duration::from_secs(1);
        jobs.submit(s, spec(1, 1), 1).unwrap().complete(s, 0);
        jobs.submit(2 * s, spec(2, 5), 2).unwrap();
        assert!(jobs.submit(3 * s, spec(3, 5), 3).is_none(), "both run");
        jobs.detach(1);
        jobs.detach(2);
        jobs.submit(4 * s, spec(3, 5), 3).unwrap();
        assert!(!jobs.by_key.contains_key(&[1; 32]), "the finished one went");
        assert!(jobs.by_key.contains_key(&[2; 32]));
    }
}

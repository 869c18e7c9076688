//! The master's state directory (`isin master --state DIR`): the scenes
//! clients uploaded and the batch jobs, as the core asks them kept
//! ([`Stored`]), so that a master restarted after a crash — `kill -9`
//! included — knows every job and which of its frames are done.
//!
//! Layout: `DIR/scenes/HASH.scene` (the scene packed as slaves receive it:
//! header and compressed stream, `isin_cluster::scene_stream::Packed::to_stored`)
//! and `DIR/jobs/KEY.job` (a [`JobRecord`] in MessagePack), `HASH` and `KEY`
//! in hex. Every file is written whole to a temporary name, flushed to disk
//! and renamed over the old one, so a crash leaves the old or the new
//! version, never half of one.

use isin_cluster::{JobRecord, Stored};
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Why the state directory could not be used.
#[derive(Debug, thiserror::Error)]
pub enum StateError {
    /// A file or folder could not be read or written.
    #[error("state directory {path}: {source}")]
    Io {
        /// The path.
        path: PathBuf,
        /// What failed.
        source: std::io::Error,
    },
    /// A job file is not a job.
    #[error("state file {path} is damaged: {why}")]
    Damaged {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        why: String,
    },
}

/// What a state directory held at start.
#[derive(Debug, Default)]
pub struct Loaded {
    /// Stored scenes.
    pub scenes: Vec<(PathBuf, Vec<u8>)>,
    /// Jobs.
    pub jobs: Vec<JobRecord>,
}

/// A master's state directory.
#[derive(Debug, Clone)]
pub struct StateDir {
    root: PathBuf,
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> StateError + '_ {
    move |source| StateError::Io { path: path.to_path_buf(), source }
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

impl StateDir {
    /// Opens (creating it if needed) the directory at `root` and reads what
    /// it holds.
    pub fn open(root: &Path) -> Result<(Self, Loaded), StateError> {
        let dir = Self { root: root.to_path_buf() };
        let mut loaded = Loaded::default();
        for sub in ["scenes", "jobs"] {
            let path = root.join(sub);
            fs::create_dir_all(&path).map_err(io(&path))?;
        }
        for (path, bytes) in dir.files("scenes", "scene")? {
            loaded.scenes.push((path, bytes));
        }
        for (path, bytes) in dir.files("jobs", "job")? {
            let job = rmp_serde::from_slice(&bytes)
                .map_err(|e| StateError::Damaged { path: path.clone(), why: e.to_string() })?;
            loaded.jobs.push(job);
        }
        Ok((dir, loaded))
    }

    /// Every `*.ext` file of `sub`, sorted by name; leftover temporary files
    /// of an interrupted write are removed.
    fn files(&self, sub: &str, ext: &str) -> Result<Vec<(PathBuf, Vec<u8>)>, StateError> {
        let dir = self.root.join(sub);
        let mut out = Vec::new();
        for entry in fs::read_dir(&dir).map_err(io(&dir))? {
            let path = entry.map_err(io(&dir))?.path();
            match path.extension().and_then(|e| e.to_str()) {
                Some(e) if e == ext => {
                    let bytes = fs::read(&path).map_err(io(&path))?;
                    out.push((path, bytes));
                }
                Some("tmp") => {
                    let _ = fs::remove_file(&path);
                }
                _ => {}
            }
        }
        out.sort_by(|a, b| a.0.cmp(&b.0));
        Ok(out)
    }

    /// Keeps what the core asked kept; returns once it is on disk.
    pub fn store(&self, what: &Stored) -> Result<(), StateError> {
        match what {
            Stored::Scene { hash, bytes } => self.write(&self.scene_path(hash), bytes),
            Stored::ForgetScene { hash } => {
                let path = self.scene_path(hash);
                match fs::remove_file(&path) {
                    Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(io(&path)(e)),
                    _ => Ok(()),
                }
            }
            Stored::Job(record) => {
                let bytes = rmp_serde::to_vec(record).map_err(|e| StateError::Damaged {
                    path: self.job_path(&record.spec.key),
                    why: e.to_string(),
                })?;
                self.write(&self.job_path(&record.spec.key), &bytes)
            }
        }
    }

    fn scene_path(&self, hash: &[u8; 32]) -> PathBuf {
        self.root.join("scenes").join(format!("{}.scene", hex(hash)))
    }

    fn job_path(&self, key: &[u8; 32]) -> PathBuf {
        self.root.join("jobs").join(format!("{}.job", hex(key)))
    }

    /// Writes `bytes` to `path` whole: a temporary file, synced, renamed.
    fn write(&self, path: &Path, bytes: &[u8]) -> Result<(), StateError> {
        let tmp = path.with_extension("tmp");
        let mut f = fs::File::create(&tmp).map_err(io(&tmp))?;
        f.write_all(bytes).map_err(io(&tmp))?;
        f.sync_all().map_err(io(&tmp))?;
        fs::rename(&tmp, path).map_err(io(path))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use isin_cluster::protocol::JobSpec;
    use isin_tracer::RenderSettings;
    use std::sync::Arc;

    fn temp_dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("isin-state-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        dir
    }

    #[test]
    fn what_is_stored_is_read_back_and_forgotten_scenes_stay_gone() {
        let root = temp_dir("roundtrip");
        let (dir, loaded) = StateDir::open(&root).unwrap();
        assert!(loaded.scenes.is_empty() && loaded.jobs.is_empty());
        let spec = JobSpec {
            key: [1; 32],
            name: "frames".into(),
            scene: [2; 32],
            frames: 9,
            settings: RenderSettings::default(),
        };
        dir.store(&Stored::Scene { hash: [2; 32], bytes: Arc::new(vec![1, 2, 3]) }).unwrap();
        dir.store(&Stored::Scene { hash: [3; 32], bytes: Arc::new(vec![4]) }).unwrap();
        dir.store(&Stored::Job(JobRecord { spec: spec.clone(), done: vec![0] })).unwrap();
        dir.store(&Stored::Job(JobRecord { spec: spec.clone(), done: vec![0, 4] })).unwrap();
        dir.store(&Stored::ForgetScene { hash: [3; 32] }).unwrap();
        dir.store(&Stored::ForgetScene { hash: [3; 32] }).unwrap();
        // An interrupted write leaves a temporary file: ignored and removed.
        fs::write(root.join("jobs").join("x.tmp"), b"half").unwrap();
        let (_, loaded) = StateDir::open(&root).unwrap();
        assert_eq!(loaded.scenes.len(), 1);
        assert_eq!(loaded.scenes[0].1, vec![1, 2, 3]);
        assert_eq!(loaded.jobs, vec![JobRecord { spec, done: vec![0, 4] }]);
        assert!(!root.join("jobs").join("x.tmp").exists());
        fs::write(root.join("jobs").join("bad.job"), b"\xc1").unwrap();
        let err = StateDir::open(&root).unwrap_err();
        assert!(err.to_string().contains("bad.job") && err.to_string().contains("damaged"), "{err}");
        let _ = fs::remove_dir_all(&root);
    }
}

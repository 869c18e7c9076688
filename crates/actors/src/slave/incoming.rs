//! A scene coming in from the master: its chunks unpacked as they arrive
//! ([`Receiver`]: every size checked first, the hash at the end), its
//! progress logged, and how long it took.

use isin_cluster::protocol::{SceneHash, SceneHeader, short_hash};
use isin_cluster::scene_stream::{Progress, ProgressLog, Receiver, StreamError, Unchecked};
use isin_tracer::SceneBundle;
use std::time::Instant;

/// One scene being received.
#[derive(Debug)]
pub(super) struct Incoming {
    rx: Receiver,
    log: ProgressLog,
    since: Instant,
}

impl Incoming {
    /// The master announced `header`.
    pub(super) fn begin(header: SceneHeader) -> Result<Self, StreamError> {
        let what = format!("receiving scene {} ({})", header.name, short_hash(&header.hash));
        let log = ProgressLog::new(what, header.compressed_bytes, std::time::Duration::ZERO);
        Ok(Self { rx: Receiver::new(header)?, log, since: Instant::now() })
    }

    /// The scene's hash.
    pub(super) fn hash(&self) -> SceneHash {
        self.rx.header().hash
    }

    /// Takes the next chunk.
    pub(super) fn chunk(
        &mut self,
        hash: &SceneHash,
        index: u32,
        bytes: &[u8],
    ) -> Result<Progress, StreamError> {
        let p = self.rx.push(hash, index, bytes)?;
        self.log.update(self.since.elapsed(), p.bytes);
        Ok(p)
    }

    /// The bundle, once every chunk is in (decoded, its hash checked).
    pub(super) fn finish(self) -> Result<SceneBundle, StreamError> {
        self.decode()?.check()
    }

    /// The bundle, once every chunk is in, decoded and handed to `work`
    /// (loading it) while its hash is checked beside it; `work`'s output
    /// only if the hash matched.
    pub(super) fn finish_with<T: Send>(
        self,
        work: impl FnOnce(&SceneBundle) -> T,
    ) -> Result<(SceneBundle, T), StreamError> {
        self.decode()?.check_with(work)
    }

    /// The bundle decoded, its hash not checked yet; the transfer logged.
    fn decode(self) -> Result<Unchecked, StreamError> {
        let h = self.rx.header().clone();
        let received = self.since.elapsed();
        let t0 = Instant::now();
        let unchecked = self.rx.decode()?;
        tracing::info!(
            "scene {} received: {} bytes compressed, {} unpacked, in {:.3} s (decoded in {:.3} s)",
            h.name,
            h.compressed_bytes,
            h.raw_bytes,
            received.as_secs_f64(),
            t0.elapsed().as_secs_f64()
        );
        Ok(unchecked)
    }
}

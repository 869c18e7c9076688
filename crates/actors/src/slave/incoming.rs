//! A scene coming in from the master: its chunks unpacked as they arrive
//! ([`Receiver`]: every size checked first, the hash at the end) on a thread
//! of their own, its progress logged, and how long it took.
//!
//! Unpacking a chunk (zstd, about 0.8 GB/s here) on the thread that reads the
//! connection held the reading up: the dragon's 1.2 MB came in over 1 Gbit/s
//! in 13 ms with each chunk unpacked as it arrived, in 7 ms without. So each
//! chunk is acknowledged as it arrives and unpacked beside the reading; a
//! chunk the [`Receiver`] refuses ends the transfer at the next chunk, or at
//! the end. The chunks waiting to be unpacked are bounded by the scene's
//! compressed size, which its header declared and [`Receiver::new`] bounded.

use isin_cluster::protocol::{SceneHash, SceneHeader, short_hash};
use isin_cluster::scene_stream::{Progress, ProgressLog, Receiver, StreamError, Unchecked};
use isin_tracer::SceneBundle;
use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// A chunk for the unpacking thread: scene, index and bytes.
type Chunk = (SceneHash, u32, Vec<u8>);

/// The unpacking thread: the receiver back, or the first error.
type Unpacker = JoinHandle<Result<Receiver, StreamError>>;

/// Where the chunks are unpacked.
#[derive(Debug)]
enum Unpacking {
    /// On a thread of its own, fed through a channel; it hands back the
    /// receiver when the channel closes.
    Beside { feed: mpsc::Sender<Chunk>, thread: Unpacker },
    /// Here, as they arrive (no thread could be started).
    Inline(Receiver),
    /// The unpacking stopped at a chunk it refused (its error was
    /// returned then), or was handed back.
    Failed,
}

/// Starts a thread that pushes the chunks it is fed into `rx`, and hands
/// `rx` back when the feed closes (or the first error).
fn unpack_beside(mut rx: Receiver) -> std::io::Result<(mpsc::Sender<Chunk>, Unpacker)> {
    let (feed, chunks) = mpsc::channel::<Chunk>();
    let thread = std::thread::Builder::new().name("isin-unpack".into()).spawn(move || {
        for (hash, index, bytes) in chunks {
            rx.push(&hash, index, &bytes)?;
        }
        Ok(rx)
    })?;
    Ok((feed, thread))
}

/// One scene being received.
#[derive(Debug)]
pub(super) struct Incoming {
    header: SceneHeader,
    unpacking: Unpacking,
    /// Chunks and compressed bytes taken so far.
    taken: Progress,
    log: ProgressLog,
    since: Instant,
    /// When the last chunk came in.
    received: Option<Duration>,
}

impl Incoming {
    /// The master announced `header`.
    pub(super) fn begin(header: SceneHeader) -> Result<Self, StreamError> {
        let what = format!("receiving scene {} ({})", header.name, short_hash(&header.hash));
        let log = ProgressLog::new(what, header.compressed_bytes, Duration::ZERO);
        let unpacking = match unpack_beside(Receiver::new(header.clone())?) {
            Ok((feed, thread)) => Unpacking::Beside { feed, thread },
            Err(e) => {
                tracing::debug!("unpacking the scene inline: {e}");
                Unpacking::Inline(Receiver::new(header.clone())?)
            }
        };
        let taken = Progress { chunks: 0, bytes: 0, complete: false };
        Ok(Self { header, unpacking, taken, log, since: Instant::now(), received: None })
    }

    /// The scene's hash.
    pub(super) fn hash(&self) -> SceneHash {
        self.header.hash
    }

    /// Takes the next chunk: unpacked beside the reading (or here), its
    /// progress counted as it arrives. An error the unpacking met with an
    /// earlier chunk comes back here.
    pub(super) fn chunk(
        &mut self,
        hash: &SceneHash,
        index: u32,
        bytes: Vec<u8>,
    ) -> Result<Progress, StreamError> {
        if self.taken.complete {
            return Err(StreamError::OutOfOrder { want: self.header.chunks, got: index });
        }
        let len = bytes.len() as u64;
        match &mut self.unpacking {
            Unpacking::Inline(rx) => {
                rx.push(hash, index, &bytes)?;
            }
            Unpacking::Beside { feed, .. } => {
                if feed.send((*hash, index, bytes)).is_err() {
                    // The thread stopped: at a chunk it refused.
                    let stopped = || StreamError::Corrupt("the scene's unpacking stopped".into());
                    return Err(self.take_receiver().err().unwrap_or_else(stopped));
                }
            }
            Unpacking::Failed => return Err(StreamError::Corrupt("the scene failed to unpack".into())),
        }
        self.taken.chunks += 1;
        self.taken.bytes += len;
        self.taken.complete = self.taken.chunks >= self.header.chunks;
        if self.taken.complete {
            self.received = Some(self.since.elapsed());
        }
        self.log.update(self.since.elapsed(), self.taken.bytes);
        Ok(self.taken)
    }

    /// The receiver, every chunk fed so far unpacked (waiting for the
    /// thread), or the error that stopped the unpacking; unpacking is over.
    fn take_receiver(&mut self) -> Result<Receiver, StreamError> {
        match std::mem::replace(&mut self.unpacking, Unpacking::Failed) {
            Unpacking::Inline(rx) => Ok(rx),
            Unpacking::Beside { feed, thread } => {
                drop(feed);
                thread.join().map_err(|_| StreamError::Corrupt("the scene's unpacking panicked".into()))?
            }
            Unpacking::Failed => Err(StreamError::Corrupt("the scene failed to unpack".into())),
        }
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

    /// The bundle decoded, its hash not checked yet; the transfer logged
    /// ("decoded in" counts the wait for the last chunks' unpacking too).
    fn decode(mut self) -> Result<Unchecked, StreamError> {
        let h = self.header.clone();
        let received = self.received.unwrap_or_else(|| self.since.elapsed());
        let t0 = Instant::now();
        let unchecked = self.take_receiver()?.decode()?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use isin_cluster::protocol::{self, Message};
    use isin_cluster::scene_stream::pack;
    use std::collections::BTreeMap;

    /// A bundle of about 1.3 MB that packs into several chunks: text that
    /// compresses and bytes from a generator that do not.
    fn bundle() -> SceneBundle {
        let text: Vec<u8> = (0..1 << 20).map(|i| b"v 1.0 2.0 3.0\n"[i % 14]).collect();
        let mut x = 0x2545_f491_4f6c_dd1du64;
        let noise: Vec<u8> = (0..300_000)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                x as u8
            })
            .collect();
        let assets = BTreeMap::from([("mesh.obj".to_string(), text), ("noise.bin".to_string(), noise)]);
        SceneBundle { name: "s.toml".into(), source: "[camera]".into(), assets }
    }

    /// The packed scene's header and its chunks as the slave reads them.
    fn chunks(b: &SceneBundle) -> (SceneHeader, Vec<(SceneHash, u32, Vec<u8>)>) {
        let p = pack(b).unwrap();
        let chunks = (0..p.header.chunks)
            .map(|i| match protocol::decode(&p.chunk_frame(i).unwrap(), usize::MAX).unwrap() {
                Message::SceneChunk { hash, index, bytes } => (hash, index, bytes.into_vec()),
                other => panic!("{other:?}"),
            })
            .collect();
        (p.header, chunks)
    }

    #[test]
    fn a_scene_unpacked_beside_the_reading_comes_out_whole() {
        let b = bundle();
        let (header, all) = chunks(&b);
        assert!(all.len() >= 2, "{header:?}");
        let mut incoming = Incoming::begin(header).unwrap();
        assert!(matches!(incoming.unpacking, Unpacking::Beside { .. }));
        for (i, (hash, index, bytes)) in all.into_iter().enumerate() {
            let p = incoming.chunk(&hash, index, bytes).unwrap();
            assert_eq!(p.chunks as usize, i + 1);
            assert_eq!(p.complete, i as u32 + 1 == incoming.header.chunks);
        }
        assert_eq!(incoming.finish().unwrap(), b);
    }

    #[test]
    fn a_chunk_the_unpacking_refuses_ends_the_transfer_then_or_at_the_end() {
        let b = bundle();
        let (header, all) = chunks(&b);
        // Chunk 0 twice, then the rest: the second is out of order.
        let mut incoming = Incoming::begin(header.clone()).unwrap();
        let mut refused = None;
        for (hash, index, bytes) in std::iter::once(all[0].clone()).chain(all.iter().cloned()) {
            match incoming.chunk(&hash, index, bytes) {
                Ok(p) if p.complete => break,
                Ok(_) => {}
                Err(e) => {
                    refused = Some(e);
                    break;
                }
            }
        }
        let error = match refused {
            Some(e) => e,
            None => incoming.finish().expect_err("a scene with a chunk out of order"),
        };
        assert!(matches!(error, StreamError::OutOfOrder { want: 1, got: 0 }), "{error:?}");

        // A cut chunk: refused for its size.
        let mut incoming = Incoming::begin(header).unwrap();
        let (hash, index, bytes) = all[0].clone();
        let cut = incoming.chunk(&hash, index, bytes[1..].to_vec()).and_then(|_| {
            let (hash, index, bytes) = all[1].clone();
            incoming.chunk(&hash, index, bytes)
        });
        let error = match cut {
            Err(e) => e,
            Ok(_) => incoming.finish().expect_err("a scene with a cut chunk"),
        };
        assert!(matches!(error, StreamError::ChunkSize { index: 0, .. }), "{error:?}");
    }
}

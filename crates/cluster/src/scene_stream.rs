//! A scene as it travels: packed once by the master — its
//! [`WireBundle`](protocol::WireBundle) in MessagePack, compressed with zstd
//! and cut into [`SCENE_CHUNK_BYTES`] chunks, each chunk's [`Message::SceneChunk`] encoded
//! once and shared by every slave it goes to — and unpacked by a
//! [`Receiver`] as the chunks arrive.
//!
//! The receiver takes untrusted bytes. It checks the header's sizes against
//! [`MAX_SCENE_RAW_BYTES`] and [`MAX_SCENE_COMPRESSED_BYTES`] and its chunk
//! count against the compressed size before it holds a byte, takes chunks
//! only in order and only of the announced size, decompresses each as it
//! arrives (so the bundle is ready as soon as the last one is in), never
//! grows the decompressed bytes past what the header declared, and checks
//! the bundle's hash at the end. The zstd window it accepts is bounded too
//! ([`MAX_WINDOW_LOG`]), so a hostile stream cannot make it allocate a large
//! history.

use crate::limits::{MAX_SCENE_COMPRESSED_BYTES, MAX_SCENE_RAW_BYTES, SCENE_CHUNK_BYTES};
use crate::protocol::{self, MAX_SCENE_NAME, Message, SceneHash, SceneHeader};
use isin_tracer::SceneBundle;
use serde::{Deserialize, Serialize};
use serde_bytes::{ByteBuf, Bytes};
use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;
use zstd::stream::raw::{DParameter, Decoder, InBuffer, Operation, OutBuffer};

/// The zstd level scenes are compressed with: meshes and textures compress
/// well enough at it, and the master packs a scene once.
pub const LEVEL: i32 = 6;

/// Largest zstd window (as a power of two) a receiver accepts: 16 MiB, above
/// the 2 MiB window of [`LEVEL`].
pub const MAX_WINDOW_LOG: u32 = 24;

/// Bytes decompressed at a time.
const SCRATCH: usize = 128 << 10;

/// Why a scene could not be packed or received.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum StreamError {
    /// A declared size beyond its limit.
    #[error("the scene's {what} is {bytes} bytes, more than the {max} accepted")]
    TooLarge {
        /// Which size.
        what: &'static str,
        /// Its declared value.
        bytes: u64,
        /// The limit.
        max: u64,
    },
    /// A header whose numbers do not fit together.
    #[error("bad scene header: {0}")]
    BadHeader(String),
    /// A chunk of another scene than the one being received.
    #[error("a chunk of scene {got}, while scene {want} is being received")]
    WrongScene {
        /// The scene being received (short hash).
        want: String,
        /// The chunk's (short hash).
        got: String,
    },
    /// A chunk out of order.
    #[error("scene chunk {got} arrived where chunk {want} was due")]
    OutOfOrder {
        /// The chunk due.
        want: u32,
        /// The chunk that came.
        got: u32,
    },
    /// A chunk of the wrong size.
    #[error("scene chunk {index} holds {bytes} bytes, not {want}")]
    ChunkSize {
        /// The chunk.
        index: u32,
        /// Its size.
        bytes: usize,
        /// The size due.
        want: usize,
    },
    /// The compressed stream is damaged, or decompresses to more than declared.
    #[error("the compressed scene is damaged: {0}")]
    Corrupt(String),
    /// Finished before every chunk was in.
    #[error("the scene is incomplete: {got} of {want} chunks")]
    Incomplete {
        /// Chunks received.
        got: u32,
        /// Chunks announced.
        want: u32,
    },
    /// The decompressed bytes are not a bundle.
    #[error("the scene does not decode: {0}")]
    Decode(String),
    /// The bundle is not the one the header named.
    #[error("the scene does not match its hash")]
    HashMismatch,
    /// The bundle could not be packed.
    #[error("cannot pack the scene: {0}")]
    Encode(String),
}

/// A scene packed for the wire (see the [module docs](self)): the
/// [`Message::SceneBegin`] and every [`Message::SceneChunk`], encoded once.
#[derive(Debug)]
pub struct Packed {
    /// What the `SceneBegin` says.
    pub header: SceneHeader,
    begin: Arc<Vec<u8>>,
    chunks: Vec<Arc<Vec<u8>>>,
}

/// [`protocol::WireBundle`] by reference: encodes to the same bytes without copying
/// the assets, and decodes borrowing them from the bytes.
#[derive(Serialize, Deserialize)]
struct WireBundleRef<'a> {
    #[serde(borrow)]
    name: &'a str,
    #[serde(borrow)]
    source: &'a str,
    #[serde(borrow)]
    assets: BTreeMap<&'a str, &'a Bytes>,
}

/// A writer that only counts the bytes written to it.
struct Counter(usize);

impl std::io::Write for Counter {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0 += buf.len();
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// A packed scene as a master keeps it on disk.
#[derive(Serialize, Deserialize)]
struct StoredScene {
    header: SceneHeader,
    compressed: ByteBuf,
}

/// First bytes of a stored scene.
const STORED_MAGIC: &[u8; 6] = b"isinsc";

/// A file name cut to at most [`MAX_SCENE_NAME`] bytes, on a character boundary.
fn header_name(name: &str) -> String {
    let mut end = name.len().min(MAX_SCENE_NAME);
    while !name.is_char_boundary(end) {
        end -= 1;
    }
    name[..end].to_string()
}

/// Packs `bundle` (named as it is served): encoded, compressed at [`LEVEL`],
/// cut into chunks. Its hash is [`protocol::scene_hash`] of it.
pub fn pack(bundle: &SceneBundle) -> Result<Packed, StreamError> {
    let raw = encode_bundle(bundle)?;
    let compressed =
        zstd::bulk::compress(&raw, LEVEL).map_err(|e| StreamError::Encode(format!("zstd: {e}")))?;
    let hash = protocol::scene_hash(bundle);
    Packed::from_compressed(hash, &bundle.name, raw.len() as u64, &compressed)
}

impl Packed {
    fn from_compressed(
        hash: SceneHash,
        name: &str,
        raw_bytes: u64,
        compressed: &[u8],
    ) -> Result<Self, StreamError> {
        let chunks = compressed.len().div_ceil(SCENE_CHUNK_BYTES);
        let header = SceneHeader {
            hash,
            name: header_name(name),
            raw_bytes,
            compressed_bytes: compressed.len() as u64,
            chunks: u32::try_from(chunks).map_err(|_| StreamError::Encode("too many chunks".into()))?,
        };
        check_header(&header)?;
        let encode = |m: &Message| protocol::encode(m).map_err(|e| StreamError::Encode(e.to_string()));
        let begin = Arc::new(encode(&Message::SceneBegin(header.clone()))?);
        let chunks = compressed
            .chunks(SCENE_CHUNK_BYTES)
            .enumerate()
            .map(|(i, bytes)| {
                let m = Message::SceneChunk { hash, index: i as u32, bytes: ByteBuf::from(bytes.to_vec()) };
                encode(&m).map(Arc::new)
            })
            .collect::<Result<_, _>>()?;
        Ok(Self { header, begin, chunks })
    }

    /// The encoded [`Message::SceneBegin`].
    pub fn begin_frame(&self) -> Arc<Vec<u8>> {
        self.begin.clone()
    }

    /// The encoded [`Message::SceneChunk`] number `index`.
    pub fn chunk_frame(&self, index: u32) -> Option<Arc<Vec<u8>>> {
        self.chunks.get(index as usize).cloned()
    }

    /// Bytes of every frame that carries the scene (begin and chunks).
    pub fn wire_bytes(&self) -> u64 {
        (self.begin.len() + self.chunks.iter().map(|c| c.len()).sum::<usize>()) as u64
    }

    /// The scene as a master stores it on disk: the header and the
    /// compressed stream ([`Packed::from_stored`] reads it back).
    pub fn to_stored(&self) -> Result<Vec<u8>, StreamError> {
        let mut compressed = Vec::with_capacity(self.header.compressed_bytes as usize);
        for frame in &self.chunks {
            match protocol::decode(frame, usize::MAX) {
                Ok(Message::SceneChunk { bytes, .. }) => compressed.extend_from_slice(&bytes),
                _ => return Err(StreamError::Encode("a packed chunk does not decode".into())),
            }
        }
        let stored = StoredScene { header: self.header.clone(), compressed: ByteBuf::from(compressed) };
        let mut out = STORED_MAGIC.to_vec();
        rmp_serde::encode::write(&mut out, &stored).map_err(|e| StreamError::Encode(e.to_string()))?;
        Ok(out)
    }

    /// Reads back what [`Packed::to_stored`] wrote: every check of a
    /// [`Receiver`] applies (the bytes may be damaged). Returns the packed
    /// scene and its bundle.
    pub fn from_stored(bytes: &[u8]) -> Result<(Self, SceneBundle), StreamError> {
        let body = bytes
            .strip_prefix(STORED_MAGIC.as_slice())
            .ok_or_else(|| StreamError::Decode("not a stored scene".into()))?;
        let mut de = rmp_serde::Deserializer::new(std::io::Cursor::new(body));
        let stored = StoredScene::deserialize(&mut de).map_err(|e| StreamError::Decode(e.to_string()))?;
        let header = stored.header;
        let mut rx = Receiver::new(header.clone())?;
        for (i, chunk) in stored.compressed.chunks(SCENE_CHUNK_BYTES).enumerate() {
            rx.push(&header.hash, i as u32, chunk)?;
        }
        let bundle = rx.finish()?;
        let packed = Self::from_compressed(header.hash, &header.name, header.raw_bytes, &stored.compressed)?;
        Ok((packed, bundle))
    }
}

/// The bundle as a scene stream holds it before compression: its
/// [`WireBundle`](protocol::WireBundle) in MessagePack.
pub fn encode_bundle(bundle: &SceneBundle) -> Result<Vec<u8>, StreamError> {
    let view = WireBundleRef {
        name: &bundle.name,
        source: &bundle.source,
        assets: bundle.assets.iter().map(|(k, v)| (k.as_str(), Bytes::new(v))).collect(),
    };
    rmp_serde::to_vec(&view).map_err(|e| StreamError::Encode(e.to_string()))
}

/// Decodes what [`encode_bundle`] wrote (untrusted bytes: declared lengths
/// are checked against the bytes present before anything is allocated;
/// trailing bytes, or anything [`encode_bundle`] would not have written for
/// the same bundle, are refused). Each asset is copied out once.
pub fn decode_bundle(raw: &[u8]) -> Result<SceneBundle, StreamError> {
    let view = decode_view(raw)?;
    Ok(SceneBundle {
        name: view.name.to_string(),
        source: view.source.to_string(),
        assets: view.assets.iter().map(|(k, v)| (k.to_string(), v.to_vec())).collect(),
    })
}

/// [`decode_bundle`] that keeps `raw`'s memory for the largest asset (its
/// bytes moved to the front): a joining slave decodes a fresh scene, and
/// copying it into fresh pages cost 4 ms for the 3.3 MB dragon, most of it
/// faulting the pages in, on the way to its first tile.
pub fn decode_bundle_owned(mut raw: Vec<u8>) -> Result<SceneBundle, StreamError> {
    let (mut bundle, largest) = {
        let view = decode_view(&raw)?;
        // Borrowed from `raw`: its place there (checked all the same).
        let within = |v: &[u8]| {
            let at = (v.as_ptr() as usize).checked_sub(raw.as_ptr() as usize)?;
            (at.checked_add(v.len())? <= raw.len()).then_some(at)
        };
        let largest = view
            .assets
            .iter()
            .max_by_key(|(_, v)| v.len())
            .and_then(|(k, v)| Some((k.to_string(), within(v)?, v.len())));
        let others = view.assets.iter().filter(|(k, _)| largest.as_ref().is_none_or(|l| l.0 != **k));
        let bundle = SceneBundle {
            name: view.name.to_string(),
            source: view.source.to_string(),
            assets: others.map(|(k, v)| (k.to_string(), v.to_vec())).collect(),
        };
        (bundle, largest)
    };
    if let Some((path, at, len)) = largest {
        raw.copy_within(at..at + len, 0);
        raw.truncate(len);
        bundle.assets.insert(path, raw);
    }
    Ok(bundle)
}

/// The bundle in `raw`, borrowed, if `raw` is exactly what [`encode_bundle`]
/// writes for it.
fn decode_view(raw: &[u8]) -> Result<WireBundleRef<'_>, StreamError> {
    let view: WireBundleRef = rmp_serde::from_slice(raw).map_err(|e| StreamError::Decode(e.to_string()))?;
    let mut len = Counter(0);
    rmp_serde::encode::write(&mut len, &view).map_err(|e| StreamError::Decode(e.to_string()))?;
    if len.0 != raw.len() {
        return Err(StreamError::Decode(format!(
            "the bundle is {} of the {} bytes, or not as a master encodes it",
            len.0,
            raw.len()
        )));
    }
    Ok(view)
}

/// Checks a header's sizes and chunk count (see the [module docs](self)).
pub fn check_header(h: &SceneHeader) -> Result<(), StreamError> {
    if h.raw_bytes > MAX_SCENE_RAW_BYTES {
        return Err(StreamError::TooLarge { what: "bundle", bytes: h.raw_bytes, max: MAX_SCENE_RAW_BYTES });
    }
    if h.compressed_bytes > MAX_SCENE_COMPRESSED_BYTES {
        let (bytes, max) = (h.compressed_bytes, MAX_SCENE_COMPRESSED_BYTES);
        return Err(StreamError::TooLarge { what: "compressed stream", bytes, max });
    }
    if h.raw_bytes == 0 || h.compressed_bytes == 0 {
        return Err(StreamError::BadHeader("an empty scene".into()));
    }
    let want = h.compressed_bytes.div_ceil(SCENE_CHUNK_BYTES as u64);
    if u64::from(h.chunks) != want {
        return Err(StreamError::BadHeader(format!(
            "{} chunks for {} compressed bytes (want {want})",
            h.chunks, h.compressed_bytes
        )));
    }
    Ok(())
}

/// Where a [`Receiver`] stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Progress {
    /// Chunks received.
    pub chunks: u32,
    /// Compressed bytes received.
    pub bytes: u64,
    /// Whether every chunk is in.
    pub complete: bool,
}

/// Unpacks one scene as its chunks arrive (see the [module docs](self)).
pub struct Receiver {
    header: SceneHeader,
    decoder: Decoder<'static>,
    raw: Vec<u8>,
    scratch: Vec<u8>,
    next: u32,
    received: u64,
    /// The zstd frame ended (no input may follow).
    ended: bool,
}

impl std::fmt::Debug for Receiver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Receiver").field("header", &self.header).field("next", &self.next).finish()
    }
}

impl Receiver {
    /// Ready for the chunks `header` announces, once its numbers pass
    /// [`check_header`]. Nothing the size of the scene is allocated yet.
    pub fn new(header: SceneHeader) -> Result<Self, StreamError> {
        check_header(&header)?;
        let mut decoder = Decoder::new().map_err(|e| StreamError::Corrupt(e.to_string()))?;
        decoder
            .set_parameter(DParameter::WindowLogMax(MAX_WINDOW_LOG))
            .map_err(|e| StreamError::Corrupt(e.to_string()))?;
        Ok(Self {
            header,
            decoder,
            raw: Vec::new(),
            scratch: vec![0; SCRATCH],
            next: 0,
            received: 0,
            ended: false,
        })
    }

    /// What is being received.
    pub fn header(&self) -> &SceneHeader {
        &self.header
    }

    /// Chunks received so far.
    pub fn chunks_received(&self) -> u32 {
        self.next
    }

    /// Takes chunk `index` of scene `hash`: it must be the next one, of its
    /// size, and decompress within the declared size.
    pub fn push(&mut self, hash: &SceneHash, index: u32, bytes: &[u8]) -> Result<Progress, StreamError> {
        if *hash != self.header.hash {
            let (want, got) = (protocol::short_hash(&self.header.hash), protocol::short_hash(hash));
            return Err(StreamError::WrongScene { want, got });
        }
        if index != self.next || index >= self.header.chunks {
            return Err(StreamError::OutOfOrder { want: self.next, got: index });
        }
        let left = self.header.compressed_bytes - self.received;
        let want = left.min(SCENE_CHUNK_BYTES as u64) as usize;
        if bytes.len() != want {
            return Err(StreamError::ChunkSize { index, bytes: bytes.len(), want });
        }
        self.decompress(bytes)?;
        self.next += 1;
        self.received += bytes.len() as u64;
        Ok(Progress { chunks: self.next, bytes: self.received, complete: self.next == self.header.chunks })
    }

    fn decompress(&mut self, bytes: &[u8]) -> Result<(), StreamError> {
        let corrupt = |e: std::io::Error| StreamError::Corrupt(e.to_string());
        let mut input = InBuffer::around(bytes);
        loop {
            if self.ended && input.pos() < bytes.len() {
                return Err(StreamError::Corrupt("bytes after the end of the stream".into()));
            }
            let mut output = OutBuffer::around(self.scratch.as_mut_slice());
            let hint = self.decoder.run(&mut input, &mut output).map_err(corrupt)?;
            let written = output.pos();
            if self.raw.len() as u64 + written as u64 > self.header.raw_bytes {
                return Err(StreamError::Corrupt(format!(
                    "it decompresses to more than the {} bytes declared",
                    self.header.raw_bytes
                )));
            }
            self.raw.extend_from_slice(&self.scratch[..written]);
            if hint == 0 {
                self.ended = true;
            }
            // Done with this chunk once its input is used up and the decoder
            // had room to spare (nothing more is buffered inside it).
            if input.pos() == bytes.len() && written < self.scratch.len() {
                return Ok(());
            }
        }
    }

    /// The bundle, once every chunk is in: decoded and its hash checked.
    pub fn finish(self) -> Result<SceneBundle, StreamError> {
        self.decode()?.check()
    }

    /// The bundle, once every chunk is in, decoded; its hash is checked by
    /// [`Unchecked::check_with`], the only way to it.
    pub fn decode(self) -> Result<Unchecked, StreamError> {
        if self.next != self.header.chunks {
            return Err(StreamError::Incomplete { got: self.next, want: self.header.chunks });
        }
        if !self.ended || self.raw.len() as u64 != self.header.raw_bytes {
            return Err(StreamError::Corrupt(format!(
                "it decompresses to {} bytes, {} were declared",
                self.raw.len(),
                self.header.raw_bytes
            )));
        }
        Ok(Unchecked { bundle: decode_bundle_owned(self.raw)?, hash: self.header.hash })
    }
}

/// A scene decoded whose hash is not checked yet ([`Receiver::decode`]).
#[derive(Debug)]
pub struct Unchecked {
    bundle: SceneBundle,
    hash: SceneHash,
}

impl Unchecked {
    /// The bundle, if its hash matches.
    pub fn check(self) -> Result<SceneBundle, StreamError> {
        if protocol::scene_hash(&self.bundle) != self.hash {
            return Err(StreamError::HashMismatch);
        }
        Ok(self.bundle)
    }

    /// Hands the bundle to `work` (e.g. building its BVH) while its hash is
    /// checked on another thread, so that the check adds nothing to the time
    /// until the scene is ready: the bundle and `work`'s output, only if the
    /// hash matched.
    pub fn check_with<T: Send>(
        self,
        work: impl FnOnce(&SceneBundle) -> T,
    ) -> Result<(SceneBundle, T), StreamError> {
        let Unchecked { bundle, hash } = self;
        let matches = || protocol::scene_hash(&bundle) == hash;
        let (matches, out) = std::thread::scope(|s| {
            let check = std::thread::Builder::new().name("isin-scene-hash".into()).spawn_scoped(s, matches);
            let out = work(&bundle);
            // Without a thread of its own, the check runs after the work.
            let matches = match check {
                Ok(check) => check.join().unwrap_or(false),
                Err(_) => matches(),
            };
            (matches, out)
        });
        if !matches {
            return Err(StreamError::HashMismatch);
        }
        Ok((bundle, out))
    }
}

/// Logs a transfer's progress through `tracing`: when it has advanced by
/// another tenth and at least a second has passed since the last line, and
/// once at the end. Time is an argument, as everywhere in the core.
#[derive(Debug)]
pub struct ProgressLog {
    what: String,
    total: u64,
    tenth: u64,
    last: Duration,
    done: bool,
}

impl ProgressLog {
    /// Progress of `what` (for the log lines), `total` bytes in all, from `now`.
    pub fn new(what: impl Into<String>, total: u64, now: Duration) -> Self {
        Self { what: what.into(), total: total.max(1), tenth: 0, last: now, done: false }
    }

    /// `done` bytes are through at `now`; logs if it is time to.
    pub fn update(&mut self, now: Duration, done: u64) {
        if self.done {
            return;
        }
        let tenth = (done.min(self.total) * 10) / self.total;
        if done >= self.total {
            self.done = true;
            let secs = now.saturating_sub(self.last).as_secs_f64();
            tracing::debug!("{}: all {} bytes ({secs:.2} s since the last report)", self.what, self.total);
        } else if tenth > self.tenth && now >= self.last + Duration::from_secs(1) {
            self.tenth = tenth;
            self.last = now;
            tracing::info!("{}: {} of {} bytes ({} %)", self.what, done, self.total, tenth * 10);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::WireBundle;

    /// A bundle with a compressible asset and an incompressible one, of
    /// about `bytes` bytes.
    pub(crate) fn bundle(bytes: usize) -> SceneBundle {
        let noise = crate::testing::Rng(0x2545_f491_4f6c_dd1du64).bytes(bytes / 4);
        let text: Vec<u8> = (0..bytes - bytes / 4).map(|i| b"v 1.0 2.0 3.0\n"[i % 14]).collect();
        let mut assets = BTreeMap::new();
        assets.insert("mesh.obj".to_string(), text);
        assets.insert("noise.bin".to_string(), noise);
        SceneBundle { name: "s.toml".into(), source: "[camera]".into(), assets }
    }

    fn chunks(p: &Packed) -> Vec<(SceneHash, u32, Vec<u8>)> {
        (0..p.header.chunks)
            .map(|i| match protocol::decode(&p.chunk_frame(i).unwrap(), usize::MAX).unwrap() {
                Message::SceneChunk { hash, index, bytes } => (hash, index, bytes.into_vec()),
                other => panic!("{other:?}"),
            })
            .collect()
    }

    #[test]
    fn a_packed_scene_is_compressed_chunked_and_received_whole() {
        let b = bundle(1 << 20);
        let p = pack(&b).unwrap();
        assert!(p.header.compressed_bytes < p.header.raw_bytes / 2, "{:?}", p.header);
        assert_eq!(p.header.chunks as u64, p.header.compressed_bytes.div_ceil(SCENE_CHUNK_BYTES as u64));
        assert!(p.header.chunks >= 2);
        // The reference encoding is the same bytes as the owned one's.
        let owned = rmp_serde::to_vec(&WireBundle::from(&b)).unwrap();
        assert_eq!(p.header.raw_bytes, owned.len() as u64);
        let mut rx = Receiver::new(p.header.clone()).unwrap();
        let all = chunks(&p);
        for (i, (h, idx, bytes)) in all.iter().enumerate() {
            let progress = rx.push(h, *idx, bytes).unwrap();
            assert_eq!(progress.complete, i + 1 == all.len());
        }
        assert_eq!(rx.finish().unwrap(), b);
    }

    #[test]
    fn a_bundle_decodes_only_from_exactly_what_a_master_encodes() {
        let b = bundle(4096);
        let raw = encode_bundle(&b).unwrap();
        assert_eq!(decode_bundle(&raw).unwrap(), b);
        assert_eq!(decode_bundle_owned(raw.clone()).unwrap(), b);
        let mut two = b.clone();
        two.assets.insert("a-small-one".into(), vec![7; 10]);
        assert_eq!(decode_bundle_owned(encode_bundle(&two).unwrap()).unwrap(), two);
        let none = SceneBundle { assets: BTreeMap::new(), ..b.clone() };
        assert_eq!(decode_bundle_owned(encode_bundle(&none).unwrap()).unwrap(), none);
        assert!(matches!(decode_bundle(&[&raw[..], &[0]].concat()), Err(StreamError::Decode(_))));
        assert!(matches!(decode_bundle(&raw[..raw.len() - 1]), Err(StreamError::Decode(_))));
        // The same bundle as a map of named fields (valid MessagePack, which
        // a lenient reader would take): not what a master sends.
        let named = rmp_serde::to_vec_named(&WireBundle::from(&b)).unwrap();
        assert!(rmp_serde::from_slice::<WireBundle>(&named).is_ok());
        assert!(matches!(decode_bundle(&named), Err(StreamError::Decode(_))));
    }

    #[test]
    fn oversized_or_inconsistent_headers_are_refused_before_anything_is_held() {
        let p = pack(&bundle(4096)).unwrap();
        let h = p.header.clone();
        let huge = SceneHeader { raw_bytes: MAX_SCENE_RAW_BYTES + 1, ..h.clone() };
        assert!(matches!(Receiver::new(huge), Err(StreamError::TooLarge { .. })));
        let huge = SceneHeader { compressed_bytes: u64::MAX, ..h.clone() };
        assert!(matches!(Receiver::new(huge), Err(StreamError::TooLarge { .. })));
        let lying = SceneHeader { chunks: 1000, ..h.clone() };
        assert!(matches!(Receiver::new(lying), Err(StreamError::BadHeader(_))));
        let empty = SceneHeader { raw_bytes: 0, ..h };
        assert!(matches!(Receiver::new(empty), Err(StreamError::BadHeader(_))));
    }

    #[test]
    fn chunks_out_of_order_of_another_scene_or_size_are_refused() {
        let p = pack(&bundle(1 << 20)).unwrap();
        let all = chunks(&p);
        let (h, _, c0) = &all[0];
        let mut rx = Receiver::new(p.header.clone()).unwrap();
        assert!(matches!(rx.push(h, 1, &all[1].2), Err(StreamError::OutOfOrder { want: 0, got: 1 })));
        assert!(matches!(rx.push(&[0; 32], 0, c0), Err(StreamError::WrongScene { .. })));
        assert!(matches!(rx.push(h, 0, &c0[1..]), Err(StreamError::ChunkSize { .. })));
        rx.push(h, 0, c0).unwrap();
        assert!(matches!(rx.push(h, 0, c0), Err(StreamError::OutOfOrder { want: 1, got: 0 })));
        assert!(matches!(rx.finish(), Err(StreamError::Incomplete { got: 1, .. })));
    }

    #[test]
    fn a_damaged_stream_or_a_lying_size_or_hash_is_refused() {
        let b = bundle(1 << 20);
        let p = pack(&b).unwrap();
        let all = chunks(&p);
        let feed = |header: SceneHeader, damage: &dyn Fn(usize, &mut Vec<u8>)| {
            let mut rx = Receiver::new(header)?;
            for (i, (h, idx, bytes)) in all.iter().enumerate() {
                let mut bytes = bytes.clone();
                damage(i, &mut bytes);
                rx.push(h, *idx, &bytes)?;
            }
            rx.finish()
        };
        assert_eq!(feed(p.header.clone(), &|_, _| {}).unwrap(), b);
        // A flipped byte mid-stream: zstd's checks or the decoder refuse it.
        let err = feed(p.header.clone(), &|i, c| {
            if i == 1 {
                c[100] ^= 0x55
            }
        })
        .unwrap_err();
        assert!(matches!(err, StreamError::Corrupt(_) | StreamError::Decode(_) | StreamError::HashMismatch));
        // Declared smaller than it decompresses to: refused as it grows.
        let small = SceneHeader { raw_bytes: p.header.raw_bytes - 1, ..p.header.clone() };
        assert!(matches!(feed(small, &|_, _| {}), Err(StreamError::Corrupt(_))));
        let big = SceneHeader { raw_bytes: p.header.raw_bytes + 1, ..p.header.clone() };
        assert!(matches!(feed(big, &|_, _| {}), Err(StreamError::Corrupt(_))));
        // Another hash: every chunk is of "another scene"; with the chunks'
        // hash rewritten too, the bundle's hash gives it away.
        let other = SceneHeader { hash: [9; 32], ..p.header.clone() };
        let mut rx = Receiver::new(other).unwrap();
        for (_, idx, bytes) in &all {
            rx.push(&[9; 32], *idx, bytes).unwrap();
        }
        assert_eq!(rx.finish(), Err(StreamError::HashMismatch));
    }

    #[test]
    fn work_on_a_bundle_is_returned_only_when_its_hash_matches() {
        let b = bundle(200 << 10);
        let p = pack(&b).unwrap();
        let receive = |hash: SceneHash| {
            let mut rx = Receiver::new(SceneHeader { hash, ..p.header.clone() }).unwrap();
            for (_, idx, bytes) in chunks(&p) {
                rx.push(&hash, idx, &bytes).unwrap();
            }
            rx
        };
        let (back, len) = receive(p.header.hash).decode().unwrap().check_with(|b| b.source.len()).unwrap();
        assert_eq!((&back, len), (&b, b.source.len()));
        let ran = std::sync::atomic::AtomicBool::new(false);
        let other = receive([7; 32])
            .decode()
            .unwrap()
            .check_with(|_| ran.store(true, std::sync::atomic::Ordering::Relaxed));
        assert_eq!(other, Err(StreamError::HashMismatch));
        assert!(ran.into_inner(), "the work runs beside the check");
    }

    #[test]
    fn a_stored_scene_reads_back_and_a_damaged_one_is_refused() {
        let b = bundle(300 << 10);
        let p = pack(&b).unwrap();
        let stored = p.to_stored().unwrap();
        let (q, back) = Packed::from_stored(&stored).unwrap();
        assert_eq!((back, &q.header), (b, &p.header));
        assert_eq!(q.wire_bytes(), p.wire_bytes());
        let mut bad = stored.clone();
        let n = bad.len();
        bad[n - 10] ^= 1;
        assert!(Packed::from_stored(&bad).is_err());
        assert!(Packed::from_stored(&stored[..n / 2]).is_err());
        assert!(Packed::from_stored(b"garbage").is_err());
    }

    #[test]
    fn progress_is_logged_by_tenths_and_seconds() {
        // Smoke test: never panics on odd totals.
        let mut log = ProgressLog::new("scene", 0, Duration::ZERO);
        log.update(Duration::from_secs(5), 0);
        let mut log = ProgressLog::new("scene", 1000, Duration::ZERO);
        for i in 0..=10u64 {
            log.update(Duration::from_millis(i * 300), i * 100);
        }
        assert!(log.done);
    }
}

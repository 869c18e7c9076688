//! The wire protocol: every message the master, slaves and viewers exchange,
//! and its encoding.
//!
//! A frame on the wire is `[version: u16 big-endian][MessagePack body]`. The
//! version comes first so that a peer speaking another protocol version gets a
//! clear [`ProtocolError::Version`] instead of a confusing decode error.
//! Decoding takes untrusted bytes: it never panics, refuses frames above a
//! maximum length before looking at them, and leaves allocation of variable
//! fields to rmp-serde, which checks declared lengths against the bytes present.

use crate::codec::{self, Codec, CodecError};
use crate::scheduler::Work;
use isin_tracer::{Camera, RenderSettings, SceneBundle, Tile};
use serde::{Deserialize, Serialize};
use serde_bytes::ByteBuf;
use sha2::{Digest, Sha256};
use std::collections::BTreeMap;

mod direct;
mod in_place;

pub use direct::{
    DirectOffer, DirectRoute, DirectTile, MAX_DIRECT_ADDR, MAX_DIRECT_FINGERPRINT, TileReceived,
    VERIFY_ONE_IN, via_master,
};
pub use in_place::{AssignmentHead, TileResultRef, decode_tile_result, encode_assignment, encode_frame_tile};

/// Version of the protocol spoken by this build; peers must match exactly.
/// (2: tile codecs negotiated at join; tiles name their codec. 3: viewers may
/// queue frames behind the open one, [`Message::QueueFrame`]. 4: the master
/// tells viewers its slaves, [`Message::Slaves`]. 5: every viewer is a client
/// of its own, interactive or batch ([`Hello::work`]), whose requests
/// supersede only its own frames. 6: scenes per client: clients upload
/// theirs ([`Message::SceneUpload`]), frames name their scene, slaves fetch a
/// scene they lack ([`Message::NeedScene`]); batch jobs ([`Message::SubmitJob`])
/// and the master's status ([`Message::Status`]). 7: scenes travel to slaves
/// compressed and in chunks under flow control ([`Message::SceneBegin`],
/// [`Message::SceneChunk`], [`Message::SceneAck`]), no longer as one
/// `SceneSync`; clients upload theirs the same way: [`Message::SceneUpload`]
/// with the header, then the chunks. 8: viewers may take tiles straight from
/// slaves ([`Hello::direct`], [`TileAssignment::direct`], [`Message::DirectHello`],
/// [`Message::DirectTile`], [`Message::DirectAck`], [`Message::TileReceived`]).)
pub const PROTOCOL_VERSION: u16 = 8;

/// Most scene hashes a slave may list as cached in its [`Hello`].
pub const MAX_CACHED_SCENES: usize = 64;

/// Most frames one batch job may hold ([`Message::SubmitJob`]): a
/// 24 frames/s animation of over an hour.
pub const MAX_JOB_FRAMES: u32 = 100_000;

/// Most slaves a [`Message::Slaves`] may list; a longer list is refused while
/// it is decoded, before it is allocated.
pub const MAX_SLAVES_LISTED: usize = 1024;

/// Longest slave name or address in a [`Message::Slaves`] (the master
/// truncates longer ones; a peer refuses them).
pub const MAX_SLAVE_TEXT: usize = 128;

/// Default largest frame accepted from an authenticated peer (scene bundles
/// with meshes and textures are the big ones).
pub const DEFAULT_MAX_FRAME: usize = 512 << 20;

/// Largest frame accepted before a peer has authenticated: a handshake message
/// is tiny, so an unauthenticated peer cannot make anyone allocate much.
pub const HANDSHAKE_MAX_FRAME: usize = 16 << 10;

/// SHA-256 of a scene bundle's contents: slaves cache scenes by it.
pub type SceneHash = [u8; 32];

/// Identifies a frame in the master (increasing).
pub type FrameId = u64;

/// Identifies a tile within a frame.
pub type TileId = u32;

/// What a connecting peer wants to be.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Role {
    /// Renders tiles.
    Slave,
    /// Requests frames and receives their tiles.
    Viewer,
}

/// A peer's answer to the master's [`Message::Challenge`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Hello {
    /// Slave or viewer.
    pub role: Role,
    /// Human-readable name for logs (the master truncates it).
    pub name: String,
    /// Render threads (slaves; 0 for viewers).
    pub threads: u32,
    /// The peer's own nonce, so the master's proof is fresh too.
    pub client_nonce: [u8; 32],
    /// `HMAC-SHA256(token, …)` over both nonces and the role: see [`crate::auth`].
    pub proof: [u8; 32],
    /// The scenes this peer already holds (slaves): they are not sent again.
    #[serde(deserialize_with = "bounded_vec::<_, _, MAX_CACHED_SCENES>")]
    pub cached_scenes: Vec<SceneHash>,
    /// Tile codecs this peer can encode and decode, by [`Codec::name`]
    /// (unknown names are ignored; absent or empty: raw only).
    #[serde(default)]
    pub codecs: Vec<String>,
    /// Viewers: what kind of work their frames are (slaves: ignored).
    #[serde(default)]
    pub work: Work,
    /// Viewers: where slaves may send this viewer's tiles straight
    /// ([`direct`](self::direct); slaves: ignored).
    #[serde(default)]
    pub direct: Option<Box<DirectOffer>>,
}

/// What a viewer needs to know about the scene being served.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SceneInfo {
    /// The scene file's name.
    pub name: String,
    /// Content hash of its bundle.
    pub hash: SceneHash,
    /// The scene's own camera.
    pub camera: Camera,
    /// The scene's own render settings.
    pub settings: RenderSettings,
}

/// The master's acceptance of a peer.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Welcome {
    /// The id the master gave this peer.
    pub id: u64,
    /// The name the master will use for it in logs.
    pub name: String,
    /// Proof that the master knows the token too (mutual authentication).
    pub proof: [u8; 32],
    /// The master's default scene, if it has one (frames that name no scene
    /// use it).
    pub scene: Option<SceneInfo>,
    /// The codec a slave must encode its tiles with (one it offered, or raw).
    pub codec: Codec,
}

/// A scene bundle as it travels: asset bytes as MessagePack binaries.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WireBundle {
    /// Name of the scene file.
    pub name: String,
    /// The scene file's text.
    pub source: String,
    /// Asset bytes by path.
    pub assets: BTreeMap<String, ByteBuf>,
}

impl From<&SceneBundle> for WireBundle {
    fn from(b: &SceneBundle) -> Self {
        Self {
            name: b.name.clone(),
            source: b.source.clone(),
            assets: b.assets.iter().map(|(k, v)| (k.clone(), ByteBuf::from(v.clone()))).collect(),
        }
    }
}

impl From<WireBundle> for SceneBundle {
    fn from(b: WireBundle) -> Self {
        Self {
            name: b.name,
            source: b.source,
            assets: b.assets.into_iter().map(|(k, v)| (k, v.into_vec())).collect(),
        }
    }
}

/// What a [`Message::SceneBegin`] announces: a scene as zstd-compressed
/// MessagePack of its [`WireBundle`], in chunks.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct SceneHeader {
    /// Content hash of the bundle ([`scene_hash`]), checked once it is in.
    pub hash: SceneHash,
    /// The scene's file name (for logs; at most [`MAX_SCENE_NAME`] bytes).
    pub name: String,
    /// Bytes of the encoded bundle, decompressed.
    pub raw_bytes: u64,
    /// Bytes of the compressed stream, all chunks together.
    pub compressed_bytes: u64,
    /// Chunks that carry it.
    pub chunks: u32,
}

/// Longest scene name in a [`SceneHeader`].
pub const MAX_SCENE_NAME: usize = 255;

/// One tile of an assignment.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct TileJob {
    /// The tile's id within its frame.
    pub id: TileId,
    /// Its pixels.
    pub tile: Tile,
}

/// Master → slave: render these tiles of this frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TileAssignment {
    /// The frame they belong to.
    pub frame: FrameId,
    /// The scene to render (a slave lacking it asks with [`Message::NeedScene`]).
    pub scene: SceneHash,
    /// The frame's camera (carried by every assignment so that message order
    /// does not matter).
    pub camera: Camera,
    /// The frame's settings.
    pub settings: RenderSettings,
    /// The tiles.
    pub tiles: Vec<TileJob>,
    /// Deliver them straight to the frame's viewer, not through the master
    /// (`None`: through the master).
    #[serde(default)]
    pub direct: Option<Box<DirectRoute>>,
}

/// Slave → master: a rendered tile.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TileResult {
    /// The frame it belongs to.
    pub frame: FrameId,
    /// The tile's id.
    pub id: TileId,
    /// The tile's rectangle (checked by the master against the one it assigned).
    pub tile: Tile,
    /// Time spent rendering it, in microseconds: the render thread's CPU
    /// time where the platform has a thread clock (a slave throttled by a CPU
    /// quota or crowded by other load still reports what the tile cost), wall
    /// time elsewhere. The master orders later frames' tiles by it.
    pub render_micros: u64,
    /// How `pixels` is encoded.
    pub codec: Codec,
    /// `w * h * 3` bytes of sRGB RGB8, row-major, encoded with `codec`.
    pub pixels: ByteBuf,
}

impl TileResult {
    /// The tile's `w * h * 3` bytes of RGB8 (decoding checks the size; never panics).
    pub fn decoded_pixels(&self) -> Result<Vec<u8>, CodecError> {
        codec::decode(self.codec, self.tile.w, self.tile.h, &self.pixels)
    }
}

/// Master → viewer: a finished tile of a requested frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameTile {
    /// The viewer's request number.
    pub request: u64,
    /// The id of the slave that rendered it (its [`Welcome::id`]).
    pub slave: u64,
    /// That slave's name (as in [`FrameStats::per_slave`]).
    pub slave_name: String,
    /// Where the pixels go.
    pub tile: Tile,
    /// How `pixels` is encoded (one the viewer offered, or raw).
    pub codec: Codec,
    /// `w * h * 3` bytes of sRGB RGB8, row-major, encoded with `codec`.
    pub pixels: ByteBuf,
}

impl FrameTile {
    /// The tile's `w * h * 3` bytes of RGB8 (decoding checks the size; never panics).
    pub fn decoded_pixels(&self) -> Result<Vec<u8>, CodecError> {
        codec::decode(self.codec, self.tile.w, self.tile.h, &self.pixels)
    }
}

/// A slave as the master tells viewers about it ([`Message::Slaves`]).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct SlaveEntry {
    /// Its id (the [`Welcome::id`], as in [`FrameTile::slave`]).
    pub id: u64,
    /// Its name (as in [`FrameTile::slave_name`]).
    pub name: String,
    /// Where it connected from, as the transport names it.
    pub addr: String,
    /// Its render threads.
    pub threads: u32,
    /// False once the master declared it dead (it stays listed for a while).
    pub alive: bool,
}

/// Deserializes a sequence of at most `MAX` elements: a longer one fails as
/// soon as its declared length (or its `MAX + 1`-th element) is seen.
fn bounded_vec<'de, D, T, const MAX: usize>(de: D) -> Result<Vec<T>, D::Error>
where
    D: serde::Deserializer<'de>,
    T: Deserialize<'de>,
{
    struct Bounded<T, const MAX: usize>(std::marker::PhantomData<T>);
    impl<'de, T: Deserialize<'de>, const MAX: usize> serde::de::Visitor<'de> for Bounded<T, MAX> {
        type Value = Vec<T>;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            write!(f, "a sequence of at most {MAX} elements")
        }
        fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<Vec<T>, A::Error> {
            if seq.size_hint().is_some_and(|n| n > MAX) {
                return Err(serde::de::Error::custom(format!("more than {MAX} elements")));
            }
            let mut out = Vec::with_capacity(seq.size_hint().unwrap_or(0).min(MAX));
            while let Some(x) = seq.next_element()? {
                if out.len() == MAX {
                    return Err(serde::de::Error::custom(format!("more than {MAX} elements")));
                }
                out.push(x);
            }
            Ok(out)
        }
    }
    de.deserialize_seq(Bounded::<T, MAX>(std::marker::PhantomData))
}

/// Summary of one completed frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FrameStats {
    /// Master-side time from request to last tile, microseconds.
    pub micros: u64,
    /// Tiles accepted (after end-of-frame splitting).
    pub tiles: u32,
    /// Tiles handed out a second time to an idle slave.
    pub duplicated: u32,
    /// Tiles put back in the queue because their slave died.
    pub requeued: u32,
    /// Tiles still waiting in one slave's queue that were moved to an idle
    /// slave at the end of the frame.
    #[serde(default)]
    pub moved: u32,
    /// Tiles accepted per slave name.
    pub per_slave: BTreeMap<String, u32>,
    /// Tiles that went straight from their slave to the viewer
    /// ([`Message::TileReceived`]); the rest came through the master.
    #[serde(default)]
    pub direct: u32,
    /// Bytes of the messages the master received from all peers while the
    /// frame was open (tiles and heartbeats; the transport's framing and
    /// encryption not counted): the frame's cost on the slaves' links.
    pub bytes_in: u64,
}

/// Every message of the protocol.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Message {
    /// Master → any peer, first: a fresh nonce to prove the token over.
    Challenge {
        /// Random bytes, never reused.
        nonce: [u8; 32],
    },
    /// Peer → master: who it is, with its proof of the token.
    Hello(Hello),
    /// Master → peer: accepted.
    Welcome(Welcome),
    /// Either way: refused, with the reason; the connection closes after it.
    Reject {
        /// Human-readable reason.
        reason: String,
    },
    /// Master → slave: a scene follows in [`SceneHeader::chunks`]
    /// [`Message::SceneChunk`]s (sent once per slave, and only if the slave
    /// does not already hold a scene with this hash; see
    /// [`crate::scene_stream`]).
    SceneBegin(SceneHeader),
    /// Master → slave: the next piece of the compressed scene announced by
    /// [`Message::SceneBegin`], in order; client → master likewise, for the
    /// scene it announced with [`Message::SceneUpload`] once the master
    /// answered [`Message::SceneWanted`].
    SceneChunk {
        /// The scene's hash.
        hash: SceneHash,
        /// The chunk's index, from 0.
        index: u32,
        /// At most [`crate::limits::SCENE_CHUNK_BYTES`] of the compressed stream.
        bytes: ByteBuf,
    },
    /// Slave → master: chunks of a scene received so far (the master keeps
    /// at most its window of chunks beyond this in flight).
    SceneAck {
        /// The scene's hash.
        hash: SceneHash,
        /// Chunks received and decoded, in all.
        chunks_received: u32,
    },
    /// Slave → master: the master's default scene is loaded (or there is
    /// none), ready for tiles.
    Ready {
        /// Hash of the default scene it holds (`None`: the master has none).
        hash: Option<SceneHash>,
    },
    /// Viewer → master: render a frame (supersedes any earlier request).
    FrameRequest {
        /// The viewer's own number for the request (its window's frame id),
        /// echoed in the replies.
        request: u64,
        /// The scene (one the master holds: its default, or one this client
        /// uploaded); `None`: the default.
        #[serde(default)]
        scene: Option<SceneHash>,
        /// Camera to render with.
        camera: Camera,
        /// Resolution, samples and the rest.
        settings: RenderSettings,
    },
    /// Master → slave: tiles to render.
    TileAssignment(TileAssignment),
    /// Master → slave: drop these tiles if not started (another slave won, or
    /// the frame was superseded).
    Cancel {
        /// The frame.
        frame: FrameId,
        /// The tiles.
        tiles: Vec<TileId>,
    },
    /// Slave → master: a rendered tile.
    TileResult(TileResult),
    /// Master → viewer: a tile of the requested frame.
    FrameTile(FrameTile),
    /// Master → viewer: the requested frame is complete.
    FrameDone {
        /// The viewer's request number.
        request: u64,
        /// How it went.
        stats: FrameStats,
    },
    /// Master → viewer: every slave it knows of — the live ones and the
    /// latest dead ones. Sent when the viewer joins and after slaves join or
    /// die (those within [`crate::ROSTER_INTERVAL`] of each other in one list).
    Slaves {
        /// The slaves, by id (at most [`MAX_SLAVES_LISTED`]).
        #[serde(deserialize_with = "bounded_vec::<_, _, MAX_SLAVES_LISTED>")]
        slaves: Vec<SlaveEntry>,
    },
    /// Either way: still alive.
    Heartbeat,
    /// Either way: a request could not be served (the connection stays open).
    Error {
        /// Human-readable message.
        message: String,
    },
    /// Viewer → master: render a frame after the frames already requested,
    /// without superseding them (a replayed camera path keeps the next frame
    /// queued so that slaves roll from one frame straight into the next). Each
    /// frame is answered with its own tiles and `FrameDone`; a later
    /// [`Message::FrameRequest`] supersedes queued frames too.
    QueueFrame {
        /// The viewer's own number for the request, echoed in the replies.
        request: u64,
        /// The scene, as in [`Message::FrameRequest`].
        #[serde(default)]
        scene: Option<SceneHash>,
        /// Camera to render with.
        camera: Camera,
        /// Resolution, samples and the rest.
        settings: RenderSettings,
        /// The frame's index in the client's job ([`Message::SubmitJob`]), if
        /// it is one: the master records it done when it completes.
        #[serde(default)]
        job_frame: Option<u32>,
    },
    /// Master → viewer: something worth telling the user that is not an
    /// error — its frames wait because no slave is connected, say. Said
    /// once, not per frame.
    Notice {
        /// Human-readable text.
        message: String,
    },
    /// Client → master: it wants to render with the scene this header
    /// announces (packed as a slave receives it, [`crate::scene_stream`]).
    /// The master answers [`Message::SceneStored`] if it holds the scene
    /// already, else [`Message::SceneWanted`] once it accepts an upload of
    /// that size from the client, or an error.
    SceneUpload(SceneHeader),
    /// Master → client: send the chunks ([`Message::SceneChunk`]) of the
    /// scene announced with [`Message::SceneUpload`].
    SceneWanted {
        /// The hash announced.
        hash: SceneHash,
    },
    /// Master → client: the scene is held; frames may name it.
    SceneStored {
        /// Its hash.
        hash: SceneHash,
    },
    /// Slave → master: an assignment named a scene this slave does not hold;
    /// the master answers with its [`Message::SceneBegin`] and chunks.
    NeedScene {
        /// The scene.
        hash: SceneHash,
    },
    /// Slave → master: a scene could not be loaded; its frames fail.
    SceneFailed {
        /// The scene.
        hash: SceneHash,
        /// The loader's error.
        reason: String,
    },
    /// Client → master: the frames that follow belong to this batch job (a
    /// still or an animation). With a state directory the master records
    /// the job, and each frame of it that completes, on disk before it
    /// answers, so a job survives a restart of the master.
    SubmitJob(JobSpec),
    /// Master → client: the job is recorded; `done` lists the frames of it
    /// completed before (by an earlier run of the same job).
    JobAccepted {
        /// The job's key, as submitted.
        key: SceneHash,
        /// Frame indices already completed, ascending.
        #[serde(deserialize_with = "bounded_vec::<_, _, { MAX_JOB_FRAMES as usize }>")]
        done: Vec<u32>,
    },
    /// Client → master: send the cluster's status.
    StatusRequest,
    /// Master → client: slaves, clients and jobs. Answers
    /// [`Message::StatusRequest`], and is pushed to every viewer with each
    /// [`Message::Slaves`] and every second while frames are open.
    Status(Status),
    /// Slave → viewer, first on a direct link: the key of the viewer's
    /// [`DirectOffer`], as the master passed it on.
    DirectHello {
        /// The key.
        key: [u8; 32],
        /// The slave's id at the master.
        slave: u64,
    },
    /// Slave → viewer: a tile of one of its frames, straight.
    DirectTile(DirectTile),
    /// Viewer → slave: the tile arrived and is shown.
    DirectAck {
        /// Its frame.
        frame: FrameId,
        /// Its id.
        id: TileId,
    },
    /// Viewer → master: a tile of one of its direct frames came straight.
    TileReceived(TileReceived),
}

/// A batch job as its client describes it ([`Message::SubmitJob`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JobSpec {
    /// Identifies the job across runs: a hash of everything that determines
    /// its frames (scene, cameras, settings). Submitting the same key again
    /// resumes the job.
    pub key: SceneHash,
    /// Name for people (the output folder, say).
    pub name: String,
    /// The scene's hash.
    pub scene: SceneHash,
    /// Frames in the job (at most [`MAX_JOB_FRAMES`]).
    pub frames: u32,
    /// The job's settings.
    pub settings: RenderSettings,
}

/// The cluster as the master sees it ([`Message::Status`]).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Status {
    /// Live slaves.
    #[serde(deserialize_with = "bounded_vec::<_, _, MAX_SLAVES_LISTED>")]
    pub slaves: Vec<SlaveStatus>,
    /// Connected clients.
    #[serde(deserialize_with = "bounded_vec::<_, _, MAX_SLAVES_LISTED>")]
    pub clients: Vec<ClientStatus>,
    /// Batch jobs known (running, or waiting for their client to return).
    #[serde(deserialize_with = "bounded_vec::<_, _, MAX_SLAVES_LISTED>")]
    pub jobs: Vec<JobStatus>,
    /// Scenes the master holds.
    pub scenes: u32,
    /// Bytes of scenes the master has sent to slaves (their
    /// [`Message::SceneBegin`] and [`Message::SceneChunk`] frames).
    #[serde(default)]
    pub scene_bytes_sent: u64,
}

/// One slave in a [`Status`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SlaveStatus {
    /// Its id.
    pub id: u64,
    /// Its name (as given with `--name`, then `#id`).
    pub name: String,
    /// Render threads.
    pub threads: u32,
    /// Tiles it delivered over the last few seconds, per second.
    pub tiles_per_second: f32,
    /// Milliseconds since it was last heard from.
    pub last_seen_ms: u64,
}

/// One client in a [`Status`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClientStatus {
    /// Its id.
    pub id: u64,
    /// Its name.
    pub name: String,
    /// Interactive or batch.
    pub work: Work,
    /// Frames it has open now.
    pub open_frames: u32,
    /// Frames completed for it.
    pub frames_done: u64,
}

/// One batch job in a [`Status`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JobStatus {
    /// Its name.
    pub name: String,
    /// Frames completed.
    pub done: u32,
    /// Frames in all.
    pub frames: u32,
    /// Whether its client is connected.
    pub running: bool,
    /// Estimated seconds to completion at the recent rate, if known.
    pub eta_seconds: Option<f32>,
}

impl Message {
    /// Short name of the message kind, for logs.
    pub fn kind(&self) -> &'static str {
        match self {
            Message::Challenge { .. } => "Challenge",
            Message::Hello(_) => "Hello",
            Message::Welcome(_) => "Welcome",
            Message::Reject { .. } => "Reject",
            Message::SceneBegin(_) => "SceneBegin",
            Message::SceneChunk { .. } => "SceneChunk",
            Message::SceneAck { .. } => "SceneAck",
            Message::Ready { .. } => "Ready",
            Message::FrameRequest { .. } => "FrameRequest",
            Message::TileAssignment(_) => "TileAssignment",
            Message::Cancel { .. } => "Cancel",
            Message::TileResult(_) => "TileResult",
            Message::FrameTile(_) => "FrameTile",
            Message::FrameDone { .. } => "FrameDone",
            Message::Slaves { .. } => "Slaves",
            Message::Heartbeat => "Heartbeat",
            Message::Error { .. } => "Error",
            Message::QueueFrame { .. } => "QueueFrame",
            Message::Notice { .. } => "Notice",
            Message::SceneUpload { .. } => "SceneUpload",
            Message::SceneWanted { .. } => "SceneWanted",
            Message::SceneStored { .. } => "SceneStored",
            Message::NeedScene { .. } => "NeedScene",
            Message::SceneFailed { .. } => "SceneFailed",
            Message::SubmitJob(_) => "SubmitJob",
            Message::JobAccepted { .. } => "JobAccepted",
            Message::StatusRequest => "StatusRequest",
            Message::Status(_) => "Status",
            Message::DirectHello { .. } => "DirectHello",
            Message::DirectTile(_) => "DirectTile",
            Message::DirectAck { .. } => "DirectAck",
            Message::TileReceived(_) => "TileReceived",
        }
    }
}

/// Why a frame could not be encoded or decoded.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum ProtocolError {
    /// Shorter than the version prefix.
    #[error("frame of {0} bytes is too short to hold a protocol version")]
    TooShort(usize),
    /// Longer than allowed.
    #[error("frame of {len} bytes exceeds the maximum of {max}")]
    TooLarge {
        /// Its length.
        len: usize,
        /// The maximum.
        max: usize,
    },
    /// The peer speaks another protocol version.
    #[error("peer speaks protocol version {got}, this build speaks {want}")]
    Version {
        /// The peer's version.
        got: u16,
        /// Ours.
        want: u16,
    },
    /// The body is not a valid message.
    #[error("malformed message: {0}")]
    Decode(String),
    /// The message could not be encoded.
    #[error("cannot encode message: {0}")]
    Encode(String),
}

/// Encodes a message as one wire frame (version prefix + MessagePack).
pub fn encode(msg: &Message) -> Result<Vec<u8>, ProtocolError> {
    // Room for the pixels at once: a tile's buffer is not grown by doubling.
    let pixels = match msg {
        Message::TileResult(r) => r.pixels.len(),
        Message::FrameTile(t) => t.pixels.len() + t.slave_name.len(),
        _ => 0,
    };
    let mut buf = Vec::with_capacity(64 + pixels);
    buf.extend_from_slice(&PROTOCOL_VERSION.to_be_bytes());
    rmp_serde::encode::write(&mut buf, msg).map_err(|e| ProtocolError::Encode(e.to_string()))?;
    Ok(buf)
}

/// Decodes one wire frame of at most `max` bytes. Never panics.
pub fn decode(frame: &[u8], max: usize) -> Result<Message, ProtocolError> {
    if frame.len() > max {
        return Err(ProtocolError::TooLarge { len: frame.len(), max });
    }
    let (version, body) = match frame {
        [a, b, body @ ..] => (u16::from_be_bytes([*a, *b]), body),
        _ => return Err(ProtocolError::TooShort(frame.len())),
    };
    if version != PROTOCOL_VERSION {
        return Err(ProtocolError::Version { got: version, want: PROTOCOL_VERSION });
    }
    // A cursor reader: binaries are read with `take(len)`, so a declared
    // length beyond the bytes present fails without allocating it.
    let mut de = rmp_serde::Deserializer::new(std::io::Cursor::new(body));
    let msg = Message::deserialize(&mut de).map_err(|e| ProtocolError::Decode(e.to_string()))?;
    let rest = body.len() as u64 - de.position().min(body.len() as u64);
    if rest != 0 {
        return Err(ProtocolError::Decode(format!("{rest} trailing bytes after the message")));
    }
    let long = |t: &String| t.len() > MAX_SLAVE_TEXT;
    let too_long = match &msg {
        Message::Slaves { slaves } => slaves.iter().any(|s| long(&s.name) || long(&s.addr)),
        Message::Status(s) => {
            s.slaves.iter().any(|x| long(&x.name))
                || s.clients.iter().any(|x| long(&x.name))
                || s.jobs.iter().any(|x| long(&x.name))
        }
        Message::SubmitJob(j) => long(&j.name),
        Message::SceneBegin(h) if h.name.len() > MAX_SCENE_NAME => {
            return Err(ProtocolError::Decode(format!("a scene name longer than {MAX_SCENE_NAME} bytes")));
        }
        Message::SceneChunk { bytes, .. } if bytes.len() > crate::limits::SCENE_CHUNK_BYTES => {
            return Err(ProtocolError::Decode(format!(
                "a scene chunk of {} bytes, more than {}",
                bytes.len(),
                crate::limits::SCENE_CHUNK_BYTES
            )));
        }
        _ => false,
    };
    if too_long {
        return Err(ProtocolError::Decode(format!(
            "{} holds a name or address longer than {MAX_SLAVE_TEXT} bytes",
            msg.kind()
        )));
    }
    Ok(msg)
}

/// Content hash of a scene bundle (name, text and every asset, length-prefixed
/// so that no two different bundles hash the same input).
pub fn scene_hash(bundle: &SceneBundle) -> SceneHash {
    scene_hash_named(&bundle.name, bundle)
}

/// What peers are told a scene is called: the last component of its path
/// (in either separator), never the path on the master's disk.
pub fn served_name(name: &str) -> &str {
    name.rsplit(['/', '\\']).next().unwrap_or(name)
}

/// The hash of `bundle` as a master serves it (under its [`served_name`]): a
/// client compares it with the master's [`SceneInfo::hash`] to know whether
/// the master serves the scene it means.
pub fn served_scene_hash(bundle: &SceneBundle) -> SceneHash {
    scene_hash_named(served_name(&bundle.name), bundle)
}

fn scene_hash_named(name: &str, bundle: &SceneBundle) -> SceneHash {
    let mut h = Sha256::new();
    let mut put = |bytes: &[u8]| {
        h.update((bytes.len() as u64).to_le_bytes());
        h.update(bytes);
    };
    put(name.as_bytes());
    put(bundle.source.as_bytes());
    for (path, bytes) in &bundle.assets {
        put(path.as_bytes());
        put(bytes);
    }
    h.finalize().into()
}

/// Hex form of a scene hash's first bytes, for logs.
pub fn short_hash(hash: &SceneHash) -> String {
    hash[..6].iter().map(|b| format!("{b:02x}")).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn samples() -> Vec<Message> {
        let mut assets = BTreeMap::new();
        assets.insert("mesh.obj".to_string(), vec![1u8, 2, 3, 250]);
        let bundle = SceneBundle { name: "s.toml".into(), source: "[camera]".into(), assets };
        vec![
            Message::Challenge { nonce: [7; 32] },
            Message::Hello(Hello {
                role: Role::Slave,
                name: "box".into(),
                threads: 4,
                client_nonce: [1; 32],
                proof: [2; 32],
                cached_scenes: vec![[3; 32]],
                codecs: codec::offer(),
                work: Work::Batch,
                direct: Some(Box::new(DirectOffer {
                    addr: "10.1.2.3:4000".into(),
                    fingerprint: None,
                    key: [6; 32],
                })),
            }),
            Message::Welcome(Welcome {
                id: 9,
                name: "box#9".into(),
                proof: [4; 32],
                scene: Some(SceneInfo {
                    name: "s".into(),
                    hash: [5; 32],
                    camera: Camera::default(),
                    settings: RenderSettings::default(),
                }),
                codec: Codec::Qoi,
            }),
            Message::Reject { reason: "no".into() },
            Message::SceneBegin(SceneHeader {
                hash: scene_hash(&bundle),
                name: "s.toml".into(),
                raw_bytes: 300,
                compressed_bytes: 120,
                chunks: 1,
            }),
            Message::SceneChunk { hash: scene_hash(&bundle), index: 0, bytes: ByteBuf::from(vec![7u8; 120]) },
            Message::SceneAck { hash: scene_hash(&bundle), chunks_received: 1 },
            Message::Ready { hash: Some([6; 32]) },
            Message::Ready { hash: None },
            Message::FrameRequest {
                request: 3,
                scene: None,
                camera: Camera::default(),
                settings: RenderSettings::default(),
            },
            Message::QueueFrame {
                request: 4,
                scene: Some([8; 32]),
                camera: Camera::default(),
                settings: RenderSettings::default(),
                job_frame: Some(17),
            },
            Message::SceneUpload(SceneHeader {
                hash: [1; 32],
                name: "u.toml".into(),
                raw_bytes: 1234,
                compressed_bytes: 600,
                chunks: 1,
            }),
            Message::SceneWanted { hash: [1; 32] },
            Message::SceneStored { hash: [1; 32] },
            Message::NeedScene { hash: [2; 32] },
            Message::SceneFailed { hash: [2; 32], reason: "bad mesh".into() },
            Message::SubmitJob(JobSpec {
                key: [3; 32],
                name: "frames/".into(),
                scene: [4; 32],
                frames: 30,
                settings: RenderSettings::default(),
            }),
            Message::JobAccepted { key: [3; 32], done: vec![0, 1, 5] },
            Message::StatusRequest,
            Message::Status(Status {
                slaves: vec![SlaveStatus {
                    id: 2,
                    name: "box#2".into(),
                    threads: 8,
                    tiles_per_second: 120.5,
                    last_seen_ms: 30,
                }],
                clients: vec![ClientStatus {
                    id: 3,
                    name: "fly#3".into(),
                    work: Work::Batch,
                    open_frames: 2,
                    frames_done: 40,
                }],
                jobs: vec![JobStatus {
                    name: "frames/".into(),
                    done: 40,
                    frames: 100,
                    running: true,
                    eta_seconds: Some(12.0),
                }],
                scenes: 2,
                scene_bytes_sent: 1 << 20,
            }),
            Message::TileAssignment(TileAssignment {
                frame: 2,
                scene: [5; 32],
                camera: Camera::default(),
                settings: RenderSettings::default(),
                tiles: vec![TileJob { id: 1, tile: Tile { x: 0, y: 32, w: 32, h: 16 } }],
                direct: Some(Box::new(DirectRoute {
                    viewer: 4,
                    request: 8,
                    offer: Some(DirectOffer {
                        addr: "viewer.lan:4000".into(),
                        fingerprint: Some("0f".repeat(32)),
                        key: [9; 32],
                    }),
                    via_master: vec![1],
                })),
            }),
            Message::DirectHello { key: [9; 32], slave: 3 },
            Message::DirectAck { frame: 2, id: 1 },
            Message::TileReceived(TileReceived {
                frame: 2,
                id: 1,
                slave: 3,
                tile: Tile { x: 0, y: 32, w: 32, h: 16 },
                render_micros: 70,
            }),
            Message::Cancel { frame: 2, tiles: vec![1, 5] },
            Message::TileResult(TileResult {
                frame: 2,
                id: 1,
                tile: Tile { x: 0, y: 32, w: 4, h: 4 },
                render_micros: 55,
                codec: Codec::Raw,
                pixels: ByteBuf::from(vec![200u8; 48]),
            }),
            Message::FrameTile(FrameTile {
                request: 3,
                slave: 12,
                slave_name: "box#12".into(),
                tile: Tile { x: 1, y: 2, w: 3, h: 4 },
                codec: Codec::Lz4,
                pixels: ByteBuf::from(codec::encode(Codec::Lz4, 3, &[9u8; 36])),
            }),
            Message::FrameDone { request: 3, stats: FrameStats::default() },
            Message::Slaves {
                slaves: vec![
                    SlaveEntry {
                        id: 4,
                        name: "a#4".into(),
                        addr: "10.0.0.2:5000".into(),
                        threads: 2,
                        alive: true,
                    },
                    SlaveEntry { id: 7, name: "b#7".into(), addr: "mem".into(), threads: 1, alive: false },
                ],
            },
            Message::Heartbeat,
            Message::Error { message: "bad".into() },
        ]
    }

    #[test]
    fn every_message_round_trips() {
        for msg in samples() {
            let bytes = encode(&msg).unwrap();
            assert_eq!(decode(&bytes, DEFAULT_MAX_FRAME).unwrap(), msg, "{}", msg.kind());
        }
    }

    #[test]
    fn pixels_travel_as_binary_not_as_integer_arrays() {
        let msg = Message::TileResult(TileResult {
            frame: 1,
            id: 1,
            tile: Tile { x: 0, y: 0, w: 32, h: 32 },
            render_micros: 1,
            codec: Codec::Raw,
            pixels: ByteBuf::from(vec![255u8; 3072]),
        });
        let bytes = encode(&msg).unwrap();
        assert!(bytes.len() < 3072 + 32, "{} bytes", bytes.len());
    }

    #[test]
    fn scene_bundle_survives_the_wire_and_hash_is_content_based() {
        let mut assets = BTreeMap::new();
        assets.insert("a".to_string(), vec![0u8, 255, 128]);
        let b = SceneBundle { name: "n".into(), source: "src".into(), assets };
        let back: SceneBundle = WireBundle::from(&b).into();
        assert_eq!(back, b);
        assert_eq!(scene_hash(&back), scene_hash(&b));
        let mut c = b.clone();
        c.assets.insert("a".into(), vec![0u8, 255, 129]);
        assert_ne!(scene_hash(&c), scene_hash(&b));
        // Moving bytes between fields must change the hash.
        let d = SceneBundle { name: "ns".into(), source: "rc".into(), assets: b.assets.clone() };
        assert_ne!(scene_hash(&d), scene_hash(&b));
    }

    #[test]
    fn a_hello_without_codecs_decodes_as_raw_only() {
        // A Hello as a peer that knows nothing of codecs encodes it: six fields.
        #[derive(Serialize)]
        struct OldHello {
            role: Role,
            name: String,
            threads: u32,
            client_nonce: [u8; 32],
            proof: [u8; 32],
            cached_scenes: Vec<SceneHash>,
        }
        #[derive(Serialize)]
        enum OldMessage {
            #[allow(dead_code)]
            Challenge {
                nonce: [u8; 32],
            },
            Hello(OldHello),
        }
        let old = OldHello {
            role: Role::Slave,
            name: "old".into(),
            threads: 1,
            client_nonce: [1; 32],
            proof: [2; 32],
            cached_scenes: vec![],
        };
        let mut bytes = PROTOCOL_VERSION.to_be_bytes().to_vec();
        rmp_serde::encode::write(&mut bytes, &OldMessage::Hello(old)).unwrap();
        match decode(&bytes, 4096).unwrap() {
            Message::Hello(h) => assert!(h.codecs.is_empty() && h.name == "old"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn tiles_decode_their_pixels_and_refuse_wrong_sizes() {
        let rgb: Vec<u8> = (0..48u8).collect();
        let t = TileResult {
            frame: 1,
            id: 2,
            tile: Tile { x: 0, y: 0, w: 4, h: 4 },
            render_micros: 0,
            codec: Codec::Qoi,
            pixels: ByteBuf::from(codec::encode(Codec::Qoi, 4, &rgb)),
        };
        assert_eq!(t.decoded_pixels().unwrap(), rgb);
        let lying = TileResult { tile: Tile { x: 0, y: 0, w: 4, h: 5 }, ..t };
        assert!(lying.decoded_pixels().is_err());
    }

    #[test]
    fn wrong_version_is_named() {
        let mut bytes = encode(&Message::Heartbeat).unwrap();
        bytes[1] = bytes[1].wrapping_add(1);
        assert!(matches!(decode(&bytes, 1024), Err(ProtocolError::Version { .. })));
    }

    #[test]
    fn oversized_frames_are_refused_before_decoding() {
        let bytes = encode(&Message::Error { message: "x".repeat(100) }).unwrap();
        assert!(matches!(decode(&bytes, 50), Err(ProtocolError::TooLarge { .. })));
        assert!(decode(&bytes, 500).is_ok());
    }

    #[test]
    fn trailing_bytes_are_refused() {
        let mut bytes = encode(&Message::Heartbeat).unwrap();
        bytes.push(0);
        assert!(matches!(decode(&bytes, 1024), Err(ProtocolError::Decode(_))));
    }

    #[test]
    fn truncated_frames_never_panic_and_never_decode() {
        for msg in samples() {
            let bytes = encode(&msg).unwrap();
            for cut in 0..bytes.len() {
                assert!(decode(&bytes[..cut], DEFAULT_MAX_FRAME).is_err(), "{} cut at {cut}", msg.kind());
            }
        }
    }

    #[test]
    fn huge_declared_lengths_do_not_allocate() {
        // A TileResult whose pixel binary claims 4 GiB but holds 3 bytes: a
        // real one whose pixels (last: bin8 marker, length 3, bytes) are re-declared.
        let mut bytes = encode(&Message::TileResult(TileResult {
            frame: 1,
            id: 1,
            tile: Tile { x: 0, y: 0, w: 1, h: 1 },
            render_micros: 1,
            codec: Codec::Raw,
            pixels: ByteBuf::from(vec![1, 2, 3]),
        }))
        .unwrap();
        assert!(decode(&bytes, DEFAULT_MAX_FRAME).is_ok());
        let at = bytes.len() - 5;
        assert_eq!(&bytes[at..at + 2], &[0xc4, 3]);
        bytes.splice(at..at + 2, [0xc6, 0xff, 0xff, 0xff, 0xff]);
        assert!(decode(&bytes, DEFAULT_MAX_FRAME).is_err());
        // And a Cancel whose tile array claims 2^32-1 entries.
        let mut bytes = PROTOCOL_VERSION.to_be_bytes().to_vec();
        bytes.push(0x81);
        bytes.push(0xa0 | 6);
        bytes.extend_from_slice(b"Cancel");
        bytes.extend_from_slice(&[0x92, 1, 0xdd, 0xff, 0xff, 0xff, 0xff, 1]);
        assert!(decode(&bytes, DEFAULT_MAX_FRAME).is_err());
    }

    #[test]
    fn slave_lists_are_bounded_while_decoding() {
        let entry =
            |id: u64| SlaveEntry { id, name: format!("s#{id}"), addr: "a".into(), threads: 1, alive: true };
        let full = Message::Slaves { slaves: (0..MAX_SLAVES_LISTED as u64).map(entry).collect() };
        assert_eq!(decode(&encode(&full).unwrap(), DEFAULT_MAX_FRAME).unwrap(), full);
        let over = Message::Slaves { slaves: (0..=MAX_SLAVES_LISTED as u64).map(entry).collect() };
        let err = decode(&encode(&over).unwrap(), DEFAULT_MAX_FRAME).unwrap_err();
        assert!(matches!(&err, ProtocolError::Decode(m) if m.contains("more than")), "{err:?}");
        // A list that declares 2^32-1 entries but holds none fails without allocating them.
        let mut bytes = PROTOCOL_VERSION.to_be_bytes().to_vec();
        bytes.push(0x81);
        bytes.push(0xa0 | 6);
        bytes.extend_from_slice(b"Slaves");
        bytes.extend_from_slice(&[0x91, 0xdd, 0xff, 0xff, 0xff, 0xff]);
        assert!(decode(&bytes, DEFAULT_MAX_FRAME).is_err());
        // Names and addresses are bounded too.
        let long =
            Message::Slaves { slaves: vec![SlaveEntry { addr: "x".repeat(MAX_SLAVE_TEXT + 1), ..entry(1) }] };
        assert!(matches!(decode(&encode(&long).unwrap(), DEFAULT_MAX_FRAME), Err(ProtocolError::Decode(_))));
    }

    #[test]
    fn scene_chunks_and_names_beyond_their_bounds_are_refused_while_decoding() {
        let max = crate::limits::SCENE_CHUNK_BYTES;
        let chunk =
            |n: usize| Message::SceneChunk { hash: [1; 32], index: 0, bytes: ByteBuf::from(vec![0; n]) };
        assert!(decode(&encode(&chunk(max)).unwrap(), DEFAULT_MAX_FRAME).is_ok());
        let err = decode(&encode(&chunk(max + 1)).unwrap(), DEFAULT_MAX_FRAME).unwrap_err();
        assert!(matches!(&err, ProtocolError::Decode(m) if m.contains("scene chunk")), "{err:?}");
        let header = |name: String| {
            Message::SceneBegin(SceneHeader {
                hash: [1; 32],
                name,
                raw_bytes: 1,
                compressed_bytes: 1,
                chunks: 1,
            })
        };
        assert!(decode(&encode(&header("a".repeat(MAX_SCENE_NAME))).unwrap(), DEFAULT_MAX_FRAME).is_ok());
        let long = encode(&header("a".repeat(MAX_SCENE_NAME + 1))).unwrap();
        assert!(matches!(decode(&long, DEFAULT_MAX_FRAME), Err(ProtocolError::Decode(_))));
    }

    #[test]
    fn random_bytes_never_panic() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let templates: Vec<Vec<u8>> = samples().iter().map(|m| encode(m).unwrap()).collect();
        for i in 0..20_000 {
            let mut bytes = if i % 2 == 0 {
                let len = (next() % 200) as usize;
                let mut v: Vec<u8> = (0..len).map(|_| next() as u8).collect();
                if v.len() >= 2 {
                    v[..2].copy_from_slice(&PROTOCOL_VERSION.to_be_bytes());
                }
                v
            } else {
                templates[(next() as usize) % templates.len()].clone()
            };
            // Flip a few bytes of valid messages: exercises deep decode paths.
            for _ in 0..(next() % 4) {
                if bytes.len() > 2 {
                    let at = 2 + (next() as usize) % (bytes.len() - 2);
                    bytes[at] = next() as u8;
                }
            }
            let _ = decode(&bytes, 4096);
        }
    }
}

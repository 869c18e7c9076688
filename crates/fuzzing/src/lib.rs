//! # isin-fuzzing — fuzz targets for every decoder of untrusted bytes
//!
//! One entry function per target, `fn(&[u8])`: it feeds the bytes to one
//! decoder of peer input or of files, and panics only on a bug — a panic in
//! the code under test, or a property of it that failed (a round trip that
//! does not round-trip, a pixel delivered twice, a peer let in without the
//! token). Errors the decoders return are the expected outcome of most inputs.
//!
//! The libFuzzer harnesses in `fuzz/fuzz_targets/` (nightly, `cargo fuzz`)
//! are one line each around these functions, and `tests/corpus.rs` replays
//! every input kept in `fuzz/corpus/<target>/` and `fuzz/regressions/<target>/`
//! through them on stable, so `cargo test` keeps what fuzzing found.
//!
//! Modules:
//! - [`wire`]: what peers send — the length-delimited stream codec, protocol
//!   messages, the handshake with the master's core, tile codecs, join tickets.
//! - [`files`]: what scene files hold — the scene TOML, OBJ, MTL, glTF, GLB,
//!   texture and environment images, and the scene bundle a slave loads.
//! - [`cluster`]: the structure-aware target — simulated slaves and viewers
//!   speaking valid-looking protocol to the master's core, its invariants
//!   checked after every step.

pub mod cluster;
pub mod files;
pub mod wire;

/// A fuzz target: its name (the harness's and the corpus directory's) and
/// its entry function.
#[derive(Clone, Copy, Debug)]
pub struct Target {
    /// Name of the harness in `fuzz/fuzz_targets/` and of its corpus directory.
    pub name: &'static str,
    /// Feeds one input to the code under test; panics only on a bug.
    pub run: fn(&[u8]),
}

/// Every target, fastest first.
pub const TARGETS: &[Target] = &[
    Target { name: "ticket", run: wire::ticket },
    Target { name: "message", run: wire::message },
    Target { name: "scene_stream", run: wire::scene_stream },
    Target { name: "tile_codec", run: wire::tile_codec },
    Target { name: "framing", run: wire::framing },
    Target { name: "handshake", run: wire::handshake },
    Target { name: "cluster", run: cluster::run },
    Target { name: "scene_toml", run: files::scene_toml },
    Target { name: "obj", run: files::obj },
    Target { name: "mtl", run: files::mtl },
    Target { name: "gltf", run: files::gltf },
    Target { name: "glb", run: files::glb },
    Target { name: "image", run: files::image },
    Target { name: "scene_bundle", run: files::scene_bundle },
];

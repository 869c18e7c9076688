//! Writes the seed inputs of every fuzz target: `cargo run -p isin-fuzzing
//! --example seeds -- DIR` fills `DIR/<target>/seed-N` (`fuzz/corpus` by
//! default), from which `cargo fuzz run` starts and `cargo fuzz cmin` keeps
//! what adds coverage.

use isin_cluster::codec::{self, Codec};
use isin_cluster::protocol::{
    self, DirectOffer, DirectRoute, DirectTile, FrameTile, Hello, Message, Role, SceneInfo, TileAssignment,
    TileJob, TileReceived, TileResult, Welcome,
};
use isin_cluster::scheduler::Work;
use isin_fuzzing::files::{MTL, fixtures, quad_obj, triangle_buffer, triangle_gltf};
use isin_tracer::{Camera, RenderSettings, SceneBundle, Tile};
use serde_bytes::ByteBuf;
use std::path::{Path, PathBuf};

fn main() {
    let out = std::env::args()
        .nth(1)
        .map_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/corpus"), PathBuf::from);
    let write = |target: &str, seeds: Vec<Vec<u8>>| {
        let dir = out.join(target);
        std::fs::create_dir_all(&dir).expect("corpus directory");
        for (i, s) in seeds.iter().enumerate() {
            std::fs::write(dir.join(format!("seed-{i}")), s).expect("seed written");
        }
        println!("{target}: {} seeds", seeds.len());
    };
    write("ticket", tickets());
    write("message", messages().iter().map(|m| protocol::encode(m).expect("encodes")).collect());
    write("scene_stream", scene_streams());
    write("tile_codec", tiles());
    write("framing", framing());
    write("handshake", handshake());
    write("cluster", (0..8u8).map(|k| (0..=255u8).map(|i| i.wrapping_mul(k * 2 + 1)).collect()).collect());
    write("scene_toml", vec![SCENE.into(), include_bytes!("../../../scenes/cornell.toml").to_vec()]);
    write("obj", vec![quad_obj("mesh.mtl").into_bytes(), CUBE_OBJ.into()]);
    write(
        "mtl",
        vec![MTL.into(), b"newmtl a\nKd 1 0 0\nmap_Kd -s 2 2 tex.png\nnewmtl b\nKe 2 2 2\n".to_vec()],
    );
    let f = fixtures();
    write("gltf", vec![triangle_gltf(Some("buffer.bin"), "tex.png").into_bytes(), data_uri_gltf()]);
    write("glb", vec![glb()]);
    write(
        "image",
        vec![
            [&[0u8][..], &f["tex.png"]].concat(),
            [&[1u8][..], &f["env.hdr"]].concat(),
            [&[2u8][..], &f["tex.png"]].concat(),
            [&[0u8][..], &jpeg()].concat(),
        ],
    );
    write("scene_bundle", bundles());
}

/// A scene using every fixture and every kind of section.
const SCENE: &str = r#"ambient = [0.05, 0.05, 0.05]
[background]
image = "env.hdr"
strength = 0.8
[settings]
width = 64
height = 48
[camera]
eye = [0, 1, 5]
target = [0, 0.5, 0]
fov = 40
[textures.wood]
kind = "image"
path = "tex.png"
[textures.check]
kind = "checker"
scale = 4
[materials.a]
kind = "phong"
texture = "wood"
[materials.b]
kind = "dielectric"
ior = 1.5
[materials.c]
kind = "emissive"
radiance = [2, 2, 2]
[[lights]]
kind = "area"
corner = [-1, 3, -1]
edge1 = [2, 0, 0]
edge2 = [0, 0, 2]
[[objects]]
kind = "sphere"
material = "b"
segments = 12
rings = 6
subdivide = 1
[[objects]]
kind = "obj"
path = "mesh.obj"
translate = [1, 0, 0]
[[objects]]
kind = "gltf"
path = "mesh.gltf"
rotate = [0, 45, 0]
scale = 2
[[objects]]
kind = "cylinder"
material = "c"
caps = false
"#;

const CUBE_OBJ: &str = "o cube\nv -1 -1 -1\nv 1 -1 -1\nv 1 1 -1\nv -1 1 -1\nv -1 -1 1\nv 1 -1 1\nv 1 1 1\nv -1 1 1\n\
g sides\nf 1 2 3 4\nf 5 6 7 8\nf -8 -7 -3 -4\ns off\nf 2 3 7 6\nf 1 4 8 5\nf 1 2 6 5\n";

fn tickets() -> Vec<Vec<u8>> {
    let fp = "ab".repeat(32);
    [
        format!("isin://token@127.0.0.1:7000?fp={fp}"),
        format!("isin+quic://t0k@[::1]:9?fp={fp}&x=1"),
        format!("isin+tcp://a@b@host:65535?fp={}", fp.to_uppercase()),
        "isin+tcp-insecure://tok@localhost:1".into(),
        "ab:cd:ef".into(),
        "quic".into(),
    ]
    .into_iter()
    .map(String::into_bytes)
    .collect()
}

fn messages() -> Vec<Message> {
    let settings = RenderSettings { width: 16, height: 8, ..RenderSettings::default() };
    let tile = Tile { x: 0, y: 0, w: 4, h: 2 };
    let rgb: Vec<u8> = (0..24).collect();
    let bundle = SceneBundle { name: "s.toml".into(), source: "[camera]".into(), assets: fixtures().clone() };
    let packed = isin_cluster::scene_stream::pack(&bundle).expect("packs");
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
                addr: "10.0.0.2:7000".into(),
                fingerprint: None,
                key: [4; 32],
            })),
        }),
        Message::Welcome(Welcome {
            id: 9,
            name: "box#9".into(),
            proof: [4; 32],
            scene: Some(SceneInfo { name: "s".into(), hash: [5; 32], camera: Camera::default(), settings }),
            codec: Codec::Qoi,
        }),
        Message::SceneBegin(packed.header.clone()),
        protocol::decode(&packed.chunk_frame(0).expect("one chunk"), usize::MAX).expect("decodes"),
        Message::SceneAck { hash: packed.header.hash, chunks_received: 1 },
        Message::Ready { hash: Some([6; 32]) },
        Message::FrameRequest { request: 3, scene: None, camera: Camera::default(), settings },
        Message::QueueFrame {
            request: 4,
            scene: Some([8; 32]),
            camera: Camera::default(),
            settings,
            job_frame: Some(2),
        },
        Message::SceneUpload(packed.header.clone()),
        Message::NeedScene { hash: [2; 32] },
        Message::SceneFailed { hash: [2; 32], reason: "no memory".into() },
        Message::StatusRequest,
        Message::Cancel { frame: 2, tiles: vec![1, 5, 9] },
        Message::TileResult(TileResult {
            frame: 1,
            id: 0,
            tile,
            render_micros: 10,
            codec: Codec::Lz4,
            pixels: ByteBuf::from(codec::encode(Codec::Lz4, 4, &rgb)),
        }),
        Message::Slaves {
            slaves: vec![protocol::SlaveEntry {
                id: 1,
                name: "a".into(),
                addr: "b".into(),
                threads: 2,
                alive: true,
            }],
        },
        Message::TileAssignment(TileAssignment {
            frame: 5,
            scene: [5; 32],
            camera: Camera::default(),
            settings,
            tiles: vec![TileJob { id: 0, tile }, TileJob { id: 1, tile }],
            direct: Some(Box::new(DirectRoute {
                viewer: 3,
                request: 4,
                offer: Some(DirectOffer {
                    addr: "[::1]:9".into(),
                    fingerprint: Some("ab".repeat(32)),
                    key: [1; 32],
                }),
                via_master: vec![1],
            })),
        }),
        Message::DirectHello { key: [1; 32], slave: 9 },
        Message::DirectTile(DirectTile {
            frame: 5,
            id: 0,
            tile: FrameTile {
                request: 4,
                slave: 9,
                slave_name: "box#9".into(),
                tile,
                codec: Codec::Raw,
                pixels: ByteBuf::from(rgb.clone()),
            },
            render_micros: 10,
        }),
        Message::DirectAck { frame: 5, id: 0 },
        Message::TileReceived(TileReceived { frame: 5, id: 0, slave: 9, tile, render_micros: 10 }),
        Message::Heartbeat,
        Message::Error { message: "no".into() },
        Message::Notice { message: "wait".into() },
    ]
}

fn tiles() -> Vec<Vec<u8>> {
    let (w, h) = (5u8, 3u8);
    let rgb: Vec<u8> = (0..usize::from(w) * usize::from(h) * 3).map(|i| (i * 7 % 256) as u8).collect();
    Codec::ALL
        .iter()
        .enumerate()
        .map(|(i, &c)| [&[i as u8, w, h][..], &codec::encode(c, u32::from(w), &rgb)].concat())
        .collect()
}

fn framing() -> Vec<Vec<u8>> {
    let frame = |body: &[u8]| [&(body.len() as u32).to_be_bytes()[..], body].concat();
    vec![
        [&[0, 64, 0][..], &frame(b"hello"), &frame(b""), &frame(&[9; 40])].concat(),
        [&[1, 0, 1][..], &frame(&[1; 200]), &frame(&[2; 100])].concat(),
        [&[0, 8, 0][..], &frame(&[3; 9])].concat(),
        [&[0, 8, 0][..], &frame(b"cut")[..5]].concat(),
    ]
}

fn handshake() -> Vec<Vec<u8>> {
    let hello = protocol::encode(&messages()[1]).expect("encodes");
    let len = hello.len() as u8;
    vec![
        [&[0u8, 0, 1, 0, len][..], &hello, &[2, 0, 3, 255]].concat(),
        vec![0, 0, 0, 0, 0, 0, 2, 0, 255, 255, 3, 1, 4, 2],
    ]
}

fn glb() -> Vec<u8> {
    let mut json = triangle_gltf(None, "tex.png").into_bytes();
    while json.len() % 4 != 0 {
        json.push(b' ');
    }
    let bin = triangle_buffer();
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let mut out = Vec::new();
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    out
}

fn base64(bytes: &[u8]) -> String {
    const ABC: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for chunk in bytes.chunks(3) {
        let n = chunk.iter().enumerate().fold(0u32, |n, (i, &b)| n | u32::from(b) << (16 - 8 * i));
        for i in 0..4 {
            out.push(if i <= chunk.len() { ABC[(n >> (18 - 6 * i) & 63) as usize] as char } else { '=' });
        }
    }
    out
}

fn data_uri_gltf() -> Vec<u8> {
    let uri = format!("data:application/octet-stream;base64,{}", base64(&triangle_buffer()));
    triangle_gltf(Some(&uri), "tex.png").into_bytes()
}

fn jpeg() -> Vec<u8> {
    let img = image::RgbImage::from_fn(8, 8, |x, y| image::Rgb([x as u8 * 30, y as u8 * 30, 90]));
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Jpeg).expect("a JPEG encodes");
    out.into_inner()
}

/// Packed scenes as the `scene_stream` target takes them: hash, unpacked
/// size, compressed stream.
fn scene_streams() -> Vec<Vec<u8>> {
    let cornell = include_str!("../../../scenes/cornell.toml");
    [
        SceneBundle { name: "fuzz.toml".into(), source: SCENE.into(), assets: fixtures().clone() },
        SceneBundle { name: "cornell.toml".into(), source: cornell.into(), assets: Default::default() },
    ]
    .iter()
    .map(|bundle| {
        let packed = isin_cluster::scene_stream::pack(bundle).expect("packs");
        let h = &packed.header;
        let mut out = h.hash.to_vec();
        out.extend_from_slice(&(h.raw_bytes as u32).to_le_bytes());
        for i in 0..h.chunks {
            let frame = packed.chunk_frame(i).expect("a chunk");
            let Ok(Message::SceneChunk { bytes, .. }) = protocol::decode(&frame, usize::MAX) else {
                panic!("a chunk decodes")
            };
            out.extend_from_slice(&bytes);
        }
        out
    })
    .collect()
}

fn bundles() -> Vec<Vec<u8>> {
    let sync = |bundle: SceneBundle| isin_cluster::scene_stream::encode_bundle(&bundle).expect("encodes");
    let cornell = include_str!("../../../scenes/cornell.toml");
    vec![
        sync(SceneBundle { name: "fuzz.toml".into(), source: SCENE.into(), assets: fixtures().clone() }),
        sync(SceneBundle { name: "cornell.toml".into(), source: cornell.into(), assets: Default::default() }),
    ]
}

//! Measures lossless tile codecs on real rendered tiles: bytes, and CPU time to
//! encode and decode, per tile. This is how [`isin_cluster::codec`]'s default
//! was chosen (docs/performance-notes.md, "Tile compression"; BENCHMARKS.md runs it).
//!
//! ```text
//! cargo run --release -p isin-cluster --example tile_codecs [-- SCENE.toml…]
//! ```
//!
//! Renders each scene at 640×480 with the viewer's two kinds of pass —
//! *moving* (1 sample, 1 shadow ray per area light) and *still* (4 samples, the
//! scene's shadow rays) — cuts the frame into 32×32 and 64×64 tiles, and runs
//! every candidate over every tile (single-threaded, best of 3 runs). Prints a
//! Markdown table: compression ratio against raw RGB8, mean bytes per tile,
//! encode and decode microseconds per tile, and for isin's own codecs the
//! master's check ([`codec::check`], which walks a tile without decoding it).

use isin_cluster::codec::{self, Codec};
use isin_tracer::{AssetSource, RenderSettings, Tile};
use std::path::{Path, PathBuf};
use std::time::Instant;

struct Disk(PathBuf);

impl AssetSource for Disk {
    fn read(&mut self, path: &str) -> Result<Vec<u8>, String> {
        std::fs::read(self.0.join(path)).map_err(|e| format!("{path}: {e}"))
    }
}

/// Replaces each byte by its wrapping difference to the same channel of the
/// pixel on its left (the pixel above for the first column).
fn delta_encode(w: u32, rgb: &[u8]) -> Vec<u8> {
    let row = w as usize * 3;
    let mut out = Vec::with_capacity(rgb.len());
    for (i, &b) in rgb.iter().enumerate() {
        let pred = if i % row >= 3 {
            rgb[i - 3]
        } else if i >= row {
            rgb[i - row]
        } else {
            0
        };
        out.push(b.wrapping_sub(pred));
    }
    out
}

/// Undoes [`delta_encode`] in place.
fn delta_decode(w: u32, data: &mut [u8]) {
    let row = w as usize * 3;
    for i in 0..data.len() {
        let pred = if i % row >= 3 {
            data[i - 3]
        } else if i >= row {
            data[i - row]
        } else {
            0
        };
        data[i] = data[i].wrapping_add(pred);
    }
}

/// The median-edge-detector (LOCO-I) predictor, per channel.
fn med_encode(w: usize, rgb: &[u8]) -> Vec<u8> {
    let row = w * 3;
    let mut out = Vec::with_capacity(rgb.len());
    for (i, &b) in rgb.iter().enumerate() {
        let (x, y) = ((i % row) / 3, i / row);
        let a = if x > 0 { rgb[i - 3] as i32 } else { 0 };
        let up = if y > 0 { rgb[i - row] as i32 } else { 0 };
        let c = if x > 0 && y > 0 { rgb[i - row - 3] as i32 } else { 0 };
        let pred = if x == 0 {
            up
        } else if y == 0 {
            a
        } else if c >= a.max(up) {
            a.min(up)
        } else if c <= a.min(up) {
            a.max(up)
        } else {
            a + up - c
        };
        out.push(b.wrapping_sub(pred as u8));
    }
    out
}

fn med_decode(w: usize, d: &mut [u8]) {
    let row = w * 3;
    for i in 0..d.len() {
        let (x, y) = ((i % row) / 3, i / row);
        let a = if x > 0 { d[i - 3] as i32 } else { 0 };
        let up = if y > 0 { d[i - row] as i32 } else { 0 };
        let c = if x > 0 && y > 0 { d[i - row - 3] as i32 } else { 0 };
        let pred = if x == 0 {
            up
        } else if y == 0 {
            a
        } else if c >= a.max(up) {
            a.min(up)
        } else if c <= a.min(up) {
            a.max(up)
        } else {
            a + up - c
        };
        d[i] = d[i].wrapping_add(pred as u8);
    }
}

type Enc = Box<dyn Fn(Tile, &[u8]) -> Vec<u8>>;
type Dec = Box<dyn Fn(Tile, &[u8]) -> Vec<u8>>;

fn candidates() -> Vec<(&'static str, Enc, Dec)> {
    let ours = |c: Codec| -> (Enc, Dec) {
        (
            Box::new(move |t: Tile, rgb: &[u8]| codec::encode(c, t.w, rgb)),
            Box::new(move |t: Tile, d: &[u8]| codec::decode(c, t.w, t.h, d).expect("decodes")),
        )
    };
    let zstd = |level: i32, delta: bool| -> (Enc, Dec) {
        (
            Box::new(move |t: Tile, rgb: &[u8]| {
                let input = if delta { delta_encode(t.w, rgb) } else { rgb.to_vec() };
                zstd::bulk::compress(&input, level).expect("zstd")
            }),
            Box::new(move |t: Tile, d: &[u8]| {
                let mut out = zstd::bulk::decompress(d, t.pixel_count() * 3).expect("zstd");
                if delta {
                    delta_decode(t.w, &mut out);
                }
                out
            }),
        )
    };
    let mut v: Vec<(&'static str, Enc, Dec)> = Vec::new();
    for (name, c) in [("raw", Codec::Raw), ("lz4", Codec::Lz4)] {
        let (e, d) = ours(c);
        v.push((name, e, d));
    }
    v.push((
        "delta-lz4",
        Box::new(|t: Tile, rgb: &[u8]| lz4_flex::block::compress(&delta_encode(t.w, rgb))),
        Box::new(|t: Tile, d: &[u8]| {
            let mut out = lz4_flex::block::decompress(d, t.pixel_count() * 3).expect("lz4");
            delta_decode(t.w, &mut out);
            out
        }),
    ));
    v.push((
        "med-lz4",
        Box::new(|t: Tile, rgb: &[u8]| lz4_flex::block::compress(&med_encode(t.w as usize, rgb))),
        Box::new(|t: Tile, d: &[u8]| {
            let mut out = lz4_flex::block::decompress(d, t.pixel_count() * 3).expect("lz4");
            med_decode(t.w as usize, &mut out);
            out
        }),
    ));
    for (name, level, delta) in
        [("zstd-1", 1, false), ("zstd-3", 3, false), ("delta-zstd-1", 1, true), ("delta-zstd-3", 3, true)]
    {
        let (e, d) = zstd(level, delta);
        v.push((name, e, d));
    }
    let (e, d) = ours(Codec::Qoi);
    v.push(("qoi", e, d));
    v
}

fn tiles(w: u32, h: u32, edge: u32) -> Vec<Tile> {
    let mut out = Vec::new();
    for y in (0..h).step_by(edge as usize) {
        for x in (0..w).step_by(edge as usize) {
            out.push(Tile { x, y, w: edge.min(w - x), h: edge.min(h - y) });
        }
    }
    out
}

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let args: Vec<PathBuf> = std::env::args().skip(1).map(PathBuf::from).collect();
    let scenes = if args.is_empty() {
        ["paper.toml", "cornell.toml", "mesh.toml"].iter().map(|s| root.join("scenes").join(s)).collect()
    } else {
        args
    };
    let cands = candidates();
    println!(
        "| scene | pass | tile | codec | ratio | bytes/tile | encode µs/tile | decode µs/tile | check µs/tile |"
    );
    println!("| --- | --- | --- | --- | ---: | ---: | ---: | ---: | ---: |");
    for path in &scenes {
        let source = std::fs::read_to_string(path).expect("scene file");
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        let mut disk = Disk(path.parent().unwrap().to_path_buf());
        let parts = isin_tracer::parse_scene(&name, &source, &mut disk).expect("scene");
        let base = parts.settings;
        let camera = parts.camera;
        let scene = isin_tracer::Scene::new(parts);
        let moving = RenderSettings { width: 640, height: 480, spp: 1, light_samples: 1, ..base };
        let still = RenderSettings {
            width: 640,
            height: 480,
            spp: 4,
            light_samples: base.light_samples.max(1),
            ..base
        };
        for (pass, settings) in [("moving", moving), ("still", still)] {
            let frame = isin_tracer::render_frame(&scene, &camera, &settings, 32, &|_| {});
            for edge in [32, 64] {
                let ts = tiles(640, 480, edge);
                let pixels: Vec<Vec<u8>> = ts
                    .iter()
                    .map(|t| {
                        let mut out = Vec::with_capacity(t.pixel_count() * 3);
                        for y in t.y..t.y + t.h {
                            let at = (y as usize * 640 + t.x as usize) * 3;
                            out.extend_from_slice(&frame.rgb[at..at + t.w as usize * 3]);
                        }
                        out
                    })
                    .collect();
                let raw: usize = pixels.iter().map(Vec::len).sum();
                for (cname, enc, dec) in &cands {
                    let mut best_enc = f64::MAX;
                    let mut best_dec = f64::MAX;
                    let mut best_check = f64::MAX;
                    let ours = Codec::from_name(cname);
                    let mut bytes = 0;
                    for _ in 0..3 {
                        let t0 = Instant::now();
                        let encoded: Vec<Vec<u8>> = ts.iter().zip(&pixels).map(|(t, p)| enc(*t, p)).collect();
                        let t1 = Instant::now();
                        for ((t, p), e) in ts.iter().zip(&pixels).zip(&encoded) {
                            assert_eq!(&dec(*t, e), p, "{cname} does not round-trip");
                        }
                        let t2 = Instant::now();
                        if let Some(c) = ours {
                            for (t, e) in ts.iter().zip(&encoded) {
                                assert_eq!(codec::check(c, t.w, t.h, e), Ok(()), "{cname} fails its check");
                            }
                        }
                        let t3 = Instant::now();
                        best_enc = best_enc.min((t1 - t0).as_secs_f64());
                        best_dec = best_dec.min((t2 - t1).as_secs_f64());
                        best_check = best_check.min((t3 - t2).as_secs_f64());
                        bytes = encoded.iter().map(Vec::len).sum();
                    }
                    let n = ts.len() as f64;
                    let check = ours.map_or("—".to_string(), |_| format!("{:.2}", best_check * 1e6 / n));
                    println!(
                        "| {name} | {pass} | {edge} | {cname} | {:.2} | {:.0} | {:.1} | {:.1} | {check} |",
                        raw as f64 / bytes as f64,
                        bytes as f64 / n,
                        best_enc * 1e6 / n,
                        best_dec * 1e6 / n,
                    );
                }
            }
        }
    }
}

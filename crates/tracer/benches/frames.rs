//! Full-frame benchmark: the shipped paper scene at 320×240 and 640×480, 1 spp,
//! on 1 and 2 threads, against the paper's 2.61 s single-PC frame and issue 2's
//! bar (1/100 of it, 26.1 ms, at 320×240 on 2 threads). Also shows what the
//! speed-ups bought, on 320×240 / 2 threads: the same frame with every
//! area-light sample traced (no adaptive shadows) and with the scalar box test
//! (no SSE; same bytes).
//!
//! `cargo bench -p isin-tracer --bench frames` — prints a Markdown table and
//! writes `target/bench/frames.json`. Wall times on a loaded machine are noisy;
//! compare rows of one run.

use isin_tracer::integrator::RayCounts;
use isin_tracer::render::{TraceOptions, render_frame_with};
use isin_tracer::{AssetSource, RenderSettings, Scene, load_scene};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The paper's single-PC frame time at 320×240 (Table 1).
const PAPER_SECONDS: f64 = 2.61;
const REPS: usize = 15;

struct Dir(PathBuf);

impl AssetSource for Dir {
    fn read(&mut self, path: &str) -> Result<Vec<u8>, String> {
        std::fs::read(self.0.join(path)).map_err(|e| format!("{path}: {e}"))
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Median and p95 seconds of [`REPS`] frames, and the rays of one frame.
fn time_frames(
    scene: &Scene,
    settings: &RenderSettings,
    threads: usize,
    options: &TraceOptions,
) -> (f64, f64, RayCounts) {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
    let mut times = Vec::with_capacity(REPS);
    let counts = pool.install(|| {
        let (_, counts) = render_frame_with(scene, &scene.camera, settings, 32, options, &|_| {}); // warm-up
        for _ in 0..REPS {
            let t = Instant::now();
            std::hint::black_box(render_frame_with(scene, &scene.camera, settings, 32, options, &|_| {}));
            times.push(t.elapsed().as_secs_f64());
        }
        counts
    });
    let med = median(times.clone());
    times.sort_by(f64::total_cmp);
    let p95 = times[(times.len() * 95).div_ceil(100).min(times.len()) - 1];
    (med, p95, counts)
}

/// (variant, scene, options, resolution, threads).
type Case<'a> = (&'a str, &'a Scene, &'a TraceOptions, (u32, u32), usize);

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let scene_path = root.join("scenes/paper.toml");
    let source = std::fs::read_to_string(&scene_path).expect("scenes/paper.toml");
    let scene =
        load_scene("scenes/paper.toml", &source, &mut Dir(root.join("scenes"))).expect("paper scene loads");
    let tris = scene.triangle_count();
    println!(
        "paper.toml: {tris} triangles; BVH + triangle data {:.1} bytes/triangle; SIMD box test {}",
        scene.bvh.memory_bytes() as f64 / tris.max(1) as f64,
        if scene.bvh.simd_active() { "on" } else { "off" }
    );
    let mut scalar = scene.clone();
    scalar.bvh.set_simd(false);
    let adaptive = TraceOptions::default();
    let exhaustive = TraceOptions { adaptive_shadows: false };

    println!(
        "| scene | variant | resolution | threads | median ms | p95 ms | frames/s | × faster than paper | Mrays/frame (shadow) | Mrays/s |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let mut json = Vec::new();
    let mut cases: Vec<Case> = Vec::new();
    for (w, h) in [(320, 240), (640, 480)] {
        for threads in [1, 2] {
            cases.push(("default", &scene, &adaptive, (w, h), threads));
        }
    }
    cases.push(("exhaustive shadows", &scene, &exhaustive, (320, 240), 2));
    cases.push(("scalar box test", &scalar, &adaptive, (320, 240), 2));
    for (variant, sc, options, (w, h), threads) in cases {
        let settings = RenderSettings { width: w, height: h, spp: 1, ..sc.settings };
        let (med, p95, counts) = time_frames(sc, &settings, threads, options);
        let speedup = if (w, h) == (320, 240) { format!("{:.0}", PAPER_SECONDS / med) } else { "–".into() };
        println!(
            "| paper.toml | {variant} | {w}×{h} | {threads} | {:.2} | {:.2} | {:.1} | {speedup} | {:.2} ({:.2}) | {:.2} |",
            med * 1e3,
            p95 * 1e3,
            1.0 / med,
            counts.total() as f64 * 1e-6,
            counts.shadow as f64 * 1e-6,
            counts.total() as f64 * 1e-6 / med
        );
        json.push(format!(
            "{{\"scene\":\"paper.toml\",\"variant\":\"{variant}\",\"width\":{w},\"height\":{h},\"threads\":{threads},\"median_ms\":{:.3},\"p95_ms\":{:.3},\"rays\":{},\"shadow_rays\":{}}}",
            med * 1e3,
            p95 * 1e3,
            counts.total(),
            counts.shadow
        ));
    }
    println!(
        "bar (issue 2): 320×240, 2 threads, under {:.1} ms (1/100 of the paper's {PAPER_SECONDS} s) on an idle machine",
        PAPER_SECONDS * 10.0
    );
    let out = root.join("target/bench");
    std::fs::create_dir_all(&out).expect("target/bench");
    std::fs::write(out.join("frames.json"), format!("[{}]\n", json.join(",\n"))).expect("write json");
}

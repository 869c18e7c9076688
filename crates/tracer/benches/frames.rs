//! Full-frame benchmark: the shipped paper scene at 320×240 and 640×480, 1 spp,
//! on 1 and 2 threads, against the paper's 2.61 s single-PC frame and issue 2's
//! bar (1/100 of it, 26.1 ms, at 320×240 on 2 threads); the paper scene, the
//! bunny and the 1.6M-triangle dragon (`scenes/bunny.toml`, `dragon.toml`) at
//! 640×480 in the viewer's "moving" settings (1 spp, one shadow ray per light
//! per hit), issue 6's bars (≥ 60 and ≥ 20 frames/s on 2 threads). Also shows
//! what the speed-ups bought, on 2 threads: camera rays traced one by one
//! instead of in 4×2 packets (same bytes), and on 320×240 the paper frame with
//! every area-light sample traced (no adaptive shadows), with the scalar
//! box test (no SSE; same bytes) and with every shadow ray traced instead of
//! answered from the shadow cells where they can (same bytes), and the first
//! frame of a session, whose shadow cells start empty. Frames otherwise follow
//! a warm-up frame on the same scene, as in an interactive session. Ray counts
//! are rays traced (shadow rays answered by a cell are not traced).
//!
//! `cargo bench -p isin-tracer --bench frames [-- bunny.toml …]` — prints a
//! Markdown table and writes `target/bench/frames.json`. Wall times on a loaded
//! machine are noisy; compare rows of one run.

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
/// With `cold`, each frame renders on a fresh copy of the scene, whose
/// shadow cells are still empty (the first frame of a session); otherwise
/// frames follow a warm-up frame on the same scene.
fn time_frames(
    scene: &Scene,
    settings: &RenderSettings,
    threads: usize,
    options: &TraceOptions,
    cold: bool,
) -> (f64, f64, RayCounts) {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
    let mut times = Vec::with_capacity(REPS);
    let counts = pool.install(|| {
        let (_, counts) = render_frame_with(scene, &scene.camera, settings, 32, options, &|_| {}); // warm-up
        for _ in 0..REPS {
            let fresh = cold.then(|| scene.clone());
            let scene = fresh.as_ref().unwrap_or(scene);
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

/// (scene name, variant, scene, settings, options, threads).
type Case<'a> = (&'a str, &'a str, &'a Scene, RenderSettings, &'a TraceOptions, usize);

/// Loads `scenes/NAME`, or says why it is skipped (the mesh scenes read
/// `../shared/meshes`, which may be absent).
fn load(root: &Path, name: &str) -> Option<Scene> {
    let path = root.join("scenes").join(name);
    let source = std::fs::read_to_string(&path).expect("shipped scene file");
    let t = Instant::now();
    match load_scene(&format!("scenes/{name}"), &source, &mut Dir(root.join("scenes"))) {
        Ok(scene) => {
            let tris = scene.triangle_count();
            println!(
                "{name}: {tris} triangles, loaded and BVH built in {:.0} ms; BVH + triangle data {:.1} bytes/triangle; \
                 SIMD box test {}",
                t.elapsed().as_secs_f64() * 1e3,
                scene.bvh.memory_bytes() as f64 / tris.max(1) as f64,
                if scene.bvh.simd_active() { "on" } else { "off" }
            );
            Some(scene)
        }
        Err(e) => {
            println!("skipping {name}: {e}");
            None
        }
    }
}

/// The settings the viewer renders with while the camera moves
/// (`isin_viewer::session::Quality::default()`: 1 spp, one shadow ray per
/// light per hit, full resolution).
fn moving(s: &RenderSettings, width: u32, height: u32) -> RenderSettings {
    RenderSettings { width, height, spp: 1, light_samples: 1, ..*s }
}

/// Large blocks (the BVH, the triangle blocks) in huge pages, as Embree's own allocator does.
#[global_allocator]
static ALLOC: isin_tracer::memory::HugePages = isin_tracer::memory::HugePages::SYSTEM;

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    // Arguments (after `--`) select scenes by file name, e.g. `-- bunny.toml`.
    let filter: Vec<String> = std::env::args().skip(1).filter(|a| !a.starts_with("--")).collect();
    let wanted = |name: &str| filter.is_empty() || filter.iter().any(|f| f == name);
    let paper = wanted("paper.toml").then(|| load(&root, "paper.toml")).flatten();
    let bunny = wanted("bunny.toml").then(|| load(&root, "bunny.toml")).flatten();
    let dragon = wanted("dragon.toml").then(|| load(&root, "dragon.toml")).flatten();
    let scalar = paper.as_ref().map(|p| {
        let mut s = p.clone();
        s.bvh.set_simd(false);
        s
    });
    let adaptive = TraceOptions::default();
    let exhaustive = TraceOptions { adaptive_shadows: false, ..TraceOptions::default() };
    let single = TraceOptions { packets: false, ..TraceOptions::default() };
    let traced = TraceOptions { shadow_cells: false, ..TraceOptions::default() };

    println!(
        "| scene | variant | resolution | threads | median ms | p95 ms | frames/s | × faster than paper | Mrays traced/frame (shadow) | Mrays/s |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let mut json = Vec::new();
    let mut cases: Vec<Case> = Vec::new();
    let mut cold_cases: Vec<Case> = Vec::new();
    if let (Some(scene), Some(scalar)) = (&paper, &scalar) {
        let shipped = |w, h| RenderSettings { width: w, height: h, spp: 1, ..scene.settings };
        for (w, h) in [(320, 240), (640, 480)] {
            for threads in [1, 2] {
                cases.push(("paper.toml", "as shipped", scene, shipped(w, h), &adaptive, threads));
            }
        }
        // The paper's own feature set: hard shadows only (soft shadows were
        // its future work), i.e. one shadow ray per light — the viewer's
        // moving settings.
        for (w, h) in [(320, 240), (640, 480)] {
            for threads in [1, 2] {
                cases.push((
                    "paper.toml",
                    "moving",
                    scene,
                    moving(&scene.settings, w, h),
                    &adaptive,
                    threads,
                ));
            }
        }
        cases.push(("paper.toml", "single camera rays", scene, shipped(320, 240), &single, 2));
        cases.push((
            "paper.toml",
            "moving, single camera rays",
            scene,
            moving(&scene.settings, 640, 480),
            &single,
            2,
        ));
        cases.push(("paper.toml", "exhaustive shadows", scene, shipped(320, 240), &exhaustive, 2));
        cases.push(("paper.toml", "no shadow cells", scene, shipped(320, 240), &traced, 2));
        cold_cases.push((
            "paper.toml",
            "first frame (empty shadow cells)",
            scene,
            shipped(320, 240),
            &adaptive,
            2,
        ));
        cases.push(("paper.toml", "scalar box test", scalar, shipped(320, 240), &adaptive, 2));
    }
    for (name, scene) in [("bunny.toml", &bunny), ("dragon.toml", &dragon)] {
        if let Some(scene) = scene {
            for threads in [1, 2] {
                cases.push((name, "moving", scene, moving(&scene.settings, 640, 480), &adaptive, threads));
            }
            let settings = moving(&scene.settings, 640, 480);
            cases.push((name, "moving, single camera rays", scene, settings, &single, 2));
            cases.push((name, "moving, no shadow cells", scene, settings, &traced, 2));
        }
    }
    let all = cases.into_iter().map(|c| (c, false)).chain(cold_cases.into_iter().map(|c| (c, true)));
    for ((name, variant, sc, settings, options, threads), cold) in all {
        let (w, h) = (settings.width, settings.height);
        let (med, p95, counts) = time_frames(sc, &settings, threads, options, cold);
        let speedup = if name == "paper.toml" && (w, h) == (320, 240) {
            format!("{:.0}", PAPER_SECONDS / med)
        } else {
            "–".into()
        };
        println!(
            "| {name} | {variant} | {w}×{h} | {threads} | {:.2} | {:.2} | {:.1} | {speedup} | {:.2} ({:.2}) | {:.2} |",
            med * 1e3,
            p95 * 1e3,
            1.0 / med,
            counts.total() as f64 * 1e-6,
            counts.shadow as f64 * 1e-6,
            counts.total() as f64 * 1e-6 / med
        );
        json.push(format!(
            "{{\"scene\":\"{name}\",\"variant\":\"{variant}\",\"width\":{w},\"height\":{h},\"spp\":{},\"light_samples\":{},\"threads\":{threads},\"median_ms\":{:.3},\"p95_ms\":{:.3},\"rays\":{},\"shadow_rays\":{}}}",
            settings.spp,
            settings.light_samples,
            med * 1e3,
            p95 * 1e3,
            counts.total(),
            counts.shadow
        ));
    }
    println!(
        "bars: issue 2 — paper 320×240, 2 threads, under {:.1} ms (1/100 of the paper's {PAPER_SECONDS} s); \
         issue 6 — paper 640×480 1 spp ≥ 60 frames/s on 2 threads, bunny and dragon (1.6M) moving ≥ 20 frames/s \
         (idle machine; `uptime` for the load)",
        PAPER_SECONDS * 10.0
    );
    let out = root.join("target/bench");
    std::fs::create_dir_all(&out).expect("target/bench");
    std::fs::write(out.join("frames.json"), format!("[{}]\n", json.join(",\n"))).expect("write json");
}

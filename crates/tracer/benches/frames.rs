//! Full-frame benchmark: the shipped paper scene at 320×240 and 640×480, 1 spp,
//! on 1 and 2 threads, against the paper's 2.61 s single-PC frame.
//!
//! `cargo bench -p isin-tracer --bench frames` — prints a Markdown table and
//! writes `target/bench/frames.json`.

use isin_tracer::{AssetSource, RenderSettings, load_scene, render_frame};
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

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let scene_path = root.join("scenes/paper.toml");
    let source = std::fs::read_to_string(&scene_path).expect("scenes/paper.toml");
    let scene =
        load_scene("scenes/paper.toml", &source, &mut Dir(root.join("scenes"))).expect("paper scene loads");

    println!("| scene | resolution | threads | median ms | p95 ms | frames/s | × faster than paper |");
    println!("|---|---|---|---|---|---|---|");
    let mut json = Vec::new();
    for (w, h) in [(320, 240), (640, 480)] {
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
            let settings = RenderSettings { width: w, height: h, spp: 1, ..scene.settings };
            let mut times = Vec::with_capacity(REPS);
            pool.install(|| {
                render_frame(&scene, &scene.camera, &settings, 32, &|_| {}); // warm-up
                for _ in 0..REPS {
                    let t = Instant::now();
                    std::hint::black_box(render_frame(&scene, &scene.camera, &settings, 32, &|_| {}));
                    times.push(t.elapsed().as_secs_f64());
                }
            });
            let med = median(times.clone());
            let p95 = {
                times.sort_by(f64::total_cmp);
                times[(times.len() * 95).div_ceil(100).min(times.len()) - 1]
            };
            let speedup =
                if (w, h) == (320, 240) { format!("{:.0}", PAPER_SECONDS / med) } else { "–".into() };
            println!(
                "| paper.toml | {w}×{h} | {threads} | {:.2} | {:.2} | {:.1} | {speedup} |",
                med * 1e3,
                p95 * 1e3,
                1.0 / med
            );
            json.push(format!(
                "{{\"scene\":\"paper.toml\",\"width\":{w},\"height\":{h},\"threads\":{threads},\"median_ms\":{:.3},\"p95_ms\":{:.3}}}",
                med * 1e3,
                p95 * 1e3
            ));
        }
    }
    let out = root.join("target/bench");
    std::fs::create_dir_all(&out).expect("target/bench");
    std::fs::write(out.join("frames.json"), format!("[{}]\n", json.join(",\n"))).expect("write json");
}

//! Renders one scene several times (on one thread unless told otherwise), as an interactive session
//! does (the scene's shadow cells fill during the first frame), and prints each frame's time and
//! its camera, secondary and shadow rays: a loop for profilers. The cost of a warm frame is the
//! difference between two runs with different frame counts, e.g.
//!
//! ```sh
//! cargo build --release -p isin-tracer --example frames
//! valgrind --tool=callgrind target/release/examples/frames scenes/paper.toml 320 240 1
//! valgrind --tool=callgrind target/release/examples/frames scenes/paper.toml 320 240 3
//! ```
//!
//! Arguments: `SCENE WIDTH HEIGHT FRAMES [--no-shadow-cells] [--fill-cells] [--threads N]
//! [--moving]` (`--fill-cells` fills the cells around every surface before the first frame, as
//! a slave does; `--threads` renders on N threads instead of one; `--moving` renders with the
//! viewer's settings while the camera moves: 1 spp, one shadow ray per light).

use isin_tracer::render::{TraceOptions, render_frame_with};
use isin_tracer::{AssetSource, RenderSettings, load_scene};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Large blocks (the BVH, the triangle blocks) in huge pages, as Embree's own allocator does.
#[global_allocator]
static ALLOC: isin_tracer::memory::HugePages = isin_tracer::memory::HugePages::SYSTEM;

struct Dir(PathBuf);

impl AssetSource for Dir {
    fn read(&mut self, path: &str) -> Result<Vec<u8>, String> {
        std::fs::read(self.0.join(path)).map_err(|e| format!("{path}: {e}"))
    }
}

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage =
        "usage: frames SCENE WIDTH HEIGHT FRAMES [--no-shadow-cells] [--fill-cells] [--threads N] [--moving]";
    let [scene_path, width, height, frames] = args.get(..4).ok_or(usage)? else { return Err(usage.into()) };
    let number = |s: &String| s.parse::<u32>().map_err(|e| format!("{s}: {e}"));
    let (width, height, frames) = (number(width)?, number(height)?, number(frames)?);
    let options =
        TraceOptions { shadow_cells: !args.iter().any(|a| a == "--no-shadow-cells"), ..Default::default() };
    let path = Path::new(scene_path);
    let text = std::fs::read_to_string(path).map_err(|e| format!("{scene_path}: {e}"))?;
    let base = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let scene = load_scene(scene_path, &text, &mut Dir(base)).map_err(|e| e.to_string())?;
    let mut settings = RenderSettings { width, height, ..scene.settings };
    if args.iter().any(|a| a == "--moving") {
        settings.spp = 1;
        settings.light_samples = 1;
    }
    let threads = match args.iter().position(|a| a == "--threads") {
        Some(i) => number(args.get(i + 1).ok_or(usage)?)? as usize,
        None => 1,
    };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().map_err(|e| e.to_string())?;
    pool.install(|| {
        if args.iter().any(|a| a == "--fill-cells") {
            let t = Instant::now();
            scene.fill_shadow_cells();
            println!(
                "filled {} shadow cells in {:.1} ms",
                scene.shadow_cells_filled(),
                t.elapsed().as_secs_f64() * 1e3
            );
        }
        for i in 0..frames {
            let t = Instant::now();
            let (_, counts) = render_frame_with(&scene, &scene.camera, &settings, 32, &options, &|_| {});
            println!(
                "frame {i}: {:.1} ms, {} primary, {} secondary, {} shadow rays traced, {} shadow cells filled",
                t.elapsed().as_secs_f64() * 1e3,
                counts.primary,
                counts.secondary,
                counts.shadow,
                scene.shadow_cells_filled()
            );
        }
    });
    Ok(())
}

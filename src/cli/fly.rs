//! `isin fly`: replays a camera path headless, one PNG per camera, and prints
//! per-frame render times (for benchmarks and tests).

use crate::assets::load_scene_file;
use anyhow::Context;
use clap::Args;
use isin_viewer::CameraPath;
use isin_viewer::stats::Summary;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Arguments of `isin fly`.
#[derive(Args, Debug)]
pub struct FlyArgs {
    /// Scene file (TOML), or a mesh file (.gltf, .glb, .obj) to make a scene around.
    pub scene: PathBuf,
    /// Camera path file (TOML, as written by `isin view --record`).
    #[arg(long)]
    pub path: PathBuf,
    /// Directory for `frame_NNNN.png` (created if missing); without it frames
    /// are rendered and timed but not written.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Image width (default: the path's recorded width, else the scene's).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height (default: the path's recorded height, else the scene's).
    #[arg(long)]
    pub height: Option<u32>,
    /// Samples per pixel (default: the scene's).
    #[arg(long)]
    pub spp: Option<u32>,
    /// Render as the viewer does while moving: 1 sample, 1 shadow ray.
    #[arg(long)]
    pub fast: bool,
    /// Render threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Tile edge in pixels.
    #[arg(long, default_value_t = 32)]
    pub tile: u32,
}

/// Runs `isin fly`.
pub fn run(args: FlyArgs) -> anyhow::Result<()> {
    let path = CameraPath::load(&args.path)?;
    anyhow::ensure!(!path.frames.is_empty(), "{} holds no frames", args.path.display());
    let (scene, _bundle) = load_scene_file(&args.scene)?;
    let mut settings = scene.settings.resized(args.width.or(path.width), args.height.or(path.height));
    if let Some(spp) = args.spp {
        settings.spp = spp;
    }
    if args.fast {
        settings.spp = 1;
        settings.light_samples = 1;
    }
    anyhow::ensure!(settings.width > 0 && settings.height > 0, "image size must be positive");
    anyhow::ensure!(settings.spp > 0, "--spp must be at least 1");
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.threads.unwrap_or(0))
        .build()
        .context("cannot start render threads")?;
    println!(
        "flying {} frames of {} through {} at {}x{}, {} spp, {} threads",
        path.frames.len(),
        args.path.display(),
        args.scene.display(),
        settings.width,
        settings.height,
        settings.spp,
        pool.current_num_threads()
    );
    let mut times = Vec::with_capacity(path.frames.len());
    let total = Instant::now();
    for (i, f) in path.frames.iter().enumerate() {
        let camera = f.camera().fit_aspect(settings.width as f32 / settings.height as f32);
        let t0 = Instant::now();
        let frame =
            pool.install(|| isin_tracer::render_frame(&scene, &camera, &settings, args.tile, &|_| {}));
        let dt = t0.elapsed();
        times.push(dt);
        if let Some(dir) = &args.out {
            let file = dir.join(format!("frame_{i:04}.png"));
            image::save_buffer(&file, &frame.rgb, frame.width, frame.height, image::ColorType::Rgb8)
                .with_context(|| format!("cannot write {}", file.display()))?;
        }
        println!("frame {i:04}  {:8.2} ms", ms(dt));
    }
    let wall = total.elapsed();
    let summary = Summary::of(&times);
    println!(
        "frames {}  median {:.2} ms  p95 {:.2} ms  max {:.2} ms  mean {:.1} fps  wall {:.2} s",
        times.len(),
        ms(summary.median),
        ms(summary.p95),
        ms(summary.max),
        summary.rate(),
        wall.as_secs_f64()
    );
    if let Some(dir) = &args.out {
        println!("wrote {}/frame_0000.png ..", dir.display());
    }
    Ok(())
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

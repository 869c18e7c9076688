//! `isin render`: one frame of a scene to a PNG file.

use crate::assets::load_scene_file;
use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `isin render`.
#[derive(Args, Debug)]
pub struct RenderArgs {
    /// Scene file (TOML).
    pub scene: PathBuf,
    /// Output PNG file.
    #[arg(short, long, default_value = "out.png")]
    pub output: PathBuf,
    /// Image width in pixels (default: the scene's).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height in pixels (default: the scene's).
    #[arg(long)]
    pub height: Option<u32>,
    /// Samples per pixel (default: the scene's).
    #[arg(long)]
    pub spp: Option<u32>,
    /// Render threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Tile edge in pixels.
    #[arg(long, default_value_t = 32)]
    pub tile: u32,
    /// Do not draw a progress bar.
    #[arg(long)]
    pub quiet: bool,
}

/// The default job with no arguments: render the shipped paper scene.
pub fn run_default() -> anyhow::Result<()> {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/paper.toml");
    run(RenderArgs {
        scene,
        output: "paper.png".into(),
        width: None,
        height: None,
        spp: None,
        threads: None,
        tile: 32,
        quiet: false,
    })
}

/// Runs `isin render`.
pub fn run(args: RenderArgs) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let (scene, _bundle) = load_scene_file(&args.scene)?;
    let load_time = t0.elapsed();

    let mut settings = scene.settings;
    if let Some(w) = args.width {
        settings.width = w;
    }
    if let Some(h) = args.height {
        settings.height = h;
    }
    if let Some(spp) = args.spp {
        settings.spp = spp;
    }
    anyhow::ensure!(settings.width > 0 && settings.height > 0, "image size must be positive");
    anyhow::ensure!(settings.spp > 0, "--spp must be at least 1");

    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.threads.unwrap_or(0))
        .build()
        .context("cannot start render threads")?;
    let pixels = settings.width as u64 * settings.height as u64;
    let bar = if args.quiet { ProgressBar::hidden() } else { ProgressBar::new(pixels) };
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {wide_bar} {percent}% ({eta})")
            .expect("static template"),
    );
    let t1 = Instant::now();
    let (frame, rays) = pool.install(|| {
        isin_tracer::render::render_frame_stats(&scene, &scene.camera, &settings, args.tile, &|n| bar.inc(n))
    });
    let render_time = t1.elapsed();
    bar.finish_and_clear();

    image::save_buffer(&args.output, &frame.rgb, frame.width, frame.height, image::ColorType::Rgb8)
        .with_context(|| format!("cannot write {}", args.output.display()))?;

    let secs = render_time.as_secs_f64();
    println!("scene      {}", args.scene.display());
    println!(
        "resolution {}x{}, {} spp, {} threads",
        settings.width,
        settings.height,
        settings.spp,
        pool.current_num_threads()
    );
    println!("triangles  {}", scene.triangle_count());
    println!("load+BVH   {:.1} ms", load_time.as_secs_f64() * 1e3);
    println!("render     {:.1} ms", render_time.as_secs_f64() * 1e3);
    println!(
        "rays       {:.2} M ({:.2} M primary, {:.2} M secondary, {:.2} M shadow): {:.2} Mrays/s",
        rays.total() as f64 / 1e6,
        rays.primary as f64 / 1e6,
        rays.secondary as f64 / 1e6,
        rays.shadow as f64 / 1e6,
        rays.total() as f64 / secs / 1e6
    );
    println!("wrote      {}", args.output.display());
    Ok(())
}

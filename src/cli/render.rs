//! `isin render`: one frame of a scene to a PNG file.

use crate::assets::load_scene_file_timed;
use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `isin render`.
#[derive(Args, Debug)]
pub struct RenderArgs {
    /// Scene file (TOML), or a mesh file (.gltf, .glb, .obj) to make a scene around.
    pub scene: PathBuf,
    /// Output PNG file.
    #[arg(short, long, default_value = "out.png")]
    pub output: PathBuf,
    /// Image width in pixels (default: the scene's; alone, the height follows
    /// at the scene's aspect ratio). An image of another shape than the
    /// scene's widens the view (or heightens it) about the centre: never stretched.
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height in pixels (default: the scene's; alone, the width follows).
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
    /// Render through the cluster of this join ticket (`isin://TOKEN@HOST:PORT?fp=…`)
    /// instead of locally; the master's scene, camera and settings are used.
    #[arg(long)]
    pub cluster: Option<String>,
}

/// Runs `isin render`.
pub fn run(args: RenderArgs) -> anyhow::Result<()> {
    if let Some(ticket) = &args.cluster {
        return run_cluster(&args, ticket);
    }
    let (scene, _bundle, load) = load_scene_file_timed(&args.scene)?;

    let mut settings = scene.settings.resized(args.width, args.height);
    if let Some(spp) = args.spp {
        settings.spp = spp;
    }
    anyhow::ensure!(settings.width > 0 && settings.height > 0, "image size must be positive");
    anyhow::ensure!(settings.spp > 0, "--spp must be at least 1");
    let camera = scene.camera.fit_aspect(settings.width as f32 / settings.height as f32);

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
        isin_tracer::render::render_frame_stats(&scene, &camera, &settings, args.tile, &|n| bar.inc(n))
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
    println!("load       {:.1} ms", load.parse.as_secs_f64() * 1e3);
    println!("BVH build  {:.1} ms", load.bvh.as_secs_f64() * 1e3);
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

/// `isin render --cluster TICKET`: one frame through a running cluster.
fn run_cluster(args: &RenderArgs, ticket: &str) -> anyhow::Result<()> {
    let ticket = super::cluster::ticket(ticket, None, isin_transport::TransportKind::Tcp)?;
    let t0 = Instant::now();
    let (frame, stats, scene, wire) =
        super::cluster::render_frame(&ticket, &args.scene, args.width, args.height, args.spp)?;
    let elapsed = t0.elapsed();
    image::save_buffer(&args.output, &frame.rgb, frame.width, frame.height, image::ColorType::Rgb8)
        .with_context(|| format!("cannot write {}", args.output.display()))?;
    println!("scene      {scene} (via cluster {})", ticket.addr);
    println!("resolution {}x{}", frame.width, frame.height);
    let per: Vec<String> = stats.per_slave.iter().map(|(k, n)| format!("{k}: {n}")).collect();
    println!(
        "tiles      {} ({}), {} moved, {} duplicated, {} requeued",
        stats.tiles,
        per.join(", "),
        stats.moved,
        stats.duplicated,
        stats.requeued
    );
    println!(
        "render     {:.1} ms (master: {:.1} ms)",
        elapsed.as_secs_f64() * 1e3,
        stats.micros as f64 / 1e3
    );
    println!("wire       {:.2} MB received", wire as f64 / 1e6);
    println!("wrote      {}", args.output.display());
    Ok(())
}

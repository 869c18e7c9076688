//! `isin render`: one frame of a scene to a PNG file.

use crate::assets::load_scene_file_timed;
use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Arguments of `isin render`.
#[derive(Args, Debug)]
pub struct RenderArgs {
    /// Scene file (TOML), or a mesh file (.gltf, .glb, .obj) to make a scene around.
    pub scene: PathBuf,
    /// Output image file (PNG, or JPEG named .jpg / .jpeg).
    #[arg(short, long, value_name = "FILE", default_value = "out.png")]
    pub output: PathBuf,
    /// Image width in pixels (default: the scene's; alone, the height follows
    /// at the scene's aspect ratio). An image of another shape than the
    /// scene's widens the view (or heightens it) about the centre: never stretched.
    #[arg(long, value_parser = super::bounded::side)]
    pub width: Option<u32>,
    /// Image height in pixels (default: the scene's; alone, the width follows).
    #[arg(long, value_parser = super::bounded::side)]
    pub height: Option<u32>,
    /// Samples per pixel (default: the scene's).
    #[arg(long, value_parser = super::bounded::spp)]
    pub spp: Option<u32>,
    /// Render threads (default, or 0: one per core).
    #[arg(long, value_parser = super::bounded::threads)]
    pub threads: Option<usize>,
    /// Tile edge in pixels.
    #[arg(long, default_value_t = 32, value_parser = super::bounded::tile)]
    pub tile: u32,
    /// Do not draw a progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// Render through the cluster of a join ticket instead of locally: SCENE
    /// goes to the master (unless it holds it already) and the frame is batch
    /// work, after people flying. If the master restarts, the render
    /// reconnects and goes on.
    #[command(flatten)]
    pub cluster: super::ticket::TicketArgs,
    /// With a ticket: give up after this many seconds (waiting for slaves, or
    /// for a master that is down, included).
    #[arg(long, value_name = "SECONDS", value_parser = super::bounded::timeout)]
    pub timeout: Option<u64>,
}

/// An output image being written: the format checked and the file created
/// (as `NAME.part` beside it) before any rendering, renamed into place once
/// the image is whole, removed if it never is — a failed render leaves
/// nothing behind.
struct Output {
    path: PathBuf,
    part: PathBuf,
    format: image::ImageFormat,
}

impl Output {
    fn create(path: &std::path::Path) -> anyhow::Result<Self> {
        let format = match image::ImageFormat::from_path(path) {
            Ok(f @ (image::ImageFormat::Png | image::ImageFormat::Jpeg)) => f,
            _ => anyhow::bail!(
                "cannot write {}: isin writes PNG or JPEG images (name the file .png, .jpg or .jpeg)",
                path.display()
            ),
        };
        let mut name = path.file_name().map(|n| n.to_os_string()).unwrap_or_default();
        name.push(".part");
        let part = path.with_file_name(name);
        std::fs::File::create(&part).with_context(|| format!("cannot write {}", path.display()))?;
        Ok(Self { path: path.to_owned(), part, format })
    }

    fn write(self, frame: &isin_tracer::Frame) -> anyhow::Result<()> {
        let file = std::fs::File::create(&self.part)
            .with_context(|| format!("cannot write {}", self.path.display()))?;
        let mut w = std::io::BufWriter::new(file);
        image::write_buffer_with_format(
            &mut w,
            &frame.rgb,
            frame.width,
            frame.height,
            image::ColorType::Rgb8,
            self.format,
        )
        .with_context(|| format!("cannot write {}", self.path.display()))?;
        std::io::Write::flush(&mut w).with_context(|| format!("cannot write {}", self.path.display()))?;
        drop(w);
        std::fs::rename(&self.part, &self.path)
            .with_context(|| format!("cannot write {}", self.path.display()))
    }
}

impl Drop for Output {
    fn drop(&mut self) {
        // Renamed away when written; otherwise a leftover.
        let _ = std::fs::remove_file(&self.part);
    }
}

/// Runs `isin render`.
pub fn run(args: RenderArgs) -> anyhow::Result<()> {
    let output = Output::create(&args.output)?;
    if let Some(ticket) = args.cluster.ticket()? {
        return run_cluster(&args, ticket, output);
    }
    let (scene, _bundle, load) = load_scene_file_timed(&args.scene)?;

    let mut settings = scene.settings.resized(args.width, args.height);
    if let Some(spp) = args.spp {
        settings.spp = spp;
    }
    // The size derived from one side at the scene's aspect is bounded too.
    isin_tracer::limits::check_settings(&settings)?;
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

    output.write(&frame)?;

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

/// `isin render --connect TICKET`: one frame through a running cluster.
fn run_cluster(args: &RenderArgs, ticket: isin_transport::Ticket, output: Output) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let (frame, stats, scene, wire) = super::cluster::render_frame(
        &ticket,
        &args.scene,
        args.width,
        args.height,
        args.spp,
        args.timeout.map(Duration::from_secs),
    )?;
    let elapsed = t0.elapsed();
    output.write(&frame)?;
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

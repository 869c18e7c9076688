//! `isin render`: one frame of a scene to an image file (see
//! [`crate::outputs`]), or to standard output; optionally streamed to tev.

use crate::assets::load_scene_file_timed;
use crate::outputs::{self, Format, Output, Pass, Spec};
use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Arguments of `isin render`.
#[derive(Args, Debug)]
pub struct RenderArgs {
    /// Scene file (TOML), or a mesh file (.gltf, .glb, .obj) to make a scene around.
    pub scene: PathBuf,
    /// Output image: .png (sRGB), .jpg / .jpeg, .exr (linear float) or .pfm
    /// (linear float); `-` writes to standard output (PNG unless --format
    /// says otherwise; the report then goes to standard error).
    #[arg(short, long, value_name = "FILE", default_value = "out.png")]
    pub output: PathBuf,
    /// Image format, whatever the file is named (default: by the file's
    /// extension; PNG for `-o -`).
    #[arg(long, value_enum)]
    pub format: Option<Format>,
    /// Bits per channel: PNG 8 (default) or 16; EXR 32 (float, default) or
    /// 16 (half); JPEG 8; PFM 32.
    #[arg(long, value_name = "BITS")]
    pub bit_depth: Option<u32>,
    /// First-hit passes to write beside the beauty, comma-separated: EXR
    /// layers in the same file (albedo.R…, normal.X…, depth.Z), or for PFM
    /// files beside it (NAME.albedo.pfm …). Local renders only.
    #[arg(long, value_enum, value_delimiter = ',', value_name = "PASSES")]
    pub passes: Vec<Pass>,
    /// Stream tiles, as they finish, into a running tev image viewer
    /// listening at HOST:PORT (tev's default: 127.0.0.1:14158); the passes
    /// go along as layers. Local renders only.
    #[arg(long, value_name = "HOST:PORT")]
    pub tev: Option<String>,
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
    /// With --connect: where slaves may deliver the tiles straight.
    #[command(flatten)]
    pub direct: super::ticket::DirectArgs,
    /// With a ticket: give up after this many seconds (waiting for slaves, or
    /// for a master that is down, included).
    #[arg(long, value_name = "SECONDS", value_parser = super::bounded::timeout)]
    pub timeout: Option<u64>,
}

/// Runs `isin render`.
pub fn run(args: RenderArgs) -> anyhow::Result<()> {
    let spec = Spec::new(&args.output, args.format, args.bit_depth, &args.passes)?;
    let output = Output::create(&args.output, spec)?;
    if let Some(ticket) = args.cluster.ticket()? {
        if output.spec().needs_linear() {
            anyhow::bail!(
                "a cluster render (--connect) carries RGB8 tiles only: EXR, PFM, 16-bit PNG and \
                 --passes need a local render (leave out --connect)"
            );
        }
        if args.tev.is_some() {
            anyhow::bail!("--tev streams local renders only: leave out --connect or --tev");
        }
        return run_cluster(&args, ticket, output);
    }
    let tev = args.tev.as_deref().map(crate::tev::TevStream::connect).transpose()?;
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
    let passes = output.spec().passes.clone();
    let tev_name = tev_image_name(&args);
    let tev = match tev {
        Some(t) => Some(t.create_image(&tev_name, settings.width, settings.height, &passes)?),
        None => None,
    };
    let on_tile = |tile: isin_tracer::Tile, buffers: &isin_tracer::FrameBuffers| {
        bar.inc(tile.pixel_count() as u64);
        if let Some(t) = &tev {
            t.send_tile(tile, buffers);
        }
    };
    let t1 = Instant::now();
    let (buffers, rays) = pool.install(|| {
        isin_tracer::render::render_frame_hdr(
            &scene,
            &camera,
            &settings,
            args.tile,
            !passes.is_empty(),
            &on_tile,
        )
    });
    let render_time = t1.elapsed();
    bar.finish_and_clear();
    if let Some(t) = tev {
        t.close();
    }

    let wrote = output.display();
    output.write(&buffers)?;

    let secs = render_time.as_secs_f64();
    let mut r = String::new();
    writeln!(r, "scene      {}", args.scene.display())?;
    writeln!(
        r,
        "resolution {}x{}, {} spp, {} threads",
        settings.width,
        settings.height,
        settings.spp,
        pool.current_num_threads()
    )?;
    writeln!(r, "triangles  {}", scene.triangle_count())?;
    writeln!(r, "load       {:.1} ms", load.parse.as_secs_f64() * 1e3)?;
    writeln!(r, "BVH build  {:.1} ms", load.bvh.as_secs_f64() * 1e3)?;
    writeln!(r, "render     {:.1} ms", render_time.as_secs_f64() * 1e3)?;
    writeln!(
        r,
        "rays       {:.2} M ({:.2} M primary, {:.2} M secondary, {:.2} M shadow): {:.2} Mrays/s",
        rays.total() as f64 / 1e6,
        rays.primary as f64 / 1e6,
        rays.secondary as f64 / 1e6,
        rays.shadow as f64 / 1e6,
        rays.total() as f64 / secs / 1e6
    )?;
    if let Some(addr) = &args.tev {
        writeln!(r, "tev        {addr} (image {tev_name})")?;
    }
    writeln!(r, "wrote      {wrote}")?;
    report(&args, &r);
    Ok(())
}

/// The name of the image in tev: the output file's name, or the scene's for `-o -`.
fn tev_image_name(args: &RenderArgs) -> String {
    let path = if outputs::is_stdout(&args.output) { &args.scene } else { &args.output };
    path.file_name().map_or_else(|| "isin".into(), |n| n.to_string_lossy().into_owned())
}

/// Prints the render's report: to standard output, unless the image goes there.
fn report(args: &RenderArgs, text: &str) {
    if outputs::is_stdout(&args.output) { eprint!("{text}") } else { print!("{text}") }
}

/// `isin render --connect TICKET`: one frame through a running cluster.
fn run_cluster(args: &RenderArgs, ticket: isin_transport::Ticket, output: Output) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let (frame, stats, scene, wire) = super::cluster::render_frame(
        &ticket,
        args.direct.direct.as_deref(),
        &args.scene,
        args.width,
        args.height,
        args.spp,
        args.timeout.map(Duration::from_secs),
    )?;
    let elapsed = t0.elapsed();
    let wrote = output.display();
    output.write_frame(&frame)?;
    let mut r = String::new();
    writeln!(r, "scene      {scene} (via cluster {})", ticket.addr)?;
    writeln!(r, "resolution {}x{}", frame.width, frame.height)?;
    let per: Vec<String> = stats.per_slave.iter().map(|(k, n)| format!("{k}: {n}")).collect();
    writeln!(
        r,
        "tiles      {} ({}), {} moved, {} duplicated, {} requeued",
        stats.tiles,
        per.join(", "),
        stats.moved,
        stats.duplicated,
        stats.requeued
    )?;
    if args.direct.direct.is_some() {
        writeln!(r, "direct     {} of {} tiles straight from the slaves", stats.direct, stats.tiles)?;
    }
    writeln!(
        r,
        "render     {:.1} ms (master: {:.1} ms)",
        elapsed.as_secs_f64() * 1e3,
        stats.micros as f64 / 1e3
    )?;
    writeln!(r, "wire       {:.2} MB received", wire as f64 / 1e6)?;
    writeln!(r, "wrote      {wrote}")?;
    report(args, &r);
    Ok(())
}

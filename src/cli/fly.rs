//! `isin fly`: replays a camera path headless, one PNG per camera, and prints
//! per-frame render times (for benchmarks and tests) — on this machine, or
//! with `--cluster` on a cluster, several frames queued at once.

use crate::assets::load_scene_file;
use anyhow::Context;
use clap::Args;
use isin_actors::viewer;
use isin_cluster::scheduler::Work;
use isin_tracer::RenderSettings;
use isin_viewer::CameraPath;
use isin_viewer::stats::Summary;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Arguments of `isin fly`.
#[derive(Args, Debug)]
pub struct FlyArgs {
    /// Scene file (TOML), or a mesh file (.gltf, .glb, .obj) to make a scene around.
    pub scene: PathBuf,
    /// Camera path file (TOML): cameras recorded by `isin view --record`, or
    /// keyframes sampled at the file's `fps` (README, "Camera paths").
    #[arg(long)]
    pub path: PathBuf,
    /// Directory for `frame_NNNN.png` (created if missing); without it frames
    /// are rendered and timed but not written.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Image width (default: the path's recorded width, else the scene's).
    #[arg(long, value_parser = super::bounded::side)]
    pub width: Option<u32>,
    /// Image height (default: the path's recorded height, else the scene's).
    #[arg(long, value_parser = super::bounded::side)]
    pub height: Option<u32>,
    /// Samples per pixel (default: the scene's).
    #[arg(long, value_parser = super::bounded::spp)]
    pub spp: Option<u32>,
    /// Render as the viewer does while moving: 1 sample, 1 shadow ray.
    #[arg(long)]
    pub fast: bool,
    /// Render threads (default, or 0: one per core).
    #[arg(long, value_parser = super::bounded::threads)]
    pub threads: Option<usize>,
    /// Tile edge in pixels.
    #[arg(long, default_value_t = 32, value_parser = super::bounded::tile)]
    pub tile: u32,
    /// Only these frames of the path: `A..B` (B not included), `A..=B`, `A..`
    /// or `..B`; files keep the frame's number in the path.
    #[arg(long, value_name = "A..B")]
    pub frames: Option<Frames>,
    /// Render on the cluster of this join ticket (`isin://TOKEN@HOST:PORT?fp=…`,
    /// as the master printed it) instead of on this machine. The master must
    /// serve SCENE; frames are batch work (people flying come first), several
    /// queued at once, each written as it completes.
    #[arg(long, value_name = "TICKET")]
    pub cluster: Option<String>,
}

/// A range of a camera path's frames, as `--frames` takes it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Frames {
    start: usize,
    /// One past the last; `None`: to the end.
    end: Option<usize>,
}

impl std::str::FromStr for Frames {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let bad = || format!("`{s}` is not a frame range: write A..B, A..=B, A.. or ..B");
        let (a, b, inclusive) = match s.split_once("..=") {
            Some((a, b)) => (a, b, true),
            None => s.split_once("..").map(|(a, b)| (a, b, false)).ok_or_else(bad)?,
        };
        let num = |t: &str| t.trim().parse::<usize>().map_err(|_| bad());
        let start = if a.trim().is_empty() { 0 } else { num(a)? };
        let end = match (b.trim().is_empty(), inclusive) {
            (true, false) => None,
            (true, true) => return Err(bad()),
            (false, false) => Some(num(b)?),
            (false, true) => Some(num(b)?.checked_add(1).ok_or_else(bad)?),
        };
        Ok(Frames { start, end })
    }
}

impl Frames {
    /// The indices of a path of `n` frames this range names; an error when
    /// it names none.
    fn of(self, n: usize) -> anyhow::Result<std::ops::Range<usize>> {
        let end = self.end.unwrap_or(n);
        anyhow::ensure!(
            self.start < end && end <= n,
            "--frames {}..{end} is not within the path's {n} frames",
            self.start
        );
        Ok(self.start..end)
    }
}

/// The settings a flight renders with: `base` (the scene's) at the size
/// asked for, or recorded in the path, and the samples asked for.
fn flight_settings(
    args: &FlyArgs,
    path: &CameraPath,
    base: RenderSettings,
) -> anyhow::Result<RenderSettings> {
    let mut settings = base.resized(args.width.or(path.width), args.height.or(path.height));
    if let Some(spp) = args.spp {
        settings.spp = spp;
    }
    if args.fast {
        settings.spp = 1;
        settings.light_samples = 1;
    }
    // The size derived from one side at the scene's aspect is bounded too.
    isin_tracer::limits::check_settings(&settings)?;
    Ok(settings)
}

/// Writes frame `i` into `dir`, if frames are written.
fn write_frame(dir: Option<&PathBuf>, i: usize, frame: &isin_tracer::Frame) -> anyhow::Result<()> {
    let Some(dir) = dir else { return Ok(()) };
    let file = dir.join(format!("frame_{i:04}.png"));
    image::save_buffer(&file, &frame.rgb, frame.width, frame.height, image::ColorType::Rgb8)
        .with_context(|| format!("cannot write {}", file.display()))
}

/// Runs `isin fly`.
pub fn run(args: FlyArgs) -> anyhow::Result<()> {
    let path = CameraPath::load(&args.path)?;
    anyhow::ensure!(!path.frames.is_empty(), "{} holds no frames", args.path.display());
    let range = args.frames.unwrap_or(Frames { start: 0, end: None }).of(path.frames.len())?;
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    if let Some(ticket) = &args.cluster {
        return run_cluster(&args, &path, range, ticket);
    }
    let (scene, _bundle) = load_scene_file(&args.scene)?;
    let settings = flight_settings(&args, &path, scene.settings)?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.threads.unwrap_or(0))
        .build()
        .context("cannot start render threads")?;
    println!(
        "flying {} frames of {} through {} at {}x{}, {} spp, {} threads",
        range.len(),
        args.path.display(),
        args.scene.display(),
        settings.width,
        settings.height,
        settings.spp,
        pool.current_num_threads()
    );
    let mut times = Vec::with_capacity(range.len());
    let total = Instant::now();
    for i in range {
        let camera = path.frames[i].camera().fit_aspect(settings.width as f32 / settings.height as f32);
        let t0 = Instant::now();
        let frame =
            pool.install(|| isin_tracer::render_frame(&scene, &camera, &settings, args.tile, &|_| {}));
        let dt = t0.elapsed();
        times.push(dt);
        write_frame(args.out.as_ref(), i, &frame)?;
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
        println!("wrote {}/frame_NNNN.png", dir.display());
    }
    Ok(())
}

/// Frames a cluster flight keeps queued at the master (it takes up to four
/// a client).
const QUEUED: usize = 3;

/// `isin fly --cluster`: the path's frames through a cluster, pipelined.
fn run_cluster(
    args: &FlyArgs,
    path: &CameraPath,
    range: std::ops::Range<usize>,
    ticket: &str,
) -> anyhow::Result<()> {
    let ticket = super::cluster::ticket(ticket, None, isin_transport::TransportKind::Tcp)?;
    let transport = super::cluster::client_transport(&ticket)?;
    actix::System::new().block_on(async move {
        let (v, scene, mut events) =
            viewer::connect_as(transport.as_ref(), &ticket, "fly", Work::Batch).await?;
        super::cluster::check_scene(&scene, &args.scene)?;
        let settings = flight_settings(args, path, scene.settings)?;
        let aspect = settings.width as f32 / settings.height as f32;
        let cameras: Vec<_> =
            path.frames[range.clone()].iter().map(|f| f.camera().fit_aspect(aspect)).collect();
        println!(
            "flying {} frames of {} through {} at {}x{}, {} spp, on the cluster at {}",
            cameras.len(),
            args.path.display(),
            args.scene.display(),
            settings.width,
            settings.height,
            settings.spp,
            ticket.addr
        );
        let total = Instant::now();
        let mut last = Duration::ZERO;
        let mut intervals = Vec::with_capacity(cameras.len());
        viewer::collect_frames(&v, &mut events, &cameras, settings, QUEUED, |k, frame, stats| {
            let i = range.start + k;
            write_frame(args.out.as_ref(), i, &frame)?;
            let at = total.elapsed();
            intervals.push(at - last);
            last = at;
            println!("frame {i:04}  done at {:8.2} s  {:4} tiles", at.as_secs_f64(), stats.tiles);
            anyhow::Ok(())
        })
        .await?;
        let summary = Summary::of(&intervals);
        println!(
            "frames {}  median {:.2} ms between frames  mean {:.1} fps  wall {:.2} s",
            intervals.len(),
            ms(summary.median),
            summary.rate(),
            total.elapsed().as_secs_f64()
        );
        if let Some(dir) = &args.out {
            println!("wrote {}/frame_NNNN.png", dir.display());
        }
        anyhow::Ok(())
    })
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_ranges_parse_as_rust_writes_them_and_are_checked_against_the_path() {
        let r = |s: &str| s.parse::<Frames>().and_then(|f| f.of(10).map_err(|e| e.to_string()));
        assert_eq!(r("2..5"), Ok(2..5));
        assert_eq!(r("2..=5"), Ok(2..6));
        assert_eq!(r("7.."), Ok(7..10));
        assert_eq!(r("..3"), Ok(0..3));
        for bad in ["5", "a..b", "3..=", "5..2", "0..11", "10.."] {
            assert!(r(bad).is_err(), "{bad}");
        }
    }
}

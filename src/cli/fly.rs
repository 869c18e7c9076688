//! `isin fly`: replays a camera path headless, one PNG per camera, and prints
//! per-frame render times (for benchmarks and tests) — on this machine, or
//! with `--connect` on a cluster, several frames queued at once.

use crate::assets::load_scene_file;
use anyhow::Context;
use clap::Args;
use isin_actors::viewer;
use isin_cluster::protocol::{self, JobSpec, SceneHash};
use isin_cluster::scheduler::Work;
use isin_tracer::{Camera, RenderSettings};
use isin_viewer::CameraPath;
use isin_viewer::stats::Summary;
use sha2::{Digest, Sha256};
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
    #[arg(long = "out-dir", alias = "out", value_name = "DIR")]
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
    /// Render on the cluster of a join ticket instead of on this machine:
    /// SCENE goes to the master (unless it holds it); frames are one batch
    /// job (people flying come first), several queued at once, each written
    /// as it completes. If the master restarts, the flight reconnects and
    /// resumes from the first frame not written.
    #[command(flatten)]
    pub cluster: super::ticket::TicketArgs,
    /// With --connect: where slaves may deliver the frames' tiles straight.
    #[command(flatten)]
    pub direct: super::ticket::DirectArgs,
    /// With a ticket: give up after this many seconds.
    #[arg(long, value_name = "SECONDS", value_parser = super::bounded::timeout)]
    pub timeout: Option<u64>,
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

/// The file of frame `i` in `dir`.
fn frame_file(dir: &std::path::Path, i: usize) -> PathBuf {
    dir.join(format!("frame_{i:04}.png"))
}

/// Writes frame `i` into `dir`, if frames are written: whole or not at all
/// (to a temporary name, then renamed), so a file there is a finished frame.
fn write_frame(dir: Option<&PathBuf>, i: usize, frame: &isin_tracer::Frame) -> anyhow::Result<()> {
    let Some(dir) = dir else { return Ok(()) };
    let file = frame_file(dir, i);
    let part = file.with_extension("png.part");
    image::save_buffer_with_format(
        &part,
        &frame.rgb,
        frame.width,
        frame.height,
        image::ColorType::Rgb8,
        image::ImageFormat::Png,
    )
    .and_then(|()| std::fs::rename(&part, &file).map_err(image::ImageError::IoError))
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
    if let Some(ticket) = args.cluster.ticket()? {
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

/// The key of a flight as a batch job: everything that decides its frames
/// (scene, cameras, settings, first frame), so rerunning the same command
/// resumes it and any change makes another job.
fn job_key(scene: &SceneHash, cameras: &[Camera], settings: &RenderSettings, first: usize) -> SceneHash {
    let mut h = Sha256::new();
    h.update(scene);
    h.update((first as u64).to_le_bytes());
    // MessagePack of plain numbers: the same bytes on every machine.
    h.update(rmp_serde::to_vec(&(cameras, settings)).unwrap_or_default());
    h.finalize().into()
}

/// `isin fly --connect`: the path's frames through a cluster, pipelined, as
/// one batch job. SCENE goes to the master unless it holds it. When the
/// master is lost (a restart), the flight reconnects and goes on from the
/// frames not yet written; a frame the master recorded done whose file is
/// there is not rendered again.
fn run_cluster(
    args: &FlyArgs,
    path: &CameraPath,
    range: std::ops::Range<usize>,
    ticket: isin_transport::Ticket,
) -> anyhow::Result<()> {
    let transport = super::cluster::client_transport(&ticket)?;
    let (_, scene_settings, bundle) = crate::assets::load_view(&args.scene)?;
    let settings = flight_settings(args, path, scene_settings)?;
    let aspect = settings.width as f32 / settings.height as f32;
    let cameras: Vec<Camera> =
        path.frames[range.clone()].iter().map(|f| f.camera().fit_aspect(aspect)).collect();
    let scene_hash = protocol::served_scene_hash(&bundle);
    let name = match &args.out {
        Some(dir) => dir.display().to_string(),
        None => args.path.display().to_string(),
    };
    let name: String =
        name.chars().rev().take(protocol::MAX_SLAVE_TEXT / 4).collect::<Vec<_>>().into_iter().rev().collect();
    let spec = JobSpec {
        key: job_key(&scene_hash, &cameras, &settings, range.start),
        name,
        scene: scene_hash,
        frames: u32::try_from(cameras.len()).unwrap_or(u32::MAX),
        settings,
    };
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
    let timeout = args.timeout.map(Duration::from_secs);
    actix::System::new().block_on(super::cluster::within(timeout, async {
        let setup = viewer::Setup { name: "fly", work: Work::Batch, scene: Some(&bundle), job: Some(&spec) };
        let total = Instant::now();
        let mut last = Duration::ZERO;
        let mut intervals = Vec::with_capacity(cameras.len());
        // Frames (indices into `cameras`) written by this run.
        let mut written = std::collections::BTreeSet::new();
        loop {
            let direct = args.direct.direct.as_deref();
            let mut c = super::cluster::connect_client(transport.as_ref(), &ticket, setup, direct).await?;
            let done_before: std::collections::BTreeSet<u32> = c.done.iter().copied().collect();
            let todo: Vec<u32> = (0..spec.frames)
                .filter(|&k| !written.contains(&k))
                .filter(|&k| {
                    let file = args.out.as_ref().map(|d| frame_file(d, range.start + k as usize));
                    !(done_before.contains(&k) && file.is_some_and(|f| f.exists()))
                })
                .collect();
            if todo.len() < cameras.len() {
                println!(
                    "resuming: {} frames done before, {} to render",
                    cameras.len() - todo.len(),
                    todo.len()
                );
            }
            let todo_cameras: Vec<Camera> = todo.iter().map(|&k| cameras[k as usize]).collect();
            let result = viewer::collect_frames(
                &c.addr,
                &mut c.events,
                &todo_cameras,
                Some(&todo),
                settings,
                QUEUED,
                |j, frame, stats| {
                    let k = todo[j];
                    let i = range.start + k as usize;
                    write_frame(args.out.as_ref(), i, &frame)?;
                    written.insert(k);
                    let at = total.elapsed();
                    intervals.push(at - last);
                    last = at;
                    println!("frame {i:04}  done at {:8.2} s  {:4} tiles", at.as_secs_f64(), stats.tiles);
                    anyhow::Ok(())
                },
            )
            .await;
            match result {
                Ok(()) => break,
                Err(viewer::ViewerError::Lost(why)) => {
                    tracing::warn!("{why}; reconnecting to resume the flight");
                }
                Err(e) => return Err(anyhow::Error::new(e)),
            }
        }
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
    }))
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

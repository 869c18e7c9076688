//! Tracer benchmark: isin's BVH against the `bvh` crate (svenstaro) and `obvhs`,
//! on the same triangles and the same rays, mirroring the Embree reference ray
//! sets (`/work/shared/anchors/embree/README.md`):
//!
//! * build: BVH build time (best wall ms of 3, as Embree reports its own), 1 and 2 rayon threads;
//! * primary: 1024×768 pinhole, vertical FOV 45°, up +Y, eye = c + (0.2, 0.25, 0.75)·d
//!   looking at c (c = box centre, d = box diagonal), rays through pixel centres;
//! * incoherent: 1M rays, origins uniform on the sphere of radius d around c, aimed
//!   at uniform random points in the box;
//! * primary8: the primary rays as isin's 8-ray packets ([`Bvh::intersect8`]) over
//!   4×2 pixel tiles, as embree_bench's `rtcIntersect8` (isin only; compared with
//!   Embree's packet figure by `scripts/bench_vs_embree.py`);
//! * shadow: from every primary hit to a uniform random point on a square area light
//!   (side d/4, centre c + (0.3 d, ·, 0.3 d) at height max.y + d/2), any-hit, with
//!   t in (1e-4 d, 0.999 · distance).
//!
//! Meshes: the bunny, the 100k dragon, Sponza seen from inside (the README's
//! `-cam -14 3 0 10 5 0`) and the dragon with every triangle split 1 → 4 twice
//! (1.6M triangles, `embree_bench -s 2`), read with the same OBJ rules as
//! `embree_bench.c` (every `v`, fanned `f`) so both trace the same triangles;
//! the box `c`, `d` come from all vertices, as there.
//!
//! Each tracing case reports the MEDIAN Mrays/s over [`REPS`] runs, for 1 and 2
//! threads, and isin's best run (`isin_best` in the JSON: Embree prints its
//! best). Per mesh the JSON also has isin's BVH + triangle bytes per triangle,
//! and at the end the process's peak RSS (VmHWM). Run with
//! `cargo bench -p isin-tracer --bench tracer`; prints a Markdown table and
//! writes `target/bench/tracer.json` (`-- json=NAME` for another name; see
//! `main` for the mesh filter). `scripts/bench-vs-embree.sh` runs it next to
//! the Embree benchmark. Meshes that are absent are skipped with a message. Ratio columns are "how many times faster isin is"
//! (Mrays/s ratio for tracing, time ratio for builds).

use isin_tracer::Vec3;
use isin_tracer::bvh::Bvh;
use isin_tracer::geometry::{Aabb, Ray};
use isin_tracer::math;
use rayon::prelude::*;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Large blocks (the BVH, the triangle blocks) in huge pages, as Embree's own allocator does.
#[global_allocator]
static ALLOC: isin_tracer::memory::HugePages = isin_tracer::memory::HugePages::SYSTEM;

#[path = "common/embree_mesh.rs"]
mod embree_mesh;
use embree_mesh::{BenchMesh, load_mesh, subdivide};

/// Repetitions per tracing case (the median is reported).
const REPS: usize = 5;
/// Repetitions per build case.
const BUILD_REPS: usize = 3;
/// Rays per parallel work item.
const CHUNK: usize = 1024;
/// Target wall time of one repetition; slower libraries trace an evenly strided
/// subset of a ray set so the whole run stays within a few minutes.
const REP_BUDGET: Duration = Duration::from_millis(400);

// ---------------------------------------------------------------------------
// Report

/// What a row measures; decides how ratios are formed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Unit {
    /// Throughput, higher is better.
    MraysPerSec,
    /// Time, lower is better.
    Millis,
}

/// One table row: a case and each library's figure (None = not measured).
#[derive(Clone, Debug)]
pub struct Row {
    /// Case name, e.g. "bunny primary 2T".
    pub case: String,
    /// Unit of the figures.
    pub unit: Unit,
    /// isin's figure.
    pub isin: f64,
    /// The `bvh` crate's figure.
    pub bvh: Option<f64>,
    /// `obvhs`'s figure.
    pub obvhs: Option<f64>,
    /// isin's best repetition (tracing rows; the statistic the Embree benchmark prints).
    pub isin_best: Option<f64>,
    /// isin's rays per CPU-second of the process (tracing rows), in millions:
    /// robust to other load on the machine, like Embree's "per CPU-s" figure.
    pub isin_per_cpu: Option<f64>,
}

impl Row {
    /// How many times faster isin is than `other` (> 1: isin wins).
    pub fn speedup(&self, other: Option<f64>) -> Option<f64> {
        let o = other?;
        Some(match self.unit {
            Unit::MraysPerSec => self.isin / o,
            Unit::Millis => o / self.isin,
        })
    }
}

/// The collected results.
#[derive(Default, Debug)]
pub struct Report {
    /// Rows in measurement order.
    pub rows: Vec<Row>,
    /// Free-form notes printed under the table.
    pub notes: Vec<String>,
    /// Per mesh: (name, triangles, bytes per triangle of isin's BVH + triangle data).
    pub meshes: Vec<(String, usize, f64)>,
}

/// Adds a row to `report` (also the hook for later rows such as a scene's frame time).
pub fn report_row(
    report: &mut Report,
    case: &str,
    unit: Unit,
    isin: f64,
    bvh: Option<f64>,
    obvhs: Option<f64>,
) {
    eprintln!("  {case}: isin {isin:.3}, bvh {bvh:.3?}, obvhs {obvhs:.3?}");
    report.rows.push(Row {
        case: case.to_string(),
        unit,
        isin,
        bvh,
        obvhs,
        isin_best: None,
        isin_per_cpu: None,
    });
}

impl Report {
    /// The Markdown table.
    pub fn markdown(&self) -> String {
        let fmt = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{v:.2}"));
        let mut s = String::from(
            "| case | isin | bvh | obvhs | isin/bvh | isin/obvhs |\n|---|---|---|---|---|---|\n",
        );
        for r in &self.rows {
            let unit = match r.unit {
                Unit::MraysPerSec => "Mrays/s",
                Unit::Millis => "ms",
            };
            s += &format!(
                "| {} ({unit}) | {:.2} | {} | {} | {}× | {}× |\n",
                r.case,
                r.isin,
                fmt(r.bvh),
                fmt(r.obvhs),
                fmt(r.speedup(r.bvh)),
                fmt(r.speedup(r.obvhs))
            );
        }
        for n in &self.notes {
            s += &format!("\n{n}");
        }
        s
    }

    /// The results as JSON (written by hand: no serde_json dependency).
    pub fn json(&self, machine: &str) -> String {
        let num = |v: Option<f64>| v.map_or("null".to_string(), |v| format!("{v:.4}"));
        let rows: Vec<String> = self
            .rows
            .iter()
            .map(|r| {
                format!(
                    "    {{\"case\": {:?}, \"unit\": {:?}, \"isin\": {}, \"isin_best\": {}, \"isin_per_cpu\": {}, \
                     \"bvh\": {}, \"obvhs\": {}, \"isin_over_bvh\": {}, \"isin_over_obvhs\": {}}}",
                    r.case,
                    match r.unit {
                        Unit::MraysPerSec => "Mrays/s",
                        Unit::Millis => "ms",
                    },
                    num(Some(r.isin)),
                    num(r.isin_best),
                    num(r.isin_per_cpu),
                    num(r.bvh),
                    num(r.obvhs),
                    num(r.speedup(r.bvh)),
                    num(r.speedup(r.obvhs))
                )
            })
            .collect();
        let notes: Vec<String> = self.notes.iter().map(|n| format!("{n:?}")).collect();
        let meshes: Vec<String> = self
            .meshes
            .iter()
            .map(|(name, tris, bpt)| {
                format!("    {{\"mesh\": {name:?}, \"triangles\": {tris}, \"bytes_per_triangle\": {bpt:.2}}}")
            })
            .collect();
        let rss = num(peak_rss_mb());
        format!(
            "{{\n  \"machine\": {machine:?},\n  \"reps\": {REPS},\n  \"peak_rss_mb\": {rss},\n  \"meshes\": [\n{}\n  ],\n  \
             \"rows\": [\n{}\n  ],\n  \"notes\": [{}]\n}}\n",
            meshes.join(",\n"),
            rows.join(",\n"),
            notes.join(", ")
        )
    }
}

// ---------------------------------------------------------------------------
// Scenes and rays

/// A ray with its interval (open for isin, as the Embree sets use it).
#[derive(Clone, Copy, Debug)]
pub struct BenchRay {
    /// The ray.
    pub ray: Ray,
    /// Interval start.
    pub t_min: f32,
    /// Interval end.
    pub t_max: f32,
}

/// The Embree benchmark's xorshift64 generator (same constants and seeding).
struct EmbreeRng(u64);

impl EmbreeRng {
    fn frand(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 40) as f32 * (1.0 / 16_777_216.0)
    }
}

/// The camera of a ray set: Embree's default view of the box, or an explicit
/// eye and target (its `-cam`).
#[derive(Clone, Copy, Debug)]
pub enum View {
    /// `eye = c + (0.2, 0.25, 0.75)·d` looking at `c`.
    Default,
    /// Eye and target.
    At(Vec3, Vec3),
}

fn primary_rays(b: &Aabb, view: View, width: usize, height: usize) -> Vec<BenchRay> {
    let (c, d) = (b.center(), b.diagonal());
    let (eye, target) = match view {
        View::Default => (c + Vec3::new(0.2, 0.25, 0.75) * d, c),
        View::At(e, t) => (e, t),
    };
    let w = (target - eye).normalize();
    let u0 = w.cross(Vec3::Y).normalize();
    let v0 = u0.cross(w).normalize();
    let th = math::tan(45f32.to_radians() / 2.0);
    let (u, v) = (u0 * (th * width as f32 / height as f32), v0 * th);
    let mut rays = Vec::with_capacity(width * height);
    for py in 0..height {
        for px in 0..width {
            let x = (px as f32 + 0.5) / width as f32 * 2.0 - 1.0;
            let y = 1.0 - (py as f32 + 0.5) / height as f32 * 2.0;
            let dir = (w + u * x + v * y).normalize();
            rays.push(BenchRay { ray: Ray::new(eye, dir), t_min: 0.0, t_max: f32::INFINITY });
        }
    }
    rays
}

fn incoherent_rays(b: &Aabb, n: usize, rng: &mut EmbreeRng) -> Vec<BenchRay> {
    let (c, d, ext) = (b.center(), b.diagonal(), b.extent());
    (0..n)
        .map(|_| {
            let o = loop {
                let o = Vec3::new(rng.frand() * 2.0 - 1.0, rng.frand() * 2.0 - 1.0, rng.frand() * 2.0 - 1.0);
                let l = o.length_squared();
                if (1e-3..=1.0).contains(&l) {
                    break o.normalize();
                }
            };
            let o = c + o * d;
            let t = b.min + Vec3::new(rng.frand(), rng.frand(), rng.frand()) * ext;
            BenchRay { ray: Ray::new(o, (t - o).normalize()), t_min: 0.0, t_max: f32::INFINITY }
        })
        .collect()
}

fn shadow_rays(b: &Aabb, primary: &[BenchRay], bvh: &Bvh, rng: &mut EmbreeRng) -> Vec<BenchRay> {
    let (c, d) = (b.center(), b.diagonal());
    let light_c = Vec3::new(c.x + 0.3 * d, b.max.y + 0.5 * d, c.z + 0.3 * d);
    let side = 0.25 * d;
    let hits: Vec<Option<Vec3>> = primary
        .par_iter()
        .map(|r| bvh.intersect(&r.ray, r.t_min, r.t_max).map(|h| r.ray.origin + r.ray.dir * h.t))
        .collect();
    hits.into_iter()
        .flatten()
        .map(|p| {
            let lp = Vec3::new(
                light_c.x + (rng.frand() - 0.5) * side,
                light_c.y,
                light_c.z + (rng.frand() - 0.5) * side,
            );
            let to = lp - p;
            let len = to.length();
            BenchRay { ray: Ray::new(p, to / len), t_min: 1e-4 * d, t_max: len * 0.999 }
        })
        .collect()
}

// ---------------------------------------------------------------------------
// The three libraries behind one interface

/// A built acceleration structure that can answer the benchmark's queries.
trait Tracer: Sync {
    /// Nearest hit distance.
    fn nearest(&self, r: &BenchRay) -> Option<f32>;
    /// Any hit within the interval.
    fn occluded(&self, r: &BenchRay) -> bool;
}

impl Tracer for Bvh {
    fn nearest(&self, r: &BenchRay) -> Option<f32> {
        self.intersect(&r.ray, r.t_min, r.t_max).map(|h| h.t)
    }
    fn occluded(&self, r: &BenchRay) -> bool {
        Bvh::occluded(self, &r.ray, r.t_min, r.t_max)
    }
}

/// The `bvh` crate: its `Bvh` over shapes holding the triangle. The crate's own
/// `Ray::intersects_triangle` culls back faces, so leaves use isin's two-sided
/// Möller–Trumbore (same cost class) to answer the same question on the same rays.
mod svenstaro {
    use super::{BenchRay, Tracer};
    use bvh::aabb::{Aabb, Bounded};
    use bvh::bounding_hierarchy::{BHShape, BoundingHierarchy};
    use isin_tracer::shapes::Triangle;

    pub struct Shape {
        pub tri: Triangle,
        node: usize,
    }

    impl Bounded<f32, 3> for Shape {
        fn aabb(&self) -> Aabb<f32, 3> {
            let b = self.tri.bounds();
            Aabb::with_bounds(b.min.to_array().into(), b.max.to_array().into())
        }
    }

    impl BHShape<f32, 3> for Shape {
        fn set_bh_node_index(&mut self, i: usize) {
            self.node = i;
        }
        fn bh_node_index(&self) -> usize {
            self.node
        }
    }

    pub struct Scene {
        bvh: bvh::bvh::Bvh<f32, 3>,
        shapes: Vec<Shape>,
    }

    /// Builds with `build_par` (rayon, the crate's parallel build).
    pub fn build(tris: &[Triangle]) -> Scene {
        let mut shapes: Vec<Shape> = tris.iter().map(|&tri| Shape { tri, node: 0 }).collect();
        let bvh = bvh::bvh::Bvh::build_par(&mut shapes);
        Scene { bvh, shapes }
    }

    fn ray(r: &BenchRay) -> bvh::ray::Ray<f32, 3> {
        bvh::ray::Ray::new(r.ray.origin.to_array().into(), r.ray.dir.to_array().into())
    }

    impl Tracer for Scene {
        fn nearest(&self, r: &BenchRay) -> Option<f32> {
            let q = ray(r);
            let mut best = r.t_max;
            let mut hit = None;
            for s in self.bvh.traverse_iterator(&q, &self.shapes) {
                if let Some((t, _, _)) = s.tri.intersect(&r.ray, r.t_min, best) {
                    best = t;
                    hit = Some(t);
                }
            }
            hit
        }
        fn occluded(&self, r: &BenchRay) -> bool {
            let q = ray(r);
            self.bvh
                .traverse_iterator(&q, &self.shapes)
                .any(|s| s.tri.intersect(&r.ray, r.t_min, r.t_max).is_some())
        }
    }
}

/// `obvhs`: a compressed-wide BVH (`build_cwbvh_from_tris`, medium quality) with
/// triangles reordered into `RtTriangle`s, as its examples recommend.
mod ob {
    use super::{BenchRay, Tracer};
    use glam::Vec3A;
    use isin_tracer::shapes::Triangle;
    use obvhs::cwbvh::CwBvh;
    use obvhs::ray::{Ray, RayHit};
    use obvhs::rt_triangle::RtTriangle;
    use std::time::Duration;

    pub struct Scene {
        bvh: CwBvh,
        tris: Vec<RtTriangle>,
    }

    pub fn build(tris: &[Triangle]) -> Scene {
        let t: Vec<obvhs::triangle::Triangle> = tris
            .iter()
            .map(|t| obvhs::triangle::Triangle { v0: t.v[0].into(), v1: t.v[1].into(), v2: t.v[2].into() })
            .collect();
        let bvh = obvhs::cwbvh::builder::build_cwbvh_from_tris(
            &t,
            obvhs::BvhBuildParams::medium_build(),
            &mut Duration::default(),
        );
        let tris = bvh.primitive_indices.iter().map(|&i| RtTriangle::from(&t[i as usize])).collect();
        Scene { bvh, tris }
    }

    fn ray(r: &BenchRay) -> Ray {
        Ray::new(Vec3A::from(r.ray.origin), Vec3A::from(r.ray.dir), r.t_min, r.t_max)
    }

    impl Tracer for Scene {
        fn nearest(&self, r: &BenchRay) -> Option<f32> {
            let mut hit = RayHit::none();
            self.bvh.ray_traverse(ray(r), &mut hit, |ray, id| self.tris[id].intersect(ray)).then_some(hit.t)
        }
        fn occluded(&self, r: &BenchRay) -> bool {
            !self.bvh.ray_traverse_miss(ray(r), |ray, id| self.tris[id].intersect(ray))
        }
    }
}

// ---------------------------------------------------------------------------
// Timing

fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("rayon pool")
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Best build time in ms over [`BUILD_REPS`] builds in `pool` — the statistic
/// Embree's benchmark reports for its own builds, so the ratio compares like
/// with like (a pool's first builds also pay for fresh pages and idle threads);
/// returns the last build.
fn time_build<T: Send>(pool: &rayon::ThreadPool, build: impl Fn() -> T + Sync) -> (f64, T) {
    let mut times = Vec::new();
    let mut built = None;
    for _ in 0..BUILD_REPS {
        drop(built.take());
        let t0 = Instant::now();
        let b = pool.install(&build);
        times.push(t0.elapsed().as_secs_f64() * 1e3);
        built = Some(b);
    }
    (times.iter().copied().fold(f64::INFINITY, f64::min), built.expect("built at least once"))
}

/// Which query a ray set is traced with.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Query {
    Nearest,
    AnyHit,
}

/// Traces `rays` once in `pool`; returns (seconds, hits).
fn trace_once(pool: &rayon::ThreadPool, t: &dyn Tracer, rays: &[BenchRay], q: Query) -> (f64, usize) {
    let t0 = Instant::now();
    let hits = pool.install(|| {
        rays.par_chunks(CHUNK)
            .map(|c| match q {
                Query::Nearest => c.iter().filter(|r| t.nearest(r).is_some()).count(),
                Query::AnyHit => c.iter().filter(|r| t.occluded(r)).count(),
            })
            .sum()
    });
    (t0.elapsed().as_secs_f64(), hits)
}

/// (Median, best, per CPU-second) Mrays/s over [`REPS`] runs. Tracers too slow for the budget trace an
/// evenly strided subset (noted in the report).
fn trace_mrays(
    pool: &rayon::ThreadPool,
    t: &dyn Tracer,
    rays: &[BenchRay],
    q: Query,
    label: &str,
    report: &mut Report,
) -> (f64, f64, Option<f64>) {
    // Probe on 1/64 of the rays to pick a stride.
    let probe: Vec<BenchRay> = rays.iter().step_by(64).copied().collect();
    let (secs, _) = trace_once(pool, t, &probe, q);
    let full = secs * 64.0;
    let stride = (full / REP_BUDGET.as_secs_f64()).ceil().max(1.0) as usize;
    let owned: Vec<BenchRay>;
    let set = if stride > 1 {
        owned = rays.iter().step_by(stride).copied().collect();
        report.notes.push(format!(
            "{label}: traced every {stride}th ray ({} of {})",
            owned.len(),
            rays.len()
        ));
        &owned[..]
    } else {
        rays
    };
    let cpu0 = process_cpu_seconds();
    let runs: Vec<f64> = (0..REPS).map(|_| set.len() as f64 / trace_once(pool, t, set, q).0 * 1e-6).collect();
    let per_cpu = match (cpu0, process_cpu_seconds()) {
        (Some(a), Some(b)) if b > a => Some((set.len() * REPS) as f64 / (b - a) * 1e-6),
        _ => None,
    };
    let best = runs.iter().copied().fold(0.0, f64::max);
    (median(runs), best, per_cpu)
}

/// User + system CPU seconds of the whole process so far (Linux: /proc, in
/// clock ticks of 10 ms; a case's repetitions take seconds, so ~1%).
fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised command name; utime and stime are 14 and 15.
    let rest = stat.rsplit_once(')')?.1;
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// The process's peak resident set size (VmHWM), in MB (Linux only).
fn peak_rss_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

fn bench_mesh(name: &str, mesh: &BenchMesh, view: View, isin_only: bool, report: &mut Report) {
    let tris = &mesh.tris[..];
    println!("== {name}: {} triangles", tris.len());
    let pools = [(1, pool(1)), (2, pool(2))];
    let mut isin = None;
    let mut sv = None;
    let mut obv = None;
    for (n, p) in &pools {
        // The previous pool's trees go first: peak RSS is one tree per library.
        drop((isin.take(), sv.take(), obv.take()));
        let (ti, b) = time_build(p, || Bvh::build(tris));
        report_row(report, &format!("{name} build {n}T"), Unit::Millis, ti, None, None);
        isin = Some(b);
        if !isin_only {
            let (ts, s) = time_build(p, || svenstaro::build(tris));
            let (to, o) = time_build(p, || ob::build(tris));
            let row = report.rows.last_mut().expect("row just added");
            (row.bvh, row.obvhs) = (Some(ts), Some(to));
            (sv, obv) = (Some(s), Some(o));
        }
    }
    let isin = isin.expect("built");
    if let Err(e) = isin.validate() {
        panic!("isin BVH invalid: {e}");
    }
    let bytes_per_tri = isin.memory_bytes() as f64 / tris.len().max(1) as f64;
    println!("  isin BVH + triangle data: {bytes_per_tri:.1} bytes/triangle");
    report.meshes.push((name.to_string(), tris.len(), bytes_per_tri));

    let b = mesh.bounds;
    let mut rng = EmbreeRng(12345);
    let primary = primary_rays(&b, view, 1024, 768);
    let incoherent = incoherent_rays(&b, 1 << 20, &mut rng);
    let shadow = shadow_rays(&b, &primary, &isin, &mut rng);
    let sets = [
        ("primary", &primary, Query::Nearest),
        ("incoherent", &incoherent, Query::Nearest),
        ("shadow", &shadow, Query::AnyHit),
    ];

    let mut tracers: Vec<(&str, &dyn Tracer)> = vec![("isin", &isin)];
    if let (Some(sv), Some(obv)) = (&sv, &obv) {
        tracers.push(("bvh", sv));
        tracers.push(("obvhs", obv));
    }
    for (kind, rays, q) in sets {
        // All three must agree on how many rays hit (same rays, same question).
        let counts: Vec<usize> =
            tracers.iter().map(|(_, t)| trace_once(&pools[1].1, *t, rays, q).1).collect();
        let counts: Vec<String> = counts.iter().map(usize::to_string).collect();
        report.notes.push(format!(
            "{name} {kind}: {} rays; hits isin/bvh/obvhs = {}",
            rays.len(),
            counts.join("/")
        ));
        for (n, p) in &pools {
            let label = format!("{name} {kind} {n}T");
            let m: Vec<(f64, f64, Option<f64>)> = tracers
                .iter()
                .map(|(lib, t)| trace_mrays(p, *t, rays, q, &format!("{label} {lib}"), report))
                .collect();
            let other = |i: usize| m.get(i).map(|x| x.0);
            report_row(report, &label, Unit::MraysPerSec, m[0].0, other(1), other(2));
            let row = report.rows.last_mut().expect("row just added");
            (row.isin_best, row.isin_per_cpu) = (Some(m[0].1), m[0].2);
        }
    }

    // isin's 8-ray packets on the same primary rays, 4×2 pixel tiles as
    // embree_bench's rtcIntersect8 (compared with Embree's packet figure).
    let packets = tile_packets(&primary, 1024, 768);
    let single_hits = trace_once(&pools[1].1, &isin, &primary, Query::Nearest).1;
    let packet_hits = trace_packets_once(&pools[1].1, &isin, &packets).1;
    assert_eq!(single_hits, packet_hits, "{name}: packets and single rays hit as many rays");
    report.notes.push(format!("{name} primary8: {} packets of 8 rays; hits {packet_hits}", packets.len()));
    for (n, p) in &pools {
        // Like the single-ray rows, a repetition lasts about REP_BUDGET: the
        // packet set is traced `k` times in one (so the CPU-time ticks add up).
        let probe = trace_packets_once(p, &isin, &packets).0;
        let k = (REP_BUDGET.as_secs_f64() / probe.max(1e-6)).ceil().clamp(1.0, 100.0) as usize;
        let run = || (0..k).map(|_| trace_packets_once(p, &isin, &packets).0).sum::<f64>();
        let (median, best, per_cpu) = measure(REPS, primary.len() * k, run);
        report_row(report, &format!("{name} primary8 {n}T"), Unit::MraysPerSec, median, None, None);
        let row = report.rows.last_mut().expect("row just added");
        (row.isin_best, row.isin_per_cpu) = (Some(best), per_cpu);
    }
}

/// A packet of eight rays for [`Bvh::intersect8`].
struct Packet8 {
    rays: [Ray; 8],
    t_min: [f32; 8],
    t_max: [f32; 8],
}

/// Groups a row-major `width × height` ray set into 4×2 pixel tiles (rays `py * width + px`),
/// in the order embree_bench traces its rtcIntersect8 packets.
fn tile_packets(rays: &[BenchRay], width: usize, height: usize) -> Vec<Packet8> {
    let mut out = Vec::with_capacity(rays.len() / 8);
    for ty in (0..height).step_by(2) {
        for tx in (0..width).step_by(4) {
            let r = |k: usize| &rays[(ty + k / 4) * width + tx + k % 4];
            out.push(Packet8 {
                rays: std::array::from_fn(|k| r(k).ray),
                t_min: std::array::from_fn(|k| r(k).t_min),
                t_max: std::array::from_fn(|k| r(k).t_max),
            });
        }
    }
    out
}

/// Traces `packets` once with isin's packet query in `pool`; returns (seconds, hits).
fn trace_packets_once(pool: &rayon::ThreadPool, bvh: &Bvh, packets: &[Packet8]) -> (f64, usize) {
    let t0 = Instant::now();
    let hits = pool.install(|| {
        packets
            .par_chunks(CHUNK / 8)
            .map(|c| {
                c.iter()
                    .map(|p| {
                        bvh.intersect8(&p.rays, p.t_min, p.t_max, 0xff).iter().filter(|h| h.is_some()).count()
                    })
                    .sum::<usize>()
            })
            .sum()
    });
    (t0.elapsed().as_secs_f64(), hits)
}

/// (Median, best, per CPU-second) Mrays/s of `reps` runs of `run` (which
/// returns its seconds) over `rays` rays.
fn measure(reps: usize, rays: usize, run: impl Fn() -> f64) -> (f64, f64, Option<f64>) {
    let cpu0 = process_cpu_seconds();
    let runs: Vec<f64> = (0..reps).map(|_| rays as f64 / run() * 1e-6).collect();
    let per_cpu = match (cpu0, process_cpu_seconds()) {
        (Some(a), Some(b)) if b > a => Some((rays * reps) as f64 / (b - a) * 1e-6),
        _ => None,
    };
    let best = runs.iter().copied().fold(0.0, f64::max);
    (median(runs), best, per_cpu)
}

fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let threads = std::thread::available_parallelism().map_or(0, |n| n.get());
    format!("{cpu}, {threads} hardware threads")
}

fn main() {
    // `cargo bench` passes `--bench`; `isin-only` skips the other libraries and any
    // other argument selects meshes by exact name (`cargo bench ... -- isin-only bunny`:
    // bunny, dragon_100k, sponza, dragon_1.6M).
    let mut filter: Vec<String> = std::env::args().skip(1).filter(|a| !a.starts_with("--")).collect();
    let isin_only = filter.iter().any(|a| a == "isin-only");
    // `json=NAME` writes target/bench/NAME instead of tracer.json.
    let json_name = filter
        .iter()
        .find_map(|a| a.strip_prefix("json="))
        .map_or_else(|| "tracer.json".to_string(), str::to_string);
    filter.retain(|a| a != "isin-only" && !a.starts_with("json="));
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let meshes = root.join("../../../shared/meshes");
    let mut report = Report::default();
    let start = Instant::now();
    let cases: [(&str, &str, View, u32); 4] = [
        ("bunny", "bunny/stanford-bunny.obj", View::Default, 0),
        ("dragon_100k", "dragon/dragon_100k.obj", View::Default, 0),
        // The README's Sponza view: `-cam -14 3 0 10 5 0`, inside the atrium.
        (
            "sponza",
            "sponza_dabrovic/sponza.obj",
            View::At(Vec3::new(-14.0, 3.0, 0.0), Vec3::new(10.0, 5.0, 0.0)),
            0,
        ),
        // Every triangle split 1 → 4 twice (`embree_bench -s 2`).
        ("dragon_1.6M", "dragon/dragon_100k.obj", View::Default, 2),
    ];
    for (name, rel, view, levels) in cases {
        if !filter.is_empty() && !filter.iter().any(|f| name == f.as_str()) {
            continue;
        }
        if let Some(mut mesh) = load_mesh(&meshes.join(rel)) {
            for _ in 0..levels {
                mesh.tris = subdivide(&mesh.tris);
            }
            bench_mesh(name, &mesh, view, isin_only, &mut report);
        }
    }
    let machine = machine();
    report.notes.push(format!("machine: {machine}; total bench time {:.0} s", start.elapsed().as_secs_f64()));
    println!("\n{}", report.markdown());
    let out = root.join("../../target/bench");
    let file = out.join(json_name);
    let written = std::fs::create_dir_all(&out).and_then(|_| std::fs::write(&file, report.json(&machine)));
    match written {
        Ok(()) => println!("wrote {}", file.display()),
        Err(e) => println!("could not write {}: {e}", out.display()),
    }
}

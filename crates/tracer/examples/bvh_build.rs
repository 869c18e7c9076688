//! BVH build timing: builds the BVH over an OBJ mesh on 1 and 2 rayon threads and
//! prints the best and median wall time, the tree's size and a fingerprint of
//! its hits (to see whether a builder change altered the tree), and optionally
//! the throughput of a quick incoherent/primary ray set (to see that tree quality held).
//!
//! ```sh
//! cargo run --release -p isin-tracer --example bvh_build -- ../shared/meshes/bunny/stanford-bunny.obj
//! # options: --reps N (default 7), --split K (split every triangle 1 -> 4, K times), --trace,
//! # --threads N (only N threads instead of 1 and 2), --rays N (probe rays, default 2^18),
//! # --trace-reps N (default 5; 1 under callgrind), --hash (a hash of the whole tree: every node's
//! # boxes and child words, the triangle blocks and lane ids, bit for bit via `Debug`),
//! # --memory fresh|reuse (glibc: every build on fresh pages, as a process's first build, or
//! # every build on reused heap memory; default: whatever the allocator does)
//! ```
//!
//! Why `--memory`: glibc serves the builder's megabyte arrays from fresh pages
//! in a process's first build, and afterwards, depending on how earlier frees
//! left the heap, either from reused memory or again from fresh pages (a page
//! fault per 4 KiB). Which of the two a repeated build gets changes with
//! unrelated allocations (measured: 0 or 2,256 page faults per bunny build for
//! the same builder), so comparisons between builder versions should fix it.

use isin_tracer::Vec3;
use isin_tracer::bvh::Bvh;
use isin_tracer::geometry::{Aabb, Ray};
use std::time::Instant;

#[path = "../benches/common/embree_mesh.rs"]
mod embree_mesh;
use embree_mesh::{BenchMesh, load_mesh, subdivide};

/// A small xorshift generator for the probe rays.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }

    fn in_box(&mut self, b: &Aabb) -> Vec3 {
        let (x, y, z) = (self.next(), self.next(), self.next());
        b.min + (b.max - b.min) * Vec3::new(x, y, z)
    }
}

/// Incoherent rays (sphere around the box aimed into it) and primary-like rays
/// (from one eye through a grid in front of the box).
fn probe_rays(b: &Aabb, n: usize) -> (Vec<Ray>, Vec<Ray>) {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let c = (b.min + b.max) * 0.5;
    let d = (b.max - b.min).length();
    let incoherent = (0..n)
        .map(|_| {
            let o = loop {
                let v = Vec3::new(rng.next(), rng.next(), rng.next()) * 2.0 - Vec3::ONE;
                let l = v.length_squared();
                if l > 1e-3 && l <= 1.0 {
                    break c + v / l.sqrt() * d;
                }
            };
            Ray::new(o, rng.in_box(b) - o)
        })
        .collect();
    let eye = c + Vec3::new(0.2, 0.25, 0.75) * d;
    let side = (n as f64).sqrt() as usize;
    let primary = (0..side * side)
        .map(|i| {
            let (x, y) = ((i % side) as f32 / side as f32, (i / side) as f32 / side as f32);
            let target = c + Vec3::new(x - 0.5, y - 0.5, 0.0) * d * 0.8;
            Ray::new(eye, target - eye)
        })
        .collect();
    (incoherent, primary)
}

/// FNV-1a over everything written to it (for [`tree_hash`]).
struct Fnv(u64);

impl std::fmt::Write for Fnv {
    fn write_str(&mut self, s: &str) -> std::fmt::Result {
        for b in s.bytes() {
            self.0 = (self.0 ^ u64::from(b)).wrapping_mul(0x100_0000_01b3);
        }
        Ok(())
    }
}

/// A hash of the whole tree: its `Debug` form lists every node's boxes (shortest
/// round-trip decimal of each `f32`, so every bit, the sign of zero included),
/// child words, triangle blocks and lane ids.
fn tree_hash(bvh: &Bvh) -> u64 {
    use std::fmt::Write;
    let mut h = Fnv(0xcbf2_9ce4_8422_2325);
    write!(h, "{bvh:?}").expect("hashing cannot fail");
    h.0
}

/// Sets glibc's allocation policy for the builds (see the module docs):
/// `fresh` maps every allocation of 64 KiB or more afresh (and unmaps it when
/// freed); `reuse` serves everything from the heap and never returns it.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn set_memory_policy(policy: &str) {
    unsafe extern "C" {
        fn mallopt(param: i32, value: i32) -> i32;
    }
    const M_TRIM_THRESHOLD: i32 = -1;
    const M_MMAP_THRESHOLD: i32 = -3;
    let (mmap, trim) = match policy {
        "fresh" => (64 << 10, 128 << 10),
        "reuse" => (i32::MAX, i32::MAX),
        other => panic!("--memory fresh|reuse, not {other}"),
    };
    // SAFETY: mallopt only changes glibc's allocation thresholds; it is called
    // before any other thread exists.
    let ok = unsafe { mallopt(M_MMAP_THRESHOLD, mmap) == 1 && mallopt(M_TRIM_THRESHOLD, trim) == 1 };
    assert!(ok, "mallopt failed");
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn set_memory_policy(_: &str) {
    panic!("--memory needs glibc");
}

/// User + system CPU seconds of the whole process so far (Linux; 10 ms ticks).
fn cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else { return f64::NAN };
    let Some((_, rest)) = stat.rsplit_once(')') else { return f64::NAN };
    let f: Vec<&str> = rest.split_whitespace().collect();
    let tick = |i: usize| f.get(i).and_then(|s| s.parse::<f64>().ok()).unwrap_or(f64::NAN);
    (tick(11) + tick(12)) / 100.0
}

/// Minor page faults of the whole process so far (Linux; NaN elsewhere): a
/// build on fresh memory takes one per 4 KiB page it writes first.
fn minor_faults() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else { return f64::NAN };
    let Some((_, rest)) = stat.rsplit_once(')') else { return f64::NAN };
    rest.split_whitespace().nth(7).and_then(|s| s.parse::<f64>().ok()).unwrap_or(f64::NAN)
}

/// The process's peak resident set size (VmHWM) in MB (Linux; NaN elsewhere).
fn peak_rss_mb() -> f64 {
    let Ok(status) = std::fs::read_to_string("/proc/self/status") else { return f64::NAN };
    let kb = status.lines().find_map(|l| l.strip_prefix("VmHWM:")).and_then(|v| v.split_whitespace().next());
    kb.and_then(|k| k.parse::<f64>().ok()).map_or(f64::NAN, |k| k / 1024.0)
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut reps = 7;
    let mut split = 0;
    let mut trace = false;
    let mut hash = false;
    let mut rays = 1 << 18;
    let mut trace_reps = 5;
    let mut thread_counts = vec![1, 2];
    let mut paths = Vec::new();
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--reps" => reps = it.next().and_then(|s| s.parse().ok()).expect("--reps N"),
            "--split" => split = it.next().and_then(|s| s.parse().ok()).expect("--split K"),
            "--trace" => trace = true,
            "--hash" => hash = true,
            "--memory" => set_memory_policy(it.next().expect("--memory fresh|reuse")),
            "--rays" => rays = it.next().and_then(|s| s.parse().ok()).expect("--rays N"),
            "--trace-reps" => trace_reps = it.next().and_then(|s| s.parse().ok()).expect("--trace-reps N"),
            "--threads" => {
                thread_counts = vec![it.next().and_then(|s| s.parse().ok()).expect("--threads N")];
            }
            p => paths.push(p.to_string()),
        }
    }
    for path in &paths {
        // Embree's bounds: every vertex of the file (subdivision stays inside them).
        let Some(BenchMesh { mut tris, bounds }) = load_mesh(std::path::Path::new(path)) else { return };
        for _ in 0..split {
            tris = subdivide(&tris);
        }
        println!("{path} (split {split}): {} triangles", tris.len());
        let mut last = None;
        for &threads in &thread_counts {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
            let mut times = Vec::new();
            let (cpu0, faults0) = (cpu_seconds(), minor_faults());
            for _ in 0..reps {
                drop(last.take());
                let t0 = Instant::now();
                let bvh = pool.install(|| Bvh::build(&tris));
                times.push(t0.elapsed().as_secs_f64() * 1e3);
                last = Some(bvh);
            }
            let cpu_ms = (cpu_seconds() - cpu0) * 1e3 / reps as f64;
            let faults = (minor_faults() - faults0) / reps as f64;
            times.sort_by(f64::total_cmp);
            println!(
                "  {threads}T build: best {:.2} ms, median {:.2} ms, CPU {cpu_ms:.1} ms per build, \
                 {faults:.0} page faults per build",
                times[0],
                times[times.len() / 2]
            );
        }
        let bvh = last.expect("built");
        bvh.validate().expect("valid BVH");
        let (incoherent, primary) = probe_rays(&bounds, rays);
        let mut fp: u64 = 0xcbf2_9ce4_8422_2325;
        for r in incoherent.iter().step_by(16) {
            let h = bvh.intersect(r, 0.0, f32::INFINITY);
            let v = h.map_or(u64::MAX, |h| u64::from(h.prim) << 32 | u64::from(h.t.to_bits()));
            fp = (fp ^ v).wrapping_mul(0x100_0000_01b3);
        }
        println!(
            "  {} wide nodes, {:.1} bytes/triangle, hit fingerprint {fp:016x}",
            bvh.node_count(),
            bvh.memory_bytes() as f64 / tris.len() as f64
        );
        if hash {
            println!("  tree hash {:016x}", tree_hash(&bvh));
        }
        println!("  peak RSS so far {:.0} MB", peak_rss_mb());
        if trace {
            for (name, rays) in [("incoherent", &incoherent), ("primary", &primary)] {
                let mut best = f64::INFINITY;
                let mut hits = 0;
                for _ in 0..trace_reps {
                    let t0 = Instant::now();
                    hits = rays.iter().filter(|r| bvh.intersect(r, 0.0, f32::INFINITY).is_some()).count();
                    best = best.min(t0.elapsed().as_secs_f64());
                }
                println!("  {name}: {:.2} Mrays/s 1T ({hits} hits)", rays.len() as f64 / best * 1e-6);
            }
            // Shadow rays from the primary hits to points on a square light above the mesh.
            let d = (bounds.max - bounds.min).length();
            let light = Vec3::new((bounds.min.x + bounds.max.x) * 0.5, bounds.max.y + 0.5 * d, bounds.min.z);
            let mut rng = Rng(0x2545_f491_4f6c_dd1d);
            let shadow: Vec<(Ray, f32)> = primary
                .iter()
                .filter_map(|r| bvh.intersect(r, 0.0, f32::INFINITY).map(|h| r.origin + r.dir * h.t))
                .map(|p| {
                    let l = light + Vec3::new(rng.next() - 0.5, 0.0, rng.next() - 0.5) * 0.25 * d;
                    let to = l - p;
                    (Ray::new(p, to / to.length()), to.length() * 0.999)
                })
                .collect();
            let (mut best, mut hits) = (f64::INFINITY, 0);
            for _ in 0..trace_reps {
                let t0 = Instant::now();
                hits = shadow.iter().filter(|(r, len)| bvh.occluded(r, 1e-4 * d, *len)).count();
                best = best.min(t0.elapsed().as_secs_f64());
            }
            println!("  shadow: {:.2} Mrays/s 1T ({hits} occluded)", shadow.len() as f64 / best * 1e-6);
        }
    }
}

//! The traversal kernel on real meshes: the SIMD and the scalar paths give the
//! same bits for every query, and the packet query equals the single-ray one.
//! Also a fixed ray workload (`kernel_workload`, ignored by default) to count
//! instructions with callgrind:
//!
//! `KERNEL_RAYS=shadow valgrind --tool=callgrind target/debug/deps/kernel-… kernel_workload --ignored`

use isin_tracer::bvh::Bvh;
use isin_tracer::geometry::{Aabb, Ray};
use isin_tracer::shapes::Triangle;
use isin_tracer::{Vec3, math};
use std::path::PathBuf;

mod common;

use common::{Rng, bounds_of, load_mesh};

/// A `width × height` pinhole camera looking at the box (rows top to bottom).
fn camera_rays(b: &Aabb, width: usize, height: usize) -> Vec<Ray> {
    let (c, d) = (b.center(), b.diagonal());
    let eye = c + Vec3::new(0.2, 0.25, 0.75) * d;
    let w = (c - eye).normalize();
    let u = w.cross(Vec3::Y).normalize();
    let v = u.cross(w);
    let th = math::tan(22.5f32.to_radians());
    let mut rays = Vec::with_capacity(width * height);
    for py in 0..height {
        for px in 0..width {
            let x = ((px as f32 + 0.5) / width as f32 * 2.0 - 1.0) * th * width as f32 / height as f32;
            let y = (1.0 - (py as f32 + 0.5) / height as f32 * 2.0) * th;
            rays.push(Ray::new(eye, (w + u * x + v * y).normalize()));
        }
    }
    rays
}

fn incoherent_rays(b: &Aabb, n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = Rng(seed);
    let (c, d) = (b.center(), b.diagonal());
    (0..n)
        .map(|_| {
            let o = c + rng.unit_vector() * d;
            Ray::new(o, (rng.in_box(b) - o).normalize())
        })
        .collect()
}

/// Shadow rays from the camera rays' hits to points on a square light above the
/// box: `(ray, t_min, t_max)`.
fn shadow_rays(b: &Aabb, bvh: &Bvh, camera: &[Ray], seed: u64) -> Vec<(Ray, f32, f32)> {
    let mut rng = Rng(seed);
    let (c, d) = (b.center(), b.diagonal());
    let light = Vec3::new(c.x + 0.3 * d, b.max.y + 0.5 * d, c.z + 0.3 * d);
    camera
        .iter()
        .filter_map(|r| bvh.intersect(r, 0.0, f32::INFINITY).map(|h| r.at(h.t)))
        .map(|p| {
            let lp = light + Vec3::new(rng.range(-0.125, 0.125), 0.0, rng.range(-0.125, 0.125)) * d;
            let to = lp - p;
            let len = to.length();
            (Ray::new(p, to / len), 1e-4 * d, len * 0.999)
        })
        .collect()
}

/// Every query on `bvh` with SIMD on equals the one with SIMD off, bit for bit.
fn assert_simd_matches_scalar(name: &str, tris: &[Triangle]) {
    let simd = Bvh::build(tris);
    let mut scalar = simd.clone();
    scalar.set_simd(false);
    assert!(!scalar.simd_active() && !scalar.avx_active());
    let mut sse = simd.clone();
    sse.set_avx(false);
    assert!(!sse.avx_active());
    println!("{name}: AVX box test {}", if simd.avx_active() { "on" } else { "not available" });
    let b = bounds_of(tris);
    let camera = camera_rays(&b, 160, 120);
    let mut rays: Vec<(Ray, f32, f32)> = camera.iter().map(|r| (*r, 0.0, f32::INFINITY)).collect();
    rays.extend(incoherent_rays(&b, 20_000, 3).into_iter().map(|r| (r, 0.0, f32::INFINITY)));
    rays.extend(shadow_rays(&b, &simd, &camera, 4));
    let bits = |h: Option<isin_tracer::shapes::Hit>| {
        h.map(|h| (h.t.to_bits(), h.u.to_bits(), h.v.to_bits(), h.prim))
    };
    let (mut hits, mut blocked) = (0, 0);
    for (i, (ray, t_min, t_max)) in rays.iter().enumerate() {
        let a = simd.intersect(ray, *t_min, *t_max);
        assert_eq!(bits(a), bits(scalar.intersect(ray, *t_min, *t_max)), "{name} ray {i}");
        assert_eq!(bits(a), bits(sse.intersect(ray, *t_min, *t_max)), "{name} ray {i} (SSE)");
        let o = simd.occluded(ray, *t_min, *t_max);
        assert_eq!(o, scalar.occluded(ray, *t_min, *t_max), "{name} ray {i}");
        assert_eq!(o, sse.occluded(ray, *t_min, *t_max), "{name} ray {i} (SSE)");
        assert_eq!(o, a.is_some(), "{name} ray {i}: any hit iff nearest hit");
        hits += a.is_some() as usize;
        blocked += (*t_max != f32::INFINITY && o) as usize;
    }
    assert!(hits > rays.len() / 4, "{name}: {hits} of {} rays hit", rays.len());
    assert!(blocked > 100, "{name}: {blocked} shadow rays blocked");
}

#[test]
fn simd_and_scalar_queries_agree_on_the_bunny() {
    let Some(tris) = load_mesh("bunny/stanford-bunny.obj") else { return };
    assert_simd_matches_scalar("bunny", &tris);
}

#[test]
fn simd_and_scalar_queries_agree_on_the_dragon() {
    let Some(tris) = load_mesh("dragon/dragon_100k.obj") else { return };
    assert_simd_matches_scalar("dragon", &tris);
}

/// Packets of four shadow rays from each camera hit to the corners of a square
/// light above the box: `(rays, t_min, t_max)`.
fn corner_packets(b: &Aabb, bvh: &Bvh, camera: &[Ray]) -> Vec<([Ray; 4], [f32; 4], [f32; 4])> {
    let (c, d) = (b.center(), b.diagonal());
    let light = Vec3::new(c.x + 0.3 * d, b.max.y + 0.5 * d, c.z + 0.3 * d);
    let h = 0.125 * d;
    let corners = [(-h, -h), (h, -h), (-h, h), (h, h)].map(|(x, z)| light + Vec3::new(x, 0.0, z));
    camera
        .iter()
        .filter_map(|r| bvh.intersect(r, 0.0, f32::INFINITY).map(|hit| r.at(hit.t)))
        .map(|p| {
            let to = corners.map(|q| q - p);
            let rays = to.map(|v| Ray::new(p, v.normalize()));
            (rays, [1e-4 * d; 4], to.map(|v| v.length() * 0.999))
        })
        .collect()
}

/// `occluded4` answers exactly `occluded` for every active ray, on coherent
/// corner packets and on packets of unrelated rays, with SIMD on and off.
#[test]
fn packet_any_hit_equals_single_rays_on_the_bunny() {
    let Some(tris) = load_mesh("bunny/stanford-bunny.obj") else { return };
    let simd = Bvh::build(&tris);
    let mut scalar = simd.clone();
    scalar.set_simd(false);
    let b = bounds_of(&tris);
    let mut packets = corner_packets(&b, &simd, &camera_rays(&b, 160, 120));
    let mut rng = Rng(21);
    let inc = incoherent_rays(&b, 8000, 22);
    for q in inc.chunks_exact(4) {
        let t_max = [0, 1, 2, 3]
            .map(|_| if rng.next_f32() < 0.5 { f32::INFINITY } else { rng.range(0.0, 1.0) * b.diagonal() });
        packets.push(([q[0], q[1], q[2], q[3]], [0.0; 4], t_max));
    }
    let (mut some, mut all, mut mixed) = (0, 0, 0);
    for (i, (rays, t_min, t_max)) in packets.iter().enumerate() {
        for active in [0b1111, 0b1010, 0b0111, 0b0001, 0] {
            let expected = (0..4)
                .filter(|&j| active & (1 << j) != 0 && simd.occluded(&rays[j], t_min[j], t_max[j]))
                .fold(0u32, |m, j| m | 1 << j);
            for bvh in [&simd, &scalar] {
                assert_eq!(
                    bvh.occluded4(rays, *t_min, *t_max, active),
                    expected,
                    "packet {i} active {active:b}"
                );
            }
            if active == 0b1111 {
                some += (expected != 0) as usize;
                all += (expected == 0b1111) as usize;
                mixed += (expected != 0 && expected != 0b1111) as usize;
            }
        }
    }
    assert!(some > 500 && all > 100 && mixed > 50, "{some} packets blocked, {all} fully, {mixed} partly");
}

/// Nanoseconds this thread has run on a CPU (Linux `/proc/thread-self/schedstat`), if known:
/// a throughput measure that does not count time other processes take the CPU away.
fn thread_cpu_ns() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    s.split_whitespace().next()?.parse().ok()
}

/// A fixed workload for instruction counts (see the module docs); `KERNEL_RAYS`
/// picks `primary`, `incoherent`, `shadow`, `corners` (four rays from each camera
/// hit to a light's corners, one by one) or `corners4` (the same as packets), `KERNEL_REPS`
/// repeats each set and prints Mrays per CPU second.
#[test]
#[ignore]
fn kernel_workload() {
    let Some(tris) = load_mesh("bunny/stanford-bunny.obj") else { return };
    let bvh = Bvh::build(&tris);
    let b = bounds_of(&tris);
    let camera = camera_rays(&b, 320, 240);
    let shadow = shadow_rays(&b, &bvh, &camera, 5);
    let incoherent = incoherent_rays(&b, 50_000, 6);
    let packets = corner_packets(&b, &bvh, &camera);
    let kind = std::env::var("KERNEL_RAYS").unwrap_or_default();
    let reps: usize = std::env::var("KERNEL_REPS").ok().and_then(|r| r.parse().ok()).unwrap_or(1);
    let mut n = 0usize;
    let mut run = |name: &str, rays: usize, f: &dyn Fn() -> usize| {
        if !(kind.is_empty() || kind == name) {
            return;
        }
        let start = thread_cpu_ns();
        for _ in 0..reps {
            n += f();
        }
        if let (Some(a), Some(b)) = (start, thread_cpu_ns()) {
            println!("{name}: {:.2} Mrays/CPU-s", (rays * reps) as f64 / ((b - a) as f64 * 1e-9) / 1e6);
        }
    };
    run("primary", camera.len(), &|| {
        camera.iter().filter(|r| bvh.intersect(r, 0.0, f32::INFINITY).is_some()).count()
    });
    run("incoherent", incoherent.len(), &|| {
        incoherent.iter().filter(|r| bvh.intersect(r, 0.0, f32::INFINITY).is_some()).count()
    });
    run("shadow", shadow.len(), &|| shadow.iter().filter(|(r, a, b)| bvh.occluded(r, *a, *b)).count());
    run("corners", packets.len() * 4, &|| {
        let one = |(rays, t_min, t_max): &([Ray; 4], [f32; 4], [f32; 4])| {
            (0..4).filter(|&j| bvh.occluded(&rays[j], t_min[j], t_max[j])).count()
        };
        packets.iter().map(one).sum()
    });
    run("corners4", packets.len() * 4, &|| {
        packets.iter().map(|(r, a, b)| bvh.occluded4(r, *a, *b, 0b1111).count_ones() as usize).sum()
    });
    assert!(n > 0);
}

/// Reads scene assets from `scenes/`.
struct SceneDir(PathBuf);

impl isin_tracer::AssetSource for SceneDir {
    fn read(&mut self, path: &str) -> Result<Vec<u8>, String> {
        std::fs::read(self.0.join(path)).map_err(|e| format!("{path}: {e}"))
    }
}

/// The shipped paper scene renders the same bytes with the AVX, the SSE and
/// the scalar box tests (mirrors, glass, area-light shadows: every query kind),
/// and with camera rays — and the reflections and refractions they spawn — traced
/// in packets or one by one.
#[test]
fn paper_scene_renders_the_same_bytes_with_avx_sse_scalar_and_packets() {
    let scenes = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let source = std::fs::read_to_string(scenes.join("paper.toml")).expect("scenes/paper.toml");
    let scene = isin_tracer::load_scene("paper.toml", &source, &mut SceneDir(scenes)).expect("loads");
    let settings = isin_tracer::RenderSettings { width: 160, height: 120, ..scene.settings };
    let render = |s: &isin_tracer::Scene| isin_tracer::render_frame(s, &s.camera, &settings, 16, &|_| {}).rgb;
    let mut sse = scene.clone();
    sse.bvh.set_avx(false);
    let mut scalar = scene.clone();
    scalar.bvh.set_simd(false);
    let a = render(&scene);
    assert!(a.iter().any(|&c| c != a[0]), "a picture, not a flat colour");
    assert!(a == render(&sse), "AVX and SSE renders differ");
    assert!(a == render(&scalar), "AVX and scalar renders differ");
    let single = isin_tracer::render::TraceOptions { packets: false, ..Default::default() };
    let one_by_one =
        isin_tracer::render::render_frame_with(&scene, &scene.camera, &settings, 16, &single, &|_| {});
    assert!(a == one_by_one.0.rgb, "packet and single-ray camera rays render differently");
    // Supersampled, with tiles whose edges cut through packets.
    let aa = isin_tracer::RenderSettings { width: 61, height: 43, spp: 4, ..scene.settings };
    let packets = isin_tracer::render_frame(&scene, &scene.camera, &aa, 7, &|_| {}).rgb;
    let single = isin_tracer::render::render_frame_with(&scene, &scene.camera, &aa, 7, &single, &|_| {});
    assert!(packets == single.0.rgb, "supersampled packet and single-ray renders differ");
}

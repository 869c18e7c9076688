//! Eight-ray packets (`Bvh::intersect8`, `Bvh::occluded8`) against the single-ray
//! queries, field by field and bit for bit: camera packets (4×2 pixel blocks),
//! shadow packets to an area light, incoherent packets, axis-parallel and
//! degenerate rays, origins on triangle edges, rays through shared vertices and
//! duplicated triangles (ties at a bit-identical `t`), on the bunny and the dragon.

use isin_tracer::bvh::{Bvh, PACKET_LANES};
use isin_tracer::geometry::{Aabb, Ray};
use isin_tracer::shapes::{Hit, Triangle};
use isin_tracer::{Vec3, math};
use rayon::prelude::*;

mod common;

use common::{Rng, bounds_of, load_mesh};

/// A packet: rays, interval starts and ends.
type Packet = ([Ray; PACKET_LANES], [f32; PACKET_LANES], [f32; PACKET_LANES]);

/// Bits of a hit, for exact comparison.
fn bits(h: &Option<Hit>) -> Option<(u32, u32, u32, u32)> {
    h.map(|h| (h.t.to_bits(), h.u.to_bits(), h.v.to_bits(), h.prim))
}

/// Camera packets: 4×2 pixel blocks of a `width × height` pinhole camera with
/// its eye at `eye`, looking at the box centre, with a vertical FOV of 45°.
fn camera_packets(b: &Aabb, eye: Vec3, width: usize, height: usize) -> Vec<Packet> {
    let c = b.center();
    let w = (c - eye).normalize();
    let u = w.cross(Vec3::Y).normalize();
    let v = u.cross(w);
    let th = math::tan(22.5f32.to_radians());
    let ray = |px: usize, py: usize| {
        let x = ((px as f32 + 0.5) / width as f32 * 2.0 - 1.0) * th * width as f32 / height as f32;
        let y = (1.0 - (py as f32 + 0.5) / height as f32 * 2.0) * th;
        Ray::new(eye, (w + u * x + v * y).normalize())
    };
    let mut out = Vec::new();
    for by in (0..height).step_by(2) {
        for bx in (0..width).step_by(4) {
            let rays = std::array::from_fn(|k| ray(bx + k % 4, by + k / 4));
            out.push((rays, [0.0; PACKET_LANES], [f32::INFINITY; PACKET_LANES]));
        }
    }
    out
}

/// Shadow packets: from each camera hit to eight random points on a square
/// light above the box.
fn shadow_packets(b: &Aabb, bvh: &Bvh, camera: &[Packet], seed: u64) -> Vec<Packet> {
    let mut rng = Rng(seed);
    let (c, d) = (b.center(), b.diagonal());
    let light = Vec3::new(c.x + 0.3 * d, b.max.y + 0.5 * d, c.z + 0.3 * d);
    let mut out = Vec::new();
    for (rays, _, _) in camera {
        for r in rays.iter().step_by(3) {
            let Some(h) = bvh.intersect(r, 0.0, f32::INFINITY) else { continue };
            let p = r.at(h.t);
            let to: [Vec3; PACKET_LANES] = std::array::from_fn(|_| {
                light + Vec3::new(rng.range(-0.125, 0.125), 0.0, rng.range(-0.125, 0.125)) * d - p
            });
            out.push((
                to.map(|v| Ray::new(p, v.normalize())),
                [1e-4 * d; PACKET_LANES],
                to.map(|v| v.length() * 0.999),
            ));
        }
    }
    out
}

/// Packets of unrelated rays (origins around the box, aimed into it), with
/// random interval starts and ends.
fn incoherent_packets(b: &Aabb, n: usize, seed: u64) -> Vec<Packet> {
    let mut rng = Rng(seed);
    let (c, d) = (b.center(), b.diagonal());
    (0..n)
        .map(|_| {
            let rays = std::array::from_fn(|_| {
                let o = c + rng.unit_vector() * d;
                Ray::new(o, (rng.in_box(b) - o).normalize())
            });
            let t_min = std::array::from_fn(|_| if rng.next_f32() < 0.2 { rng.range(0.0, d) } else { 0.0 });
            let t_max = std::array::from_fn(|_| {
                if rng.next_f32() < 0.5 { f32::INFINITY } else { rng.range(0.5, 2.0) * d }
            });
            (rays, t_min, t_max)
        })
        .collect()
}

/// Narrow packets of one origin with directions of one sign per axis, aimed
/// near random points of the box: the packet path proper, with random
/// intervals (some ending before the surface).
fn coherent_packets(b: &Aabb, n: usize, seed: u64) -> Vec<Packet> {
    let mut rng = Rng(seed);
    let (c, d) = (b.center(), b.diagonal());
    (0..n)
        .map(|_| {
            let o = c + rng.unit_vector() * d;
            let target = rng.in_box(b);
            let spread = d * 0.01 * rng.next_f32();
            let rays = std::array::from_fn(|_| {
                let t = target
                    + Vec3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0)) * spread;
                Ray::new(o, (t - o).normalize())
            });
            let t_min = std::array::from_fn(|_| if rng.next_f32() < 0.2 { rng.range(0.0, d) } else { 0.0 });
            let t_max = std::array::from_fn(|_| {
                if rng.next_f32() < 0.3 { rng.range(0.5, 1.5) * d } else { f32::INFINITY }
            });
            (rays, t_min, t_max)
        })
        .collect()
}

/// Degenerate packets: axis-parallel rays (+0 and −0 in the other components),
/// origins exactly on triangle edges and vertices, rays aimed exactly at
/// vertices and edge midpoints (shared by neighbouring triangles), and packets
/// whose directions differ in sign.
fn degenerate_packets(tris: &[Triangle], b: &Aabb, n: usize, seed: u64) -> Vec<Packet> {
    let mut rng = Rng(seed);
    let d = b.diagonal();
    let mut out = Vec::new();
    for i in 0..n {
        let tri = tris[(rng.next_f32() * tris.len() as f32) as usize % tris.len()];
        let [a, bb, cc] = tri.v;
        let rays: [Ray; PACKET_LANES] = match i % 5 {
            // Axis-parallel, through points of the box.
            0 => {
                let axis = i % 3;
                let sign = if i % 2 == 0 { 1.0 } else { -1.0 };
                std::array::from_fn(|k| {
                    let mut dir = Vec3::splat(if k % 2 == 0 { 0.0 } else { -0.0 });
                    dir[axis] = sign;
                    let mut o =
                        a + Vec3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0))
                            * 0.002
                            * d;
                    o[axis] -= sign * d;
                    Ray::new(o, dir)
                })
            }
            // One origin on an edge of the triangle, eight directions of one octant.
            1 => {
                let o = a + (bb - a) * 0.5;
                let base = Vec3::new(rng.range(0.1, 1.0), rng.range(0.1, 1.0), rng.range(0.1, 1.0));
                let flip = Vec3::new(
                    if rng.next_f32() < 0.5 { -1.0 } else { 1.0 },
                    if rng.next_f32() < 0.5 { -1.0 } else { 1.0 },
                    if rng.next_f32() < 0.5 { -1.0 } else { 1.0 },
                );
                std::array::from_fn(|k| {
                    let j = Vec3::new(rng.range(0.0, 0.05), rng.range(0.0, 0.05), k as f32 * 0.01);
                    Ray::new(o, ((base + j) * flip).normalize())
                })
            }
            // From one eye exactly at vertices and edge midpoints of this and
            // the next triangles (neighbours share them).
            2 | 3 => {
                let eye = b.center() + rng.unit_vector() * d;
                std::array::from_fn(|k| {
                    let t = tris[(tris.iter().position(|x| x.v == tri.v).unwrap_or(0) + k / 4) % tris.len()];
                    let target = match k % 4 {
                        0 => t.v[0],
                        1 => t.v[1],
                        2 => (t.v[0] + t.v[1]) * 0.5,
                        _ => (t.v[1] + t.v[2]) * 0.5,
                    };
                    Ray::new(eye, target - eye)
                })
            }
            // Origins at the triangle's vertices, directions of both signs.
            _ => std::array::from_fn(|k| Ray::new([a, bb, cc][k % 3], rng.unit_vector())),
        };
        let t_min = [if i % 7 == 0 { 1e-4 * d } else { 0.0 }; PACKET_LANES];
        out.push((rays, t_min, [f32::INFINITY; PACKET_LANES]));
    }
    out
}

/// True when the packet has, per axis, direction components of one sign,
/// none zero: the packet path proper (others fall back to single rays).
fn one_octant(rays: &[Ray; PACKET_LANES]) -> bool {
    (0..3).all(|a| rays.iter().all(|r| r.dir[a] > 0.0) || rays.iter().all(|r| r.dir[a] < 0.0))
}

/// Checks both packet queries against the single-ray ones for every packet and
/// a few activity masks; returns (rays hit, packets in one octant).
fn check(bvh: &Bvh, packets: &[Packet]) -> (usize, usize) {
    let masks = [0xffu8, 0b1010_0101, 0b0000_0110, 0b1000_0000, 0];
    let results: Vec<(usize, usize)> = packets
        .par_iter()
        .enumerate()
        .map(|(i, (rays, t_min, t_max))| {
            let single: Vec<Option<Hit>> =
                (0..PACKET_LANES).map(|j| bvh.intersect(&rays[j], t_min[j], t_max[j])).collect();
            for active in masks {
                let got = bvh.intersect8(rays, *t_min, *t_max, active);
                for j in 0..PACKET_LANES {
                    let want = if active & (1 << j) != 0 { single[j] } else { None };
                    assert_eq!(
                        bits(&got[j]),
                        bits(&want),
                        "packet {i} ray {j} active {active:08b}: {:?}",
                        rays[j]
                    );
                }
                // Any hit: over the interval, and up to just before / after the nearest hit.
                for scale in [1.0f32, 0.999, 1.001] {
                    let ends: [f32; PACKET_LANES] = std::array::from_fn(|j| match single[j] {
                        Some(h) if scale != 1.0 => h.t * scale,
                        _ => t_max[j],
                    });
                    let want = (0..PACKET_LANES)
                        .filter(|&j| active & (1 << j) != 0 && bvh.occluded(&rays[j], t_min[j], ends[j]))
                        .fold(0u8, |m, j| m | 1 << j);
                    assert_eq!(
                        bvh.occluded8(rays, *t_min, ends, active),
                        want,
                        "packet {i} active {active:08b} any-hit (scale {scale})"
                    );
                }
            }
            (single.iter().filter(|h| h.is_some()).count(), one_octant(rays) as usize)
        })
        .collect();
    results.iter().fold((0, 0), |(a, b), (c, d)| (a + c, b + d))
}

/// Runs every packet kind on `tris`, with SIMD on and off.
fn check_mesh(name: &str, tris: &[Triangle]) {
    let bvh = Bvh::build(tris);
    let b = bounds_of(tris);
    let d = b.diagonal();
    let camera = camera_packets(&b, b.center() + Vec3::new(0.2, 0.25, 0.75) * d, 256, 192);
    let (hits, octant) = check(&bvh, &camera);
    assert!(hits > 5_000, "{name} camera: {hits} hits");
    assert!(
        octant * 100 > camera.len() * 95,
        "{name} camera: {octant} of {} packets in one octant",
        camera.len()
    );
    // A second view, from below and closer.
    let camera2 = camera_packets(&b, b.center() + Vec3::new(-0.3, -0.2, 0.4) * d, 128, 96);
    let (hits, _) = check(&bvh, &camera2);
    assert!(hits > 1_000, "{name} camera 2: {hits} hits");
    let shadow = shadow_packets(&b, &bvh, &camera, 7);
    let (_, octant) = check(&bvh, &shadow);
    assert!(shadow.len() > 1_000 && octant * 2 > shadow.len(), "{name} shadow: {octant} of {}", shadow.len());
    let coherent = coherent_packets(&b, 4_000, 8);
    let (hits, octant) = check(&bvh, &coherent);
    assert!(hits > 4_000 && octant > 3_900, "{name} coherent: {hits} hits, {octant} in one octant");
    let (hits, _) = check(&bvh, &incoherent_packets(&b, 1_000, 9));
    assert!(hits > 2_000, "{name} incoherent: {hits} hits");
    let (hits, _) = check(&bvh, &degenerate_packets(tris, &b, 2_000, 10));
    assert!(hits > 2_000, "{name} degenerate: {hits} hits");

    let mut scalar = bvh.clone();
    scalar.set_simd(false);
    check(&scalar, &coherent[..500]);
}

#[test]
fn packets_equal_single_rays_on_the_bunny() {
    let Some(tris) = load_mesh("bunny/stanford-bunny.obj") else { return };
    check_mesh("bunny", &tris);
}

#[test]
fn packets_equal_single_rays_on_the_dragon() {
    let Some(tris) = load_mesh("dragon/dragon_100k.obj") else { return };
    check_mesh("dragon", &tris);
}

/// Duplicated triangles and a regular grid whose diagonals and vertices are
/// shared: many hits at a bit-identical `t` in different triangles, where the
/// single-ray query's own order decides (the packet must notice the tie).
#[test]
fn ties_at_identical_t_give_the_single_ray_answer() {
    let mut tris = Vec::new();
    let p = |i: usize, j: usize| Vec3::new(i as f32 * 0.25, 0.0, j as f32 * 0.25);
    for i in 0..40 {
        for j in 0..40 {
            tris.push(Triangle { v: [p(i, j), p(i + 1, j), p(i + 1, j + 1)] });
            tris.push(Triangle { v: [p(i, j), p(i + 1, j + 1), p(i, j + 1)] });
            if (i + j) % 3 == 0 {
                // A duplicate, and the same triangle with its vertices rotated.
                tris.push(Triangle { v: [p(i, j), p(i + 1, j), p(i + 1, j + 1)] });
                tris.push(Triangle { v: [p(i + 1, j + 1), p(i, j + 1), p(i, j)] });
            }
        }
    }
    let bvh = Bvh::build(&tris);
    let mut packets = Vec::new();
    let mut rng = Rng(3);
    for n in 0..3_000 {
        // Straight down at grid points and edge midpoints (exact in binary), or
        // obliquely from one eye at points of the grid.
        let eye = Vec3::new(rng.range(1.0, 9.0), rng.range(1.0, 6.0), rng.range(1.0, 9.0));
        let (gi, gj) = ((rng.next_f32() * 36.0) as usize, (rng.next_f32() * 36.0) as usize);
        let rays = std::array::from_fn(|k| {
            let target =
                p(gi + k % 4, gj + k / 4) + Vec3::new(0.125 * (n % 2) as f32, 0.0, 0.125 * (k % 2) as f32);
            if n % 3 == 0 {
                Ray::new(target + Vec3::Y, Vec3::new(1e-3, -1.0, 1e-3))
            } else {
                Ray::new(eye, target - eye)
            }
        });
        packets.push((rays, [0.0; PACKET_LANES], [f32::INFINITY; PACKET_LANES]));
    }
    let (hits, octant) = check(&bvh, &packets);
    assert!(hits > 20_000 && octant > 2_000, "{hits} hits, {octant} packets in one octant");
    // The rays do hit several triangles at one t: the test is meaningful.
    let ties = packets
        .iter()
        .flat_map(|(rays, _, _)| rays.iter())
        .filter(|r| {
            let ts: Vec<u32> = tris
                .iter()
                .filter_map(|t| t.intersect(r, 0.0, f32::INFINITY))
                .map(|h| h.0.to_bits())
                .collect();
            let min = ts.iter().copied().min_by(|a, b| f32::from_bits(*a).total_cmp(&f32::from_bits(*b)));
            min.is_some_and(|m| ts.iter().filter(|&&t| t == m).count() > 1)
        })
        .count();
    assert!(ties > 1_000, "{ties} rays with tied nearest hits");
}

/// Empty tree, lone triangle and inactive packets.
#[test]
fn small_and_empty_trees() {
    let empty = Bvh::default();
    let rays = [Ray::new(Vec3::ZERO, Vec3::new(0.1, 0.2, -1.0)); PACKET_LANES];
    assert_eq!(bits(&empty.intersect8(&rays, [0.0; 8], [f32::INFINITY; 8], 0xff)[0]), None);
    assert_eq!(empty.occluded8(&rays, [0.0; 8], [f32::INFINITY; 8], 0xff), 0);
    let tri =
        Triangle { v: [Vec3::new(-1.0, -1.0, -2.0), Vec3::new(1.0, -1.0, -2.0), Vec3::new(0.0, 1.0, -2.0)] };
    let bvh = Bvh::build(&[tri]);
    let rays: [Ray; PACKET_LANES] =
        std::array::from_fn(|k| Ray::new(Vec3::ZERO, Vec3::new(k as f32 * 0.1 + 0.01, 0.05, -1.0)));
    let got = bvh.intersect8(&rays, [0.0; 8], [f32::INFINITY; 8], 0xff);
    for (k, h) in got.iter().enumerate() {
        assert_eq!(bits(h), bits(&bvh.intersect(&rays[k], 0.0, f32::INFINITY)), "ray {k}");
    }
    assert!(got[0].is_some() && got[7].is_none(), "{got:?}");
    let want = (0..PACKET_LANES).filter(|&k| got[k].is_some()).fold(0u8, |m, k| m | 1 << k);
    assert_eq!(bvh.occluded8(&rays, [0.0; 8], [f32::INFINITY; 8], 0xff), want);
    assert_eq!(bvh.occluded8(&rays, [0.0; 8], [1.5; 8], 0xff), 0, "the triangle is 2 units away");
}

/// A fixed workload for counting instructions (ignored by default): the
/// bunny's 1024×768 camera packets (or shadow packets from their hits) traced
/// as packets or as single rays, chosen by `PACKET_RAYS` = `primary8`
/// (default), `primary`, `shadow8`, `shadow` or `none` (setup only);
/// `PACKET_MESH` picks another mesh.
///
/// `PACKET_RAYS=primary valgrind --tool=callgrind target/debug/deps/packet-… packet_workload --ignored`
#[test]
#[ignore]
fn packet_workload() {
    let mesh = std::env::var("PACKET_MESH").unwrap_or_else(|_| "bunny/stanford-bunny.obj".into());
    let Some(tris) = load_mesh(&mesh) else { return };
    let bvh = Bvh::build(&tris);
    let b = bounds_of(&tris);
    let camera = camera_packets(&b, b.center() + Vec3::new(0.2, 0.25, 0.75) * b.diagonal(), 1024, 768);
    let kind = std::env::var("PACKET_RAYS").unwrap_or_else(|_| "primary8".into());
    let packets = if kind.starts_with("shadow") { shadow_packets(&b, &bvh, &camera, 1) } else { camera };
    let start = std::time::Instant::now();
    let hits: usize = if kind == "none" {
        0 // setup only, to subtract from instruction counts
    } else if kind.ends_with('8') {
        packets
            .iter()
            .map(|(r, a, z)| {
                if kind == "shadow8" {
                    bvh.occluded8(r, *a, *z, 0xff).count_ones() as usize
                } else {
                    bvh.intersect8(r, *a, *z, 0xff).iter().filter(|h| h.is_some()).count()
                }
            })
            .sum()
    } else {
        packets
            .iter()
            .flat_map(|(r, a, z)| (0..PACKET_LANES).map(move |j| (r[j], a[j], z[j])))
            .filter(|(r, a, z)| {
                if kind == "shadow" { bvh.occluded(r, *a, *z) } else { bvh.intersect(r, *a, *z).is_some() }
            })
            .count()
    };
    let secs = start.elapsed().as_secs_f64();
    let rays = packets.len() * PACKET_LANES;
    println!("{kind}: {rays} rays, {hits} hits, {:.2} Mrays/s", rays as f64 / secs * 1e-6);
}

//! Shadow cells (`isin_tracer::shadows`) on the shipped scenes: wherever a
//! cell says nothing can block the shadow rays from a shading point to a
//! light, tracing those rays through the BVH must find nothing either; and
//! where it offers an entry node, a walk from there must answer every
//! shadow ray as a walk from the root does.

mod common;

use common::Rng;
use isin_tracer::geometry::Ray;
use isin_tracer::integrator::SurfacePoint;
use isin_tracer::shadows::CellAnswer;
use isin_tracer::{AssetSource, Scene, Vec2, Vec3, load_scene};
use std::path::{Path, PathBuf};

/// The integrator's shadow rays stop this fraction of the way to the light.
const SHADOW_SHORTEN: f32 = 1.0 - 1e-3;

struct Dir(PathBuf);

impl AssetSource for Dir {
    fn read(&mut self, path: &str) -> Result<Vec<u8>, String> {
        std::fs::read(self.0.join(path)).map_err(|e| format!("{path}: {e}"))
    }
}

fn scene(name: &str) -> Scene {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let text = std::fs::read_to_string(dir.join(name)).expect("scene file");
    load_scene(name, &text, &mut Dir(dir)).unwrap_or_else(|e| panic!("{e}"))
}

/// Shading points as the integrator makes them: the camera's view (a grid
/// of pixels) and rays from random points of the scene's box in random
/// directions (walls seen from outside, undersides, reflections).
fn shading_points(scene: &Scene, rng: &mut Rng) -> Vec<(SurfacePoint, bool)> {
    let mut rays = Vec::new();
    for y in 0..48 {
        for x in 0..64 {
            rays.push((scene.camera.ray((x as f32 + 0.5) / 64.0, (y as f32 + 0.5) / 48.0), true));
        }
    }
    for _ in 0..3000 {
        rays.push((Ray::new(rng.in_box(&scene.bounds), rng.unit_vector()), false));
    }
    rays.iter()
        .filter_map(|(ray, camera)| {
            let hit = scene.intersect(ray, 0.0, f32::INFINITY)?;
            Some((SurfacePoint::new(scene, ray, &hit), *camera))
        })
        .collect()
}

/// Checks every clear (point, light) pair against the BVH; returns the
/// number of lookups, of clear ones among the camera's points, and of
/// shadow rays from points that are not clear that the BVH found blocked.
fn check(scene: &Scene, seed: u64) -> (usize, usize, usize, usize) {
    let mut rng = Rng(seed);
    let (mut camera_lookups, mut camera_clear, mut blocked, mut checked) = (0, 0, 0, 0);
    for (sp, camera) in shading_points(scene, &mut rng) {
        let origin = sp.p + sp.ng * sp.eps;
        for (index, light) in scene.lights.iter().enumerate() {
            let clear = scene.shadow_clear(index, origin);
            if camera {
                camera_lookups += 1;
                camera_clear += clear as usize;
            }
            for _ in 0..8 {
                let u = Vec2::new(rng.next_f32(), rng.next_f32());
                let Some(ls) = light.sample(sp.p, u) else { continue };
                if ls.dir.dot(sp.ng) <= 0.0 {
                    continue;
                }
                let hit = scene.occluded(&Ray::new(origin, ls.dir), 0.0, ls.dist * SHADOW_SHORTEN);
                assert!(!(clear && hit), "light {index}: clear cell at {origin:?}, but {ls:?} is blocked");
                checked += clear as usize;
                blocked += hit as usize;
            }
        }
    }
    (camera_lookups, camera_clear, blocked, checked)
}

#[test]
fn clear_cells_never_hide_a_blocked_shadow_ray_in_the_shipped_scenes() {
    for name in ["paper.toml", "cornell.toml"] {
        let scene = scene(name);
        let (lookups, clear, blocked, checked) = check(&scene, 7);
        println!(
            "{name}: {clear} of {lookups} camera lookups clear, {checked} rays checked, {blocked} blocked"
        );
        // The test has teeth: much of the view is clear, and there are
        // shadows elsewhere for a wrong "clear" to hide.
        assert!(clear * 3 > lookups, "{name}: only {clear} of {lookups} camera lookups are clear");
        assert!(checked > 10_000 && blocked > 1_000, "{name}: {checked} checked, {blocked} blocked");
        assert!(scene.shadow_cells_filled() > 100);
    }
}

#[test]
fn entry_nodes_answer_shadow_rays_as_the_whole_tree_does() {
    for name in ["paper.toml", "cornell.toml"] {
        let scene = scene(name);
        let mut rng = Rng(23);
        let (mut entries, mut blocked, mut rays) = (0, 0, 0);
        for (sp, _) in shading_points(&scene, &mut rng) {
            let origin = sp.p + sp.ng * sp.eps;
            for (index, light) in scene.lights.iter().enumerate() {
                let cell = scene.shadow_cell(index, origin);
                if !matches!(cell, CellAnswer::Entry(_)) {
                    continue;
                }
                entries += 1;
                for _ in 0..8 {
                    let u = Vec2::new(rng.next_f32(), rng.next_f32());
                    let Some(ls) = light.sample(sp.p, u) else { continue };
                    let ray = Ray::new(origin, ls.dir);
                    let t_max = ls.dist * SHADOW_SHORTEN;
                    let expected = scene.occluded(&ray, 0.0, t_max);
                    assert_eq!(
                        cell.occluded(&scene.bvh, &ray, 0.0, t_max),
                        expected,
                        "{name}, light {index}, {ray:?}"
                    );
                    rays += 1;
                    blocked += expected as usize;
                }
            }
        }
        println!("{name}: {entries} lookups found an entry node, {rays} rays, {blocked} blocked");
        assert!(entries > 500 && rays > 4_000, "{name}: {entries} entry nodes, {rays} rays");
        assert!(blocked * 10 > rays && blocked < rays, "{name}: {blocked} of {rays} blocked");
    }
}

#[test]
fn cells_fill_the_same_way_on_a_fresh_copy_of_the_scene() {
    let scene = scene("paper.toml");
    let mut rng = Rng(11);
    let points = shading_points(&scene, &mut rng);
    let answers = |s: &Scene| -> Vec<bool> {
        points
            .iter()
            .flat_map(|(sp, _)| (0..s.lights.len()).map(move |l| (sp.p + sp.ng * sp.eps, l)))
            .map(|(o, l)| s.shadow_clear(l, o))
            .collect()
    };
    let first = answers(&scene);
    let copy = scene.clone();
    assert_eq!(copy.shadow_cells_filled(), 0, "a clone starts with empty cells");
    // Filled in the reverse order, the cells give the same answers.
    let mut reversed: Vec<bool> = points
        .iter()
        .rev()
        .flat_map(|(sp, _)| (0..copy.lights.len()).rev().map(move |l| (sp.p + sp.ng * sp.eps, l)))
        .map(|(o, l)| copy.shadow_clear(l, o))
        .collect();
    reversed.reverse();
    assert_eq!(first, reversed);
    assert_eq!(answers(&copy), first);
    assert!(first.iter().any(|&c| c) && first.iter().any(|&c| !c));
}

#[test]
fn points_outside_the_grid_or_beyond_the_lights_are_never_clear() {
    let scene = scene("cornell.toml");
    let far = scene.bounds.max + Vec3::splat(10.0);
    for l in 0..scene.lights.len() {
        assert!(!scene.shadow_clear(l, far));
        assert!(!scene.shadow_clear(l, Vec3::NAN));
    }
    assert!(!scene.shadow_clear(scene.lights.len(), scene.bounds.min));
}

#[test]
fn cells_filled_at_load_answer_as_cells_filled_on_demand() {
    let lazy = scene("paper.toml");
    let eager = lazy.clone();
    eager.fill_shadow_cells();
    let filled = eager.shadow_cells_filled();
    assert!(filled > 1000, "{filled} cells filled");
    let mut rng = Rng(5);
    let points = shading_points(&lazy, &mut rng);
    let mut clear = 0;
    for (sp, _) in &points {
        let origin = sp.p + sp.ng * sp.eps;
        for l in 0..lazy.lights.len() {
            let (a, b) = (lazy.shadow_clear(l, origin), eager.shadow_clear(l, origin));
            assert_eq!(a, b, "light {l} at {origin:?}");
            clear += a as usize;
        }
    }
    assert!(clear > 1000);
    // Nearly every cell a shading point needs was filled at load.
    let more = eager.shadow_cells_filled() - filled;
    assert!(more * 20 < filled, "{more} cells filled after the {filled} filled at load");
}

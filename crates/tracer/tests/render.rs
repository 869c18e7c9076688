//! End-to-end rendering tests: determinism across tilings and thread counts,
//! hard and soft shadows, mirrors, refraction, anti-aliasing — and a picture of
//! the whole feature set written to a PNG for a human to look at.
//!
//! Scenes are built in code (the scene-file loader is tested elsewhere).

use isin_tracer::lights::Light;
use isin_tracer::materials::{Albedo, Material};
use isin_tracer::render::render_frame_stats;
use isin_tracer::scene::{SceneParts, TriangleShading};
use isin_tracer::shapes::Triangle;
use isin_tracer::textures::Texture;
use isin_tracer::{Camera, Frame, RenderSettings, Scene, Tile, Vec2, Vec3, render_frame, render_tile};

/// Accumulates triangles for a test scene.
#[derive(Default)]
struct Builder {
    parts: SceneParts,
}

impl Builder {
    fn material(&mut self, m: Material) -> u32 {
        self.parts.materials.push(m);
        (self.parts.materials.len() - 1) as u32
    }

    fn texture(&mut self, t: Texture) -> u32 {
        self.parts.textures.push(t);
        (self.parts.textures.len() - 1) as u32
    }

    fn tri(&mut self, v: [Vec3; 3], normals: Option<[Vec3; 3]>, uvs: [Vec2; 3], material: u32) {
        let t = Triangle { v };
        let n = t.normal().normalize();
        self.parts.triangles.push(t);
        self.parts.shading.push(TriangleShading { normals: normals.unwrap_or([n; 3]), uvs, material });
    }

    /// A quad p0..p3 (counter-clockwise seen from the front) with UVs
    /// (0,0) (1,0) (1,1) (0,1) scaled by `uv_scale`.
    fn quad(&mut self, p: [Vec3; 4], uv_scale: f32, material: u32) {
        let uv = [Vec2::ZERO, Vec2::new(uv_scale, 0.0), Vec2::splat(uv_scale), Vec2::new(0.0, uv_scale)];
        self.tri([p[0], p[1], p[2]], None, [uv[0], uv[1], uv[2]], material);
        self.tri([p[0], p[2], p[3]], None, [uv[0], uv[2], uv[3]], material);
    }

    /// An axis-aligned box, faces wound outwards.
    fn cuboid(&mut self, min: Vec3, max: Vec3, material: u32) {
        let c = (min + max) * 0.5;
        let corner = |i: u32| {
            Vec3::new(
                if i & 1 == 0 { min.x } else { max.x },
                if i & 2 == 0 { min.y } else { max.y },
                if i & 4 == 0 { min.z } else { max.z },
            )
        };
        for face in [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]] {
            let mut q = face.map(corner);
            let n = (q[1] - q[0]).cross(q[2] - q[0]);
            if n.dot(q[0] - c) < 0.0 {
                q.reverse();
            }
            self.quad(q, 1.0, material);
        }
    }

    /// A UV sphere with smooth vertex normals, wound outwards.
    fn sphere(&mut self, centre: Vec3, r: f32, slices: u32, stacks: u32, material: u32) {
        let point = |i: u32, j: u32| {
            let phi = i as f32 / slices as f32 * std::f32::consts::TAU;
            let theta = j as f32 / stacks as f32 * std::f32::consts::PI;
            Vec3::new(theta.sin() * phi.cos(), theta.cos(), theta.sin() * phi.sin())
        };
        for j in 0..stacks {
            for i in 0..slices {
                let n = [point(i, j), point(i + 1, j), point(i + 1, j + 1), point(i, j + 1)];
                for idx in [[0, 1, 2], [0, 2, 3]] {
                    let mut nn = idx.map(|k| n[k]);
                    let mut v = nn.map(|d| centre + d * r);
                    let t = Triangle { v };
                    if t.area() < 1e-9 {
                        continue; // degenerate at the poles
                    }
                    if t.normal().dot(v[0] + v[1] + v[2] - centre * 3.0) < 0.0 {
                        v.swap(1, 2);
                        nn.swap(1, 2);
                    }
                    self.tri(v, Some(nn), [Vec2::ZERO; 3], material);
                }
            }
        }
    }

    fn build(self, camera: Camera, settings: RenderSettings) -> Scene {
        let mut parts = self.parts;
        parts.camera = camera;
        parts.settings = settings;
        Scene::new(parts)
    }
}

fn grey(a: f32) -> Material {
    Material::Phong {
        albedo: Albedo::Constant(Vec3::splat(a)),
        specular: Vec3::ZERO,
        shininess: 1.0,
        reflectivity: 0.0,
    }
}

/// Fractional image coordinates of world point `q`.
fn project(camera: &Camera, q: Vec3) -> (f32, f32) {
    let (x, y) = (camera.plane_x(), camera.plane_y());
    let n = x.cross(y);
    let d = q - camera.eye;
    let s = (camera.corners[0] - camera.eye).dot(n) / d.dot(n);
    let h = camera.eye + d * s - camera.corners[0];
    (h.dot(x) / x.length_squared(), h.dot(y) / y.length_squared())
}

/// Renders the single pixel that sees world point `q`.
fn pixel_at(scene: &Scene, settings: &RenderSettings, q: Vec3) -> [u8; 3] {
    let (fx, fy) = project(&scene.camera, q);
    let (x, y) = ((fx * settings.width as f32) as u32, (fy * settings.height as f32) as u32);
    assert!(x < settings.width && y < settings.height, "{q:?} is off screen");
    let rgb = render_tile(scene, &scene.camera, settings, Tile { x, y, w: 1, h: 1 });
    [rgb[0], rgb[1], rgb[2]]
}

fn luma(p: [u8; 3]) -> f32 {
    (p[0] as f32 + p[1] as f32 + p[2] as f32) / 3.0
}

/// A floor, a 2 × 2 square occluder at height 2 and one light at (4, 5, 0),
/// seen from the side so the shadow is not hidden behind the occluder.
fn shadow_scene(light: Light, light_samples: u32) -> (Scene, RenderSettings) {
    let mut b = Builder::default();
    let floor = b.material(grey(0.8));
    let occ = b.material(grey(0.5));
    let f = 20.0;
    b.quad(
        [Vec3::new(-f, 0.0, f), Vec3::new(f, 0.0, f), Vec3::new(f, 0.0, -f), Vec3::new(-f, 0.0, -f)],
        1.0,
        floor,
    );
    b.quad(
        [
            Vec3::new(-1.0, 2.0, 1.0),
            Vec3::new(1.0, 2.0, 1.0),
            Vec3::new(1.0, 2.0, -1.0),
            Vec3::new(-1.0, 2.0, -1.0),
        ],
        1.0,
        occ,
    );
    b.parts.lights.push(light);
    let settings = RenderSettings { width: 160, height: 120, spp: 1, light_samples, ..Default::default() };
    let camera =
        Camera::look_at(Vec3::new(-8.0, 10.0, 0.0), Vec3::new(-2.0, 0.0, 0.0), Vec3::Y, 60.0, 4.0 / 3.0);
    (b.build(camera, settings), settings)
}

#[test]
fn point_light_casts_a_hard_shadow() {
    let light = Light::Point { position: Vec3::new(4.0, 5.0, 0.0), intensity: Vec3::splat(60.0) };
    let (scene, settings) = shadow_scene(light, 1);
    // The occluder's shadow on the floor spans x ∈ [−4.33, −1], z ∈ [−1.67, 1.67].
    let shadow = pixel_at(&scene, &settings, Vec3::new(-2.5, 0.0, 0.0));
    let lit = pixel_at(&scene, &settings, Vec3::new(-2.5, 0.0, 3.0));
    let lit2 = pixel_at(&scene, &settings, Vec3::new(-0.5, 0.0, 0.0));
    assert_eq!(shadow, [0, 0, 0], "umbra is black without ambient light");
    assert!(luma(lit) > 50.0 && luma(lit2) > 50.0, "{lit:?} {lit2:?}");
    // Hard: every floor pixel across the shadow edge is either black or lit.
    for i in 0..=20 {
        let x = -1.5 + i as f32 * 0.05;
        let p = pixel_at(&scene, &settings, Vec3::new(x, 0.0, 0.0));
        assert!(p == [0, 0, 0] || luma(p) > 50.0, "x {x}: {p:?}");
    }
}

#[test]
fn area_light_gives_a_penumbra() {
    let (h, y) = (0.5, 5.0);
    // Counter-clockwise seen from below: shines down.
    let light = Light::Area {
        vertices: vec![
            Vec3::new(4.0 - h, y, -h),
            Vec3::new(4.0 + h, y, -h),
            Vec3::new(4.0 + h, y, h),
            Vec3::new(4.0 - h, y, h),
        ],
        radiance: Vec3::splat(60.0),
    };
    let (scene, settings) = shadow_scene(light, 64);
    // Umbra x ∈ [−4, −1.33]; penumbra (−1.33, −0.67) at z = 0; lit beyond.
    let umbra = luma(pixel_at(&scene, &settings, Vec3::new(-2.5, 0.0, 0.0)));
    let lit = luma(pixel_at(&scene, &settings, Vec3::new(-0.3, 0.0, 0.0)));
    assert_eq!(umbra, 0.0);
    assert!(lit > 100.0, "lit {lit}");
    let mut prev = umbra;
    for x in [-1.2, -1.0, -0.8] {
        let p = luma(pixel_at(&scene, &settings, Vec3::new(x, 0.0, 0.0)));
        assert!(p > umbra + 10.0 && p < lit - 10.0, "x {x}: {p} not between {umbra} and {lit}");
        assert!(p > prev, "brightens towards the lit side");
        prev = p;
    }
}

#[test]
fn mirror_shows_the_reflected_object() {
    for (mirror, expect_red) in [(Material::Mirror { tint: Vec3::ONE }, true), (grey(0.5), false)] {
        let mut b = Builder::default();
        let m = b.material(mirror);
        let red = b.material(Material::Emissive { radiance: Vec3::new(1.0, 0.0, 0.0) });
        // Mirror in front of the camera, a red panel behind the camera.
        b.quad(
            [
                Vec3::new(-5.0, -5.0, -5.0),
                Vec3::new(5.0, -5.0, -5.0),
                Vec3::new(5.0, 5.0, -5.0),
                Vec3::new(-5.0, 5.0, -5.0),
            ],
            1.0,
            m,
        );
        b.quad(
            [
                Vec3::new(-5.0, -5.0, 20.0),
                Vec3::new(5.0, -5.0, 20.0),
                Vec3::new(5.0, 5.0, 20.0),
                Vec3::new(-5.0, 5.0, 20.0),
            ],
            1.0,
            red,
        );
        b.parts.ambient = Vec3::splat(0.2);
        b.parts.background = Vec3::new(0.0, 0.0, 1.0);
        let settings = RenderSettings { width: 32, height: 24, ..Default::default() };
        let scene = b.build(Camera::default(), settings);
        let p = pixel_at(&scene, &settings, Vec3::new(0.0, 0.0, -5.0));
        if expect_red {
            assert_eq!(p, [255, 0, 0], "the mirror shows the red panel behind the camera");
        } else {
            assert!(p[0] == p[1] && p[1] == p[2], "a grey wall stays grey: {p:?}");
        }
    }
}

#[test]
fn glass_sphere_refracts_and_inverts_the_background() {
    let mut b = Builder::default();
    let red = b.material(Material::Emissive { radiance: Vec3::new(1.0, 0.0, 0.0) });
    let blue = b.material(Material::Emissive { radiance: Vec3::new(0.0, 0.0, 1.0) });
    let glass = b.material(Material::Dielectric { ior: 1.5, tint: Vec3::ONE });
    let z = -4.0;
    b.quad(
        [
            Vec3::new(-20.0, -20.0, z),
            Vec3::new(0.0, -20.0, z),
            Vec3::new(0.0, 20.0, z),
            Vec3::new(-20.0, 20.0, z),
        ],
        1.0,
        red,
    );
    b.quad(
        [
            Vec3::new(0.0, -20.0, z),
            Vec3::new(20.0, -20.0, z),
            Vec3::new(20.0, 20.0, z),
            Vec3::new(0.0, 20.0, z),
        ],
        1.0,
        blue,
    );
    b.sphere(Vec3::ZERO, 1.0, 64, 32, glass);
    let settings = RenderSettings { width: 64, height: 48, max_depth: 8, ..Default::default() };
    let camera = Camera::look_at(Vec3::new(0.0, 0.0, 20.0), Vec3::ZERO, Vec3::Y, 10.0, 4.0 / 3.0);
    let scene = b.build(camera, settings);
    // Beside the sphere: the background as it is.
    let left = pixel_at(&scene, &settings, Vec3::new(-1.5, 0.0, 0.0));
    assert!(left[0] > 200 && left[2] < 30, "{left:?}");
    // Through the ball lens (focal length 1.5 from its centre) the background
    // 4 units behind is seen mirrored: left of centre shows the blue right half.
    let through_left = pixel_at(&scene, &settings, Vec3::new(-0.3, 0.0, 1.0));
    let through_right = pixel_at(&scene, &settings, Vec3::new(0.3, 0.0, 1.0));
    assert!(through_left[2] > 150 && through_left[0] < 60, "{through_left:?}");
    assert!(through_right[0] > 150 && through_right[2] < 60, "{through_right:?}");
}

#[test]
fn supersampling_anti_aliases_an_edge() {
    // The paper's camera: an 8-pixel-wide image maps pixel 4 to x ∈ [0, 1] on
    // the z = 0 plane. A white panel ends at x = 0.3, inside that pixel.
    let mut b = Builder::default();
    let white = b.material(Material::Emissive { radiance: Vec3::ONE });
    b.quad(
        [
            Vec3::new(-10.0, -10.0, 0.0),
            Vec3::new(0.3, -10.0, 0.0),
            Vec3::new(0.3, 10.0, 0.0),
            Vec3::new(-10.0, 10.0, 0.0),
        ],
        1.0,
        white,
    );
    let mut settings = RenderSettings { width: 8, height: 6, spp: 1, ..Default::default() };
    let scene = b.build(Camera::default(), settings);
    let tile = Tile { x: 3, y: 3, w: 3, h: 1 };
    let one = render_tile(&scene, &scene.camera, &settings, tile);
    assert_eq!(one, vec![255, 255, 255, 0, 0, 0, 0, 0, 0], "one sample per pixel: hard edge");
    settings.spp = 64;
    let many = render_tile(&scene, &scene.camera, &settings, tile);
    assert_eq!(&many[..3], &[255, 255, 255]);
    assert_eq!(&many[6..], &[0, 0, 0]);
    // About 30 % coverage: linear 0.3 is sRGB ≈ 149.
    let edge = many[3];
    assert!(edge > 120 && edge < 175, "edge pixel {edge}");
    assert!(many[3] == many[4] && many[4] == many[5]);
}

/// The full feature set: checker floor to the horizon, mirror sphere, glass
/// sphere, diffuse box, an image-textured panel, a point light and a quad area
/// light with its visible lamp.
fn showcase(width: u32, height: u32, sphere_detail: u32) -> Scene {
    let mut b = Builder::default();
    let checker = b.texture(Texture::Checker {
        even: Vec3::new(0.8, 0.8, 0.75),
        odd: Vec3::new(0.1, 0.12, 0.3),
        scale: 1.0,
    });
    let floor = b.material(Material::Phong {
        albedo: Albedo::Texture { texture: checker, tint: Vec3::ONE },
        specular: Vec3::ZERO,
        shininess: 1.0,
        reflectivity: 0.0,
    });
    let mirror = b.material(Material::Mirror { tint: Vec3::splat(0.9) });
    let glass = b.material(Material::Dielectric { ior: 1.5, tint: Vec3::new(0.95, 1.0, 0.95) });
    let boxm = b.material(Material::Phong {
        albedo: Albedo::Constant(Vec3::new(0.7, 0.25, 0.1)),
        specular: Vec3::splat(0.3),
        shininess: 40.0,
        reflectivity: 0.0,
    });
    // A small procedural image: a 16×16 orange/white grid, sRGB.
    let mut rgba = Vec::new();
    for y in 0..16u32 {
        for x in 0..16u32 {
            let line = x % 8 == 0 || y % 8 == 0;
            rgba.extend_from_slice(if line { &[250, 250, 250, 255] } else { &[230, 120, 30, 255] });
        }
    }
    let image = b.texture(Texture::Image(isin_tracer::textures::MipMap::from_srgb8(16, 16, &rgba)));
    let panel = b.material(Material::Phong {
        albedo: Albedo::Texture { texture: image, tint: Vec3::ONE },
        specular: Vec3::ZERO,
        shininess: 1.0,
        reflectivity: 0.0,
    });
    let lamp = b.material(Material::Emissive { radiance: Vec3::splat(6.0) });

    let f = 300.0;
    b.quad(
        [Vec3::new(-f, 0.0, f), Vec3::new(f, 0.0, f), Vec3::new(f, 0.0, -f), Vec3::new(-f, 0.0, -f)],
        2.0 * f,
        floor,
    );
    b.sphere(Vec3::new(-2.2, 1.0, -0.5), 1.0, 2 * sphere_detail, sphere_detail, mirror);
    b.sphere(Vec3::new(0.3, 0.8, 1.6), 0.8, 2 * sphere_detail, sphere_detail, glass);
    b.cuboid(Vec3::new(1.6, 0.0, -1.6), Vec3::new(3.0, 1.4, -0.2), boxm);
    b.quad(
        [
            Vec3::new(-1.0, 0.0, -3.5),
            Vec3::new(1.0, 0.0, -3.5),
            Vec3::new(1.0, 2.0, -3.5),
            Vec3::new(-1.0, 2.0, -3.5),
        ],
        2.0,
        panel,
    );
    // Area light above the box, facing down, with its visible lamp just above
    // (the shortened shadow rays keep it from shadowing its own samples).
    let (lx, lz, ly, h) = (-0.6, 0.2, 3.4, 0.5);
    let lv = [
        Vec3::new(lx - h, ly, lz - h),
        Vec3::new(lx + h, ly, lz - h),
        Vec3::new(lx + h, ly, lz + h),
        Vec3::new(lx - h, ly, lz + h),
    ];
    b.parts.lights.push(Light::Area { vertices: lv.to_vec(), radiance: Vec3::splat(6.0) });
    b.quad(lv, 1.0, lamp);
    b.parts.lights.push(Light::Point { position: Vec3::new(5.0, 6.0, -4.0), intensity: Vec3::splat(50.0) });
    b.parts.ambient = Vec3::splat(0.05);
    b.parts.background = Vec3::new(0.35, 0.5, 0.8);
    let settings = RenderSettings { width, height, spp: 1, light_samples: 16, max_depth: 6, seed: 7 };
    let camera = Camera::look_at(
        Vec3::new(0.5, 2.2, 8.5),
        Vec3::new(0.0, 0.9, 0.0),
        Vec3::Y,
        50.0,
        width as f32 / height as f32,
    );
    b.build(camera, settings)
}

fn render_in_pool(scene: &Scene, settings: &RenderSettings, threads: usize, tile: u32) -> Frame {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    pool.install(|| render_frame(scene, &scene.camera, settings, tile, &|_| {}))
}

#[test]
fn images_are_identical_across_tilings_and_thread_counts() {
    let scene = showcase(48, 36, 8);
    let settings = RenderSettings { spp: 4, light_samples: 4, ..scene.settings };
    let whole = render_tile(&scene, &scene.camera, &settings, Tile { x: 0, y: 0, w: 48, h: 36 });
    // 7 × 5 tiles: odd sizes, the last column and row clipped.
    let mut tiled = Frame::new(48, 36);
    for y in (0..36).step_by(5) {
        for x in (0..48).step_by(7) {
            let tile = Tile { x, y, w: 7.min(48 - x), h: 5.min(36 - y) };
            tiled.blit(tile, &render_tile(&scene, &scene.camera, &settings, tile));
        }
    }
    assert_eq!(tiled.rgb, whole, "7×5 tiles");
    let one = render_in_pool(&scene, &settings, 1, 16);
    let two = render_in_pool(&scene, &settings, 2, 3);
    assert_eq!(one.rgb, whole, "1 thread");
    assert_eq!(two.rgb, whole, "2 threads");
    // Not trivially identical: the image has content and the seed matters.
    assert!(whole.iter().any(|&b| b != whole[0]));
    let reseeded = render_tile(
        &scene,
        &scene.camera,
        &RenderSettings { seed: 8, ..settings },
        Tile { x: 0, y: 0, w: 48, h: 36 },
    );
    assert_ne!(reseeded, whole, "the seed changes the jitter");
}

#[test]
fn progress_counts_every_pixel_and_rays_are_counted() {
    let scene = showcase(40, 30, 6);
    let done = std::sync::atomic::AtomicU64::new(0);
    let (frame, counts) = render_frame_stats(&scene, &scene.camera, &scene.settings, 9, &|n| {
        done.fetch_add(n, std::sync::atomic::Ordering::Relaxed);
    });
    assert_eq!(done.into_inner(), 40 * 30);
    assert_eq!(frame.rgb.len(), 40 * 30 * 3);
    assert_eq!(counts.primary, 40 * 30);
    assert!(counts.shadow > counts.primary, "point + area light shadow rays");
    assert!(counts.secondary > 0, "mirror and glass rays");
}

/// Renders the showcase to a PNG under the target directory for a human to
/// look at (`ISIN_SHOWCASE=WxH[xSPP]` for another size).
#[test]
fn showcase_picture() {
    let spec = std::env::var("ISIN_SHOWCASE").unwrap_or_else(|_| "160x120x1".into());
    let dims: Vec<u32> = spec.split('x').filter_map(|s| s.parse().ok()).collect();
    let (w, h) = (dims.first().copied().unwrap_or(160), dims.get(1).copied().unwrap_or(120));
    let spp = dims.get(2).copied().unwrap_or(1);
    let scene = showcase(w, h, 24);
    let settings = RenderSettings { spp, ..scene.settings };
    let t = std::time::Instant::now();
    let (frame, counts) = render_frame_stats(&scene, &scene.camera, &settings, 16, &|_| {});
    let secs = t.elapsed().as_secs_f64();
    let path = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("showcase.png");
    image::save_buffer(&path, &frame.rgb, w, h, image::ExtendedColorType::Rgb8).unwrap();
    println!(
        "wrote {} ({} tris, {:.2} s, {} rays, {:.2} Mrays/s)",
        path.display(),
        scene.triangle_count(),
        secs,
        counts.total(),
        counts.total() as f64 / secs / 1e6
    );
    // The sky is at the top, the floor at the bottom.
    let px = |x: u32, y: u32| {
        let i = ((y * w + x) * 3) as usize;
        [frame.rgb[i], frame.rgb[i + 1], frame.rgb[i + 2]]
    };
    let sky = px(w / 2, 0);
    assert!(sky[2] > sky[0], "sky is blue: {sky:?}");
}

#[test]
fn distant_checker_floor_converges_to_the_average_colour() {
    // Lit only by a unit ambient term, a pixel shows the filtered texture itself.
    let mut b = Builder::default();
    let tex = b.texture(Texture::Checker { even: Vec3::ONE, odd: Vec3::ZERO, scale: 4.0 });
    let floor = b.material(Material::Phong {
        albedo: Albedo::Texture { texture: tex, tint: Vec3::ONE },
        specular: Vec3::ZERO,
        shininess: 1.0,
        reflectivity: 0.0,
    });
    let f = 1000.0;
    b.quad(
        [Vec3::new(-f, 0.0, f), Vec3::new(f, 0.0, f), Vec3::new(f, 0.0, -f), Vec3::new(-f, 0.0, -f)],
        2.0 * f,
        floor,
    );
    b.parts.ambient = Vec3::ONE;
    let settings = RenderSettings { width: 96, height: 64, ..Default::default() };
    let camera = Camera::look_at(Vec3::new(0.0, 1.0, 0.0), Vec3::new(0.0, 0.0, -10.0), Vec3::Y, 60.0, 1.5);
    let scene = b.build(camera, settings);
    let frame = render_frame(&scene, &scene.camera, &settings, 16, &|_| {});
    let row = |q: Vec3| (project(&scene.camera, q).1 * settings.height as f32) as usize;
    let mean = isin_tracer::render::encode_srgb8(0.5) as i32;
    // Far away (hundreds of squares per pixel): every pixel of the row is the
    // average grey, not a moiré of black and white.
    let far = row(Vec3::new(0.0, 0.0, -150.0));
    for x in 0..settings.width as usize {
        let v = frame.rgb[(far * settings.width as usize + x) * 3] as i32;
        assert!((v - mean).abs() <= 6, "far pixel {x}: {v} vs {mean}");
    }
    // Close by (several pixels per square) the squares are still crisp.
    let near = row(Vec3::new(0.0, 0.0, -2.13));
    let line = &frame.rgb[near * settings.width as usize * 3..(near + 1) * settings.width as usize * 3];
    assert!(line.iter().any(|&v| v > 240) && line.iter().any(|&v| v < 15), "near row keeps its contrast");
}

/// Throughput of the shading code itself on a scene so small that
/// intersection costs little (run with `--ignored --nocapture`).
#[test]
#[ignore = "timing, not a check"]
fn shading_throughput() {
    let mut b = Builder::default();
    let tex = b.texture(Texture::Checker { even: Vec3::ONE, odd: Vec3::splat(0.2), scale: 1.0 });
    let floor = b.material(Material::Phong {
        albedo: Albedo::Texture { texture: tex, tint: Vec3::ONE },
        specular: Vec3::splat(0.2),
        shininess: 20.0,
        reflectivity: 0.2,
    });
    let boxm = b.material(grey(0.6));
    let f = 50.0;
    b.quad(
        [Vec3::new(-f, 0.0, f), Vec3::new(f, 0.0, f), Vec3::new(f, 0.0, -f), Vec3::new(-f, 0.0, -f)],
        2.0 * f,
        floor,
    );
    b.cuboid(Vec3::new(-1.0, 0.0, -1.0), Vec3::new(1.0, 2.0, 1.0), boxm);
    b.parts.lights.push(Light::Point { position: Vec3::new(3.0, 6.0, 3.0), intensity: Vec3::splat(50.0) });
    b.parts.lights.push(Light::Area {
        vertices: vec![
            Vec3::new(-3.0, 5.0, -0.5),
            Vec3::new(-2.0, 5.0, -0.5),
            Vec3::new(-2.0, 5.0, 0.5),
            Vec3::new(-3.0, 5.0, 0.5),
        ],
        radiance: Vec3::splat(10.0),
    });
    let settings = RenderSettings { width: 320, height: 240, spp: 1, light_samples: 4, ..Default::default() };
    let camera =
        Camera::look_at(Vec3::new(0.0, 3.0, 8.0), Vec3::new(0.0, 0.5, 0.0), Vec3::Y, 50.0, 4.0 / 3.0);
    let scene = b.build(camera, settings);
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        let t = std::time::Instant::now();
        let runs = 5;
        let mut counts = isin_tracer::integrator::RayCounts::default();
        for _ in 0..runs {
            counts = pool.install(|| render_frame_stats(&scene, &scene.camera, &settings, 16, &|_| {})).1;
        }
        let secs = t.elapsed().as_secs_f64() / runs as f64;
        println!(
            "{threads} thread(s): {:.2} ms/frame, {} rays/frame, {:.1} Mrays/s",
            secs * 1e3,
            counts.total(),
            counts.total() as f64 / secs / 1e6
        );
    }
}

#[test]
fn facing_mirrors_with_unbounded_depth_terminate() {
    let mut b = Builder::default();
    let m = b.material(Material::Mirror { tint: Vec3::ONE });
    for z in [-5.0, 15.0] {
        b.quad(
            [
                Vec3::new(-5e3, -5e3, z),
                Vec3::new(5e3, -5e3, z),
                Vec3::new(5e3, 5e3, z),
                Vec3::new(-5e3, 5e3, z),
            ],
            1.0,
            m,
        );
    }
    b.parts.background = Vec3::ONE;
    let settings = RenderSettings { width: 8, height: 6, max_depth: u32::MAX, ..Default::default() };
    let scene = b.build(Camera::default(), settings);
    let (rgb, counts) = isin_tracer::render::render_tile_stats(
        &scene,
        &scene.camera,
        &settings,
        Tile { x: 1, y: 1, w: 2, h: 2 },
    );
    // The ray bounces between the mirrors until the depth cap, then sees black.
    // (The pixels are chosen off the quads' diagonal, the edge shared by their
    // two triangles.)
    assert_eq!(rgb, vec![0; 12]);
    assert_eq!(counts.secondary, 4 * isin_tracer::integrator::MAX_DEPTH_LIMIT as u64);
}

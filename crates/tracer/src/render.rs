//! Tiles and frames: [`render_tile`] is the unit of work the cluster hands out;
//! [`render_frame`] renders a whole image on a rayon thread pool.
//!
//! Pixel `(x, y)` of a `W × H` image averages `spp` camera rays through
//! `camera.ray((x + jx)/W, (y + jy)/H)`: with one sample `(jx, jy)` is the pixel
//! centre (the paper's mapping); with more they are stratified, jittered points
//! of the pixel ([`crate::sampling`]). Each ray carries a texture-filtering cone
//! whose spread is one pixel's angle divided by `⌈√spp⌉`, the side of a
//! sample's stratum. The average (linear RGB) is clamped to `[0, 1]` and
//! encoded with the exact sRGB transfer function to RGB8.
//!
//! The random numbers of a pixel are keyed by the pixel, the sample index and
//! [`RenderSettings::seed`] only, so any tiling on any number of threads or
//! machines produces the same bytes. The `_stats` variants also count the rays
//! traced, for Mrays/s figures.
//!
//! [`render_tile_hdr`] and [`render_frame_hdr`] give the same pixels before
//! that encoding — linear, unclamped floats ([`FrameBuffers`]) — and, when
//! asked, the first-hit albedo, normal and depth passes ([`Passes`]) for
//! denoisers and compositing; the passes cost only what finding the first
//! hit's surface costs, and the beauty's encoding is the RGB8 path's bytes.

use crate::bvh::PACKET_LANES;
use crate::cameras::Camera;
use crate::geometry::Ray;
use crate::integrator::{FirstHit, Integrator, RayCone, RayCounts, SampleId};
use crate::math;
use crate::sampling::{Sampler, ceil_sqrt, stratified_square};
use crate::scene::Scene;
use glam::{Vec2, Vec3, Vec4};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// How to render: resolution, sampling and recursion limits.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RenderSettings {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Camera samples per pixel (stratified, jittered).
    pub spp: u32,
    /// Shadow rays per area light per camera hit (stratified over the light;
    /// fewer behind dim reflections and refractions, see `integrator`).
    pub light_samples: u32,
    /// Maximum recursion depth for mirror and refraction rays.
    pub max_depth: u32,
    /// Seed mixed into every sample's hash.
    pub seed: u64,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self { width: 640, height: 480, spp: 1, light_samples: 4, max_depth: 6, seed: 0 }
    }
}

impl RenderSettings {
    /// These settings at `width` × `height`, where either may be `None` to
    /// follow the other at the settings' aspect ratio (rounded, at least 1
    /// pixel); both `None` keeps the size.
    pub fn resized(self, width: Option<u32>, height: Option<u32>) -> RenderSettings {
        let aspect = self.width.max(1) as f64 / self.height.max(1) as f64;
        let (width, height) = match (width, height) {
            (Some(w), Some(h)) => (w, h),
            (Some(w), None) => (w, ((w as f64 / aspect).round() as u32).max(1)),
            (None, Some(h)) => (((h as f64 * aspect).round() as u32).max(1), h),
            (None, None) => (self.width, self.height),
        };
        RenderSettings { width, height, ..self }
    }
}

/// A rectangle of pixels, `x..x+w` × `y..y+h`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Tile {
    /// Left column.
    pub x: u32,
    /// Top row.
    pub y: u32,
    /// Width in pixels.
    pub w: u32,
    /// Height in pixels.
    pub h: u32,
}

impl Tile {
    /// Splits a `width × height` image into tiles of at most `size × size`,
    /// row by row.
    pub fn grid(width: u32, height: u32, size: u32) -> Vec<Tile> {
        let size = size.max(1);
        let mut tiles = Vec::new();
        for y in (0..height).step_by(size as usize) {
            for x in (0..width).step_by(size as usize) {
                tiles.push(Tile { x, y, w: size.min(width - x), h: size.min(height - y) });
            }
        }
        tiles
    }

    /// Number of pixels.
    pub fn pixel_count(&self) -> usize {
        self.w as usize * self.h as usize
    }
}

/// A rendered image: sRGB-encoded RGB8, row-major, 3 bytes per pixel.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Frame {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width * height * 3` bytes.
    pub rgb: Vec<u8>,
}

/// Why a tile's pixels cannot be copied into a frame.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum BlitError {
    /// The tile reaches outside the frame.
    #[error("tile {tile:?} does not fit in a {width}×{height} frame")]
    OutOfBounds {
        /// The offending tile.
        tile: Tile,
        /// Frame width.
        width: u32,
        /// Frame height.
        height: u32,
    },
    /// The pixel data does not hold `w × h × 3` bytes.
    #[error("tile {tile:?} needs {expected} bytes, got {got}")]
    WrongLength {
        /// The tile.
        tile: Tile,
        /// `w × h × 3`.
        expected: usize,
        /// Bytes supplied.
        got: usize,
    },
}

impl Frame {
    /// Like [`Frame::blit`], but checks the tile and the data first (for tiles
    /// received over the network) and copies nothing when they do not fit.
    pub fn try_blit(&mut self, tile: Tile, rgb: &[u8]) -> Result<(), BlitError> {
        let fits_x = tile.x.checked_add(tile.w).is_some_and(|e| e <= self.width);
        let fits_y = tile.y.checked_add(tile.h).is_some_and(|e| e <= self.height);
        if !fits_x || !fits_y {
            return Err(BlitError::OutOfBounds { tile, width: self.width, height: self.height });
        }
        let expected = tile.pixel_count() * 3;
        if rgb.len() != expected {
            return Err(BlitError::WrongLength { tile, expected, got: rgb.len() });
        }
        self.blit(tile, rgb);
        Ok(())
    }

    /// A black frame.
    pub fn new(width: u32, height: u32) -> Self {
        Self { width, height, rgb: vec![0; width as usize * height as usize * 3] }
    }

    /// Copies a tile's pixels (as returned by [`render_tile`]) into place.
    ///
    /// # Panics
    /// If the tile does not lie inside the frame or `rgb` has the wrong length;
    /// use [`Frame::try_blit`] for tiles that arrive from elsewhere.
    pub fn blit(&mut self, tile: Tile, rgb: &[u8]) {
        let row = tile.w as usize * 3;
        for j in 0..tile.h as usize {
            let dst = ((tile.y as usize + j) * self.width as usize + tile.x as usize) * 3;
            self.rgb[dst..dst + row].copy_from_slice(&rgb[j * row..(j + 1) * row]);
        }
    }
}

/// A rendered image in linear floats, row-major: the beauty (the mean
/// radiance of each pixel's samples, unclamped: what [`Frame`] holds
/// clamped and sRGB-encoded) and, when asked for, the first-hit passes.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameBuffers {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Linear RGB radiance, `width * height` pixels.
    pub beauty: Vec<[f32; 3]>,
    /// The albedo, normal and depth passes, if rendered.
    pub passes: Option<Passes>,
}

/// What camera rays see at their first hits, per pixel ([`FirstHit`], for
/// denoisers and compositing). Albedo and normal are the means over the
/// pixel's samples (a sample that escapes counts as zero), so they are
/// anti-aliased like the beauty and the normal need not be unit length;
/// depth is the nearest of the samples' distances (`+∞` where every
/// sample escapes), not a blend of surfaces in front and behind.
#[derive(Clone, Debug, PartialEq)]
pub struct Passes {
    /// Surface colour in `[0, 1]`, linear RGB.
    pub albedo: Vec<[f32; 3]>,
    /// World-space shading normal, facing the camera.
    pub normal: Vec<[f32; 3]>,
    /// Distance from the eye along the camera ray.
    pub depth: Vec<f32>,
}

impl FrameBuffers {
    /// A black image (zero depth and passes where `passes`; depth `+∞`).
    pub fn new(width: u32, height: u32, passes: bool) -> Self {
        let n = width as usize * height as usize;
        let passes = passes.then(|| Passes {
            albedo: vec![[0.0; 3]; n],
            normal: vec![[0.0; 3]; n],
            depth: vec![f32::INFINITY; n],
        });
        Self { width, height, beauty: vec![[0.0; 3]; n], passes }
    }

    /// Copies a tile's buffers (as returned by [`render_tile_hdr`], with
    /// passes if this frame has them) into place.
    ///
    /// # Panics
    /// If the tile does not lie inside the frame or its buffers do not match it.
    pub fn blit(&mut self, tile: Tile, from: &FrameBuffers) {
        assert_eq!((from.width, from.height), (tile.w, tile.h), "tile buffers of another size");
        let (w, tw) = (self.width as usize, tile.w as usize);
        fn rows<T: Copy>(to: &mut [T], from: &[T], tile: Tile, w: usize, tw: usize) {
            for j in 0..tile.h as usize {
                let dst = (tile.y as usize + j) * w + tile.x as usize;
                to[dst..dst + tw].copy_from_slice(&from[j * tw..(j + 1) * tw]);
            }
        }
        rows(&mut self.beauty, &from.beauty, tile, w, tw);
        if let Some(p) = &mut self.passes {
            let q = from.passes.as_ref().expect("tile rendered without the frame's passes");
            rows(&mut p.albedo, &q.albedo, tile, w, tw);
            rows(&mut p.normal, &q.normal, tile, w, tw);
            rows(&mut p.depth, &q.depth, tile, w, tw);
        }
    }

    /// The beauty as [`render_frame`] writes it: clamped, sRGB-encoded RGB8
    /// ([`encode_srgb8`]).
    pub fn to_frame(&self) -> Frame {
        let rgb = self.beauty.iter().flatten().map(|&c| encode_srgb8_fast(c)).collect();
        Frame { width: self.width, height: self.height, rgb }
    }
}

/// The sRGB opto-electronic transfer function (linear → encoded), exact and
/// deterministic: `12.92·c` below 0.0031308, else `1.055·c^(1/2.4) − 0.055`.
#[inline]
pub fn linear_to_srgb(c: f32) -> f32 {
    if c <= 0.003_130_8 { c * 12.92 } else { 1.055 * math::powf(c, 1.0 / 2.4) - 0.055 }
}

/// Encodes a linear value as an sRGB byte: clamped to `[0, 1]` (NaN → 0),
/// passed through [`linear_to_srgb`] and rounded to nearest. This is the
/// reference definition; the renderer uses the equivalent, faster
/// [`encode_srgb8_fast`].
#[inline]
pub fn encode_srgb8(c: f32) -> u8 {
    let c = if c.is_nan() { 0.0 } else { c.clamp(0.0, 1.0) };
    (linear_to_srgb(c) * 255.0 + 0.5).min(255.0) as u8
}

/// `THRESHOLDS[k - 1]` is the smallest linear value that [`encode_srgb8`] maps
/// to `k` or more, found by bisection over the bit patterns of non-negative
/// floats (whose order is the order of their values).
fn srgb8_thresholds() -> &'static [f32; 255] {
    static TABLE: std::sync::OnceLock<[f32; 255]> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let mut t = [0.0f32; 255];
        for (k, slot) in t.iter_mut().enumerate() {
            let target = (k + 1) as u8;
            let (mut lo, mut hi) = (0u32, 1.0f32.to_bits());
            // Invariant: encode(lo) < target <= encode(hi).
            while hi - lo > 1 {
                let mid = lo + (hi - lo) / 2;
                if encode_srgb8(f32::from_bits(mid)) >= target {
                    hi = mid;
                } else {
                    lo = mid;
                }
            }
            *slot = f32::from_bits(hi);
        }
        t
    })
}

/// Floats sharing the sign, exponent and top seven mantissa bits (the bits
/// above this shift) share a bucket of [`srgb8_buckets`].
const BUCKET_SHIFT: u32 = 16;

/// For each bucket from the one holding the first threshold to the one
/// holding the last: how many thresholds lie at or below the bucket's
/// smallest float (thresholds are positive, so their bit patterns are in
/// value order).
fn srgb8_buckets() -> &'static [u8] {
    static TABLE: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let t = srgb8_thresholds();
        let (first, last) = (t[0].to_bits() >> BUCKET_SHIFT, t[254].to_bits() >> BUCKET_SHIFT);
        (first..=last)
            .map(|b| {
                let start = f32::from_bits(b << BUCKET_SHIFT);
                t.partition_point(|&x| x <= start) as u8
            })
            .collect()
    })
}

/// [`encode_srgb8`] from a table of its 255 thresholds: the same bytes (the
/// reference is monotonic), without a `powf` per channel. The count of
/// thresholds at or below `c` starts from its bucket's (`srgb8_buckets`)
/// and steps over the few thresholds inside the bucket.
#[inline]
pub fn encode_srgb8_fast(c: f32) -> u8 {
    let t = srgb8_thresholds();
    // Also 0 for NaN, negative numbers and −∞; 255 for +∞.
    if c.is_nan() || c < t[0] {
        return 0;
    }
    if c >= t[254] {
        return 255;
    }
    let buckets = srgb8_buckets();
    let first = t[0].to_bits() >> BUCKET_SHIFT;
    let mut k = buckets[((c.to_bits() >> BUCKET_SHIFT) - first) as usize] as usize;
    // A bucket holds at most one threshold past its start (a test checks),
    // so one step without a branch; the loop is a safety net that never runs.
    k += usize::from(t[k] <= c);
    while t[k] <= c {
        k += 1;
    }
    k as u8
}

/// The sub-pixel offset of camera sample `sample` of `spp` for pixel `(x, y)`:
/// the pixel centre when `spp == 1` (the paper's mapping), otherwise a
/// stratified, jittered point (see [`crate::sampling`]).
#[inline]
pub fn pixel_offset(x: u32, y: u32, sample: u32, spp: u32, seed: u64) -> Vec2 {
    if spp <= 1 {
        Vec2::splat(0.5)
    } else {
        stratified_square(sample, spp, &Sampler::pixel(x, y, seed).child(CAMERA_STREAM))
    }
}

/// Sub-stream tag of the camera jitter (the integrator's streams are tagged
/// with the recursion depth, far below this).
const CAMERA_STREAM: u32 = u32::MAX;

/// Renders the pixels of `tile` (which must lie inside the `settings` image):
/// `tile.w * tile.h * 3` bytes of sRGB RGB8, row-major. Bit-identical for a
/// pixel whatever the tiling, thread or machine.
pub fn render_tile(scene: &Scene, camera: &Camera, settings: &RenderSettings, tile: Tile) -> Vec<u8> {
    render_tile_stats(scene, camera, settings, tile).0
}

/// [`render_tile`], also returning how many rays of each kind it traced.
pub fn render_tile_stats(
    scene: &Scene,
    camera: &Camera,
    settings: &RenderSettings,
    tile: Tile,
) -> (Vec<u8>, RayCounts) {
    render_tile_with(scene, camera, settings, tile, &TraceOptions::default())
}

/// Tracing choices that are not part of the scene description: the defaults
/// are what [`render_tile`] uses; the others exist for reference images,
/// benchmarks and tests. None of them changes a pixel except
/// `adaptive_shadows`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TraceOptions {
    /// Trace area-light shadow rays adaptively (see
    /// [`Integrator::with_adaptive_shadows`]); on by default.
    pub adaptive_shadows: bool,
    /// Trace camera rays in packets of a 4×2 block of pixels
    /// ([`crate::bvh::Bvh::intersect8`], the same hits as single rays); on by default.
    pub packets: bool,
    /// Answer shadow rays from the scene's shadow cells where they can
    /// ([`crate::shadows`], the same answers as tracing them); on by default.
    pub shadow_cells: bool,
}

impl Default for TraceOptions {
    fn default() -> Self {
        Self { adaptive_shadows: true, packets: true, shadow_cells: true }
    }
}

/// Pixels of one camera-ray packet: a block `PACKET_W` wide and
/// `PACKET_LANES / PACKET_W` high.
const PACKET_W: u32 = 4;

/// [`render_tile_stats`] with explicit [`TraceOptions`].
pub fn render_tile_with(
    scene: &Scene,
    camera: &Camera,
    settings: &RenderSettings,
    tile: Tile,
    options: &TraceOptions,
) -> (Vec<u8>, RayCounts) {
    let mut out = vec![0u8; tile.pixel_count() * 3];
    let counts = trace_tile::<false>(scene, camera, settings, tile, options, &mut |at, c, _| {
        out[3 * at..3 * at + 3].copy_from_slice(&[
            encode_srgb8_fast(c.x),
            encode_srgb8_fast(c.y),
            encode_srgb8_fast(c.z),
        ]);
    });
    (out, counts)
}

/// The pixels of `tile` as linear floats ([`FrameBuffers`], `tile.w × tile.h`),
/// with the first-hit passes when `passes` is set: the beauty is the value
/// [`render_tile`] encodes, so `render_tile_hdr(…).to_frame().rgb` is
/// `render_tile(…)` byte for byte. Also returns the rays traced.
pub fn render_tile_hdr(
    scene: &Scene,
    camera: &Camera,
    settings: &RenderSettings,
    tile: Tile,
    passes: bool,
) -> (FrameBuffers, RayCounts) {
    let mut out = FrameBuffers::new(tile.w, tile.h, passes);
    let options = TraceOptions::default();
    let counts = if passes {
        let FrameBuffers { beauty, passes, .. } = &mut out;
        let p = passes.as_mut().expect("made with passes");
        trace_tile::<true>(scene, camera, settings, tile, &options, &mut |at, c, first| {
            beauty[at] = c.to_array();
            p.albedo[at] = first.albedo.to_array();
            p.normal[at] = first.normal.to_array();
            p.depth[at] = first.depth;
        })
    } else {
        trace_tile::<false>(scene, camera, settings, tile, &options, &mut |at, c, _| {
            out.beauty[at] = c.to_array()
        })
    };
    (out, counts)
}

/// The passes of a pixel so far: sums of its samples' albedos and normals,
/// the nearest of their depths.
#[derive(Clone, Copy)]
struct PassSums {
    albedo: Vec3,
    normal: Vec3,
    depth: f32,
}

impl PassSums {
    const EMPTY: PassSums = PassSums { albedo: Vec3::ZERO, normal: Vec3::ZERO, depth: f32::INFINITY };

    #[inline]
    fn add(&mut self, f: FirstHit) {
        self.albedo += f.albedo;
        self.normal += f.normal;
        self.depth = self.depth.min(f.depth);
    }

    /// The pixel's passes: the mean albedo and normal, the nearest depth.
    #[inline]
    fn finish(&self, inv_spp: f32) -> FirstHit {
        FirstHit { albedo: self.albedo * inv_spp, normal: self.normal * inv_spp, depth: self.depth }
    }
}

/// Traces the pixels of `tile`, handing each to `put` as (its index in the
/// tile, row-major; its mean linear radiance; its passes, which are
/// [`FirstHit::NOTHING`] unless `PASSES`). Without `PASSES` nothing is
/// traced or computed that the radiance does not need.
fn trace_tile<const PASSES: bool>(
    scene: &Scene,
    camera: &Camera,
    settings: &RenderSettings,
    tile: Tile,
    options: &TraceOptions,
    put: &mut impl FnMut(usize, Vec3, &FirstHit),
) -> RayCounts {
    let mut counts = RayCounts::default();
    let integrator = Integrator::new(scene, settings)
        .with_adaptive_shadows(options.adaptive_shadows)
        .with_shadow_cells(options.shadow_cells);
    let spp = settings.spp.max(1);
    let (w, h) = (settings.width.max(1) as f32, settings.height.max(1) as f32);
    // With several samples each one stands for a stratum ⌈√spp⌉ times smaller
    // than the pixel, and so does its texture-filtering cone.
    let spread = camera.pixel_spread(settings.width) / ceil_sqrt(spp) as f32;
    let cone = RayCone::primary(spread);
    let inv_spp = 1.0 / spp as f32;
    let seed = settings.seed;
    let camera_ray = |x: u32, y: u32, s: u32| {
        let o = pixel_offset(x, y, s, spp, seed);
        camera.ray((x as f32 + o.x) / w, (y as f32 + o.y) / h)
    };
    let mut put = |x: u32, y: u32, sum: Vec3, passes: &PassSums| {
        let at = ((y - tile.y) * tile.w + (x - tile.x)) as usize;
        let first = if PASSES { passes.finish(inv_spp) } else { FirstHit::NOTHING };
        put(at, sum * inv_spp, &first);
    };
    if !options.packets {
        for y in tile.y..tile.y + tile.h {
            for x in tile.x..tile.x + tile.w {
                let pixel = Sampler::pixel(x, y, seed);
                let mut sum = Vec3::ZERO;
                let mut passes = PassSums::EMPTY;
                for s in 0..spp {
                    let sample = SampleId { pixel, index: s };
                    let ray = camera_ray(x, y, s);
                    if PASSES {
                        // What `trace` does, with the hit kept for the passes.
                        let hit = scene.intersect_visible(&ray, 0.0, f32::INFINITY);
                        passes.add(integrator.first_hit(&ray, hit, cone));
                        sum += integrator.trace_hit(&ray, hit, cone, &sample, &mut counts);
                    } else {
                        sum += integrator.trace(&ray, cone, &sample, &mut counts);
                    }
                }
                put(x, y, sum, &passes);
            }
        }
        return counts;
    }
    // Each pixel sums its samples in the same order as above, and a packet
    // finds exactly the single-ray hits, so the bytes are the same.
    let lane_xy = |bx: u32, by: u32, lane: u32| (bx + lane % PACKET_W, by + lane / PACKET_W);
    for by in (tile.y..tile.y + tile.h).step_by((PACKET_LANES as u32 / PACKET_W) as usize) {
        for bx in (tile.x..tile.x + tile.w).step_by(PACKET_W as usize) {
            let mut active = 0u8;
            let mut pixels = [Sampler::pixel(0, 0, 0); PACKET_LANES];
            for lane in 0..PACKET_LANES as u32 {
                let (x, y) = lane_xy(bx, by, lane);
                if x < tile.x + tile.w && y < tile.y + tile.h {
                    active |= 1 << lane;
                    pixels[lane as usize] = Sampler::pixel(x, y, seed);
                }
            }
            let lanes = || (0..PACKET_LANES as u32).filter(move |l| active & (1 << l) != 0);
            let mut sums = [Vec3::ZERO; PACKET_LANES];
            let mut passes = [PassSums::EMPTY; PACKET_LANES];
            for s in 0..spp {
                // Image coordinates of every lane (those past the tile's edge
                // too: their rays are made but not traced), then the rays
                // four at a time.
                let (mut fx, mut fy) = ([0.0f32; PACKET_LANES], [0.0f32; PACKET_LANES]);
                for lane in 0..PACKET_LANES as u32 {
                    let (x, y) = lane_xy(bx, by, lane);
                    let o = pixel_offset(x, y, s, spp, seed);
                    (fx[lane as usize], fy[lane as usize]) = (x as f32 + o.x, y as f32 + o.y);
                }
                let quad = |f: &[f32; PACKET_LANES], k: usize| Vec4::from_slice(&f[4 * k..4 * k + 4]);
                let quads: [[Ray; 4]; PACKET_LANES / 4] =
                    std::array::from_fn(|k| camera.ray4(quad(&fx, k) / w, quad(&fy, k) / h));
                let rays: [Ray; PACKET_LANES] = std::array::from_fn(|j| quads[j / 4][j % 4]);
                let hits =
                    scene.bvh.intersect8(&rays, [0.0; PACKET_LANES], [f32::INFINITY; PACKET_LANES], active);
                if PASSES {
                    for lane in lanes() {
                        let l = lane as usize;
                        passes[l].add(integrator.first_hit(&rays[l], hits[l], cone));
                    }
                }
                let samples = pixels.map(|pixel| SampleId { pixel, index: s });
                let radiance = integrator.trace_packet(&rays, &hits, cone, &samples, active, &mut counts);
                for lane in lanes() {
                    sums[lane as usize] += radiance[lane as usize];
                }
            }
            for lane in lanes() {
                let (x, y) = lane_xy(bx, by, lane);
                put(x, y, sums[lane as usize], &passes[lane as usize]);
            }
        }
    }
    counts
}

/// Renders a whole frame, tiles spread over the current rayon pool; `progress`
/// is called with the number of pixels finished after each tile.
pub fn render_frame(
    scene: &Scene,
    camera: &Camera,
    settings: &RenderSettings,
    tile_size: u32,
    progress: &(dyn Fn(u64) + Sync),
) -> Frame {
    render_frame_stats(scene, camera, settings, tile_size, progress).0
}

/// [`render_frame`], also returning how many rays of each kind were traced.
pub fn render_frame_stats(
    scene: &Scene,
    camera: &Camera,
    settings: &RenderSettings,
    tile_size: u32,
    progress: &(dyn Fn(u64) + Sync),
) -> (Frame, RayCounts) {
    render_frame_with(scene, camera, settings, tile_size, &TraceOptions::default(), progress)
}

/// [`render_frame_stats`] with explicit [`TraceOptions`].
pub fn render_frame_with(
    scene: &Scene,
    camera: &Camera,
    settings: &RenderSettings,
    tile_size: u32,
    options: &TraceOptions,
    progress: &(dyn Fn(u64) + Sync),
) -> (Frame, RayCounts) {
    let tiles = Tile::grid(settings.width, settings.height, tile_size);
    let rendered: Vec<(Tile, Vec<u8>, RayCounts)> = tiles
        .par_iter()
        .map(|&tile| {
            let (rgb, counts) = render_tile_with(scene, camera, settings, tile, options);
            progress(tile.pixel_count() as u64);
            (tile, rgb, counts)
        })
        .collect();
    let mut frame = Frame::new(settings.width, settings.height);
    let mut counts = RayCounts::default();
    for (tile, rgb, c) in &rendered {
        frame.blit(*tile, rgb);
        counts.add(c);
    }
    (frame, counts)
}

/// [`render_frame_stats`] in linear floats, with the first-hit passes when
/// `passes` is set; `on_tile` is called with each tile's buffers as it is
/// finished (on the rendering thread), e.g. to stream them to a viewer.
/// The beauty's [`FrameBuffers::to_frame`] is [`render_frame`]'s frame.
pub fn render_frame_hdr(
    scene: &Scene,
    camera: &Camera,
    settings: &RenderSettings,
    tile_size: u32,
    passes: bool,
    on_tile: &(dyn Fn(Tile, &FrameBuffers) + Sync),
) -> (FrameBuffers, RayCounts) {
    let tiles = Tile::grid(settings.width, settings.height, tile_size);
    let rendered: Vec<(Tile, FrameBuffers, RayCounts)> = tiles
        .par_iter()
        .map(|&tile| {
            let (buffers, counts) = render_tile_hdr(scene, camera, settings, tile, passes);
            on_tile(tile, &buffers);
            (tile, buffers, counts)
        })
        .collect();
    let mut frame = FrameBuffers::new(settings.width, settings.height, passes);
    let mut counts = RayCounts::default();
    for (tile, buffers, c) in &rendered {
        frame.blit(*tile, buffers);
        counts.add(c);
    }
    (frame, counts)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_size_given_on_one_side_keeps_the_aspect() {
        let s = RenderSettings { width: 512, height: 512, ..RenderSettings::default() };
        assert_eq!(s.resized(Some(100), None).height, 100);
        let s = RenderSettings::default(); // 640 × 480
        assert_eq!((s.resized(Some(100), None).width, s.resized(Some(100), None).height), (100, 75));
        assert_eq!(s.resized(None, Some(30)).width, 40);
        assert_eq!(s.resized(Some(7), Some(9)).height, 9);
        assert_eq!(s.resized(None, None), s);
        assert_eq!(s.resized(Some(1), None).height, 1, "never zero");
    }

    /// A floor, a box and a small stick floating above it, lit by a quad lamp:
    /// umbra, penumbra and fully lit floor, seen from above at an angle.
    pub(crate) fn shadow_test_scene() -> Scene {
        use crate::lights::Light;
        use crate::materials::Material;
        use crate::scene::{SceneParts, TriangleShading};
        use crate::shapes::Triangle;
        let mut parts = SceneParts { materials: vec![Material::default()], ..Default::default() };
        let mut quad = |c: [Vec3; 4]| {
            for v in [[c[0], c[1], c[2]], [c[0], c[2], c[3]]] {
                let n = (v[1] - v[0]).cross(v[2] - v[0]).normalize();
                parts.triangles.push(Triangle { v });
                parts.shading.push(TriangleShading { normals: [n; 3], uvs: [Vec2::ZERO; 3], material: 0 });
            }
        };
        let cuboid = |quad: &mut dyn FnMut([Vec3; 4]), lo: Vec3, hi: Vec3| {
            let p = |x: bool, y: bool, z: bool| {
                Vec3::new(
                    if x { hi.x } else { lo.x },
                    if y { hi.y } else { lo.y },
                    if z { hi.z } else { lo.z },
                )
            };
            let (f, t) = (false, true);
            quad([p(f, t, f), p(f, t, t), p(t, t, t), p(t, t, f)]);
            quad([p(f, f, f), p(t, f, f), p(t, f, t), p(f, f, t)]);
            quad([p(f, f, t), p(t, f, t), p(t, t, t), p(f, t, t)]);
            quad([p(f, f, f), p(f, t, f), p(t, t, f), p(t, f, f)]);
            quad([p(f, f, f), p(f, f, t), p(f, t, t), p(f, t, f)]);
            quad([p(t, f, f), p(t, t, f), p(t, t, t), p(t, f, t)]);
        };
        quad([
            Vec3::new(-8.0, 0.0, -8.0),
            Vec3::new(-8.0, 0.0, 8.0),
            Vec3::new(8.0, 0.0, 8.0),
            Vec3::new(8.0, 0.0, -8.0),
        ]);
        cuboid(&mut quad, Vec3::new(-2.0, 0.0, -1.0), Vec3::new(-1.0, 2.0, 1.0));
        cuboid(&mut quad, Vec3::new(1.0, 1.5, -0.1), Vec3::new(1.2, 1.7, 0.1));
        parts.lights.push(Light::Area {
            vertices: vec![
                Vec3::new(-1.0, 5.0, -1.0),
                Vec3::new(1.0, 5.0, -1.0),
                Vec3::new(1.0, 5.0, 1.0),
                Vec3::new(-1.0, 5.0, 1.0),
            ],
            radiance: Vec3::splat(8.0),
        });
        parts.camera = Camera::look_at(Vec3::new(0.0, 9.0, 9.0), Vec3::ZERO, Vec3::Y, 50.0, 4.0 / 3.0);
        parts.settings =
            RenderSettings { width: 96, height: 72, spp: 1, light_samples: 16, ..Default::default() };
        Scene::new(parts)
    }

    #[test]
    fn adaptive_shadows_trace_fewer_rays_and_agree_with_exhaustive_ones() {
        let scene = shadow_test_scene();
        let s = scene.settings;
        let tile = Tile { x: 0, y: 0, w: s.width, h: s.height };
        let exhaustive = TraceOptions { adaptive_shadows: false, ..TraceOptions::default() };
        let (a, ca) = render_tile_with(&scene, &scene.camera, &s, tile, &TraceOptions::default());
        let (e, ce) = render_tile_with(&scene, &scene.camera, &s, tile, &exhaustive);
        assert_eq!((ca.primary, ca.secondary), (ce.primary, ce.secondary));
        assert!(ca.shadow * 2 < ce.shadow, "adaptive {} vs exhaustive {} shadow rays", ca.shadow, ce.shadow);
        // The picture has umbra, penumbra and light.
        let luma: Vec<u32> = e.chunks(3).map(|p| p.iter().map(|&c| c as u32).sum()).collect();
        let max = *luma.iter().max().unwrap();
        let between = luma.iter().filter(|&&l| l > 30 && l + 30 < max).count();
        assert!(luma.contains(&0) && between > 200, "penumbra pixels: {between}");
        // Identical except where an occluder hides the middle of the lamp but
        // none of its corners (under the small stick, a worst case), and not
        // far off there.
        let differ: Vec<u8> = a.iter().zip(&e).map(|(x, y)| x.abs_diff(*y)).filter(|&d| d > 0).collect();
        assert!(differ.len() * 25 < a.len(), "{} of {} bytes differ", differ.len(), a.len());
        assert!(differ.iter().all(|&d| d <= 64), "{differ:?}");
        let mean = differ.iter().map(|&d| d as f32).sum::<f32>() / differ.len().max(1) as f32;
        assert!(mean < 16.0, "mean difference {mean}");
    }

    #[test]
    fn ratio_estimator_is_noise_free_where_lit_and_close_to_a_converged_image() {
        let scene = shadow_test_scene();
        let s = RenderSettings { light_samples: 8, ..scene.settings };
        let tile = Tile { x: 0, y: 0, w: s.width, h: s.height };
        // 1024 samples: above the ratio estimator's limit, the plain average,
        // traced exhaustively.
        let reference = RenderSettings { light_samples: 1024, ..s };
        let exhaustive = TraceOptions { adaptive_shadows: false, ..TraceOptions::default() };
        // Every sample traced, so that only the estimator differs (adaptive
        // tracing's own error is the test above's).
        let (a, _) = render_tile_with(&scene, &scene.camera, &s, tile, &exhaustive);
        let (r, _) = render_tile_with(&scene, &scene.camera, &reference, tile, &exhaustive);
        let diff: Vec<u8> = a.iter().zip(&r).map(|(x, y)| x.abs_diff(*y)).collect();
        let mean = diff.iter().map(|&d| d as f32).sum::<f32>() / diff.len() as f32;
        assert!(mean < 1.0, "mean difference {mean} from the converged image");
        // Penumbrae keep eight samples' noise (a pixel whose eight samples
        // all happen to be blocked is black), rarely and not far.
        let big = diff.iter().filter(|&&d| d > 16).count();
        assert!(big * 100 < diff.len(), "{big} of {} bytes off by more than 16", diff.len());
        assert!(diff.iter().all(|&d| d <= 64), "max difference {:?}", diff.iter().max());
        // In the open (the image's top-right corner: floor far from both
        // occluders) eight samples give the converged value to the byte: the
        // unshadowed diffuse light is exact, not sampled.
        let (w, h) = (s.width as usize, s.height as usize);
        let mut open = 0;
        for y in 0..h / 6 {
            for x in w - w / 6..w {
                let i = 3 * (y * w + x);
                assert!(diff[i..i + 3].iter().all(|&d| d <= 1), "pixel ({x}, {y}) differs");
                open += 1;
            }
        }
        assert!(open > 50);
    }

    #[test]
    fn shadow_cells_trace_fewer_rays_and_render_the_same_bytes() {
        let scene = shadow_test_scene();
        let s = scene.settings;
        let tile = Tile { x: 0, y: 0, w: s.width, h: s.height };
        let traced = TraceOptions { shadow_cells: false, ..TraceOptions::default() };
        for adaptive in [true, false] {
            let on = TraceOptions { adaptive_shadows: adaptive, ..TraceOptions::default() };
            let off = TraceOptions { adaptive_shadows: adaptive, ..traced };
            let (a, ca) = render_tile_with(&scene, &scene.camera, &s, tile, &on);
            let (b, cb) = render_tile_with(&scene, &scene.camera, &s, tile, &off);
            assert!(a == b, "shadow cells change pixels (adaptive: {adaptive})");
            assert_eq!((ca.primary, ca.secondary), (cb.primary, cb.secondary));
            assert!(ca.shadow * 2 < cb.shadow, "{} vs {} shadow rays traced", ca.shadow, cb.shadow);
        }
        assert!(scene.shadow_cells_filled() > 0);
    }

    #[test]
    fn simd_and_scalar_box_tests_render_the_same_bytes() {
        let scene = shadow_test_scene();
        let mut scalar = scene.clone();
        scalar.bvh.set_simd(false);
        assert!(!scalar.bvh.simd_active());
        assert_eq!(scene.bvh.simd_active(), cfg!(target_arch = "x86_64"));
        let s = scene.settings;
        let tile = Tile { x: 0, y: 0, w: s.width, h: s.height };
        let (a, ca) = render_tile_stats(&scene, &scene.camera, &s, tile);
        let (b, cb) = render_tile_stats(&scalar, &scalar.camera, &s, tile);
        assert_eq!(ca, cb);
        assert!(a == b, "SIMD and scalar traversal differ");
        assert!(a.iter().any(|&c| c != a[0]));
    }

    #[test]
    fn linear_buffers_encode_to_the_same_bytes_at_any_tiling_with_or_without_passes() {
        let scene = shadow_test_scene();
        let s = RenderSettings { spp: 4, ..scene.settings };
        let reference = render_frame(&scene, &scene.camera, &s, 32, &|_| {});
        let mut seen = Vec::new();
        for (tile, passes) in [(32, false), (7, true), (96, true)] {
            let tiles = std::sync::atomic::AtomicUsize::new(0);
            let on_tile = |_: Tile, b: &FrameBuffers| {
                assert_eq!(b.passes.is_some(), passes);
                tiles.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            };
            let (hdr, _) = render_frame_hdr(&scene, &scene.camera, &s, tile, passes, &on_tile);
            assert!(hdr.to_frame() == reference, "tile {tile}, passes {passes}: other bytes");
            assert_eq!(tiles.into_inner(), Tile::grid(s.width, s.height, tile).len());
            seen.push(hdr);
        }
        assert_eq!(seen[0].beauty, seen[1].beauty);
        assert!(seen[1] == seen[2], "passes depend on the tiling");
    }

    #[test]
    fn packets_and_single_rays_give_the_same_passes() {
        let scene = shadow_test_scene();
        let s = RenderSettings { spp: 2, ..scene.settings };
        let tile = Tile { x: 5, y: 3, w: 41, h: 29 };
        let run = |packets: bool| {
            let mut out = Vec::new();
            let options = TraceOptions { packets, ..TraceOptions::default() };
            trace_tile::<true>(&scene, &scene.camera, &s, tile, &options, &mut |at, c, f| {
                out.push((at, c, *f))
            });
            out
        };
        let (a, b) = (run(true), run(false));
        assert_eq!(a.len(), tile.pixel_count());
        let sorted = |mut v: Vec<(usize, Vec3, FirstHit)>| {
            v.sort_by_key(|p| p.0);
            v
        };
        assert!(sorted(a) == sorted(b));
    }

    #[test]
    fn passes_record_the_first_hit() {
        let scene = shadow_test_scene();
        let s = scene.settings;
        let (hdr, _) = render_frame_hdr(&scene, &scene.camera, &s, 16, true, &|_, _| {});
        let p = hdr.passes.as_ref().unwrap();
        // The centre pixel looks at the bare floor by the origin (default
        // material, albedo 0.7) from (0, 9, 9).
        let (x, y) = (s.width / 2, s.height / 2);
        let i = (y * s.width + x) as usize;
        assert_eq!(p.normal[i], [0.0, 1.0, 0.0]);
        assert_eq!(p.albedo[i], [0.7; 3]);
        let eye = scene.camera.eye;
        let ray = scene.camera.ray((x as f32 + 0.5) / s.width as f32, (y as f32 + 0.5) / s.height as f32);
        let t = -eye.y / ray.dir.y;
        assert!((p.depth[i] - t).abs() < 1e-3 * t, "depth {} vs {t}", p.depth[i]);
        assert!((t - eye.length()).abs() < 0.5);
        // Pixels that see nothing have no albedo or normal and lie at infinity;
        // every other depth is finite and positive.
        for ((a, n), d) in p.albedo.iter().zip(&p.normal).zip(&p.depth) {
            assert_eq!(*d == f32::INFINITY, *n == [0.0; 3], "depth {d}, normal {n:?}");
            if *d == f32::INFINITY {
                assert_eq!(*a, [0.0; 3]);
            } else {
                assert!(*d > 0.0 && (Vec3::from_array(*n).length() - 1.0).abs() < 1e-4);
            }
        }
    }

    #[test]
    fn spread_tests_pick_the_corners() {
        use crate::integrator::spread_tests;
        let us: Vec<Vec2> =
            (0..9).map(|i| Vec2::new((i % 3) as f32 * 0.4 + 0.1, (i / 3) as f32 * 0.4 + 0.1)).collect();
        // Smallest and largest x + y, then smallest and largest x − y.
        assert_eq!(spread_tests(&us), [0, 8, 6, 2]);
    }

    #[test]
    fn srgb_encoding_endpoints_and_monotonic() {
        assert_eq!(encode_srgb8(0.0), 0);
        assert_eq!(encode_srgb8(1.0), 255);
        assert_eq!(encode_srgb8(-3.0), 0);
        assert_eq!(encode_srgb8(7.0), 255);
        assert_eq!(encode_srgb8(f32::NAN), 0);
        // Linear 0.5 is sRGB 188 (0.7354 × 255 = 187.5…).
        assert_eq!(encode_srgb8(0.5), 188);
        // Linear segment: 0.002 × 12.92 × 255 = 6.59.
        assert_eq!(encode_srgb8(0.002), 7);
        let mut prev = 0.0;
        for i in 0..=10_000 {
            let v = linear_to_srgb(i as f32 / 10_000.0);
            assert!(v >= prev, "monotonic at {i}");
            prev = v;
        }
        // The two segments meet continuously.
        let k = 0.003_130_8f32;
        assert!((linear_to_srgb(k) - linear_to_srgb(k + 1e-7)).abs() < 1e-5);
        // Round trip with the decoder of the texture module.
        for b in 0..=255u8 {
            assert_eq!(encode_srgb8(crate::textures::srgb_to_linear(b as f32 / 255.0)), b);
        }
    }

    #[test]
    fn srgb_buckets_hold_at_most_one_threshold_past_their_start() {
        let t = srgb8_thresholds();
        let first = t[0].to_bits() >> BUCKET_SHIFT;
        for (i, &count) in srgb8_buckets().iter().enumerate() {
            let next = f32::from_bits((first + i as u32 + 1) << BUCKET_SHIFT);
            let inside = t.iter().filter(|&&x| x < next).count() - count as usize;
            assert!(inside <= 1, "bucket {i}: {inside} thresholds");
        }
    }

    #[test]
    fn fast_srgb_encoding_equals_the_reference() {
        let t = srgb8_thresholds();
        for &c in t.iter() {
            for x in [c, f32::from_bits(c.to_bits() - 1), f32::from_bits(c.to_bits() + 1)] {
                assert_eq!(encode_srgb8_fast(x), encode_srgb8(x), "at {x}");
            }
        }
        for i in 0..=200_000 {
            let x = i as f32 / 200_000.0 * 1.1 - 0.05;
            assert_eq!(encode_srgb8_fast(x), encode_srgb8(x), "at {x}");
        }
        for x in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -0.0, 1e-30, 1e30] {
            assert_eq!(encode_srgb8_fast(x), encode_srgb8(x), "at {x}");
        }
    }

    #[test]
    fn try_blit_rejects_tiles_that_do_not_fit() {
        let mut f = Frame::new(4, 3);
        let t = Tile { x: 2, y: 1, w: 2, h: 2 };
        assert_eq!(f.try_blit(t, &[7; 12]), Ok(()));
        assert_eq!(f.rgb[(4 + 2) * 3], 7);
        assert_eq!(f.rgb[0], 0);
        assert!(matches!(f.try_blit(Tile { x: 3, ..t }, &[0; 12]), Err(BlitError::OutOfBounds { .. })));
        assert!(matches!(
            f.try_blit(Tile { x: u32::MAX, ..t }, &[0; 12]),
            Err(BlitError::OutOfBounds { .. })
        ));
        assert!(matches!(f.try_blit(t, &[0; 11]), Err(BlitError::WrongLength { .. })));
    }

    #[test]
    fn tile_grid_covers_the_image_once() {
        let tiles = Tile::grid(23, 17, 5);
        let mut hits = vec![0; 23 * 17];
        for t in &tiles {
            for y in t.y..t.y + t.h {
                for x in t.x..t.x + t.w {
                    hits[(y * 23 + x) as usize] += 1;
                }
            }
        }
        assert!(hits.iter().all(|&h| h == 1));
    }

    #[test]
    fn pixel_offsets_are_centred_for_one_sample_and_stratified_for_more() {
        assert_eq!(pixel_offset(3, 4, 0, 1, 9), Vec2::splat(0.5));
        let mut cells: Vec<(u32, u32)> = (0..4)
            .map(|s| pixel_offset(3, 4, s, 4, 9))
            .map(|o| ((o.x * 2.0) as u32, (o.y * 2.0) as u32))
            .collect();
        cells.sort();
        assert_eq!(cells, vec![(0, 0), (0, 1), (1, 0), (1, 1)]);
    }
}

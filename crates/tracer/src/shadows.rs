//! Shadow cells: what can block a shadow ray, remembered per region of space.
//!
//! Most shadow rays in a room reach their light: they cross the room from a
//! wall or the floor to the lamp and meet nothing, yet each pays a walk down
//! the BVH to prove it. [`ShadowCells`] splits the scene's box into a grid of
//! cubic cells and, per light, asks the BVH once per cell whether anything
//! can block *any* segment from inside the cell to the light (shaft culling,
//! see [`crate::bvh::Shaft`]). Where nothing can — the common case — every
//! shadow ray from that cell to that light is known to reach it without
//! tracing it. Elsewhere a cell keeps an *entry node* ([`crate::bvh::ShaftEntry`]):
//! up to eight subtrees of the BVH that hold every triangle overlapping its
//! shaft, so that its shadow rays skip the upper levels of the tree and the
//! subtrees off to the side, and start their walk there.
//!
//! **Exact.** A cell is clear only when no triangle lies in the shaft of
//! segments from the cell to the light (widened by a margin for rounding),
//! apart from surfaces a ray from the cell provably cannot reach (see
//! `bvh::shaft`), so every answer is the one the BVH gives; pixels do not
//! change. Nor does an answer depend on which thread first filled the cell,
//! so renders stay deterministic.
//!
//! **Filled once per session.** A cell is filled the first time a shading
//! point in it asks, or all cells around surfaces at once
//! ([`ShadowCells::fill_surface_cells`], which a cluster's slaves call when
//! they load a scene, so that each slave does not refill cells for the tiles
//! it happens to get), and then serves every frame: the scene is static while
//! the camera moves. A cell is two bytes (an atomic): unfilled, clear with
//! the index of its set of surface planes in a small per-light table (a room
//! has few distinct ones: the floor, each wall, their corners), or not clear
//! with the index of its entry node (224 bytes, allocated as cells fill), so
//! a light's grid stays in the caches. A 320×240 frame of the paper scene
//! fills about 10,000 cells over its two lights; filling around every surface
//! takes 16,000 (17 ms on one thread, 7 of them building entry nodes).

use crate::bvh::{Bvh, Shaft, ShaftEntry, SurfacePlanes};
use crate::geometry::{Aabb, Ray};
use crate::lights::Light;
use crate::shapes::Triangle;
use glam::Vec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU16, AtomicUsize, Ordering};
use std::sync::{Mutex, OnceLock};

/// Cells a light's grid aims at (the cell size is chosen so that the scene's
/// box holds about this many).
pub const TARGET_CELLS: f32 = 32_768.0;

/// The grid is at least this fine along the scene's longest side.
pub const MIN_CELLS_PER_SIDE: f32 = 32.0;

/// Lights with cells; further lights' shadow rays always traverse the BVH.
pub const MAX_CELL_LIGHTS: usize = 8;

/// Distinct sets of surface planes per light; cells that would need more
/// count as not clear.
pub const MAX_PLANE_SETS: usize = 1024;

/// A cell not filled yet.
const UNFILLED: u16 = 0;
/// A cell that is not clear, without an entry node.
const NOT_CLEAR: u16 = 1;
/// A clear cell holds this plus the index of its plane set.
const FIRST_SET: u16 = 2;
/// A cell that is not clear holds this plus the index of its entry node.
const FIRST_ENTRY: u16 = FIRST_SET + MAX_PLANE_SETS as u16;
/// Entry nodes per light.
const MAX_ENTRIES: usize = (u16::MAX - FIRST_ENTRY) as usize + 1;
/// Entry nodes are stored in chunks of this many, allocated as cells fill.
const ENTRY_CHUNK: usize = 256;

/// The cell around a point, in every light's grid ([`ShadowCells::cell`]).
#[derive(Clone, Copy, Debug, Default)]
pub struct CellIndex(Option<usize>);

/// What a light's shadow cell knows about the shadow rays from a point to
/// the light ([`ShadowCells::lookup`]).
#[derive(Clone, Copy, Debug)]
pub enum CellAnswer<'a> {
    /// Nothing can block them.
    Clear,
    /// Only triangles below this entry node can.
    Entry(&'a ShaftEntry),
    /// Not known: search the whole tree.
    Unknown,
}

impl CellAnswer<'_> {
    /// True for [`CellAnswer::Clear`].
    #[inline(always)]
    pub fn is_clear(&self) -> bool {
        matches!(self, CellAnswer::Clear)
    }

    /// Whether anything blocks `ray` between `t_min` and `t_max`: a shadow
    /// ray from the point this answer was looked up for, stopping short of
    /// the light. [`Bvh::occluded`]'s answer, by the shortest walk the cell
    /// allows.
    #[inline(always)]
    pub fn occluded(&self, bvh: &Bvh, ray: &Ray, t_min: f32, t_max: f32) -> bool {
        match self {
            CellAnswer::Clear => false,
            CellAnswer::Entry(entry) => bvh.occluded_from(entry, ray, t_min, t_max),
            CellAnswer::Unknown => bvh.occluded(ray, t_min, t_max),
        }
    }
}

/// Per-light grids of shadow cells over a scene (see the module docs).
#[derive(Debug, Default)]
pub struct ShadowCells {
    /// Lower corner of the grid.
    origin: Vec3,
    /// Cell edge length and its reciprocal.
    size: f32,
    inv_size: f32,
    /// Cells along each axis.
    dims: [u32; 3],
    /// Rounding margin for shafts (world units).
    shaft_margin: f32,
    /// Rounding margin for the surface planes of lists (world units).
    plane_margin: f32,
    /// One grid per light (the first [`MAX_CELL_LIGHTS`]).
    lights: Vec<LightCells>,
}

/// One light's grid.
#[derive(Debug)]
struct LightCells {
    /// The light's corners (or position): where its shadow rays end.
    points: Vec<Vec3>,
    /// Their bounding box.
    bounds: Aabb,
    /// Per cell: [`UNFILLED`], [`NOT_CLEAR`], or [`FIRST_SET`] + the index
    /// in `sets` of the surfaces left out of a clear cell.
    cells: Vec<AtomicU16>,
    /// The distinct plane sets of clear cells, filled in order.
    sets: Vec<OnceLock<SurfacePlanes>>,
    /// Number of `sets` filled; held while adding one.
    adding: Mutex<usize>,
    /// The entry nodes of cells that are not clear, in chunks of
    /// [`ENTRY_CHUNK`], in the order the cells filled.
    entries: Vec<OnceLock<Box<[OnceLock<ShaftEntry>]>>>,
    /// Number of `entries` slots taken.
    entered: AtomicUsize,
}

impl LightCells {
    fn new(points: Vec<Vec3>, bounds: Aabb, cells: usize) -> Self {
        LightCells {
            points,
            bounds,
            cells: (0..cells).map(|_| AtomicU16::new(UNFILLED)).collect(),
            sets: (0..if cells > 0 { MAX_PLANE_SETS } else { 0 }).map(|_| OnceLock::new()).collect(),
            adding: Mutex::new(0),
            entries: (0..if cells > 0 { MAX_ENTRIES.div_ceil(ENTRY_CHUNK) } else { 0 })
                .map(|_| OnceLock::new())
                .collect(),
            entered: AtomicUsize::new(0),
        }
    }

    /// The cell value for a cell that is not clear, with entry node `entry`
    /// ([`NOT_CLEAR`] when the table is full). Two threads filling the same
    /// cell each store one; either gives the same answers.
    fn value_of_entry(&self, entry: ShaftEntry) -> u16 {
        let slot = self.entered.fetch_add(1, Ordering::Relaxed);
        if slot >= MAX_ENTRIES {
            return NOT_CLEAR;
        }
        let Some(chunk) = self.entries.get(slot / ENTRY_CHUNK) else { return NOT_CLEAR };
        let chunk = chunk.get_or_init(|| (0..ENTRY_CHUNK).map(|_| OnceLock::new()).collect());
        let _ = chunk[slot % ENTRY_CHUNK].set(entry);
        FIRST_ENTRY + slot as u16
    }

    /// The entry node of cell value `value` (at least [`FIRST_ENTRY`]).
    #[inline(always)]
    fn entry(&self, value: u16) -> Option<&ShaftEntry> {
        let slot = (value - FIRST_ENTRY) as usize;
        self.entries.get(slot / ENTRY_CHUNK)?.get()?.get(slot % ENTRY_CHUNK)?.get()
    }

    /// The cell value for a clear cell with surface planes `planes`
    /// ([`NOT_CLEAR`] when the table is full).
    fn value_of(&self, planes: SurfacePlanes) -> u16 {
        // A poisoned lock only means another thread panicked mid-search; the
        // table itself is append-only and stays valid.
        let mut count = self.adding.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(i) = self.sets[..*count].iter().position(|s| s.get() == Some(&planes)) {
            return FIRST_SET + i as u16;
        }
        if *count == self.sets.len() {
            return NOT_CLEAR;
        }
        let _ = self.sets[*count].set(planes);
        *count += 1;
        FIRST_SET + (*count - 1) as u16
    }
}

impl Clone for ShadowCells {
    /// A clone starts with empty cells (they refill on demand, with the same contents).
    fn clone(&self) -> Self {
        ShadowCells {
            lights: self
                .lights
                .iter()
                .map(|l| LightCells::new(l.points.clone(), l.bounds, l.cells.len()))
                .collect(),
            ..*self
        }
    }
}

impl ShadowCells {
    /// Empty grids for the lights of a scene whose triangles lie in `bounds`.
    pub fn new(bounds: &Aabb, lights: &[Light]) -> Self {
        let none = ShadowCells::default();
        if !(bounds.min.is_finite() && bounds.max.is_finite()) || lights.is_empty() {
            return none;
        }
        let extent = (bounds.max - bounds.min).max(Vec3::ZERO);
        let longest = extent.max_element();
        if longest.is_nan() || longest <= 0.0 {
            return none;
        }
        let volume =
            extent.x.max(longest * 1e-3) * extent.y.max(longest * 1e-3) * extent.z.max(longest * 1e-3);
        let size =
            crate::math::powf(volume / TARGET_CELLS, 1.0 / 3.0).max(longest / (4.0 * MIN_CELLS_PER_SIDE));
        let size = size.min(longest / MIN_CELLS_PER_SIDE);
        let dims = [0, 1, 2].map(|a| ((extent[a] / size).ceil() as u32).clamp(1, 1024));
        let count = dims.iter().map(|&d| d as usize).product::<usize>();
        let mut scale = 1.0 + bounds.min.abs().max(bounds.max.abs()).max_element();
        let mut grids = Vec::new();
        for light in lights.iter().take(MAX_CELL_LIGHTS) {
            let points = match light {
                Light::Point { position, .. } => vec![*position],
                Light::Area { vertices, .. } => vertices.clone(),
            };
            let mut lb = Aabb::EMPTY;
            for &p in &points {
                lb.grow(p);
                scale = scale.max(1.0 + p.abs().max_element());
            }
            // Lights that are not finite keep an empty grid (every lookup Unknown).
            let finite = lb.min.is_finite() && lb.max.is_finite();
            grids.push(LightCells::new(points, lb, if finite { count } else { 0 }));
        }
        ShadowCells {
            origin: bounds.min,
            size,
            inv_size: 1.0 / size,
            dims,
            shaft_margin: 1e-5 * scale,
            plane_margin: 2e-6 * scale,
            lights: grids,
        }
    }

    /// What the cell around `origin` knows about shadow rays from `origin`
    /// to light `light` (the index into the scene's lights) that stop short
    /// of the light (see [`Bvh::shaft_clear`]). Fills the cell on first use.
    #[inline(always)]
    pub fn lookup(&self, bvh: &Bvh, light: usize, origin: Vec3) -> CellAnswer<'_> {
        self.lookup_in(bvh, light, self.cell(origin), origin)
    }

    /// The cell containing `origin`, the same for every light's grid (for
    /// [`ShadowCells::lookup_in`]).
    #[inline(always)]
    pub fn cell(&self, origin: Vec3) -> CellIndex {
        CellIndex(self.cell_of(origin))
    }

    /// [`ShadowCells::lookup`] where `cell` is [`ShadowCells::cell`]`(origin)`.
    #[inline(always)]
    pub fn lookup_in(&self, bvh: &Bvh, light: usize, cell: CellIndex, origin: Vec3) -> CellAnswer<'_> {
        let Some(index) = cell.0 else { return CellAnswer::Unknown };
        let Some(grid) = self.lights.get(light) else { return CellAnswer::Unknown };
        let Some(cell) = grid.cells.get(index) else { return CellAnswer::Unknown };
        let mut value = cell.load(Ordering::Acquire);
        if value == UNFILLED {
            value = self.fill(bvh, grid, index);
        }
        if value >= FIRST_ENTRY {
            grid.entry(value).map_or(CellAnswer::Unknown, CellAnswer::Entry)
        } else if value >= FIRST_SET
            && grid.sets[(value - FIRST_SET) as usize].get().is_some_and(|p| p.admit(origin))
        {
            CellAnswer::Clear
        } else {
            CellAnswer::Unknown
        }
    }

    /// True when no shadow ray from `origin` to light `light` can be
    /// blocked ([`ShadowCells::lookup`] finds the cell clear).
    pub fn clear(&self, bvh: &Bvh, light: usize, origin: Vec3) -> bool {
        self.lookup(bvh, light, origin).is_clear()
    }

    /// Index of the cell containing `p`, if `p` lies in the grid.
    #[inline(always)]
    fn cell_of(&self, p: Vec3) -> Option<usize> {
        let rel = (p - self.origin) * self.inv_size;
        // Also false for NaN.
        if !(rel.cmpge(Vec3::ZERO).all()) {
            return None;
        }
        let mut index = 0usize;
        for a in (0..3).rev() {
            let c = rel[a] as u32;
            if c >= self.dims[a] {
                return None;
            }
            index = index * self.dims[a] as usize + c as usize;
        }
        Some(index)
    }

    /// Fills cell `index` of `grid` and returns its value (another thread
    /// may be filling it too; both find the same planes, so either value
    /// gives the same answers).
    #[cold]
    #[inline(never)]
    fn fill(&self, bvh: &Bvh, grid: &LightCells, index: usize) -> u16 {
        let value = match self.shaft(grid, index) {
            Some(shaft) => match bvh.shaft_clear(&shaft, &grid.points, self.plane_margin) {
                Some(planes) => grid.value_of(planes),
                None => bvh.shaft_entry(&shaft).map_or(NOT_CLEAR, |e| grid.value_of_entry(e)),
            },
            None => NOT_CLEAR,
        };
        // Release: the plane set or entry node is in its table before the
        // cell points at it.
        grid.cells[index].store(value, Ordering::Release);
        value
    }

    /// The shaft of segments from cell `index` to `grid`'s light.
    fn shaft(&self, grid: &LightCells, index: usize) -> Option<Shaft> {
        let (nx, ny) = (self.dims[0] as usize, self.dims[1] as usize);
        let c = Vec3::new((index % nx) as f32, ((index / nx) % ny) as f32, (index / (nx * ny)) as f32);
        // The cell, widened so that points `cell_of` rounds into it lie inside.
        let lo = self.origin + c * self.size - Vec3::splat(self.shaft_margin);
        let hi = self.origin + (c + Vec3::ONE) * self.size + Vec3::splat(self.shaft_margin);
        Shaft::between(&Aabb { min: lo, max: hi }, &grid.bounds, self.shaft_margin)
    }

    /// Fills, in parallel, every light's cells that a triangle's box
    /// overlaps — where shading points lie — so that a session's frames do
    /// not pay for them (the cells a shading point finds unfilled, e.g. just
    /// off a surface across a cell boundary, still fill on demand). Each
    /// process of a cluster fills its own; doing it at load keeps every
    /// slave's frames free of it.
    pub fn fill_surface_cells(&self, bvh: &Bvh, triangles: &[Triangle]) {
        let count = self.lights.iter().map(|g| g.cells.len()).max().unwrap_or(0);
        if count == 0 {
            return;
        }
        let mut marked = vec![false; count];
        let coord = |p: Vec3| ((p - self.origin) * self.inv_size).max(Vec3::ZERO).min(self.max_coord());
        for t in triangles {
            let b = t.bounds();
            let (lo, hi) = (coord(b.min), coord(b.max));
            if !(lo.is_finite() && hi.is_finite()) {
                continue;
            }
            let (lo, hi) = (lo.as_uvec3(), hi.as_uvec3());
            for z in lo.z..=hi.z {
                for y in lo.y..=hi.y {
                    let row = (z as usize * self.dims[1] as usize + y as usize) * self.dims[0] as usize;
                    marked[row + lo.x as usize..=row + hi.x as usize].fill(true);
                }
            }
        }
        let cells: Vec<usize> = (0..count).filter(|&i| marked[i]).collect();
        for grid in self.lights.iter().filter(|g| !g.cells.is_empty()) {
            cells.par_iter().for_each(|&i| {
                if grid.cells[i].load(Ordering::Acquire) == UNFILLED {
                    self.fill(bvh, grid, i);
                }
            });
        }
    }

    /// The largest cell coordinates, as floats.
    fn max_coord(&self) -> Vec3 {
        Vec3::new(self.dims[0] as f32 - 1.0, self.dims[1] as f32 - 1.0, self.dims[2] as f32 - 1.0)
    }

    /// Number of cells filled so far, over all lights (for statistics).
    pub fn filled(&self) -> usize {
        self.lights
            .iter()
            .map(|g| g.cells.iter().filter(|c| c.load(Ordering::Relaxed) != UNFILLED).count())
            .sum()
    }
}

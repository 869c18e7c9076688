//! Meshes as `../shared/anchors/embree/embree_bench.c` reads them, shared by
//! the tracer bench and the `bvh_build` example so both build the triangles
//! Embree is measured on.

use isin_tracer::Vec3;
use isin_tracer::geometry::Aabb;
use isin_tracer::shapes::Triangle;
use std::path::Path;

/// A mesh as the Embree benchmark sees it: every `v` line and every `f` line
/// (polygons fanned), plus the bounds of all vertices.
pub struct BenchMesh {
    /// Triangles in file order.
    pub tris: Vec<Triangle>,
    /// Bounds of every vertex in the file (used or not), as Embree computes them.
    pub bounds: Aabb,
}

/// Loads an OBJ the way `embree_bench.c` does (`v x y z`, `f` with `/vt/vn`
/// suffixes and negative indices, fanned), so both see the same triangles in
/// the same order; faces with out-of-range indices are skipped.
pub fn load_mesh(path: &Path) -> Option<BenchMesh> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) => {
            println!("skipping {}: {e}", path.display());
            return None;
        }
    };
    let mut verts: Vec<Vec3> = Vec::new();
    let mut tris = Vec::new();
    let mut bounds = Aabb::EMPTY;
    for line in text.lines() {
        let mut it = line.split_whitespace();
        match it.next() {
            Some("v") => {
                let c: Vec<f32> = it.take(3).filter_map(|x| x.parse().ok()).collect();
                if let [x, y, z] = c[..] {
                    let v = Vec3::new(x, y, z);
                    bounds = bounds.union(&Aabb { min: v, max: v });
                    verts.push(v);
                }
            }
            Some("f") => {
                let idx: Vec<Option<Vec3>> = it
                    .map_while(|w| w.split('/').next()?.parse::<i64>().ok())
                    .map(|i| {
                        let i = if i < 0 { verts.len() as i64 + i } else { i - 1 };
                        usize::try_from(i).ok().and_then(|i| verts.get(i).copied())
                    })
                    .collect();
                for k in 1..idx.len().saturating_sub(1) {
                    if let (Some(a), Some(b), Some(c)) = (idx[0], idx[k], idx[k + 1]) {
                        tris.push(Triangle { v: [a, b, c] });
                    }
                }
            }
            _ => {}
        }
    }
    Some(BenchMesh { tris, bounds })
}

/// Splits every triangle 1 → 4 at its edge midpoints, in `embree_bench.c`'s
/// order: `(a, ab, ca)`, `(ab, b, bc)`, `(ca, bc, c)`, `(ab, bc, ca)`.
pub fn subdivide(tris: &[Triangle]) -> Vec<Triangle> {
    let mut out = Vec::with_capacity(tris.len() * 4);
    for t in tris {
        let [a, b, c] = t.v;
        let mid = |p: Vec3, q: Vec3| (p + q) * 0.5;
        let (ab, bc, ca) = (mid(a, b), mid(b, c), mid(c, a));
        out.extend_from_slice(&[
            Triangle { v: [a, ab, ca] },
            Triangle { v: [ab, b, bc] },
            Triangle { v: [ca, bc, c] },
            Triangle { v: [ab, bc, ca] },
        ]);
    }
    out
}

//! Midpoint subdivision of meshes, for the `subdivide = N` object option:
//! every triangle becomes four per level (the three edge midpoints cut it),
//! so a level multiplies the triangle count by 4 without changing the shape.
//! It exists to make big test meshes (the 1.6M-triangle dragon is the 100k
//! one subdivided twice) from the shared real ones.
//!
//! The split order is the one of the Embree reference benchmark
//! (`../shared/anchors/embree/embree_bench.c`): triangle `(a, b, c)` with
//! midpoints `ab`, `bc`, `ca` becomes `(a, ab, ca)`, `(ab, b, bc)`,
//! `(ca, bc, c)`, `(ab, bc, ca)`, all with the parent's winding. Midpoints are
//! shared between the two triangles of an edge; normals and texture
//! coordinates are interpolated (normals renormalised).

use crate::meshes::Mesh;
use std::collections::HashMap;

/// Most subdivision levels an object may ask for (4⁶ = 4096 triangles per
/// original one).
pub const MAX_SUBDIVIDE: u32 = 6;

/// `mesh` subdivided `levels` times. Indices must be in range (the caller
/// checks them).
pub fn subdivide(mesh: &Mesh, levels: u32) -> Mesh {
    let mut m = mesh.clone();
    for _ in 0..levels {
        m = subdivide_once(&m);
    }
    m
}

/// One level of midpoint subdivision.
fn subdivide_once(m: &Mesh) -> Mesh {
    let n = m.positions.len();
    let (has_normals, has_uvs, has_colours) = (m.normals.len() == n, m.uvs.len() == n, m.colours.len() == n);
    let has_uvs1 = m.uvs1.len() == n;
    let mut out = Mesh {
        positions: m.positions.clone(),
        normals: if has_normals { m.normals.clone() } else { Vec::new() },
        uvs: if has_uvs { m.uvs.clone() } else { Vec::new() },
        indices: Vec::with_capacity(m.indices.len() * 4),
        colours: if has_colours { m.colours.clone() } else { Vec::new() },
        uvs1: if has_uvs1 { m.uvs1.clone() } else { Vec::new() },
    };
    let mut midpoints: HashMap<(u32, u32), u32> = HashMap::with_capacity(m.indices.len() * 3 / 2);
    let mut midpoint = |out: &mut Mesh, a: u32, b: u32| -> u32 {
        let key = (a.min(b), a.max(b));
        *midpoints.entry(key).or_insert_with(|| {
            let (i, j) = (key.0 as usize, key.1 as usize);
            let index = out.positions.len() as u32;
            out.positions.push((m.positions[i] + m.positions[j]) * 0.5);
            if has_normals {
                out.normals.push((m.normals[i] + m.normals[j]).normalize_or_zero());
            }
            if has_uvs {
                out.uvs.push((m.uvs[i] + m.uvs[j]) * 0.5);
            }
            if has_colours {
                out.colours.push((m.colours[i] + m.colours[j]) * 0.5);
            }
            if has_uvs1 {
                out.uvs1.push((m.uvs1[i] + m.uvs1[j]) * 0.5);
            }
            index
        })
    };
    for &[a, b, c] in &m.indices {
        let ab = midpoint(&mut out, a, b);
        let bc = midpoint(&mut out, b, c);
        let ca = midpoint(&mut out, c, a);
        out.indices.extend_from_slice(&[[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Vec2, Vec3};

    fn area(m: &Mesh) -> f32 {
        m.indices
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| m.positions[i as usize]);
                (b - a).cross(c - a).length() * 0.5
            })
            .sum()
    }

    #[test]
    fn each_level_quadruples_triangles_and_keeps_area_and_winding() {
        let mesh = crate::meshes::uv_sphere(12, 6);
        for levels in 0..3 {
            let s = subdivide(&mesh, levels);
            assert_eq!(s.indices.len(), mesh.indices.len() * 4usize.pow(levels));
            assert!((area(&s) - area(&mesh)).abs() < 1e-4 * area(&mesh), "level {levels}");
            assert_eq!(s.normals.len(), s.positions.len());
            assert_eq!(s.uvs.len(), s.positions.len());
        }
        // Children face the way their parent does.
        let s = subdivide(&mesh, 1);
        for (k, parent) in mesh.indices.iter().enumerate() {
            let face = |m: &Mesh, t: &[u32; 3]| {
                let [a, b, c] = t.map(|i| m.positions[i as usize]);
                (b - a).cross(c - a)
            };
            let np = face(&mesh, parent);
            if np.length() == 0.0 {
                continue;
            }
            for child in &s.indices[4 * k..4 * k + 4] {
                assert!(face(&s, child).dot(np) > 0.0);
            }
        }
    }

    #[test]
    fn midpoints_are_shared_and_attributes_interpolated() {
        // Two triangles sharing the edge 1–2 of a unit square.
        let mesh = Mesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Z, Vec3::new(1.0, 0.0, 1.0)],
            normals: vec![Vec3::Y, Vec3::Y, Vec3::X, Vec3::X],
            uvs: vec![Vec2::ZERO, Vec2::X, Vec2::Y, Vec2::ONE],
            indices: vec![[0, 2, 1], [1, 2, 3]],
            colours: vec![Vec3::X, Vec3::Y, Vec3::Y, Vec3::Z],
            uvs1: Vec::new(),
        };
        let s = subdivide(&mesh, 1);
        // 4 corners + 5 distinct edges.
        assert_eq!(s.positions.len(), 9);
        assert_eq!(s.indices.len(), 8);
        let shared = s.positions.iter().position(|&p| p == Vec3::new(0.5, 0.0, 0.5)).unwrap();
        assert_eq!(s.uvs[shared], Vec2::splat(0.5));
        assert_eq!(s.colours[shared], Vec3::Y, "midway between two green vertices");
        assert_eq!(s.colours.len(), s.positions.len());
        assert!((s.normals[shared] - Vec3::new(1.0, 1.0, 0.0).normalize()).length() < 1e-6);
        assert!(s.normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-6));
    }

    #[test]
    fn split_order_matches_the_embree_benchmark() {
        let mesh = Mesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            indices: vec![[0, 1, 2]],
            ..Mesh::default()
        };
        let s = subdivide(&mesh, 1);
        let tri = |k: usize| s.indices[k].map(|i| s.positions[i as usize]);
        let (a, b, c) = (Vec3::ZERO, Vec3::X, Vec3::Y);
        let (ab, bc, ca) = ((a + b) * 0.5, (b + c) * 0.5, (c + a) * 0.5);
        assert_eq!(tri(0), [a, ab, ca]);
        assert_eq!(tri(1), [ab, b, bc]);
        assert_eq!(tri(2), [ca, bc, c]);
        assert_eq!(tri(3), [ab, bc, ca]);
        assert!(s.normals.is_empty() && s.uvs.is_empty());
    }
}

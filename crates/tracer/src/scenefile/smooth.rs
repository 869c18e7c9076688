//! Vertex normals for meshes that have none: smooth shading by smoothing
//! group and crease angle.
//!
//! Every corner of a triangle gets the sum of the normals of the triangles
//! that touch its position, belong to its smoothing group and bend away from
//! it by at most the crease angle, each weighted by its angle at that corner
//! (so how a face is split into triangles does not matter); group 0 is flat. The sums
//! run in triangle order, so the normals are the same bytes on every machine.

use crate::meshes::Mesh;
use glam::Vec3;
use std::collections::HashMap;

/// Default crease angle of `smooth = true`, degrees.
pub const DEFAULT_SMOOTH_ANGLE: f32 = 30.0;

/// The angle of triangle `t` of `mesh` at its corner at `p`.
fn corner_angle(mesh: &Mesh, t: usize, p: Vec3) -> f32 {
    let v = mesh.indices[t].map(|i| mesh.positions[i as usize]);
    let k = v.iter().position(|&q| q == p).unwrap_or(0);
    let (a, b) = ((v[(k + 1) % 3] - v[k]).normalize_or_zero(), (v[(k + 2) % 3] - v[k]).normalize_or_zero());
    crate::math::acos(a.dot(b).clamp(-1.0, 1.0))
}

/// `mesh` (which must have in-range indices) with vertex normals: one vertex
/// per triangle corner, normals smoothed across triangles of the same group
/// (`groups`, one per triangle; `None` puts all in group 1) whose face
/// normals differ by at most `max_angle` degrees. Degenerate triangles get
/// no say in their neighbours' normals.
pub fn smooth_normals(mesh: &Mesh, groups: Option<&[u32]>, max_angle: f32) -> Mesh {
    let n = mesh.positions.len();
    let group = |t: usize| groups.and_then(|g| g.get(t).copied()).unwrap_or(1);
    let units: Vec<Vec3> = mesh
        .indices
        .iter()
        .map(|&[a, b, c]| {
            let p = |i: u32| mesh.positions[i as usize];
            (p(b) - p(a)).cross(p(c) - p(a)).normalize_or_zero()
        })
        .collect();
    // Triangles around each position (by its bits: welds split vertices).
    let key = |p: Vec3| p.to_array().map(f32::to_bits);
    let mut around: HashMap<[u32; 3], Vec<u32>> = HashMap::with_capacity(n);
    for (t, idx) in mesh.indices.iter().enumerate() {
        for &i in idx {
            let list = around.entry(key(mesh.positions[i as usize])).or_default();
            if list.last() != Some(&(t as u32)) {
                list.push(t as u32);
            }
        }
    }
    let cos_max = crate::math::cos(max_angle.clamp(0.0, 180.0).to_radians()) - 1e-6;
    let has_uvs = mesh.uvs.len() == n;
    let has_colours = mesh.colours.len() == n;
    let has_uvs1 = mesh.uvs1.len() == n;
    let mut out = Mesh::default();
    for (t, idx) in mesh.indices.iter().enumerate() {
        for &i in idx {
            let p = mesh.positions[i as usize];
            let own = units[t];
            let normal = if group(t) == 0 || own == Vec3::ZERO {
                own
            } else {
                let mut sum = Vec3::ZERO;
                for &u in &around[&key(p)] {
                    let u = u as usize;
                    if group(u) == group(t) && units[u] != Vec3::ZERO && units[u].dot(own) >= cos_max {
                        sum += units[u] * corner_angle(mesh, u, p);
                    }
                }
                sum.normalize_or(own)
            };
            out.positions.push(p);
            out.normals.push(normal);
            if has_uvs {
                out.uvs.push(mesh.uvs[i as usize]);
            }
            if has_colours {
                out.colours.push(mesh.colours[i as usize]);
            }
            if has_uvs1 {
                out.uvs1.push(mesh.uvs1[i as usize]);
            }
        }
        let k = out.positions.len() as u32;
        out.indices.push([k - 3, k - 2, k - 1]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit cube with split vertices and no normals (the built-in one's positions).
    fn flat_cube() -> Mesh {
        let c = crate::meshes::cuboid();
        Mesh { positions: c.positions, indices: c.indices, uvs: c.uvs, ..Mesh::default() }
    }

    #[test]
    fn a_cube_keeps_its_edges_under_the_crease_angle_and_rounds_over_it() {
        let cube = flat_cube();
        let creased = smooth_normals(&cube, None, 30.0);
        for (t, idx) in creased.indices.iter().enumerate() {
            let [a, b, c] = idx.map(|i| creased.positions[i as usize]);
            let face = (b - a).cross(c - a).normalize();
            for &i in idx {
                assert!(
                    (creased.normals[i as usize] - face).length() < 1e-6,
                    "triangle {t}: 90° edges stay sharp"
                );
            }
        }
        let round = smooth_normals(&cube, None, 180.0);
        for (p, n) in round.positions.iter().zip(&round.normals) {
            // Each corner: the mean of its three faces' normals, along the diagonal.
            assert!((*n - p.normalize()).length() < 1e-5, "{p} → {n}");
        }
    }

    #[test]
    fn smoothing_groups_keep_other_groups_and_group_zero_apart() {
        let cube = flat_cube();
        let t = cube.indices.len();
        // All in group 1 but the first two triangles (one face) in group 0.
        let groups: Vec<u32> = (0..t).map(|i| if i < 2 { 0 } else { 1 }).collect();
        let s = smooth_normals(&cube, Some(&groups), 180.0);
        let corner = |t: usize, k: usize| s.normals[s.indices[t][k] as usize];
        let face = |t: usize| {
            let [a, b, c] = s.indices[t].map(|i| s.positions[i as usize]);
            (b - a).cross(c - a).normalize()
        };
        for k in 0..3 {
            assert!((corner(0, k) - face(0)).length() < 1e-6, "group 0 is flat");
            assert!((corner(5, k) - face(5)).length() > 0.1, "group 1 rounds");
            // Group 1 leaves the group-0 face out of its corners' sums.
            assert!(corner(5, k).dot(face(0)) < 1e-6, "{}", corner(5, k));
        }
        assert_eq!(s.uvs.len(), s.positions.len());
        assert!(s.normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-5));
    }
}

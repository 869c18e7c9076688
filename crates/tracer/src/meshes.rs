//! Built-in triangle primitives (quad, box, UV sphere, cylinder) as indexed
//! meshes with normals and texture coordinates, and the affine transforms that
//! place meshes in the world.
//!
//! Every primitive is centred on the origin and fits in the cube `[-½, ½]³`, so
//! a scale is its size. Triangles are counter-clockwise seen from outside, and
//! texture coordinates follow the glTF convention: (0, 0) is the top-left of an
//! image and `v` grows downwards.

use crate::math;
use glam::{Mat3, Mat4, Vec2, Vec3};
use std::f32::consts::PI;

/// An indexed triangle mesh.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Unit vertex normals, parallel to `positions`; empty for a flat-shaded
    /// mesh (each triangle then uses its face normal).
    pub normals: Vec<Vec3>,
    /// Texture coordinates, parallel to `positions`; empty when the mesh has none.
    pub uvs: Vec<Vec2>,
    /// Triangles as vertex indices, counter-clockwise seen from the front.
    pub indices: Vec<[u32; 3]>,
    /// Vertex colours (linear RGB), parallel to `positions`; empty when the
    /// mesh has none.
    pub colours: Vec<Vec3>,
    /// A second set of texture coordinates (glTF `TEXCOORD_1`), parallel to
    /// `positions`; empty when the mesh has none.
    pub uvs1: Vec<Vec2>,
}

impl Mesh {
    fn vertex(&mut self, p: Vec3, n: Vec3, uv: Vec2) -> u32 {
        self.positions.push(p);
        self.normals.push(n);
        self.uvs.push(uv);
        (self.positions.len() - 1) as u32
    }

    /// Adds triangle `i`, ordered so that it faces along `n`.
    fn triangle_facing(&mut self, [a, b, c]: [u32; 3], n: Vec3) {
        let p = |i: u32| self.positions[i as usize];
        let face = (p(b) - p(a)).cross(p(c) - p(a));
        self.indices.push(if face.dot(n) >= 0.0 { [a, b, c] } else { [a, c, b] });
    }

    /// Adds a flat square face of side 1 centred at `n / 2`, facing `n`, with
    /// `u` growing along `right` and `v` along `down`.
    fn face(&mut self, n: Vec3, right: Vec3, down: Vec3) {
        let c = n * 0.5;
        let corner = |s: f32, t: f32| c + right * (s - 0.5) + down * (t - 0.5);
        let ids = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
            .map(|(s, t)| self.vertex(corner(s, t), n, Vec2::new(s, t)));
        self.triangle_facing([ids[0], ids[1], ids[2]], n);
        self.triangle_facing([ids[0], ids[2], ids[3]], n);
    }

    /// The mesh with every vertex transformed by `t` (normals by its inverse
    /// transpose, renormalised). A mirroring transform reverses the winding so
    /// triangles keep facing outwards.
    pub fn transformed(&self, t: &Transform) -> Mesh {
        let normal_matrix = t.normal_matrix();
        let indices = if t.flips_winding() {
            self.indices.iter().map(|&[a, b, c]| [a, c, b]).collect()
        } else {
            self.indices.clone()
        };
        Mesh {
            positions: self.positions.iter().map(|&p| t.point(p)).collect(),
            normals: self.normals.iter().map(|&n| (normal_matrix * n).normalize_or_zero()).collect(),
            uvs: self.uvs.clone(),
            indices,
            colours: self.colours.clone(),
            uvs1: self.uvs1.clone(),
        }
    }
}

/// The unit square in the XZ plane (`-½ ≤ x, z ≤ ½`), facing +Y; `u` along +X,
/// `v` along +Z.
pub fn quad() -> Mesh {
    let mut m = Mesh::default();
    m.face(Vec3::Y, Vec3::X, Vec3::Z);
    for p in &mut m.positions {
        p.y = 0.0;
    }
    m
}

/// The unit cube with flat faces, each with its own 0..1 texture coordinates,
/// upright when seen from outside (side faces have `v` pointing down).
pub fn cuboid() -> Mesh {
    let mut m = Mesh::default();
    m.face(Vec3::Z, Vec3::X, Vec3::NEG_Y);
    m.face(Vec3::NEG_Z, Vec3::NEG_X, Vec3::NEG_Y);
    m.face(Vec3::X, Vec3::NEG_Z, Vec3::NEG_Y);
    m.face(Vec3::NEG_X, Vec3::Z, Vec3::NEG_Y);
    m.face(Vec3::Y, Vec3::X, Vec3::Z);
    m.face(Vec3::NEG_Y, Vec3::X, Vec3::NEG_Z);
    m
}

/// A UV sphere of diameter 1 with smooth normals: `segments` (≥ 3) around the
/// Y axis and `rings` (≥ 2) from the north pole (`v = 0`) to the south pole.
/// `u = 0` faces +Z and grows towards +X.
pub fn uv_sphere(segments: u32, rings: u32) -> Mesh {
    let (segments, rings) = (segments.max(3), rings.max(2));
    let mut m = Mesh::default();
    for r in 0..=rings {
        let v = r as f32 / rings as f32;
        let (st, ct) = (math::sin(PI * v), math::cos(PI * v));
        for s in 0..=segments {
            let u = s as f32 / segments as f32;
            let (sp, cp) = (math::sin(2.0 * PI * u), math::cos(2.0 * PI * u));
            let n = Vec3::new(st * sp, ct, st * cp);
            m.vertex(n * 0.5, n, Vec2::new(u, v));
        }
    }
    let row = segments + 1;
    for r in 0..rings {
        for s in 0..segments {
            let (a, b, c, d) = (r * row + s, (r + 1) * row + s, (r + 1) * row + s + 1, r * row + s + 1);
            if r + 1 < rings {
                m.indices.push([a, b, c]);
            }
            if r > 0 {
                m.indices.push([a, c, d]);
            }
        }
    }
    m
}

/// A cylinder of diameter 1 and height 1 along Y with `segments` (≥ 3) around
/// it: a smooth side (`u` around from +Z towards +X, `v` from top to bottom)
/// and, when `caps`, flat discs at both ends (planar UVs like [`quad`]).
pub fn cylinder(segments: u32, caps: bool) -> Mesh {
    let segments = segments.max(3);
    let mut m = Mesh::default();
    let dir = |s: u32| {
        let a = 2.0 * PI * s as f32 / segments as f32;
        Vec3::new(math::sin(a), 0.0, math::cos(a))
    };
    for s in 0..=segments {
        let n = dir(s);
        let u = s as f32 / segments as f32;
        m.vertex(n * 0.5 + Vec3::Y * 0.5, n, Vec2::new(u, 0.0));
        m.vertex(n * 0.5 - Vec3::Y * 0.5, n, Vec2::new(u, 1.0));
    }
    for s in 0..segments {
        let (a, b, c, d) = (2 * s, 2 * s + 1, 2 * s + 3, 2 * s + 2);
        m.indices.push([a, b, c]);
        m.indices.push([a, c, d]);
    }
    if caps {
        for n in [Vec3::Y, Vec3::NEG_Y] {
            let planar = |p: Vec3| Vec2::new(p.x + 0.5, p.z + 0.5);
            let centre = m.vertex(n * 0.5, n, Vec2::splat(0.5));
            let first = m.positions.len() as u32;
            for s in 0..segments {
                let p = dir(s) * 0.5 + n * 0.5;
                m.vertex(p, n, planar(p));
            }
            for s in 0..segments {
                let next = first + (s + 1) % segments;
                m.triangle_facing([centre, first + s, next], n);
            }
        }
    }
    m
}

/// An affine transform: `p ↦ linear · p + translation`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transform {
    /// Rotation, scale and shear.
    pub linear: Mat3,
    /// Translation.
    pub translation: Vec3,
}

impl Default for Transform {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Transform {
    /// The transform that changes nothing.
    pub const IDENTITY: Transform = Transform { linear: Mat3::IDENTITY, translation: Vec3::ZERO };

    /// Scale, then rotate by Euler angles in degrees (about X, then Y, then
    /// Z), then translate.
    pub fn from_srt(scale: Vec3, rotate_degrees: Vec3, translate: Vec3) -> Self {
        let axis = |deg: f32| {
            let r = deg.to_radians();
            (math::sin(r), math::cos(r))
        };
        let (sx, cx) = axis(rotate_degrees.x);
        let (sy, cy) = axis(rotate_degrees.y);
        let (sz, cz) = axis(rotate_degrees.z);
        let rx = Mat3::from_cols(Vec3::X, Vec3::new(0.0, cx, sx), Vec3::new(0.0, -sx, cx));
        let ry = Mat3::from_cols(Vec3::new(cy, 0.0, -sy), Vec3::Y, Vec3::new(sy, 0.0, cy));
        let rz = Mat3::from_cols(Vec3::new(cz, sz, 0.0), Vec3::new(-sz, cz, 0.0), Vec3::Z);
        Transform { linear: rz * ry * rx * Mat3::from_diagonal(scale), translation: translate }
    }

    /// The affine part of a 4 × 4 matrix (glTF node matrices).
    pub fn from_mat4(m: Mat4) -> Self {
        Transform { linear: Mat3::from_mat4(m), translation: m.w_axis.truncate() }
    }

    /// `self` followed by `outer`.
    pub fn then(&self, outer: &Transform) -> Transform {
        Transform {
            linear: outer.linear * self.linear,
            translation: outer.linear * self.translation + outer.translation,
        }
    }

    /// Transforms a point.
    #[inline]
    pub fn point(&self, p: Vec3) -> Vec3 {
        self.linear * p + self.translation
    }

    /// The matrix that transforms normals: the inverse transpose of the linear
    /// part (zero when that is singular).
    pub fn normal_matrix(&self) -> Mat3 {
        let det = self.linear.determinant();
        if det == 0.0 || !det.is_finite() { Mat3::ZERO } else { self.linear.inverse().transpose() }
    }

    /// Transforms a normal and renormalises it (zero if it degenerates).
    pub fn normal(&self, n: Vec3) -> Vec3 {
        (self.normal_matrix() * n).normalize_or_zero()
    }

    /// True when the transform mirrors space (negative determinant), which
    /// turns counter-clockwise triangles clockwise.
    pub fn flips_winding(&self) -> bool {
        self.linear.determinant() < 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: Vec3, b: Vec3) -> bool {
        (a - b).length() < 1e-5
    }

    /// Every triangle's winding agrees with its vertex normals, every normal is
    /// unit length, every UV lies in 0..=1 and the mesh fits the unit cube.
    fn check_well_formed(m: &Mesh, name: &str) {
        assert_eq!(m.normals.len(), m.positions.len(), "{name}");
        assert_eq!(m.uvs.len(), m.positions.len(), "{name}");
        for &[a, b, c] in &m.indices {
            let p = [a, b, c].map(|i| m.positions[i as usize]);
            let face = (p[1] - p[0]).cross(p[2] - p[0]);
            assert!(face.length() > 1e-7, "{name}: degenerate triangle {p:?}");
            for i in [a, b, c] {
                let n = m.normals[i as usize];
                assert!((n.length() - 1.0).abs() < 1e-5, "{name}: normal {n:?}");
                assert!(n.dot(face) > 0.0, "{name}: triangle {p:?} winds against its normal {n:?}");
            }
        }
        for p in &m.positions {
            assert!(p.abs().max_element() <= 0.5 + 1e-6, "{name}: {p:?} outside the unit cube");
        }
        for uv in &m.uvs {
            assert!((0.0..=1.0).contains(&uv.x) && (0.0..=1.0).contains(&uv.y), "{name}: uv {uv:?}");
        }
    }

    fn area(m: &Mesh) -> f32 {
        m.indices
            .iter()
            .map(|&[a, b, c]| {
                let p = [a, b, c].map(|i| m.positions[i as usize]);
                0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length()
            })
            .sum()
    }

    #[test]
    fn primitives_are_well_formed() {
        check_well_formed(&quad(), "quad");
        check_well_formed(&cuboid(), "box");
        check_well_formed(&uv_sphere(24, 12), "sphere");
        check_well_formed(&cylinder(20, true), "cylinder");
        check_well_formed(&cylinder(3, false), "open cylinder");
    }

    #[test]
    fn primitive_sizes_and_counts() {
        assert_eq!(quad().indices.len(), 2);
        assert!((area(&quad()) - 1.0).abs() < 1e-6);
        assert_eq!(cuboid().indices.len(), 12);
        assert!((area(&cuboid()) - 6.0).abs() < 1e-5);
        // 2 triangles per quad except one at each pole per segment.
        let s = uv_sphere(32, 16);
        assert_eq!(s.indices.len(), 32 * 16 * 2 - 2 * 32);
        let sphere_area = PI * 1.0; // 4π r², r = ½
        assert!((area(&s) - sphere_area).abs() / sphere_area < 0.02, "{}", area(&s));
        let c = cylinder(64, true);
        assert_eq!(c.indices.len(), 64 * 2 + 2 * 64);
        let cyl_area = PI * 1.0 + 2.0 * PI * 0.25; // side π d h + two discs
        assert!((area(&c) - cyl_area).abs() / cyl_area < 0.01, "{}", area(&c));
        assert_eq!(cylinder(64, false).indices.len(), 128);
    }

    #[test]
    fn quad_uvs_run_along_x_and_z() {
        let q = quad();
        for (p, uv) in q.positions.iter().zip(&q.uvs) {
            assert!(close(Vec3::new(uv.x - 0.5, 0.0, uv.y - 0.5), *p), "{p:?} {uv:?}");
        }
    }

    #[test]
    fn box_side_faces_are_upright() {
        let b = cuboid();
        for ((p, n), uv) in b.positions.iter().zip(&b.normals).zip(&b.uvs) {
            if n.y == 0.0 {
                // v = 0 at the top edge of every side face.
                assert_eq!(uv.y == 0.0, p.y > 0.0, "{p:?} {uv:?}");
            }
        }
    }

    #[test]
    fn srt_scales_then_rotates_then_translates() {
        let t = Transform::from_srt(
            Vec3::new(2.0, 1.0, 1.0),
            Vec3::new(0.0, 0.0, 90.0),
            Vec3::new(0.0, 0.0, 5.0),
        );
        // x scaled to 2, then rotated 90° about Z onto +Y, then moved.
        assert!(close(t.point(Vec3::X), Vec3::new(0.0, 2.0, 5.0)), "{:?}", t.point(Vec3::X));
        let t = Transform::from_srt(Vec3::ONE, Vec3::new(90.0, 0.0, 0.0), Vec3::ZERO);
        assert!(close(t.point(Vec3::Y), Vec3::Z));
        let t = Transform::from_srt(Vec3::ONE, Vec3::new(0.0, 90.0, 0.0), Vec3::ZERO);
        assert!(close(t.point(Vec3::Z), Vec3::X));
        // X first, then Y: Y rotated about X goes to Z, then about Y to X.
        let t = Transform::from_srt(Vec3::ONE, Vec3::new(90.0, 90.0, 0.0), Vec3::ZERO);
        assert!(close(t.point(Vec3::Y), Vec3::X), "{:?}", t.point(Vec3::Y));
    }

    #[test]
    fn normals_use_the_inverse_transpose() {
        // Squash a 45° slope vertically: the normal must tilt towards +Y.
        let t = Transform::from_srt(Vec3::new(1.0, 0.5, 1.0), Vec3::ZERO, Vec3::ZERO);
        let n = t.normal(Vec3::new(1.0, 1.0, 0.0).normalize());
        let tangent = t.point(Vec3::new(1.0, -1.0, 0.0));
        assert!(n.dot(tangent).abs() < 1e-6, "normal stays perpendicular to the surface");
        assert!((n.length() - 1.0).abs() < 1e-6);
        assert!(n.y > n.x);
    }

    #[test]
    fn mirroring_keeps_triangles_facing_out() {
        let t = Transform::from_srt(Vec3::new(-1.0, 2.0, 1.0), Vec3::new(10.0, 20.0, 30.0), Vec3::ONE);
        assert!(t.flips_winding());
        let m = cuboid().transformed(&t);
        for &[a, b, c] in &m.indices {
            let p = [a, b, c].map(|i| m.positions[i as usize]);
            let face = (p[1] - p[0]).cross(p[2] - p[0]);
            assert!(face.dot(m.normals[a as usize]) > 0.0);
            let centre = (p[0] + p[1] + p[2]) / 3.0;
            assert!(face.dot(centre - Vec3::ONE) > 0.0, "faces point away from the box centre");
        }
    }

    #[test]
    fn composition_applies_inner_first() {
        let inner = Transform::from_srt(Vec3::splat(2.0), Vec3::ZERO, Vec3::X);
        let outer = Transform::from_srt(Vec3::ONE, Vec3::new(0.0, 0.0, 90.0), Vec3::Z);
        let both = inner.then(&outer);
        let p = Vec3::new(1.0, 2.0, 3.0);
        assert!(close(both.point(p), outer.point(inner.point(p))));
    }
}

//! Helpers shared by the tracer's integration tests: a deterministic ray
//! generator and the shared meshes.
#![allow(dead_code)] // each test crate uses a different subset

use isin_tracer::Vec3;
use isin_tracer::geometry::Aabb;
use isin_tracer::shapes::Triangle;
use std::path::PathBuf;

/// xorshift64* — a tiny deterministic generator for test rays.
pub struct Rng(pub u64);

impl Rng {
    pub fn next_f32(&mut self) -> f32 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 40) as f32 / (1u64 << 24) as f32
    }
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.next_f32()
    }
    pub fn in_box(&mut self, b: &Aabb) -> Vec3 {
        Vec3::new(self.range(b.min.x, b.max.x), self.range(b.min.y, b.max.y), self.range(b.min.z, b.max.z))
    }
    pub fn unit_vector(&mut self) -> Vec3 {
        loop {
            let v = Vec3::new(self.range(-1.0, 1.0), self.range(-1.0, 1.0), self.range(-1.0, 1.0));
            let l = v.length_squared();
            if l > 1e-3 && l <= 1.0 {
                return v / l.sqrt();
            }
        }
    }
}

pub fn mesh_path(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/meshes").join(rel)
}

/// Loads an OBJ's triangles, or `None` (with a printed reason) when it is absent.
pub fn load_mesh(rel: &str) -> Option<Vec<Triangle>> {
    let path = mesh_path(rel);
    if !path.exists() {
        println!("skipping: {} not found", path.display());
        return None;
    }
    let opts = tobj::LoadOptions { triangulate: true, ..Default::default() };
    let (models, _) = tobj::load_obj(&path, &opts).expect("mesh parses");
    let mut tris = Vec::new();
    for m in &models {
        let p = &m.mesh.positions;
        let vert = |i: u32| {
            let i = i as usize * 3;
            Vec3::new(p[i], p[i + 1], p[i + 2])
        };
        for f in m.mesh.indices.chunks_exact(3) {
            tris.push(Triangle { v: [vert(f[0]), vert(f[1]), vert(f[2])] });
        }
    }
    Some(tris)
}

pub fn bounds_of(tris: &[Triangle]) -> Aabb {
    tris.iter().fold(Aabb::EMPTY, |b, t| b.union(&t.bounds()))
}

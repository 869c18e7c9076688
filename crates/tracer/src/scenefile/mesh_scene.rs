//! Scenes made around a mesh file (`.gltf`, `.glb`, `.obj`), so that a model
//! can be rendered without writing a scene file.
//!
//! [`mesh_scene`] writes the scene as TOML text that refers to the mesh as an
//! asset — exactly what `isin scene FILE` prints — so the made scene is an
//! ordinary [`super::SceneBundle`], ships to slaves like any other, and can be
//! saved and edited. It holds:
//!
//! - **the camera**: the file's own camera when it is a glTF file with a
//!   perspective camera in its default scene (the first one found), else a
//!   look-at camera on the bounding box's centre from a three-quarter view
//!   (35° to the right of the model's front, +Z, and 25° above it), 45°
//!   horizontal field of view, as close as keeps every corner of the
//!   bounding box in the frame, with a 10 % margin;
//! - **the lights**: the file's `KHR_lights_punctual` lights when it has some
//!   (point and spot lights become point lights — isin has no cones —,
//!   directional lights point lights 1000 bounding radii away, as bright
//!   there as the light says), else a default rig: a square area key light
//!   above the camera's left, whose soft shadows fall behind and to the right,
//!   and a dim point fill light just above the camera, whose shadows the
//!   camera does not see; the key gives an irradiance of 2 at the model's
//!   centre, the fill 0.6;
//! - **a sky**: a blue zenith over a pale horizon, for metals and glass to
//!   reflect;
//! - **a ground plane**, light grey, just under the bounding box, unless the
//!   file brings its own camera or lights (then it is a composed scene).
//!
//! Numbers are written with Rust's shortest round-trip formatting, so the
//! text loads to exactly the scene it was made from.

use super::build::{Builder, join};
use super::{AssetSource, SceneError, gltf};
use crate::geometry::Aabb;
use crate::scene::SceneParts;
use glam::Vec3;
use std::fmt::Write as _;

/// The kinds of mesh file a scene can be made around.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MeshFormat {
    /// glTF 2.0, JSON (`.gltf`) or binary (`.glb`).
    Gltf,
    /// Wavefront OBJ (`.obj`).
    Obj,
}

impl MeshFormat {
    /// The format of a file by its extension (case-insensitive), `None` for
    /// anything else (e.g. a `.toml` scene).
    pub fn from_path(path: &str) -> Option<MeshFormat> {
        let ext = path.rsplit_once('.')?.1.to_ascii_lowercase();
        match ext.as_str() {
            "gltf" | "glb" => Some(MeshFormat::Gltf),
            "obj" => Some(MeshFormat::Obj),
            _ => None,
        }
    }

    /// The object kind that loads it in a scene file.
    fn kind(self) -> &'static str {
        match self {
            MeshFormat::Gltf => "gltf",
            MeshFormat::Obj => "obj",
        }
    }
}

/// A camera found in a mesh file: eye, viewing direction, up, horizontal field
/// of view in degrees and, when the file gives one, the aspect ratio.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct FileCamera {
    pub eye: Vec3,
    pub forward: Vec3,
    pub up: Vec3,
    /// Vertical field of view, radians.
    pub yfov: f32,
    pub aspect: Option<f32>,
}

/// A punctual light found in a mesh file (colour × intensity already applied).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum FileLight {
    /// A point (or spot) light in candela.
    Point { position: Vec3, intensity: Vec3 },
    /// A directional light: the direction light travels, illuminance in lux.
    Directional { direction: Vec3, illuminance: Vec3 },
}

/// The text of a TOML string holding `s`.
fn toml_string(s: &str) -> String {
    toml::Value::String(s.to_owned()).to_string()
}

fn num(x: f32) -> String {
    format!("{x:?}")
}

fn vec(v: Vec3) -> String {
    format!("[{}, {}, {}]", num(v.x), num(v.y), num(v.z))
}

/// Loads only the mesh at `path` (as a scene of that one object).
fn load_mesh(path: &str, format: MeshFormat, assets: &mut dyn AssetSource) -> Result<SceneParts, SceneError> {
    let probe = format!("[[objects]]\nkind = \"{}\"\npath = {}\n", format.kind(), toml_string(path));
    Builder::new(path, &probe, assets).quiet().build()
}

/// The world-space bounding box of the mesh file at `path` (read through
/// `assets`), as it is placed in a scene with no transform of its own.
pub fn mesh_bounds(path: &str, assets: &mut dyn AssetSource) -> Result<Aabb, SceneError> {
    let format = MeshFormat::from_path(path).ok_or_else(|| not_a_mesh(path))?;
    let parts = load_mesh(path, format, assets)?;
    Ok(parts.triangles.iter().fold(Aabb::EMPTY, |b, t| b.union(&t.bounds())))
}

fn not_a_mesh(path: &str) -> SceneError {
    SceneError::Invalid {
        at: super::Location { file: path.to_owned(), line: 0 },
        what: "mesh file".into(),
        message: "not a mesh file: expected a .gltf, .glb or .obj extension".into(),
    }
}

/// The scene made around the mesh file at `path` (a path the asset source
/// understands, which the scene text refers to), as TOML text; see the module
/// docs for what it holds. Fails as loading the mesh in a scene would.
pub fn mesh_scene(path: &str, assets: &mut dyn AssetSource) -> Result<String, SceneError> {
    let format = MeshFormat::from_path(path).ok_or_else(|| not_a_mesh(path))?;
    let parts = load_mesh(path, format, assets)?;
    let bounds = parts.triangles.iter().fold(Aabb::EMPTY, |b, t| b.union(&t.bounds()));
    let (camera, lights) = match format {
        MeshFormat::Gltf => {
            let bytes = assets.read(&join("", path)).map_err(|reason| SceneError::MissingAsset {
                at: super::Location { file: path.to_owned(), line: 0 },
                what: "mesh file".into(),
                path: path.to_owned(),
                reason,
            })?;
            gltf::cameras_and_lights(&bytes).map_err(|message| SceneError::BadAsset {
                at: super::Location { file: path.to_owned(), line: 0 },
                what: "mesh file".into(),
                path: path.to_owned(),
                message,
            })?
        }
        MeshFormat::Obj => (None, Vec::new()),
    };
    Ok(write_scene(path, format, &bounds, camera, &lights))
}

/// Width of made scenes; the height follows the camera's aspect (4:3 unless
/// the file's camera says otherwise).
const WIDTH: u32 = 640;
/// Horizontal field of view of the framing camera, degrees.
const FOV: f32 = 45.0;

fn write_scene(
    path: &str,
    format: MeshFormat,
    bounds: &Aabb,
    camera: Option<FileCamera>,
    lights: &[FileLight],
) -> String {
    let centre = bounds.center();
    let radius = (bounds.diagonal() * 0.5).max(1e-3);
    let aspect = camera.and_then(|c| c.aspect).filter(|a| a.is_finite() && *a > 0.05 && *a < 20.0);
    let aspect = aspect.unwrap_or(4.0 / 3.0);
    let height = ((WIDTH as f32 / aspect).round() as u32).clamp(1, 8 * WIDTH);
    let mut s = String::new();
    let _ = writeln!(s, "# isin scene made around {path} (`isin scene {path}`); edit freely.");
    let _ = writeln!(s, "# Format: see scenes/paper.toml in the isin repository.");
    let _ = writeln!(s, "ambient = 0.04");
    let _ = writeln!(s, "background = {{ zenith = [0.16, 0.27, 0.5], horizon = [0.62, 0.66, 0.72] }}");
    let _ = writeln!(s);
    let _ = writeln!(s, "[settings]\nwidth = {WIDTH}\nheight = {height}\nspp = 4\nlight_samples = 16");
    let _ = writeln!(s);

    // The camera.
    let (eye, target, up, fov) = match camera {
        Some(c) => {
            let hfov = 2.0 * crate::math::atan2(crate::math::tan(c.yfov * 0.5) * aspect, 1.0);
            (c.eye, c.eye + c.forward, c.up, hfov.to_degrees().clamp(1.0, 170.0))
        }
        None => {
            let (az, el) = (35f32.to_radians(), 25f32.to_radians());
            let to_eye = Vec3::new(crate::math::sin(az) * crate::math::cos(el), crate::math::sin(el), {
                crate::math::cos(az) * crate::math::cos(el)
            });
            let distance = framing_distance(bounds, -to_eye, FOV, aspect).max(radius * 0.1);
            (centre + to_eye * distance, centre, Vec3::Y, FOV)
        }
    };
    let _ = writeln!(s, "[camera]");
    if camera.is_some() {
        let _ = writeln!(s, "# the file's own camera");
    }
    let _ = writeln!(s, "eye = {}\ntarget = {}\nup = {}\nfov = {}", vec(eye), vec(target), vec(up), num(fov));
    let _ = writeln!(s);

    // The lights.
    if lights.is_empty() {
        let forward = (target - eye).normalize_or_zero();
        let right = forward.cross(up).normalize_or_zero();
        let true_up = right.cross(forward);
        // Key: above, left of and behind the camera, looking at the centre.
        let key_dir = (-forward * 0.8 - right * 0.9 + true_up * 1.3).normalize_or(Vec3::Y);
        let key_distance = 3.0 * radius;
        let key = centre + key_dir * key_distance;
        let side = radius;
        let n = -key_dir;
        let t1 = n.any_orthonormal_vector();
        let t2 = n.cross(t1);
        let corner = key - (t1 + t2) * (side * 0.5);
        let radiance = 2.0 * key_distance * key_distance / (side * side);
        let _ = writeln!(s, "# default rig: a soft key light and a fill light at the camera");
        let _ = writeln!(s, "[[lights]]\nkind = \"area\"");
        let _ =
            writeln!(s, "corner = {}\nedge1 = {}\nedge2 = {}", vec(corner), vec(t1 * side), vec(t2 * side));
        let _ = writeln!(s, "radiance = [1.0, 0.97, 0.92]\npower = {}\nvisible = false", num(radiance));
        let _ = writeln!(s);
        let fill = eye + true_up * (0.1 * (centre - eye).length());
        let fill_distance = (centre - fill).length();
        let _ = writeln!(s, "[[lights]]\nkind = \"point\"\nposition = {}", vec(fill));
        let _ =
            writeln!(s, "intensity = [0.9, 0.95, 1.0]\npower = {}", num(0.6 * fill_distance * fill_distance));
        let _ = writeln!(s);
    } else {
        let _ = writeln!(s, "# the file's own lights (KHR_lights_punctual)");
        for light in lights {
            let (position, intensity) = match *light {
                FileLight::Point { position, intensity } => (position, intensity),
                FileLight::Directional { direction, illuminance } => {
                    let far = 1000.0 * radius;
                    let dir = direction.normalize_or(-Vec3::Y);
                    (centre - dir * far, illuminance * (far * far))
                }
            };
            let _ = writeln!(s, "[[lights]]\nkind = \"point\"\nposition = {}", vec(position));
            let _ = writeln!(s, "intensity = {}", vec(intensity.max(Vec3::ZERO)));
            let _ = writeln!(s);
        }
    }

    // The mesh, and a ground plane under it.
    let ground = camera.is_none() && lights.is_empty();
    if ground {
        let _ = writeln!(s, "[materials.ground]\nkind = \"phong\"\ncolor = 0.6");
        let _ = writeln!(s);
    }
    let _ = writeln!(s, "[[objects]]\nkind = \"{}\"\npath = {}", format.kind(), toml_string(path));
    if ground {
        let _ = writeln!(s);
        let ground = Vec3::new(centre.x, bounds.min.y - 1e-3 * radius, centre.z);
        let _ = writeln!(s, "[[objects]]\nname = \"ground\"\nkind = \"quad\"\nmaterial = \"ground\"");
        let _ = writeln!(s, "scale = {}\ntranslate = {}", num(40.0 * radius), vec(ground));
    }
    s
}

/// How far from the centre of `bounds`, looking along unit `forward` with a
/// `hfov_degrees` × (the same / `aspect`) frustum and +Y up, a camera must
/// stand to see every corner of the box, with a 10 % margin.
fn framing_distance(bounds: &Aabb, forward: Vec3, hfov_degrees: f32, aspect: f32) -> f32 {
    let right = forward.cross(Vec3::Y).normalize_or(Vec3::X);
    let up = right.cross(forward);
    let tan_h = crate::math::tan(hfov_degrees.to_radians() * 0.5) / 1.1;
    let tan_v = tan_h / aspect;
    let c = bounds.center();
    let mut d: f32 = 0.0;
    for i in 0..8 {
        let corner = Vec3::new(
            if i & 1 == 0 { bounds.min.x } else { bounds.max.x },
            if i & 2 == 0 { bounds.min.y } else { bounds.max.y },
            if i & 4 == 0 { bounds.min.z } else { bounds.max.z },
        );
        let p = corner - c;
        let depth = p.dot(forward);
        // |x| ≤ tan_h (depth + d)  ⇔  d ≥ |x| / tan_h − depth.
        d = d.max(p.dot(right).abs() / tan_h - depth).max(p.dot(up).abs() / tan_v - depth);
    }
    d
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_come_from_extensions() {
        assert_eq!(MeshFormat::from_path("a/b.GLTF"), Some(MeshFormat::Gltf));
        assert_eq!(MeshFormat::from_path("b.glb"), Some(MeshFormat::Gltf));
        assert_eq!(MeshFormat::from_path("b.obj"), Some(MeshFormat::Obj));
        assert_eq!(MeshFormat::from_path("b.toml"), None);
        assert_eq!(MeshFormat::from_path("obj"), None);
    }

    #[test]
    fn framing_keeps_every_corner_in_view() {
        let b = Aabb { min: Vec3::new(-1.0, 0.0, -2.0), max: Vec3::new(3.0, 1.0, 0.5) };
        let fwd = Vec3::new(-0.4, -0.3, -1.0).normalize();
        let d = framing_distance(&b, fwd, 45.0, 4.0 / 3.0);
        let cam = crate::Camera::look_at(b.center() - fwd * d, b.center(), Vec3::Y, 45.0, 4.0 / 3.0);
        let mut touches = false;
        for i in 0..8 {
            let p = Vec3::new(
                if i & 1 == 0 { b.min.x } else { b.max.x },
                if i & 2 == 0 { b.min.y } else { b.max.y },
                if i & 4 == 0 { b.min.z } else { b.max.z },
            );
            // Where the ray to p crosses the image plane, in plane units.
            let dir = p - cam.eye;
            let t = cam.eye_distance() / dir.dot(cam.forward());
            let q = cam.eye + dir * t - cam.corners[0];
            let (fx, fy) = (q.dot(cam.plane_x()) / cam.plane_x().length_squared(), {
                q.dot(cam.plane_y()) / cam.plane_y().length_squared()
            });
            assert!((0.0..=1.0).contains(&fx) && (0.0..=1.0).contains(&fy), "corner {p} at {fx}, {fy}");
            touches |= !(0.06..=0.94).contains(&fx) || !(0.06..=0.94).contains(&fy);
        }
        assert!(touches, "the box fills the frame to its margin");
    }
}

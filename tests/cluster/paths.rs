//! Keyframed camera paths flown through a cluster.
//!
//! - `a_keyframed_flight…`: a path of four keys (look-at and corners forms,
//!   Catmull-Rom) sampled at 10 fps into 30 cameras; `fly --cluster` writes
//!   the same 30 files as `fly` here, pixel for pixel and byte for byte.

use super::util::{self, Cluster, Proc, Stream, Transport, assert_same_pixels};
use std::path::Path;

/// Four keys from 0 to 2.9 s at 10 fps: frames at 0.0, 0.1, … 2.9, the
/// last on the last key — 30 cameras.
const KEYS: &str = r#"version = 2
fps = 10
interpolation = "catmull-rom"

[[key]]
t = 0.0
eye = [0.0, 3.6, 13.5]
corners = [[-4.0, 5.594, 0.801], [4.0, 5.594, 0.801], [4.0, -0.387, 1.279], [-4.0, -0.387, 1.279]]

[[key]]
t = 1.0
eye = [3.0, 3.0, 4.0]
look_at = [0.0, 1.2, -4.5]
fov = 55

[[key]]
t = 2.0
eye = [4.5, 3.5, -3.0]
look_at = [0.0, 1.2, -4.5]
fov = 60

[[key]]
t = 2.9
eye = [2.0, 4.0, -8.5]
look_at = [-1.0, 1.2, -4.0]
up = [0.2, 1.0, 0.0]
fov = 60
"#;

/// Cameras the keys are sampled into.
const CAMERAS: usize = 30;

cluster_test!(a_keyframed_flight_through_the_cluster_equals_fly_here_byte_for_byte, |t: Transport| {
    let c = Cluster::start(t, 2, &[]);
    let path = c.dir.path().join("keys.toml");
    std::fs::write(&path, KEYS).unwrap();
    let scene = util::scene();
    let fly = |out: &Path, cluster: Option<&str>| {
        let mut args = vec!["fly", scene.to_str().unwrap(), "--path", path.to_str().unwrap()];
        args.extend(["--out-dir", out.to_str().unwrap(), "--width", "64", "--height", "48", "--spp", "1"]);
        args.extend(cluster.map(|t| ["--connect", t]).into_iter().flatten());
        let mut p = Proc::spawn("fly", &args, "warn");
        assert!(p.wait_exit().success(), "fly failed\n{}\n{}", p.dump(), c.master.dump());
        let said = p.matching(Stream::Out, |l| l.starts_with(&format!("flying {CAMERAS} frames")));
        assert_eq!(said.len(), 1, "{}", p.dump());
    };
    let (here, there) = (c.dir.path().join("here"), c.dir.path().join("there"));
    fly(&here, None);
    fly(&there, Some(&c.ticket));
    let mut previous: Option<Vec<u8>> = None;
    let mut moves = 0;
    for i in 0..CAMERAS {
        let name = format!("frame_{i:04}.png");
        let (a, b) = (util::pixels(&here.join(&name)), util::pixels(&there.join(&name)));
        assert_same_pixels(&b, &a, &format!("{name}: cluster vs here"));
        let (fa, fb) = (std::fs::read(here.join(&name)).unwrap(), std::fs::read(there.join(&name)).unwrap());
        assert!(fa == fb, "{name}: the files differ though their pixels do not");
        moves += usize::from(previous.as_ref().is_some_and(|p| *p != a));
        previous = Some(a);
    }
    assert!(moves >= CAMERAS - 2, "only {moves} of {} frames differ from the one before", CAMERAS - 1);
    for dir in [&here, &there] {
        let written = std::fs::read_dir(dir).unwrap().count();
        assert_eq!(written, CAMERAS, "{}: one file per sampled camera and no others", dir.display());
    }
});

//! `isin render -o`: the formats renderers write, read back by third-party
//! readers (the `exr` and `image` crates, Python's OpenEXR where installed);
//! `-o -` to standard output; the passes; a render streamed into a fake tev
//! that decodes tev's packet format.

use isin_tracer::render::{encode_srgb8, linear_to_srgb};
use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

const SIZE: [&str; 6] = ["--width", "80", "--height", "60", "--spp", "1"];
/// The channels of `--passes albedo,normal,depth`, sorted.
const ALL_PASSES: [&str; 10] =
    ["B", "G", "R", "albedo.B", "albedo.G", "albedo.R", "depth.Z", "normal.X", "normal.Y", "normal.Z"];

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).to_path_buf()
}

/// Runs `isin render scenes/paper.toml --quiet ARGS` at 80 × 60.
fn render(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_isin"))
        .current_dir(root())
        .args(["render", "scenes/paper.toml", "--quiet"])
        .args(SIZE)
        .args(args)
        .env("RUST_LOG", "warn")
        .stdin(Stdio::null())
        .output()
        .expect("isin runs")
}

/// [`render`], which must succeed.
fn rendered(args: &[&str]) -> Output {
    let out = render(args);
    assert!(out.status.success(), "isin {args:?}: {}", String::from_utf8_lossy(&out.stderr));
    out
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// An EXR's channels, by name, as floats, and whether each is half.
fn read_exr(bytes: &[u8]) -> HashMap<String, (Vec<f32>, bool)> {
    use exr::prelude::*;
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(bytes))
        .expect("a readable EXR");
    assert_eq!(image.layer_data.size, Vec2(80, 60));
    image
        .layer_data
        .channel_data
        .list
        .iter()
        .map(|c| {
            let half = matches!(c.sample_data, FlatSamples::F16(_));
            (c.name.to_string(), (c.sample_data.values_as_f32().collect(), half))
        })
        .collect()
}

fn names(channels: &HashMap<String, (Vec<f32>, bool)>) -> Vec<String> {
    let mut n: Vec<String> = channels.keys().cloned().collect();
    n.sort();
    n
}

#[test]
fn exr_layers_read_back_and_the_beauty_is_the_pngs_pixels_before_encoding() {
    let dir = tempfile::tempdir().unwrap();
    let (png, exr) = (dir.path().join("out.png"), dir.path().join("out.exr"));
    rendered(&["-o", s(&png)]);
    // Another tiling, too: the pixels do not depend on it.
    rendered(&["-o", s(&exr), "--passes", "albedo,normal,depth", "--tile", "8"]);
    let channels = read_exr(&std::fs::read(&exr).unwrap());
    assert_eq!(names(&channels), ALL_PASSES);
    assert!(channels.values().all(|(_, half)| !half), "32-bit float by default");
    let png = image::open(&png).unwrap().to_rgb8();
    let c = |name: &str| &channels[name].0;
    let mut brighter_than_white = 0;
    for (i, p) in png.pixels().enumerate() {
        for (k, name) in ["R", "G", "B"].iter().enumerate() {
            let linear = c(name)[i];
            let byte = p.0[k];
            // The PNG is exactly the clamped, sRGB-encoded beauty…
            assert_eq!(encode_srgb8(linear), byte, "pixel {i} {name}: {linear}");
            // …so within 1/255 of it before quantisation.
            let encoded = linear_to_srgb(linear.clamp(0.0, 1.0));
            assert!((encoded - byte as f32 / 255.0).abs() <= 1.0 / 255.0, "pixel {i} {name}");
            brighter_than_white += usize::from(linear > 1.0);
        }
    }
    // The visible lamp is kept unclamped.
    assert!(brighter_than_white > 0, "no value above 1: the beauty was clamped");
    let mut background = 0;
    for i in 0..80 * 60 {
        let n = [c("normal.X")[i], c("normal.Y")[i], c("normal.Z")[i]];
        let len = n.iter().map(|v| v * v).sum::<f32>().sqrt();
        let depth = c("depth.Z")[i];
        if len == 0.0 {
            assert_eq!(depth, f32::INFINITY);
            background += 1;
        } else {
            assert!((len - 1.0).abs() < 1e-4, "pixel {i}: normal {n:?}");
            assert!(depth.is_finite() && depth > 0.0, "pixel {i}: depth {depth}");
        }
        for name in ["albedo.R", "albedo.G", "albedo.B"] {
            assert!((0.0..=1.0).contains(&c(name)[i]), "pixel {i}: {name} {}", c(name)[i]);
        }
    }
    // paper.toml is a closed room: every camera ray hits something.
    assert_eq!(background, 0);
    // The albedo sees the floor's checker texture: many colours, not one.
    let mut albedos: Vec<u32> = c("albedo.R").iter().map(|v| v.to_bits()).collect();
    albedos.sort();
    albedos.dedup();
    assert!(albedos.len() > 8, "{} albedo values", albedos.len());

    python_openexr_reads(&exr, &channels);
}

/// Python's OpenEXR (the reference implementation's binding) finds the same
/// channels and values; skipped, saying so, where it is not installed.
fn python_openexr_reads(exr: &Path, channels: &HashMap<String, (Vec<f32>, bool)>) {
    let probe = Command::new("python3").args(["-c", "import OpenEXR"]).output();
    if !probe.is_ok_and(|o| o.status.success()) {
        println!(
            "skipped the Python OpenEXR check: `python3 -c 'import OpenEXR'` fails (pip install OpenEXR)"
        );
        return;
    }
    let script = "import sys, OpenEXR, numpy\n\
        f = OpenEXR.File(sys.argv[1], separate_channels=True)\n\
        for name, c in sorted(f.channels().items()):\n\
        \x20   p = c.pixels.astype(numpy.float64)\n\
        \x20   fin = numpy.isfinite(p)\n\
        \x20   print(name, p.shape[1], p.shape[0], repr(float(p[fin].sum())), int((~fin).sum()))\n";
    let out = Command::new("python3").args(["-c", script, s(exr)]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    let mut seen = Vec::new();
    for line in text.lines() {
        let f: Vec<&str> = line.split(' ').collect();
        let (values, _) = &channels[f[0]];
        assert_eq!((f[1], f[2]), ("80", "60"), "{line}");
        let sum: f64 = values.iter().filter(|v| v.is_finite()).map(|&v| v as f64).sum();
        let theirs: f64 = f[3].parse().unwrap();
        assert!((sum - theirs).abs() <= 1e-9 * sum.abs().max(1.0), "{line}: we read a sum of {sum}");
        assert_eq!(f[4].parse::<usize>().unwrap(), values.iter().filter(|v| !v.is_finite()).count());
        seen.push(f[0].to_string());
    }
    assert_eq!(seen, ALL_PASSES);
}

#[test]
fn half_exr_pfm_and_sixteen_bit_png_hold_the_same_image() {
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n);
    rendered(&["-o", s(&p("f.exr")), "--passes", "depth,albedo"]);
    rendered(&["-o", s(&p("h.exr")), "--passes", "depth,albedo", "--bit-depth", "16"]);
    rendered(&["-o", s(&p("o.pfm")), "--passes", "depth,albedo"]);
    rendered(&["-o", s(&p("o8.png"))]);
    rendered(&["-o", s(&p("o16.png")), "--bit-depth", "16"]);
    let float = read_exr(&std::fs::read(p("f.exr")).unwrap());
    let half = read_exr(&std::fs::read(p("h.exr")).unwrap());
    assert_eq!(
        names(&half),
        ["B", "G", "R", "albedo.B", "albedo.G", "albedo.R", "depth.Z"].map(String::from)
    );
    for (name, (values, is_half)) in &half {
        // Depth stays 32-bit: half is too coarse for distances.
        assert_eq!(*is_half, name != "depth.Z", "{name}");
        let want: Vec<f32> = float[name].0.iter().map(|&v| exr::prelude::f16::from_f32(v).to_f32()).collect();
        if *is_half {
            assert!(values == &want, "{name}: not the float image rounded to half");
        } else {
            assert!(values == &float[name].0, "{name}");
        }
    }

    // PFM: the float image bit for bit, bottom row first, passes as files beside it.
    let pfm = |name: &str, channels: usize| -> Vec<f32> {
        let bytes = std::fs::read(p(name)).unwrap();
        let kind = if channels == 3 { "PF" } else { "Pf" };
        let header = format!("{kind}\n80 60\n-1.0\n");
        assert!(bytes.starts_with(header.as_bytes()), "{name}: header");
        let data = &bytes[header.len()..];
        assert_eq!(data.len(), 80 * 60 * channels * 4);
        let floats: Vec<f32> = data.chunks(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
        // Back to top-down rows.
        floats.chunks(80 * channels).rev().flatten().copied().collect()
    };
    let beauty = pfm("o.pfm", 3);
    for (i, v) in beauty.iter().enumerate() {
        assert_eq!(v.to_bits(), float[["R", "G", "B"][i % 3]].0[i / 3].to_bits(), "beauty sample {i}");
    }
    assert!(pfm("o.depth.pfm", 1) == float["depth.Z"].0);
    let albedo = pfm("o.albedo.pfm", 3);
    assert!(
        (0..albedo.len()).all(|i| albedo[i] == float[["albedo.R", "albedo.G", "albedo.B"][i % 3]].0[i / 3])
    );
    assert!(!p("o.normal.pfm").exists(), "a pass not asked for");

    // 16-bit PNG: real 16-bit samples that round to the 8-bit PNG's.
    let png16 = image::open(p("o16.png")).unwrap();
    assert_eq!(png16.color(), image::ColorType::Rgb16);
    let (png16, png8) = (png16.to_rgb16(), image::open(p("o8.png")).unwrap().to_rgb8());
    let mut finer = 0;
    for (a, b) in png16.as_raw().iter().zip(png8.as_raw()) {
        assert!((*a as f32 / 257.0 - *b as f32).abs() <= 0.51, "{a} vs {b}");
        finer += usize::from(a % 257 != 0);
    }
    assert!(finer > png8.as_raw().len() / 2, "only {finer} samples use the 16 bits");
}

#[test]
fn standard_output_gets_a_png_unless_format_says_otherwise() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("f.png");
    rendered(&["-o", s(&file)]);
    let out = rendered(&["-o", "-"]);
    let piped = image::load_from_memory_with_format(&out.stdout, image::ImageFormat::Png).expect("a PNG");
    assert!(piped.to_rgb8() == image::open(&file).unwrap().to_rgb8());
    let report = String::from_utf8_lossy(&out.stderr);
    assert!(report.contains("wrote      standard output"), "the report goes to stderr: {report}");

    let out = rendered(&["-o", "-", "--format", "exr", "--passes", "normal"]);
    let channels = read_exr(&out.stdout);
    assert_eq!(names(&channels), ["B", "G", "R", "normal.X", "normal.Y", "normal.Z"].map(String::from));
    let png = image::open(&file).unwrap().to_rgb8();
    assert!(png.pixels().enumerate().all(|(i, p)| encode_srgb8(channels["G"].0[i]) == p.0[1]));
    // --format decides whatever the file is called.
    let named = dir.path().join("image.data");
    rendered(&["-o", s(&named), "--format", "jpeg"]);
    assert_eq!(image::guess_format(&std::fs::read(&named).unwrap()).unwrap(), image::ImageFormat::Jpeg);
}

/// Runs a render that must be refused; returns its stderr and what it left in `dir`.
fn refused_in(dir: &Path, args: &[&str]) -> (String, Vec<PathBuf>) {
    let out = render(args);
    assert!(!out.status.success(), "isin {args:?} succeeded");
    let left = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).collect();
    (String::from_utf8_lossy(&out.stderr).into_owned(), left)
}

#[test]
fn what_cannot_be_written_is_refused_before_rendering_and_leaves_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n);
    // Refused before the scene is even read: a scene that does not exist is not what fails.
    for (out, extra, says) in [
        ("x.tiff", &[][..], "isin writes png, jpg (or jpeg), exr, pfm images"),
        ("x", &[], "isin writes png, jpg (or jpeg), exr, pfm images"),
        ("x.png", &["--passes", "albedo"], "--passes needs a linear float format"),
        ("x.jpg", &["--bit-depth", "16"], "--bit-depth 16 does not fit JPEG"),
    ] {
        let path = p(out);
        let mut args = vec!["-o", s(&path)];
        args.extend(extra);
        let cmd = Command::new(env!("CARGO_BIN_EXE_isin"))
            .current_dir(root())
            .args(["render", "no/such/scene.toml"])
            .args(&args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&cmd.stderr);
        assert!(!cmd.status.success() && err.contains(says), "{out} {extra:?}: {err}");
        assert!(!err.contains("scene.toml"), "the scene was read first: {err}");
        let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert!(left.is_empty(), "left behind: {left:?}");
    }
    let (err, left) =
        refused_in(dir.path(), &["-o", s(&p("x.pfm")), "--passes", "albedo", "--tev", "127.0.0.1:9"]);
    assert!(err.contains("cannot connect to tev at 127.0.0.1:9"), "{err}");
    assert!(left.is_empty(), "left behind: {left:?}");
    // The cluster carries RGB8 only: HDR output through it is refused, saying so.
    for extra in [&["-o", s(&p("x.exr"))][..], &["-o", s(&p("x.png")), "--bit-depth", "16"]] {
        let mut args = extra.to_vec();
        args.extend(["--connect", "isin+tcp-insecure://t@127.0.0.1:9"]);
        let (err, left) = refused_in(dir.path(), &args);
        assert!(err.contains("RGB8 tiles only"), "{err}");
        assert!(left.is_empty(), "left behind: {left:?}");
    }
}

/// What a fake tev received: the images it was told to create and the
/// updates to them, decoded from tev's packet format.
#[derive(Default)]
struct Tev {
    /// Name, width, height, channel names.
    created: Vec<(String, i32, i32, Vec<String>)>,
    /// Per channel of the image, its pixels as updated.
    pixels: HashMap<String, Vec<f32>>,
    /// How many times each pixel was updated.
    updates: Vec<u32>,
    tiles: usize,
}

/// Reads a tev packet stream to its end.
fn fake_tev(mut stream: std::net::TcpStream) -> Tev {
    let mut all = Vec::new();
    stream.read_to_end(&mut all).unwrap();
    let mut tev = Tev::default();
    let mut at = 0;
    while at < all.len() {
        let len = u32::from_le_bytes(all[at..at + 4].try_into().unwrap()) as usize;
        let mut r = Fields { b: &all[at + 4..at + len], at: 0 };
        at += len;
        match r.u8() {
            4 => {
                let _focus = r.u8();
                let name = r.str();
                let (w, h, n) = (r.i32(), r.i32(), r.i32());
                let channels: Vec<String> = (0..n).map(|_| r.str()).collect();
                for c in &channels {
                    tev.pixels.insert(c.clone(), vec![f32::NAN; (w * h) as usize]);
                }
                tev.updates = vec![0; (w * h) as usize];
                tev.created.push((name, w, h, channels));
                assert_eq!(r.at, r.b.len(), "CreateImage has trailing bytes");
            }
            6 => {
                let _focus = r.u8();
                let name = r.str();
                assert_eq!(name, tev.created[0].0);
                let n = r.i32() as usize;
                let channels: Vec<String> = (0..n).map(|_| r.str()).collect();
                let (x, y, w, h) = (r.i32(), r.i32(), r.i32(), r.i32());
                let offsets: Vec<i64> = (0..n).map(|_| r.i64()).collect();
                let strides: Vec<i64> = (0..n).map(|_| r.i64()).collect();
                let data: Vec<f32> =
                    r.b[r.at..].chunks(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
                let width = tev.created[0].1;
                for px in 0..(w * h) as usize {
                    let (tx, ty) = (px as i32 % w, px as i32 / w);
                    let i = ((y + ty) * width + x + tx) as usize;
                    for c in 0..n {
                        tev.pixels.get_mut(&channels[c]).unwrap()[i] =
                            data[(offsets[c] + px as i64 * strides[c]) as usize];
                    }
                    tev.updates[i] += 1;
                }
                tev.tiles += 1;
            }
            t => panic!("unknown packet type {t}"),
        }
    }
    tev
}

/// Little-endian fields of a packet.
struct Fields<'a> {
    b: &'a [u8],
    at: usize,
}

impl Fields<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let v = self.b[self.at..self.at + N].try_into().unwrap();
        self.at += N;
        v
    }
    fn u8(&mut self) -> u8 {
        self.take::<1>()[0]
    }
    fn i32(&mut self) -> i32 {
        i32::from_le_bytes(self.take())
    }
    fn i64(&mut self) -> i64 {
        i64::from_le_bytes(self.take())
    }
    fn str(&mut self) -> String {
        let end = self.at + self.b[self.at..].iter().position(|&c| c == 0).expect("NUL-terminated");
        let s = String::from_utf8(self.b[self.at..end].to_vec()).unwrap();
        self.at = end + 1;
        s
    }
}

#[test]
fn tiles_stream_into_tev_as_the_exr_has_them() {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let server = std::thread::spawn(move || fake_tev(listener.accept().unwrap().0));
    let dir = tempfile::tempdir().unwrap();
    let exr = dir.path().join("streamed.exr");
    let out = rendered(&["-o", s(&exr), "--passes", "normal,depth", "--tile", "16", "--tev", &addr]);
    assert!(String::from_utf8_lossy(&out.stdout).contains(&format!("tev        {addr}")));
    // The render closes the connection when it is done.
    let tev = server.join().unwrap();
    assert_eq!(tev.created.len(), 1);
    let (name, w, h, channels) = &tev.created[0];
    assert_eq!((name.as_str(), *w, *h), ("streamed.exr", 80, 60));
    let want = ["R", "G", "B", "normal.X", "normal.Y", "normal.Z", "depth.Z"];
    assert_eq!(channels, &want);
    // 16-pixel tiles over 80 × 60: 5 × 4 of them, every pixel sent once.
    assert_eq!(tev.tiles, 20);
    assert!(tev.updates.iter().all(|&n| n == 1));
    let file = read_exr(&std::fs::read(&exr).unwrap());
    for c in want {
        let (a, b) = (&tev.pixels[c], &file[c].0);
        assert!(a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()), "channel {c} differs from the EXR");
    }
}

#[test]
fn a_tev_that_goes_away_does_not_stop_the_render() {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    // Takes the connection and hangs up at once.
    let server = std::thread::spawn(move || drop(listener.accept().unwrap()));
    let dir = tempfile::tempdir().unwrap();
    let exr = dir.path().join("kept.exr");
    rendered(&["-o", s(&exr), "--passes", "albedo", "--tile", "8", "--tev", &addr]);
    server.join().unwrap();
    assert_eq!(names(&read_exr(&std::fs::read(&exr).unwrap())).len(), 6);
}

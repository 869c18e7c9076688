//! Output images as renderers write them: PNG (8- or 16-bit sRGB), JPEG,
//! OpenEXR (linear half or float, with the albedo, normal and depth passes as
//! extra channels) and PFM (linear float, one file per pass), to a file or to
//! standard output.
//!
//! Everything that can be refused is refused by [`Output::create`], before any
//! rendering: an unknown format, a bit depth or passes the format cannot hold.
//! Files are written whole to `NAME.part` beside their place and renamed into
//! it, so a failed or interrupted render leaves neither a partial nor an
//! empty file.

use anyhow::Context;
use isin_tracer::render::linear_to_srgb;
use isin_tracer::{Frame, FrameBuffers};
use std::io::Write;
use std::path::{Path, PathBuf};

/// The formats, as `--format` names them and as file names end.
pub const FORMATS: &str = "png, jpg (or jpeg), exr, pfm";

/// An image format isin writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// PNG: sRGB, 8 bits a channel (16 with `--bit-depth 16`).
    Png,
    /// JPEG: sRGB, 8 bits a channel.
    #[value(alias = "jpeg")]
    Jpg,
    /// OpenEXR: linear float (half with `--bit-depth 16`), passes as extra channels.
    Exr,
    /// Portable float map: linear 32-bit float, passes as files beside it.
    Pfm,
}

impl Format {
    /// The format a file name's extension names, if any (case-insensitive).
    pub fn from_path(path: &Path) -> Option<Format> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        Some(match ext.as_str() {
            "png" => Format::Png,
            "jpg" | "jpeg" => Format::Jpg,
            "exr" => Format::Exr,
            "pfm" => Format::Pfm,
            _ => return None,
        })
    }

    /// Whether the format keeps linear floats (and so can hold passes).
    pub fn is_linear(self) -> bool {
        matches!(self, Format::Exr | Format::Pfm)
    }

    /// Its name in messages.
    fn name(self) -> &'static str {
        match self {
            Format::Png => "PNG",
            Format::Jpg => "JPEG",
            Format::Exr => "EXR",
            Format::Pfm => "PFM",
        }
    }
}

/// A pass written beside the beauty (`--passes`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, clap::ValueEnum)]
pub enum Pass {
    /// First-hit surface colour, linear RGB in `[0, 1]`.
    Albedo,
    /// First-hit shading normal, world space (X, Y, Z in `[-1, 1]`).
    Normal,
    /// First-hit distance from the eye along the camera ray (`+inf` for the background).
    Depth,
}

impl Pass {
    /// The pass's name: its EXR layer, and its PFM file's infix.
    pub fn name(self) -> &'static str {
        match self {
            Pass::Albedo => "albedo",
            Pass::Normal => "normal",
            Pass::Depth => "depth",
        }
    }

    /// Its channels' names within the layer.
    pub fn channels(self) -> &'static [&'static str] {
        match self {
            Pass::Albedo => &["R", "G", "B"],
            Pass::Normal => &["X", "Y", "Z"],
            Pass::Depth => &["Z"],
        }
    }
}

/// The full channel names of an image with `passes`, in the order
/// [`channel_values`] gives their values: `R`, `G`, `B`, then each pass's as
/// `LAYER.CHANNEL` (e.g. `albedo.R`, `normal.X`, `depth.Z`).
pub fn channel_names(passes: &[Pass]) -> Vec<String> {
    let mut names: Vec<String> = ["R", "G", "B"].map(String::from).into();
    for p in passes {
        names.extend(p.channels().iter().map(|c| format!("{}.{c}", p.name())));
    }
    names
}

/// The values of pixel `i` of `buffers` in [`channel_names`] order.
///
/// # Panics
/// If `passes` is not empty and `buffers` were rendered without passes.
pub fn channel_values(buffers: &FrameBuffers, passes: &[Pass], i: usize, out: &mut Vec<f32>) {
    out.extend(buffers.beauty[i]);
    for p in passes {
        let all = buffers.passes.as_ref().expect("rendered with passes");
        match p {
            Pass::Albedo => out.extend(all.albedo[i]),
            Pass::Normal => out.extend(all.normal[i]),
            Pass::Depth => out.push(all.depth[i]),
        }
    }
}

/// How the image is to be written: chosen and checked before rendering.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Spec {
    /// The format.
    pub format: Format,
    /// Bits per channel: 8 or 16 for PNG, 8 for JPEG, 16 (half) or 32 for
    /// EXR, 32 for PFM.
    pub bits: u32,
    /// Passes besides the beauty, sorted, without repeats.
    pub passes: Vec<Pass>,
}

impl Spec {
    /// The spec for writing to `path` (`-` for standard output): the format
    /// is `format` when given, else the file name's extension (PNG for
    /// standard output); `bits` defaults to the format's (8 for PNG and JPEG,
    /// 32 for EXR and PFM).
    pub fn new(
        path: &Path,
        format: Option<Format>,
        bits: Option<u32>,
        passes: &[Pass],
    ) -> anyhow::Result<Spec> {
        let stdout = is_stdout(path);
        let format = match (format, stdout) {
            (Some(f), _) => f,
            (None, true) => Format::Png,
            (None, false) => Format::from_path(path).with_context(|| {
                format!(
                    "cannot write {}: isin writes {FORMATS} images; name the file so \
                     (or say which with --format)",
                    path.display()
                )
            })?,
        };
        let bits = match (format, bits) {
            (Format::Png | Format::Jpg, None) => 8,
            (Format::Exr | Format::Pfm, None) => 32,
            (Format::Png, Some(b @ (8 | 16))) | (Format::Jpg, Some(b @ 8)) => b,
            (Format::Exr, Some(b @ (16 | 32))) | (Format::Pfm, Some(b @ 32)) => b,
            (f, Some(b)) => anyhow::bail!(
                "--bit-depth {b} does not fit {}: PNG takes 8 or 16, JPEG 8, EXR 16 (half) or 32 (float), PFM 32",
                f.name()
            ),
        };
        let mut passes = passes.to_vec();
        passes.sort();
        passes.dedup();
        if !passes.is_empty() && !format.is_linear() {
            anyhow::bail!(
                "--passes needs a linear float format: write .exr (passes as extra layers) or .pfm \
                 (one file per pass), not {}",
                format.name()
            );
        }
        if !passes.is_empty() && format == Format::Pfm && stdout {
            anyhow::bail!("--passes with PFM writes one file per pass: give -o a file name, not -");
        }
        Ok(Spec { format, bits, passes })
    }

    /// Whether the image needs more than the RGB8 pixels of a [`Frame`].
    pub fn needs_linear(&self) -> bool {
        self.format.is_linear() || self.bits > 8 || !self.passes.is_empty()
    }
}

/// Whether `path` means standard output.
pub fn is_stdout(path: &Path) -> bool {
    path.as_os_str() == "-"
}

/// An output image being written: its spec checked and its files created
/// (as `NAME.part`) before any rendering, renamed into place once all are
/// whole, removed if they never are.
pub struct Output {
    spec: Spec,
    /// `None` for standard output.
    path: Option<PathBuf>,
    /// Final and temporary names of every file: the image, then (PFM) the passes'.
    files: Vec<(PathBuf, PathBuf)>,
}

impl Output {
    /// Checks `spec` against `path` and creates the temporary files.
    pub fn create(path: &Path, spec: Spec) -> anyhow::Result<Output> {
        if is_stdout(path) {
            return Ok(Output { spec, path: None, files: Vec::new() });
        }
        let mut finals = vec![path.to_owned()];
        if spec.format == Format::Pfm {
            finals.extend(spec.passes.iter().map(|p| pass_path(path, *p)));
        }
        let mut out = Output { spec, path: Some(path.to_owned()), files: Vec::new() };
        for f in finals {
            let mut name = f.file_name().map(|n| n.to_os_string()).unwrap_or_default();
            name.push(".part");
            let part = f.with_file_name(name);
            std::fs::File::create(&part).with_context(|| format!("cannot write {}", f.display()))?;
            out.files.push((f, part));
        }
        Ok(out)
    }

    /// The spec.
    pub fn spec(&self) -> &Spec {
        &self.spec
    }

    /// Where the image goes, for messages (`-` for standard output).
    pub fn display(&self) -> String {
        self.path.as_ref().map_or_else(|| "standard output".into(), |p| p.display().to_string())
    }

    /// Writes an image that has only RGB8 pixels (a cluster render): PNG or
    /// JPEG at 8 bits, as checked by the caller ([`Spec::needs_linear`]).
    pub fn write_frame(self, frame: &Frame) -> anyhow::Result<()> {
        anyhow::ensure!(!self.spec.needs_linear(), "an RGB8 frame cannot be written as {:?}", self.spec);
        let bytes = encode_8bit(frame, self.spec.format)?;
        self.finish(vec![bytes])
    }

    /// Encodes `buffers` (rendered with passes if the spec has any) and
    /// writes every file.
    pub fn write(self, buffers: &FrameBuffers) -> anyhow::Result<()> {
        let (w, h) = (buffers.width, buffers.height);
        let files = match self.spec.format {
            Format::Png if self.spec.bits == 16 => vec![encode_png16(buffers)?],
            Format::Png | Format::Jpg => vec![encode_8bit(&buffers.to_frame(), self.spec.format)?],
            Format::Exr => vec![encode_exr(buffers, &self.spec.passes, self.spec.bits == 16)?],
            Format::Pfm => {
                let mut files = vec![encode_pfm(w, h, 3, |i, out| out.extend(buffers.beauty[i]))];
                let passes = buffers.passes.as_ref();
                for p in &self.spec.passes {
                    let all = passes.context("rendered without passes")?;
                    files.push(match p {
                        Pass::Albedo => encode_pfm(w, h, 3, |i, out| out.extend(all.albedo[i])),
                        Pass::Normal => encode_pfm(w, h, 3, |i, out| out.extend(all.normal[i])),
                        Pass::Depth => encode_pfm(w, h, 1, |i, out| out.push(all.depth[i])),
                    });
                }
                files
            }
        };
        self.finish(files)
    }

    /// Writes the encoded files (in [`Output::files`] order) to their
    /// temporary names, then renames them all into place.
    fn finish(mut self, contents: Vec<Vec<u8>>) -> anyhow::Result<()> {
        if self.path.is_none() {
            let mut out = std::io::stdout().lock();
            for c in &contents {
                out.write_all(c).context("cannot write the image to standard output")?;
            }
            return out.flush().context("cannot write the image to standard output");
        }
        for ((path, part), bytes) in self.files.iter().zip(&contents) {
            std::fs::write(part, bytes).with_context(|| format!("cannot write {}", path.display()))?;
        }
        for (path, part) in &self.files {
            std::fs::rename(part, path).with_context(|| format!("cannot write {}", path.display()))?;
        }
        self.files.clear();
        Ok(())
    }
}

impl Drop for Output {
    fn drop(&mut self) {
        // Emptied once renamed; otherwise leftovers.
        for (_, part) in &self.files {
            let _ = std::fs::remove_file(part);
        }
    }
}

/// Where a PFM output's pass goes: `out.pfm` → `out.albedo.pfm`.
pub fn pass_path(path: &Path, pass: Pass) -> PathBuf {
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let ext = path.extension().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "pfm".into());
    path.with_file_name(format!("{stem}.{}.{ext}", pass.name()))
}

/// An 8-bit PNG or JPEG of `frame`.
fn encode_8bit(frame: &Frame, format: Format) -> anyhow::Result<Vec<u8>> {
    let format = match format {
        Format::Jpg => image::ImageFormat::Jpeg,
        _ => image::ImageFormat::Png,
    };
    let mut out = std::io::Cursor::new(Vec::new());
    image::write_buffer_with_format(
        &mut out,
        &frame.rgb,
        frame.width,
        frame.height,
        image::ColorType::Rgb8,
        format,
    )
    .context("cannot encode the image")?;
    Ok(out.into_inner())
}

/// Encodes a linear value as a 16-bit sRGB sample: clamped to `[0, 1]`
/// (NaN → 0), the exact sRGB curve, rounded to nearest.
pub fn encode_srgb16(c: f32) -> u16 {
    let c = if c.is_nan() { 0.0 } else { c.clamp(0.0, 1.0) };
    (linear_to_srgb(c) * 65535.0 + 0.5).min(65535.0) as u16
}

/// A 16-bit sRGB PNG of the beauty.
fn encode_png16(buffers: &FrameBuffers) -> anyhow::Result<Vec<u8>> {
    use image::ImageEncoder;
    let bytes: Vec<u8> =
        buffers.beauty.iter().flatten().flat_map(|&c| encode_srgb16(c).to_ne_bytes()).collect();
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new(&mut out)
        .write_image(&bytes, buffers.width, buffers.height, image::ExtendedColorType::Rgb16)
        .context("cannot encode the image")?;
    Ok(out)
}

/// A single-part OpenEXR image: the beauty as `R`, `G`, `B`, each pass as
/// `LAYER.CHANNEL` ([`channel_names`]); half floats when `half`, except the
/// depth, always 32-bit (half's 11-bit mantissa is too coarse for distances).
/// ZIP-compressed scan lines, which every reader opens.
fn encode_exr(buffers: &FrameBuffers, passes: &[Pass], half: bool) -> anyhow::Result<Vec<u8>> {
    use exr::prelude::*;
    let names = channel_names(passes);
    let n = buffers.width as usize * buffers.height as usize;
    let mut planes: Vec<Vec<f32>> = vec![Vec::with_capacity(n); names.len()];
    let mut pixel = Vec::with_capacity(names.len());
    for i in 0..n {
        pixel.clear();
        channel_values(buffers, passes, i, &mut pixel);
        for (plane, &v) in planes.iter_mut().zip(&pixel) {
            plane.push(v);
        }
    }
    let channels: Vec<AnyChannel<FlatSamples>> = names
        .iter()
        .zip(planes)
        .map(|(name, plane)| {
            let samples = if half && !name.starts_with("depth.") {
                FlatSamples::F16(plane.into_iter().map(f16::from_f32).collect())
            } else {
                FlatSamples::F32(plane)
            };
            AnyChannel::new(name.as_str(), samples)
        })
        .collect();
    let layer = Layer::new(
        (buffers.width as usize, buffers.height as usize),
        LayerAttributes::default(),
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(SmallVec::from_vec(channels)),
    );
    let mut out = std::io::Cursor::new(Vec::new());
    Image::from_layer(layer).write().to_buffered(&mut out).context("cannot encode the EXR image")?;
    Ok(out.into_inner())
}

/// A PFM image of `channels` (3: `PF`, colour; 1: `Pf`, greyscale) floats a
/// pixel, given by `pixel(index, out)` for row-major index `index`: rows
/// bottom to top, little-endian (scale −1), as the format has them.
fn encode_pfm(w: u32, h: u32, channels: usize, pixel: impl Fn(usize, &mut Vec<f32>)) -> Vec<u8> {
    let kind = if channels == 3 { "PF" } else { "Pf" };
    let mut out = format!("{kind}\n{w} {h}\n-1.0\n").into_bytes();
    let mut values = Vec::with_capacity(channels);
    for y in (0..h as usize).rev() {
        for x in 0..w as usize {
            values.clear();
            pixel(y * w as usize + x, &mut values);
            for v in &values {
                out.extend(v.to_le_bytes());
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(path: &str, format: Option<Format>, bits: Option<u32>, passes: &[Pass]) -> anyhow::Result<Spec> {
        Spec::new(Path::new(path), format, bits, passes)
    }

    #[test]
    fn the_format_comes_from_format_else_the_extension_else_png_for_stdout() {
        assert_eq!(spec("a.PNG", None, None, &[]).unwrap().format, Format::Png);
        assert_eq!(spec("a.jpeg", None, None, &[]).unwrap().format, Format::Jpg);
        assert_eq!(spec("a.exr", None, None, &[]).unwrap().bits, 32);
        assert_eq!(spec("-", None, None, &[]).unwrap().format, Format::Png);
        assert_eq!(spec("-", Some(Format::Exr), None, &[]).unwrap().format, Format::Exr);
        assert_eq!(spec("a.img", Some(Format::Pfm), None, &[]).unwrap().format, Format::Pfm);
        let e = spec("a.tiff", None, None, &[]).unwrap_err().to_string();
        assert!(e.contains("a.tiff") && e.contains(FORMATS), "{e}");
    }

    #[test]
    fn bit_depths_and_passes_the_format_cannot_hold_are_refused() {
        assert_eq!(spec("a.png", None, Some(16), &[]).unwrap().bits, 16);
        assert_eq!(spec("a.exr", None, Some(16), &[]).unwrap().bits, 16);
        for (path, bits) in [("a.jpg", 16), ("a.pfm", 16), ("a.exr", 8), ("a.png", 32)] {
            let e = spec(path, None, Some(bits), &[]).unwrap_err().to_string();
            assert!(e.contains(&format!("--bit-depth {bits}")), "{e}");
        }
        let e = spec("a.png", None, None, &[Pass::Albedo]).unwrap_err().to_string();
        assert!(e.contains("--passes") && e.contains(".exr"), "{e}");
        assert!(spec("-", Some(Format::Pfm), None, &[Pass::Depth]).is_err());
        let s = spec("a.exr", None, None, &[Pass::Depth, Pass::Albedo, Pass::Depth]).unwrap();
        assert_eq!(s.passes, [Pass::Albedo, Pass::Depth]);
        assert!(s.needs_linear() && spec("a.png", None, Some(16), &[]).unwrap().needs_linear());
        assert!(!spec("a.jpg", None, None, &[]).unwrap().needs_linear());
    }

    #[test]
    fn channel_names_follow_the_passes() {
        assert_eq!(
            channel_names(&[Pass::Albedo, Pass::Normal, Pass::Depth]),
            [
                "R", "G", "B", "albedo.R", "albedo.G", "albedo.B", "normal.X", "normal.Y", "normal.Z",
                "depth.Z"
            ]
        );
        assert_eq!(pass_path(Path::new("d/out.pfm"), Pass::Normal), Path::new("d/out.normal.pfm"));
    }

    #[test]
    fn sixteen_bit_srgb_spans_the_range_and_agrees_with_eight_bit() {
        assert_eq!((encode_srgb16(0.0), encode_srgb16(1.0), encode_srgb16(f32::NAN)), (0, 65535, 0));
        assert_eq!(encode_srgb16(9.0), 65535);
        for i in 0..=1000 {
            let c = i as f32 / 1000.0;
            let (a, b) = (encode_srgb16(c) as f32 / 257.0, isin_tracer::render::encode_srgb8(c) as f32);
            assert!((a - b).abs() <= 0.51, "at {c}: {a} vs {b}");
        }
    }
}

//! `isin scene`: the scene made around a mesh file, as TOML on standard output.

use clap::Args;
use std::io::Write as _;
use std::path::PathBuf;

/// Arguments of `isin scene`.
#[derive(Args, Debug)]
pub struct SceneArgs {
    /// Mesh file (.gltf, .glb, .obj); a .toml scene is printed as it is.
    ///
    /// The printed scene refers to the mesh by this path, so save it in the
    /// current directory (`isin scene models/x.gltf > x.toml`); it renders to
    /// the same pixels as `isin render models/x.gltf`.
    pub file: PathBuf,
}

/// Runs `isin scene`.
pub fn run(args: SceneArgs) -> anyhow::Result<()> {
    let text = crate::assets::scene_text(&args.file)?;
    std::io::stdout().lock().write_all(text.as_bytes())?;
    Ok(())
}

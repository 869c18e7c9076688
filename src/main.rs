//! `isin` — interactive, distributed CPU ray tracer.

mod assets;
mod cli;
mod frame_cache;
mod netlab;

fn main() -> anyhow::Result<()> {
    cli::run()
}

//! `isin` — interactive, distributed CPU ray tracer.

mod assets;
mod cli;

fn main() -> anyhow::Result<()> {
    cli::run()
}

//! `isin` — interactive, distributed CPU ray tracer.

mod assets;
mod cli;
mod netlab;

fn main() -> anyhow::Result<()> {
    cli::run()
}

//! `isin` — interactive, distributed CPU ray tracer.

mod assets;
mod cli;
mod frame_cache;
mod outputs;
mod tev;

/// Large blocks (the BVH, the triangle blocks) in huge pages, as Embree's own allocator does.
#[global_allocator]
static ALLOC: isin_tracer::memory::HugePages = isin_tracer::memory::HugePages;

fn main() -> anyhow::Result<()> {
    cli::run()
}

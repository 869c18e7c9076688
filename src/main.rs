//! `isin` — interactive, distributed CPU ray tracer.

mod assets;
mod cli;
mod frame_cache;
mod outputs;
mod tev;

/// Large blocks (the BVH, the triangle blocks) in huge pages, as Embree's own allocator does;
/// small ones from mimalloc (the workspace's Cargo.toml says why).
#[global_allocator]
static ALLOC: isin_tracer::memory::HugePages<mimalloc::MiMalloc> =
    isin_tracer::memory::HugePages::over(mimalloc::MiMalloc);

fn main() -> anyhow::Result<()> {
    cli::run()
}

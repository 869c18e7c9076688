//! Command-line interface.

mod bench;
mod cluster;
mod master;
mod render;
mod slave;

use clap::{Parser, Subcommand};

/// isin — an interactive, distributed CPU ray tracer.
#[derive(Parser, Debug)]
#[command(version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Render a scene to a PNG file (locally, or through a cluster with --cluster).
    Render(render::RenderArgs),
    /// Serve a scene to slaves and viewers; prints a join ticket.
    Master(master::MasterArgs),
    /// Render tiles for a master.
    Slave(slave::SlaveArgs),
    /// Benchmarks (`isin bench cluster`).
    Bench(bench::BenchArgs),
}

/// Parses the command line and runs the chosen command.
pub fn run() -> anyhow::Result<()> {
    init_logging();
    let cli = Cli::parse();
    match cli.command {
        Some(Command::Render(args)) => render::run(args),
        Some(Command::Master(args)) => master::run(args),
        Some(Command::Slave(args)) => slave::run(args),
        Some(Command::Bench(args)) => bench::run(args),
        None => cluster::run_default(),
    }
}

fn init_logging() {
    use tracing_subscriber::EnvFilter;
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("info"));
    let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr());
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(ansi)
        .with_writer(std::io::stderr)
        .try_init();
}

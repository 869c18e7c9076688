//! Command-line interface.

mod bounded;
mod cluster;
mod fly;
mod master;
mod remote;
mod render;
mod scene;
mod slave;
mod view;

use clap::{Parser, Subcommand};

/// isin — an interactive, distributed CPU ray tracer.
///
/// Without a command: a master and local slaves in this process, shown in the
/// viewer window on scenes/paper.toml (the window options below apply); with
/// no display, a few frames rendered to paper.png.
#[derive(Parser, Debug)]
#[command(version, about, long_about = None, args_conflicts_with_subcommands = true)]
#[command(after_help = view::KEYS_HELP)]
pub struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    /// Window options of the default viewer.
    #[command(flatten)]
    window: view::WindowArgs,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Render a scene to a PNG file (locally, or through a cluster with --cluster).
    Render(render::RenderArgs),
    /// Fly through a scene in a window (keyboard and mouse navigation).
    #[command(after_help = view::KEYS_HELP)]
    View(view::ViewArgs),
    /// Replay a camera path headless: one PNG per camera, with frame times.
    Fly(fly::FlyArgs),
    /// Print the scene isin makes around a mesh file (.gltf, .glb, .obj) as editable TOML.
    Scene(scene::SceneArgs),
    /// Serve a scene to slaves and viewers; prints a join ticket.
    Master(master::MasterArgs),
    /// Render tiles for a master.
    Slave(slave::SlaveArgs),
    /// Benchmarks (`isin bench cluster`).
    Bench(isin_lab::bench::BenchArgs),
}

/// Parses the command line and runs the chosen command.
pub fn run() -> anyhow::Result<()> {
    init_logging();
    let cli = Cli::parse();
    match cli.command {
        Some(Command::Render(args)) => render::run(args),
        Some(Command::View(args)) => view::run(args),
        Some(Command::Fly(args)) => fly::run(args),
        Some(Command::Scene(args)) => scene::run(args),
        Some(Command::Master(args)) => master::run(args),
        Some(Command::Slave(args)) => slave::run(args),
        Some(Command::Bench(args)) => isin_lab::bench::run(args),
        None => cluster::run_default(&cli.window),
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

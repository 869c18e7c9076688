//! Command-line interface.

mod bounded;
mod cluster;
mod fly;
mod logging;
mod master;
mod remote;
mod render;
mod scene;
mod slave;
mod status;
mod ticket;
mod view;

use clap::{CommandFactory, Parser, Subcommand};
use std::ffi::OsString;

/// What `isin` does with no arguments, at the head of its help.
const NO_ARGUMENTS: &str = "\
With no arguments: a master and two local slaves in this process render the default scene
(built into the binary) in a viewer window; the window options below apply. Without a display
(no DISPLAY), a few frames are rendered instead and the first is written to paper.png in the
current folder.
`isin FILE [OPTIONS]` is short for `isin view FILE [OPTIONS]`.";

/// An interactive, distributed CPU ray tracer.
#[derive(Parser, Debug)]
#[command(version, propagate_version = true, about, long_about = None, before_help = NO_ARGUMENTS)]
#[command(args_conflicts_with_subcommands = true)]
#[command(
    help_template = "{about-with-newline}\n{before-help}{usage-heading} {usage}\n\n{all-args}{after-help}"
)]
#[command(override_usage = "isin [OPTIONS]\n       isin FILE [VIEW OPTIONS]\n       isin <COMMAND>")]
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
    /// Render a scene to an image file: PNG, JPEG, EXR or PFM (locally, or through a cluster with --connect).
    Render(render::RenderArgs),
    /// Fly through a scene in a window (keyboard and mouse navigation).
    #[command(after_help = view::KEYS_HELP)]
    View(view::ViewArgs),
    /// Replay a camera path headless: one PNG per camera, with frame times.
    Fly(fly::FlyArgs),
    /// Print the scene isin makes around a mesh file (.gltf, .glb, .obj) as editable TOML.
    Scene(scene::SceneArgs),
    /// Serve slaves and clients (a default scene, and those clients bring); prints a join ticket.
    Master(master::MasterArgs),
    /// Render tiles for a master.
    Slave(slave::SlaveArgs),
    /// Print a cluster's slaves, clients and jobs.
    Status(status::StatusArgs),
    /// Benchmarks of whole clusters (run from the checkout; `scaling` and `transports` need root).
    ///
    /// Their default scenes and output folders are relative to the checkout.
    Bench(isin_lab::bench::BenchArgs),
    /// Print a shell completion script (e.g. `isin completions bash > /etc/bash_completion.d/isin`).
    Completions {
        /// The shell.
        shell: clap_complete::Shell,
    },
    /// Print the manual page (roff; `isin man | man -l -`).
    Man,
}

/// Parses the command line and runs the chosen command.
pub fn run() -> anyhow::Result<()> {
    logging::init();
    let cli = Cli::parse_from(view_shorthand(std::env::args_os().collect()));
    match cli.command {
        Some(Command::Render(args)) => render::run(args),
        Some(Command::View(args)) => view::run(args),
        Some(Command::Fly(args)) => fly::run(args),
        Some(Command::Scene(args)) => scene::run(args),
        Some(Command::Master(args)) => master::run(args),
        Some(Command::Slave(args)) => slave::run(args),
        Some(Command::Status(args)) => status::run(args),
        Some(Command::Bench(args)) => isin_lab::bench::run(args),
        Some(Command::Completions { shell }) => {
            clap_complete::generate(shell, &mut Cli::command(), "isin", &mut std::io::stdout());
            Ok(())
        }
        Some(Command::Man) => {
            let cmd = Cli::command();
            let description = format!("{}\n\n{NO_ARGUMENTS}", cmd.get_about().unwrap_or_default());
            Ok(clap_mangen::Man::new(cmd.long_about(description)).render(&mut std::io::stdout())?)
        }
        None => cluster::run_default(&cli.window),
    }
}

/// `isin FILE …` as `isin view FILE …`: the first argument is taken for a
/// file when it is no command and looks like a path (it exists, or holds a
/// `.` or a `/`), so that a mistyped command still gets clap's suggestion.
fn view_shorthand(mut args: Vec<OsString>) -> Vec<OsString> {
    let Some(first) = args.get(1).and_then(|a| a.to_str()) else { return args };
    let command = first == "help" || Cli::command().find_subcommand(first).is_some();
    let path_like = first.contains(['.', '/']) || std::path::Path::new(first).exists();
    if !first.starts_with('-') && !command && path_like {
        args.insert(1, "view".into());
    }
    args
}

//! The `easyhec` command line: parses, dispatches to one file per subcommand under `cli/`,
//! and prints any error as one line.

mod cli;

use std::process::ExitCode;

use clap::{CommandFactory, Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "easyhec",
    version = cli::version::version_line(),
    about = "Markerless eye-to-hand camera calibration by silhouette alignment"
)]
struct Cli {
    #[command(flatten)]
    log: cli::logging::LogArgs,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the whole calibration loop on a configured cell (move, capture, solve, explore).
    Calibrate(cli::calibrate::CalibrateArgs),
    /// Solve camera_from_base from a recorded run directory (easyhec-run/1).
    Solve(cli::solve::SolveArgs),
    /// Write a synthetic run directory with a separate ground-truth file.
    #[cfg(feature = "sim")]
    Synth(cli::synth::SynthArgs),
    /// Convert another tool's recordings into a run directory.
    #[command(subcommand)]
    Import(cli::import::ImportCommand),
    /// Write a result in the form another tool reads.
    Export(cli::export::ExportArgs),
    /// Publish a result on ROS 2's /tf_static until stopped (build with --features ros2).
    Publish(cli::publish::PublishArgs),
    /// Publish a simulated cell's camera as ROS 2 Image and CameraInfo topics (build with
    /// --features ros2).
    #[cfg(feature = "sim")]
    SimCamera(cli::sim_camera::SimCameraArgs),
    /// Benchmarks (figures in docs/benchmarks.md).
    #[command(subcommand)]
    Bench(cli::bench::BenchCommand),
    /// Serve calibrations of a cell over HTTP (API, web page, bump checks) until stopped.
    Daemon(cli::daemon::DaemonArgs),
    /// Print a shell completion script (e.g. `easyhec completions bash > /etc/bash_completion.d/easyhec`).
    Completions {
        /// The shell to complete in.
        #[arg(value_enum)]
        shell: clap_complete::Shell,
    },
}

fn main() -> ExitCode {
    // With `--features ur`, this executable is also the UR driver's `ur_rtde` child process.
    easyhec_drivers::ur::serve_worker_if_asked();
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e)
            if matches!(
                e.kind(),
                clap::error::ErrorKind::DisplayHelp
                    | clap::error::ErrorKind::DisplayVersion
                    | clap::error::ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand
            ) =>
        {
            e.exit()
        }
        Err(e) => {
            eprintln!(
                "error: {} (see easyhec --help)",
                easyhec::error::cut(&one_line(&e))
            );
            return ExitCode::FAILURE;
        }
    };
    cli.log.init();
    let outcome = match cli.command {
        Command::Calibrate(a) => cli::calibrate::run(a),
        Command::Solve(a) => cli::solve::run(a),
        #[cfg(feature = "sim")]
        Command::Synth(a) => cli::synth::run(a),
        Command::Import(i) => i.run(),
        Command::Export(a) => cli::export::run(a),
        Command::Publish(a) => cli::publish::run(a),
        #[cfg(feature = "sim")]
        Command::SimCamera(a) => cli::sim_camera::run(a),
        Command::Bench(b) => b.run(),
        Command::Daemon(a) => cli::daemon::run(a),
        Command::Completions { shell } => {
            clap_complete::generate(
                shell,
                &mut Cli::command(),
                "easyhec",
                &mut std::io::stdout(),
            );
            Ok(())
        }
    };
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if e.downcast_ref::<cli::exit::Exit>().is_some() => {
            let exit = e.downcast_ref::<cli::exit::Exit>().expect("checked above");
            if let Some(m) = &exit.message {
                eprintln!("error: {m}");
            }
            ExitCode::from(exit.code)
        }
        Err(e) => {
            // The one place a command's error is reported: as the process's last line, in
            // the same one-line form whatever the log settings (scripts and tests read it).
            let chain: Vec<String> = e.chain().map(|c| c.to_string()).collect();
            eprintln!("error: {}", easyhec::error::cut(&chain.join(": ")));
            ExitCode::FAILURE
        }
    }
}

/// A command-line error as one line, as for every other bad input: clap's first line, plus the
/// allowed values when clap lists them (`--help` has the rest).
fn one_line(e: &clap::Error) -> String {
    let text = e.render().to_string();
    let mut lines = text.lines().map(str::trim);
    let first = lines
        .next()
        .unwrap_or("invalid arguments")
        .trim_start_matches("error: ");
    match lines.find(|l| l.starts_with("[possible values:")) {
        Some(values) => format!(
            "{first}: allowed: {}",
            values
                .trim_start_matches("[possible values: ")
                .trim_end_matches(']')
        ),
        None => first.to_string(),
    }
}

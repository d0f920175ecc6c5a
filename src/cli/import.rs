//! `easyhec import`: another tool's recordings as a run directory.

use super::exit::outln;
use std::path::PathBuf;

use clap::Subcommand;
use easyhec::interop::{import_easyhec, EasyHecImport};
use easyhec::robot::{RobotModel, RobotSource};

use super::urdf_for_run;

#[derive(Subcommand)]
pub enum ImportCommand {
    /// EasyHeC's offline folder: color/ mask/ qpos/ K.txt [initial_guess.txt].
    Easyhec {
        /// Source folder.
        dir: PathBuf,
        /// Output run directory.
        #[arg(long)]
        out: PathBuf,
        /// Robot URDF.
        #[arg(long)]
        urdf: PathBuf,
        /// Actuated joints in qpos order (default: the URDF's movable, non-mimic joints).
        #[arg(long, value_delimiter = ',')]
        joints: Option<Vec<String>>,
        /// Links the masks leave out (e.g. fingers).
        #[arg(long, value_delimiter = ',')]
        ignore_links: Vec<String>,
        /// Replace OUT when it exists and is not empty (refused otherwise).
        #[arg(long)]
        force: bool,
    },
}

impl ImportCommand {
    /// Runs the import.
    pub fn run(self) -> anyhow::Result<()> {
        match self {
            ImportCommand::Easyhec {
                dir,
                out,
                urdf,
                joints,
                ignore_links,
                force,
            } => easyhec(dir, out, urdf, joints, ignore_links, force),
        }
    }
}

/// On SIGINT, SIGTERM or SIGHUP during the import, deletes its half-written staging folder
/// before the process ends (128 + the signal): the default action would leave a hidden
/// folder of copied frames beside the target.
fn abandon_staging_on_signals() {
    let watcher = std::thread::Builder::new()
        .name("easyhec-import-signals".into())
        .spawn(|| {
            let Ok(rt) = tokio::runtime::Builder::new_current_thread()
                .enable_io()
                .build()
            else {
                return;
            };
            rt.block_on(async {
                use tokio::signal::unix::{signal, SignalKind};
                let (Ok(mut int), Ok(mut term), Ok(mut hup)) = (
                    signal(SignalKind::interrupt()),
                    signal(SignalKind::terminate()),
                    signal(SignalKind::hangup()),
                ) else {
                    return;
                };
                let code = tokio::select! {
                    _ = int.recv() => libc::SIGINT,
                    _ = term.recv() => libc::SIGTERM,
                    _ = hup.recv() => libc::SIGHUP,
                };
                eprintln!("easyhec: import stopped by a signal; its half-written copy is deleted");
                easyhec::interop::import::abandon_staging_and_exit(128 + code);
            });
        });
    if let Err(e) = watcher {
        tracing::warn!("cannot watch for signals during the import: {e}");
    }
}

/// Converts EasyHeC's offline folder into a run directory.
pub fn easyhec(
    dir: PathBuf,
    out: PathBuf,
    urdf: PathBuf,
    joints: Option<Vec<String>>,
    ignore_links: Vec<String>,
    force: bool,
) -> anyhow::Result<()> {
    // The URDF is loaded with the named joints and links, so a misspelt, fixed or repeated
    // joint fails here, before anything is read from the source folder.
    let robot = RobotModel::load(&RobotSource {
        urdf: urdf.clone(),
        joints: joints.clone(),
        ignore_links: ignore_links.clone(),
        ..Default::default()
    })?;
    let joints = robot.joint_names().iter().map(|s| s.to_string()).collect();
    let urdf = urdf_for_run(&urdf)?;
    abandon_staging_on_signals();
    let run = import_easyhec(&EasyHecImport {
        source: dir,
        out: out.clone(),
        urdf,
        joints,
        ignore_links,
        initial_guess: None,
        force,
    })?;
    outln!("imported {} views into {}", run.views.len(), out.display());
    Ok(())
}

//! `easyhec calibrate`: the closed loop on a configured cell.

use super::exit::{self, outln, Exit};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicI32, Ordering};
use std::sync::Arc;
use tokio::signal::unix::Signal;

use clap::Args;
use easyhec::calibrate::{calibrate, ConfirmMove, PlannedPose, RunOptions};
use easyhec::cell::Cell;
use easyhec::config::{read_config, RendererChoice};
use easyhec::geometry::{rotation_error_deg, translation_error_mm};
use easyhec::run::rig::RunLayout;
use easyhec::time::rfc3339;

use super::fmt_joints;

#[derive(Args)]
pub struct CalibrateArgs {
    /// Cell config (TOML), e.g. config/sim-xarm6.toml.
    #[arg(long)]
    pub config: PathBuf,
    /// Run directory to record into (default: runs/<UTC time>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Plan and print the poses with their checks; never move.
    #[arg(long)]
    pub dry_run: bool,
    /// Ask before each move.
    #[arg(long)]
    pub confirm: bool,
    /// Renderer: cpu, wgpu or auto (overrides `[calibration] renderer`).
    #[arg(long)]
    pub renderer: Option<RendererChoice>,
}

/// Runs the closed loop on the configured cell and prints what it did.
pub fn run(a: CalibrateArgs) -> anyhow::Result<()> {
    let mut config = read_config(&a.config)?;
    if let Some(r) = a.renderer {
        config.calibration.renderer = r;
    }
    if let Some(p) = &a.out {
        let config_dir = a.config.parent().unwrap_or(Path::new("."));
        let reads = [a.config.clone(), config_dir.join(&config.robot.urdf)];
        if let Some(problem) = easyhec::io::output_dir_problem(p, &reads) {
            anyhow::bail!("{}: --out: {problem}", p.display());
        }
    }
    let cell = Arc::new(Cell::build(config, &a.config)?);
    let out = a.out.unwrap_or_else(|| {
        PathBuf::from("runs").join(rfc3339(std::time::SystemTime::now()).replace(':', "-"))
    });
    let confirm: Option<ConfirmMove> = if a.confirm {
        Some(Arc::new(|p: &PlannedPose| {
            let why = if p.in_image.is_finite() {
                format!("score {:.1}, {:.0}% in image", p.score, p.in_image * 100.0)
            } else {
                "a seeding view near the start: no camera estimate yet".into()
            };
            eprint!(
                "move to {} ({why}, clearance {:.1} mm self / {:.1} mm environment)? [y/N] ",
                fmt_joints(&p.joints),
                p.clearance.self_m * 1e3,
                p.clearance.environment_m * 1e3
            );
            let _ = std::io::stderr().flush();
            let mut line = String::new();
            std::io::stdin().read_line(&mut line).is_ok() && line.trim().eq_ignore_ascii_case("y")
        }))
    } else {
        None
    };
    let cancel = Arc::new(AtomicBool::new(false));
    let caught = Arc::new(AtomicI32::new(0));
    let opts = RunOptions {
        dry_run: a.dry_run,
        confirm,
        cancel: Some(cancel.clone()),
        // The bar shows at the default log level and above (the global `--quiet` hides it).
        progress: tracing::enabled!(tracing::Level::INFO),
        ..RunOptions::default()
    };
    let runtime = super::runtime()?;
    let watcher = runtime.spawn(stop_on_signals(cell.clone(), cancel, caught.clone()));
    let outcome = runtime.block_on(calibrate(&cell, &out, &opts));
    watcher.abort();
    let signal = caught.load(Ordering::SeqCst);
    if signal != 0 {
        return Err(stopped_by_signal(signal, &out, outcome.as_ref().ok()));
    }
    let outcome = outcome?;
    let r = &outcome.result;
    if a.dry_run {
        outln!(
            "dry run: {} poses planned from the first view's estimate (nothing moved); speed {:.2} rad/s",
            outcome.planned.len(),
            cell.config.calibration.speed_rad_s
        );
        for (i, p) in outcome.planned.iter().enumerate() {
            outln!(
                "  {}: {}  score {:.1}  in image {:.0}%  path {} poses checked, clearance {:.1} mm self / {:.1} mm environment",
                i + 1,
                fmt_joints(&p.joints),
                p.score,
                p.in_image * 100.0,
                p.path_samples,
                p.clearance.self_m * 1e3,
                p.clearance.environment_m * 1e3
            );
        }
        for (a, b, why) in &cell.checker.skipped_pairs {
            if *why == "always in contact"
                || *why == "allowed in config"
                || *why == "disabled in SRDF"
            {
                outln!("  not checked: {a} / {b} ({why})");
            }
        }
        return Ok(());
    }
    let t = |k: &str| r.timings_s.get(k).copied().unwrap_or(0.0);
    let rig = outcome.layout == RunLayout::NamedCameras;
    // A rig's fit and bounds are per camera (`report_cameras`); the run's line has its views,
    // times and why it stopped.
    let fit = if rig {
        String::new()
    } else {
        format!("; mean IoU {:.4}", outcome.report.mean_iou())
    };
    tracing::info!(
        "calibrated from {} views in {:.1} s (solve {:.1} s, explore {:.1} s, motion {:.1} s): {}{fit} -> {}",
        r.views_used.len(),
        t("total"),
        t("solve"),
        t("explore"),
        t("motion"),
        r.stop_reason,
        outcome.run_dir.join("result.json").display()
    );
    if let Some(u) = r.uncertainty.as_ref().filter(|_| !rig) {
        tracing::info!(
            "1-sigma: rotation [{:.4}, {:.4}, {:.4}] deg, translation [{:.3}, {:.3}, {:.3}] mm",
            u.rotation_deg[0],
            u.rotation_deg[1],
            u.rotation_deg[2],
            u.translation_mm[0],
            u.translation_mm[1],
            u.translation_mm[2]
        );
        if let Some(bound) = u.camera_centre_95_mm {
            tracing::info!("camera centre within {bound:.2} mm of the estimate (95%)");
        }
    }
    write_truth(&cell, &outcome.run_dir)?;
    report_cameras(&cell, &outcome)?;
    if outcome.faulted {
        return Err(Exit {
            code: exit::FAULT,
            message: Some(format!(
                "the loop stopped on an arm fault: {}; the run folder {} keeps the {} views recorded before it",
                r.stop_reason,
                outcome.run_dir.display(),
                r.views_used.len()
            )),
        }
        .into());
    }
    Ok(())
}

/// Waits for SIGINT, SIGTERM or SIGHUP. The first sets the loop's cancel flag and stops the
/// arm at once (the loop then closes the run folder with what it has); a second ends the
/// process at once. Without it the default action would kill the process mid-move with no
/// stop command sent to the arm.
async fn stop_on_signals(cell: Arc<Cell>, cancel: Arc<AtomicBool>, caught: Arc<AtomicI32>) {
    use tokio::signal::unix::{signal, SignalKind};
    let (Ok(mut int), Ok(mut term), Ok(mut hup)) = (
        signal(SignalKind::interrupt()),
        signal(SignalKind::terminate()),
        signal(SignalKind::hangup()),
    ) else {
        tracing::warn!("cannot watch for SIGINT, SIGTERM and SIGHUP: a signal ends the process without stopping the arm");
        return;
    };
    let first = next_signal(&mut int, &mut term, &mut hup).await;
    caught.store(first, Ordering::SeqCst);
    cancel.store(true, Ordering::SeqCst);
    eprintln!(
        "easyhec: {}: stopping the arm and closing the run folder (send it again to quit at once)",
        signal_name(first)
    );
    if let Err(e) = cell.arm.stop().await {
        eprintln!("easyhec: stopping the arm failed: {e}");
    }
    let second = next_signal(&mut int, &mut term, &mut hup).await;
    eprintln!("easyhec: {} again: quitting at once", signal_name(second));
    std::process::exit(128 + second);
}

/// The next of the three signals to arrive, by number.
async fn next_signal(int: &mut Signal, term: &mut Signal, hup: &mut Signal) -> i32 {
    tokio::select! {
        _ = int.recv() => libc::SIGINT,
        _ = term.recv() => libc::SIGTERM,
        _ = hup.recv() => libc::SIGHUP,
    }
}

/// What a calibration stopped by `signal` ends with: the exit code 128 + the signal, and a
/// line that says where the run is and how to solve what it recorded.
fn stopped_by_signal(
    signal: i32,
    out: &Path,
    outcome: Option<&easyhec::calibrate::Outcome>,
) -> anyhow::Error {
    let views = outcome.map_or(0, |o| o.result.views_used.len());
    let dir = outcome.map_or(out, |o| o.run_dir.as_path());
    let next = if views > 0 {
        format!(
            "solve what it recorded with `easyhec solve {}`",
            dir.display()
        )
    } else {
        "it recorded no view to solve".to_string()
    };
    Exit {
        code: u8::try_from(128 + signal).unwrap_or(1),
        message: Some(format!(
            "stopped by {} after {views} views (the arm was sent a stop); the run folder {} is closed: {next}",
            signal_name(signal),
            dir.display()
        )),
    }
    .into()
}

/// The conventional name of the signals `calibrate` handles.
fn signal_name(signal: i32) -> &'static str {
    match signal {
        libc::SIGINT => "SIGINT",
        libc::SIGTERM => "SIGTERM",
        libc::SIGHUP => "SIGHUP",
        _ => "a signal",
    }
}

/// Each camera's lines: for named cameras, why it stopped and its fit and bound (a run of
/// one camera printed those above); on a simulated cell, its error against the truth.
fn report_cameras(cell: &Cell, outcome: &easyhec::calibrate::Outcome) -> anyhow::Result<()> {
    let named = outcome.layout == RunLayout::NamedCameras;
    for (unit, cam) in cell.cameras().iter().zip(&outcome.cameras) {
        if named {
            let bound = cam.report.uncertainty.camera_centre_95_mm;
            tracing::info!(
                "{}: mean IoU {:.4}, camera centre within {bound:.2} mm (95%); {}",
                cam.name,
                cam.report.mean_iou(),
                cam.result.stop_reason
            );
        }
        let Some(truth) = unit.sim.camera_from_base else {
            continue;
        };
        let estimate = cam.result.camera_from_base();
        let (deg, mm) = (
            rotation_error_deg(&estimate, &truth),
            translation_error_mm(&estimate, &truth),
        );
        if named {
            outln!(
                "{}: error against the simulated truth: rotation {deg:.4} deg, translation {mm:.3} mm",
                cam.name
            );
        } else {
            outln!(
                "error against the simulated truth ({}): rotation {deg:.4} deg, translation {mm:.3} mm",
                unit.config.mount().transform_name()
            );
        }
    }
    Ok(())
}

/// On a simulated cell: writes `ground_truth.json` into the run, so a later `easyhec solve`
/// of it prints each camera's error.
#[cfg(feature = "sim")]
fn write_truth(cell: &Cell, run_dir: &Path) -> anyhow::Result<()> {
    easyhec::cell::sim::write_ground_truth(cell, run_dir)?;
    Ok(())
}

#[cfg(not(feature = "sim"))]
fn write_truth(_: &Cell, _: &Path) -> anyhow::Result<()> {
    Ok(())
}

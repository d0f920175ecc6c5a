//! What a session is set up from (the run's settings, each camera's track and starting pose,
//! the robot entry) and how it reports (progress, per-camera results, the loop's fit check).

use std::path::Path;

use nalgebra::Isometry3;

use crate::calibrate::recorder;
use crate::calibrate::{Progress, RoundRecord, RunOptions};
use crate::cell::{CameraRef, Cell};
use crate::config::CalibrationSettings;
use crate::error::{Error, Result};
use crate::pipeline::segment_solve::{LiveFrames, POOR_FIT_IOU};
use crate::run::{PerView, ResultFile, RobotEntry, UncertaintyEntry};
use crate::solve::{SolveOptions, SolveReport};

use super::Track;

/// One camera's `easyhec-result/1` record of the loop's final solve.
pub(super) fn camera_result(
    report: &SolveReport,
    seen: &crate::robot::RobotModel,
    stop_reason: String,
    timings_s: &std::collections::BTreeMap<String, f64>,
    opts: &SolveOptions,
) -> ResultFile {
    let mut result = ResultFile::new(&report.camera_from_base, &seen.links[seen.base]);
    result.views_used = (0..report.per_view_iou.len()).collect();
    result.per_view = report
        .per_view_iou
        .iter()
        .enumerate()
        .map(|(i, &iou)| PerView { view: i, iou })
        .collect();
    result.uncertainty = UncertaintyEntry::of_report(report, opts);
    result.mount_contact_left_out = report.mount_contact_left_out;
    result.stop_reason = stop_reason;
    result.timings_s = timings_s.clone();
    result
}

/// `only_cameras` names cameras of the cell, each once, and at least one.
pub(super) fn check_only_cameras(cell: &Cell, names: Option<&[String]>) -> Result<()> {
    let Some(names) = names else {
        return Ok(());
    };
    let known: Vec<&str> = cell.cameras().iter().map(|c| c.name).collect();
    match crate::config::cameras::selection_problem(&known, names) {
        Some(m) => Err(Error::Usage(m)),
        None => Ok(()),
    }
}

/// A camera of the cell as a track: its intrinsics, its starting pose, and the frames a
/// context-aware segmenter keeps (only ever one camera's: `CellConfig::check_whole_run_segmenters`).
pub(super) fn track<'a>(unit: CameraRef<'a>, guess: Option<Isometry3<f64>>) -> Result<Track<'a>> {
    let live = unit.segmenter.uses_context().then(|| LiveFrames {
        frames: Vec::new(),
        min_band_px: unit.segmenter_config.min_band_px(),
        final_band_px: unit.segmenter_config.final_band_px(),
    });
    Ok(Track {
        camera: unit.device.intrinsics().clone(),
        unit,
        guess,
        live,
        views: Vec::new(),
        report: None,
        change: None,
        done: None,
    })
}

/// Refuses to write a result whose silhouettes do not match the masks (mean IoU under
/// [`POOR_FIT_IOU`]): its covariance would describe a wrong pose and still look tight. The
/// run directory keeps every view for a look and an offline re-solve.
pub(super) fn judge_loop_fit(
    report: &SolveReport,
    camera: Option<&str>,
    run_dir: &Path,
) -> Result<()> {
    let camera = camera
        .map(|n| format!("camera '{n}': "))
        .unwrap_or_default();
    let mean = report.mean_iou();
    if mean.is_nan() || mean < POOR_FIT_IOU {
        let poor: Vec<usize> = report
            .per_view_iou
            .iter()
            .enumerate()
            .filter(|(_, &iou)| iou < POOR_FIT_IOU)
            .map(|(i, _)| i)
            .collect();
        return Err(Error::Solve(format!(
            "{camera}poor fit: mean IoU {mean:.3} is below {POOR_FIT_IOU} (views {poor:?} fit poorly); no result written. The views are in {}: check the masks, joints and initial_guess, then re-solve them with `easyhec solve` (`--allow-poor-fit` writes a poor result anyway)",
            run_dir.display()
        )));
    }
    Ok(())
}

/// The `[calibration]` settings of this run: `RunOptions::max_views` applied, the commanded
/// speed checked against the safety cap.
pub(super) fn run_settings(cell: &Cell, opts: &RunOptions) -> Result<CalibrationSettings> {
    let mut settings = cell.config.calibration.clone();
    if let Some(m) = opts.max_views {
        if m == 0 {
            return Err(Error::input(
                &cell.config_path,
                "calibration.max_views",
                "a run needs at least 1 view",
            ));
        }
        settings.max_views = m;
        settings.min_views = settings.min_views.min(m);
    }
    let speed = settings.speed_rad_s;
    let cap = cell.checker.speed_cap_rad_s();
    if speed > cap {
        return Err(Error::input(
            &cell.config_path,
            "calibration.speed_rad_s",
            format!("{speed} rad/s is above the safety cap of {cap} rad/s (safety.speed_cap_rad_s and the joints' velocity limits)"),
        ));
    }
    Ok(settings)
}

/// The starting pose: the run's own (a warm start), else the config's, else none.
pub(super) fn initial_guess(
    cell: &Cell,
    opts: &RunOptions,
    settings: &CalibrationSettings,
) -> Result<Option<Isometry3<f64>>> {
    let given = opts.initial_guess.is_some() || settings.initial_guess.is_some();
    if given && cell.units.len() > 1 {
        return Err(Error::input(
            &cell.config_path,
            "calibration.initial_guess",
            "one starting pose cannot serve several cameras: leave it out, and each fixed camera of the list is found by the automatic initialisation",
        ));
    }
    Ok(match (&opts.initial_guess, &settings.initial_guess) {
        (Some(g), _) => Some(*g),
        (None, Some(g)) => Some(
            g.camera_from_base()
                .map_err(|m| Error::input(&cell.config_path, "calibration.initial_guess", m))?,
        ),
        (None, None) => None,
    })
}

/// The run's `robot` entry: absolute paths, so the run solves from anywhere.
pub(super) fn robot_entry(cell: &Cell) -> RobotEntry {
    let src = &cell.robot.source;
    RobotEntry {
        urdf: recorder::absolute(&src.urdf),
        package_dirs: src
            .package_dirs
            .iter()
            .map(|(k, v)| (k.clone(), recorder::absolute(v)))
            .collect(),
        package_paths: src
            .package_paths
            .iter()
            .map(|p| recorder::absolute(p))
            .collect(),
        base_link: Some(cell.robot.links[cell.robot.base].clone()),
        ignore_links: src.ignore_links.clone(),
        joints: cell
            .robot
            .joint_names()
            .iter()
            .map(|s| s.to_string())
            .collect(),
        xacro_args: src.xacro_args.clone(),
    }
}

pub(super) fn progress_bar(opts: &RunOptions, max_views: usize) -> indicatif::ProgressBar {
    if !opts.progress {
        return indicatif::ProgressBar::hidden();
    }
    let pb = indicatif::ProgressBar::new(max_views as u64);
    pb.set_style(
        indicatif::ProgressStyle::with_template(
            "{spinner} views {pos}/{len} {wide_msg} [{elapsed}]",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    pb.enable_steady_tick(std::time::Duration::from_millis(200));
    pb
}

pub(super) fn emit_view(opts: &RunOptions, taken: &[Vec<f64>]) {
    if let Some(joints) = taken.last() {
        opts.emit(Progress::ViewCaptured {
            index: taken.len() - 1,
            joints: joints.clone(),
        });
    }
}

pub(super) fn emit_round(opts: &RunOptions, rounds: &[RoundRecord], report: &SolveReport) {
    if let Some(r) = rounds.last() {
        opts.emit(Progress::Round {
            round: r.round,
            views: r.views,
            loss: r.loss,
            mean_iou: r.mean_iou,
            camera_from_base: r.camera_from_base,
            uncertainty: UncertaintyEntry::of(&report.uncertainty).map(Box::new),
        });
    }
}

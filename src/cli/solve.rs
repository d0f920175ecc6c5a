//! `easyhec solve`: camera_from_base from a recorded run directory.

use super::exit::outln;
use std::path::PathBuf;

use anyhow::anyhow;
use clap::{Args, ValueEnum};
use easyhec::config::{RendererChoice, SegmenterConfig};
use easyhec::explore::Selection;
use easyhec::pipeline::offline::{solve_run, OfflineOutcome, OfflineSolve};
use easyhec::run::rig::RunLayout;
use easyhec::solve::{DominantTerm, MountContact, Optimizer};

#[derive(Args)]
pub struct SolveArgs {
    /// Run directory (or its run.json).
    pub run: PathBuf,
    /// Number of views to use (default: all).
    #[arg(long)]
    pub views: Option<usize>,
    /// How views are chosen.
    #[arg(long, value_enum, default_value_t = SelectArg::First)]
    pub select: SelectArg,
    /// Seed for --select random.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Result path (default RUN/result.json).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Start from this pose instead of the run's initial_guess: a JSON file with
    /// `camera_from_base` (4x4, row-major), such as another solve's result.json.
    #[arg(long)]
    pub initial_guess: Option<PathBuf>,
    /// The optimiser.
    #[arg(long, value_enum, default_value_t = Optimizer::Lm)]
    pub optimizer: Optimizer,
    /// Write one agreement overlay PNG per view into this folder.
    #[arg(long)]
    pub overlays: Option<PathBuf>,
    /// The renderer backend.
    #[arg(long, value_enum, default_value_t = RendererChoice::Auto)]
    pub renderer: RendererChoice,
    /// Keep every view even when some do not fit any pose the others agree on (by default
    /// such views are left out of the result and named on stderr).
    #[arg(long)]
    pub keep_all_views: bool,
    /// Segment views that have an image but no mask with this segmenter, in
    /// segment → solve → re-segment rounds. Either builtin, the segmenter with no training
    /// (background plate, prior silhouette and colour models; docs/method.md), or a TOML file
    /// holding a `[segmenter]` table as a cell config writes it (e.g. `kind = "sam"` with your
    /// exported model; its paths are relative to that file).
    #[arg(long, value_name = "builtin|FILE")]
    pub segmenter: Option<String>,
    /// With --segmenter: segment every view's image, ignoring recorded masks.
    #[arg(long, requires = "segmenter")]
    pub ignore_masks: bool,
    /// With --segmenter: write the masks it made into this folder (NNN.mask.png).
    #[arg(long, requires = "segmenter")]
    pub masks_out: Option<PathBuf>,
    /// Write the result even when the fit is poor (mean IoU under 0.8, or fewer than two
    /// views left that agree); by default such a solve fails and writes nothing.
    #[arg(long)]
    pub allow_poor_fit: bool,
    /// 1-sigma error of each recorded joint, radians (encoder noise plus kinematic error):
    /// carried into the reported uncertainty (docs/uncertainty.md). 0 to 0.1.
    #[arg(long, default_value_t = 5e-4, value_parser = joint_noise)]
    pub joint_noise_rad: f64,
    /// Model-error floor of the reported rotation, degrees (1 sigma per camera axis): what
    /// no mask shows, such as a URDF or intrinsics error. 0 to 5.
    #[arg(long, default_value_t = 0.0, value_parser = floor_deg)]
    pub model_floor_rotation_deg: f64,
    /// Model-error floor of the camera centre's position, millimetres (1 sigma per camera
    /// axis). 0 to 100.
    #[arg(long, default_value_t = 0.0, value_parser = floor_mm)]
    pub model_floor_translation_mm: f64,
    /// Estimate the masks' outline offset (a segmenter's fat or thin bias, pixels) with the
    /// pose, and report it with its sigma in result.json (docs/uncertainty.md).
    #[arg(long)]
    pub estimate_mask_offset: bool,
    /// The outline where the robot stands on its mount (its fixed base's lowest 15 mm):
    /// `auto` leaves it out where the masks disagree with the rendered robot there (a plate
    /// of the base's colour, a flange the masks leave out), `fit` always reads it,
    /// `leave-out` never does (docs/method.md §6).
    #[arg(long, value_enum, default_value_t = MountContact::Auto)]
    pub mount_contact: MountContact,
}

/// `--select`: how a solve picks its views.
#[derive(Clone, Copy, ValueEnum)]
pub enum SelectArg {
    /// Views 0..K-1.
    First,
    /// View 0, then the view where the camera hypotheses disagree most, re-solving each round.
    Explore,
    /// Like explore, but random (seeded by --seed).
    Random,
}

/// Solves the run and prints the outcome (remarks on stderr as they happen).
pub fn run(a: SolveArgs) -> anyhow::Result<()> {
    let optimizer = a.optimizer;
    if optimizer == Optimizer::Adam && a.estimate_mask_offset {
        return Err(easyhec::error::Error::Usage(
            "--estimate-mask-offset: the Adam baseline fits the pose alone; allowed: with --optimizer lm (the default)".into(),
        )
        .into());
    }
    let selection = match a.select {
        SelectArg::First => Selection::First,
        SelectArg::Random => Selection::Random(a.seed),
        SelectArg::Explore => Selection::Explore,
    };
    let (segmenter, segmenter_file) = match a.segmenter.as_deref().map(segmenter_config) {
        Some(chosen) => {
            let (config, file) = chosen?;
            (Some(config), file)
        }
        None => (None, None),
    };
    let request = OfflineSolve {
        run: a.run,
        views: a.views,
        selection,
        seed: a.seed,
        optimizer,
        out: a.out,
        initial_guess: a.initial_guess,
        overlays: a.overlays,
        renderer: a.renderer,
        keep_all_views: a.keep_all_views,
        segmenter,
        segmenter_file,
        ignore_masks: a.ignore_masks,
        masks_out: a.masks_out,
        allow_poor_fit: a.allow_poor_fit,
        joint_noise_rad: a.joint_noise_rad,
        model_floor: (a.model_floor_rotation_deg, a.model_floor_translation_mm),
        estimate_mask_offset: a.estimate_mask_offset,
        mount_contact: a.mount_contact,
    };
    let activity = super::progress::Activity::start("solve");
    let outcome = solve_run(&request, &mut |line| activity.note(line))?;
    drop(activity);
    match outcome.layout {
        RunLayout::OneCamera => report_one(&outcome),
        RunLayout::NamedCameras => report_named(&outcome),
    }
}

/// The lines of a run of one camera: its fit, its bound and which term sets it.
fn report_one(outcome: &OfflineOutcome) -> anyhow::Result<()> {
    let camera = outcome.first();
    if !camera.poor_views.is_empty() {
        tracing::warn!(
            "views {:?} fit poorly (IoU < 0.8): the reported uncertainty does not cover a wrong model; check each view's joints against its mask, ignore_links, and the URDF",
            camera.poor_views
        );
    }
    let report = &camera.report;
    outln!(
        "{} solved from {} views in {:.2} s: mean IoU {:.4}, 1-sigma rot {:.4?} deg, trans {:.3?} mm, camera centre within {:.2} mm (95%) -> {}",
        camera.transform,
        camera.views,
        camera.solve_s,
        report.mean_iou(),
        report.uncertainty.rotation_deg,
        report.uncertainty.translation_mm,
        report.uncertainty.camera_centre_95_mm,
        outcome.out.display()
    );
    let terms = camera
        .result
        .uncertainty
        .as_ref()
        .and_then(|u| u.terms.as_ref());
    let dominant = terms.map(|t| t.dominant.as_str());
    if dominant == Some(DominantTerm::InterView.name()) {
        // On real frames this is the usual case: say so, or a user compares the bound with
        // the simulator's figures.
        outln!(
            "the uncertainty is set by how far the views disagree (each view's outline pulls the pose its own way: mesh, joint or mask errors), not by outline noise"
        );
    } else if dominant == Some(DominantTerm::Segmentation.name()) {
        outln!(
            "the uncertainty is set by the pixels the segmenter could not decide from the images (robot against a background of its own colour, or never uncovered): masks from a segmentation network, or a background that differs from the robot, tighten it"
        );
    }
    if let Some(why) = terms.and_then(|t| t.segmentation_not_measured.as_deref()) {
        outln!(
            "the uncertainty leaves out the segmentation term ({why}): the masks' shared error is not in it, so read the bound as a lower one"
        );
    }
    if let Some((path, rot, trans)) = &camera.truth_error {
        outln!(
            "error vs {}: rotation {rot:.4} deg, translation {trans:.3} mm",
            path.display()
        );
    }
    Ok(())
}

/// One line per camera of an `easyhec-run/2` run.
fn report_named(outcome: &OfflineOutcome) -> anyhow::Result<()> {
    for cam in &outcome.cameras {
        if !cam.poor_views.is_empty() {
            tracing::warn!(
                "{}: views {:?} fit poorly (IoU < 0.8): the reported uncertainty does not cover a wrong model",
                cam.name,
                cam.poor_views
            );
        }
        let u = &cam.report.uncertainty;
        outln!(
            "{}: {} solved from {} views: mean IoU {:.4}, 1-sigma rot {:.4?} deg, trans {:.3?} mm, camera centre within {:.2} mm (95%)",
            cam.name,
            cam.transform,
            cam.views,
            cam.report.mean_iou(),
            u.rotation_deg,
            u.translation_mm,
            u.camera_centre_95_mm
        );
        if let Some((_, rot, trans)) = cam.truth_error {
            outln!(
                "{}: error against the simulated truth: rotation {rot:.4} deg, translation {trans:.3} mm",
                cam.name
            );
        }
    }
    outln!(
        "{} cameras -> {}",
        outcome.cameras.len(),
        outcome.out.display()
    );
    Ok(())
}

/// `--joint-noise-rad`: a finite 0 to 0.1 rad (the cell config's bound).
fn joint_noise(text: &str) -> Result<f64, String> {
    number_within(
        text,
        easyhec::config::checks::bounds::JOINT_NOISE_RAD,
        "rad",
    )
}

/// `--model-floor-rotation-deg`: 0 to the cell config's bound.
fn floor_deg(text: &str) -> Result<f64, String> {
    number_within(
        text,
        easyhec::config::checks::bounds::MODEL_FLOOR_DEG,
        "deg",
    )
}

/// `--model-floor-translation-mm`: 0 to the cell config's bound.
fn floor_mm(text: &str) -> Result<f64, String> {
    number_within(text, easyhec::config::checks::bounds::MODEL_FLOOR_MM, "mm")
}

/// A finite number from 0 to `bound`.
fn number_within(text: &str, bound: f64, unit: &str) -> Result<f64, String> {
    let v: f64 = text.parse().map_err(|e| format!("{e}"))?;
    if v.is_finite() && (0.0..=bound).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{v}; allowed: 0 to {bound} {unit}"))
    }
}

/// `--segmenter`'s value: a segmenter's name, or a file holding a `[segmenter]` table (and
/// that file, which its paths are relative to).
fn segmenter_config(value: &str) -> anyhow::Result<(SegmenterConfig, Option<PathBuf>)> {
    let path = std::path::Path::new(value);
    match SegmenterConfig::by_name(value) {
        Ok(config) => Ok((config, None)),
        Err(_) if value.ends_with(".toml") || path.is_file() => {
            Ok((SegmenterConfig::from_file(path)?, Some(path.to_path_buf())))
        }
        Err(e) => Err(anyhow!(e)),
    }
}

//! `easyhec bench real`: the reported uncertainty against what the views themselves show, on
//! a recorded real run with a reference pose (the shared xArm7 RealSense set: 10 views, SAM 2
//! masks, an RGB-D reference from another method and a rough guess). Simulated noise can be
//! what the covariance was built for; real frames carry model errors no simulator has.
//!
//! Per run it reports each view's IoU, the pose against `reference.json`, the reported 1σ
//! against a view-level jackknife σ (each view left out in turn, re-solved warm from the
//! all-view pose), the reference in units of both, and the 95% camera-centre bound against
//! the reference's centre.

use std::path::{Path, PathBuf};
use std::time::Instant;

use nalgebra::{Isometry3, Matrix6};

use super::Report;
use crate::backend::{open_renderer, Backend};
use crate::camera::LensWarp;
use crate::config::{RendererChoice, SegmenterConfig};
use crate::error::{Error, Result};
use crate::explore::Selection;
use crate::geometry::{
    camera_centre_error_mm, log_se3, rotation_error_deg, translation_error_mm, Twist,
};
use crate::mask::Mask;
use crate::pipeline::offline::{solve_run, OfflineSolve};
use crate::render::{CpuRenderer, PosedRobot, SilhouetteRenderer};
use crate::run::{load_run, read_pose_file, ResultFile};
use crate::solve::{
    predicted_outline_motion_px, solve, uncertainty_of, with_view_disagreement, SolveOptions,
    SolveReport, Uncertainty, View,
};
use crate::solve::{MountContact, Optimizer};

/// A recorded real run against its reference pose.
#[derive(clap::Args, Clone, Debug)]
pub struct RealBench {
    /// Run folder (`easyhec-run/1`) holding `reference.json` and `rough_guess.json`.
    #[arg(long, default_value = "../shared/datasets/xarm7_realsense_roboreg")]
    pub run: PathBuf,
    /// Renderer: cpu, wgpu or auto.
    #[arg(long, default_value = "cpu")]
    pub renderer: RendererChoice,
    /// Use the first N views (default: all).
    #[arg(long, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(2..=100))]
    pub views: Option<usize>,
    /// Also calibrate from the colour frames alone (`easyhec solve --segmenter builtin
    /// --ignore-masks`), from the rough guess and with no guess, against the mask pose.
    #[arg(long)]
    pub images: bool,
    /// Estimate the masks' outline offset with the pose, as `easyhec solve
    /// --estimate-mask-offset` does.
    #[arg(long)]
    pub mask_offset: bool,
    /// How every fit treats the robot's mount contact, as `easyhec solve --mount-contact`.
    #[arg(long, value_enum, default_value_t = MountContact::Auto)]
    pub mount_contact: MountContact,
}

/// The fit settings a real-frame benchmark can change from the defaults.
#[derive(Clone, Copy, Debug, Default)]
pub struct FitChoices {
    /// Estimate the masks' outline offset ([`SolveOptions::estimate_mask_offset`]).
    pub mask_offset: bool,
    /// How fits treat the mount contact ([`SolveOptions::mount_contact`]).
    pub mount_contact: MountContact,
}

/// An images-only calibration of the run against the pose its provided masks give.
#[derive(Clone, Debug)]
pub struct ImagesOnly {
    /// How it started: `rough_guess.json` or the automatic initialisation.
    pub start: &'static str,
    /// Rotation, translation and camera-centre distance (deg, mm, mm) from the mask pose
    /// and from the reference, or why the solve failed.
    pub apart: std::result::Result<([f64; 3], [f64; 3]), String>,
    /// Per-view IoU of the segmenter's masks against the provided ones.
    pub mask_iou: Vec<f64>,
    /// What the images-only result promised: its 95% camera-centre bound and its
    /// segmentation term's (mm; NaN when not measured), and the largest offset on any axis
    /// of the mask pose and of the reference in its reported 1σ.
    pub promise: Option<Promise>,
    /// Wall time, seconds.
    pub wall_s: f64,
}

/// An images-only result's uncertainty held against the poses it should cover.
#[derive(Clone, Copy, Debug)]
pub struct Promise {
    /// Reported 95% camera-centre bound, millimetres.
    pub centre_95_mm: f64,
    /// The segmentation term's bound on its own, millimetres (NaN when not measured).
    pub segmentation_centre_95_mm: f64,
    /// The mask pose's largest offset on any axis, in reported σ.
    pub mask_pose_sigmas: f64,
    /// The reference's largest offset on any axis, in reported σ.
    pub reference_sigmas: f64,
    /// Outline motion (px, least and most over the recorded views) that a bump check at
    /// those views puts down to the calibration's own uncertainty: with the segmentation term
    /// taken out, as the check does, and with it left in.
    pub bump_allowance_px: [(f64, f64); 2],
}

/// What `bench real` measured.
#[derive(Clone, Debug)]
pub struct RealFigures {
    /// Mask IoU per view at the estimate.
    pub per_view_iou: Vec<f64>,
    /// Rotation, translation and camera-centre distance from the reference: deg, mm, mm.
    pub from_reference: [f64; 3],
    /// The reported uncertainty.
    pub reported: Uncertainty,
    /// The view-level jackknife's.
    pub jackknife: Uncertainty,
    /// The reference's offset per axis in units of the reported 1σ.
    pub reference_in_reported_sigmas: [f64; 6],
    /// The same in units of the jackknife σ.
    pub reference_in_jackknife_sigmas: [f64; 6],
    /// Wall time of the all-view solve with its view jackknife, seconds.
    pub solve_s: f64,
    /// The part of it the fit took (the solve without the view jackknife), seconds.
    pub fit_s: f64,
    /// The all-view pose from the provided masks.
    pub mask_pose: Isometry3<f64>,
    /// The masks' outline offset, when estimated.
    pub mask_offset: Option<crate::solve::MaskOffset>,
}

impl RealBench {
    /// Runs the benchmark; per-solve lines go to `log`.
    pub fn run(&self, log: &mut dyn FnMut(&str)) -> Result<Report> {
        let fit = FitChoices {
            mask_offset: self.mask_offset,
            mount_contact: self.mount_contact,
        };
        let f = real_figures(&self.run, self.renderer, self.views, fit, log)?;
        let mut report = report_of(&self.run, &f);
        if self.images {
            let views = Some(f.per_view_iou.len());
            for start in [Start::RoughGuess, Start::Automatic] {
                let i = images_only(&self.run, self.renderer, views, start, &f.mask_pose, fit)?;
                report.line(images_line(&i));
            }
        }
        Ok(report)
    }
}

/// Solves the run from its rough guess, then once per left-out view, and compares.
pub fn real_figures(
    dir: &Path,
    renderer: RendererChoice,
    views: Option<usize>,
    fit: FitChoices,
    log: &mut dyn FnMut(&str),
) -> Result<RealFigures> {
    // The run's masks are given, so `auto` fits their mount contact, as `easyhec solve` does.
    let opts = SolveOptions {
        estimate_mask_offset: fit.mask_offset,
        mount_contact: fit.mount_contact.for_given_masks(),
        ..SolveOptions::default()
    };
    let reference = read_pose_file(&dir.join("reference.json"))?;
    let guess = read_pose_file(&dir.join("rough_guess.json"))?;
    let run = load_run(dir)?;
    let k = views.unwrap_or(run.views.len()).min(run.views.len());
    let all: Vec<View> = run.views[..k]
        .iter()
        .map(|v| View {
            robot: PosedRobot::new(&run.robot, &v.joints),
            observed: v.observed.clone(),
        })
        .collect();
    let backend = open_renderer(renderer, true).map_err(Error::Usage)?;
    let t = Instant::now();
    let full = solve(backend.as_ref(), &run.camera, &all, &guess, &opts)?;
    let fit_s = t.elapsed().as_secs_f64();
    let full = with_view_disagreement(backend.as_ref(), &run.camera, &all, full, &opts);
    let solve_s = t.elapsed().as_secs_f64();
    log(&format!(
        "all {k} views: {solve_s:.1} s ({fit_s:.1} s fit, {:.1} s view jackknife), mean IoU {:.4}, mount contact {}",
        solve_s - fit_s,
        full.mean_iou(),
        if full.mount_contact_left_out { "left out" } else { "fitted" }
    ));
    let jackknife = view_jackknife(backend.as_ref(), &run.camera, &all, &full, &opts, log)?;
    let est = full.camera_from_base;
    Ok(RealFigures {
        per_view_iou: full.per_view_iou.clone(),
        from_reference: [
            rotation_error_deg(&est, &reference),
            translation_error_mm(&est, &reference),
            camera_centre_error_mm(&est, &reference),
        ],
        reference_in_reported_sigmas: super::coverage::errors_in_sigmas(
            &est,
            &reference,
            &full.uncertainty,
        ),
        reference_in_jackknife_sigmas: super::coverage::errors_in_sigmas(
            &est, &reference, &jackknife,
        ),
        reported: full.uncertainty,
        jackknife,
        solve_s,
        fit_s,
        mask_pose: est,
        mask_offset: full.mask_offset,
    })
}

/// The view-level jackknife: each view left out in turn and the rest re-solved from the
/// all-view pose, without the seeded posterior refinement (its sampling would add noise the
/// jackknife multiplies by (n-1)^2); `C = (n-1)/n sum (d_i - d)(d_i - d)^T` over the left
/// increments `d_i` from a centre solved the same way.
fn view_jackknife(
    backend: &dyn Backend,
    camera: &easyhec_drivers::Intrinsics,
    views: &[View],
    full: &SolveReport,
    opts: &SolveOptions,
    log: &mut dyn FnMut(&str),
) -> Result<Uncertainty> {
    // On the outline the all-view fit used: its mount-contact decision, not one per subset.
    let opts = SolveOptions {
        refine_samples: 0,
        ..opts.as_fitted(full)
    };
    let centre = solve(backend, camera, views, &full.camera_from_base, &opts)?.camera_from_base;
    let n = views.len();
    let mut deltas: Vec<Twist> = Vec::with_capacity(n);
    for left_out in 0..n {
        let rest: Vec<View> = (0..n)
            .filter(|&j| j != left_out)
            .map(|j| views[j].clone())
            .collect();
        let pose = solve(backend, camera, &rest, &centre, &opts)?.camera_from_base;
        log(&format!(
            "without view {left_out}: moved {:.3} deg, {:.2} mm",
            rotation_error_deg(&pose, &centre),
            translation_error_mm(&pose, &centre)
        ));
        deltas.push(log_se3(&(pose * centre.inverse())));
    }
    let mean: Twist = deltas.iter().sum::<Twist>() / n as f64;
    let scatter: Matrix6<f64> = deltas
        .iter()
        .map(|d| (d - mean) * (d - mean).transpose())
        .sum();
    let c = scatter * ((n - 1) as f64 / n as f64);
    Ok(uncertainty_of(&c, &centre))
}

/// The benchmark's tables.
fn report_of(dir: &Path, f: &RealFigures) -> Report {
    let mut r = Report::default();
    r.line(format!("run: {}", dir.display()));
    let ious: Vec<String> = f.per_view_iou.iter().map(|v| format!("{v:.3}")).collect();
    r.line(format!("per-view IoU: {}", ious.join(" ")));
    r.line(format!(
        "from the reference: {:.3} deg, {:.2} mm (camera centre {:.2} mm); all-view solve {:.1} s ({:.1} s fit, {:.1} s view jackknife)",
        f.from_reference[0], f.from_reference[1], f.from_reference[2], f.solve_s, f.fit_s, f.solve_s - f.fit_s
    ));
    r.line("| axis | reported 1σ | jackknife 1σ | reported / jackknife | reference / reported σ | reference / jackknife σ |");
    r.line("|---|---|---|---|---|---|");
    let axes = [
        "rot x (deg)",
        "rot y (deg)",
        "rot z (deg)",
        "trans x (mm)",
        "trans y (mm)",
        "trans z (mm)",
    ];
    let sigmas = |u: &Uncertainty| {
        [
            u.rotation_deg[0],
            u.rotation_deg[1],
            u.rotation_deg[2],
            u.translation_mm[0],
            u.translation_mm[1],
            u.translation_mm[2],
        ]
    };
    let (rep, jk) = (sigmas(&f.reported), sigmas(&f.jackknife));
    for k in 0..6 {
        r.line(format!(
            "| {} | {:.4} | {:.4} | {:.2} | {:.2} | {:.2} |",
            axes[k],
            rep[k],
            jk[k],
            rep[k] / jk[k],
            f.reference_in_reported_sigmas[k],
            f.reference_in_jackknife_sigmas[k]
        ));
    }
    r.line(format!(
        "95% camera-centre bound {:.2} mm (jackknife's {:.2} mm); the reference's centre lies {:.2} mm away",
        f.reported.camera_centre_95_mm,
        f.jackknife.camera_centre_95_mm,
        f.from_reference[2]
    ));
    if let Some(m) = f.mask_offset {
        r.line(format!(
            "mask outline offset {:+.3} px (1σ {:.3} px)",
            m.px, m.sigma_px
        ));
    }
    r
}

/// Where an images-only solve starts.
#[derive(Clone, Copy, Debug)]
pub enum Start {
    /// From `rough_guess.json`.
    RoughGuess,
    /// From the automatic initialisation (no guess).
    Automatic,
}

/// `easyhec solve RUN --segmenter builtin --ignore-masks` (from the rough guess, or with no
/// guess), its pose against `mask_pose` and the reference, and its masks against the
/// provided ones. A solve that fails is a figure too (its error line), not an error.
pub fn images_only(
    dir: &Path,
    renderer: RendererChoice,
    views: Option<usize>,
    start: Start,
    mask_pose: &Isometry3<f64>,
    fit: FitChoices,
) -> Result<ImagesOnly> {
    let scratch = tempfile::tempdir().map_err(|e| Error::io(std::env::temp_dir(), e))?;
    let masks_dir = scratch.path().join("masks");
    let request = OfflineSolve {
        run: dir.to_path_buf(),
        views,
        selection: Selection::First,
        seed: 0,
        optimizer: Optimizer::Lm,
        out: Some(scratch.path().join("result.json")),
        initial_guess: matches!(start, Start::RoughGuess).then(|| dir.join("rough_guess.json")),
        overlays: None,
        renderer,
        keep_all_views: false,
        segmenter: Some(SegmenterConfig::by_name("builtin").map_err(Error::Usage)?),
        segmenter_file: None,
        ignore_masks: true,
        masks_out: Some(masks_dir.clone()),
        allow_poor_fit: true,
        joint_noise_rad: 5e-4,
        model_floor: (0.0, 0.0),
        estimate_mask_offset: fit.mask_offset,
        mount_contact: fit.mount_contact,
    };
    let t = Instant::now();
    let solved = solve_run(&request, &mut |_| {});
    let wall_s = t.elapsed().as_secs_f64();
    let start_name = match start {
        Start::RoughGuess => "from rough_guess.json",
        Start::Automatic => "with no guess",
    };
    let outcome = match solved {
        Ok(o) => o,
        Err(e) => {
            return Ok(ImagesOnly {
                start: start_name,
                apart: Err(e.to_string()),
                mask_iou: Vec::new(),
                promise: None,
                wall_s,
            })
        }
    };
    let report = &outcome.first().report;
    let est = report.camera_from_base;
    let reference = read_pose_file(&dir.join("reference.json"))?;
    let written = ResultFile::read(&scratch.path().join("result.json"))?;
    let run = load_run(dir)?;
    let k = views.unwrap_or(usize::MAX).min(run.views.len());
    let largest = |other: &Isometry3<f64>| {
        super::coverage::errors_in_sigmas(&est, other, &report.uncertainty)
            .iter()
            .fold(0.0f64, |m, z| m.max(z.abs()))
    };
    let promise = Promise {
        centre_95_mm: report.uncertainty.camera_centre_95_mm,
        segmentation_centre_95_mm: report.segmentation_bound_mm().unwrap_or(f64::NAN),
        mask_pose_sigmas: largest(mask_pose),
        reference_sigmas: largest(&reference),
        bump_allowance_px: [false, true]
            .map(|with_segmentation| bump_allowance_px(&run, k, &written, with_segmentation)),
    };
    let apart = |other: &Isometry3<f64>| {
        [
            rotation_error_deg(&est, other),
            translation_error_mm(&est, other),
            camera_centre_error_mm(&est, other),
        ]
    };
    let mask_iou = run
        .views
        .iter()
        .take(k)
        .enumerate()
        .map(|(position, v)| {
            let made = Mask::load(&masks_dir.join(crate::run::mask_file_name(position)))?;
            Ok(run.camera.undistort_mask(&made).iou(&v.observed))
        })
        .collect::<Result<Vec<f64>>>()?;
    Ok(ImagesOnly {
        start: start_name,
        apart: Ok((apart(mask_pose), apart(&reference))),
        mask_iou,
        promise: Some(promise),
        wall_s,
    })
}

/// The least and most, over the first `k` recorded views, of the outline motion that the
/// written result's uncertainty predicts at its pose: what a bump check there allows
/// ([`crate::run::UncertaintyEntry::moving_between_checks`] with this solve's zero model floor, then
/// [`predicted_outline_motion_px`]), or with the whole covariance when `with_segmentation`.
fn bump_allowance_px(
    run: &crate::run::LoadedRun,
    k: usize,
    result: &ResultFile,
    with_segmentation: bool,
) -> (f64, f64) {
    let covariance = result
        .uncertainty
        .as_ref()
        .and_then(|u| match with_segmentation {
            true => u.covariance_matrix(),
            false => u.moving_between_checks(&Matrix6::zeros()),
        });
    let Some(covariance) = covariance else {
        return (f64::NAN, f64::NAN);
    };
    let pose = result.camera_from_base();
    let pinhole = run.camera.undistorted();
    run.views[..k]
        .iter()
        .map(|v| {
            let posed = PosedRobot::new(&run.robot, &v.joints);
            let rendered = CpuRenderer.render(&posed, &pinhole, &pose, Some(1.0));
            predicted_outline_motion_px(&rendered, &pinhole, &covariance)
        })
        .fold((f64::INFINITY, 0.0), |(lo, hi), px| {
            (lo.min(px), hi.max(px))
        })
}

/// One line per images-only solve.
fn images_line(i: &ImagesOnly) -> String {
    let (m, r) = match &i.apart {
        Ok(figures) => figures,
        Err(e) => {
            return format!(
                "images only, {}: failed after {:.1} s: {e}",
                i.start, i.wall_s
            )
        }
    };
    let promised = i.promise.map_or(String::new(), |p| {
        format!(
            "; reported 95% centre bound {:.2} mm (segmentation term {:.2} mm), the mask pose at most {:.2}σ and the reference at most {:.2}σ away on any axis; a bump check at the recorded views allows {:.2}–{:.2} px for it ({:.2}–{:.2} px were the segmentation term left in)",
            p.centre_95_mm, p.segmentation_centre_95_mm, p.mask_pose_sigmas, p.reference_sigmas,
            p.bump_allowance_px[0].0, p.bump_allowance_px[0].1, p.bump_allowance_px[1].0, p.bump_allowance_px[1].1
        )
    });
    format!(
        "images only, {}: {:.3} deg, {:.2} mm (camera centre {:.2} mm) from the mask pose; {:.3} deg, {:.2} mm from the reference; mask IoU against the provided masks mean {:.3} (min {:.3}){promised}; {:.1} s",
        i.start,
        m[0],
        m[1],
        m[2],
        r[0],
        r[1],
        i.mask_iou.iter().sum::<f64>() / i.mask_iou.len().max(1) as f64,
        i.mask_iou.iter().copied().fold(f64::INFINITY, f64::min),
        i.wall_s
    )
}

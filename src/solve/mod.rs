//! Camera-pose solvers over many views.
//!
//! - [`Optimizer::Lm`] (default): coarse-to-fine Levenberg–Marquardt on a sub-pixel boundary
//!   residual — every outline sample of the rendered silhouette should lie on the observed
//!   mask's boundary; its residual is the observed mask's signed distance at the sample, with
//!   Cauchy weights so segmentation blobs and missed parts do not drag the pose.
//! - [`Optimizer::Adam`]: the paper's setting (Adam, lr 3e-3, 1000 full-resolution steps on the
//!   mask loss, best iterate), kept as the baseline the benchmark compares against.
//!
//! Both optimise a left se(3) increment of `camera_from_base` (see [`crate::geometry`]).
//!
//! Layout: `boundary` holds the outline residuals and their normal equations, `lm` and `adam`
//! the two optimisers, `search` the coarse global search a poor fit falls back to, `refine`
//! the posterior refinement after LM, `covariance` the outline residuals' covariance (a
//! sandwich built to cover the true error, docs/uncertainty.md), `disagreement` the
//! view-level jackknife that widens it to what the views' disagreement shows, and
//! `uncertainty` its summaries (1-sigma per axis, the 95% camera-centre bound).

use nalgebra::{Isometry3, Matrix6};
use rayon::prelude::*;

use crate::backend::Backend;
use crate::camera::Intrinsics;
use crate::error::{Error, Result};
use crate::mask::Mask;
use crate::objective::mask_loss;
use crate::render::{PosedRobot, SilhouetteRenderer};

mod adam;
mod boundary;
mod covariance;
mod disagreement;
mod lm;
mod refine;
mod search;
mod shared_joints;
mod uncertainty;

pub use crate::config::calibration::MountContact;
pub use boundary::{mount_contact_disagrees, MOUNT_DISAGREEMENT_PX};
pub use covariance::model_floor;
pub use disagreement::{JACKKNIFE_MIN_VIEWS, MAX_GROUPS};
pub use search::coarse_search;
pub(crate) use search::cross_entropy_search;
pub use shared_joints::{
    refine_with_joint_corrections, solve_with_shared_joints, CameraSolve, SharedCamera,
    SharedRefinement, SharedSolve,
};
pub use uncertainty::{
    predicted_outline_motion_px, translation_covariance, uncertainty_of, Uncertainty,
};

use adam::solve_adam;
use boundary::{accumulate_keeping, Level};
use lm::solve_lm;
use refine::refine;

/// One observation: the robot posed at the view's joints and the observed mask in the
/// undistorted pinhole image.
#[derive(Clone, Debug)]
pub struct View {
    /// Robot geometry at this view's joint vector.
    pub robot: PosedRobot,
    /// Observed robot mask (pinhole image, camera size).
    pub observed: Mask,
}

/// Which optimiser to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Optimizer {
    /// Coarse-to-fine Levenberg–Marquardt on the boundary residual (default).
    #[default]
    Lm,
    /// The paper's Adam baseline.
    Adam,
}

impl std::str::FromStr for Optimizer {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        <Optimizer as clap::ValueEnum>::from_str(s, false)
            .map_err(|_| format!("unknown optimizer '{s}': use lm or adam"))
    }
}

/// Solver settings.
#[derive(Clone, Debug)]
pub struct SolveOptions {
    /// Optimiser.
    pub optimizer: Optimizer,
    /// Image-pyramid downsampling factors, coarse to fine (LM).
    pub pyramid: Vec<u32>,
    /// Iteration cap per pyramid level (LM).
    pub max_iterations_per_level: usize,
    /// Cauchy scale of the boundary residual at coarse levels, pixels of the level's image
    /// (LM): wide enough to pull in a rough start.
    pub robust_scale_px: f64,
    /// Cauchy scale at full resolution (LM): tight, so segmentation noise and blobs lose
    /// their pull (chosen by `easyhec bench accuracy`).
    pub fine_robust_scale_px: f64,
    /// Outline sample spacing, pixels.
    pub boundary_step_px: f64,
    /// Adam steps.
    pub adam_steps: usize,
    /// Adam learning rate (rad and m per step).
    pub adam_learning_rate: f64,
    /// Inflation of the covariance for the correlation of neighbouring outline samples
    /// (pixels of outline per independent observation).
    pub correlation_length_px: f64,
    /// Image tile (pixels) within which outline residuals count as one observation in the
    /// covariance: a few correlation lengths of a segmenter's boundary error.
    pub covariance_tile_px: f64,
    /// Standard deviation of each reported joint's error, radians (metres for prismatic
    /// joints): encoder noise plus what the kinematic model gets wrong. The covariance
    /// carries it; the fit cannot see it.
    pub joint_noise_rad: f64,
    /// Model-error floor of the reported rotation, degrees per camera axis.
    pub floor_rotation_deg: f64,
    /// Model-error floor of the reported translation increment, millimetres per camera axis.
    pub floor_translation_mm: f64,
    /// Below this mean IoU the LM result triggers a wide coarse search and a second solve.
    pub recover_below_iou: f64,
    /// Seed of the coarse search and the posterior refinement.
    pub search_seed: u64,
    /// Poses drawn in the posterior refinement after LM (0 or 1 disables it).
    pub refine_samples: usize,
    /// Best-scoring samples averaged by the refinement.
    pub refine_keep: usize,
    /// Covariance inflation for the refinement's sampling.
    pub refine_inflation: f64,
    /// Vertex-clustering cell at coarse pyramid levels, as a fraction of the level's pixel
    /// footprint at 1 m.
    pub coarse_cell_fraction: f64,
    /// Estimate the masks' signed outline offset (a segmenter's fat or thin bias) jointly
    /// with the pose (LM): the pose then no longer moves along the optical axis to make up
    /// for it, and the covariance carries what not knowing it costs.
    pub estimate_mask_offset: bool,
    /// How the fit treats the outline where the robot stands on its mount (within
    /// [`crate::render::MOUNT_CONTACT_HEIGHT_M`] of its fixed base's foot): fitted, left out
    /// (with the observed outline matched to it), or left out only when the masks disagree
    /// with the rendered robot there ([`MountContact::Auto`], the default).
    pub mount_contact: MountContact,
}

impl SolveOptions {
    /// These options with [`MountContact::Auto`] taken as [`MountContact::Fit`]: what a
    /// solve uses where it has not decided (Adam, which counts pixels, never does).
    fn fitting_mount_contact_unless_told(&self) -> SolveOptions {
        SolveOptions {
            mount_contact: self.mount_contact.for_given_masks(),
            ..self.clone()
        }
    }

    /// These options as `report`'s fit used them: an automatic mount contact becomes what
    /// the fit decided, so the terms computed after it (the jackknife, the segmentation term)
    /// and a warm re-solve rest on the same outline rather than deciding again.
    pub fn as_fitted(&self, report: &SolveReport) -> SolveOptions {
        SolveOptions {
            mount_contact: if report.mount_contact_left_out {
                MountContact::LeaveOut
            } else {
                self.mount_contact.for_given_masks()
            },
            ..self.clone()
        }
    }
}

impl Default for SolveOptions {
    fn default() -> Self {
        SolveOptions {
            optimizer: Optimizer::Lm,
            pyramid: vec![8, 4, 2, 1],
            max_iterations_per_level: 25,
            robust_scale_px: 2.0,
            fine_robust_scale_px: 0.5,
            boundary_step_px: 1.0,
            adam_steps: 1000,
            adam_learning_rate: 3e-3,
            correlation_length_px: 16.0,
            covariance_tile_px: 10.0,
            joint_noise_rad: 5e-4,
            floor_rotation_deg: 0.0,
            floor_translation_mm: 0.0,
            recover_below_iou: 0.8,
            search_seed: 0,
            refine_samples: 64,
            refine_keep: 8,
            refine_inflation: 4.0,
            coarse_cell_fraction: 0.3,
            estimate_mask_offset: false,
            mount_contact: MountContact::Auto,
        }
    }
}

/// What a solve found.
#[derive(Clone, Debug)]
pub struct SolveReport {
    /// The estimate.
    pub camera_from_base: Isometry3<f64>,
    /// How far the observed masks' outline lies outward of the rendered robot's (when
    /// [`SolveOptions::estimate_mask_offset`]).
    pub mask_offset: Option<MaskOffset>,
    /// 6x6 covariance of the left increment `(rho, phi)` at the estimate: the reported one,
    /// built to cover the true error: the statistical covariance, widened by what the views'
    /// disagreement shows beyond it, plus the model floor.
    pub covariance: Matrix6<f64>,
    /// The outline residuals' covariance alone (module `covariance`), without the floor,
    /// with the mask offset estimated alongside when it was.
    pub statistical_covariance: Matrix6<f64>,
    /// What estimating the mask offset added to `statistical_covariance` (zero when it was
    /// not estimated): the mask-bias term.
    pub mask_bias_covariance: Matrix6<f64>,
    /// What the views' disagreement showed (module `disagreement`).
    pub disagreement: Disagreement,
    /// What the pixels the segmenter left undecided could move the pose by
    /// ([`with_segmentation_term`]).
    pub segmentation: SegmentationTerm,
    /// The covariance the posterior refinement and exploration draw pose hypotheses from:
    /// the fit's curvature scaled by the outline noise. Their settings were tuned on it; it
    /// is no promise about the error.
    pub sampling_covariance: Matrix6<f64>,
    /// 1-sigma uncertainty derived from `covariance`.
    pub uncertainty: Uncertainty,
    /// Residual variance of one pixel of outline at full resolution, px^2 (the per-sample
    /// variance times the correlation length): what one more view's outline is worth.
    pub outline_noise_px2: f64,
    /// Mask IoU per view at the estimate (full resolution).
    pub per_view_iou: Vec<f64>,
    /// The paper's mask loss at the estimate.
    pub loss: f64,
    /// Renders performed (each covers all views).
    pub iterations: usize,
    /// Accepted iterates, first to last (exploration's "trajectory" candidates).
    pub trajectory: Vec<Isometry3<f64>>,
    /// Whether the fit left the robot's mount contact out ([`SolveOptions::mount_contact`]).
    pub mount_contact_left_out: bool,
}

/// A segmenter's systematic bias: the signed offset of the observed masks' outline from the
/// rendered robot's, estimated jointly with the pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MaskOffset {
    /// Pixels outward (negative: the masks are thin).
    pub px: f64,
    /// Its 1-sigma, pixels.
    pub sigma_px: f64,
}

/// The inter-view term of a report's covariance.
#[derive(Clone, Debug, Default, PartialEq)]
pub enum Disagreement {
    /// Not measured: an intermediate solve, whose covariance is the statistical one.
    #[default]
    NotMeasured,
    /// Too few views for a jackknife (fewer than [`JACKKNIFE_MIN_VIEWS`]), or a left-out
    /// solve lost the robot: the covariance is the statistical one.
    Unavailable,
    /// Measured: what the view jackknife added to the statistical covariance (zero when the
    /// views disagree no more than chance allows).
    Measured(Box<Matrix6<f64>>),
}

/// The segmentation term of a report's covariance (module [`crate::pipeline::undecided`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub enum SegmentationTerm {
    /// Not for these masks: given in the run, or drawn by a segmenter without per-pixel
    /// evidence (their error is the jackknife's and a model floor's to show).
    #[default]
    NotApplicable,
    /// The masks' segmenter has the evidence, but the term could not be measured (the
    /// reason): the covariance leaves out how far its undecided pixels could move the pose,
    /// and the result says so rather than failing or passing it over.
    Unavailable(String),
    /// Measured: what it added to the covariance.
    Measured(Box<Matrix6<f64>>),
}

impl SegmentationTerm {
    /// The covariance it added, when measured.
    pub fn covariance(&self) -> Option<&Matrix6<f64>> {
        match self {
            SegmentationTerm::Measured(c) => Some(c),
            _ => None,
        }
    }
}

/// Which term sets a reported covariance.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DominantTerm {
    /// The outline residuals' own scatter.
    Statistical,
    /// The views' disagreement.
    InterView,
    /// The configured model-error floor.
    ModelFloor,
    /// Not knowing the segmenter's outline offset.
    MaskBias,
    /// The pixels the segmenter could not decide.
    Segmentation,
}

impl DominantTerm {
    /// The name `result.json` and the page use.
    pub fn name(self) -> &'static str {
        match self {
            DominantTerm::Statistical => "statistical",
            DominantTerm::InterView => "inter-view",
            DominantTerm::ModelFloor => "model floor",
            DominantTerm::MaskBias => "mask bias",
            DominantTerm::Segmentation => "segmentation",
        }
    }
}

/// Widens `report`'s covariance to cover what its views' disagreement shows (a view-level
/// jackknife, module `disagreement`): what a reported result gets once, after its last
/// solve. Intermediate solves skip it; it costs about as much as the solve itself.
pub fn with_view_disagreement(
    renderer: &dyn SilhouetteRenderer,
    camera: &Intrinsics,
    views: &[View],
    mut report: SolveReport,
    opts: &SolveOptions,
) -> SolveReport {
    if report.disagreement != Disagreement::NotMeasured || opts.optimizer == Optimizer::Adam {
        return report;
    }
    let opts = &opts.as_fitted(&report);
    let pose = report.camera_from_base;
    let camera = camera.undistorted();
    let Some((jackknife, dof)) = disagreement::view_jackknife(
        renderer,
        &camera,
        views,
        &pose,
        report.mask_offset_px(),
        opts,
    ) else {
        report.disagreement = Disagreement::Unavailable;
        return report;
    };
    let floor = model_floor(opts.floor_rotation_deg, opts.floor_translation_mm);
    let term = disagreement::inter_view_term(&report.statistical_covariance, &jackknife, dof);
    // A segmentation term already added stays in.
    let segmentation = report
        .segmentation
        .covariance()
        .copied()
        .unwrap_or_else(Matrix6::zeros);
    report.covariance = report.statistical_covariance + term + floor + segmentation;
    report.uncertainty = uncertainty_of(&report.covariance, &pose);
    report.disagreement = Disagreement::Measured(Box::new(term));
    report
}

/// `report` with the segmentation term as measured (module [`crate::pipeline::undecided`]):
/// the views' disagreement cannot show a segmenter's error that every view shares, such as
/// masks that run fat wherever the robot meets a wall of its own colour. `Ok(Some(c))` adds
/// `c` to the covariance, `Ok(None)` (no evidence to measure it from) leaves the report as it
/// is, and an error is recorded as [`SegmentationTerm::Unavailable`]: offline and in the loop
/// alike, the result is reported and says what it leaves out. A term already set stays.
pub fn with_segmentation_term(
    mut report: SolveReport,
    measured: Result<Option<Matrix6<f64>>>,
) -> SolveReport {
    if report.segmentation != SegmentationTerm::NotApplicable {
        return report;
    }
    match measured {
        Ok(None) => {}
        Ok(Some(c)) => {
            report.covariance += c;
            report.uncertainty = uncertainty_of(&report.covariance, &report.camera_from_base);
            report.segmentation = SegmentationTerm::Measured(Box::new(c));
        }
        Err(e) => {
            tracing::warn!("segmentation term not measured: {e}");
            report.segmentation = SegmentationTerm::Unavailable(e.to_string());
        }
    }
    report
}

/// Solves for `camera_from_base` from `views`, starting at `initial`. With
/// [`MountContact::Auto`], a fit whose masks disagree with the rendered robot at its mount
/// contact goes on with that outline left out ([`walk_settling_mount_contact`]).
pub fn solve(
    renderer: &dyn Backend,
    camera: &Intrinsics,
    views: &[View],
    initial: &Isometry3<f64>,
    opts: &SolveOptions,
) -> Result<SolveReport> {
    if views.is_empty() {
        return Err(Error::Solve("no views to solve from".into()));
    }
    let camera = camera.undistorted();
    // Adam fits the pose alone: its report must not claim an offset it never fitted.
    let adam_opts;
    let opts = if opts.optimizer == Optimizer::Adam && opts.estimate_mask_offset {
        adam_opts = SolveOptions {
            estimate_mask_offset: false,
            ..opts.clone()
        };
        &adam_opts
    } else {
        opts
    };
    let asked = opts;
    let (first, settled) = match opts.optimizer {
        Optimizer::Lm => walk_settling_mount_contact(renderer, &camera, views, initial, opts)?,
        Optimizer::Adam => {
            let (pose, iterations, trajectory) =
                solve_adam(renderer, &camera, views, initial, opts);
            let walk = lm::Walk {
                pose,
                offset_px: 0.0,
                iterations,
                trajectory,
            };
            (walk, opts.fitting_mount_contact_unless_told())
        }
    };
    let opts = &settled;
    let iterations = first.iterations;
    let report = finish(renderer, &camera, views, first, opts)?;
    if opts.optimizer == Optimizer::Adam {
        return Ok(report);
    }
    if report.mean_iou() >= opts.recover_below_iou {
        return refine(renderer, &camera, views, report, opts);
    }
    // The fast path landed in a poor local minimum (or the guess was rough): search a wide
    // neighbourhood of the guess at low resolution, then refine from the best candidate.
    let start = coarse_search(renderer, &camera, views, initial, opts);
    // From the new start the masks may fit well enough to decide on the mount contact.
    let (mut second, retry_opts) = match asked.mount_contact {
        MountContact::Auto if !report.mount_contact_left_out => {
            walk_settling_mount_contact(renderer, &camera, views, &start, asked)?
        }
        _ => (
            solve_lm(renderer, &camera, views, &start, opts)?,
            opts.clone(),
        ),
    };
    second.iterations += iterations;
    let retry = finish(renderer, &camera, views, second, &retry_opts)?;
    let best = if retry.mean_iou() > report.mean_iou() {
        retry
    } else {
        report
    };
    let opts = asked.as_fitted(&best);
    refine(renderer, &camera, views, best, &opts)
}

/// LM over the pyramid, and the options the rest of the solve uses. With
/// [`MountContact::Auto`], LM first fits the mount contact; at its pose the masks are checked
/// against the render ([`mount_contact_disagrees`]). Where they disagree, LM walks the whole
/// pyramid again from there with the contact left out, and the rest of the solve leaves it
/// out too; otherwise the walk stands, and is the very walk a `fit` solve takes. On the real
/// xArm7 set the second walk lands where a solve told to leave the contact out does; shorter
/// ones stopped short of it: the two finest levels from the finished fit by 1.8 mm (camera
/// centre), the finest alone from the fit's second-finest level by 3.6 mm, five iterations a
/// level by 0.5 mm for 0.15 s of the 0.6 s the walk costs; deciding at that coarser pose
/// instead missed the builtin masks' disagreement altogether.
fn walk_settling_mount_contact(
    renderer: &dyn Backend,
    camera: &Intrinsics,
    views: &[View],
    initial: &Isometry3<f64>,
    opts: &SolveOptions,
) -> Result<(lm::Walk, SolveOptions)> {
    let fit = opts.fitting_mount_contact_unless_told();
    let fitted = solve_lm(renderer, camera, views, initial, &fit)?;
    if opts.mount_contact != MountContact::Auto
        || !mount_contact_disagrees(renderer, camera, views, &fitted.pose, opts)
    {
        return Ok((fitted, fit));
    }
    let leave_out = SolveOptions {
        mount_contact: MountContact::LeaveOut,
        ..opts.clone()
    };
    let mut walk = solve_lm(renderer, camera, views, &fitted.pose, &leave_out)?;
    walk.iterations += fitted.iterations;
    let mut trajectory = fitted.trajectory;
    trajectory.extend(walk.trajectory.drain(1..));
    walk.trajectory = trajectory;
    Ok((walk, leave_out))
}

/// Mean of `v` (0 for an empty slice).
pub(crate) fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

impl SolveReport {
    /// The estimated mask offset, pixels (0 when not estimated).
    pub fn mask_offset_px(&self) -> f64 {
        self.mask_offset.map_or(0.0, |m| m.px)
    }

    /// Mean mask IoU over the views solved from.
    pub fn mean_iou(&self) -> f64 {
        mean(&self.per_view_iou)
    }

    /// The term whose 95% camera-centre bound is largest on its own.
    pub fn dominant_term(&self, opts: &SolveOptions) -> DominantTerm {
        let bound =
            |c: &Matrix6<f64>| uncertainty_of(c, &self.camera_from_base).camera_centre_95_mm;
        let floor = model_floor(opts.floor_rotation_deg, opts.floor_translation_mm);
        // The mask-bias term is part of the statistical covariance: set against the rest of
        // it, not against the whole.
        let mut terms = vec![
            (
                DominantTerm::Statistical,
                bound(&(self.statistical_covariance - self.mask_bias_covariance)),
            ),
            (DominantTerm::ModelFloor, bound(&floor)),
        ];
        if self.mask_offset.is_some() {
            terms.push((DominantTerm::MaskBias, bound(&self.mask_bias_covariance)));
        }
        if let Disagreement::Measured(c) = &self.disagreement {
            terms.push((DominantTerm::InterView, bound(c)));
        }
        if let Some(c) = self.segmentation.covariance() {
            terms.push((DominantTerm::Segmentation, bound(c)));
        }
        terms
            .into_iter()
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map_or(DominantTerm::Statistical, |t| t.0)
    }

    /// The 95% camera-centre bound of the mask-bias term on its own, millimetres (when the
    /// offset was estimated).
    pub fn mask_bias_bound_mm(&self) -> Option<f64> {
        self.mask_offset.map(|_| {
            uncertainty_of(&self.mask_bias_covariance, &self.camera_from_base).camera_centre_95_mm
        })
    }

    /// The 95% camera-centre bound of the segmentation term on its own, millimetres (when
    /// measured).
    pub fn segmentation_bound_mm(&self) -> Option<f64> {
        self.segmentation
            .covariance()
            .map(|c| uncertainty_of(c, &self.camera_from_base).camera_centre_95_mm)
    }

    /// The 95% camera-centre bound of the statistical term and of what the inter-view term
    /// added (when measured) on their own, millimetres.
    pub fn term_bounds_mm(&self) -> (f64, Option<f64>) {
        let bound =
            |c: &Matrix6<f64>| uncertainty_of(c, &self.camera_from_base).camera_centre_95_mm;
        let views = match &self.disagreement {
            Disagreement::Measured(c) => Some(bound(c)),
            _ => None,
        };
        (bound(&self.statistical_covariance), views)
    }
}

/// The report at `pose`: full-resolution normal equations give the covariance and outline
/// noise, the silhouettes they rendered give the per-view IoU and the mask loss.
fn finish(
    renderer: &dyn SilhouetteRenderer,
    camera: &Intrinsics,
    views: &[View],
    walk: lm::Walk,
    opts: &SolveOptions,
) -> Result<SolveReport> {
    let lm::Walk {
        pose,
        offset_px,
        iterations,
        trajectory,
    } = walk;
    let level = Level::new(camera, views, 1, opts.fine_robust_scale_px);
    let robots: Vec<&PosedRobot> = views.iter().map(|v| &v.robot).collect();
    let (n, silhouettes) = accumulate_keeping(renderer, &robots, &level, &pose, offset_px, opts);
    let fitted = if opts.estimate_mask_offset { 7.0 } else { 6.0 };
    let dof = (n.length / opts.correlation_length_px - fitted).max(1.0);
    let sigma2 = n.weighted_sq / opts.correlation_length_px / dof;
    let unpinned = || Matrix6::from_diagonal_element(f64::INFINITY);
    let statistical =
        covariance::pose_covariance(&level, &silhouettes, &robots, &pose, offset_px, opts);
    let statistical_covariance = statistical.as_ref().map_or_else(unpinned, |s| s.pose);
    let mask_bias_covariance = statistical.as_ref().map_or_else(Matrix6::zeros, |s| {
        // The difference of two covariances of the same residuals: symmetrised and clamped,
        // since rounding can take it a hair below zero.
        let d = s.pose - s.pose_offset_known;
        covariance::positive_part(&((d + d.transpose()) * 0.5))
    });
    let mask_offset = opts.estimate_mask_offset.then(|| MaskOffset {
        px: offset_px,
        sigma_px: statistical
            .as_ref()
            .and_then(|s| s.offset_px2)
            .map_or(f64::INFINITY, |v| v.max(0.0).sqrt()),
    });
    let covariance =
        statistical_covariance + model_floor(opts.floor_rotation_deg, opts.floor_translation_mm);
    let sampling_covariance = n
        .pose_normal(opts.estimate_mask_offset)
        .try_inverse()
        .map_or_else(unpinned, |inv| inv * sigma2 * opts.correlation_length_px);
    let uncertainty = uncertainty_of(&covariance, &pose);
    let renders: Vec<(f64, f64)> = silhouettes
        .par_iter()
        .zip(views)
        .map(|(s, v)| (s.mask.iou(&v.observed), mask_loss(&s.mask, &v.observed)))
        .collect();
    let loss = renders.iter().map(|r| r.1).sum::<f64>() / views.len() as f64;
    Ok(SolveReport {
        camera_from_base: pose,
        mask_offset,
        covariance,
        statistical_covariance,
        mask_bias_covariance,
        disagreement: Disagreement::NotMeasured,
        segmentation: SegmentationTerm::NotApplicable,
        sampling_covariance,
        uncertainty,
        outline_noise_px2: sigma2 * opts.correlation_length_px,
        per_view_iou: renders.iter().map(|r| r.0).collect(),
        loss,
        iterations,
        trajectory,
        // Only what was left out: a camera on a link has no mount, and Adam counts pixels.
        mount_contact_left_out: opts.mount_contact == MountContact::LeaveOut
            && opts.optimizer == Optimizer::Lm
            && views.iter().any(|v| v.robot.mount().is_some()),
    })
}

//! `[calibration]`: how the closed loop chooses, counts and stops its views.

use std::path::Path;

use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

use super::camera::LookAt;
use crate::error::{Error, Result};

/// `[calibration]` in a cell config.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationSettings {
    /// A rough camera pose (tape measure, or a previous calibration); absent: automatic
    /// initialisation.
    #[serde(default)]
    pub initial_guess: Option<InitialGuess>,
    /// `explore` (default: docs/method.md §5) or `random` (a random safe pose; the baseline).
    #[serde(default)]
    pub selection: SelectionSetting,
    /// Views at most (the first is taken where the arm stands).
    #[serde(default = "default_max_views")]
    pub max_views: usize,
    /// Views before the variance rule may stop the loop.
    #[serde(default = "default_min_views")]
    pub min_views: usize,
    /// Joint samples drawn per round (paper: 2000).
    #[serde(default = "default_joint_samples")]
    pub joint_samples: usize,
    /// Hill-climbing steps from each of the best `information`-scored samples (8 starts);
    /// 0 keeps the best sample as drawn.
    #[serde(default = "default_climb_steps")]
    pub climb_steps: usize,
    /// Camera candidates per round (paper: 50).
    #[serde(default = "default_candidates")]
    pub candidates: usize,
    /// `posterior` (default) or `trajectory` (the paper's).
    #[serde(default)]
    pub candidate_source: SourceSetting,
    /// Commanded speed of the fastest joint, rad/s (must be within the safety cap).
    #[serde(default = "default_speed")]
    pub speed_rad_s: f64,
    /// Seed of joint sampling and candidates.
    #[serde(default)]
    pub seed: u64,
    /// Variance rule: relative change of the best score between rounds.
    #[serde(default = "default_variance_tol")]
    pub variance_rel_tol: f64,
    /// Variance rule also needs the estimate to move less than this, degrees…
    #[serde(default = "default_pose_tol_deg")]
    pub pose_tol_deg: f64,
    /// …and this, millimetres.
    #[serde(default = "default_pose_tol_mm")]
    pub pose_tol_mm: f64,
    /// Uncertainty rule: stop once `min_views` are taken and the reported 95% bound on the
    /// camera centre is at most this many millimetres (absent: only the variance rule and
    /// `max_views` stop the loop).
    #[serde(default = "default_stop_centre")]
    pub stop_centre_95_mm: Option<f64>,
    /// Clear arm faults automatically and re-plan from where the arm stopped.
    #[serde(default)]
    pub clear_faults: bool,
    /// Failed moves tolerated before the loop gives up.
    #[serde(default = "default_max_failures")]
    pub max_motion_failures: usize,
    /// Image downsampling for scoring candidate poses.
    #[serde(default = "default_score_downsample")]
    pub score_downsample: u32,
    /// How `explore` ranks joint samples: `information` (default) or `variance` (the paper's).
    #[serde(default)]
    pub score: ScoreSetting,
    /// Error of a reported joint position, radians (1 sigma, per view: encoder noise plus
    /// kinematic error). `information` scoring counts what such errors do to the estimate.
    #[serde(default = "default_joint_noise")]
    pub joint_noise_rad: f64,
    /// Model-error floor of the reported rotation, degrees (1 sigma per camera axis): what no
    /// mask residual shows, such as a URDF or intrinsics error. Added to the covariance.
    #[serde(default)]
    pub model_floor_rotation_deg: f64,
    /// Model-error floor of the camera centre's position, millimetres (1 sigma per camera
    /// axis).
    #[serde(default)]
    pub model_floor_translation_mm: f64,
    /// Estimate the masks' outline offset (a segmenter's fat or thin bias) with each pose,
    /// and report it with its sigma: for a segmenter known to draw masks fat or thin.
    #[serde(default)]
    pub estimate_mask_offset: bool,
    /// How every fit treats the outline where the robot stands on its mount: `auto` leaves
    /// it out where the masks disagree with the rendered robot there (a plate of the base's
    /// colour, a flange the masks leave out), `fit` always reads it, `leave-out` never does.
    #[serde(default)]
    pub mount_contact: MountContact,
    /// Rank poses by information per second (the move plus each view's other work) instead
    /// of by information alone. Only arms whose moves take time are affected: the simulated
    /// arm arrives at once unless `[arm] speedup` slows it.
    #[serde(default = "default_weigh_motion_time")]
    pub weigh_motion_time: bool,
    /// What each view costs besides its move, seconds (capture, segmentation, solve and
    /// planning), for `weigh_motion_time`; absent: measured during the run.
    #[serde(default)]
    pub view_overhead_s: Option<f64>,
    /// For a camera on a link: the least fraction of the image the robot must cover (under
    /// the estimate) for a pose to be worth a view. A fixed camera uses
    /// `[safety] min_in_image` instead.
    #[serde(default = "default_min_robot_image_fraction")]
    pub min_robot_image_fraction: f64,
    /// Renderer backend: `auto` (default: wgpu on a hardware GPU, the CPU otherwise), `cpu`
    /// or `wgpu` (any adapter, software ones included). `--renderer` overrides it.
    #[serde(default)]
    pub renderer: RendererChoice,
}

fn default_max_views() -> usize {
    5
}
fn default_min_views() -> usize {
    3
}
fn default_joint_samples() -> usize {
    2000
}
fn default_climb_steps() -> usize {
    100
}
fn default_candidates() -> usize {
    50
}
fn default_speed() -> f64 {
    0.5
}
fn default_variance_tol() -> f64 {
    0.1
}
fn default_pose_tol_deg() -> f64 {
    0.02
}
fn default_pose_tol_mm() -> f64 {
    0.2
}
fn default_stop_centre() -> Option<f64> {
    Some(1.0)
}
fn default_max_failures() -> usize {
    3
}
fn default_joint_noise() -> f64 {
    0.0005
}
fn default_weigh_motion_time() -> bool {
    true
}
fn default_min_robot_image_fraction() -> f64 {
    0.05
}
fn default_score_downsample() -> u32 {
    8
}

impl Default for CalibrationSettings {
    fn default() -> Self {
        toml::from_str("").expect("every field has a default")
    }
}

/// A starting pose, as measured or as a matrix.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(untagged)]
pub enum InitialGuess {
    /// Eye / look-at / roll.
    LookAt(LookAt),
    /// `camera_from_base`, row-major 4x4.
    Matrix {
        /// Base frame → OpenCV optical frame.
        camera_from_base: [[f64; 4]; 4],
    },
}

impl InitialGuess {
    /// As `camera_from_base`.
    pub fn camera_from_base(&self) -> std::result::Result<Isometry3<f64>, String> {
        match self {
            InitialGuess::LookAt(l) => l.checked_camera_from_base(),
            InitialGuess::Matrix { camera_from_base } => {
                crate::geometry::from_rows(camera_from_base)
            }
        }
    }
}

/// How a fit treats the robot's outline at its mount contact (docs/method.md §6). A base on a
/// plate of its own colour gives masks that run fat there (the `builtin` segmenter never sees
/// the plate uncovered), and hand-made masks can leave out a flange the mesh has: either
/// pulls the camera along its axis. Where the masks are right there, the foot's outline holds
/// the depth, so it is left out only when it disagrees.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum MountContact {
    /// Fit it, then leave it out and solve again when the masks' outline there lies more
    /// than 2 px (`solve::MOUNT_DISAGREEMENT_PX`) from the rendered one, beyond how far the
    /// rest of the outline lies, in most views (`solve::mount_contact_disagrees`). Meant
    /// for masks a segmenter draws; the offline solve fits masks a run gives
    /// ([`MountContact::for_given_masks`]).
    #[default]
    Auto,
    /// Always fit it.
    Fit,
    /// Always leave it out.
    LeaveOut,
}

impl MountContact {
    /// What it means for masks the run gives (hand-made, or another tool's): `auto` fits
    /// them, since they are the user's to mend; the offline solve says when they disagree.
    pub fn for_given_masks(self) -> MountContact {
        match self {
            MountContact::Auto => MountContact::Fit,
            told => told,
        }
    }
}

/// How the next pose is chosen.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum SelectionSetting {
    /// Where the camera hypotheses disagree most.
    #[default]
    Explore,
    /// A random safe pose that shows the robot (baseline).
    Random,
}

/// How exploration ranks joint samples.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum ScoreSetting {
    /// How much a view lowers the predicted rotation and translation covariance of the
    /// solver's estimate, joint errors included ([`crate::explore::cost_reduction`]).
    #[default]
    Information,
    /// Variance of the camera candidates' masks (docs/method.md §5, the paper's score).
    Variance,
}

/// Where exploration's camera candidates come from.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum SourceSetting {
    /// Posterior samples.
    #[default]
    Posterior,
    /// Optimiser iterates (paper).
    Trajectory,
}

impl CalibrationSettings {
    /// Checks ranges, naming the key at fault.
    pub fn validate(&self, path: &Path) -> Result<()> {
        let bad = |f: &str, m: &str| Err(Error::input(path, format!("calibration.{f}"), m));
        if self.max_views == 0 {
            return bad("max_views", "must be at least 1");
        }
        if self.min_views > self.max_views {
            return bad("min_views", "must not exceed max_views");
        }
        if self.joint_samples == 0 {
            return bad("joint_samples", "must be at least 1");
        }
        if self.candidates < 2 {
            return bad("candidates", "must be at least 2");
        }
        if !(self.speed_rad_s > 0.0 && self.speed_rad_s.is_finite()) {
            return bad("speed_rad_s", "must be a positive speed");
        }
        if self.score_downsample == 0 {
            return bad("score_downsample", "must be at least 1");
        }
        if let Some(g) = &self.initial_guess {
            if let Err(m) = g.camera_from_base() {
                return bad("initial_guess", &m);
            }
        }
        Ok(())
    }
}

/// Which renderer backend to use (`--renderer`, `[calibration] renderer`). Plain data, kept
/// with the configuration; `backend::open_renderer` acts on it.
#[derive(
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    serde::Deserialize,
    serde::Serialize,
    clap::ValueEnum,
)]
#[serde(rename_all = "kebab-case")]
pub enum RendererChoice {
    /// The CPU reference renderer.
    Cpu,
    /// wgpu on the best adapter there is, software rasterisers included.
    Wgpu,
    /// wgpu on a hardware GPU adapter, the CPU otherwise (default).
    #[default]
    Auto,
}

impl std::str::FromStr for RendererChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        <RendererChoice as clap::ValueEnum>::from_str(s, false)
            .map_err(|_| format!("unknown renderer {s:?}: use cpu, wgpu or auto"))
    }
}

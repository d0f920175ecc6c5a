//! The daemon's records as its data folder keeps them and its API returns them: the file
//! format tags, a calibration's record and state, the active entries and the bump checks.
//! Plain data, apart from [`super::store`] (which writes them) and [`super::reconcile`]
//! (which reads them back and repairs them), so neither has to import the other.

use serde::{Deserialize, Serialize};

use crate::run::{ResultFile, UncertaintyEntry};

/// `index.json` format tag.
pub const INDEX_FORMAT: &str = "easyhec-daemon-index/1";
/// `active.json` format tag.
pub const ACTIVE_FORMAT: &str = "easyhec-daemon-active/1";
/// `active.json` format tag of a cell with a list of cameras: one [`ActiveFile`] per camera,
/// each camera activated, marked stale and recalibrated by itself.
pub const RIG_ACTIVE_FORMAT: &str = "easyhec-daemon-active/2";
/// `checks.json` format tag.
pub const CHECKS_FORMAT: &str = "easyhec-daemon-checks/1";

/// Where a calibration is in its life.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum State {
    /// Accepted, not started yet.
    Queued,
    /// The loop is running.
    Running,
    /// Finished with a result.
    Succeeded,
    /// Ended by an error (the error field says which).
    Failed,
    /// Ended by `POST …/cancel`; the arm was stopped.
    Cancelled,
    /// The daemon stopped (shut down or killed) while it ran; the views taken are on disk.
    Interrupted,
}

/// What a running calibration's loop is doing now.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum Phase {
    /// Grabbing and segmenting a view.
    Capturing,
    /// Solving the pose from the views so far.
    Solving,
    /// Choosing the next pose.
    Planning,
    /// Moving the arm to it.
    Moving,
}

impl State {
    /// Whether the calibration has ended.
    pub fn is_final(self) -> bool {
        !matches!(self, State::Queued | State::Running)
    }

    /// Lower-case name, as in JSON.
    pub fn name(self) -> &'static str {
        match self {
            State::Queued => "queued",
            State::Running => "running",
            State::Succeeded => "succeeded",
            State::Failed => "failed",
            State::Cancelled => "cancelled",
            State::Interrupted => "interrupted",
        }
    }
}

/// Error of an estimate against a simulated cell's true pose.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq, utoipa::ToSchema)]
pub struct TruthError {
    /// Rotation error, degrees.
    pub rotation_deg: f64,
    /// Translation error, millimetres.
    pub translation_mm: f64,
}

/// One calibration: what `GET /api/v1/calibrations/{id}` returns and `index.json` keeps.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq, utoipa::ToSchema)]
pub struct CalibrationRecord {
    /// `cal-NNNN`, also the run directory's name.
    pub id: String,
    /// Life-cycle state.
    pub state: State,
    /// `api` (a start request) or `bump` (a bump check's recalibration).
    pub trigger: String,
    /// Planned only, never moved.
    pub dry_run: bool,
    /// Views at most for this run.
    pub max_views: usize,
    /// RFC 3339 times.
    pub created_at: String,
    /// When the loop started.
    #[serde(default)]
    pub started_at: Option<String>,
    /// When it ended.
    #[serde(default)]
    pub finished_at: Option<String>,
    /// The run directory, relative to the data folder.
    pub run_dir: String,
    /// What the loop is doing now.
    #[serde(default)]
    pub phase: Option<Phase>,
    /// Last solved round (0-based).
    #[serde(default)]
    pub round: Option<usize>,
    /// Views captured and recorded.
    pub views: usize,
    /// Mask loss at the current estimate.
    #[serde(default)]
    pub loss: Option<f64>,
    /// Mean mask IoU at the current estimate.
    #[serde(default)]
    pub mean_iou: Option<f64>,
    /// Best variance found by the last planning step (scoring pixels).
    #[serde(default)]
    pub best_variance: Option<f64>,
    /// The current estimate, row-major 4x4.
    #[serde(default)]
    pub camera_from_base: Option<[[f64; 4]; 4]>,
    /// 1-sigma uncertainty of the current estimate.
    #[serde(default)]
    pub uncertainty: Option<UncertaintyEntry>,
    /// Why the loop stopped.
    #[serde(default)]
    pub stop_reason: Option<String>,
    /// Why it failed or was interrupted.
    #[serde(default)]
    pub error: Option<String>,
    /// The calibration whose pose this one was warm-started from.
    #[serde(default)]
    pub warm_start_from: Option<String>,
    /// Dry runs: poses planned.
    #[serde(default)]
    pub planned_poses: Option<usize>,
    /// Simulated cells only: error of the estimate against the camera's true pose now.
    #[serde(default)]
    pub truth_error: Option<TruthError>,
    /// A list of cameras: the cameras this calibration was asked for (the top-level
    /// estimate fields are the first one's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cameras: Option<Vec<String>>,
    /// A list of cameras: each calibrated camera's final result.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_results: Option<Vec<CameraRecord>>,
}

/// One camera's final result in a calibration of a list of cameras.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq, utoipa::ToSchema)]
pub struct CameraRecord {
    /// The camera's name in the config.
    pub camera: String,
    /// Its estimate, row-major 4x4.
    pub camera_from_base: [[f64; 4]; 4],
    /// 1-sigma uncertainty of the estimate.
    #[serde(default)]
    pub uncertainty: Option<UncertaintyEntry>,
    /// Mean mask IoU at the estimate.
    pub mean_iou: f64,
    /// Why this camera stopped asking for views.
    pub stop_reason: String,
    /// Simulated cells only: error against the camera's true pose now.
    #[serde(default)]
    pub truth_error: Option<TruthError>,
}

/// `active.json`: the calibration in use, with its result, surviving restarts.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq, utoipa::ToSchema)]
pub struct ActiveFile {
    /// Always [`ACTIVE_FORMAT`].
    pub format: String,
    /// Calibration id.
    pub id: String,
    /// When it became active.
    pub activated_at: String,
    /// A bump check found the camera moved since.
    pub stale: bool,
    /// When it became stale.
    #[serde(default)]
    pub stale_since: Option<String>,
    /// The camera of a list this entry belongs to (absent for a cell of one camera).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<String>,
    /// The `easyhec-result/1` body.
    pub result: ResultFile,
}

/// `active.json` of a cell with a list of cameras: the cameras that have an active
/// calibration, sorted by name. Two cameras may be active from different calibrations.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq, utoipa::ToSchema)]
pub struct RigActiveFile {
    /// Always [`RIG_ACTIVE_FORMAT`].
    pub format: String,
    /// One entry per camera, each naming its camera.
    pub cameras: Vec<ActiveFile>,
}

/// One bump check.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq, utoipa::ToSchema)]
pub struct CheckRecord {
    /// RFC 3339 time.
    pub at: String,
    /// `api` or `schedule`.
    pub trigger: String,
    /// The calibration checked.
    pub calibration_id: String,
    /// Reported joints at capture.
    pub joints: Vec<f64>,
    /// Whether the arm was moved to `check_pose` first.
    pub moved_to_check_pose: bool,
    /// IoU of the observed mask and the silhouette rendered under the calibration, once the
    /// segmenter's outline offset (`mask_offset_px`) is taken out.
    pub iou: f64,
    /// Mean distance between the two outlines, both ways, pixels, once the segmenter's
    /// outline offset is taken out.
    pub boundary_px: f64,
    /// How far the observed outline lay outward of the rendered one (the mean of the middle
    /// half of its distances, pixels, negative: inward), up to `bump_max_mask_offset_px`
    /// either way: a segmenter's fat or thin habit, which the two figures above do not count.
    #[serde(default)]
    pub mask_offset_px: f64,
    /// Thresholds applied: IoU below…
    pub min_iou: f64,
    /// …or boundary distance above this marks the calibration stale: `bump_max_boundary_px`
    /// plus `explained_px`.
    pub max_boundary_px: f64,
    /// Outline distance the calibration's own uncertainty explains at this view, pixels
    /// (twice the RMS displacement its covariance predicts; 0 without a covariance).
    #[serde(default)]
    pub explained_px: f64,
    /// The verdict.
    pub stale: bool,
    /// The recalibration this check started, if any.
    #[serde(default)]
    pub recalibration: Option<String>,
    /// The camera checked, for a cell with a list of cameras.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<String>,
}

/// What [`super::store::Store::open`] repaired.
#[derive(Clone, Debug, Default)]
pub struct Recovery {
    /// Calibrations found queued or running, now `interrupted`.
    pub interrupted: Vec<String>,
}

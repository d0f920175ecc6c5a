//! The closed loop (docs/method.md §5): capture, solve, choose the next arm pose where the
//! camera hypotheses that still fit disagree most, check it is safe, move, capture, solve
//! again, and stop when more views stop helping. Everything is recorded into a run directory
//! as it happens ([`recorder`]), so a crash loses nothing and `easyhec solve` can re-solve it
//! offline. Where to go next is the [`planner`]'s job; this module runs the rounds.

pub mod motion_cost;
pub mod planner;
pub mod recorder;
mod session;
mod stop_reason;
pub mod visibility;

pub use stop_reason::StopReason;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

use crate::cell::Cell;
use crate::error::Result;
use crate::run::{ResultFile, UncertaintyEntry};
use crate::safety::Clearance;
use crate::solve::SolveReport;

pub use motion_cost::MotionCost;
pub use planner::{choose_reachable, rank_poses, PlanCamera, PlanRequest, PlanStats, Ranked};
pub use recorder::Recorder;
pub use visibility::{in_image_fraction, VisibilityRule};

/// One round of the loop, as `rounds.json` records it.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RoundRecord {
    /// 0-based round.
    pub round: usize,
    /// Views solved from.
    pub views: usize,
    /// The estimate after this round.
    pub camera_from_base: [[f64; 4]; 4],
    /// Mean mask IoU at the estimate.
    pub mean_iou: f64,
    /// Mask loss at the estimate.
    pub loss: f64,
    /// Change from the previous round's estimate, degrees / millimetres.
    pub pose_change: Option<[f64; 2]>,
    /// Best disagreement score found when planning the next view (scoring pixels).
    pub best_variance: Option<f64>,
    /// The pose chosen next, when one was.
    pub next_joints: Option<Vec<f64>>,
    /// Events (faults, refusals, skipped candidates).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub events: Vec<String>,
    /// Each camera's figures, for a list of cameras (the round's own figures are then the
    /// first camera's).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub cameras: Vec<CameraRound>,
}

/// One camera's figures in a round of a rig.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct CameraRound {
    /// The camera's name.
    pub name: String,
    /// Its estimate after this round.
    pub camera_from_base: [[f64; 4]; 4],
    /// Mean mask IoU at the estimate.
    pub mean_iou: f64,
    /// Mask loss at the estimate.
    pub loss: f64,
    /// Change from the previous round's estimate, degrees / millimetres.
    pub pose_change: Option<[f64; 2]>,
    /// The reported 95% bound on the camera centre, millimetres.
    pub camera_centre_95_mm: f64,
    /// Why the camera stopped asking for views, once it has.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub done: Option<String>,
}

/// What the loop produced for one camera.
#[derive(Clone, Debug)]
pub struct CameraOutcome {
    /// The camera's name.
    pub name: String,
    /// Its result, as `easyhec-result/1` would record it.
    pub result: ResultFile,
    /// Its final solve.
    pub report: SolveReport,
}

/// A pose chosen by the planner, with its checks.
#[derive(Clone, Debug)]
pub struct PlannedPose {
    /// Target joints.
    pub joints: Vec<f64>,
    /// Ranking score (higher is better; see [`crate::config::ScoreSetting`]).
    pub score: f64,
    /// Variance of the camera candidates' masks at this pose (computed for the best only,
    /// unless the variance ranked them all).
    pub variance: Option<f64>,
    /// What the view shows under the current estimate: the share of the robot inside the image
    /// (fixed camera), or the share of the image the robot covers (camera on a link). NaN for
    /// a seeding move, taken before there is any estimate (score 0 then too).
    pub in_image: f64,
    /// Clearances along the path.
    pub clearance: Clearance,
    /// Poses checked on the path.
    pub path_samples: usize,
}

/// Asked before each move with the planned pose; `false` ends the calibration.
pub type ConfirmMove = Arc<dyn Fn(&PlannedPose) -> bool + Send + Sync>;

/// What the loop reports as it goes, so a caller (the daemon) can show live progress
/// without reading the run directory back.
#[derive(Clone, Debug, Serialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum Progress {
    /// A view was captured and recorded (`views/NNN.*` and `run.json` are on disk).
    ViewCaptured {
        /// Index of the view in the run.
        index: usize,
        /// Reported joints at capture.
        joints: Vec<f64>,
    },
    /// A round was solved (after `rounds.json` was written).
    Round {
        /// 0-based round.
        round: usize,
        /// Views solved from.
        views: usize,
        /// Mask loss at the estimate.
        loss: f64,
        /// Mean mask IoU at the estimate.
        mean_iou: f64,
        /// The estimate, row-major 4x4.
        camera_from_base: [[f64; 4]; 4],
        /// 1-sigma uncertainty of the estimate, when the fit gives one (boxed: it is most of
        /// the event's size).
        uncertainty: Option<Box<UncertaintyEntry>>,
    },
    /// Planning for the next view finished: the candidates' disagreement at the best pose.
    Planned {
        /// The round whose estimate was planned from.
        round: usize,
        /// Best variance (scoring pixels), when a pose showed the robot.
        best_variance: Option<f64>,
    },
    /// The arm is about to move to the pose of the next view.
    Moving {
        /// Index the view will get.
        view: usize,
        /// Target joints.
        joints: Vec<f64>,
    },
}

/// Receives [`Progress`] events; called on the loop's thread, so keep it quick.
pub type ProgressSink = Arc<dyn Fn(&Progress) + Send + Sync>;

/// How to run the loop.
#[derive(Clone, Default)]
pub struct RunOptions {
    /// Plan and print, never move.
    pub dry_run: bool,
    /// Asked before each move; `false` ends the calibration.
    pub confirm: Option<ConfirmMove>,
    /// Draw progress bars on stderr.
    pub progress: bool,
    /// Per-view and per-round events (the daemon's live status).
    pub on_progress: Option<ProgressSink>,
    /// Set to end the calibration: checked between rounds and before each move, and watched
    /// during a move, which is then stopped (`Arm::stop`). The outcome is `cancelled`.
    pub cancel: Option<Arc<AtomicBool>>,
    /// Starting pose instead of `[calibration] initial_guess` (a recalibration warm-started
    /// from the previous result).
    pub initial_guess: Option<Isometry3<f64>>,
    /// `[calibration] max_views` for this run only (at least 1).
    pub max_views: Option<usize>,
    /// For a list of cameras: calibrate only these, by name; the others neither grab nor
    /// ask for views. A bumped camera is recalibrated so, leaving the others' results alone.
    pub only_cameras: Option<Vec<String>>,
    /// Starting poses by camera name, before the camera's own and the run's guesses (a
    /// rig's recalibration warm-started from each camera's previous result).
    pub camera_guesses: std::collections::BTreeMap<String, Isometry3<f64>>,
}

impl RunOptions {
    fn emit(&self, p: Progress) {
        if let Some(sink) = &self.on_progress {
            sink(&p);
        }
    }

    fn cancelled(&self) -> bool {
        self.cancel
            .as_ref()
            .is_some_and(|c| c.load(Ordering::SeqCst))
    }

    /// Resolves once the cancel flag is set (never without one).
    async fn wait_cancelled(&self) {
        loop {
            if self.cancelled() {
                return;
            }
            tokio::time::sleep(std::time::Duration::from_millis(20)).await;
        }
    }
}

/// What a calibration produced.
#[derive(Clone, Debug)]
pub struct Outcome {
    /// The result as written to `result.json` (not written on a dry run); for a list of
    /// cameras, the first camera's part of it.
    pub result: ResultFile,
    /// The final solve (the first camera's).
    pub report: SolveReport,
    /// Every camera's result and solve, in the config's order.
    pub cameras: Vec<CameraOutcome>,
    /// Every round.
    pub rounds: Vec<RoundRecord>,
    /// Dry run: the poses that would be visited.
    pub planned: Vec<PlannedPose>,
    /// Run directory.
    pub run_dir: PathBuf,
    /// How the run recorded its cameras, and so which result format was written.
    pub layout: crate::run::rig::RunLayout,
    /// Ended by [`RunOptions::cancel`] (the result covers the views taken until then).
    pub cancelled: bool,
    /// Ended because the arm faulted (and `clear_faults` is off) or its moves kept failing:
    /// the result covers the views taken until then, and a caller must not report success.
    pub faulted: bool,
}

/// Runs the loop on `cell`, recording into `out`.
pub async fn calibrate(cell: &Cell, out: &Path, opts: &RunOptions) -> Result<Outcome> {
    let mut session = session::Session::start(cell, out, opts)?;
    session.first_view().await?;
    let stop_reason = loop {
        if let Some(reason) = session.round().await? {
            break reason;
        }
    };
    session.finish(stop_reason)
}

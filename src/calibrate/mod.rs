//! The closed loop (docs/method.md §5): capture, solve, choose the next arm pose where the
//! camera hypotheses that still fit disagree most, check it is safe, move, capture, solve
//! again, and stop when more views stop helping. Everything is recorded into a run directory
//! as it happens ([`recorder`]), so a crash loses nothing and `easyhec solve` can re-solve it
//! offline. Where to go next is the [`planner`]'s job; this module runs the rounds.

pub mod planner;
pub mod recorder;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use easyhec_drivers::ArmStatus;
use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

use crate::backend::{open_renderer, Backend};
use crate::camera::{Intrinsics, LensWarp};
use crate::cell::Cell;
use crate::config::CalibrationSettings;
use crate::error::{Error, Result};
use crate::geometry::{rotation_error_deg, to_rows, translation_error_mm};
use crate::init::{initialise, InitOptions};
use crate::io::write_json_atomic;
use crate::pipeline::segment_solve::{LiveFrames, POOR_FIT_IOU};
use crate::render::PosedRobot;
use crate::run::{CameraEntry, PerView, ResultFile, RobotEntry, UncertaintyEntry};
use crate::safety::{CheckedMove, Clearance};
use crate::solve::{solve, SolveOptions, SolveReport, View};

pub use planner::{choose_reachable, in_image_fraction, rank_poses, PlanStats, Ranked};
pub use recorder::Recorder;

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
}

/// A pose chosen by the planner, with its checks.
#[derive(Clone, Debug)]
pub struct PlannedPose {
    /// Target joints.
    pub joints: Vec<f64>,
    /// Ranking score (higher is better; see [`ScoreSetting`]).
    pub score: f64,
    /// Variance of the camera candidates' masks at this pose (computed for the best only,
    /// unless the variance ranked them all).
    pub variance: Option<f64>,
    /// Fraction of the robot inside the image under the current estimate.
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
        /// 1-sigma uncertainty of the estimate, when the fit gives one.
        uncertainty: Option<UncertaintyEntry>,
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
    /// The result as written to `result.json` (not written on a dry run).
    pub result: ResultFile,
    /// The final solve.
    pub report: SolveReport,
    /// Every round.
    pub rounds: Vec<RoundRecord>,
    /// Dry run: the poses that would be visited.
    pub planned: Vec<PlannedPose>,
    /// Run directory.
    pub run_dir: PathBuf,
    /// Ended by [`RunOptions::cancel`] (the result covers the views taken until then).
    pub cancelled: bool,
}

/// Runs the loop on `cell`, recording into `out`.
pub async fn calibrate(cell: &Cell, out: &Path, opts: &RunOptions) -> Result<Outcome> {
    let mut session = Session::start(cell, out, opts)?;
    session.first_view().await?;
    let stop_reason = loop {
        if let Some(reason) = session.round().await? {
            break reason;
        }
    };
    session.finish(stop_reason)
}

/// Why a move did not bring a new view.
enum MoveOutcome {
    /// The arm is at the target.
    Arrived,
    /// The move failed; re-plan from wherever the arm stopped.
    Retry,
    /// End the loop with this reason.
    Stop(String),
}

/// Everything one calibration carries from round to round.
struct Session<'a> {
    cell: &'a Cell,
    opts: &'a RunOptions,
    settings: CalibrationSettings,
    camera: Intrinsics,
    rec: Recorder,
    pb: indicatif::ProgressBar,
    renderer: Arc<dyn Backend>,
    solve_opts: SolveOptions,
    started: Instant,
    solve_s: f64,
    explore_s: f64,
    motion_s: f64,
    guess: Option<Isometry3<f64>>,
    /// Reported joints of every view.
    taken: Vec<Vec<f64>>,
    /// Frames kept for a context-aware segmenter (absent for per-frame segmenters).
    live: Option<LiveFrames>,
    views: Vec<View>,
    report: Option<SolveReport>,
    rounds: Vec<RoundRecord>,
    previous_best: Option<f64>,
    failures: usize,
    planned: Vec<PlannedPose>,
    cancelled: bool,
}

impl<'a> Session<'a> {
    /// Checks the run's settings, opens the renderer and starts the run directory.
    fn start(cell: &'a Cell, out: &Path, opts: &'a RunOptions) -> Result<Session<'a>> {
        let settings = run_settings(cell, opts)?;
        let camera = cell.camera.intrinsics().clone();
        let guess = initial_guess(cell, opts, &settings)?;
        let rec = Recorder::create(out, robot_entry(cell), CameraEntry::of(&camera), guess)?;
        let pb = progress_bar(opts, settings.max_views);
        let renderer = open_renderer(settings.renderer, !opts.progress)
            .map_err(|m| Error::input(&cell.config_path, "calibration.renderer", m))?;
        let live = cell.segmenter.uses_context().then(|| LiveFrames {
            frames: Vec::new(),
            min_band_px: cell.config.segmenter.min_band_px(),
            final_band_px: cell.config.segmenter.final_band_px(),
        });
        Ok(Session {
            cell,
            opts,
            settings,
            camera,
            rec,
            pb,
            renderer,
            solve_opts: SolveOptions::default(),
            started: Instant::now(),
            solve_s: 0.0,
            explore_s: 0.0,
            motion_s: 0.0,
            guess,
            taken: Vec::new(),
            live,
            views: Vec::new(),
            report: None,
            rounds: Vec::new(),
            previous_best: None,
            failures: 0,
            planned: Vec::new(),
            cancelled: false,
        })
    }

    fn report(&self) -> &SolveReport {
        self.report
            .as_ref()
            .expect("round 0 solved before any other step")
    }

    fn last_round(&mut self) -> &mut RoundRecord {
        self.rounds.last_mut().expect("round 0 exists")
    }

    /// The view where the arm stands, and the first estimate from it (the guess, or an
    /// automatic initialisation).
    async fn first_view(&mut self) -> Result<()> {
        let guess = self.guess;
        self.capture(guess.as_ref(), None).await?;
        emit_view(self.opts, &self.taken);
        self.pb.set_position(1);
        let t = Instant::now();
        let r = self.renderer.as_ref();
        let report = match guess {
            Some(g) => solve(r, &self.camera, &self.views, &g, &self.solve_opts)?,
            None => initialise(
                r,
                &self.camera,
                &self.views,
                &self.solve_opts,
                &InitOptions::default(),
            )?,
        };
        self.solve_s += t.elapsed().as_secs_f64();
        self.rounds = vec![RoundRecord {
            round: 0,
            views: 1,
            camera_from_base: to_rows(&report.camera_from_base),
            mean_iou: report.mean_iou(),
            loss: report.loss,
            pose_change: None,
            best_variance: None,
            next_joints: None,
            events: Vec::new(),
        }];
        self.rec.write_rounds(&self.rounds)?;
        emit_round(self.opts, &self.rounds, &report);
        self.report = Some(report);
        Ok(())
    }

    /// One round: plan, check the stop rules, move, capture and solve. `Some(reason)` ends
    /// the loop.
    async fn round(&mut self) -> Result<Option<String>> {
        let round = self.rounds.len() - 1;
        if self.opts.cancelled() {
            self.cancelled = true;
            return Ok(Some(format!("cancelled after {} views", self.views.len())));
        }
        let s = &self.settings;
        if self.views.len() >= s.max_views && !self.opts.dry_run {
            return Ok(Some(format!(
                "reached the maximum of {} views",
                s.max_views
            )));
        }
        let (ranked, best) = self.plan(round);
        if let Some(reason) = self.converged(best) {
            return Ok(Some(reason));
        }
        self.previous_best = best;
        let from = self.cell.arm.read_joints().await?;
        if self.opts.dry_run {
            return Ok(Some(self.plan_dry_run(&ranked, &from)));
        }
        let mut events = Vec::new();
        let speed = self.settings.speed_rad_s;
        let chosen = choose_reachable(self.cell, &ranked, &from, speed, |_| false, &mut events);
        self.last_round().events.extend(events);
        let Some((pose, mv)) = chosen else {
            return Ok(Some(format!(
                "no safe, reachable pose left after {} views",
                self.views.len()
            )));
        };
        match self.move_to(&pose, &mv).await? {
            MoveOutcome::Arrived => {}
            MoveOutcome::Retry => return Ok(None),
            MoveOutcome::Stop(reason) => return Ok(Some(reason)),
        }
        self.capture_and_solve(round, best).await?;
        Ok(None)
    }

    /// Ranks the next poses and records the planning step.
    fn plan(&mut self, round: usize) -> (Vec<Ranked>, Option<f64>) {
        let t = Instant::now();
        let (ranked, stats) = rank_poses(
            self.renderer.as_ref(),
            self.cell,
            &self.camera,
            self.report(),
            &self.taken,
            &self.settings,
            round,
        );
        let best = ranked.first().and_then(|r| r.variance);
        self.explore_s += t.elapsed().as_secs_f64();
        self.opts.emit(Progress::Planned {
            round,
            best_variance: best,
        });
        let last = self.last_round();
        last.best_variance = best;
        last.events.push(format!(
            "{} joint samples: {} safe, {} show the robot",
            stats.sampled, stats.safe, stats.scored
        ));
        (ranked, best)
    }

    /// The variance rule: the best disagreement settled, enough views, and the estimate
    /// barely moved in the last round.
    fn converged(&self, best: Option<f64>) -> Option<String> {
        let s = &self.settings;
        let last = self.rounds.last()?;
        let (Some(prev), Some(best), Some([deg, mm])) =
            (self.previous_best, best, last.pose_change)
        else {
            return None;
        };
        let settled = (prev - best).abs() <= s.variance_rel_tol * prev.max(1e-12);
        (settled && self.views.len() >= s.min_views && deg < s.pose_tol_deg && mm < s.pose_tol_mm)
            .then(|| format!("variance converged after {} views", self.views.len()))
    }

    /// A dry run plans the whole sequence from the first view's estimate, chaining paths,
    /// and moves nothing.
    fn plan_dry_run(&mut self, ranked: &[Ranked], from: &[f64]) -> String {
        let mut at = from.to_vec();
        let mut events = Vec::new();
        for _ in 1..self.settings.max_views {
            let planned = &self.planned;
            let far = |q: &[f64]| {
                planned.iter().any(|p: &PlannedPose| {
                    p.joints
                        .iter()
                        .zip(q)
                        .map(|(a, b)| (a - b).abs())
                        .fold(0.0, f64::max)
                        < 0.3
                })
            };
            let speed = self.settings.speed_rad_s;
            match choose_reachable(self.cell, ranked, &at, speed, far, &mut events) {
                Some((p, _)) => {
                    at = p.joints.clone();
                    self.planned.push(p);
                }
                None => break,
            }
        }
        self.last_round().events.extend(events);
        format!(
            "dry run: planned {} poses, nothing moved",
            self.planned.len()
        )
    }

    /// Asks the operator (when configured), then sends the checked move and watches it, the
    /// cancel flag included; a failed move is recorded and, within the failure budget,
    /// retried from wherever the arm stopped.
    async fn move_to(&mut self, pose: &PlannedPose, mv: &CheckedMove) -> Result<MoveOutcome> {
        let n = self.views.len();
        if let Some(confirm) = &self.opts.confirm {
            if !self.pb.suspend(|| confirm(pose)) {
                return Ok(MoveOutcome::Stop(format!(
                    "operator declined a move after {n} views"
                )));
            }
        }
        if self.opts.cancelled() {
            self.cancelled = true;
            return Ok(MoveOutcome::Stop(format!("cancelled after {n} views")));
        }
        self.last_round().next_joints = Some(pose.joints.clone());
        self.pb.set_message(format!("moving to view {}", n + 1));
        self.opts.emit(Progress::Moving {
            view: n,
            joints: pose.joints.clone(),
        });
        let t = Instant::now();
        let moved = self.execute(mv).await;
        self.motion_s += t.elapsed().as_secs_f64();
        if self.opts.cancelled() {
            if moved.is_err() {
                let _ = self.cell.arm.stop().await;
                self.last_round()
                    .events
                    .push("move stopped: calibration cancelled".into());
            }
            self.cancelled = true;
            return Ok(MoveOutcome::Stop(format!("cancelled after {n} views")));
        }
        match moved {
            Ok(()) => Ok(MoveOutcome::Arrived),
            Err(e) => self.after_failed_move(e).await,
        }
    }

    /// Sends a checked move and waits for it, stopping the arm if the run is cancelled.
    async fn execute(&self, mv: &CheckedMove) -> Result<()> {
        let motion = self.cell.arm.execute(mv).await?;
        tokio::select! {
            r = motion.wait() => r.map_err(Error::from),
            () = self.opts.wait_cancelled() => {
                // Stop first; the motion future is dropped, the arm halts where it is.
                let _ = self.cell.arm.stop().await;
                Err(Error::Hardware("move stopped: calibration cancelled".into()))
            }
        }
    }

    /// Records a failed move and decides: retry (clearing a fault when allowed) or stop.
    async fn after_failed_move(&mut self, e: Error) -> Result<MoveOutcome> {
        self.failures += 1;
        let note = format!("move failed: {e}");
        self.last_round().events.push(note.clone());
        self.rec.write_rounds(&self.rounds)?;
        let _ = self.cell.arm.stop().await;
        let status = self.cell.arm.status().await?;
        let faulted = matches!(status, ArmStatus::Fault(_) | ArmStatus::Stopped);
        if self.failures > self.settings.max_motion_failures {
            return Ok(MoveOutcome::Stop(format!(
                "gave up after {} failed moves ({note})",
                self.failures
            )));
        }
        if faulted {
            if !self.settings.clear_faults {
                return Ok(MoveOutcome::Stop(format!(
                    "arm fault, not cleared (calibration.clear_faults = false): {e}"
                )));
            }
            self.cell.arm.clear_fault().await?;
        }
        Ok(MoveOutcome::Retry)
    }

    /// Captures the view at the new pose, solves from the previous estimate and records the
    /// round.
    async fn capture_and_solve(&mut self, round: usize, best: Option<f64>) -> Result<()> {
        let previous = self.report().camera_from_base;
        let report = self.report.take().expect("round 0 solved");
        let captured = self.capture(Some(&previous), Some(&report)).await;
        self.report = Some(report);
        captured?;
        emit_view(self.opts, &self.taken);
        self.pb.set_position(self.views.len() as u64);
        let t = Instant::now();
        let mut report = solve(
            self.renderer.as_ref(),
            &self.camera,
            &self.views,
            &previous,
            &self.solve_opts,
        )?;
        report.trajectory.insert(0, previous);
        self.solve_s += t.elapsed().as_secs_f64();
        let change = [
            rotation_error_deg(&previous, &report.camera_from_base),
            translation_error_mm(&previous, &report.camera_from_base),
        ];
        self.rounds.push(RoundRecord {
            round: round + 1,
            views: self.views.len(),
            camera_from_base: to_rows(&report.camera_from_base),
            mean_iou: report.mean_iou(),
            loss: report.loss,
            pose_change: Some(change),
            best_variance: None,
            next_joints: None,
            events: Vec::new(),
        });
        self.rec.write_rounds(&self.rounds)?;
        emit_round(self.opts, &self.rounds, &report);
        self.pb.set_message(format!(
            "round {} loss {:.5} IoU {:.4} best var {:.1} px change {:.3} deg / {:.2} mm",
            round + 1,
            report.loss,
            report.mean_iou(),
            best.unwrap_or(0.0),
            change[0],
            change[1]
        ));
        self.report = Some(report);
        Ok(())
    }

    /// Reads the joints and grabs a frame at the arm's present pose, segments it, records the
    /// view and adds it to `views`. With a context-aware segmenter the new frame is segmented
    /// together with every earlier one under `estimate`, and earlier masks are re-segmented
    /// and rewritten when they change.
    async fn capture(
        &mut self,
        estimate: Option<&Isometry3<f64>>,
        report: Option<&SolveReport>,
    ) -> Result<()> {
        let cell = self.cell;
        let joints = cell.arm.read_joints().await?;
        let frame = cell.camera.grab().await?;
        let camera = &self.camera;
        if frame.width != camera.width || frame.height != camera.height {
            return Err(Error::Hardware(format!(
                "camera returned a {}x{} frame; its intrinsics say {}x{}",
                frame.width, frame.height, camera.width, camera.height
            )));
        }
        let Some(live) = self.live.as_mut() else {
            let mask = cell.segmenter.segment(&frame)?;
            self.rec.add_view(&joints, &frame, &mask)?;
            self.taken.push(joints.clone());
            self.views.push(View {
                robot: PosedRobot::new(&cell.robot, &joints),
                observed: camera.undistort_mask(&mask),
            });
            return Ok(());
        };
        live.frames.push(frame);
        self.taken.push(joints.clone());
        let band = live.min_band_px;
        let rec = &self.rec;
        let masks = match live.resegment(
            self.renderer.as_ref(),
            cell.segmenter.as_ref(),
            &cell.robot,
            camera,
            band,
            &self.taken,
            estimate,
            report,
            &mut self.views,
            |i, m| rec.replace_mask(i, m),
        ) {
            Ok(m) => m,
            Err(e) => {
                live.frames.pop();
                self.taken.pop();
                return Err(e);
            }
        };
        let last = live.frames.last().expect("just pushed");
        self.rec
            .add_view(&joints, last, masks.last().expect("one mask per frame"))?;
        Ok(())
    }

    /// The last views were segmented under the previous estimate: re-segment all of them
    /// under the final one and solve once more; when that estimate fits, with the final
    /// (narrowest) band: a narrow band is only safe around a right render.
    fn resegment_final(&mut self) -> Result<()> {
        let Some(live) = &self.live else {
            return Ok(());
        };
        let t = Instant::now();
        let report = self.report.as_ref().expect("round 0 solved");
        let floor = if report.mean_iou() >= POOR_FIT_IOU {
            live.final_band_px.min(live.min_band_px)
        } else {
            live.min_band_px
        };
        let rec = &self.rec;
        live.resegment(
            self.renderer.as_ref(),
            self.cell.segmenter.as_ref(),
            &self.cell.robot,
            &self.camera,
            floor,
            &self.taken,
            Some(&report.camera_from_base),
            Some(report),
            &mut self.views,
            |i, m| rec.replace_mask(i, m),
        )?;
        let report = solve(
            self.renderer.as_ref(),
            &self.camera,
            &self.views,
            &report.camera_from_base,
            &self.solve_opts,
        )?;
        self.solve_s += t.elapsed().as_secs_f64();
        let last = self.last_round();
        last.camera_from_base = to_rows(&report.camera_from_base);
        last.mean_iou = report.mean_iou();
        last.loss = report.loss;
        last.events
            .push("re-segmented every view under the final estimate and re-solved".into());
        self.report = Some(report);
        Ok(())
    }

    /// Re-segments once more when that helps, then writes the result (not on a dry run).
    fn finish(mut self, stop_reason: String) -> Result<Outcome> {
        self.pb.finish_and_clear();
        if !self.opts.dry_run && !self.cancelled {
            self.resegment_final()?;
        }
        self.rec.write_rounds(&self.rounds)?;
        let report = self.report.take().expect("round 0 solved");
        let cell = self.cell;
        let mut result =
            ResultFile::new(&report.camera_from_base, &cell.robot.links[cell.robot.base]);
        result.views_used = (0..self.views.len()).collect();
        result.per_view = report
            .per_view_iou
            .iter()
            .enumerate()
            .map(|(i, &iou)| PerView { view: i, iou })
            .collect();
        result.uncertainty = UncertaintyEntry::of(&report.uncertainty);
        result.stop_reason = stop_reason;
        let timings = [
            ("total", self.started.elapsed().as_secs_f64()),
            ("solve", self.solve_s),
            ("explore", self.explore_s),
            ("motion", self.motion_s),
        ];
        for (k, v) in timings {
            result.timings_s.insert(k.into(), v);
        }
        if !self.opts.dry_run {
            write_json_atomic(&self.rec.dir().join("result.json"), &result)?;
        }
        Ok(Outcome {
            result,
            report,
            rounds: self.rounds,
            planned: self.planned,
            run_dir: self.rec.dir().to_path_buf(),
            cancelled: self.cancelled,
        })
    }
}

/// The `[calibration]` settings of this run: `RunOptions::max_views` applied, the commanded
/// speed checked against the safety cap.
fn run_settings(cell: &Cell, opts: &RunOptions) -> Result<CalibrationSettings> {
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
fn initial_guess(
    cell: &Cell,
    opts: &RunOptions,
    settings: &CalibrationSettings,
) -> Result<Option<Isometry3<f64>>> {
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
fn robot_entry(cell: &Cell) -> RobotEntry {
    let src = &cell.robot.source;
    RobotEntry {
        urdf: recorder::absolute(&src.urdf),
        package_dirs: src
            .package_dirs
            .iter()
            .map(|(k, v)| (k.clone(), recorder::absolute(v)))
            .collect(),
        base_link: Some(cell.robot.links[cell.robot.base].clone()),
        ignore_links: src.ignore_links.clone(),
        joints: cell
            .robot
            .joint_names()
            .iter()
            .map(|s| s.to_string())
            .collect(),
    }
}

fn progress_bar(opts: &RunOptions, max_views: usize) -> indicatif::ProgressBar {
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

fn emit_view(opts: &RunOptions, taken: &[Vec<f64>]) {
    if let Some(joints) = taken.last() {
        opts.emit(Progress::ViewCaptured {
            index: taken.len() - 1,
            joints: joints.clone(),
        });
    }
}

fn emit_round(opts: &RunOptions, rounds: &[RoundRecord], report: &SolveReport) {
    if let Some(r) = rounds.last() {
        opts.emit(Progress::Round {
            round: r.round,
            views: r.views,
            loss: r.loss,
            mean_iou: r.mean_iou,
            camera_from_base: r.camera_from_base,
            uncertainty: UncertaintyEntry::of(&report.uncertainty),
        });
    }
}

//! One calibration's state from round to round, and the steps of a round: plan, check the
//! stop rules, move, capture, solve, record. The stop rules (`stop`), the moves (`motion`) and
//! the set-up and reporting helpers (`setup`) have files of their own.

mod motion;
mod seed;
mod setup;
mod stop;

use setup::{
    camera_result, check_only_cameras, emit_round, emit_view, initial_guess, judge_loop_fit,
    progress_bar, robot_entry, run_settings, track,
};

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use rayon::prelude::*;

use nalgebra::{Isometry3, Matrix6};

use super::motion_cost::{self, MotionCost};
use super::planner::{choose_reachable, rank_poses, PlanCamera, PlanRequest, Ranked};
use super::recorder::{RecordedCamera, Recorder};
use super::{
    CameraOutcome, CameraRound, Outcome, PlannedPose, Progress, RoundRecord, RunOptions, StopReason,
};
use crate::backend::{open_renderer, Backend};
use crate::camera::{Intrinsics, LensWarp};
use crate::cell::{CameraRef, Cell};
use crate::config::CalibrationSettings;
use crate::error::{Error, Result};
use crate::geometry::{rotation_error_deg, to_rows, translation_error_mm};
use crate::init::{initialise, InitOptions};
use crate::pipeline::segment_solve::{kept_mount_decision, LiveFrames, POOR_FIT_IOU};
use crate::pipeline::undecided::{undecided_term, SegmentedFrame};
use crate::render::PosedRobot;
use crate::run::rig::{write_result, JointCorrections, RunLayout, RunSummary};
use crate::run::CameraEntry;
use crate::run::ResultFile;
use crate::solve::{
    solve, solve_with_shared_joints, with_segmentation_term, CameraSolve, SegmentationTerm,
    SolveOptions, SolveReport, View,
};

/// Mean IoU below which a camera on a link has a round's solve repeated from the run's own
/// starting pose (a fixed camera: below [`POOR_FIT_IOU`]). A fixed camera sees the whole arm,
/// whose outline fits far worse than that anywhere but near the right pose. A wrist camera
/// sees a few round links from close by: a right estimate fits at 0.97 or better under
/// segmenter-like noise, yet one that slid into a wrong basin can still fit at 0.9 (seen in
/// a seeded fixed-and-wrist cell: the wrist camera alone 4.2° / 38 mm off at IoU 0.90, under
/// a 95% bound of 0.2 mm).
const REFIT_IOU: f64 = 0.95;
/// Why a move did not bring a new view.
enum MoveOutcome {
    /// The arm is at the target.
    Arrived,
    /// The move failed; re-plan from wherever the arm stopped.
    Retry,
    /// End the loop with this reason.
    Stop(StopReason),
}

/// One camera's side of the loop: its views, masks and estimate. A single camera is a rig of
/// one; every camera of a rig sees every view.
struct Track<'a> {
    unit: CameraRef<'a>,
    camera: Intrinsics,
    guess: Option<Isometry3<f64>>,
    /// Frames kept for a context-aware segmenter (absent for per-frame segmenters).
    live: Option<LiveFrames>,
    views: Vec<View>,
    report: Option<SolveReport>,
    /// Change of the estimate in the last round, degrees / millimetres.
    change: Option<[f64; 2]>,
    /// Why this camera stopped asking for views (a rig's camera that converged).
    done: Option<StopReason>,
}

impl Track<'_> {
    fn report(&self) -> &SolveReport {
        self.report
            .as_ref()
            .expect("round 0 solved before any other step")
    }

    /// `report` with the segmentation term ([`crate::pipeline::undecided`]) when this
    /// camera's masks were drawn from its live frames by a segmenter with per-pixel evidence.
    /// A term that cannot be measured is recorded as such ([`with_segmentation_term`]).
    fn with_segmentation_term(
        &self,
        renderer: &dyn Backend,
        report: SolveReport,
        opts: &SolveOptions,
    ) -> SolveReport {
        let Some(live) = &self.live else {
            return report;
        };
        if report.segmentation != SegmentationTerm::NotApplicable {
            return report;
        }
        let measured = self.measure_segmentation_term(live, renderer, &report, opts);
        with_segmentation_term(report, measured)
    }

    /// The segmentation term's covariance for `report` from the live frames (see
    /// [`undecided_term`]).
    fn measure_segmentation_term(
        &self,
        live: &LiveFrames,
        renderer: &dyn Backend,
        report: &SolveReport,
        opts: &SolveOptions,
    ) -> Result<Option<Matrix6<f64>>> {
        if live.frames.len() != self.views.len() {
            return Err(Error::Solve(format!(
                "{} frames kept for {} views",
                live.frames.len(),
                self.views.len()
            )));
        }
        let drawn: Vec<SegmentedFrame> = live
            .frames
            .iter()
            .zip(&self.views)
            .enumerate()
            .map(|(i, (frame, view))| SegmentedFrame {
                frame,
                robot: view.robot.clone(),
                view: Some(i),
            })
            .collect();
        // The band the final masks were drawn with (`Session::resegment_final`).
        let band_px = if report.mean_iou() >= POOR_FIT_IOU {
            live.final_band_px.min(live.min_band_px)
        } else {
            live.min_band_px
        };
        undecided_term(
            renderer,
            &self.camera,
            self.unit.segmenter,
            &drawn,
            &self.views,
            report,
            band_px,
            opts,
        )
    }
}

/// Everything one calibration carries from round to round.
pub(super) struct Session<'a> {
    cell: &'a Cell,
    opts: &'a RunOptions,
    settings: CalibrationSettings,
    tracks: Vec<Track<'a>>,
    rec: Recorder,
    pb: indicatif::ProgressBar,
    renderer: Arc<dyn Backend>,
    solve_opts: SolveOptions,
    started: Instant,
    solve_s: f64,
    explore_s: f64,
    motion_s: f64,
    /// Seconds spent reading joints, grabbing and segmenting.
    capture_s: f64,
    /// Reported joints of every view.
    taken: Vec<Vec<f64>>,
    rounds: Vec<RoundRecord>,
    previous_best: Option<f64>,
    failures: usize,
    planned: Vec<PlannedPose>,
    /// Each view's joint correction from every camera together, once it ran.
    joint_corrections: Option<JointCorrections>,
}

impl<'a> Session<'a> {
    /// Checks the run's settings, opens the renderer and starts the run directory.
    pub(super) fn start(cell: &'a Cell, out: &Path, opts: &'a RunOptions) -> Result<Session<'a>> {
        // The total time counts setup too (the renderer, a GPU device included).
        let started = Instant::now();
        let settings = run_settings(cell, opts)?;
        let guess = initial_guess(cell, opts, &settings)?;
        check_only_cameras(cell, opts.only_cameras.as_deref())?;
        let tracks = cell
            .cameras()
            .into_iter()
            .enumerate()
            .filter(|(_, unit)| {
                opts.only_cameras
                    .as_ref()
                    .is_none_or(|names| names.iter().any(|n| n == unit.name))
            })
            .map(|(i, unit)| {
                let own = unit
                    .initial_guess
                    .map(|g| g.camera_from_base())
                    .transpose()
                    .map_err(|m| {
                        Error::input(
                            &cell.config_path,
                            format!("{}.initial_guess", cell.config.camera.key(i)),
                            m,
                        )
                    })?;
                let warm = opts.camera_guesses.get(unit.name).copied();
                track(unit, warm.or(own).or(guess))
            })
            .collect::<Result<Vec<_>>>()?;
        let recorded = tracks
            .iter()
            .map(|t| RecordedCamera {
                name: t.unit.name.to_string(),
                entry: CameraEntry {
                    mount: t.unit.config.mount().clone(),
                    ..CameraEntry::of(&t.camera)
                },
                guess: t.guess,
            })
            .collect();
        let layout = RunLayout::of_cameras(&cell.config.camera);
        let rec = Recorder::create(out, robot_entry(cell), recorded, layout)?;
        let pb = progress_bar(opts, settings.max_views);
        let renderer = open_renderer(settings.renderer, !opts.progress)
            .map_err(|m| Error::input(&cell.config_path, "calibration.renderer", m))?;
        let solve_opts = SolveOptions {
            joint_noise_rad: settings.joint_noise_rad,
            floor_rotation_deg: settings.model_floor_rotation_deg,
            floor_translation_mm: settings.model_floor_translation_mm,
            estimate_mask_offset: settings.estimate_mask_offset,
            mount_contact: settings.mount_contact,
            ..SolveOptions::default()
        };
        Ok(Session {
            cell,
            opts,
            settings,
            tracks,
            rec,
            pb,
            renderer,
            solve_opts,
            started,
            solve_s: 0.0,
            explore_s: 0.0,
            motion_s: 0.0,
            capture_s: 0.0,
            taken: Vec::new(),
            rounds: Vec::new(),
            previous_best: None,
            failures: 0,
            planned: Vec::new(),
            joint_corrections: None,
        })
    }

    /// The first camera's latest solve (the one a single-camera run reports).
    fn report(&self) -> &SolveReport {
        self.tracks[0].report()
    }

    /// Whether the loop serves several cameras: they then converge one by one, and planning
    /// asks that every camera sees the robot.
    fn several(&self) -> bool {
        self.tracks.len() > 1
    }

    fn views(&self) -> usize {
        self.taken.len()
    }

    fn last_round(&mut self) -> &mut RoundRecord {
        self.rounds.last_mut().expect("round 0 exists")
    }

    /// The view where the arm stands, and the first estimate of every camera from it (its
    /// guess, or an automatic initialisation); with no guess and a segmenter that needs
    /// context, the seeding views near the start and the estimate they settle (`seed`).
    pub(super) async fn first_view(&mut self) -> Result<()> {
        let events = if self.needs_seed_views() {
            self.seed_views().await?
        } else {
            let t = Instant::now();
            self.capture(true).await?;
            self.capture_s += t.elapsed().as_secs_f64();
            emit_view(self.opts, &self.taken);
            self.pb.set_position(1);
            Vec::new()
        };
        let t = Instant::now();
        let (r, opts) = (self.renderer.as_ref(), &self.solve_opts);
        // Seeding settles its camera's first estimate itself.
        let pending: Vec<usize> = (0..self.tracks.len())
            .filter(|&k| self.tracks[k].report.is_none())
            .collect();
        let reports: Vec<Result<SolveReport>> = pending
            .par_iter()
            .map(|&k| {
                let track = &self.tracks[k];
                match track.guess {
                    Some(g) => solve(r, &track.camera, &track.views, &g, opts),
                    None => initialise(
                        r,
                        &track.camera,
                        &track.views,
                        opts,
                        &InitOptions::default(),
                    ),
                }
            })
            .collect();
        for (k, report) in pending.into_iter().zip(reports) {
            self.tracks[k].report = Some(report?);
        }
        self.solve_s += t.elapsed().as_secs_f64();
        let report = self.report();
        self.rounds = vec![RoundRecord {
            round: 0,
            views: self.views(),
            camera_from_base: to_rows(&report.camera_from_base),
            mean_iou: report.mean_iou(),
            loss: report.loss,
            pose_change: None,
            best_variance: None,
            next_joints: None,
            events,
            cameras: self.camera_rounds(),
        }];
        self.rec.write_rounds(&self.rounds)?;
        emit_round(self.opts, &self.rounds, self.report());
        Ok(())
    }

    /// Each camera's figures for `rounds.json`, in a rig (empty for one camera, whose
    /// figures are the round's own).
    fn camera_rounds(&self) -> Vec<CameraRound> {
        if !self.several() {
            return Vec::new();
        }
        self.tracks
            .iter()
            .map(|t| {
                let r = t.report();
                CameraRound {
                    name: t.unit.name.to_string(),
                    camera_from_base: to_rows(&r.camera_from_base),
                    mean_iou: r.mean_iou(),
                    loss: r.loss,
                    pose_change: t.change,
                    camera_centre_95_mm: r.uncertainty.camera_centre_95_mm,
                    done: t.done.as_ref().map(ToString::to_string),
                }
            })
            .collect()
    }

    /// One round: plan, check the stop rules, move, capture and solve. `Some(reason)` ends
    /// the loop.
    pub(super) async fn round(&mut self) -> Result<Option<StopReason>> {
        let round = self.rounds.len() - 1;
        if self.opts.cancelled() {
            return Ok(Some(StopReason::Cancelled {
                views: self.views(),
            }));
        }
        let s = &self.settings;
        if self.views() >= s.max_views && !self.opts.dry_run {
            return Ok(Some(StopReason::MaxViews { max: s.max_views }));
        }
        if let Some(reason) = self.precise_enough() {
            return Ok(Some(reason));
        }
        if let Some(reason) = self.rig_converged() {
            return Ok(Some(reason));
        }
        let from = self.cell.arm.read_joints().await?;
        let (ranked, best) = self.plan(round, &from);
        if let Some(reason) = self.converged(best) {
            return Ok(Some(reason));
        }
        self.previous_best = best;
        if self.opts.dry_run {
            return Ok(Some(self.plan_dry_run(&ranked, &from)));
        }
        let mut events = Vec::new();
        let speed = self.settings.speed_rad_s;
        let chosen = choose_reachable(self.cell, &ranked, &from, speed, |_| false, &mut events);
        self.last_round().events.extend(events);
        let Some((pose, mv)) = chosen else {
            let views = self.views();
            return Ok(Some(if ranked.is_empty() {
                StopReason::NoPoseShowsRobot {
                    views,
                    several: self.several(),
                }
            } else {
                StopReason::NoReachablePose { views }
            }));
        };
        match self.move_to(&pose, &mv).await? {
            MoveOutcome::Arrived => {}
            MoveOutcome::Retry => return Ok(None),
            MoveOutcome::Stop(reason) => return Ok(Some(reason)),
        }
        self.capture_and_solve(round, best).await?;
        Ok(None)
    }

    /// Ranks the next poses from where the arm stands and records the planning step.
    fn plan(&mut self, round: usize, from: &[f64]) -> (Vec<Ranked>, Option<f64>) {
        let t = Instant::now();
        let request = PlanRequest {
            round,
            taken: &self.taken,
            motion: self.motion_cost(from),
        };
        let cameras: Vec<PlanCamera> = self
            .tracks
            .iter()
            .map(|t| PlanCamera {
                camera: &t.camera,
                mount: t.unit.config.mount(),
                seen: t.unit.seen,
                report: t.report(),
                wants_views: t.done.is_none(),
            })
            .collect();
        let (ranked, stats) = rank_poses(
            self.renderer.as_ref(),
            self.cell,
            &cameras,
            &self.settings,
            &request,
        );
        let best = ranked.first().and_then(|r| r.variance);
        self.explore_s += t.elapsed().as_secs_f64();
        self.opts.emit(Progress::Planned {
            round,
            best_variance: best,
        });
        let seen_by = if self.several() {
            "every camera"
        } else {
            "the robot"
        };
        let last = self.last_round();
        last.best_variance = best;
        last.events.push(format!(
            "{} joint samples: {} safe, {} show {seen_by}",
            stats.sampled, stats.safe, stats.scored
        ));
        (ranked, best)
    }

    /// The time model of the next move, when moves take time and the settings weigh it: the
    /// overhead is `view_overhead_s`, else this run's own capture, solve and planning time per
    /// view so far (setup and waiting for an operator left out).
    fn motion_cost(&self, from: &[f64]) -> Option<MotionCost> {
        let time_scale = motion_cost::time_scale(&self.cell.config);
        if !self.settings.weigh_motion_time || time_scale <= 0.0 {
            return None;
        }
        let measured =
            || (self.capture_s + self.solve_s + self.explore_s) / self.views().max(1) as f64;
        Some(MotionCost {
            from: from.to_vec(),
            speed_rad_s: self.settings.speed_rad_s,
            time_scale,
            overhead_s: self.settings.view_overhead_s.unwrap_or_else(measured),
        })
    }

    /// A dry run plans the whole sequence from the first view's estimate, chaining paths,
    /// and moves nothing.
    fn plan_dry_run(&mut self, ranked: &[Ranked], from: &[f64]) -> StopReason {
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
        StopReason::DryRun {
            planned: self.planned.len(),
        }
    }

    /// Captures the view at the new pose, solves every camera from its previous estimate
    /// and records the round.
    async fn capture_and_solve(&mut self, round: usize, best: Option<f64>) -> Result<()> {
        let t = Instant::now();
        let captured = self.capture(false).await;
        self.capture_s += t.elapsed().as_secs_f64();
        captured?;
        emit_view(self.opts, &self.taken);
        self.pb.set_position(self.views() as u64);
        let t = Instant::now();
        let previous: Vec<Isometry3<f64>> = self
            .tracks
            .iter()
            .map(|t| t.report().camera_from_base)
            .collect();
        let reports: Vec<Result<SolveReport>> = (0..self.tracks.len())
            .into_par_iter()
            .map(|k| self.solve_from(k, &previous[k]))
            .collect();
        for ((track, report), before) in self.tracks.iter_mut().zip(reports).zip(&previous) {
            let mut report = report?;
            report.trajectory.insert(0, *before);
            track.change = Some([
                rotation_error_deg(before, &report.camera_from_base),
                translation_error_mm(before, &report.camera_from_base),
            ]);
            track.report = Some(report);
        }
        self.solve_s += t.elapsed().as_secs_f64();
        self.mark_converged();
        let report = self.report();
        let change = self.tracks[0].change.expect("just solved");
        self.rounds.push(RoundRecord {
            round: round + 1,
            views: self.views(),
            camera_from_base: to_rows(&report.camera_from_base),
            mean_iou: report.mean_iou(),
            loss: report.loss,
            pose_change: Some(change),
            best_variance: None,
            next_joints: None,
            events: Vec::new(),
            cameras: self.camera_rounds(),
        });
        self.rec.write_rounds(&self.rounds)?;
        let report = self.report();
        emit_round(self.opts, &self.rounds, report);
        self.pb.set_message(format!(
            "round {} loss {:.5} IoU {:.4} best var {:.1} px change {:.3} deg / {:.2} mm",
            round + 1,
            report.loss,
            report.mean_iou(),
            best.unwrap_or(0.0),
            change[0],
            change[1]
        ));
        Ok(())
    }

    /// Solves camera `k`'s views from `previous`. When that fits poorly ([`REFIT_IOU`]) and
    /// the run has a starting pose of its own (a drawing, a tape measure, the last
    /// calibration), solves from that too and keeps the better fit: one ambiguous first view (a wrist camera that
    /// saw only a round base) can lead the estimate far from the start, and later views then
    /// fit nowhere near it.
    fn solve_from(&self, k: usize, previous: &Isometry3<f64>) -> Result<SolveReport> {
        let (r, t) = (self.renderer.as_ref(), &self.tracks[k]);
        let opts = self.opts_for(k);
        let report = solve(r, &t.camera, &t.views, previous, &opts)?;
        let refit_below = match t.unit.config.mount().is_fixed() {
            true => POOR_FIT_IOU,
            false => REFIT_IOU,
        };
        let Some(guess) = t.guess.filter(|_| report.mean_iou() < refit_below) else {
            return Ok(report);
        };
        let again = solve(r, &t.camera, &t.views, &guess, &opts)?;
        Ok(if again.mean_iou() > report.mean_iou() {
            again
        } else {
            report
        })
    }

    /// The solve options for camera `k`'s next solve: once one of its solves has left the
    /// mount contact out, the rest do too, as in offline segment-and-solve rounds (later
    /// masks, drawn round a settled render, hide part of what decided).
    fn opts_for(&self, k: usize) -> SolveOptions {
        match &self.tracks[k].report {
            Some(report) => kept_mount_decision(&self.solve_opts, report),
            None => self.solve_opts.clone(),
        }
    }

    /// Reads the joints and grabs a frame from every camera at the arm's present pose,
    /// segments them, records the view and adds it to each camera's views. With a
    /// context-aware segmenter (one camera only) the new frame is segmented together with
    /// every earlier one under the estimate, and earlier masks are re-segmented and
    /// rewritten when they change.
    async fn capture(&mut self, first: bool) -> Result<()> {
        let (joints, mut frames) = self.grab_all().await?;
        if self.tracks[0].live.is_some() {
            let frame = frames
                .pop()
                .expect("one camera with a context-aware segmenter");
            return self.capture_in_context(joints, frame, first);
        }
        let masks = self
            .tracks
            .iter()
            .zip(&frames)
            .collect::<Vec<_>>()
            .into_par_iter()
            .map(|(t, f)| t.unit.segmenter.segment(f))
            .collect::<Result<Vec<_>>>()?;
        let pairs: Vec<_> = frames.iter().zip(&masks).collect();
        self.rec.add_view(&joints, &pairs)?;
        self.taken.push(joints.clone());
        for (t, mask) in self.tracks.iter_mut().zip(&masks) {
            t.views.push(View {
                robot: PosedRobot::new(t.unit.seen, &joints),
                observed: t.camera.undistort_mask(mask),
            });
        }
        Ok(())
    }

    /// Reads the joints and grabs a frame from every camera, each checked against its
    /// intrinsics' size.
    async fn grab_all(&self) -> Result<(Vec<f64>, Vec<easyhec_drivers::Frame>)> {
        let joints = self.cell.arm.read_joints().await?;
        let mut frames = Vec::with_capacity(self.tracks.len());
        for t in &self.tracks {
            let frame = t.unit.device.grab().await?;
            let camera = &t.camera;
            if frame.width != camera.width || frame.height != camera.height {
                let which = if self.several() {
                    format!("camera '{}'", t.unit.name)
                } else {
                    "camera".into()
                };
                return Err(Error::Hardware(format!(
                    "{which} returned a {}x{} frame; its intrinsics say {}x{}",
                    frame.width, frame.height, camera.width, camera.height
                )));
            }
            frames.push(frame);
        }
        Ok((joints, frames))
    }

    /// [`Session::capture`] for a context-aware segmenter: every frame so far is segmented
    /// again with the new one, under the estimate (the guess before the first solve).
    fn capture_in_context(
        &mut self,
        joints: Vec<f64>,
        frame: easyhec_drivers::Frame,
        first: bool,
    ) -> Result<()> {
        let t = &mut self.tracks[0];
        let estimate = if first {
            t.guess
        } else {
            t.report.as_ref().map(|r| r.camera_from_base)
        };
        let live = t.live.as_mut().expect("checked by the caller");
        live.frames.push(frame);
        self.taken.push(joints.clone());
        let band = live.min_band_px;
        let rec = &self.rec;
        let masks = match live.resegment(
            self.renderer.as_ref(),
            t.unit.segmenter,
            t.unit.seen,
            &t.camera,
            band,
            &self.taken,
            estimate.as_ref(),
            t.report.as_ref(),
            &mut t.views,
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
        let mask = masks.last().expect("one mask per frame");
        self.rec.add_view(&joints, &[(last, mask)])?;
        Ok(())
    }

    /// The last views were segmented under the previous estimate: re-segment all of them
    /// under the final one and solve once more; when that estimate fits, with the final
    /// (narrowest) band: a narrow band is only safe around a right render.
    fn resegment_final(&mut self) -> Result<()> {
        let opts = self.opts_for(0);
        let t = &mut self.tracks[0];
        let Some(live) = &t.live else {
            return Ok(());
        };
        let started = Instant::now();
        let report = t.report.as_ref().expect("round 0 solved");
        let floor = if report.mean_iou() >= POOR_FIT_IOU {
            live.final_band_px.min(live.min_band_px)
        } else {
            live.min_band_px
        };
        let rec = &self.rec;
        live.resegment(
            self.renderer.as_ref(),
            t.unit.segmenter,
            t.unit.seen,
            &t.camera,
            floor,
            &self.taken,
            Some(&report.camera_from_base),
            Some(report),
            &mut t.views,
            |i, m| rec.replace_mask(i, m),
        )?;
        let report = solve(
            self.renderer.as_ref(),
            &t.camera,
            &t.views,
            &report.camera_from_base,
            &opts,
        )?;
        t.report = Some(report);
        self.solve_s += started.elapsed().as_secs_f64();
        self.record_final_solve(
            "re-segmented every view under the final estimate and re-solved".into(),
        );
        Ok(())
    }

    /// The last round records the solve that the end of the loop changed (a re-segmentation
    /// or the shared joint correction), so rounds.json ends on the result it reports.
    fn record_final_solve(&mut self, event: String) {
        let cameras = self.camera_rounds();
        let first = self.tracks[0].report();
        let (camera_from_base, mean_iou, loss) = (
            to_rows(&first.camera_from_base),
            first.mean_iou(),
            first.loss,
        );
        let last = self.last_round();
        last.camera_from_base = camera_from_base;
        last.mean_iou = mean_iou;
        last.loss = loss;
        last.cameras = cameras;
        last.events.push(event);
    }

    /// Several cameras saw every view: each view's joint correction is estimated from all of
    /// them together and every camera is re-solved with it (docs/cameras.md, "Shared joint
    /// correction"); one camera alone cannot tell a joint's error from its own pose error.
    fn correct_shared_joints(&mut self) {
        if self.tracks.len() < 2 || self.solve_opts.joint_noise_rad <= 0.0 {
            return;
        }
        let started = Instant::now();
        let cameras: Vec<CameraSolve> = self
            .tracks
            .iter()
            .map(|t| CameraSolve {
                name: t.unit.name,
                seen: t.unit.seen,
                camera: &t.camera,
                views: &t.views,
                report: t.report().clone(),
            })
            .collect();
        let shared = solve_with_shared_joints(
            self.renderer.as_ref(),
            cameras,
            &self.taken,
            &self.solve_opts,
        );
        let summary = shared.summary(&[]);
        let corrections = JointCorrections {
            views: (0..self.taken.len()).collect(),
            per_view_rad: shared.corrections,
        };
        self.joint_corrections = corrections.is_finite().then_some(corrections);
        for (t, r) in self.tracks.iter_mut().zip(shared.reports) {
            t.report = Some(r);
        }
        self.solve_s += started.elapsed().as_secs_f64();
        self.record_final_solve(summary);
    }

    /// Re-segments once more when that helps, then writes the result (not on a dry run):
    /// `easyhec-result/1` for a `[camera]` table, `easyhec-result/2` for `[[camera]]`
    /// tables.
    pub(super) fn finish(mut self, stop: StopReason) -> Result<Outcome> {
        self.pb.finish_and_clear();
        let stop_reason = stop.to_string();
        if !self.opts.dry_run && !stop.is_cancel() {
            self.resegment_final()?;
            self.correct_shared_joints();
            self.measure_view_disagreement();
            self.measure_segmentation_terms();
            // rounds.json ends on the figures result.json reports.
            let cameras = self.camera_rounds();
            self.last_round().cameras = cameras;
        }
        self.rec.write_rounds(&self.rounds)?;
        if !self.opts.dry_run && !stop.is_cancel() {
            for t in &self.tracks {
                let name = self.several().then_some(t.unit.name);
                judge_loop_fit(t.report(), name, self.rec.dir())?;
            }
        }
        let mut timings_s = std::collections::BTreeMap::new();
        let timings = [
            ("total", self.started.elapsed().as_secs_f64()),
            ("solve", self.solve_s),
            ("explore", self.explore_s),
            ("motion", self.motion_s),
            ("capture", self.capture_s),
        ];
        for (k, v) in timings {
            timings_s.insert(k.to_string(), v);
        }
        let cameras: Vec<CameraOutcome> = self
            .tracks
            .iter_mut()
            .map(|t| {
                let report = t.report.take().expect("round 0 solved");
                let reason = t
                    .done
                    .as_ref()
                    .map_or_else(|| stop_reason.clone(), ToString::to_string);
                let result =
                    camera_result(&report, t.unit.seen, reason, &timings_s, &self.solve_opts);
                CameraOutcome {
                    name: t.unit.name.to_string(),
                    result,
                    report,
                }
            })
            .collect();
        let mut result = cameras[0].result.clone();
        result.stop_reason = stop_reason.clone();
        let layout = RunLayout::of_cameras(&self.cell.config.camera);
        if !self.opts.dry_run {
            let path = self.rec.dir().join("result.json");
            let results: Vec<(&str, &ResultFile)> = cameras
                .iter()
                .map(|c| (c.name.as_str(), &c.result))
                .collect();
            let summary = RunSummary {
                stop_reason,
                timings_s,
                joint_corrections: self.joint_corrections.take(),
            };
            write_result(layout, &path, &results, summary)?;
        }
        Ok(Outcome {
            result,
            report: cameras[0].report.clone(),
            cameras,
            rounds: self.rounds,
            planned: self.planned,
            run_dir: self.rec.dir().to_path_buf(),
            layout,
            cancelled: stop.is_cancel(),
            faulted: stop.is_fault(),
        })
    }
}

//! The closed loop (method.md §5): capture, solve, choose the next arm pose where the camera
//! hypotheses that still fit disagree most, check it is safe, move, capture, solve again, and
//! stop when more views stop helping. Everything is recorded into a run directory as it
//! happens (`easyhec-run/1` plus `rounds.json`), so a crash loses nothing and `easyhec solve`
//! can re-solve it offline.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Instant, SystemTime, UNIX_EPOCH};

use easyhec_drivers::{ArmStatus, Frame};
use nalgebra::{Isometry3, Matrix6};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::camera::Camera;
use crate::cell::Cell;
use crate::config::{CalibrationSettings, ScoreSetting, SelectionSetting, SourceSetting};

use crate::backend::{open_renderer, Backend};
use crate::error::{Error, Result};
use crate::explore::{
    camera_candidates, cost_reduction, view_terms, CandidateSource, ExploreOptions, ViewTerms,
};
use crate::geometry::{rotation_error_deg, to_rows, translation_error_mm};
use crate::init::{initialise, InitOptions};
use crate::io::{write_atomic, write_json_atomic};
use crate::mask::Mask;
use crate::render::{CoarseRobot, PosedRobot, SilhouetteRenderer};
use crate::run::{
    CameraEntry, PerView, PoseEntry, ResultFile, RobotEntry, RunFile, UncertaintyEntry, ViewEntry,
    RUN_FORMAT,
};
use crate::safety::{CheckedMove, Clearance};
use crate::solve::{solve, SolveOptions, SolveReport, View};

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
    /// A benchmark protocol, not a product setting: the frame where the arm stands is still
    /// captured, recorded and solved for the first estimate, but every later solve, the
    /// planner's record of views taken and the view count use only the views the selection
    /// chose (so `max_views` of them are all chosen): round 0 counts 0 views and the result's
    /// `views_used` / `per_view` leave view 0 out. Measures what choosing every view gains.
    pub start_view_initialises_only: bool,
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

/// Writes the run directory incrementally.
pub struct Recorder {
    dir: PathBuf,
    run: RunFile,
}

/// RFC 3339 UTC time of `t` (seconds precision).
pub fn rfc3339(t: SystemTime) -> String {
    let secs = t
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0) as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Civil date from days since 1970-01-01 (Howard Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

impl Recorder {
    /// Starts a run directory (refuses one that already holds a run).
    pub fn create(
        dir: &Path,
        robot: RobotEntry,
        camera: CameraEntry,
        guess: Option<Isometry3<f64>>,
    ) -> Result<Recorder> {
        if dir.join("run.json").exists() {
            return Err(Error::input(
                dir,
                "--out",
                "already holds a run.json: choose a new folder (nothing recorded is overwritten)",
            ));
        }
        std::fs::create_dir_all(dir.join("views"))
            .map_err(|e| Error::io(dir, format!("cannot create the run folder: {e}")))?;
        Ok(Recorder {
            dir: dir.to_path_buf(),
            run: RunFile {
                format: RUN_FORMAT.into(),
                robot,
                camera,
                initial_guess: guess.map(|g| PoseEntry {
                    camera_from_base: to_rows(&g),
                }),
                views: Vec::new(),
            },
        })
    }

    /// The run folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Writes a view's frame and mask, then `run.json`; returns its index.
    pub fn add_view(&mut self, joints: &[f64], frame: &Frame, mask: &Mask) -> Result<usize> {
        let i = self.run.views.len();
        let image_rel = format!("views/{i:03}.png");
        let mask_rel = format!("views/{i:03}.mask.png");
        let img = image::RgbImage::from_raw(frame.width, frame.height, frame.rgb.clone())
            .ok_or_else(|| {
                Error::Hardware(format!(
                    "camera frame has {} bytes for {}x{} RGB",
                    frame.rgb.len(),
                    frame.width,
                    frame.height
                ))
            })?;
        let mut png = std::io::Cursor::new(Vec::new());
        img.write_to(&mut png, image::ImageFormat::Png)
            .map_err(|e| Error::io(self.dir.join(&image_rel), e))?;
        write_atomic(&self.dir.join(&image_rel), png.get_ref())?;
        write_atomic(&self.dir.join(&mask_rel), &mask.to_png_bytes())?;
        self.run.views.push(ViewEntry {
            joints: joints.to_vec(),
            mask: Some(mask_rel),
            image: Some(image_rel),
            captured_at: Some(rfc3339(frame.captured_at)),
        });
        write_json_atomic(&self.dir.join("run.json"), &self.run)?;
        Ok(i)
    }

    /// Replaces view `i`'s mask (a context-aware segmenter re-segmented it with more views
    /// or a better estimate): written atomically, the frame and `run.json` untouched.
    pub fn replace_mask(&self, i: usize, mask: &Mask) -> Result<()> {
        let Some(rel) = self.run.views.get(i).and_then(|v| v.mask.as_ref()) else {
            return Err(Error::Solve(format!(
                "re-segmented view {i}, which the run does not hold"
            )));
        };
        write_atomic(&self.dir.join(rel), &mask.to_png_bytes())
    }

    /// Writes `rounds.json`.
    pub fn write_rounds(&self, rounds: &[RoundRecord]) -> Result<()> {
        #[derive(Serialize)]
        struct Rounds<'a> {
            format: &'static str,
            rounds: &'a [RoundRecord],
        }
        write_json_atomic(
            &self.dir.join("rounds.json"),
            &Rounds {
                format: "easyhec-rounds/1",
                rounds,
            },
        )
    }
}

fn absolute(p: &Path) -> String {
    std::fs::canonicalize(p)
        .unwrap_or_else(|_| p.to_path_buf())
        .display()
        .to_string()
}

/// Fraction of the robot's (decimated) surface points that land inside the image.
pub fn in_image_fraction(
    robot: &PosedRobot,
    camera: &Camera,
    camera_from_base: &Isometry3<f64>,
) -> f64 {
    if robot.vertices_base.is_empty() {
        return 0.0;
    }
    let (w, h) = (f64::from(camera.width), f64::from(camera.height));
    let inside = robot
        .vertices_base
        .iter()
        .filter(|p| {
            let c = camera_from_base * **p;
            if c.z <= 0.05 {
                return false;
            }
            let x = camera.project(&c);
            x[0] >= 0.0 && x[1] >= 0.0 && x[0] <= w - 1.0 && x[1] <= h - 1.0
        })
        .count();
    inside as f64 / robot.vertices_base.len() as f64
}

/// A scored joint sample that passed the static checks.
#[derive(Clone, Debug)]
pub struct Ranked {
    /// Joints.
    pub joints: Vec<f64>,
    /// Ranking score (higher is better; see [`ScoreSetting`]).
    pub score: f64,
    /// Variance of the camera candidates' masks at this pose (computed for the best only,
    /// unless the variance ranked them all).
    pub variance: Option<f64>,
    /// In-image fraction under the estimate.
    pub in_image: f64,
}

/// Statistics of one planning pass.
#[derive(Clone, Copy, Debug, Default)]
pub struct PlanStats {
    /// Joint samples drawn.
    pub sampled: usize,
    /// Samples that passed limits/collision/workspace.
    pub safe: usize,
    /// …and the in-image rule (scored).
    pub scored: usize,
}

/// Draws joint samples, keeps the statically safe ones that show the robot, and scores them
/// by the candidates' disagreement, best first.
pub fn rank_poses(
    renderer: &dyn Backend,
    cell: &Cell,
    camera: &Camera,
    report: &SolveReport,
    taken: &[Vec<f64>],
    settings: &CalibrationSettings,
    round: usize,
) -> (Vec<Ranked>, PlanStats) {
    let checker = &cell.checker;
    let mut rng =
        rand_chacha::ChaCha8Rng::seed_from_u64(settings.seed.wrapping_mul(1000) + round as u64);
    let samples: Vec<Vec<f64>> = (0..settings.joint_samples)
        .map(|_| {
            checker
                .limits()
                .iter()
                .map(|&(lo, hi)| rng.random_range(lo..=hi))
                .collect()
        })
        .collect();
    let pinhole = camera.undistorted();
    let low = pinhole.downsampled(settings.score_downsample);
    // Vertex clustering at one scoring pixel (at 1 m): coarse masks need no finer mesh.
    let cell_m = f64::from(settings.score_downsample) / pinhole.fx.max(pinhole.fy);
    // The variance of binary masks only measures disagreement once the hypotheses' outlines
    // differ by whole scoring pixels; a converged posterior moves them by a fraction of one,
    // which leaves the score as quantisation noise. In the linear regime the ranking of views
    // does not depend on the covariance's scale, so the samples come from the posterior
    // inflated until its typical outline displacement is about two scoring pixels.
    let mut widened = report.clone();
    let u = &report.uncertainty;
    let rot_rad = u
        .rotation_deg
        .iter()
        .map(|v| v * v)
        .sum::<f64>()
        .sqrt()
        .to_radians();
    let trans_m = u.translation_mm.iter().map(|v| v * v).sum::<f64>().sqrt() * 1e-3;
    let depth = report.camera_from_base.translation.vector.norm().max(0.1);
    let typical_px = pinhole.fx * (rot_rad + trans_m / depth);
    let wanted_px = 2.0 * f64::from(settings.score_downsample);
    if typical_px.is_finite() && typical_px > 0.0 && typical_px < wanted_px {
        let k = wanted_px / typical_px;
        widened.covariance *= k * k;
    }
    let candidates = camera_candidates(
        &widened,
        &ExploreOptions {
            candidates: settings.candidates,
            source: match settings.candidate_source {
                SourceSetting::Posterior => CandidateSource::Posterior,
                SourceSetting::Trajectory => CandidateSource::Trajectory,
            },
            seed: settings.seed.wrapping_mul(7919) + round as u64,
            ..ExploreOptions::default()
        },
    );
    let estimate = report.camera_from_base;
    let t_start = std::time::Instant::now();
    // The variance score only needs coarse masks: one decimation per robot (link frames),
    // posed per sample. The information score reads outline samples, which follow the
    // posed surface more faithfully when each pose is clustered in the base frame.
    let coarse = CoarseRobot::new(&cell.robot, cell_m);
    let per_pose = settings.score == ScoreSetting::Information;
    let pose_coarse = |q: &[f64]| {
        if per_pose {
            PosedRobot::new(&cell.robot, q).decimated(cell_m)
        } else {
            coarse.pose(&cell.robot, q)
        }
    };
    let safe: Vec<(Vec<f64>, PosedRobot)> = samples
        .into_par_iter()
        .filter(|q| checker.check_pose(q).is_ok())
        .map(|q| {
            let posed = pose_coarse(&q);
            (q, posed)
        })
        .collect();
    let n_safe = safe.len();
    if std::env::var_os("EASYHEC_DEBUG").is_some() {
        eprintln!(
            "rank_poses: static checks {:.2} s",
            t_start.elapsed().as_secs_f64()
        );
    }
    let t_checked = std::time::Instant::now();
    let in_view: Vec<(f64, Vec<f64>, PosedRobot)> = safe
        .into_par_iter()
        .filter_map(|(q, posed)| {
            let in_image = in_image_fraction(&posed, &pinhole, &estimate);
            (in_image >= checker.min_in_image).then_some((in_image, q, posed))
        })
        .collect();
    let n_scored = in_view.len();
    // Batched through the renderer: a GPU backend scores the whole pool per submission.
    let variances = |pool: &[&PosedRobot], cands: &[Isometry3<f64>]| {
        renderer.disagreement_many(&low, pool, cands)
    };
    let mut ranked: Vec<(Ranked, PosedRobot)> = match (settings.selection, settings.score) {
        (SelectionSetting::Random, _) => in_view
            .into_iter()
            .map(|(in_image, q, posed)| {
                // Random order: a hash of the joints, so the choice is seeded and repeatable.
                let mut h = rand_chacha::ChaCha8Rng::seed_from_u64(
                    q.iter()
                        .fold(settings.seed, |a, v| a.rotate_left(7) ^ v.to_bits()),
                );
                let r = Ranked {
                    score: h.random::<f64>(),
                    variance: None,
                    joints: q,
                    in_image,
                };
                (r, posed)
            })
            .collect(),
        (SelectionSetting::Explore, ScoreSetting::Information) => {
            let terms = |posed: &PosedRobot, q: &[f64]| {
                view_terms(
                    &low,
                    pinhole.fx,
                    posed,
                    &cell.robot.joint_motions(q),
                    &estimate,
                    report.outline_noise_px2,
                    settings.joint_noise_rad,
                )
            };
            // What the views taken so far contribute, on the same footing as the candidates
            // (a tiny ridge keeps a one-view outline matrix invertible).
            let mut current: ViewTerms = taken
                .par_iter()
                .map(|q| terms(&pose_coarse(q), q))
                .reduce(ViewTerms::zeros, |a, b| a + b);
            current.outline_information += Matrix6::identity() * 1e-6;
            let score = |posed: &PosedRobot, q: &[f64]| {
                cost_reduction(&current, &terms(posed, q), &estimate)
            };
            let mut scored: Vec<(Ranked, PosedRobot)> = in_view
                .into_par_iter()
                .map(|(in_image, q, posed)| {
                    let r = Ranked {
                        score: score(&posed, &q),
                        variance: None,
                        joints: q,
                        in_image,
                    };
                    (r, posed)
                })
                .collect();
            // 2000 random samples leave the best view's information well short of what a
            // few steps of local search from the best of them reach (README: exploration).
            if settings.climb_steps > 0 {
                scored.sort_by(|a, b| b.0.score.total_cmp(&a.0.score));
                let starts: Vec<Ranked> = scored
                    .iter()
                    .take(CLIMB_STARTS)
                    .map(|r| r.0.clone())
                    .collect();
                let climbed: Vec<(Ranked, PosedRobot)> = starts
                    .into_par_iter()
                    .enumerate()
                    .filter_map(|(i, start)| {
                        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(
                            settings.seed.wrapping_mul(31337) + (round * 64 + i) as u64,
                        );
                        climb(
                            start,
                            settings.climb_steps,
                            checker.limits(),
                            &mut rng,
                            |q| {
                                if checker.check_pose(q).is_err() {
                                    return None;
                                }
                                let posed = pose_coarse(q);
                                let in_image = in_image_fraction(&posed, &pinhole, &estimate);
                                (in_image >= checker.min_in_image)
                                    .then(|| (score(&posed, q), in_image, posed))
                            },
                        )
                    })
                    .collect();
                scored.extend(climbed);
            }
            scored
        }
        (SelectionSetting::Explore, ScoreSetting::Variance) => {
            // Two passes: every sample against the first fifth of the candidates, then the
            // best quarter against all of them (the argmax is almost always in that quarter;
            // this halves the planning time).
            let quick = &candidates[..(candidates.len() / 5).max(2).min(candidates.len())];
            let pool: Vec<&PosedRobot> = in_view.iter().map(|(_, _, p)| p).collect();
            let quick_scores = variances(&pool, quick);
            let mut first: Vec<(f64, f64, Vec<f64>, PosedRobot)> = in_view
                .into_iter()
                .zip(quick_scores)
                .map(|((in_image, q, posed), v)| (v, in_image, q, posed))
                .collect();
            first.sort_by(|a, b| b.0.total_cmp(&a.0));
            first.truncate((n_scored / 4).max(64.min(n_scored)));
            let pool: Vec<&PosedRobot> = first.iter().map(|(_, _, _, p)| p).collect();
            let full = variances(&pool, &candidates);
            first
                .into_iter()
                .zip(full)
                .map(|((_, in_image, q, posed), v)| {
                    let r = Ranked {
                        score: v,
                        variance: Some(v),
                        joints: q,
                        in_image,
                    };
                    (r, posed)
                })
                .collect()
        }
    };
    ranked.sort_by(|a, b| b.0.score.total_cmp(&a.0.score));
    // The stop rule watches the candidates' disagreement at the best pose, whatever ranked it.
    if let Some((best, posed)) = ranked.first_mut() {
        if best.variance.is_none() {
            best.variance = variances(&[&*posed], &candidates).first().copied();
        }
    }
    let ranked: Vec<Ranked> = ranked.into_iter().map(|r| r.0).collect();
    if std::env::var_os("EASYHEC_DEBUG").is_some() {
        eprintln!(
            "rank_poses: scoring {:.2} s, {} scored, {} triangles per coarse robot",
            t_checked.elapsed().as_secs_f64(),
            ranked.len(),
            PosedRobot::new(
                &cell.robot,
                &ranked.first().map(|r| r.joints.clone()).unwrap_or_default()
            )
            .decimated(cell_m)
            .topology
            .triangles
            .len()
        );
    }
    let stats = PlanStats {
        sampled: settings.joint_samples,
        safe: n_safe,
        scored: n_scored,
    };
    (ranked, stats)
}

/// Best-scored samples each hill climb starts from.
const CLIMB_STARTS: usize = 8;

/// How far inside its joint limits a climbed target stays, radians.
const LIMIT_MARGIN_RAD: f64 = 0.02;

/// Stochastic hill climb in joint space from `start`: Gaussian steps of every joint
/// (0.3 rad, shrunk by 15% per failed step), a step kept when `evaluate` passes the pose
/// (static safety checks, robot in view) and it scores higher. `None` when no step improved
/// on `start`. The climbed pose still goes through the path check before any move.
fn climb(
    start: Ranked,
    steps: usize,
    limits: &[(f64, f64)],
    rng: &mut rand_chacha::ChaCha8Rng,
    evaluate: impl Fn(&[f64]) -> Option<(f64, f64, PosedRobot)>,
) -> Option<(Ranked, PosedRobot)> {
    let mut best = start;
    let mut best_posed = None;
    let mut sigma = 0.3;
    for _ in 0..steps {
        let q: Vec<f64> = best
            .joints
            .iter()
            .zip(limits)
            .map(|(&v, &(lo, hi))| {
                let z: f64 = StandardNormal.sample(rng);
                // A target on a limit would leave the next read, encoder noise and all,
                // outside it, and no path could start there.
                let m = LIMIT_MARGIN_RAD.min(0.25 * (hi - lo));
                (v + sigma * z).clamp(lo + m, hi - m)
            })
            .collect();
        match evaluate(&q) {
            Some((score, in_image, posed)) if score > best.score => {
                best = Ranked {
                    joints: q,
                    score,
                    variance: None,
                    in_image,
                };
                best_posed = Some(posed);
            }
            _ => sigma = (sigma * 0.85).max(0.02),
        }
    }
    best_posed.map(|p| (best, p))
}

/// Picks the best-ranked pose whose path from `from` passes the full move check.
pub fn choose_reachable(
    cell: &Cell,
    ranked: &[Ranked],
    from: &[f64],
    speed_rad_s: f64,
    skip: impl Fn(&[f64]) -> bool,
    events: &mut Vec<String>,
) -> Option<(PlannedPose, CheckedMove)> {
    let mut rejected = 0;
    for r in ranked.iter().filter(|r| !skip(&r.joints)).take(64) {
        match cell.checker.check_move(from, &r.joints, speed_rad_s) {
            Ok(mv) => {
                if rejected > 0 {
                    events.push(format!("{rejected} better-scored poses had unsafe paths"));
                }
                return Some((
                    PlannedPose {
                        joints: r.joints.clone(),
                        score: r.score,
                        variance: r.variance,
                        in_image: r.in_image,
                        clearance: mv.clearance,
                        path_samples: mv.samples,
                    },
                    mv,
                ));
            }
            Err(_) => rejected += 1,
        }
    }
    events.push(format!("{rejected} candidate paths rejected"));
    None
}

/// Prior band (pixels) around the silhouette under the initial guess: a guess several
/// degrees and centimetres off moves the outline by tens of pixels.
const GUESS_BAND_PX: f32 = 80.0;

/// What a context-aware segmenter keeps between captures.
struct Context<'a> {
    renderer: &'a dyn SilhouetteRenderer,
    frames: Vec<Frame>,
    /// The narrowest band while views are still being added (`[segmenter] min_band_px`).
    min_band_px: f32,
    /// The narrowest band of the last re-segmentation (`[segmenter] final_band_px`).
    final_band_px: f32,
    /// `RunOptions::start_view_initialises_only`: reports after the first leave out the
    /// frames before this index.
    first_used: usize,
}

impl Context<'_> {
    /// Segments every frame so far with priors under `estimate` (bands from `report` when
    /// there is one, at least `band_floor_px`), rewrites the earlier views' masks that
    /// changed, and rebuilds `views`.
    #[allow(clippy::too_many_arguments)]
    fn resegment(
        &self,
        band_floor_px: f32,
        cell: &Cell,
        camera: &Camera,
        rec: &Recorder,
        taken: &[Vec<f64>],
        estimate: Option<&Isometry3<f64>>,
        report: Option<&SolveReport>,
        views: &mut Vec<View>,
    ) -> Result<Vec<Mask>> {
        let robots: Vec<PosedRobot> = taken
            .iter()
            .map(|q| PosedRobot::new(&cell.robot, q))
            .collect();
        let priors = estimate
            .map(|pose| crate::segment::refine::priors(self.renderer, camera, &robots, pose));
        let bands = match (report, &priors) {
            (Some(r), Some(p)) => {
                // A report after the first may have left out the frames before `first_used`
                // (it has not seen the newest frame either).
                let first_view = if self.first_used > 0 {
                    views.len().saturating_sub(r.per_view_iou.len())
                } else {
                    0
                };
                crate::segment::refine::bands_px(camera, r, p, first_view, band_floor_px)
            }
            _ => vec![GUESS_BAND_PX; robots.len()],
        };
        let masks = crate::segment::refine::segment_frames(
            cell.segmenter.as_ref(),
            &self.frames,
            priors.as_deref(),
            &bands,
        )?;
        for (i, m) in masks.iter().enumerate().take(views.len()) {
            let observed = camera.undistort_mask(m);
            if observed != views[i].observed {
                rec.replace_mask(i, m)?;
                views[i].observed = observed;
            }
        }
        views.truncate(masks.len());
        for (m, r) in masks.iter().zip(robots).skip(views.len()) {
            views.push(View {
                robot: r,
                observed: camera.undistort_mask(m),
            });
        }
        Ok(masks)
    }
}

/// Reads the joints and grabs a frame at the arm's present pose, segments it, records the
/// view and adds it to `views`. With a context-aware segmenter (`ctx`) the new frame is
/// segmented together with every earlier one (background plate) under `estimate`, and
/// earlier masks are re-segmented and rewritten when they change.
#[allow(clippy::too_many_arguments)]
async fn capture(
    cell: &Cell,
    camera: &Camera,
    rec: &mut Recorder,
    taken: &mut Vec<Vec<f64>>,
    ctx: Option<&mut Context<'_>>,
    views: &mut Vec<View>,
    estimate: Option<&Isometry3<f64>>,
    report: Option<&SolveReport>,
) -> Result<()> {
    let joints = cell.arm.read_joints().await?;
    let frame = cell.camera.grab().await?;
    if frame.width != camera.width || frame.height != camera.height {
        return Err(Error::Hardware(format!(
            "camera returned a {}x{} frame; its intrinsics say {}x{}",
            frame.width, frame.height, camera.width, camera.height
        )));
    }
    let Some(ctx) = ctx else {
        let mask = cell.segmenter.segment(&frame)?;
        rec.add_view(&joints, &frame, &mask)?;
        taken.push(joints.clone());
        views.push(View {
            robot: PosedRobot::new(&cell.robot, &joints),
            observed: camera.undistort_mask(&mask),
        });
        return Ok(());
    };
    ctx.frames.push(frame);
    taken.push(joints.clone());
    let masks = match ctx.resegment(
        ctx.min_band_px,
        cell,
        camera,
        rec,
        taken,
        estimate,
        report,
        views,
    ) {
        Ok(m) => m,
        Err(e) => {
            ctx.frames.pop();
            taken.pop();
            return Err(e);
        }
    };
    let last = ctx.frames.last().expect("just pushed");
    rec.add_view(&joints, last, masks.last().expect("one mask per frame"))?;
    Ok(())
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

/// Runs the loop on `cell`, recording into `out`.
pub async fn calibrate(cell: &Cell, out: &Path, opts: &RunOptions) -> Result<Outcome> {
    let started = Instant::now();
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
    let s = &settings;
    let camera = Camera::from_intrinsics(cell.camera.intrinsics());
    let speed = s.speed_rad_s;
    let cap = cell.checker.speed_cap_rad_s();
    if speed > cap {
        return Err(Error::input(
            &cell.config_path,
            "calibration.speed_rad_s",
            format!("{speed} rad/s is above the safety cap of {cap} rad/s (safety.speed_cap_rad_s and the joints' velocity limits)"),
        ));
    }
    let src = &cell.robot.source;
    let robot_entry = RobotEntry {
        urdf: absolute(&src.urdf),
        package_dirs: src
            .package_dirs
            .iter()
            .map(|(k, v)| (k.clone(), absolute(v)))
            .collect(),
        base_link: Some(cell.robot.links[cell.robot.base].clone()),
        ignore_links: src.ignore_links.clone(),
        joints: cell
            .robot
            .joint_names()
            .iter()
            .map(|s| s.to_string())
            .collect(),
    };
    let camera_entry = CameraEntry::of(&camera);
    let guess = match (&opts.initial_guess, &s.initial_guess) {
        (Some(g), _) => Some(*g),
        (None, Some(g)) => Some(
            g.camera_from_base()
                .map_err(|m| Error::input(&cell.config_path, "calibration.initial_guess", m))?,
        ),
        (None, None) => None,
    };
    let mut rec = Recorder::create(out, robot_entry, camera_entry, guess)?;
    let pb = progress_bar(opts, s.max_views);
    let renderer = open_renderer(s.renderer, !opts.progress)
        .map_err(|m| Error::input(&cell.config_path, "calibration.renderer", m))?;
    let solve_opts = SolveOptions::default();
    let (mut solve_s, mut explore_s, mut motion_s) = (0.0, 0.0, 0.0);

    // Views before this index are left out of every solve after the first and of the view
    // count (`RunOptions::start_view_initialises_only`).
    let first_used = usize::from(opts.start_view_initialises_only);
    let mut taken = Vec::new();
    let mut ctx = cell.segmenter.uses_context().then(|| Context {
        renderer: renderer.as_ref(),
        first_used,
        frames: Vec::new(),
        min_band_px: cell.config.segmenter.min_band_px(),
        final_band_px: cell.config.segmenter.final_band_px(),
    });
    let mut views = Vec::new();
    capture(
        cell,
        &camera,
        &mut rec,
        &mut taken,
        ctx.as_mut(),
        &mut views,
        guess.as_ref(),
        None,
    )
    .await?;
    emit_view(opts, &taken);
    pb.set_position((1 - first_used) as u64);
    let t = Instant::now();
    let mut report = match guess {
        Some(g) => solve(renderer.as_ref(), &camera, &views, &g, &solve_opts)?,
        None => initialise(
            renderer.as_ref(),
            &camera,
            &views,
            &solve_opts,
            &InitOptions::default(),
        )?,
    };
    solve_s += t.elapsed().as_secs_f64();
    let mut rounds = vec![RoundRecord {
        round: 0,
        views: 1 - first_used,
        camera_from_base: to_rows(&report.camera_from_base),
        mean_iou: report.mean_iou(),
        loss: report.loss,
        pose_change: None,
        best_variance: None,
        next_joints: None,
        events: Vec::new(),
    }];
    rec.write_rounds(&rounds)?;
    emit_round(opts, &rounds, &report);
    let safe_arm = &cell.arm;
    let mut previous_best: Option<f64> = None;
    let mut failures = 0;
    let mut planned = Vec::new();
    let stop_reason;
    let mut cancelled = false;
    loop {
        let round = rounds.len() - 1;
        if opts.cancelled() {
            cancelled = true;
            stop_reason = format!("cancelled after {} views", views.len() - first_used);
            break;
        }
        if views.len() - first_used >= s.max_views && !opts.dry_run {
            stop_reason = format!("reached the maximum of {} views", s.max_views);
            break;
        }
        let t = Instant::now();
        let (ranked, stats) = rank_poses(
            renderer.as_ref(),
            cell,
            &camera,
            &report,
            &taken[first_used..],
            s,
            round,
        );
        let best = ranked.first().and_then(|r| r.variance);
        explore_s += t.elapsed().as_secs_f64();
        opts.emit(Progress::Planned {
            round,
            best_variance: best,
        });
        let last = rounds.last_mut().expect("round 0 exists");
        last.best_variance = best;
        last.events.push(format!(
            "{} joint samples: {} safe, {} show the robot",
            stats.sampled, stats.safe, stats.scored
        ));
        if let (Some(prev), Some(best), Some([deg, mm])) = (previous_best, best, last.pose_change) {
            let settled = (prev - best).abs() <= s.variance_rel_tol * prev.max(1e-12);
            if settled
                && views.len() - first_used >= s.min_views
                && deg < s.pose_tol_deg
                && mm < s.pose_tol_mm
            {
                stop_reason = format!(
                    "variance converged after {} views",
                    views.len() - first_used
                );
                break;
            }
        }
        previous_best = best;
        let from = cell.arm.read_joints().await?;
        if opts.dry_run {
            // Plan the whole sequence from the first view's estimate, chaining paths.
            let mut at = from.clone();
            let mut events = Vec::new();
            for _ in (1 - first_used)..s.max_views {
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
                match choose_reachable(cell, &ranked, &at, speed, far, &mut events) {
                    Some((p, _)) => {
                        at = p.joints.clone();
                        planned.push(p);
                    }
                    None => break,
                }
            }
            rounds.last_mut().expect("round").events.extend(events);
            stop_reason = format!("dry run: planned {} poses, nothing moved", planned.len());
            break;
        }
        let mut events = Vec::new();
        let Some((pose, mv)) =
            choose_reachable(cell, &ranked, &from, speed, |_| false, &mut events)
        else {
            rounds.last_mut().expect("round").events.extend(events);
            stop_reason = format!(
                "no safe, reachable pose left after {} views",
                views.len() - first_used
            );
            break;
        };
        rounds.last_mut().expect("round").events.extend(events);
        if let Some(confirm) = &opts.confirm {
            let ok = pb.suspend(|| confirm(&pose));
            if !ok {
                stop_reason = format!(
                    "operator declined a move after {} views",
                    views.len() - first_used
                );
                break;
            }
        }
        if opts.cancelled() {
            cancelled = true;
            stop_reason = format!("cancelled after {} views", views.len() - first_used);
            break;
        }
        rounds.last_mut().expect("round").next_joints = Some(pose.joints.clone());
        pb.set_message(format!("moving to view {}", views.len() - first_used + 1));
        opts.emit(Progress::Moving {
            view: views.len(),
            joints: pose.joints.clone(),
        });
        let t = Instant::now();
        let moved = match safe_arm.execute(&mv).await {
            Ok(motion) => {
                tokio::select! {
                    r = motion.wait() => r.map_err(Error::from),
                    () = opts.wait_cancelled() => {
                        // Stop first; the motion future is dropped, the arm halts where it is.
                        let _ = cell.arm.stop().await;
                        Err(Error::Hardware("move stopped: calibration cancelled".into()))
                    }
                }
            }
            Err(e) => Err(e),
        };
        motion_s += t.elapsed().as_secs_f64();
        if opts.cancelled() {
            if moved.is_err() {
                let _ = cell.arm.stop().await;
                rounds
                    .last_mut()
                    .expect("round")
                    .events
                    .push("move stopped: calibration cancelled".into());
            }
            cancelled = true;
            stop_reason = format!("cancelled after {} views", views.len() - first_used);
            break;
        }
        if let Err(e) = moved {
            failures += 1;
            let note = format!("move failed: {e}");
            rounds.last_mut().expect("round").events.push(note.clone());
            rec.write_rounds(&rounds)?;
            let _ = cell.arm.stop().await;
            let status = cell.arm.status().await?;
            let faulted = matches!(status, ArmStatus::Fault(_) | ArmStatus::Stopped);
            if failures > s.max_motion_failures {
                stop_reason = format!("gave up after {failures} failed moves ({note})");
                break;
            }
            if faulted {
                if !s.clear_faults {
                    stop_reason =
                        format!("arm fault, not cleared (calibration.clear_faults = false): {e}");
                    break;
                }
                cell.arm.clear_fault().await?;
            }
            // Re-plan from wherever the arm stopped.
            continue;
        }
        capture(
            cell,
            &camera,
            &mut rec,
            &mut taken,
            ctx.as_mut(),
            &mut views,
            Some(&report.camera_from_base),
            Some(&report),
        )
        .await?;
        emit_view(opts, &taken);
        pb.set_position((views.len() - first_used) as u64);
        let previous = report.camera_from_base;
        let t = Instant::now();
        report = solve(
            renderer.as_ref(),
            &camera,
            &views[first_used..],
            &previous,
            &solve_opts,
        )?;
        report.trajectory.insert(0, previous);
        solve_s += t.elapsed().as_secs_f64();
        let change = [
            rotation_error_deg(&previous, &report.camera_from_base),
            translation_error_mm(&previous, &report.camera_from_base),
        ];
        rounds.push(RoundRecord {
            round: round + 1,
            views: views.len() - first_used,
            camera_from_base: to_rows(&report.camera_from_base),
            mean_iou: report.mean_iou(),
            loss: report.loss,
            pose_change: Some(change),
            best_variance: None,
            next_joints: None,
            events: Vec::new(),
        });
        rec.write_rounds(&rounds)?;
        emit_round(opts, &rounds, &report);
        pb.set_message(format!(
            "round {} loss {:.5} IoU {:.4} best var {:.1} px change {:.3} deg / {:.2} mm",
            round + 1,
            report.loss,
            report.mean_iou(),
            best.unwrap_or(0.0),
            change[0],
            change[1]
        ));
    }
    pb.finish_and_clear();
    // The views the final estimate rests on: with no chosen view taken, the start view's.
    let used_from = if views.len() > first_used {
        first_used
    } else {
        0
    };
    if let Some(ctx) = &ctx {
        if !opts.dry_run && !cancelled {
            // The last views were segmented under the previous estimate: re-segment all of
            // them under the final one and solve once more; when that estimate fits, with the
            // final (narrowest) band: a narrow band is only safe around a right render.
            let t = Instant::now();
            let floor = if report.mean_iou() >= crate::segment::refine::POOR_FIT_IOU {
                ctx.final_band_px.min(ctx.min_band_px)
            } else {
                ctx.min_band_px
            };
            ctx.resegment(
                floor,
                cell,
                &camera,
                &rec,
                &taken,
                Some(&report.camera_from_base),
                Some(&report),
                &mut views,
            )?;
            report = solve(
                renderer.as_ref(),
                &camera,
                &views[used_from..],
                &report.camera_from_base,
                &solve_opts,
            )?;
            solve_s += t.elapsed().as_secs_f64();
            let last = rounds.last_mut().expect("round 0 exists");
            last.camera_from_base = to_rows(&report.camera_from_base);
            last.mean_iou = report.mean_iou();
            last.loss = report.loss;
            last.events
                .push("re-segmented every view under the final estimate and re-solved".into());
        }
    }
    rec.write_rounds(&rounds)?;
    let mut result = ResultFile::new(&report.camera_from_base, &cell.robot.links[cell.robot.base]);
    result.views_used = (used_from..views.len()).collect();
    result.per_view = report
        .per_view_iou
        .iter()
        .enumerate()
        .map(|(i, &iou)| PerView {
            view: used_from + i,
            iou,
        })
        .collect();
    result.uncertainty = UncertaintyEntry::of(&report.uncertainty);
    result.stop_reason = stop_reason;
    result
        .timings_s
        .insert("total".into(), started.elapsed().as_secs_f64());
    result.timings_s.insert("solve".into(), solve_s);
    result.timings_s.insert("explore".into(), explore_s);
    result.timings_s.insert("motion".into(), motion_s);
    if !opts.dry_run {
        write_json_atomic(&rec.dir().join("result.json"), &result)?;
    }
    Ok(Outcome {
        result,
        report,
        rounds,
        planned,
        run_dir: rec.dir().to_path_buf(),
        cancelled,
    })
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The climb only carries the posed robot through; an empty one will do.
    fn posed() -> PosedRobot {
        PosedRobot {
            vertices_base: Vec::new(),
            topology: std::sync::Arc::new(crate::mesh::TriMesh::default()),
            vertex_link: std::sync::Arc::new(Vec::new()),
        }
    }

    #[test]
    fn the_climb_improves_its_start_and_keeps_off_the_limits() {
        // The score peaks outside the limits, at joint 0 = 2.5 (limit 2.0): the climb must
        // walk towards it and stop a margin short of the limit.
        let limits = [(-2.0, 2.0), (-1.0, 1.0)];
        let score = |q: &[f64]| -(q[0] - 2.5).powi(2) - q[1].powi(2);
        let start = Ranked {
            joints: vec![-1.0, 0.8],
            score: score(&[-1.0, 0.8]),
            variance: None,
            in_image: 1.0,
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let (best, _) = climb(start.clone(), 300, &limits, &mut rng, |q| {
            Some((score(q), 1.0, posed()))
        })
        .expect("a better pose");
        assert!(best.score > start.score + 5.0, "{best:?}");
        assert!(
            best.joints[0] <= 2.0 - LIMIT_MARGIN_RAD + 1e-12 && best.joints[0] > 1.8,
            "{best:?}"
        );
        assert!(best.joints[1].abs() < 0.2, "{best:?}");
    }

    #[test]
    fn the_climb_never_keeps_a_pose_the_checks_refuse() {
        // Everything with joint 0 above zero is "unsafe"; the best allowed pose is at 0.
        let limits = [(-2.0, 2.0)];
        let start = Ranked {
            joints: vec![-1.5],
            score: -1.5,
            variance: None,
            in_image: 1.0,
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let (best, _) = climb(start, 200, &limits, &mut rng, |q| {
            (q[0] <= 0.0).then(|| (q[0], 1.0, posed()))
        })
        .expect("a better pose");
        assert!(best.joints[0] <= 0.0 && best.joints[0] > -0.2, "{best:?}");
        // No step can improve on the optimum: nothing is returned.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let top = Ranked {
            joints: vec![0.0],
            score: 0.0,
            variance: None,
            in_image: 1.0,
        };
        assert!(climb(top, 50, &limits, &mut rng, |q| {
            (q[0] <= 0.0).then(|| (q[0], 1.0, posed()))
        })
        .is_none());
    }
}

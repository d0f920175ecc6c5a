//! The planner: where the arm goes next. It draws joint samples, keeps the statically safe
//! ones that show the robot under the current estimate, and ranks them by what a view there
//! would tell (`[calibration] score`), or at random for the baseline selection. A ranked pose
//! still has to pass the path check ([`choose_reachable`]) before the arm may move.

use std::sync::Arc;

use nalgebra::{Isometry3, Matrix6};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

use super::motion_cost::MotionCost;
use super::visibility::VisibilityRule;
use super::PlannedPose;
use crate::backend::Backend;
use crate::camera::Intrinsics;
use crate::cell::Cell;
use crate::config::{CalibrationSettings, Mount, ScoreSetting, SelectionSetting, SourceSetting};
use crate::explore::{
    camera_candidates, cost_reduction, view_terms, CandidateSource, ExploreOptions, ViewTerms,
};
use crate::render::{CoarseRobot, PosedRobot};
use crate::robot::RobotModel;
use crate::safety::CheckedMove;
use crate::solve::SolveReport;

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
    /// What the view shows under the estimate: the in-image share of the robot (fixed
    /// camera) or the image share it covers (camera on a link); with several cameras, the
    /// least of theirs.
    pub in_image: f64,
}

/// Statistics of one planning pass.
#[derive(Clone, Copy, Debug, Default)]
pub struct PlanStats {
    /// Joint samples drawn.
    pub sampled: usize,
    /// Samples that passed limits/collision/workspace.
    pub safe: usize,
    /// …and show the robot (scored).
    pub scored: usize,
}

/// What one round plans from besides the estimate: the round, the views taken, and the time
/// model when moves cost time.
#[derive(Clone, Debug)]
pub struct PlanRequest<'a> {
    /// 0-based round (seeds the samples).
    pub round: usize,
    /// Reported joints of every view taken.
    pub taken: &'a [Vec<f64>],
    /// Rank by information per second of this time model (`information` score only).
    pub motion: Option<MotionCost>,
}

/// One camera as the planner sees it: its model, its mount and the robot it sees, its
/// current estimate, and whether it still asks for views (a camera that has converged in a
/// rig does not).
#[derive(Clone, Copy)]
pub struct PlanCamera<'a> {
    /// The camera's intrinsics (distortion allowed).
    pub camera: &'a Intrinsics,
    /// Where it is mounted: the rule for what a view must show follows from it.
    pub mount: &'a Mount,
    /// The robot as this camera sees it (rooted at its link for a camera on one).
    pub seen: &'a Arc<RobotModel>,
    /// Its latest solve.
    pub report: &'a SolveReport,
    /// Whether a view's value to this camera counts.
    pub wants_views: bool,
}

/// Draws joint samples, keeps the statically safe ones that show the robot to every camera,
/// and scores them by what a view would tell the cameras that still want views, best first.
/// With several cameras the scores add: each camera's information score is a reduction of
/// `ln det` of its covariance, which has no units and no scale, so a pose that shrinks one
/// camera's uncertainty volume by some factor is worth the same whichever camera it is.
pub fn rank_poses(
    renderer: &dyn Backend,
    cell: &Cell,
    cameras: &[PlanCamera],
    settings: &CalibrationSettings,
    request: &PlanRequest,
) -> (Vec<Ranked>, PlanStats) {
    let (round, taken) = (request.round, request.taken);
    let mut round_plan = RoundPlan::new(renderer, cell, cameras, settings, round);
    round_plan.motion = request.motion.clone();
    let samples = round_plan.draw_samples();
    let t_start = std::time::Instant::now();
    let safe = round_plan.statically_safe(samples);
    let n_safe = safe.len();
    if tracing::enabled!(tracing::Level::DEBUG) {
        tracing::debug!(
            "rank_poses: static checks {:.2} s",
            t_start.elapsed().as_secs_f64()
        );
    }
    let t_checked = std::time::Instant::now();
    let in_view = round_plan.in_view(safe);
    let n_scored = in_view.len();
    let mut ranked = match (settings.selection, settings.score) {
        (SelectionSetting::Random, _) => round_plan.rank_random(in_view),
        (SelectionSetting::Explore, ScoreSetting::Information) => {
            round_plan.rank_by_information(in_view, taken)
        }
        (SelectionSetting::Explore, ScoreSetting::Variance) => {
            round_plan.rank_by_variance(in_view, n_scored)
        }
    };
    ranked.sort_by(|a, b| b.0.score.total_cmp(&a.0.score));
    // The stop rule watches the candidates' disagreement at the best pose, whatever ranked it.
    if let Some((best, posed)) = ranked.first_mut() {
        if best.variance.is_none() {
            best.variance = round_plan.variances(&[&*posed]).first().copied();
        }
    }
    let ranked: Vec<Ranked> = ranked.into_iter().map(|r| r.0).collect();
    if tracing::enabled!(tracing::Level::DEBUG) {
        round_plan.debug_scoring(&ranked, t_checked);
    }
    let stats = PlanStats {
        sampled: settings.joint_samples,
        safe: n_safe,
        scored: n_scored,
    };
    (ranked, stats)
}

/// A sample's coarse posed robot per robot model the round's cameras see
/// ([`RoundPlan::models`]): one for fixed cameras, one more per link a camera rides on.
type Poses = Vec<PosedRobot>;
/// A joint sample that passed the static checks, with its coarse posed robots.
type Posed = (Vec<f64>, Poses);
/// A sample in view: its in-image fraction, joints and coarse posed robots.
type InView = (f64, Vec<f64>, Poses);
/// A ranked sample with the posed robots it was scored on.
type RankedPosed = (Ranked, Poses);

/// One camera's share of a planning round: its scoring images, the camera candidates drawn
/// around its estimate, and whether its score counts.
struct CameraPlan<'a> {
    report: &'a SolveReport,
    /// Index of the robot model this camera sees in [`RoundPlan::models`].
    model: usize,
    seen: &'a Arc<RobotModel>,
    visibility: VisibilityRule,
    pinhole: Intrinsics,
    low: Intrinsics,
    candidates: Vec<Isometry3<f64>>,
    estimate: Isometry3<f64>,
    wants_views: bool,
}

/// What one planning round shares between its steps: every camera's plan, and how samples
/// are posed coarsely.
struct RoundPlan<'a> {
    renderer: &'a dyn Backend,
    cell: &'a Cell,
    settings: &'a CalibrationSettings,
    round: usize,
    cameras: Vec<CameraPlan<'a>>,
    cell_m: f64,
    /// The distinct robot models the cameras see: every fixed camera shares the cell's
    /// robot, a camera on a link sees the robot rooted there.
    models: Vec<&'a Arc<RobotModel>>,
    /// Each model decimated once, for the variance score.
    coarse: Vec<CoarseRobot>,
    motion: Option<MotionCost>,
}

impl<'a> CameraPlan<'a> {
    fn new(
        cam: &PlanCamera<'a>,
        cell: &Cell,
        model: usize,
        settings: &CalibrationSettings,
        round: usize,
    ) -> Self {
        let pinhole = cam.camera.undistorted();
        let low = pinhole.downsampled(settings.score_downsample);
        let candidates = camera_candidates(
            &widened_posterior(cam.report, &pinhole, settings.score_downsample),
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
        CameraPlan {
            report: cam.report,
            model,
            seen: cam.seen,
            visibility: VisibilityRule::of(cell, cam.mount),
            low,
            candidates,
            estimate: cam.report.camera_from_base,
            pinhole,
            wants_views: cam.wants_views,
        }
    }
}

impl<'a> RoundPlan<'a> {
    fn new(
        renderer: &'a dyn Backend,
        cell: &'a Cell,
        cameras: &[PlanCamera<'a>],
        settings: &'a CalibrationSettings,
        round: usize,
    ) -> Self {
        let mut models: Vec<&'a Arc<RobotModel>> = Vec::new();
        let cameras: Vec<CameraPlan> = cameras
            .iter()
            .map(|c| {
                let model = models
                    .iter()
                    .position(|m| Arc::ptr_eq(m, c.seen))
                    .unwrap_or_else(|| {
                        models.push(c.seen);
                        models.len() - 1
                    });
                CameraPlan::new(c, cell, model, settings, round)
            })
            .collect();
        // Vertex clustering at one scoring pixel (at 1 m) of the sharpest camera: coarse
        // masks need no finer mesh.
        let f_max = cameras
            .iter()
            .map(|c| c.pinhole.fx.max(c.pinhole.fy))
            .fold(1.0, f64::max);
        let cell_m = f64::from(settings.score_downsample) / f_max;
        RoundPlan {
            renderer,
            cell,
            settings,
            round,
            cameras,
            cell_m,
            coarse: models.iter().map(|m| CoarseRobot::new(m, cell_m)).collect(),
            models,
            motion: None,
        }
    }

    /// Uniform joint samples within the checker's limits, seeded per round.
    fn draw_samples(&self) -> Vec<Vec<f64>> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(
            self.settings.seed.wrapping_mul(1000) + self.round as u64,
        );
        (0..self.settings.joint_samples)
            .map(|_| {
                self.cell
                    .checker
                    .limits()
                    .iter()
                    .map(|&(lo, hi)| rng.random_range(lo..=hi))
                    .collect()
            })
            .collect()
    }

    /// The variance score only needs coarse masks: one decimation per robot (link frames),
    /// posed per sample. The information score reads outline samples, which follow the posed
    /// surface more faithfully when each pose is clustered in the base frame. One posed
    /// robot per model the cameras see.
    fn pose_coarse(&self, q: &[f64]) -> Poses {
        self.models
            .iter()
            .zip(&self.coarse)
            .map(|(seen, coarse)| {
                if self.settings.score == ScoreSetting::Information {
                    PosedRobot::new(seen, q).decimated(self.cell_m)
                } else {
                    coarse.pose(seen, q)
                }
            })
            .collect()
    }

    /// The samples that pass limits, collision and workspace checks, posed coarsely.
    fn statically_safe(&self, samples: Vec<Vec<f64>>) -> Vec<Posed> {
        samples
            .into_par_iter()
            .filter(|q| self.cell.checker.check_pose(q).is_ok())
            .map(|q| {
                let posed = self.pose_coarse(&q);
                (q, posed)
            })
            .collect()
    }

    /// The safe samples that show enough of the robot under the estimate.
    fn in_view(&self, safe: Vec<Posed>) -> Vec<InView> {
        safe.into_par_iter()
            .filter_map(|(q, posed)| {
                let in_image = self.shows(&posed)?;
                Some((in_image, q, posed))
            })
            .collect()
    }

    /// How much of the robot a view of `posed` shows under the estimates, when enough for
    /// every camera (each by its own [`VisibilityRule`]): every camera records every view,
    /// so each must see the robot. The least share of any camera.
    fn shows(&self, posed: &Poses) -> Option<f64> {
        self.cameras
            .iter()
            .map(|c| {
                c.visibility
                    .shows(&posed[c.model], &c.pinhole, &c.low, &c.estimate)
            })
            .try_fold(f64::INFINITY, |least, s| s.map(|s| least.min(s)))
    }

    /// The candidates' disagreement at each pool pose, added over the cameras that want
    /// views. Batched through the renderer: a GPU backend scores the whole pool per
    /// submission.
    fn variances(&self, pool: &[&Poses]) -> Vec<f64> {
        self.variances_with(pool, |c| &c.candidates)
    }

    fn variances_with(
        &self,
        pool: &[&Poses],
        candidates: impl for<'c> Fn(&'c CameraPlan<'a>) -> &'c [Isometry3<f64>],
    ) -> Vec<f64> {
        let mut total = vec![0.0; pool.len()];
        for c in self.cameras.iter().filter(|c| c.wants_views) {
            let seen: Vec<&PosedRobot> = pool.iter().map(|p| &p[c.model]).collect();
            let v = self
                .renderer
                .disagreement_many(&c.low, &seen, candidates(c));
            total.iter_mut().zip(v).for_each(|(t, v)| *t += v);
        }
        total
    }

    /// The baseline: a seeded random order (a hash of the joints, so it is repeatable).
    fn rank_random(&self, in_view: Vec<InView>) -> Vec<RankedPosed> {
        in_view
            .into_iter()
            .map(|(in_image, q, posed)| {
                let mut h = rand_chacha::ChaCha8Rng::seed_from_u64(
                    q.iter()
                        .fold(self.settings.seed, |a, v| a.rotate_left(7) ^ v.to_bits()),
                );
                let r = Ranked {
                    score: h.random::<f64>(),
                    variance: None,
                    joints: q,
                    in_image,
                };
                (r, posed)
            })
            .collect()
    }

    /// What a view at `q` adds to camera `c`'s estimate's information (outline and joint
    /// terms).
    fn terms(&self, c: &CameraPlan, posed: &Poses, q: &[f64]) -> ViewTerms {
        view_terms(
            &c.low,
            c.pinhole.fx,
            &posed[c.model],
            &c.seen.joint_motions(q),
            &c.estimate,
            c.report.outline_noise_px2,
            self.settings.joint_noise_rad,
        )
    }

    /// Ranks by how much each view lowers the predicted covariance, then climbs from the best
    /// few: 2000 random samples leave the best view's information well short of what a few
    /// steps of local search from the best of them reach.
    fn rank_by_information(&self, in_view: Vec<InView>, taken: &[Vec<f64>]) -> Vec<RankedPosed> {
        // What the views taken so far contribute to each camera, on the same footing as the
        // candidates (a tiny ridge keeps a one-view outline matrix invertible).
        let wanting: Vec<&CameraPlan> = self.cameras.iter().filter(|c| c.wants_views).collect();
        let current: Vec<ViewTerms> = wanting
            .iter()
            .map(|c| {
                let mut t = taken
                    .par_iter()
                    .map(|q| self.terms(c, &self.pose_coarse(q), q))
                    .reduce(ViewTerms::zeros, |a, b| a + b);
                t.outline_information += Matrix6::identity() * 1e-6;
                t
            })
            .collect();
        let score = |posed: &Poses, q: &[f64]| {
            let gain: f64 = wanting
                .iter()
                .zip(&current)
                .map(|(c, now)| cost_reduction(now, &self.terms(c, posed, q), &c.estimate))
                .sum();
            match &self.motion {
                Some(m) => m.rate(gain, q),
                None => gain,
            }
        };
        let mut scored: Vec<RankedPosed> = in_view
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
        if self.settings.climb_steps > 0 {
            let climbed = self.climb_from_best(&mut scored, &score);
            scored.extend(climbed);
        }
        scored
    }

    /// Hill climbs from the [`CLIMB_STARTS`] best-scored samples (sorts `scored`).
    fn climb_from_best(
        &self,
        scored: &mut [RankedPosed],
        score: &(dyn Fn(&Poses, &[f64]) -> f64 + Sync),
    ) -> Vec<RankedPosed> {
        scored.sort_by(|a, b| b.0.score.total_cmp(&a.0.score));
        let starts: Vec<Ranked> = scored
            .iter()
            .take(CLIMB_STARTS)
            .map(|r| r.0.clone())
            .collect();
        let checker = &self.cell.checker;
        starts
            .into_par_iter()
            .enumerate()
            .filter_map(|(i, start)| {
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(
                    self.settings.seed.wrapping_mul(31337) + (self.round * 64 + i) as u64,
                );
                climb(
                    start,
                    self.settings.climb_steps,
                    checker.limits(),
                    &mut rng,
                    |q| {
                        if checker.check_pose(q).is_err() {
                            return None;
                        }
                        let posed = self.pose_coarse(q);
                        let in_image = self.shows(&posed)?;
                        Some((score(&posed, q), in_image, posed))
                    },
                )
            })
            .collect()
    }

    /// The paper's score in two passes: every sample against the first fifth of the
    /// candidates, then the best quarter against all of them (the argmax is almost always in
    /// that quarter; this halves the planning time).
    fn rank_by_variance(&self, in_view: Vec<InView>, n_scored: usize) -> Vec<RankedPosed> {
        let pool: Vec<&Poses> = in_view.iter().map(|(_, _, p)| p).collect();
        let quick_scores = self.variances_with(&pool, |c| {
            &c.candidates[..(c.candidates.len() / 5).max(2).min(c.candidates.len())]
        });
        let mut first: Vec<(f64, f64, Vec<f64>, Poses)> = in_view
            .into_iter()
            .zip(quick_scores)
            .map(|((in_image, q, posed), v)| (v, in_image, q, posed))
            .collect();
        first.sort_by(|a, b| b.0.total_cmp(&a.0));
        first.truncate((n_scored / 4).max(64.min(n_scored)));
        let pool: Vec<&Poses> = first.iter().map(|(_, _, _, p)| p).collect();
        let full = self.variances(&pool);
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

    /// At debug level (`RUST_LOG=easyhec=debug` or `-v`): the scoring time and the coarse robot's size.
    fn debug_scoring(&self, ranked: &[Ranked], t_checked: std::time::Instant) {
        tracing::debug!(
            "rank_poses: scoring {:.2} s, {} scored, {} triangles per coarse robot",
            t_checked.elapsed().as_secs_f64(),
            ranked.len(),
            PosedRobot::new(
                self.models[0],
                &ranked.first().map(|r| r.joints.clone()).unwrap_or_default()
            )
            .decimated(self.cell_m)
            .topology
            .triangles
            .len()
        );
    }
}

/// The variance of binary masks only measures disagreement once the hypotheses' outlines
/// differ by whole scoring pixels; a converged posterior moves them by a fraction of one,
/// which leaves the score as quantisation noise. In the linear regime the ranking of views
/// does not depend on the covariance's scale, so the samples come from the posterior
/// inflated until its typical outline displacement is about two scoring pixels.
fn widened_posterior(
    report: &SolveReport,
    pinhole: &Intrinsics,
    score_downsample: u32,
) -> SolveReport {
    let mut widened = report.clone();
    let u = crate::solve::uncertainty_of(&report.sampling_covariance, &report.camera_from_base);
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
    let wanted_px = 2.0 * f64::from(score_downsample);
    if typical_px.is_finite() && typical_px > 0.0 && typical_px < wanted_px {
        let k = wanted_px / typical_px;
        widened.sampling_covariance *= k * k;
    }
    widened
}

/// Best-scored samples each hill climb starts from.
const CLIMB_STARTS: usize = 8;

/// How far inside its joint limits a climbed target stays, radians.
const LIMIT_MARGIN_RAD: f64 = 0.02;

/// Stochastic hill climb in joint space from `start`: Gaussian steps of every joint
/// (0.3 rad, shrunk by 15% per failed step), a step kept when `evaluate` passes the pose
/// (static safety checks, robot in view) and it scores higher. `None` when no step improved
/// on `start`. The climbed pose still goes through the path check before any move.
fn climb<P>(
    start: Ranked,
    steps: usize,
    limits: &[(f64, f64)],
    rng: &mut rand_chacha::ChaCha8Rng,
    evaluate: impl Fn(&[f64]) -> Option<(f64, f64, P)>,
) -> Option<(Ranked, P)> {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The climb only carries the posed robot through; an empty one will do.
    fn posed() -> PosedRobot {
        PosedRobot {
            vertices_base: Vec::new(),
            topology: std::sync::Arc::new(crate::mesh::TriMesh::default()),
            vertex_link: std::sync::Arc::new(Vec::new()),
            joint_motions: std::sync::Arc::new(Vec::new()),
            fixed_links: Default::default(),
            mount_cache: Default::default(),
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

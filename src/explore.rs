//! Consistency-based view selection (docs/method.md §5): the next view is the one where the camera
//! poses that still fit the data disagree most about the robot's silhouette.
//!
//! Candidates are drawn from the solver's Gaussian posterior (default) or taken from its
//! optimisation trajectory (the paper's choice). A view's score is the per-pixel variance of
//! the candidates' masks, `V = sum_p c_p (K - c_p) / K^2`, at reduced resolution; the paper
//! shows the summed loss over candidates bounds it from above, so a high `V` is a view that
//! will shrink the candidate set. The score itself is a batched computation of the backend
//! ([`crate::scoring::BatchScoring::disagreement_many`], defined by
//! [`crate::scoring::cpu::disagreement`]); this module chooses what to score and what to do
//! with the scores.

use nalgebra::{Isometry3, Matrix6};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

use crate::backend::Backend;
use crate::camera::Intrinsics;
use crate::geometry::{exp_se3, Twist};
use crate::render::{PosedRobot, SilhouetteRenderer};
use crate::robot::JointMotion;
use crate::solve::SolveReport;

/// Where camera candidates come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum CandidateSource {
    /// Samples of `N(estimate, covariance)` (default; needs no optimiser history).
    #[default]
    Posterior,
    /// Iterates of the optimisation trajectory after its first fifth (the paper's choice).
    Trajectory,
}

/// Exploration settings.
#[derive(Clone, Debug)]
pub struct ExploreOptions {
    /// Number of camera candidates `K` (paper: 50).
    pub candidates: usize,
    /// Image downsampling for scoring.
    pub downsample: u32,
    /// Candidate source.
    pub source: CandidateSource,
    /// Sampling seed.
    pub seed: u64,
    /// Vertex-clustering cell for scoring meshes, metres (coarse masks need no detail).
    pub cell_m: f64,
}

impl Default for ExploreOptions {
    fn default() -> Self {
        ExploreOptions {
            candidates: 50,
            downsample: 4,
            source: CandidateSource::Posterior,
            seed: 0,
            cell_m: 0.004,
        }
    }
}

/// Camera-pose hypotheses that still fit the data.
pub fn camera_candidates(report: &SolveReport, opts: &ExploreOptions) -> Vec<Isometry3<f64>> {
    let k = opts.candidates.max(2);
    match opts.source {
        CandidateSource::Posterior => {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(opts.seed);
            let finite = report.sampling_covariance.iter().all(|v| v.is_finite());
            let Some(chol) = report.sampling_covariance.cholesky().filter(|_| finite) else {
                return vec![report.camera_from_base; k];
            };
            (0..k)
                .map(|i| {
                    if i == 0 {
                        return report.camera_from_base;
                    }
                    let z = Twist::from_fn(|_, _| StandardNormal.sample(&mut rng));
                    exp_se3(&(chol.l() * z)) * report.camera_from_base
                })
                .collect()
        }
        CandidateSource::Trajectory => {
            let t = &report.trajectory;
            if t.is_empty() {
                return vec![report.camera_from_base; k];
            }
            let tail = &t[(t.len() / 5).min(t.len() - 1)..];
            (0..k).map(|i| tail[i * tail.len() / k]).collect()
        }
    }
}

/// What one view tells the solver about the camera pose, over the left se(3) increment
/// `(rho, phi)`: how its outline pins the pose, and how its reported joints' errors push the
/// solver's estimate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewTerms {
    /// `A = sum_s l_s j_s j_s^T / noise_px2` over outline samples `s` (rendered at the
    /// estimate): `j_s` the sample's normal displacement per unit increment, `l_s` the outline
    /// length it stands for (full-resolution pixels). The solver's normal matrix for the view.
    pub outline_information: Matrix6<f64>,
    /// `S = sigma_q^2 B B^T`, `B = sum_links H_link Xi_link`: the covariance of the pull the
    /// view's joint errors (`N(0, sigma_q^2)` per joint) put on the solver's normal equations.
    /// A joint error moves a whole link rigidly, which the outline sees exactly like a camera
    /// motion `Xi dq`; the solver, which takes the reported joints as true, follows it.
    pub joint_scatter: Matrix6<f64>,
}

impl ViewTerms {
    /// No views.
    pub fn zeros() -> Self {
        ViewTerms {
            outline_information: Matrix6::zeros(),
            joint_scatter: Matrix6::zeros(),
        }
    }
}

impl std::ops::Add for ViewTerms {
    type Output = ViewTerms;
    fn add(self, other: ViewTerms) -> ViewTerms {
        ViewTerms {
            outline_information: self.outline_information + other.outline_information,
            joint_scatter: self.joint_scatter + other.joint_scatter,
        }
    }
}

/// [`ViewTerms`] of one view of `robot` rendered at `estimate` on `camera` (a scoring
/// camera; `full_fx` is the full-resolution focal length the outline lengths and
/// displacements are scaled to).
pub fn view_terms(
    camera: &Intrinsics,
    full_fx: f64,
    robot: &PosedRobot,
    motions: &[JointMotion],
    estimate: &Isometry3<f64>,
    noise_px2: f64,
    joint_noise_rad: f64,
) -> ViewTerms {
    let sil = crate::render::CpuRenderer.render(robot, camera, estimate, Some(1.0));
    let links = motions.first().map_or(0, |m| m.moves_link.len());
    // Per link: sum of l j j^T (scoring pixels).
    let mut per_link = vec![Matrix6::<f64>::zeros(); links + 1];
    for s in &sil.boundary {
        let jp = s.pixel_jacobian(camera);
        let jn: Twist = (jp.row(0) * s.normal[0] + jp.row(1) * s.normal[1]).transpose();
        let link = robot
            .vertex_link
            .get(s.vertex as usize)
            .map_or(links, |&l| (l as usize).min(links));
        per_link[link] += jn * jn.transpose() * s.length_px;
    }
    // Scoring pixels -> full-resolution pixels: displacement and length each scale by f.
    let f = full_fx / camera.fx;
    let scale = f * f * f / noise_px2.max(1e-12);
    let outline_information: Matrix6<f64> = per_link.iter().sum::<Matrix6<f64>>() * scale;
    let n = motions.len();
    if joint_noise_rad <= 0.0 || n == 0 {
        return ViewTerms {
            outline_information,
            joint_scatter: Matrix6::zeros(),
        };
    }
    let twists: Vec<Twist> = motions
        .iter()
        .map(|m| m.twist_in_camera(estimate))
        .collect();
    let mut b = nalgebra::DMatrix::<f64>::zeros(6, n);
    for (link, h) in per_link.iter().enumerate().take(links) {
        if h.iter().all(|v| *v == 0.0) {
            continue;
        }
        for (k, m) in motions.iter().enumerate() {
            if m.moves_link[link] {
                let col = h * twists[k] * scale;
                let mut dst = b.column_mut(k);
                dst += col;
            }
        }
    }
    let scatter = &b * b.transpose() * (joint_noise_rad * joint_noise_rad);
    ViewTerms {
        outline_information,
        joint_scatter: Matrix6::from_iterator(scatter.iter().copied()),
    }
}

/// Covariance of the solver's estimate from views whose terms sum to `terms`: the sandwich
/// `A^-1 (A + S) A^-1`, since the solver weighs each view by its outline (`A`) whatever its
/// joints' errors (`S`) do to it. `None` when the outlines leave a direction unpinned.
pub fn estimate_covariance(terms: &ViewTerms) -> Option<Matrix6<f64>> {
    let a = &terms.outline_information;
    let a_inv = a.cholesky()?.inverse();
    Some(a_inv * (a + terms.joint_scatter) * a_inv)
}

/// The selection's cost of a covariance of `camera_from_base`'s left increment:
/// `ln det` of the rotation block plus `ln det` of the covariance of the translation
/// `camera_from_base` reports (`rho - t x phi`, `t` its translation), so that views are
/// chosen for the two errors the calibration is judged by, each independent of units.
pub fn selection_cost(covariance: &Matrix6<f64>, camera_from_base: &Isometry3<f64>) -> f64 {
    let translation = crate::solve::translation_covariance(covariance, camera_from_base);
    let rotation = covariance.fixed_view::<3, 3>(3, 3).into_owned();
    let ln_det = |m: &nalgebra::Matrix3<f64>| {
        m.cholesky().map_or(f64::INFINITY, |c| {
            2.0 * c.l().diagonal().iter().map(|v| v.ln()).sum::<f64>()
        })
    };
    ln_det(&rotation) + ln_det(&translation)
}

/// How much adding a view with terms `candidate` to the views taken (`current`) lowers the
/// [`selection_cost`] of the solver's estimate at `camera_from_base` (higher is better).
pub fn cost_reduction(
    current: &ViewTerms,
    candidate: &ViewTerms,
    camera_from_base: &Isometry3<f64>,
) -> f64 {
    let cost = |t: &ViewTerms| {
        estimate_covariance(t).map_or(f64::INFINITY, |c| selection_cost(&c, camera_from_base))
    };
    let after = cost(&(*current + *candidate));
    if !after.is_finite() {
        return f64::NEG_INFINITY;
    }
    let before = cost(current);
    if before.is_finite() {
        before - after
    } else {
        -after
    }
}

/// Scores every pool entry (robot poses; pass meshes decimated with `opts.cell_m` — coarse
/// masks need no detail) and returns `(index into pool, score)` of the best, or `None` for
/// an empty pool. Scoring is at `opts.downsample` resolution.
pub fn choose_next(
    renderer: &dyn Backend,
    camera: &Intrinsics,
    pool: &[&PosedRobot],
    candidates: &[Isometry3<f64>],
    opts: &ExploreOptions,
) -> Option<(usize, f64)> {
    let low = camera.undistorted().downsampled(opts.downsample.max(1));
    let coarse: Vec<PosedRobot> = pool.par_iter().map(|r| r.decimated(opts.cell_m)).collect();
    let coarse: Vec<&PosedRobot> = coarse.iter().collect();
    renderer
        .disagreement_many(&low, &coarse, candidates)
        .into_iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(&b.1))
}

/// How `easyhec solve` picks views from a recorded run (docs/formats.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Selection {
    /// Views `0..K-1`.
    First,
    /// View 0, then views drawn at random (seeded).
    Random(u64),
    /// View 0, then the most disagreeing view each round.
    Explore,
}

/// When incremental selection stops early.
#[derive(Clone, Debug)]
pub struct StopRule {
    /// Stop when the best score changes by less than this fraction between rounds…
    pub variance_rel_tol: f64,
    /// …and the pose moved less than this rotation (degrees)…
    pub pose_tol_deg: f64,
    /// …and this translation (millimetres).
    pub pose_tol_mm: f64,
}

impl Default for StopRule {
    fn default() -> Self {
        StopRule {
            variance_rel_tol: 0.1,
            pose_tol_deg: 0.02,
            pose_tol_mm: 0.2,
        }
    }
}

/// Outcome of an incremental solve.
#[derive(Clone, Debug)]
pub struct Selected {
    /// Indices into the pool, in the order they were added.
    pub order: Vec<usize>,
    /// The final solve.
    pub report: SolveReport,
    /// Why selection stopped.
    pub stop_reason: String,
    /// Seconds spent scoring views.
    pub explore_s: f64,
    /// Seconds spent solving.
    pub solve_s: f64,
}

/// Solves from up to `max_views` views of `pool`, chosen by `selection`; `First` solves once,
/// the others add one view per round and re-solve warm-started from the previous estimate.
#[allow(clippy::too_many_arguments)]
pub fn solve_selected(
    renderer: &dyn Backend,
    camera: &Intrinsics,
    pool: &[crate::solve::View],
    initial: &Isometry3<f64>,
    max_views: usize,
    selection: Selection,
    solve_opts: &crate::solve::SolveOptions,
    explore_opts: &ExploreOptions,
    stop: &StopRule,
) -> crate::Result<Selected> {
    use rand::seq::SliceRandom;
    use std::time::Instant;
    let k = max_views.clamp(1, pool.len().max(1));
    let solve_views = |order: &[usize], start: &Isometry3<f64>| {
        let views: Vec<crate::solve::View> = order.iter().map(|&i| pool[i].clone()).collect();
        crate::solve::solve(renderer, camera, &views, start, solve_opts)
    };
    let (mut explore_s, mut solve_s) = (0.0, 0.0);
    if selection == Selection::First {
        let order: Vec<usize> = (0..k).collect();
        let t = Instant::now();
        let report = solve_views(&order, initial)?;
        return Ok(Selected {
            order,
            report,
            stop_reason: format!("used the first {k} views"),
            explore_s,
            solve_s: t.elapsed().as_secs_f64(),
        });
    }
    let mut random_order: Vec<usize> = (1..pool.len()).collect();
    if let Selection::Random(seed) = selection {
        random_order.shuffle(&mut rand_chacha::ChaCha8Rng::seed_from_u64(seed));
    }
    let mut order = vec![0];
    let t = Instant::now();
    let mut report = solve_views(&order, initial)?;
    solve_s += t.elapsed().as_secs_f64();
    let mut previous_best: Option<f64> = None;
    let scoring: Vec<PosedRobot> = if selection == Selection::Explore {
        pool.par_iter()
            .map(|v| v.robot.decimated(explore_opts.cell_m))
            .collect()
    } else {
        Vec::new()
    };
    let mut stop_reason = format!("reached {k} views");
    while order.len() < k {
        let remaining: Vec<usize> = (0..pool.len()).filter(|i| !order.contains(i)).collect();
        if remaining.is_empty() {
            stop_reason = "no views left in the pool".into();
            break;
        }
        let t = Instant::now();
        let next = match selection {
            Selection::Explore => {
                let candidates = camera_candidates(
                    &report,
                    &ExploreOptions {
                        seed: explore_opts.seed + order.len() as u64,
                        ..explore_opts.clone()
                    },
                );
                let robots: Vec<&PosedRobot> = remaining.iter().map(|&i| &scoring[i]).collect();
                let (best, score) =
                    choose_next(renderer, camera, &robots, &candidates, explore_opts)
                        .expect("pool not empty");
                explore_s += t.elapsed().as_secs_f64();
                if let Some(prev) = previous_best {
                    let settled = (prev - score).abs() <= stop.variance_rel_tol * prev.max(1e-12);
                    if settled && order.len() >= 2 && pose_settled(&report, stop) {
                        stop_reason = format!("variance converged after {} views", order.len());
                        break;
                    }
                }
                previous_best = Some(score);
                remaining[best]
            }
            _ => *random_order
                .iter()
                .find(|i| !order.contains(i))
                .expect("pool not empty"),
        };
        order.push(next);
        let previous_pose = report.camera_from_base;
        let t = Instant::now();
        report = solve_views(&order, &previous_pose)?;
        report.trajectory.insert(0, previous_pose);
        solve_s += t.elapsed().as_secs_f64();
    }
    Ok(Selected {
        order,
        report,
        stop_reason,
        explore_s,
        solve_s,
    })
}

/// Whether the last round moved the estimate less than the stop rule's pose tolerance (the
/// trajectory of an incremental round starts with the previous round's estimate).
fn pose_settled(report: &SolveReport, stop: &StopRule) -> bool {
    let Some(first) = report.trajectory.first() else {
        return false;
    };
    crate::geometry::rotation_error_deg(first, &report.camera_from_base) < stop.pose_tol_deg
        && crate::geometry::translation_error_mm(first, &report.camera_from_base) < stop.pose_tol_mm
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::look_at_camera_from_base;
    use crate::robot::RobotModel;
    use nalgebra::Vector3;

    #[test]
    fn doubling_every_view_halves_each_variance() {
        let current = ViewTerms {
            outline_information: Matrix6::from_diagonal(&Twist::new(4.0, 1.0, 9.0, 2.0, 3.0, 5.0)),
            joint_scatter: Matrix6::from_diagonal(&Twist::new(1.0, 0.0, 2.0, 0.5, 0.0, 1.0)),
        };
        let pose = look_at_camera_from_base(
            &Vector3::new(1.3, 0.5, 0.8),
            &Vector3::new(0.1, 0.0, 0.3),
            &Vector3::z(),
        );
        assert!(cost_reduction(&current, &ViewTerms::zeros(), &pose).abs() < 1e-12);
        // Twice the outline and twice the scatter: the sandwich covariance halves, so each
        // 3x3 determinant drops by 2^3.
        let g = cost_reduction(&current, &current, &pose);
        assert!((g - 6.0 * 2f64.ln()).abs() < 1e-9, "{g}");
        // A view that pins nothing on its own still counts once the sum is invertible.
        let none = ViewTerms::zeros();
        assert!(cost_reduction(&none, &current, &pose).is_finite());
        assert_eq!(cost_reduction(&none, &none, &pose), f64::NEG_INFINITY);
    }

    #[test]
    fn joint_twists_predict_how_each_joint_moves_the_robot() {
        let urdf = concat!(env!("CARGO_MANIFEST_DIR"), "/robots/xarm6/robot.urdf");
        let robot = RobotModel::from_urdf(urdf).unwrap();
        let q = [0.3, -0.4, -0.5, 0.2, 0.9, 0.1];
        let camera_from_base = look_at_camera_from_base(
            &Vector3::new(1.3, 0.5, 0.8),
            &Vector3::new(0.1, 0.0, 0.3),
            &Vector3::z(),
        );
        let before = robot.posed_vertices(&q);
        let motions = robot.joint_motions(&q);
        let dq = 1e-6;
        for (j, m) in motions.iter().enumerate() {
            let mut q2 = q;
            q2[j] += dq;
            let after = robot.posed_vertices(&q2);
            let xi = m.twist_in_camera(&camera_from_base);
            let (rho, phi) = (xi.fixed_rows::<3>(0), xi.fixed_rows::<3>(3));
            let mut moved = 0;
            for (k, (a, b)) in before.iter().zip(&after).enumerate().step_by(97) {
                let (pa, pb) = (camera_from_base * a, camera_from_base * b);
                let link = robot.vertex_link[k] as usize;
                let predicted = if m.moves_link[link] {
                    moved += 1;
                    (rho + phi.cross(&pa.coords)) * dq
                } else {
                    Vector3::zeros()
                };
                let err = (pb - pa - predicted).norm();
                assert!(err < 1e-10, "joint {j} vertex {k}: off by {err} m");
            }
            assert!(moved > 0, "joint {j} moves nothing");
        }
    }

    #[test]
    fn joint_errors_widen_the_estimate_and_only_widen_it() {
        let urdf = concat!(env!("CARGO_MANIFEST_DIR"), "/robots/xarm6/robot.urdf");
        let robot = RobotModel::from_urdf(urdf).unwrap();
        let q = [0.3, -0.4, -0.5, 0.2, 0.9, 0.1];
        let posed = PosedRobot::new(&robot, &q).decimated(0.01);
        let camera = Intrinsics::pinhole(160, 120, 150.0, 150.0, 80.0, 60.0);
        let estimate = look_at_camera_from_base(
            &Vector3::new(1.3, 0.5, 0.8),
            &Vector3::new(0.1, 0.0, 0.3),
            &Vector3::z(),
        );
        let motions = robot.joint_motions(&q);
        let terms = |noise| view_terms(&camera, 600.0, &posed, &motions, &estimate, 0.3, noise);
        let exact = terms(0.0);
        let noisy = terms(0.0005);
        // The outline's information does not depend on the joints' errors.
        assert_eq!(exact.outline_information, noisy.outline_information);
        assert_eq!(exact.joint_scatter, Matrix6::zeros());
        // Exact joints: one view pins all six degrees of freedom.
        let cov_exact = estimate_covariance(&exact).expect("one view pins the pose");
        let cov_noisy = estimate_covariance(&noisy).expect("one view pins the pose");
        // Joint errors add a positive semi-definite part to the covariance…
        let added = (cov_noisy - cov_exact).symmetric_eigen();
        let largest = cov_noisy.symmetric_eigen().eigenvalues.max();
        assert!(
            added.eigenvalues.min() > -1e-9 * largest,
            "{:?}",
            added.eigenvalues
        );
        // …and a real one: 0.5 mrad per joint at least doubles the predicted volume…
        let grown = cov_noisy.determinant() / cov_exact.determinant();
        assert!(grown > 2.0, "determinant grew only {grown}x");
        // …and larger joint errors widen it more, in the calibration's own terms too.
        let cov_worse = estimate_covariance(&terms(0.002)).unwrap();
        assert!(cov_worse.determinant() > cov_noisy.determinant());
        assert!(selection_cost(&cov_worse, &estimate) > selection_cost(&cov_noisy, &estimate));
    }
}

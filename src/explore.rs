//! Consistency-based view selection (method.md §5): the next view is the one where the camera
//! poses that still fit the data disagree most about the robot's silhouette.
//!
//! Candidates are drawn from the solver's Gaussian posterior (default) or taken from its
//! optimisation trajectory (the paper's choice). A view's score is the per-pixel variance of
//! the candidates' masks, `V = sum_p c_p (K - c_p) / K^2`, at reduced resolution; the paper
//! shows the summed loss over candidates bounds it from above, so a high `V` is a view that
//! will shrink the candidate set.

use nalgebra::{Isometry3, Matrix6};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

use crate::camera::Camera;
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
            let finite = report.covariance.iter().all(|v| v.is_finite());
            let Some(chol) = report.covariance.cholesky().filter(|_| finite) else {
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

/// Total per-pixel variance of the candidates' silhouettes of `robot`, in pixels of the
/// scoring image, on the CPU rasteriser: single-threaded with reused buffers, because callers
/// score many poses in parallel, where per-render thread fan-out and allocation would cost
/// more than the rasterisation of a coarse mesh at scoring resolution.
pub fn disagreement_cpu(camera: &Camera, robot: &PosedRobot, candidates: &[Isometry3<f64>]) -> f64 {
    let k = candidates.len() as f64;
    let mut counts = vec![0u16; (camera.width * camera.height) as usize];
    let mut mask = crate::mask::Mask::new(camera.width, camera.height);
    let mut pixels = vec![[0.0f64; 2]; robot.vertices_base.len()];
    for pose in candidates {
        mask.data.fill(0);
        for (px, v) in pixels.iter_mut().zip(&robot.vertices_base) {
            let p = pose * v;
            *px = if p.z > crate::render::NEAR_PLANE_M {
                camera.project(&p)
            } else {
                [f64::NAN, f64::NAN]
            };
        }
        for t in &robot.topology.triangles {
            let (a, b, c) = (
                pixels[t[0] as usize],
                pixels[t[1] as usize],
                pixels[t[2] as usize],
            );
            if a[0].is_nan() || b[0].is_nan() || c[0].is_nan() {
                continue;
            }
            crate::render::fill_triangle(&mut mask, a, b, c);
        }
        for (c, &v) in counts.iter_mut().zip(&mask.data) {
            *c += u16::from(v);
        }
    }
    counts
        .iter()
        .map(|&c| f64::from(c) * (k - f64::from(c)))
        .sum::<f64>()
        / (k * k)
}

/// Information one view of `robot` carries about the camera pose, as a 6x6 matrix over the
/// left se(3) increment, with the reported joints' errors marginalised out.
///
/// Each outline sample `s` (rendered at `estimate`) contributes `l_s j_s j_s^T / noise_px2`,
/// with `j_s` its normal displacement per unit increment and `l_s` the outline length it
/// stands for (full-resolution pixels). A joint error moves a whole link rigidly, which the
/// outline sees exactly like a camera motion `Xi_L dq`; with `dq ~ N(0, joint_noise_rad^2)`
/// per view the information left about the camera is the Schur complement
/// `A - B (C + I / joint_noise_rad^2)^-1 B^T`. Views whose outline a joint error could fake
/// are worth little, however long their outline: segmentation noise averages out along an
/// outline, joint errors do not.
pub fn view_information(
    camera: &Camera,
    full_fx: f64,
    robot: &PosedRobot,
    motions: &[JointMotion],
    estimate: &Isometry3<f64>,
    noise_px2: f64,
    joint_noise_rad: f64,
) -> Matrix6<f64> {
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
    let a: Matrix6<f64> = per_link.iter().sum::<Matrix6<f64>>() * scale;
    let n = motions.len();
    if joint_noise_rad <= 0.0 || n == 0 {
        return a;
    }
    let twists: Vec<Twist> = motions
        .iter()
        .map(|m| joint_twist_in_camera(m, estimate))
        .collect();
    let mut b = nalgebra::DMatrix::<f64>::zeros(6, n);
    let mut c = nalgebra::DMatrix::<f64>::zeros(n, n);
    for (link, h) in per_link.iter().enumerate().take(links) {
        if h.iter().all(|v| *v == 0.0) {
            continue;
        }
        let mut xi = nalgebra::DMatrix::<f64>::zeros(6, n);
        for (k, m) in motions.iter().enumerate() {
            if m.moves_link[link] {
                xi.set_column(k, &twists[k]);
            }
        }
        let hd = nalgebra::DMatrix::from_iterator(6, 6, h.iter().copied()) * scale;
        let hx = &hd * &xi;
        c += xi.transpose() * &hx;
        b += hx;
    }
    for k in 0..n {
        c[(k, k)] += 1.0 / (joint_noise_rad * joint_noise_rad);
    }
    let Some(c_inv) = c.try_inverse() else {
        return a;
    };
    let schur = &b * c_inv * b.transpose();
    a - Matrix6::from_iterator(schur.iter().copied())
}

/// A joint's motion as a left se(3) increment in the camera frame: a link it moves by `dq`
/// has its points move by `dq * (rho + phi x p)` in the camera frame, exactly as under a
/// camera increment `(rho, phi)`, so the outline cannot tell the two apart.
pub fn joint_twist_in_camera(motion: &JointMotion, camera_from_base: &Isometry3<f64>) -> Twist {
    let axis = camera_from_base.rotation * motion.axis_base;
    if motion.prismatic {
        Twist::new(axis.x, axis.y, axis.z, 0.0, 0.0, 0.0)
    } else {
        let o = (camera_from_base * motion.origin_base).coords;
        let rho = o.cross(&axis);
        Twist::new(rho.x, rho.y, rho.z, axis.x, axis.y, axis.z)
    }
}

/// How much a view with information `candidate` would add to `current`: the log of the
/// posterior volume's shrinkage, `log det(current + candidate) - log det(current)`
/// (D-optimal design; invariant to how rotation and translation are scaled).
pub fn information_gain(current: &Matrix6<f64>, candidate: &Matrix6<f64>) -> f64 {
    let logdet = |m: &Matrix6<f64>| {
        m.cholesky()
            .map(|c| 2.0 * c.l().diagonal().iter().map(|v| v.ln()).sum::<f64>())
    };
    match (logdet(current), logdet(&(current + candidate))) {
        (Some(a), Some(b)) => b - a,
        _ => 0.0,
    }
}

/// Scores every pool entry (robot poses; pass meshes decimated with `opts.cell_m` — coarse
/// masks need no detail) and returns `(index into pool, score)` of the best, or `None` for
/// an empty pool. Scoring is at `opts.downsample` resolution.
pub fn choose_next(
    renderer: &dyn SilhouetteRenderer,
    camera: &Camera,
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

/// How `easyhec solve` picks views from a recorded run (formats.md).
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
    renderer: &dyn SilhouetteRenderer,
    camera: &Camera,
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
    fn doubling_the_information_halves_each_variance() {
        let current = Matrix6::from_diagonal(&Twist::new(4.0, 1.0, 9.0, 2.0, 3.0, 5.0));
        assert!(information_gain(&current, &Matrix6::zeros()).abs() < 1e-12);
        let g = information_gain(&current, &current);
        assert!((g - 6.0 * 2f64.ln()).abs() < 1e-9, "{g}");
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
            let xi = joint_twist_in_camera(m, &camera_from_base);
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
    fn joint_errors_take_information_away_and_only_away() {
        let urdf = concat!(env!("CARGO_MANIFEST_DIR"), "/robots/xarm6/robot.urdf");
        let robot = RobotModel::from_urdf(urdf).unwrap();
        let q = [0.3, -0.4, -0.5, 0.2, 0.9, 0.1];
        let posed = PosedRobot::new(&robot, &q).decimated(0.01);
        let camera = Camera::pinhole(160, 120, 150.0, 150.0, 80.0, 60.0);
        let estimate = look_at_camera_from_base(
            &Vector3::new(1.3, 0.5, 0.8),
            &Vector3::new(0.1, 0.0, 0.3),
            &Vector3::z(),
        );
        let motions = robot.joint_motions(&q);
        let info =
            |noise| view_information(&camera, 600.0, &posed, &motions, &estimate, 0.3, noise);
        let exact = info(0.0);
        let noisy = info(0.0005);
        // Exact joints: one view pins all six degrees of freedom.
        assert!(exact.cholesky().is_some());
        // Marginalising joint errors removes a positive semi-definite part…
        let removed = (exact - noisy).symmetric_eigen();
        let largest = exact.symmetric_eigen().eigenvalues.max();
        assert!(
            removed.eigenvalues.min() > -1e-9 * largest,
            "{:?}",
            removed.eigenvalues
        );
        // …and a real one: camera rotations a joint error can fake lose most of their weight.
        let lost = 1.0 - noisy.determinant() / exact.determinant();
        assert!(lost > 0.5, "determinant lost only {lost}");
        // Larger joint errors take more.
        assert!(info(0.002).determinant() < noisy.determinant());
    }
}

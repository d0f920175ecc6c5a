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

use nalgebra::{Isometry3, Matrix6, Vector3};
use rayon::prelude::*;

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::geometry::{exp_se3, skew, Twist};
use crate::mask::{Mask, SignedDistance};
use crate::objective::{loss_gradient, mask_loss};
use crate::render::{PosedRobot, SilhouetteRenderer};

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
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
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
        match s {
            "lm" => Ok(Optimizer::Lm),
            "adam" => Ok(Optimizer::Adam),
            other => Err(format!("unknown optimizer '{other}': use lm or adam")),
        }
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
    /// Cauchy scale of the boundary residual, pixels of the level's image (LM).
    pub robust_scale_px: f64,
    /// Outline sample spacing, pixels.
    pub boundary_step_px: f64,
    /// Adam steps.
    pub adam_steps: usize,
    /// Adam learning rate (rad and m per step).
    pub adam_learning_rate: f64,
    /// Inflation of the covariance for the correlation of neighbouring outline samples
    /// (pixels of outline per independent observation).
    pub correlation_length_px: f64,
    /// Below this mean IoU the LM result triggers a wide coarse search and a second solve.
    pub recover_below_iou: f64,
    /// Seed of the coarse search.
    pub search_seed: u64,
}

impl Default for SolveOptions {
    fn default() -> Self {
        SolveOptions {
            optimizer: Optimizer::Lm,
            pyramid: vec![8, 4, 2, 1],
            max_iterations_per_level: 25,
            robust_scale_px: 2.0,
            boundary_step_px: 1.0,
            adam_steps: 1000,
            adam_learning_rate: 3e-3,
            correlation_length_px: 4.0,
            recover_below_iou: 0.8,
            search_seed: 0,
        }
    }
}

/// 1-sigma uncertainty about the camera axes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Uncertainty {
    /// Rotation about camera x, y, z, degrees.
    pub rotation_deg: [f64; 3],
    /// Translation of `camera_from_base` along camera x, y, z, millimetres.
    pub translation_mm: [f64; 3],
}

/// What a solve found.
#[derive(Clone, Debug)]
pub struct SolveReport {
    /// The estimate.
    pub camera_from_base: Isometry3<f64>,
    /// 6x6 covariance of the left increment `(rho, phi)` at the estimate.
    pub covariance: Matrix6<f64>,
    /// 1-sigma uncertainty derived from `covariance`.
    pub uncertainty: Uncertainty,
    /// Mask IoU per view at the estimate (full resolution).
    pub per_view_iou: Vec<f64>,
    /// The paper's mask loss at the estimate.
    pub loss: f64,
    /// Renders performed (each covers all views).
    pub iterations: usize,
    /// Accepted iterates, first to last (exploration's "trajectory" candidates).
    pub trajectory: Vec<Isometry3<f64>>,
}

struct Level {
    camera: Camera,
    sdf: Vec<SignedDistance>,
}

struct Normal {
    cost: f64,
    h: Matrix6<f64>,
    g: Twist,
    weighted_sq: f64,
    length: f64,
}

fn accumulate(
    renderer: &dyn SilhouetteRenderer,
    views: &[View],
    level: &Level,
    pose: &Isometry3<f64>,
    opts: &SolveOptions,
) -> Normal {
    let parts: Vec<Normal> = views
        .par_iter()
        .zip(&level.sdf)
        .map(|(view, sdf)| {
            let sil = renderer.render(
                &view.robot,
                &level.camera,
                pose,
                Some(opts.boundary_step_px),
            );
            let c = opts.robust_scale_px;
            let mut n = Normal {
                cost: 0.0,
                h: Matrix6::zeros(),
                g: Twist::zeros(),
                weighted_sq: 0.0,
                length: 0.0,
            };
            for s in &sil.boundary {
                let Some((r, grad)) = sdf.sample(s.pixel[0], s.pixel[1]) else {
                    continue;
                };
                let jp = s.pixel_jacobian(&level.camera);
                let j = (jp.row(0) * grad[0] + jp.row(1) * grad[1]).transpose();
                let u = (r / c) * (r / c);
                let w = 1.0 / (1.0 + u);
                let ds = s.length_px;
                n.cost += ds * 0.5 * c * c * (1.0 + u).ln();
                n.h += j * j.transpose() * (w * ds);
                n.g += j * (w * r * ds);
                n.weighted_sq += w * r * r * ds;
                n.length += ds;
            }
            n
        })
        .collect();
    let mut total = Normal {
        cost: 0.0,
        h: Matrix6::zeros(),
        g: Twist::zeros(),
        weighted_sq: 0.0,
        length: 0.0,
    };
    for p in parts {
        total.cost += p.cost;
        total.h += p.h;
        total.g += p.g;
        total.weighted_sq += p.weighted_sq;
        total.length += p.length;
    }
    total
}

fn mean_cost(n: &Normal) -> f64 {
    if n.length > 0.0 {
        n.cost / n.length
    } else {
        f64::INFINITY
    }
}

/// Solves for `camera_from_base` from `views`, starting at `initial`.
pub fn solve(
    renderer: &dyn SilhouetteRenderer,
    camera: &Camera,
    views: &[View],
    initial: &Isometry3<f64>,
    opts: &SolveOptions,
) -> Result<SolveReport> {
    if views.is_empty() {
        return Err(Error::Solve("no views to solve from".into()));
    }
    let camera = camera.undistorted();
    let (pose, iterations, trajectory) = match opts.optimizer {
        Optimizer::Lm => solve_lm(renderer, &camera, views, initial, opts)?,
        Optimizer::Adam => solve_adam(renderer, &camera, views, initial, opts),
    };
    let report = finish(renderer, &camera, views, pose, iterations, trajectory, opts)?;
    if opts.optimizer == Optimizer::Adam || mean(&report.per_view_iou) >= opts.recover_below_iou {
        return Ok(report);
    }
    // The fast path landed in a poor local minimum (or the guess was rough): search a wide
    // neighbourhood of the guess at low resolution, then refine from the best candidate.
    let start = coarse_search(renderer, &camera, views, initial, opts);
    let (pose, more, trajectory) = solve_lm(renderer, &camera, views, &start, opts)?;
    let retry = finish(
        renderer,
        &camera,
        views,
        pose,
        iterations + more,
        trajectory,
        opts,
    )?;
    Ok(if mean(&retry.per_view_iou) > mean(&report.per_view_iou) {
        retry
    } else {
        report
    })
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// Cross-entropy search over left increments of `initial`, maximising the mean mask IoU of up
/// to four views at 1/8 resolution with decimated meshes.
pub fn coarse_search(
    renderer: &dyn SilhouetteRenderer,
    camera: &Camera,
    views: &[View],
    initial: &Isometry3<f64>,
    opts: &SolveOptions,
) -> Isometry3<f64> {
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    let factor = 8;
    let level = camera.downsampled(factor);
    let step = views.len().div_ceil(4).max(1);
    let subset: Vec<(PosedRobot, Mask)> = views
        .par_iter()
        .step_by(step)
        .map(|v| (v.robot.decimated(0.004), v.observed.downsample(factor)))
        .collect();
    let score = |pose: &Isometry3<f64>| -> f64 {
        subset
            .iter()
            .map(|(r, m)| renderer.render(r, &level, pose, None).mask.iou(m))
            .sum::<f64>()
            / subset.len() as f64
    };
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(opts.search_seed);
    let mut best = (score(initial), *initial);
    let mut sigma = Twist::new(0.12, 0.12, 0.12, 0.2, 0.2, 0.2);
    for _round in 0..12 {
        let centre = best.1;
        let samples: Vec<Twist> = (0..128)
            .map(|_| {
                Twist::from_fn(|k, _| {
                    Normal::new(0.0, sigma[k])
                        .map(|n| n.sample(&mut rng))
                        .unwrap_or(0.0)
                })
            })
            .collect();
        let mut scored: Vec<(f64, Twist)> = samples
            .par_iter()
            .map(|xi| (score(&(exp_se3(xi) * centre)), *xi))
            .collect();
        scored.sort_by(|a, b| b.0.total_cmp(&a.0));
        let elite = &scored[..12];
        if elite[0].0 > best.0 {
            best = (elite[0].0, exp_se3(&elite[0].1) * centre);
        }
        let mean_xi = elite.iter().fold(Twist::zeros(), |a, e| a + e.1) / elite.len() as f64;
        let spread = elite.iter().fold(Twist::zeros(), |a, e| {
            a + (e.1 - mean_xi).component_mul(&(e.1 - mean_xi))
        }) / elite.len() as f64;
        sigma = spread
            .map(|v| v.sqrt())
            .zip_map(&sigma, |s, old| s.clamp(0.5 * old, old).max(2e-3));
    }
    best.1
}

fn solve_lm(
    renderer: &dyn SilhouetteRenderer,
    camera: &Camera,
    views: &[View],
    initial: &Isometry3<f64>,
    opts: &SolveOptions,
) -> Result<(Isometry3<f64>, usize, Vec<Isometry3<f64>>)> {
    let mut pose = *initial;
    let mut iterations = 0;
    let mut trajectory = vec![pose];
    for &factor in &opts.pyramid {
        let level = Level {
            camera: camera.downsampled(factor),
            sdf: views
                .par_iter()
                .map(|v| SignedDistance::of(&v.observed.downsample(factor)))
                .collect(),
        };
        let mut current = accumulate(renderer, views, &level, &pose, opts);
        iterations += 1;
        if current.length == 0.0 {
            return Err(Error::Solve(
                "the robot is not visible from the initial guess in any view: check initial_guess.camera_from_base (direction and units)".into(),
            ));
        }
        let mut lambda = 1e-4;
        for _ in 0..opts.max_iterations_per_level {
            let mut a = current.h;
            for k in 0..6 {
                a[(k, k)] += lambda * current.h[(k, k)].max(1e-12);
            }
            let Some(step) = a.cholesky().map(|c| -c.solve(&current.g)) else {
                lambda *= 10.0;
                continue;
            };
            let candidate = exp_se3(&step) * pose;
            let next = accumulate(renderer, views, &level, &candidate, opts);
            iterations += 1;
            if next.length > 0.0 && mean_cost(&next) <= mean_cost(&current) {
                pose = candidate;
                current = next;
                trajectory.push(pose);
                lambda = (lambda / 3.0).max(1e-7);
                let rot = step.fixed_rows::<3>(3).norm();
                let trans = step.fixed_rows::<3>(0).norm();
                if rot < 2e-6 && trans < 2e-6 {
                    break;
                }
            } else {
                lambda *= 4.0;
                if lambda > 1e4 {
                    break;
                }
            }
        }
        if std::env::var_os("EASYHEC_DEBUG").is_some() {
            let iou: f64 = views
                .iter()
                .map(|v| {
                    renderer
                        .render(&v.robot, &level.camera, &pose, None)
                        .mask
                        .iou(&v.observed.downsample(factor))
                })
                .sum::<f64>()
                / views.len() as f64;
            eprintln!(
                "level {factor}: mean cost {:.3} length {:.0} iou {iou:.3} lambda {lambda:.1e}",
                mean_cost(&current),
                current.length
            );
        }
    }
    Ok((pose, iterations, trajectory))
}

fn solve_adam(
    renderer: &dyn SilhouetteRenderer,
    camera: &Camera,
    views: &[View],
    initial: &Isometry3<f64>,
    opts: &SolveOptions,
) -> (Isometry3<f64>, usize, Vec<Isometry3<f64>>) {
    let (b1, b2, eps) = (0.9, 0.999, 1e-8);
    let mut pose = *initial;
    let mut m = Twist::zeros();
    let mut v = Twist::zeros();
    let mut best = (f64::INFINITY, pose);
    let mut trajectory = Vec::with_capacity(opts.adam_steps);
    for t in 1..=opts.adam_steps {
        let (loss, grad) = views
            .par_iter()
            .map(|view| {
                let sil = renderer.render(&view.robot, camera, &pose, Some(opts.boundary_step_px));
                (
                    mask_loss(&sil.mask, &view.observed),
                    loss_gradient(&sil, &view.observed, camera),
                )
            })
            .reduce(|| (0.0, Twist::zeros()), |a, b| (a.0 + b.0, a.1 + b.1));
        let n = views.len() as f64;
        let (loss, grad) = (loss / n, grad / n);
        if loss < best.0 {
            best = (loss, pose);
        }
        trajectory.push(pose);
        m = m * b1 + grad * (1.0 - b1);
        v = v * b2 + grad.component_mul(&grad) * (1.0 - b2);
        let mh = m / (1.0 - b1.powi(t as i32));
        let vh = v / (1.0 - b2.powi(t as i32));
        let step = mh.zip_map(&vh, |a, b| -opts.adam_learning_rate * a / (b.sqrt() + eps));
        pose = exp_se3(&step) * pose;
    }
    (best.1, opts.adam_steps, trajectory)
}

fn finish(
    renderer: &dyn SilhouetteRenderer,
    camera: &Camera,
    views: &[View],
    pose: Isometry3<f64>,
    iterations: usize,
    trajectory: Vec<Isometry3<f64>>,
    opts: &SolveOptions,
) -> Result<SolveReport> {
    let level = Level {
        camera: camera.clone(),
        sdf: views
            .par_iter()
            .map(|v| SignedDistance::of(&v.observed))
            .collect(),
    };
    let n = accumulate(renderer, views, &level, &pose, opts);
    let dof = (n.length / opts.correlation_length_px - 6.0).max(1.0);
    let sigma2 = n.weighted_sq / opts.correlation_length_px / dof;
    let covariance = match n.h.try_inverse() {
        Some(inv) => inv * sigma2 * opts.correlation_length_px,
        None => Matrix6::from_diagonal_element(f64::INFINITY),
    };
    let uncertainty = uncertainty_of(&covariance, &pose);
    let renders: Vec<(f64, f64)> = views
        .par_iter()
        .map(|v| {
            let m = renderer.render(&v.robot, camera, &pose, None).mask;
            (m.iou(&v.observed), mask_loss(&m, &v.observed))
        })
        .collect();
    let loss = renders.iter().map(|r| r.1).sum::<f64>() / views.len() as f64;
    Ok(SolveReport {
        camera_from_base: pose,
        covariance,
        uncertainty,
        per_view_iou: renders.iter().map(|r| r.0).collect(),
        loss,
        iterations,
        trajectory,
    })
}

/// 1-sigma rotation (about camera axes) and translation of `camera_from_base`'s translation
/// part, from the covariance of the left increment. Under `exp(xi) * T` the translation moves
/// by `rho + phi x t`, hence `A = [I, -[t]x]`.
pub fn uncertainty_of(covariance: &Matrix6<f64>, camera_from_base: &Isometry3<f64>) -> Uncertainty {
    let t: Vector3<f64> = camera_from_base.translation.vector;
    let mut a = nalgebra::Matrix3x6::zeros();
    a.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&nalgebra::Matrix3::identity());
    a.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-skew(&t)));
    let ct = a * covariance * a.transpose();
    Uncertainty {
        rotation_deg: [0, 1, 2].map(|k| covariance[(3 + k, 3 + k)].max(0.0).sqrt().to_degrees()),
        translation_mm: [0, 1, 2].map(|k| ct[(k, k)].max(0.0).sqrt() * 1000.0),
    }
}

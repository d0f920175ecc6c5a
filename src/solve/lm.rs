//! Levenberg–Marquardt, coarse to fine over the image pyramid (the default optimiser).

use nalgebra::Isometry3;
use rayon::prelude::*;

use super::boundary::{accumulate, total_cost, Level};
use super::{SolveOptions, View};
use crate::camera::Intrinsics;
use crate::error::{Error, Result};
use crate::geometry::exp_se3;
use crate::render::{PosedRobot, SilhouetteRenderer};

/// Runs LM on the boundary residuals at each pyramid level in turn: the pose, the renders
/// performed and the accepted iterates.
pub(super) fn solve_lm(
    renderer: &dyn SilhouetteRenderer,
    camera: &Intrinsics,
    views: &[View],
    initial: &Isometry3<f64>,
    opts: &SolveOptions,
) -> Result<(Isometry3<f64>, usize, Vec<Isometry3<f64>>)> {
    let debug = tracing::enabled!(tracing::Level::DEBUG);
    let mut pose = *initial;
    let mut iterations = 0;
    let mut trajectory = vec![pose];
    for &factor in &opts.pyramid {
        let started = std::time::Instant::now();
        let scale = if factor == 1 {
            opts.fine_robust_scale_px
        } else {
            opts.robust_scale_px
        };
        let level = Level::new(camera, views, factor, scale);
        // Coarse levels see the robot through big pixels: a mesh clustered to a fraction of a
        // pixel renders the same silhouette at a fraction of the cost.
        let cell_m = opts.coarse_cell_fraction * f64::from(factor) / camera.fx.max(camera.fy);
        let decimated: Vec<PosedRobot> = if factor > 1 && cell_m > 1e-3 {
            views
                .par_iter()
                .map(|v| v.robot.decimated(cell_m))
                .collect()
        } else {
            Vec::new()
        };
        let level_views: Vec<&PosedRobot> = if decimated.is_empty() {
            views.iter().map(|v| &v.robot).collect()
        } else {
            decimated.iter().collect()
        };
        let mut current = accumulate(renderer, &level_views, &level, &pose, opts);
        iterations += 1;
        if current.length == 0.0 {
            return Err(Error::Solve(
                "the robot is not visible from the initial guess in any view: check initial_guess.camera_from_base (direction and units)".into(),
            ));
        }
        let mut lambda = 1e-4;
        let mut level_iterations = 0;
        // Steps below ~1/100 pixel of the level are noise.
        let tolerance = 1e-5 * f64::from(factor);
        // Coarse levels only have to land in the next level's basin; at the finest, the
        // posterior refinement ([`refine`]) finishes what LM's rough end-game would grind on.
        // Fine levels get a render budget of ~40 view-renders (8 iterations at 5 views).
        let fine_cap = (40 / views.len().max(1))
            .max(8)
            .min(opts.max_iterations_per_level.max(1));
        let cap = if factor >= 4 {
            opts.max_iterations_per_level.min(10)
        } else {
            fine_cap
        };
        for _ in 0..cap {
            let mut a = current.h;
            for k in 0..6 {
                a[(k, k)] += lambda * current.h[(k, k)].max(1e-12);
            }
            let Some(step) = a.cholesky().map(|c| -c.solve(&current.g)) else {
                lambda *= 10.0;
                continue;
            };
            let candidate = exp_se3(&step) * pose;
            let next = accumulate(renderer, &level_views, &level, &candidate, opts);
            iterations += 1;
            level_iterations += 1;
            if next.length > 0.0 && total_cost(&next) <= total_cost(&current) {
                pose = candidate;
                current = next;
                trajectory.push(pose);
                lambda = (lambda / 3.0).max(1e-7);
                let rot = step.fixed_rows::<3>(3).norm();
                let trans = step.fixed_rows::<3>(0).norm();
                if rot < tolerance && trans < tolerance {
                    break;
                }
            } else {
                lambda *= 4.0;
                if lambda > 1e4 {
                    break;
                }
            }
        }
        if debug {
            tracing::debug!(
                "level {factor}: {level_iterations} iterations, {:.3} s, cost {:.1} over {:.0} px of outline",
                started.elapsed().as_secs_f64(),
                total_cost(&current),
                current.length
            );
        }
    }
    Ok((pose, iterations, trajectory))
}

//! Levenberg–Marquardt, coarse to fine over the image pyramid (the default optimiser).

use nalgebra::{Isometry3, SMatrix, SVector};
use rayon::prelude::*;

use super::boundary::{accumulate, total_cost, Level, Normal};
use super::{SolveOptions, View};
use crate::camera::Intrinsics;
use crate::error::{Error, Result};
use crate::geometry::{exp_se3, Twist};
use crate::render::{PosedRobot, SilhouetteRenderer};

/// Runs LM on the boundary residuals at each pyramid level in turn: the pose, the renders
/// performed and the accepted iterates.
pub(super) fn solve_lm(
    renderer: &dyn SilhouetteRenderer,
    camera: &Intrinsics,
    views: &[View],
    initial: &Isometry3<f64>,
    opts: &SolveOptions,
) -> Result<Walk> {
    let mut walk = Walk::at(initial);
    for &factor in &opts.pyramid {
        let level = Level::new(camera, views, factor, robust_scale_at(factor, opts));
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
        let cap = iteration_cap(factor, views.len(), opts);
        walk.level(renderer, &level, &level_views, factor, cap, opts, None)?;
    }
    Ok(walk)
}

/// The Cauchy scale at pyramid `factor`: wide at coarse levels, tight at full resolution.
pub(super) fn robust_scale_at(factor: u32, opts: &SolveOptions) -> f64 {
    if factor == 1 {
        opts.fine_robust_scale_px
    } else {
        opts.robust_scale_px
    }
}

/// LM iterations allowed at pyramid `factor` over `views` views.
pub(super) fn iteration_cap(factor: u32, views: usize, opts: &SolveOptions) -> usize {
    // Coarse levels only have to land in the next level's basin; at the finest, the
    // posterior refinement ([`super::refine`]) finishes what LM's rough end-game would grind
    // on. Fine levels get a render budget of ~40 view-renders (8 iterations at 5 views).
    if factor >= 4 {
        opts.max_iterations_per_level.min(10)
    } else {
        (40 / views.max(1))
            .max(8)
            .min(opts.max_iterations_per_level.max(1))
    }
}

/// An LM descent through the pyramid: where it stands, the renders it took, its iterates.
pub(super) struct Walk {
    pub(super) pose: Isometry3<f64>,
    /// How far the observed outline lies outward of the rendered one, full-resolution pixels
    /// (0 unless [`SolveOptions::estimate_mask_offset`]).
    pub(super) offset_px: f64,
    pub(super) iterations: usize,
    pub(super) trajectory: Vec<Isometry3<f64>>,
}

impl Walk {
    /// A walk that has not yet moved from `pose`.
    pub(super) fn at(pose: &Isometry3<f64>) -> Walk {
        Walk {
            pose: *pose,
            offset_px: 0.0,
            iterations: 0,
            trajectory: vec![*pose],
        }
    }

    /// At most `cap` LM iterations on `level`, whose observations belong to `robots`;
    /// `start`, when given, is the normal equations at the walk's pose (saving a render).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn level(
        &mut self,
        renderer: &dyn SilhouetteRenderer,
        level: &Level,
        robots: &[&PosedRobot],
        factor: u32,
        cap: usize,
        opts: &SolveOptions,
        start: Option<Normal>,
    ) -> Result<()> {
        let started = std::time::Instant::now();
        let mut current = match start {
            Some(normal) => normal,
            None => accumulate(renderer, robots, level, &self.pose, self.offset_px, opts),
        };
        self.iterations += 1;
        if current.length == 0.0 {
            return Err(Error::Solve(
                "the robot is not visible from the initial guess in any view: check initial_guess.camera_from_base (direction and units)".into(),
            ));
        }
        let mut lambda = 1e-4;
        let mut level_iterations = 0;
        // Steps below ~1/100 pixel of the level are noise.
        let tolerance = 1e-5 * f64::from(factor);
        for _ in 0..cap {
            let Some((step, offset_step)) =
                damped_step(&current, lambda, opts.estimate_mask_offset)
            else {
                lambda *= 10.0;
                continue;
            };
            let candidate = exp_se3(&step) * self.pose;
            let candidate_offset = self.offset_px + offset_step;
            let next = accumulate(renderer, robots, level, &candidate, candidate_offset, opts);
            self.iterations += 1;
            level_iterations += 1;
            if next.length > 0.0 && total_cost(&next) <= total_cost(&current) {
                self.pose = candidate;
                self.offset_px = candidate_offset;
                current = next;
                self.trajectory.push(self.pose);
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
        tracing::debug!(
            "level {factor}: {level_iterations} iterations, {:.3} s, cost {:.1} over {:.0} px of outline",
            started.elapsed().as_secs_f64(),
            total_cost(&current),
            current.length
        );
        Ok(())
    }
}

/// The damped Gauss–Newton step of the pose (and of the mask offset, when estimated).
fn damped_step(n: &Normal, lambda: f64, with_offset: bool) -> Option<(Twist, f64)> {
    if !with_offset {
        let mut a = n.h;
        for k in 0..6 {
            a[(k, k)] += lambda * n.h[(k, k)].max(1e-12);
        }
        return a.cholesky().map(|c| (-c.solve(&n.g), 0.0));
    }
    let mut a = SMatrix::<f64, 7, 7>::zeros();
    a.fixed_view_mut::<6, 6>(0, 0).copy_from(&n.h);
    a.fixed_view_mut::<6, 1>(0, 6).copy_from(&n.h_pose_offset);
    a.fixed_view_mut::<1, 6>(6, 0)
        .copy_from(&n.h_pose_offset.transpose());
    a[(6, 6)] = n.h_offset;
    for k in 0..7 {
        a[(k, k)] += lambda * a[(k, k)].max(1e-12);
    }
    let mut g = SVector::<f64, 7>::zeros();
    g.fixed_rows_mut::<6>(0).copy_from(&n.g);
    g[6] = n.g_offset;
    let step = -a.cholesky()?.solve(&g);
    Some((step.fixed_rows::<6>(0).into_owned(), step[6]))
}

//! Adam on the mask loss: the paper's optimiser, kept as the benchmark's baseline.

use nalgebra::Isometry3;
use rayon::prelude::*;

use super::{SolveOptions, View};
use crate::camera::Intrinsics;
use crate::geometry::{exp_se3, Twist};
use crate::objective::{loss_gradient, mask_loss};
use crate::render::SilhouetteRenderer;

/// `opts.adam_steps` full-resolution Adam steps; returns the best iterate (lowest loss), the
/// step count and every iterate.
pub(super) fn solve_adam(
    renderer: &dyn SilhouetteRenderer,
    camera: &Intrinsics,
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

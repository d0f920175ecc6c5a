//! The paper's objective and its exact gradient.
//!
//! `L = 1/(V P) * sum_views sum_pixels (R - M)^2` with hard masks (V views, P pixels each).
//! Its gradient with respect to a left se(3) increment is the boundary integral of
//! docs/method.md §3: `dL/dxi = 1/(V P) * sum ∮ (1 - 2 M(x)) n(x)·(dx/dxi) ds` — expanding into
//! background costs, expanding into observed robot pays. [`supersampled_loss`] is the
//! continuous-coverage version of the same loss that the gradient is checked against.

use nalgebra::Isometry3;

use crate::camera::Intrinsics;
use crate::geometry::Twist;
use crate::mask::Mask;
use crate::render::{render_coverage, PosedRobot, Silhouette};

/// Mean squared per-pixel error of two hard masks (the fraction of disagreeing pixels).
pub fn mask_loss(rendered: &Mask, observed: &Mask) -> f64 {
    let wrong = rendered
        .data
        .iter()
        .zip(&observed.data)
        .filter(|(a, b)| (**a != 0) != (**b != 0))
        .count();
    wrong as f64 / rendered.data.len() as f64
}

/// Boundary-integral gradient of [`mask_loss`] for one view (not divided by the view count).
pub fn loss_gradient(silhouette: &Silhouette, observed: &Mask, camera: &Intrinsics) -> Twist {
    let pixels = f64::from(camera.width) * f64::from(camera.height);
    let mut g = Twist::zeros();
    for s in &silhouette.boundary {
        let m = if observed.at(s.pixel[0], s.pixel[1]) {
            1.0
        } else {
            0.0
        };
        let j = s.pixel_jacobian(camera);
        let normal_velocity = j.row(0) * s.normal[0] + j.row(1) * s.normal[1];
        g += normal_velocity.transpose() * ((1.0 - 2.0 * m) * s.length_px);
    }
    g / pixels
}

/// The loss with the rendered silhouette's exact sub-pixel coverage (approximated by
/// `factor x factor` supersampling): `1/P * sum_p [cov_p (1 - 2 M_p) + M_p]`.
pub fn supersampled_loss(
    robot: &PosedRobot,
    camera: &Intrinsics,
    camera_from_base: &Isometry3<f64>,
    observed: &Mask,
    factor: u32,
) -> f64 {
    let cov = render_coverage(robot, camera, camera_from_base, factor);
    let total: f64 = cov
        .iter()
        .zip(&observed.data)
        .map(|(&c, &m)| {
            let m = f64::from(m);
            f64::from(c) * (1.0 - 2.0 * m) + m
        })
        .sum();
    total / cov.len() as f64
}

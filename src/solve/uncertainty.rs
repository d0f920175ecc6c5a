//! The summaries of a pose covariance users read: 1-sigma per camera axis, and one 95% bound
//! on the camera centre's position error.

use std::sync::OnceLock;

use nalgebra::{Isometry3, Matrix3, Matrix6, Vector3, Vector6};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};

use crate::camera::Intrinsics;
use crate::geometry::skew;
use crate::render::Silhouette;

/// 1-sigma uncertainty about the camera axes, and the 95% camera-centre bound.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Uncertainty {
    /// Rotation about camera x, y, z, degrees.
    pub rotation_deg: [f64; 3],
    /// Translation of `camera_from_base` along camera x, y, z, millimetres.
    pub translation_mm: [f64; 3],
    /// Radius (mm) of the ball around the estimated camera centre that holds the true centre
    /// with 95% probability under the covariance: one number to gate a task on.
    pub camera_centre_95_mm: f64,
    /// The covariance of the left increment `(rho, phi)` these figures summarise.
    pub covariance: Matrix6<f64>,
}

/// How far `covariance` (of the left increment of `camera_from_base`) predicts the outline of
/// `rendered` to move, pixels: twice the RMS, over the outline, of each sample's 1-sigma
/// displacement along its normal. A bump check allows this much outline distance for the
/// calibration's own uncertainty; negative variances along a sample (a covariance with terms
/// taken out) count as none.
pub fn predicted_outline_motion_px(
    rendered: &Silhouette,
    camera: &Intrinsics,
    covariance: &Matrix6<f64>,
) -> f64 {
    let (mut sum, mut length) = (0.0, 0.0);
    for s in &rendered.boundary {
        let jp = s.pixel_jacobian(camera);
        let j: Vector6<f64> = (jp.row(0) * s.normal[0] + jp.row(1) * s.normal[1]).transpose();
        sum += (j.transpose() * covariance * j)[(0, 0)].max(0.0) * s.length_px;
        length += s.length_px;
    }
    if length > 0.0 && sum.is_finite() {
        2.0 * (sum / length).sqrt()
    } else {
        0.0
    }
}

/// Covariance of the translation `camera_from_base` reports, from the covariance of its left
/// increment `(rho, phi)`: a left increment moves that translation by `rho - t x phi`.
pub fn translation_covariance(
    covariance: &Matrix6<f64>,
    camera_from_base: &Isometry3<f64>,
) -> Matrix3<f64> {
    let t: Vector3<f64> = camera_from_base.translation.vector;
    let mut a = nalgebra::Matrix3x6::zeros();
    a.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&Matrix3::identity());
    a.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-skew(&t)));
    a * covariance * a.transpose()
}

/// Covariance of the camera centre (base frame): the centre `-R^T t` moves by `-R^T rho` under
/// a left increment `(rho, phi)` of `camera_from_base`.
pub fn camera_centre_covariance(
    covariance: &Matrix6<f64>,
    camera_from_base: &Isometry3<f64>,
) -> Matrix3<f64> {
    let r = camera_from_base.rotation.to_rotation_matrix().into_inner();
    let rho = covariance.fixed_view::<3, 3>(0, 0).into_owned();
    r.transpose() * rho * r
}

/// Standard normal draws, fixed once: the 95% quantile of a Gaussian vector's length has no
/// closed form for unequal variances, and a fixed sample keeps the bound deterministic.
fn unit_draws() -> &'static [[f64; 3]] {
    static DRAWS: OnceLock<Vec<[f64; 3]>> = OnceLock::new();
    DRAWS.get_or_init(|| {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(95);
        (0..20_000)
            .map(|_| [0; 3].map(|_| StandardNormal.sample(&mut rng)))
            .collect()
    })
}

/// The 95% quantile of `|x|` for `x ~ N(0, c)`, in the units of `sqrt(c)`; infinite when `c`
/// is not a finite covariance.
pub fn norm_quantile_95(c: &Matrix3<f64>) -> f64 {
    if !c.iter().all(|v| v.is_finite()) {
        return f64::INFINITY;
    }
    let eig = c.symmetric_eigenvalues().map(|l| l.max(0.0));
    let mut sq: Vec<f64> = unit_draws()
        .iter()
        .map(|z| (0..3).map(|k| eig[k] * z[k] * z[k]).sum())
        .collect();
    let at = (sq.len() as f64 * 0.95) as usize;
    let (_, q, _) = sq.select_nth_unstable_by(at, f64::total_cmp);
    q.sqrt()
}

/// 1-sigma rotation (about camera axes) and translation of `camera_from_base`'s translation
/// part, from the covariance of the left increment (see [`translation_covariance`]), and the
/// 95% camera-centre bound.
pub fn uncertainty_of(covariance: &Matrix6<f64>, camera_from_base: &Isometry3<f64>) -> Uncertainty {
    let ct = translation_covariance(covariance, camera_from_base);
    let centre = camera_centre_covariance(covariance, camera_from_base);
    // An unpinned direction makes every figure infinite, never a NaN that prints as 0.
    let sigma = |variance: f64| {
        if variance.is_nan() {
            f64::INFINITY
        } else {
            variance.max(0.0).sqrt()
        }
    };
    Uncertainty {
        rotation_deg: [0, 1, 2].map(|k| sigma(covariance[(3 + k, 3 + k)]).to_degrees()),
        translation_mm: [0, 1, 2].map(|k| sigma(ct[(k, k)]) * 1000.0),
        camera_centre_95_mm: norm_quantile_95(&centre) * 1000.0,
        covariance: *covariance,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn norm_quantile_matches_the_one_and_three_dimensional_cases() {
        // One direction: |x| is a half-normal, 95% at 1.960 sigma.
        let one = norm_quantile_95(&Matrix3::from_diagonal(&Vector3::new(4.0, 0.0, 0.0)));
        assert!((one - 2.0 * 1.960).abs() < 0.05, "{one}");
        // Three equal directions: chi with 3 dof, 95% at sqrt(7.815) = 2.796.
        let three = norm_quantile_95(&Matrix3::identity());
        assert!((three - 2.796).abs() < 0.03, "{three}");
        assert!(norm_quantile_95(&Matrix3::from_element(f64::NAN)).is_infinite());
    }

    #[test]
    fn an_unpinned_covariance_reports_infinite_figures_not_zero() {
        let pose = Isometry3::new(Vector3::new(0.1, -0.2, 1.0), Vector3::new(0.3, 0.2, -0.1));
        let u = uncertainty_of(&Matrix6::from_diagonal_element(f64::INFINITY), &pose);
        assert!(u.rotation_deg.iter().all(|v| v.is_infinite()), "{u:?}");
        assert!(u.translation_mm.iter().all(|v| v.is_infinite()), "{u:?}");
        assert!(u.camera_centre_95_mm.is_infinite());
    }

    #[test]
    fn centre_moves_opposite_the_rotated_increment() {
        let pose = Isometry3::new(Vector3::new(0.1, -0.2, 1.0), Vector3::new(0.3, 0.2, -0.1));
        let mut cov = Matrix6::zeros();
        cov[(2, 2)] = 1e-6; // 1 mm along the camera's optical axis only
        let c = camera_centre_covariance(&cov, &pose);
        let axis = pose.rotation.inverse() * Vector3::z();
        assert!((c - axis * axis.transpose() * 1e-6).norm() < 1e-12);
    }
}

//! The 1-sigma summary of a pose covariance, about the camera axes.

use nalgebra::{Isometry3, Matrix6, Vector3};

use crate::geometry::skew;

/// 1-sigma uncertainty about the camera axes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Uncertainty {
    /// Rotation about camera x, y, z, degrees.
    pub rotation_deg: [f64; 3],
    /// Translation of `camera_from_base` along camera x, y, z, millimetres.
    pub translation_mm: [f64; 3],
}

/// Covariance of the translation `camera_from_base` reports, from the covariance of its left
/// increment `(rho, phi)`: a left increment moves that translation by `rho - t x phi`.
pub fn translation_covariance(
    covariance: &Matrix6<f64>,
    camera_from_base: &Isometry3<f64>,
) -> nalgebra::Matrix3<f64> {
    let t: Vector3<f64> = camera_from_base.translation.vector;
    let mut a = nalgebra::Matrix3x6::zeros();
    a.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&nalgebra::Matrix3::identity());
    a.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-skew(&t)));
    a * covariance * a.transpose()
}

/// 1-sigma rotation (about camera axes) and translation of `camera_from_base`'s translation
/// part, from the covariance of the left increment (see [`translation_covariance`]).
pub fn uncertainty_of(covariance: &Matrix6<f64>, camera_from_base: &Isometry3<f64>) -> Uncertainty {
    let ct = translation_covariance(covariance, camera_from_base);
    Uncertainty {
        rotation_deg: [0, 1, 2].map(|k| covariance[(3 + k, 3 + k)].max(0.0).sqrt().to_degrees()),
        translation_mm: [0, 1, 2].map(|k| ct[(k, k)].max(0.0).sqrt() * 1000.0),
    }
}

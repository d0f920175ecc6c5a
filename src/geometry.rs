//! Rigid-transform helpers: se(3) exponential, pose errors, matrix I/O.
//!
//! Convention: a local increment `xi = (rho, phi)` (translation first, rotation second) is
//! applied on the left, in the camera frame: `camera_from_base <- exp(xi) * camera_from_base`.
//! Left-multiplication keeps the increment "about the camera axes", which is also the frame the
//! reported uncertainty is expressed in.

use nalgebra::{
    Isometry3, Matrix3, Matrix4, Rotation3, Translation3, UnitQuaternion, Vector3, Vector6,
};

/// A 6-vector `(rho_x, rho_y, rho_z, phi_x, phi_y, phi_z)` in se(3).
pub type Twist = Vector6<f64>;

/// Skew-symmetric matrix so that `skew(a) * b == a.cross(&b)`.
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Exponential map of se(3) (closed form, exact for any angle).
pub fn exp_se3(xi: &Twist) -> Isometry3<f64> {
    let rho = Vector3::new(xi[0], xi[1], xi[2]);
    let phi = Vector3::new(xi[3], xi[4], xi[5]);
    let theta = phi.norm();
    let rotation = UnitQuaternion::from_scaled_axis(phi);
    let w = skew(&phi);
    let v = if theta < 1e-9 {
        Matrix3::identity() + 0.5 * w
    } else {
        let t2 = theta * theta;
        Matrix3::identity()
            + (1.0 - theta.cos()) / t2 * w
            + (theta - theta.sin()) / (t2 * theta) * w * w
    };
    Isometry3::from_parts(Translation3::from(v * rho), rotation)
}

/// Logarithm of SE(3), inverse of [`exp_se3`].
pub fn log_se3(pose: &Isometry3<f64>) -> Twist {
    let phi = pose.rotation.scaled_axis();
    let theta = phi.norm();
    let w = skew(&phi);
    let v_inv = if theta < 1e-9 {
        Matrix3::identity() - 0.5 * w
    } else {
        let half = 0.5 * theta;
        Matrix3::identity() - 0.5 * w
            + (1.0 - half * half.cos() / half.sin()) / (theta * theta) * w * w
    };
    let rho = v_inv * pose.translation.vector;
    Twist::new(rho.x, rho.y, rho.z, phi.x, phi.y, phi.z)
}

/// Geodesic rotation angle between two poses, degrees (docs/method.md §7).
pub fn rotation_error_deg(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    a.rotation.angle_to(&b.rotation).to_degrees()
}

/// Norm of the difference of the translation parts, millimetres (docs/method.md §7).
pub fn translation_error_mm(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    (a.translation.vector - b.translation.vector).norm() * 1000.0
}

/// Distance between the camera centres (`-R^T t`) of two `camera_from_base` poses, mm.
pub fn camera_centre_error_mm(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    let ca = a.inverse().translation.vector;
    let cb = b.inverse().translation.vector;
    (ca - cb).norm() * 1000.0
}

/// Row-major 4x4 rows, as the run and result formats store them.
pub fn to_rows(pose: &Isometry3<f64>) -> [[f64; 4]; 4] {
    let m = pose.to_homogeneous();
    let mut rows = [[0.0; 4]; 4];
    for (r, row) in rows.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = m[(r, c)];
        }
    }
    rows
}

/// Largest translation a transform read from a file may hold, metres per axis. Far beyond any
/// robot cell, and small enough that inverting and chaining such transforms stays finite (a
/// finite 1e308 would turn into infinity in an export).
pub const MAX_TRANSLATION_M: f64 = 1000.0;

/// Why translation `t` cannot be used, if it cannot: every entry within
/// [`MAX_TRANSLATION_M`].
pub fn translation_problem(t: &[f64; 3]) -> Option<String> {
    point_problem("translation", t)
}

/// Why point `p` (named `name` in the message) cannot be used, if it cannot: every entry
/// within [`MAX_TRANSLATION_M`] of the origin.
pub fn point_problem(name: &str, p: &[f64; 3]) -> Option<String> {
    p.iter().position(|v| v.abs() > MAX_TRANSLATION_M).map(|k| {
        format!(
            "{name}[{k}] = {} m; allowed: -{MAX_TRANSLATION_M} to {MAX_TRANSLATION_M} m",
            p[k]
        )
    })
}

/// Parses a row-major 4x4 into a rigid transform, re-orthonormalising the rotation.
///
/// Errors name what is wrong so the caller can point at the file and field.
pub fn from_rows(rows: &[[f64; 4]; 4]) -> Result<Isometry3<f64>, String> {
    let m = Matrix4::from_fn(|r, c| rows[r][c]);
    if m.iter().any(|v| !v.is_finite()) {
        return Err("matrix has a non-finite entry".into());
    }
    if let Some(problem) = translation_problem(&[m[(0, 3)], m[(1, 3)], m[(2, 3)]]) {
        return Err(problem);
    }
    if (m[(3, 0)].abs() + m[(3, 1)].abs() + m[(3, 2)].abs() + (m[(3, 3)] - 1.0).abs()) > 1e-6 {
        return Err("last row must be [0, 0, 0, 1]".into());
    }
    let r = m.fixed_view::<3, 3>(0, 0).into_owned();
    let orthogonality = (r.transpose() * r - Matrix3::identity()).abs().max();
    if orthogonality > 1e-3 || r.determinant() < 0.0 {
        return Err(format!(
            "upper-left 3x3 is not a rotation (|R^T R - I| = {orthogonality:.2e}, det = {:.3})",
            r.determinant()
        ));
    }
    Ok(rigid_from_rows(rows))
}

/// The rigid transform nearest to row-major `rows`, with no checks: for rows a caller built
/// itself from a pose (a result about to be written), where a check could only fail on a
/// pose the solver produced and must not panic over.
pub fn rigid_from_rows(rows: &[[f64; 4]; 4]) -> Isometry3<f64> {
    let r = Matrix3::from_fn(|i, j| rows[i][j]);
    // Bounded iterations: a non-finite matrix never converges.
    let nearest = Rotation3::from_matrix_eps(&r, 1e-12, 100, Rotation3::identity());
    let rotation = UnitQuaternion::from_rotation_matrix(&nearest);
    let t = Vector3::new(rows[0][3], rows[1][3], rows[2][3]);
    Isometry3::from_parts(Translation3::from(t), rotation)
}

/// URDF `<origin xyz rpy>` (fixed-axis roll, pitch, yaw) to a transform.
pub fn from_xyz_rpy(xyz: [f64; 3], rpy: [f64; 3]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(xyz[0], xyz[1], xyz[2]),
        UnitQuaternion::from_euler_angles(rpy[0], rpy[1], rpy[2]),
    )
}

/// A camera looking from `eye` at `target`, as `camera_from_base` in the OpenCV optical frame
/// (z forward, y down). `up` is the base-frame direction that should appear upwards.
pub fn look_at_camera_from_base(
    eye: &Vector3<f64>,
    target: &Vector3<f64>,
    up: &Vector3<f64>,
) -> Isometry3<f64> {
    let z = (target - eye).normalize();
    let mut x = z.cross(up);
    if x.norm() < 1e-9 {
        x = z.cross(&Vector3::x());
    }
    let x = x.normalize();
    let y = z.cross(&x);
    // base_from_camera has columns x, y, z.
    let r = Matrix3::from_columns(&[x, y, z]);
    let base_from_camera = Isometry3::from_parts(
        Translation3::from(*eye),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)),
    );
    base_from_camera.inverse()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_log_round_trip() {
        let xi = Twist::new(0.1, -0.2, 0.3, 0.4, -0.5, 0.6);
        let back = log_se3(&exp_se3(&xi));
        assert!((back - xi).norm() < 1e-12, "{back:?}");
        let small = Twist::new(1e-3, 0.0, 0.0, 1e-12, 0.0, 0.0);
        assert!((log_se3(&exp_se3(&small)) - small).norm() < 1e-12);
    }

    #[test]
    fn rows_round_trip_and_rejects_bad_rotation() {
        let p = exp_se3(&Twist::new(0.5, 0.1, 1.2, 0.3, 0.2, -1.0));
        let q = from_rows(&to_rows(&p)).unwrap();
        assert!(rotation_error_deg(&p, &q) < 1e-9 && translation_error_mm(&p, &q) < 1e-9);
        let mut rows = to_rows(&p);
        rows[0][0] = 3.0;
        assert!(from_rows(&rows).unwrap_err().contains("not a rotation"));
    }

    #[test]
    fn look_at_puts_target_on_optical_axis() {
        let eye = Vector3::new(1.5, 0.3, 0.8);
        let target = Vector3::new(0.0, 0.0, 0.3);
        let c = look_at_camera_from_base(&eye, &target, &Vector3::z());
        let p = c * nalgebra::Point3::from(target);
        assert!(p.x.abs() < 1e-12 && p.y.abs() < 1e-12 && p.z > 0.0);
        // Base "up" maps to image "up" (negative y).
        let up = c * nalgebra::Point3::from(target + Vector3::z() * 0.1);
        assert!(up.y < 0.0);
    }
}

//! The camera model on the solver's side: lens warps of masks for the one intrinsics type,
//! [`Intrinsics`] (defined with the drivers, which report it).
//!
//! Distortion is handled once, up front: an observed mask from a distorted camera is resampled
//! into the ideal pinhole image with the same `fx fy cx cy` ([`LensWarp::undistort_mask`]), and
//! everything downstream (rendering, gradients, exploration) works in that pinhole image.
//! Rendering straight-edged triangles stays exact, and a distorted run then solves exactly as an
//! undistorted one (tested in `tests/solve_cli.rs`). Pinhole pixels whose ray falls outside the
//! distorted image (pincushion corners) repeat the image border.

pub use easyhec_drivers::Intrinsics;

use crate::mask::Mask;

/// Mask warps through a camera's lens (they need the library's [`Mask`], so they live here
/// rather than on [`Intrinsics`] itself).
pub trait LensWarp {
    /// Resamples a mask taken through this (distorted) camera into the ideal pinhole image with
    /// the same intrinsics: each pinhole pixel looks up where its ray lands in the distorted
    /// image and takes the bilinearly interpolated value there (>= 0.5 is robot; rays past
    /// the edge repeat the border).
    fn undistort_mask(&self, distorted: &Mask) -> Mask;

    /// Warps an ideal pinhole mask into this camera's distorted image (the inverse of
    /// [`LensWarp::undistort_mask`]; the simulator uses it to fake a real lens).
    fn distort_mask(&self, pinhole: &Mask) -> Mask;
}

impl LensWarp for Intrinsics {
    fn undistort_mask(&self, distorted: &Mask) -> Mask {
        if !self.is_distorted() {
            return distorted.clone();
        }
        let mut out = Mask::new(self.width, self.height);
        for v in 0..self.height {
            for u in 0..self.width {
                let xn = (f64::from(u) - self.cx) / self.fx;
                let yn = (f64::from(v) - self.cy) / self.fy;
                let (xd, yd) = self.distort_normalized(xn, yn);
                let value = distorted
                    .sample_bilinear_clamped(self.fx * xd + self.cx, self.fy * yd + self.cy);
                out.set(u, v, value >= 0.5);
            }
        }
        out
    }

    fn distort_mask(&self, pinhole: &Mask) -> Mask {
        if !self.is_distorted() {
            return pinhole.clone();
        }
        let mut out = Mask::new(self.width, self.height);
        for v in 0..self.height {
            for u in 0..self.width {
                let xd = (f64::from(u) - self.cx) / self.fx;
                let yd = (f64::from(v) - self.cy) / self.fy;
                let (x, y) = self.undistort_normalized(xd, yd);
                let value = pinhole.sample_bilinear(self.fx * x + self.cx, self.fy * y + self.cy);
                out.set(u, v, value >= 0.5);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    #[test]
    fn undistort_inverts_distort() {
        let mut c = Intrinsics::pinhole(640, 480, 600.0, 600.0, 320.0, 240.0);
        c.distortion = Some([-0.28, 0.09, 0.001, -0.0005, -0.01]);
        for &(x, y) in &[(0.0, 0.0), (0.3, -0.2), (-0.45, 0.35)] {
            let (xd, yd) = c.distort_normalized(x, y);
            let (xu, yu) = c.undistort_normalized(xd, yd);
            assert!(
                (xu - x).abs() < 1e-9 && (yu - y).abs() < 1e-9,
                "{x},{y} -> {xu},{yu}"
            );
        }
    }

    #[test]
    fn pincushion_corners_repeat_the_border_instead_of_inventing_background() {
        let mut c = Intrinsics::pinhole(64, 48, 40.0, 40.0, 31.5, 23.5);
        c.distortion = Some([0.3, 0.1, 0.0, 0.0, 0.0]);
        // Robot fills the whole distorted frame: the undistorted mask must too.
        let full = Mask {
            width: 64,
            height: 48,
            data: vec![1; 64 * 48],
        };
        assert_eq!(c.undistort_mask(&full).count(), 64 * 48);
        // A robot-free frame stays robot-free.
        assert_eq!(c.undistort_mask(&Mask::new(64, 48)).count(), 0);
    }

    #[test]
    fn downsampled_keeps_pixel_centres() {
        let c = Intrinsics::pinhole(640, 480, 600.0, 600.0, 319.5, 239.5);
        let d = c.downsampled(2);
        // The image centre stays the image centre.
        assert!((d.cx - 159.5).abs() < 1e-12 && (d.cy - 119.5).abs() < 1e-12);
        let p = Point3::new(0.1, -0.05, 1.0);
        let (a, b) = (c.project(&p), d.project(&p));
        assert!(((a[0] + 0.5) / 2.0 - 0.5 - b[0]).abs() < 1e-12);
    }
}

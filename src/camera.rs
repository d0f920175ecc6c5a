//! Pinhole camera with ROS/OpenCV `plumb_bob` distortion.
//!
//! Distortion is handled once, up front: an observed mask from a distorted camera is resampled
//! into the ideal pinhole image with the same `fx fy cx cy` ([`Camera::undistort_mask`]), and
//! everything downstream (rendering, gradients, exploration) works in that pinhole image.
//! Rendering straight-edged triangles stays exact, and a distorted run then solves exactly as an
//! undistorted one (tested in `tests/solve_cli.rs`). Pinhole pixels whose ray falls outside the
//! distorted image (pincushion corners) repeat the image border.

use easyhec_drivers::Intrinsics;
use nalgebra::Point3;

use crate::mask::Mask;

/// Intrinsics in pixels; pixel centres sit at integer coordinates (OpenCV convention).
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Focal length x, pixels.
    pub fx: f64,
    /// Focal length y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// `plumb_bob` coefficients `k1 k2 p1 p2 k3`; `None` = ideal pinhole.
    pub distortion: Option<[f64; 5]>,
}

impl Camera {
    /// An ideal pinhole camera.
    pub fn pinhole(width: u32, height: u32, fx: f64, fy: f64, cx: f64, cy: f64) -> Camera {
        Camera {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            distortion: None,
        }
    }

    /// The camera a driver reports (drivers speak [`Intrinsics`], the solver [`Camera`]).
    pub fn from_intrinsics(i: &Intrinsics) -> Camera {
        Camera {
            width: i.width,
            height: i.height,
            fx: i.fx,
            fy: i.fy,
            cx: i.cx,
            cy: i.cy,
            distortion: i.distortion,
        }
    }

    /// As driver [`Intrinsics`].
    pub fn intrinsics(&self) -> Intrinsics {
        Intrinsics {
            width: self.width,
            height: self.height,
            fx: self.fx,
            fy: self.fy,
            cx: self.cx,
            cy: self.cy,
            distortion: self.distortion,
        }
    }

    /// Whether any distortion coefficient is non-zero.
    pub fn is_distorted(&self) -> bool {
        self.distortion.is_some_and(|d| d.iter().any(|&k| k != 0.0))
    }

    /// The same camera without distortion (the image the solver works in).
    pub fn undistorted(&self) -> Camera {
        Camera {
            distortion: None,
            ..self.clone()
        }
    }

    /// Intrinsics for an image downsampled by `factor` (an image-pyramid level). Pixel centres
    /// stay at integer coordinates: `c' = (c + 0.5) / f - 0.5`.
    pub fn downsampled(&self, factor: u32) -> Camera {
        let f = f64::from(factor);
        Camera {
            width: self.width.div_ceil(factor),
            height: self.height.div_ceil(factor),
            fx: self.fx / f,
            fy: self.fy / f,
            cx: (self.cx + 0.5) / f - 0.5,
            cy: (self.cy + 0.5) / f - 0.5,
            distortion: self.distortion,
        }
    }

    /// Pinhole projection of a camera-frame point (ignores distortion).
    #[inline]
    pub fn project(&self, p: &Point3<f64>) -> [f64; 2] {
        [self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy]
    }

    /// Applies distortion to normalised coordinates `(x/z, y/z)`.
    pub fn distort_normalized(&self, x: f64, y: f64) -> (f64, f64) {
        let Some([k1, k2, p1, p2, k3]) = self.distortion else {
            return (x, y);
        };
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        (
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        )
    }

    /// Inverts [`Camera::distort_normalized`] by fixed-point iteration (as OpenCV does).
    pub fn undistort_normalized(&self, xd: f64, yd: f64) -> (f64, f64) {
        if self.distortion.is_none() {
            return (xd, yd);
        }
        let (mut x, mut y) = (xd, yd);
        for _ in 0..20 {
            let (dx, dy) = self.distort_normalized(x, y);
            x += xd - dx;
            y += yd - dy;
        }
        (x, y)
    }

    /// Full projection of a camera-frame point including distortion.
    pub fn project_distorted(&self, p: &Point3<f64>) -> [f64; 2] {
        let (x, y) = self.distort_normalized(p.x / p.z, p.y / p.z);
        [self.fx * x + self.cx, self.fy * y + self.cy]
    }

    /// Resamples a mask taken through this (distorted) camera into the ideal pinhole image with
    /// the same intrinsics: each pinhole pixel looks up where its ray lands in the distorted
    /// image and takes the bilinearly interpolated value there (>= 0.5 is robot; rays past
    /// the edge repeat the border).
    pub fn undistort_mask(&self, distorted: &Mask) -> Mask {
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

    /// Warps an ideal pinhole mask into this camera's distorted image (the inverse of
    /// [`Camera::undistort_mask`]; the simulator uses it to fake a real lens).
    pub fn distort_mask(&self, pinhole: &Mask) -> Mask {
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

    #[test]
    fn undistort_inverts_distort() {
        let mut c = Camera::pinhole(640, 480, 600.0, 600.0, 320.0, 240.0);
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
        let mut c = Camera::pinhole(64, 48, 40.0, 40.0, 31.5, 23.5);
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
        let c = Camera::pinhole(640, 480, 600.0, 600.0, 319.5, 239.5);
        let d = c.downsampled(2);
        // The image centre stays the image centre.
        assert!((d.cx - 159.5).abs() < 1e-12 && (d.cy - 119.5).abs() < 1e-12);
        let p = Point3::new(0.1, -0.05, 1.0);
        let (a, b) = (c.project(&p), d.project(&p));
        assert!(((a[0] + 0.5) / 2.0 - 0.5 - b[0]).abs() < 1e-12);
    }
}

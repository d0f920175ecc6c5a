//! The synthetic segmentation-noise model ([`NoiseModel`]) applied to a true mask:
//! - **boundary jitter**: the silhouette boundary is displaced along its normal by a smooth
//!   random field with RMS `boundary_jitter_px`: smoothed white noise with correlation length
//!   `boundary_correlation_px` (a segmenter's soft boundary, thresholded), or, when that is 0,
//!   six random planar waves of wavelength 8–40 px;
//! - **blur** (first, when `blur_px` > 0): the robot's coverage is Gaussian-blurred and
//!   thresholded at one half, as a segmenter that rounds corners and thins thin parts;
//! - **outline offset**: the whole outline moved outward (fat masks) or inward by
//!   `outline_offset_px`, with the jitter;
//! - **blobs**: with probability `blob_probability` per view, 1–2 ellipses (3–12 px radii)
//!   centred near the boundary are painted as robot or cut out as background.
//!
//! `easyhec synth` and the `sim-truth` segmenter share it, so a benchmark's masks look like a
//! segmenter's whichever way they are made.

use rand::Rng;

use crate::config::NoiseModel;
use crate::mask::{Mask, SignedDistance};

/// Applies boundary jitter and blobs to a true mask, seeded by `rng`.
pub fn apply_mask_noise(rng: &mut impl Rng, mask: &Mask, noise: &NoiseModel) -> Mask {
    apply_mask_noise_to_coverage(rng, mask, None, noise)
}

/// [`apply_mask_noise`] with the robot's sub-pixel coverage of each pixel (row-major, 0–1)
/// for the blur to act on; without it the blur sees the mask's own 0/1 coverage, which has
/// already lost where inside a pixel the outline runs.
pub fn apply_mask_noise_to_coverage(
    rng: &mut impl Rng,
    mask: &Mask,
    coverage: Option<&[f32]>,
    noise: &NoiseModel,
) -> Mask {
    let blurred;
    let mask = if noise.blur_px > 0.0 {
        let binary: Vec<f32>;
        let coverage = match coverage.filter(|c| c.len() == mask.data.len()) {
            Some(c) => c,
            None => {
                binary = mask.data.iter().map(|&v| f32::from(v.min(1))).collect();
                &binary
            }
        };
        blurred = blur_and_threshold(coverage, mask.width, mask.height, noise.blur_px);
        &blurred
    } else {
        mask
    };
    let mut out = mask.clone();
    let offset = noise.outline_offset_px;
    if noise.boundary_jitter_px > 0.0 || offset != 0.0 {
        let sdf = SignedDistance::of(mask);
        let field = if noise.boundary_jitter_px <= 0.0 {
            vec![0.0; sdf.data.len()]
        } else if noise.boundary_correlation_px > 0.0 {
            smoothed_field(rng, mask.width, mask.height, noise)
        } else {
            planar_wave_field(rng, mask.width, mask.height, noise)
        };
        let reach = 4.0 * noise.boundary_jitter_px + offset.abs() + 1.0;
        for (i, (&d, &f)) in sdf.data.iter().zip(&field).enumerate() {
            if f64::from(d).abs() <= reach {
                out.data[i] = u8::from(f64::from(d) < f + offset);
            }
        }
    }
    if noise.blob_probability > 0.0 && rng.random_bool(noise.blob_probability.clamp(0.0, 1.0)) {
        let boundary: Vec<(u32, u32)> = (0..mask.height)
            .flat_map(|v| (0..mask.width).map(move |u| (u, v)))
            .filter(|&(u, v)| {
                mask.get(i64::from(u), i64::from(v)) && !mask.get(i64::from(u) + 1, i64::from(v))
            })
            .collect();
        if !boundary.is_empty() {
            for _ in 0..rng.random_range(1..=2) {
                let (bu, bv) = boundary[rng.random_range(0..boundary.len())];
                let (ra, rb) = (rng.random_range(3.0..12.0), rng.random_range(3.0..12.0));
                let (cu, cv) = (
                    f64::from(bu) + rng.random_range(-ra..ra),
                    f64::from(bv) + rng.random_range(-rb..rb),
                );
                let value = rng.random_bool(0.5);
                for v in
                    (cv - rb).floor().max(0.0) as u32..((cv + rb).ceil() as u32).min(mask.height)
                {
                    for u in
                        (cu - ra).floor().max(0.0) as u32..((cu + ra).ceil() as u32).min(mask.width)
                    {
                        let (du, dv) = ((f64::from(u) - cu) / ra, (f64::from(v) - cv) / rb);
                        if du * du + dv * dv <= 1.0 {
                            out.set(u, v, value);
                        }
                    }
                }
            }
        }
    }
    out
}

/// A coverage image blurred by a Gaussian of standard deviation `sigma_px`, thresholded at
/// one half (pixels past the image border count as background).
fn blur_and_threshold(coverage: &[f32], width: u32, height: u32, sigma_px: f64) -> Mask {
    let (w, h) = (width as usize, height as usize);
    let radius = (3.0 * sigma_px).ceil() as isize;
    let kernel: Vec<f64> = (-radius..=radius)
        .map(|k| (-(k * k) as f64 / (2.0 * sigma_px * sigma_px)).exp())
        .collect();
    let total: f64 = kernel.iter().sum();
    let kernel: Vec<f64> = kernel.iter().map(|k| k / total).collect();
    let pass = |src: &[f64], along_rows: bool| {
        let mut dst = vec![0.0; src.len()];
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0.0;
                for (k, weight) in kernel.iter().enumerate() {
                    let d = k as isize - radius;
                    let (sx, sy) = if along_rows {
                        (x as isize + d, y as isize)
                    } else {
                        (x as isize, y as isize + d)
                    };
                    if sx >= 0 && sy >= 0 && (sx as usize) < w && (sy as usize) < h {
                        acc += weight * src[sy as usize * w + sx as usize];
                    }
                }
                dst[y * w + x] = acc;
            }
        }
        dst
    };
    let coverage: Vec<f64> = coverage.iter().map(|&v| f64::from(v)).collect();
    let blurred = pass(&pass(&coverage, true), false);
    let mut out = Mask::new(width, height);
    for (o, c) in out.data.iter_mut().zip(&blurred) {
        *o = u8::from(*c > 0.5);
    }
    out
}

/// The share of each pixel of a `factor`-times finer mask that is robot: a sub-pixel
/// coverage for [`apply_mask_noise_to_coverage`].
pub fn coverage_of_finer(fine: &Mask, factor: u32, width: u32, height: u32) -> Vec<f32> {
    let area = (factor * factor) as f32;
    let mut coverage = vec![0.0f32; (width * height) as usize];
    for v in 0..height {
        for u in 0..width {
            let mut inside = 0u32;
            for dv in 0..factor {
                for du in 0..factor {
                    let (x, y) = (i64::from(u * factor + du), i64::from(v * factor + dv));
                    inside += u32::from(fine.get(x, y));
                }
            }
            coverage[(v * width + u) as usize] = inside as f32 / area;
        }
    }
    coverage
}

/// Boundary displacement per pixel: six planar waves, RMS `boundary_jitter_px`.
fn planar_wave_field(rng: &mut impl Rng, width: u32, height: u32, noise: &NoiseModel) -> Vec<f64> {
    let waves: Vec<(f64, f64, f64)> = (0..6)
        .map(|_| {
            let angle = rng.random_range(0.0..std::f64::consts::TAU);
            let k = std::f64::consts::TAU / rng.random_range(8.0..40.0);
            (
                k * angle.cos(),
                k * angle.sin(),
                rng.random_range(0.0..std::f64::consts::TAU),
            )
        })
        .collect();
    // The sum of six unit-amplitude cosines has RMS sqrt(3).
    let amp = noise.boundary_jitter_px / 3f64.sqrt();
    (0..height)
        .flat_map(|v| (0..width).map(move |u| (f64::from(u), f64::from(v))))
        .map(|(u, v)| {
            waves
                .iter()
                .map(|(kx, ky, ph)| (kx * u + ky * v + ph).cos())
                .sum::<f64>()
                * amp
        })
        .collect()
}

/// Boundary displacement per pixel: white noise smoothed by a Gaussian of standard deviation
/// `boundary_correlation_px / sqrt(2)` (so the field's correlation is `exp(-d^2 / 2 l^2)`),
/// scaled to RMS `boundary_jitter_px`.
fn smoothed_field(rng: &mut impl Rng, width: u32, height: u32, noise: &NoiseModel) -> Vec<f64> {
    use rand_distr::{Distribution, StandardNormal};
    let (w, h) = (width as usize, height as usize);
    let white: Vec<f64> = (0..w * h).map(|_| StandardNormal.sample(rng)).collect();
    let sigma = noise.boundary_correlation_px / std::f64::consts::SQRT_2;
    let radius = (3.0 * sigma).ceil() as isize;
    let kernel: Vec<f64> = (-radius..=radius)
        .map(|k| (-(k * k) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let blur = |src: &[f64], stride: usize, step: usize, len: usize, lines: usize| {
        let mut dst = vec![0.0; src.len()];
        for line in 0..lines {
            for i in 0..len {
                let mut acc = 0.0;
                for (k, weight) in kernel.iter().enumerate() {
                    // Mirror at the borders so the field has the same variance everywhere.
                    let j = (i as isize + k as isize - radius).unsigned_abs();
                    let j = if j >= len {
                        (2 * len - 2).saturating_sub(j)
                    } else {
                        j
                    };
                    acc += weight * src[line * stride + j.min(len - 1) * step];
                }
                dst[line * stride + i * step] = acc;
            }
        }
        dst
    };
    let rows = blur(&white, w, 1, w, h);
    let field = blur(&rows, 1, w, h, w);
    let rms = (field.iter().map(|f| f * f).sum::<f64>() / field.len().max(1) as f64).sqrt();
    let scale = if rms > 0.0 {
        noise.boundary_jitter_px / rms
    } else {
        0.0
    };
    field.into_iter().map(|f| f * scale).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 40x40 square, a 1-pixel line and a thin wedge, blurred by 0.9 px: the square's
    /// straight edges stay, the line vanishes, the wedge's tip is cut back.
    #[test]
    fn blur_cuts_sharp_tips_and_thin_parts_but_keeps_straight_edges() {
        let mut mask = Mask::new(100, 80);
        for v in 20..60 {
            for u in 20..60 {
                mask.set(u, v, true);
            }
        }
        for v in 10..70 {
            mask.set(80, v, true);
        }
        // A wedge opening downwards from its tip at (90, 10), one pixel wider every 4 rows.
        for v in 10u32..70 {
            for u in 90..=90 + (v - 10) / 4 {
                mask.set(u, v, true);
            }
        }
        let coverage: Vec<f32> = mask.data.iter().map(|&v| f32::from(v)).collect();
        let out = blur_and_threshold(&coverage, 100, 80, 0.9);
        assert!(out.get(20, 40) && out.get(59, 40) && !out.get(19, 40) && !out.get(60, 40));
        assert!(
            out.get(20, 20),
            "a right-angled corner pixel keeps half its coverage"
        );
        assert!((10..70).all(|v| !out.get(80, v)), "a 1 px line is lost");
        assert!(
            !out.get(90, 10) && !out.get(90, 11),
            "the wedge's tip is cut"
        );
        assert!(out.get(91, 40), "the wedge's wide part stays");
    }

    /// A square whose sides cover three quarters of their pixels: with its sub-pixel
    /// coverage the blur rounds the corner off (the corner pixel, 9/16 covered, is lost) and
    /// keeps the sides; from the 0/1 mask alone the corner would stay.
    #[test]
    fn with_sub_pixel_coverage_the_blur_rounds_corners() {
        let mut fine = Mask::new(400, 320);
        // Fine 81..239: coarse pixels 20 and 59 are three quarters covered.
        for v in 81..239 {
            for u in 81..239 {
                fine.set(u, v, true);
            }
        }
        let coverage = coverage_of_finer(&fine, 4, 100, 80);
        assert!((coverage[20 * 100 + 20] - 0.5625).abs() < 1e-6);
        assert!((coverage[40 * 100 + 20] - 0.75).abs() < 1e-6);
        let out = blur_and_threshold(&coverage, 100, 80, 0.9);
        assert!(out.get(20, 40) && out.get(59, 40), "the sides stay");
        assert!(
            !out.get(20, 20) && !out.get(59, 59),
            "the corners are rounded off"
        );
        assert!(out.get(21, 21), "inside the rounding the square stays");
        let binary: Vec<f32> = coverage
            .iter()
            .map(|&c| f32::from(u8::from(c >= 0.5)))
            .collect();
        assert!(blur_and_threshold(&binary, 100, 80, 0.9).get(20, 20));
    }
}

//! The synthetic segmentation-noise model ([`NoiseModel`]) applied to a true mask:
//! - **boundary jitter**: the silhouette boundary is displaced along its normal by a smooth
//!   random field with RMS `boundary_jitter_px`: smoothed white noise with correlation length
//!   `boundary_correlation_px` (a segmenter's soft boundary, thresholded), or, when that is 0,
//!   six random planar waves of wavelength 8–40 px;
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
    let mut out = mask.clone();
    if noise.boundary_jitter_px > 0.0 {
        let sdf = SignedDistance::of(mask);
        let field = if noise.boundary_correlation_px > 0.0 {
            smoothed_field(rng, mask.width, mask.height, noise)
        } else {
            planar_wave_field(rng, mask.width, mask.height, noise)
        };
        for (i, (&d, &f)) in sdf.data.iter().zip(&field).enumerate() {
            if f64::from(d).abs() <= 4.0 * noise.boundary_jitter_px + 1.0 {
                out.data[i] = u8::from(f64::from(d) < f);
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

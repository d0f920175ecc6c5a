//! The synthetic segmentation-noise model ([`NoiseModel`]) applied to a true mask:
//! - **boundary jitter**: the silhouette boundary is displaced along its normal by a smooth
//!   random field (six random planar waves, wavelength 8–40 px) with RMS `boundary_jitter_px`;
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
        // Six planar waves; the sum of six unit-amplitude cosines has RMS sqrt(3).
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
        let amp = noise.boundary_jitter_px / 3f64.sqrt();
        for v in 0..mask.height {
            for u in 0..mask.width {
                let i = (v * mask.width + u) as usize;
                let d = f64::from(sdf.data[i]);
                if d.abs() > 4.0 * noise.boundary_jitter_px + 1.0 {
                    continue;
                }
                let field: f64 = waves
                    .iter()
                    .map(|(kx, ky, ph)| (kx * f64::from(u) + ky * f64::from(v) + ph).cos())
                    .sum::<f64>()
                    * amp;
                out.data[i] = u8::from(d < field);
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

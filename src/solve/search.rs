//! The coarse global search a poor LM fit falls back to (cross-entropy at low resolution).

use nalgebra::Isometry3;
use rayon::prelude::*;

use super::{SolveOptions, View};
use crate::camera::Intrinsics;
use crate::geometry::{exp_se3, Twist};
use crate::mask::Mask;
use crate::render::{PosedRobot, SilhouetteRenderer};

/// Cross-entropy search over left increments of `initial`, maximising the mean mask IoU of up
/// to four views at 1/8 resolution with decimated meshes.
pub fn coarse_search(
    renderer: &dyn SilhouetteRenderer,
    camera: &Intrinsics,
    views: &[View],
    initial: &Isometry3<f64>,
    opts: &SolveOptions,
) -> Isometry3<f64> {
    let factor = 8;
    let level = camera.downsampled(factor);
    let step = views.len().div_ceil(4).max(1);
    let subset: Vec<(PosedRobot, Mask)> = views
        .par_iter()
        .step_by(step)
        .map(|v| (v.robot.decimated(0.004), v.observed.downsample(factor)))
        .collect();
    let subset_robots: Vec<&PosedRobot> = subset.iter().map(|(r, _)| r).collect();
    let score = |pose: &Isometry3<f64>| -> f64 {
        renderer
            .render_many(&subset_robots, &level, pose, None)
            .iter()
            .zip(&subset)
            .map(|(s, (_, m))| s.mask.iou(m))
            .sum::<f64>()
            / subset.len() as f64
    };
    cross_entropy_search(initial, opts.search_seed, score)
}

/// Cross-entropy search over left increments of `initial` for the pose `score` rates highest
/// (12 rounds of 128 draws, the 12 best refitting each round's spread, which starts at 0.2 rad
/// and 0.12 m and at most halves per round). Returns `initial` when no draw beats it.
pub(crate) fn cross_entropy_search(
    initial: &Isometry3<f64>,
    seed: u64,
    score: impl Fn(&Isometry3<f64>) -> f64 + Sync,
) -> Isometry3<f64> {
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut best = (score(initial), *initial);
    let mut sigma = Twist::new(0.12, 0.12, 0.12, 0.2, 0.2, 0.2);
    for _round in 0..12 {
        let centre = best.1;
        let samples: Vec<Twist> = (0..128)
            .map(|_| {
                Twist::from_fn(|k, _| {
                    Normal::new(0.0, sigma[k])
                        .map(|n| n.sample(&mut rng))
                        .unwrap_or(0.0)
                })
            })
            .collect();
        let mut scored: Vec<(f64, Twist)> = samples
            .par_iter()
            .map(|xi| (score(&(exp_se3(xi) * centre)), *xi))
            .collect();
        scored.sort_by(|a, b| b.0.total_cmp(&a.0));
        let elite = &scored[..12];
        if elite[0].0 > best.0 {
            best = (elite[0].0, exp_se3(&elite[0].1) * centre);
        }
        let mean_xi = elite.iter().fold(Twist::zeros(), |a, e| a + e.1) / elite.len() as f64;
        let spread = elite.iter().fold(Twist::zeros(), |a, e| {
            a + (e.1 - mean_xi).component_mul(&(e.1 - mean_xi))
        }) / elite.len() as f64;
        sigma = spread
            .map(|v| v.sqrt())
            .zip_map(&sigma, |s, old| s.clamp(0.5 * old, old).max(2e-3));
    }
    best.1
}

//! Initialisation from colour frames alone: the robot is what changes between views.
//!
//! With no guess, the mask-fit initialisation ([`super::initialise`]) needs masks good enough
//! to score a pose on, and a segmenter with no pose to lean on has only its background plate.
//! On the real xArm7 set those first masks lie at IoU 0.19–0.62 from SAM 2's (the base
//! missing, moving clutter in) and no hypothesis fits them. A camera pose predicts more than a
//! silhouette: for every pair of views it predicts where the image must change, the pixels the
//! robot covers in one view and not in the other. The base and its mount, in the same place in
//! every view, predict no change, so the plate's blind spot does not matter. Whatever else
//! changes (a second robot, a screen, a person) only lowers the true pose's score, unless it
//! moves like the robot would under some other pose (the simulator's hard frames:
//! docs/benchmarks.md).
//!
//! Hypotheses (the shells of [`super::hypotheses`]) are scored by the Dice overlap of predicted
//! and observed change ([`crate::segment::change`]) at 1/8 resolution, over every pair of up to
//! five views spread through the run; the best few distinct ones are refined by a
//! cross-entropy search on the same score.

use easyhec_drivers::Frame;
use nalgebra::Isometry3;
use rayon::prelude::*;

use super::{centre_of, distinct_starts, hypotheses, InitOptions};
use crate::camera::{Intrinsics, LensWarp};
use crate::error::{Error, Result};
use crate::mask::Mask;
use crate::render::{PosedRobot, SilhouetteRenderer};
use crate::segment::change::changed_between;
use crate::solve::cross_entropy_search;

/// Downsampling of the scoring level.
const FACTOR: u32 = 8;
/// Most views whose pairs are scored (ten pairs).
const MAX_VIEWS: usize = 5;
/// Below this mean Dice overlap no hypothesis explains what changed: the initialisation fails
/// rather than hand on a pose.
const MIN_SCORE: f64 = 0.25;

/// A camera pose found from what changed between views, with its score.
#[derive(Clone, Debug)]
pub struct ChangeStart {
    /// The pose.
    pub camera_from_base: Isometry3<f64>,
    /// Mean Dice overlap of predicted and observed change over the scored pairs (0–1).
    pub score: f64,
}

/// Observed change between two of the scored views, at the scoring level.
struct ChangePair {
    a: usize,
    b: usize,
    /// Fraction of changed full-resolution pixels in each scoring-level pixel.
    fraction: Vec<f32>,
    /// Sum of `fraction`.
    total: f64,
}

/// Finds `camera_from_base` from `frames` (all of one camera, `robots` posed at their joints)
/// with no guess, or says why it could not. `camera` is the frames' own (possibly distorted).
pub fn initialise_from_change(
    renderer: &dyn SilhouetteRenderer,
    camera: &Intrinsics,
    frames: &[&Frame],
    robots: &[PosedRobot],
    opts: &InitOptions,
) -> Result<ChangeStart> {
    let mut starts = starts_from_change(renderer, camera, frames, robots, opts)?;
    Ok(starts.swap_remove(0))
}

/// [`initialise_from_change`]'s distinct refined starts, best first, every one explaining the
/// change well enough: a caller that can tell a right start by its fit (a few views taken
/// close together leave the change ambiguous) tries them in turn.
pub fn starts_from_change(
    renderer: &dyn SilhouetteRenderer,
    camera: &Intrinsics,
    frames: &[&Frame],
    robots: &[PosedRobot],
    opts: &InitOptions,
) -> Result<Vec<ChangeStart>> {
    if frames.len() < 2 || frames.len() != robots.len() {
        return Err(Error::Solve(
            "initialisation from images needs two or more views of one camera".into(),
        ));
    }
    let pixels = camera.width as usize * camera.height as usize;
    if let Some(i) = frames.iter().position(|f| {
        f.width != camera.width || f.height != camera.height || f.rgb.len() != 3 * pixels
    }) {
        return Err(Error::Solve(format!(
            "initialisation from images: frame {i} of those given is not {}x{} RGB, the camera's size",
            camera.width, camera.height
        )));
    }
    let pinhole = camera.undistorted();
    let level = pinhole.downsampled(FACTOR);
    let chosen = spread(frames.len());
    let pairs = change_pairs(camera, frames, &chosen);
    let cell_m = 0.5 * f64::from(FACTOR) / pinhole.fx.max(pinhole.fy);
    let low: Vec<PosedRobot> = chosen
        .iter()
        .map(|&i| robots[i].decimated(cell_m))
        .collect();
    let low_refs: Vec<&PosedRobot> = low.iter().collect();
    let score = |pose: &Isometry3<f64>| -> f64 {
        let rendered = renderer.render_many(&low_refs, &level, pose, None);
        pairs
            .iter()
            .map(|p| dice(&rendered[p.a].mask, &rendered[p.b].mask, p))
            .sum::<f64>()
            / pairs.len() as f64
    };
    let aim = changed_centroid(&pairs, &level).unwrap_or([pinhole.cx, pinhole.cy]);
    let mut scored: Vec<(f64, Isometry3<f64>)> =
        hypotheses(&centre_of(&robots[chosen[0]]), &pinhole, aim, opts)
            .into_par_iter()
            .map(|pose| (score(&pose), pose))
            .collect();
    scored.sort_by(|a, b| b.0.total_cmp(&a.0));
    refined(&scored, opts, score)
}

/// `scored`'s distinct leaders after a cross-entropy search on `score` from each, best first,
/// those that explain the change well enough; or why none does.
fn refined(
    scored: &[(f64, Isometry3<f64>)],
    opts: &InitOptions,
    score: impl Fn(&Isometry3<f64>) -> f64 + Sync,
) -> Result<Vec<ChangeStart>> {
    let mut found: Vec<ChangeStart> = distinct_starts(scored, opts.refine_best)
        .into_iter()
        .enumerate()
        .map(|(k, start)| {
            let pose = cross_entropy_search(&start, k as u64, &score);
            ChangeStart {
                score: score(&pose),
                camera_from_base: pose,
            }
        })
        .collect();
    // Stable and reversed, so that of equal scores the later wins, as a maximum would pick.
    found.reverse();
    found.sort_by(|a, b| b.score.total_cmp(&a.score));
    let Some(best) = found.first() else {
        return Err(Error::Solve(
            "initialisation from images failed: no hypothesis to score".into(),
        ));
    };
    tracing::debug!(
        "initialisation from change: overlap {:.3}, camera_from_base translation {:?} m, rotation vector {:?} rad",
        best.score,
        best.camera_from_base.translation.vector.as_slice(),
        best.camera_from_base.rotation.scaled_axis().as_slice()
    );
    if best.score < MIN_SCORE {
        return Err(Error::Solve(format!(
            "initialisation from images failed: no camera pose explains what changed between the views (best overlap {:.2} < {MIN_SCORE:.2}); give initial_guess.camera_from_base",
            best.score
        )));
    }
    found.retain(|f| f.score >= MIN_SCORE);
    Ok(found)
}

/// Up to [`MAX_VIEWS`] view indices spread evenly over `n` views.
fn spread(n: usize) -> Vec<usize> {
    let m = n.min(MAX_VIEWS);
    if m < 2 {
        return (0..m).collect();
    }
    (0..m).map(|k| k * (n - 1) / (m - 1)).collect()
}

/// The observed change of every pair of the `chosen` views, undistorted to the pinhole image
/// the renders are drawn in.
fn change_pairs(camera: &Intrinsics, frames: &[&Frame], chosen: &[usize]) -> Vec<ChangePair> {
    let mut index = Vec::new();
    for a in 0..chosen.len() {
        for b in a + 1..chosen.len() {
            index.push((a, b));
        }
    }
    index
        .into_par_iter()
        .map(|(a, b)| {
            let fraction = camera
                .undistort_mask(&changed_between(frames[chosen[a]], frames[chosen[b]]))
                .block_fractions(FACTOR);
            let total = fraction.iter().map(|&f| f64::from(f)).sum();
            ChangePair {
                a,
                b,
                fraction,
                total,
            }
        })
        .collect()
}

/// Dice overlap of the change two renders predict (robot in one, not the other) with `pair`'s
/// observed change.
fn dice(a: &Mask, b: &Mask, pair: &ChangePair) -> f64 {
    let (mut overlap, mut predicted) = (0.0f64, 0.0f64);
    for ((&x, &y), &f) in a.data.iter().zip(&b.data).zip(&pair.fraction) {
        if (x != 0) != (y != 0) {
            predicted += 1.0;
            overlap += f64::from(f);
        }
    }
    let denominator = predicted + pair.total;
    if denominator > 0.0 {
        2.0 * overlap / denominator
    } else {
        0.0
    }
}

/// Centroid (scoring-level pixels, rescaled to full resolution) of all observed change.
fn changed_centroid(pairs: &[ChangePair], level: &Intrinsics) -> Option<[f64; 2]> {
    let w = level.width as usize;
    let (mut su, mut sv, mut n) = (0.0, 0.0, 0.0);
    for p in pairs {
        for (i, &f) in p.fraction.iter().enumerate() {
            let f = f64::from(f);
            su += f * (i % w) as f64;
            sv += f * (i / w) as f64;
            n += f;
        }
    }
    let f = f64::from(FACTOR);
    (n > 0.0).then(|| [(su / n + 0.5) * f - 0.5, (sv / n + 0.5) * f - 0.5])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spread_views_cover_the_run_ends_first_and_last() {
        assert_eq!(spread(10), vec![0, 2, 4, 6, 9]);
        assert_eq!(spread(3), vec![0, 1, 2]);
        assert_eq!(spread(1), vec![0]);
    }
}

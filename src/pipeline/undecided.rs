//! The segmentation term of a reported covariance: how far the pose could move with the
//! pixels the segmenter could not decide.
//!
//! A segmenter's error that every view shares does not show as disagreement between views,
//! so the view jackknife cannot see it. On the real xArm7 set the builtin masks run fat
//! wherever the white arm meets the white wall and around the base's mount plate, in every
//! view alike. The pose from colour frames alone then sits about 11 mm nearer the camera than
//! the pose from SAM 2 masks, while its statistical and inter-view terms promised a 95%
//! camera-centre bound of 7 mm. Such pixels are the ones the images left undecided: the
//! segmenter's evidence there (change against the background plate and colour, before
//! smoothing and without the prior's pull) is near even odds, and the label came from the
//! smoothing and the prior. So the masks are drawn again under the reported pose and solved
//! three times more: as drawn, with every undecided pixel near the outline as background,
//! and as robot. Each of the last two displacements from the first is taken as a draw of the
//! error: the term is the mean of their outer products. Where the smoothing and the prior
//! labelled those pixels right, it is generous.

use easyhec_drivers::Frame;
use nalgebra::{Isometry3, Matrix6};

use crate::backend::Backend;
use crate::camera::{Intrinsics, LensWarp};
use crate::error::{Error, Result};
use crate::geometry::log_se3;
use crate::mask::Mask;
use crate::pipeline::segment_solve::{bands_px, priors};
use crate::render::PosedRobot;
use crate::segment::builtin::signed_distance;
use crate::segment::{Evidence, Segmenter, ViewInput};
use crate::solve::{solve, SolveOptions, SolveReport, View};

/// A pixel is undecided when the images' log-odds for robot lie within this of zero: odds
/// under e to 1 either way.
pub const UNDECIDED_LOG_ODDS: f32 = 1.0;

/// A frame the segmenter drew a mask from: the robot as posed in it and, when the result
/// used that view, its index among the result's views. Every such frame lends the builtin
/// segmenter its background plate, used or not.
pub struct SegmentedFrame<'a> {
    /// The colour frame.
    pub frame: &'a Frame,
    /// The robot at the frame's joints.
    pub robot: PosedRobot,
    /// Index into the result's views, when the result used this view.
    pub view: Option<usize>,
}

/// The segmentation term for `report`, solved from `views`. `drawn` lists every frame the
/// segmenter drew; they are drawn again by `segmenter` under the report's render, with bands
/// of at least `band_px`, and the ones the result used are relabelled in `views` (the others
/// keep their masks). The result is the covariance of the left increment `(rho, phi)`, as
/// [`crate::solve::with_segmentation_term`] adds it; `None` when no used view was segmented or
/// the segmenter has no per-pixel evidence.
#[allow(clippy::too_many_arguments)]
pub fn undecided_term(
    renderer: &dyn Backend,
    camera: &Intrinsics,
    segmenter: &dyn Segmenter,
    drawn: &[SegmentedFrame<'_>],
    views: &[View],
    report: &SolveReport,
    band_px: f32,
    opts: &SolveOptions,
) -> Result<Option<Matrix6<f64>>> {
    if drawn.iter().all(|d| d.view.is_none()) {
        return Ok(None);
    }
    let pose = report.camera_from_base;
    let robots: Vec<PosedRobot> = drawn.iter().map(|d| d.robot.clone()).collect();
    let rendered = priors(renderer, camera, &robots, &pose);
    // Bands from the report's mean fit, as for views it did not solve: offline, the frames
    // include views the result left out, in the run's order rather than the report's.
    let bands = bands_px(camera, report, &rendered, rendered.len(), band_px);
    let inputs: Vec<ViewInput> = drawn
        .iter()
        .zip(&rendered)
        .zip(&bands)
        .map(|((d, prior), &band_px)| ViewInput {
            frame: d.frame,
            prior: Some(prior),
            band_px,
        })
        .collect();
    let Some(Evidence {
        masks,
        log_odds: evidence,
    }) = segmenter.segment_views_with_evidence(&inputs)?
    else {
        return Ok(None);
    };
    if masks.len() != drawn.len()
        || evidence.len() != drawn.len()
        || masks
            .iter()
            .zip(&evidence)
            .any(|(m, e)| m.data.len() != e.len())
    {
        return Err(Error::Solve(format!(
            "segmenter '{}' gave {} masks and {} evidence maps for {} frames",
            segmenter.name(),
            masks.len(),
            evidence.len(),
            drawn.len()
        )));
    }
    // Warm, never the wide search a poor fit would start: the term measures how far the
    // undecided pixels pull, not another basin.
    let opts = SolveOptions {
        recover_below_iou: 0.0,
        ..opts.as_fitted(report)
    };
    // The views with their masks drawn again: `None` as drawn, else the undecided pixels
    // all robot or all background.
    let relabelled = |undecided_is_robot: Option<bool>| -> Vec<View> {
        let mut out = views.to_vec();
        for (k, d) in drawn.iter().enumerate() {
            let Some(i) = d.view else { continue };
            let mask = match undecided_is_robot {
                None => masks[k].clone(),
                Some(robot) => relabel(&masks[k], &evidence[k], &rendered[k], bands[k], robot),
            };
            out[i].observed = camera.undistort_mask(&mask);
        }
        out
    };
    // Displacements are taken from the solve of the masks as drawn again, so that what
    // drawing them again moves (a new render and band) does not count as undecided.
    let base = solve(renderer, camera, &relabelled(None), &pose, &opts)?.camera_from_base;
    let mut increments = Vec::with_capacity(2);
    for undecided_is_robot in [false, true] {
        let moved = solve(
            renderer,
            camera,
            &relabelled(Some(undecided_is_robot)),
            &base,
            &opts,
        )?;
        increments.push(increment(&base, &moved.camera_from_base));
    }
    let term = increments
        .iter()
        .map(|xi| xi * xi.transpose())
        .sum::<Matrix6<f64>>()
        / increments.len() as f64;
    Ok(term.iter().all(|v| v.is_finite()).then_some(term))
}

/// `mask` with its undecided pixels within `band` pixels of `prior`'s outline set to robot
/// or to background.
fn relabel(
    mask: &Mask,
    evidence: &[f32],
    prior: &Mask,
    band: f32,
    undecided_is_robot: bool,
) -> Mask {
    let (w, h) = (mask.width as usize, mask.height as usize);
    let to_outline = signed_distance(prior, w, h);
    let mut out = mask.clone();
    for ((m, &e), &d) in out.data.iter_mut().zip(evidence).zip(&to_outline) {
        if e.abs() < UNDECIDED_LOG_ODDS && d.abs() < band {
            *m = u8::from(undecided_is_robot);
        }
    }
    out
}

/// The left increment taking `from` to `to`, in the camera frame.
fn increment(from: &Isometry3<f64>, to: &Isometry3<f64>) -> nalgebra::Vector6<f64> {
    log_se3(&(to * from.inverse()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Only the undecided pixels near the prior's outline change, and to the side asked for.
    #[test]
    fn relabel_moves_only_undecided_pixels_near_the_outline() {
        let (w, h) = (40u32, 30u32);
        let mut prior = Mask::new(w, h);
        let mut mask = Mask::new(w, h);
        for y in 10..20 {
            for x in 10..30 {
                prior.set(x, y, true);
                mask.set(x, y, true);
            }
        }
        let mut evidence = vec![5.0f32; (w * h) as usize];
        // Undecided: one pixel just outside the outline, one just inside, one far outside.
        let (outside, inside, far) = (9 * w + 15, 10 * w + 15, 2 * w + 2);
        for i in [outside, inside, far] {
            evidence[i as usize] = 0.5;
        }
        let grown = relabel(&mask, &evidence, &prior, 4.0, true);
        let shrunk = relabel(&mask, &evidence, &prior, 4.0, false);
        assert_eq!(grown.data[outside as usize], 1);
        assert_eq!(shrunk.data[inside as usize], 0);
        assert_eq!(grown.data[far as usize], 0, "beyond the band");
        assert_eq!(grown.count(), mask.count() + 1);
        assert_eq!(shrunk.count(), mask.count() - 1);
    }
}

//! Segment → solve → re-segment: context-aware segmenters improve as the estimate does, and
//! the estimate improves with the masks. The one place that alternates a segmenter with the
//! solver: `easyhec solve --segmenter` (through `pipeline::offline`), the closed loop's live
//! frames ([`LiveFrames`]) and the daemon's bump check ([`segment_among_recorded`]).

use easyhec_drivers::Frame;
use nalgebra::Isometry3;

use crate::backend::Backend;
use crate::camera::{Intrinsics, LensWarp};
use crate::error::Result;
use crate::mask::Mask;
use crate::render::{PosedRobot, SilhouetteRenderer};
use crate::robot::RobotModel;
use crate::segment::builtin::evidence_over;
use crate::segment::{Segmenter, ViewInput};
use crate::solve::{solve, MountContact, SolveOptions, SolveReport, View};
use rayon::prelude::*;

/// The robot's silhouettes under `camera_from_base`, in each frame's own (distorted) image:
/// the prior a context-aware segmenter bounds its search with.
pub fn priors(
    renderer: &dyn SilhouetteRenderer,
    camera: &Intrinsics,
    robots: &[PosedRobot],
    camera_from_base: &Isometry3<f64>,
) -> Vec<Mask> {
    let pinhole = camera.undistorted();
    let refs: Vec<&PosedRobot> = robots.iter().collect();
    renderer
        .render_many(&refs, &pinhole, camera_from_base, None)
        .into_iter()
        .map(|s| camera.distort_mask(&s.mask))
        .collect()
}

/// Segments `frames` together, frame `i` under `rendered[i]` (when given) with band
/// `bands_px[i]`: the one way the segment-and-solve steps, the calibration loop and the bump
/// check call the segmenter.
pub fn segment_frames<F: std::borrow::Borrow<Frame>>(
    segmenter: &dyn Segmenter,
    frames: &[F],
    rendered: Option<&[Mask]>,
    bands_px: &[f32],
) -> Result<Vec<Mask>> {
    let inputs: Vec<ViewInput> = frames
        .iter()
        .zip(bands_px)
        .enumerate()
        .map(|(i, (frame, &band_px))| ViewInput {
            frame: frame.borrow(),
            prior: rendered.map(|r| &r[i]),
            band_px,
        })
        .collect();
    segmenter.segment_views(&inputs)
}

/// Prior band per view, pixels: the smallest band, plus three sigma of the pose uncertainty
/// projected into the image (of the sampling covariance, which the band widths were tuned
/// on), plus the outline offset a view's misfit implies (a view that
/// fits at IoU 0.7 has outlines about 0.3 · area / perimeter apart: wrong joints, a bad mask).
/// `report`'s per-view fits belong to `rendered[first_view..]`; frames it did not solve get
/// its mean fit.
pub fn bands_px(
    camera: &Intrinsics,
    report: &SolveReport,
    rendered: &[Mask],
    first_view: usize,
    min_band_px: f32,
) -> Vec<f32> {
    let u = crate::solve::uncertainty_of(&report.sampling_covariance, &report.camera_from_base);
    let norm = |v: &[f64; 3]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
    let depth_m = report.camera_from_base.translation.vector.norm().max(0.3);
    let sigma_px =
        camera.fx * (norm(&u.rotation_deg).to_radians() + norm(&u.translation_mm) * 1e-3 / depth_m);
    let sigma_px = if sigma_px.is_finite() { sigma_px } else { 50.0 };
    // Views the report has not seen (just captured, or left out) get its mean fit.
    let mean_iou = if report.per_view_iou.is_empty() {
        0.9
    } else {
        report.mean_iou()
    };
    rendered
        .iter()
        .enumerate()
        .map(|(i, m)| {
            let iou = i
                .checked_sub(first_view)
                .and_then(|k| report.per_view_iou.get(k))
                .copied()
                .unwrap_or(mean_iou);
            let area = m.count() as f64;
            let perimeter = m.outline_crossings().len().max(1) as f64;
            let misfit_px = (1.0 - iou).max(0.0) * area / perimeter;
            (f64::from(min_band_px) + 3.0 * sigma_px + 2.0 * misfit_px).min(120.0) as f32
        })
        .collect()
}

/// What [`segment_and_solve`] settled on.
pub struct Settled {
    /// The final masks, in each frame's own (distorted) image.
    pub masks: Vec<Mask>,
    /// The final solve.
    pub report: SolveReport,
    /// Segment-and-solve rounds run.
    pub rounds: usize,
}

/// Mean IoU below which a settled segment-and-solve counts as a poor fit (the solve's own
/// "fit poorly" warning level): round 0 is tried the other way, and no final narrow band.
pub const POOR_FIT_IOU: f64 = 0.8;

/// Alternates segmentation and solving until the masks stop changing (mean IoU between
/// rounds ≥ 0.995) or `max_rounds` is reached, with bands of at least `min_band_px`; a
/// settled pose that fits (mean IoU ≥ 0.8) gets one more round with `final_band_px`. Round 0 segments without a prior unless
/// there is a single view (then the prior from `initial` with `initial_band_px`); `start`
/// turns round 0's masks into the first estimate (the given guess, or a search). When that
/// settles at a poor fit and there is an initial pose, round 0 is redone under its prior and
/// the better-fitting outcome is kept: the plate alone keeps what moves on its own (a person,
/// a box) and misses what never moves, which can pull the first solve away from a good guess
/// (2 of 8 hard synthetic runs, 3–4° off); the prior first is not the default because masks
/// shaped by a guess's render fit that render whether or not the guess is right.
#[allow(clippy::too_many_arguments)]
pub fn segment_and_solve(
    renderer: &dyn Backend,
    camera: &Intrinsics,
    segmenter: &dyn Segmenter,
    frames: &[&Frame],
    robots: &[PosedRobot],
    start: &dyn Fn(&[View]) -> Result<Isometry3<f64>>,
    initial_prior: Option<(&Isometry3<f64>, f32)>,
    min_band_px: f32,
    final_band_px: f32,
    solve_opts: &SolveOptions,
    max_rounds: usize,
) -> Result<Settled> {
    let views_of = |masks: &[Mask]| -> Vec<View> {
        masks
            .iter()
            .zip(robots)
            .map(|(m, r)| View {
                robot: r.clone(),
                observed: camera.undistort_mask(m),
            })
            .collect()
    };
    // Every view under `report`'s render, bands of at least `floor_px`.
    let resegment = |report: &SolveReport, floor_px: f32| -> Result<Vec<Mask>> {
        let rendered = priors(renderer, camera, robots, &report.camera_from_base);
        let bands = bands_px(camera, report, &rendered, 0, floor_px);
        segment_frames(segmenter, frames, Some(&rendered), &bands)
    };
    // One alternation; round 0 under `round0_prior`'s render (pose, band) when given, else
    // from the plate alone.
    let run = |round0_prior: Option<(&Isometry3<f64>, f32)>| -> Result<Settled> {
        let first_priors = round0_prior.map(|(pose, _)| priors(renderer, camera, robots, pose));
        let band0 = round0_prior.map_or(min_band_px, |(_, b)| b);
        let mut masks = segment_frames(
            segmenter,
            frames,
            first_priors.as_deref(),
            &vec![band0; frames.len()],
        )?;
        let mut views = views_of(&masks);
        let initial = start(&views)?;
        let mut report = solve(renderer, camera, &views, &initial, solve_opts)?;
        let mut opts = kept_mount_decision(solve_opts, &report);
        let mut rounds = 1;
        while rounds < max_rounds && segmenter.uses_context() {
            let next = resegment(&report, min_band_px)?;
            let change = next.iter().zip(&masks).map(|(a, b)| a.iou(b)).sum::<f64>()
                / next.len().max(1) as f64;
            masks = next;
            views = views_of(&masks);
            report = solve(renderer, camera, &views, &report.camera_from_base, &opts)?;
            opts = kept_mount_decision(&opts, &report);
            rounds += 1;
            if change >= 0.995 {
                break;
            }
        }
        Ok(Settled {
            masks,
            report,
            rounds,
        })
    };
    let prior_first = initial_prior.is_some() && frames.len() < 3;
    let first = run(initial_prior.filter(|_| prior_first))?;
    let best = if prior_first || initial_prior.is_none() || first.report.mean_iou() >= POOR_FIT_IOU
    {
        first
    } else {
        let second = run(initial_prior)?;
        if second.report.mean_iou() > first.report.mean_iou() {
            second
        } else {
            first
        }
    };
    // Settled and fitting: one last round with the final band. A narrow band is only safe
    // around a right render, so not while the pose can still move, nor after a poor fit.
    if !segmenter.uses_context()
        || final_band_px >= min_band_px
        || best.report.mean_iou() < POOR_FIT_IOU
    {
        return Ok(best);
    }
    let masks = resegment(&best.report, final_band_px)?;
    let views = views_of(&masks);
    let report = solve(
        renderer,
        camera,
        &views,
        &best.report.camera_from_base,
        &kept_mount_decision(solve_opts, &best.report),
    )?;
    Ok(Settled {
        masks,
        report,
        rounds: best.rounds + 1,
    })
}

/// `opts` for the next round after `report`: once a round's solve that fits (mean IoU at
/// least [`POOR_FIT_IOU`]) has left the mount contact out ([`MountContact::Auto`] deciding
/// so), later rounds leave it out too. The masks come from the same segmenter on the same
/// scene, and later rounds draw them in narrower bands round the render, which hides part
/// of the disagreement that decided (docs/method.md §6): deciding again each round let the
/// real xArm7's final solve flip back on a borderline vote. A round that fits poorly binds
/// nothing: its few fitting views are a thin basis for the rest.
pub fn kept_mount_decision(opts: &SolveOptions, report: &SolveReport) -> SolveOptions {
    let decided = report.mount_contact_left_out && report.mean_iou() >= POOR_FIT_IOU;
    SolveOptions {
        mount_contact: mount_contact_after(opts.mount_contact, decided),
        ..opts.clone()
    }
}

/// The mount-contact setting after a round asked `asked` and decided to leave the contact
/// out or not.
fn mount_contact_after(asked: MountContact, left_out: bool) -> MountContact {
    if asked == MountContact::Auto && left_out {
        MountContact::LeaveOut
    } else {
        asked
    }
}

/// Tuning of [`search_view_pairs`].
#[derive(Clone, Debug)]
pub struct PairSearchOptions {
    /// Band (pixels) of the one segmentation every pair is first solved on: wide, because the
    /// start pose is poor.
    pub screen_band_px: f32,
    /// How many of the best-fitting pairs are re-segmented under their own pose.
    pub finalists: usize,
    /// Band of that re-segmentation; the pair that fits its own masks best wins.
    pub settle_band_px: f32,
    /// Band of the final masks, drawn around each view's refitted joints.
    pub final_band_px: f32,
}

impl Default for PairSearchOptions {
    fn default() -> Self {
        PairSearchOptions {
            screen_band_px: 80.0,
            finalists: 6,
            settle_band_px: 40.0,
            final_band_px: 4.0,
        }
    }
}

/// What [`search_view_pairs`] settled on.
pub struct PairFound {
    /// The two views (indices into the frames) whose solve fits its own masks best.
    pub pair: (usize, usize),
    /// That pair's mean IoU on masks segmented under its own pose.
    pub score: f64,
    /// The next-best finalist and its score, for the log: a close second means a weak choice.
    pub runner_up: Option<((usize, usize), f64)>,
    /// Every view's mask (drawn under its refitted joints where the segmenter has evidence)
    /// and the pair's solve on them.
    pub settled: Settled,
}

/// Every view pair, one segmentation under `start`; the best `finalists` re-segmented under
/// their own pose; the best of those kept. For runs where no pose fits all views (recorded
/// joints that do not describe their images, the Panda example in docs/benchmarks.md) and the masks come
/// from a context-aware segmenter: masks segmented around a wrong render fit no pose, the
/// consistency check then has nothing to tell views apart with, and a solve of the right two
/// views lands near the pose the provided masks give (0.45° / 4.5 mm on the Panda). The final
/// masks are drawn around each view's joints refitted to the segmenter's own evidence at that
/// pose ([`refit_joints`]): the recorded joints' render is a poor prior exactly where they are
/// wrong. Returns None with fewer than three views or when the pair does not fit its final
/// masks (mean IoU below [`POOR_FIT_IOU`]).
#[allow(clippy::too_many_arguments)]
pub fn search_view_pairs(
    renderer: &dyn Backend,
    camera: &Intrinsics,
    segmenter: &dyn Segmenter,
    frames: &[&Frame],
    robot: &RobotModel,
    joints: &[Vec<f64>],
    start: &Isometry3<f64>,
    solve_opts: &SolveOptions,
    opts: &PairSearchOptions,
) -> Result<Option<PairFound>> {
    let n = frames.len();
    if n < 3 || joints.len() != n {
        return Ok(None);
    }
    let robots: Vec<PosedRobot> = joints.iter().map(|q| PosedRobot::new(robot, q)).collect();
    let segment_under = |posed: &[PosedRobot], pose: &Isometry3<f64>, band_px: f32| {
        let rendered = priors(renderer, camera, posed, pose);
        segment_frames(segmenter, frames, Some(&rendered), &vec![band_px; n])
    };
    let view = |masks: &[Mask], k: usize| View {
        robot: robots[k].clone(),
        observed: camera.undistort_mask(&masks[k]),
    };
    // Pairs of views that disagree fit at IoU 0.5–0.6: the solve's recovery search (meant for
    // a start in the wrong basin) and posterior refinement would cost most of the time and
    // decide nothing, so the screening and settling solves go without them.
    let quick = SolveOptions {
        recover_below_iou: 0.0,
        refine_samples: 0,
        ..solve_opts.clone()
    };
    let solve_with =
        |masks: &[Mask], (i, j): (usize, usize), from: &Isometry3<f64>, opts: &SolveOptions| {
            solve(
                renderer,
                camera,
                &[view(masks, i), view(masks, j)],
                from,
                opts,
            )
        };
    let solve_pair = |masks: &[Mask], pair: (usize, usize), from: &Isometry3<f64>| {
        solve_with(masks, pair, from, &quick)
    };
    let screen = segment_under(&robots, start, opts.screen_band_px)?;
    let pairs: Vec<(usize, usize)> = (0..n)
        .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
        .collect();
    // Screening only ranks the pairs: half resolution is enough.
    let coarse = SolveOptions {
        pyramid: quick.pyramid.iter().copied().filter(|&f| f > 1).collect(),
        ..quick.clone()
    };
    let mut screened: Vec<((usize, usize), SolveReport)> = pairs
        .par_iter()
        .map(|&pair| Ok((pair, solve_with(&screen, pair, start, &coarse)?)))
        .collect::<Result<_>>()?;
    screened.sort_by(|a, b| b.1.mean_iou().total_cmp(&a.1.mean_iou()));
    screened.truncate(opts.finalists.max(1));
    let mut finals: Vec<((usize, usize), SolveReport)> = screened
        .par_iter()
        .map(|(pair, report)| {
            let masks = segment_under(&robots, &report.camera_from_base, opts.settle_band_px)?;
            Ok((*pair, solve_pair(&masks, *pair, &report.camera_from_base)?))
        })
        .collect::<Result<_>>()?;
    finals.sort_by(|a, b| b.1.mean_iou().total_cmp(&a.1.mean_iou()));
    let (pair, best) = finals[0].clone();
    let runner_up = finals.get(1).map(|(p, r)| (*p, r.mean_iou()));
    let pose = best.camera_from_base;
    let posed = match segmenter.evidence(frames)? {
        Some(evidence) => (0..n)
            .into_par_iter()
            .map(|k| {
                let q = refit_joints(renderer, camera, robot, joints, k, &evidence[k], &pose);
                PosedRobot::new(robot, &q)
            })
            .collect(),
        None => robots.clone(),
    };
    let masks = segment_under(&posed, &pose, opts.final_band_px)?;
    let report = solve_with(&masks, pair, &pose, solve_opts)?;
    if report.mean_iou() < POOR_FIT_IOU {
        return Ok(None);
    }
    Ok(Some(PairFound {
        pair,
        score: best.mean_iou(),
        runner_up,
        settled: Settled {
            masks,
            report,
            rounds: 3,
        },
    }))
}

/// View `k`'s joints refitted to its image at `camera_from_base`: the recorded vector, or one
/// part of the way (a quarter to all of it) towards another view's, whichever render covers
/// the most `evidence` (per-pixel log-odds for robot, [`Segmenter::evidence`]); then each
/// joint in turn, in steps from 0.1 down to 0.01 rad. For drawing masks only: the solve keeps
/// the recorded joints, so a refitted view still has to agree with the others to be used.
pub fn refit_joints(
    renderer: &dyn SilhouetteRenderer,
    camera: &Intrinsics,
    robot: &RobotModel,
    joints: &[Vec<f64>],
    k: usize,
    evidence: &[f32],
    camera_from_base: &Isometry3<f64>,
) -> Vec<f64> {
    let score = |q: &[f64]| {
        let posed = [PosedRobot::new(robot, q)];
        evidence_over(
            &priors(renderer, camera, &posed, camera_from_base)[0],
            evidence,
        )
    };
    let own = &joints[k];
    let mut best_q = own.clone();
    let mut best = score(own);
    for other in joints {
        for t in [0.25, 0.5, 0.75, 1.0] {
            let q: Vec<f64> = own
                .iter()
                .zip(other)
                .map(|(a, b)| a + t * (b - a))
                .collect();
            let s = score(&q);
            if s > best {
                (best, best_q) = (s, q);
            }
        }
    }
    for step in [0.1, 0.05, 0.02, 0.01] {
        let mut improved = true;
        while improved {
            improved = false;
            for j in 0..best_q.len() {
                for s in [-step, step] {
                    let mut q = best_q.clone();
                    q[j] += s;
                    let v = score(&q);
                    if v > best + 1e-3 {
                        (best, best_q, improved) = (v, q, true);
                    }
                }
            }
        }
    }
    best_q
}

/// Prior band (pixels) around the silhouette under the initial guess: a guess several
/// degrees and centimetres off moves the outline by tens of pixels.
pub const GUESS_BAND_PX: f32 = 80.0;

/// The closed loop's frames for a context-aware segmenter: every frame so far, segmented
/// together (background plate) under the current estimate each time one is added, so earlier
/// masks improve as the estimate does.
pub struct LiveFrames {
    /// Every frame captured so far, in view order.
    pub frames: Vec<Frame>,
    /// The narrowest band while views are still being added (`[segmenter] min_band_px`).
    pub min_band_px: f32,
    /// The narrowest band of the last re-segmentation (`[segmenter] final_band_px`).
    pub final_band_px: f32,
}

impl LiveFrames {
    /// Segments every frame with priors under `estimate` (bands from `report` when there is
    /// one, at least `band_floor_px`; the guess band before any solve), calls `changed` for
    /// each earlier view whose mask changed (the recorder rewrites it), and rebuilds `views`
    /// to match the frames.
    #[allow(clippy::too_many_arguments)]
    pub fn resegment(
        &self,
        renderer: &dyn Backend,
        segmenter: &dyn Segmenter,
        robot: &RobotModel,
        camera: &Intrinsics,
        band_floor_px: f32,
        taken: &[Vec<f64>],
        estimate: Option<&Isometry3<f64>>,
        report: Option<&SolveReport>,
        views: &mut Vec<View>,
        mut changed: impl FnMut(usize, &Mask) -> Result<()>,
    ) -> Result<Vec<Mask>> {
        let robots: Vec<PosedRobot> = taken.iter().map(|q| PosedRobot::new(robot, q)).collect();
        let priors = estimate.map(|pose| priors(renderer, camera, &robots, pose));
        let bands = match (report, &priors) {
            (Some(r), Some(p)) => bands_px(camera, r, p, 0, band_floor_px),
            _ => vec![GUESS_BAND_PX; robots.len()],
        };
        let masks = segment_frames(segmenter, &self.frames, priors.as_deref(), &bands)?;
        for (i, m) in masks.iter().enumerate().take(views.len()) {
            let observed = camera.undistort_mask(m);
            if observed != views[i].observed {
                changed(i, m)?;
                views[i].observed = observed;
            }
        }
        views.truncate(masks.len());
        for (m, r) in masks.iter().zip(robots).skip(views.len()) {
            views.push(View {
                robot: r,
                observed: camera.undistort_mask(m),
            });
        }
        Ok(masks)
    }
}

/// A context-aware segmenter's (`builtin`) mask of `frame` at `joints`, segmented together
/// with `recorded` frames of a calibration (less those taken at the same joints, which show
/// the robot where the new frame does and so lend it no background), each with the robot
/// rendered under `pose` as its prior and band `band_px` (the bump check uses the loop's
/// tightest: a wider one lets the hard cases, a light robot on a light wall or distractors
/// touching it, spread the mask, and a knocked camera still moves the robot off the render by
/// more than this). A segmenter whose prompted views stand alone (`sam`) draws `frame` by
/// itself.
#[allow(clippy::too_many_arguments)]
pub fn segment_among_recorded(
    renderer: &dyn SilhouetteRenderer,
    segmenter: &dyn Segmenter,
    robot: &RobotModel,
    camera: &Intrinsics,
    frame: Frame,
    joints: &[f64],
    recorded: Vec<(Frame, Vec<f64>)>,
    pose: &Isometry3<f64>,
    band_px: f32,
) -> Result<Option<Mask>> {
    let recorded = if segmenter.prompted_views_stand_alone() {
        Vec::new()
    } else {
        recorded
    };
    let (mut frames, mut all_joints): (Vec<Frame>, Vec<Vec<f64>>) = recorded
        .into_iter()
        .filter(|(_, q)| {
            q.iter()
                .zip(joints)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max)
                > 0.05
        })
        .unzip();
    frames.push(frame);
    all_joints.push(joints.to_vec());
    let robots: Vec<PosedRobot> = all_joints
        .iter()
        .map(|q| PosedRobot::new(robot, q))
        .collect();
    let priors = priors(renderer, camera, &robots, pose);
    let bands = vec![band_px; frames.len()];
    Ok(segment_frames(segmenter, &frames, Some(&priors), &bands)?.pop())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_round_that_left_the_mount_out_decides_for_the_rounds_after_it() {
        use MountContact::{Auto, Fit, LeaveOut};
        assert_eq!(mount_contact_after(Auto, true), LeaveOut);
        assert_eq!(mount_contact_after(Auto, false), Auto);
        // What the user chose stands.
        assert_eq!(mount_contact_after(Fit, false), Fit);
        assert_eq!(mount_contact_after(LeaveOut, true), LeaveOut);
    }
}

//! Filling a run's missing masks with a segmenter: segment → solve → re-segment until the
//! masks settle, and the view-pair search when no pose fits them all.

use std::path::Path;
use std::time::Instant;

use nalgebra::{Isometry3, Matrix6};

use crate::backend::Backend;
use crate::camera::LensWarp;
use crate::config::SegmenterConfig;
use crate::error::{Error, Result};
use crate::init::change::initialise_from_change;
use crate::init::{initialise, InitOptions};
use crate::pipeline::segment_solve::{self, PairSearchOptions, POOR_FIT_IOU};
use crate::pipeline::undecided::{undecided_term, SegmentedFrame};
use crate::render::PosedRobot;
use crate::run::LoadedRun;
use crate::segment::Segmenter;
use crate::solve::{self, SolveOptions, SolveReport, View};

/// Fills the masks of views that need one: segment → solve → re-segment over those views
/// until the masks settle (`pipeline::segment_solve`). Returns the settled pose when it fits
/// (mean IoU ≥ 0.8): the solve that follows starts there, since masks drawn near that pose's
/// render are what it must fit, and a start back at the guess can stop in another basin (hard
/// synthetic seed 3: 5.9° off from the guess, 0.006° from the settled pose). Every fit in
/// the rounds and the searches takes `opts`, except that once a round leaves the mount
/// contact out the later rounds do too ([`segment_solve::kept_mount_decision`]). With the
/// pose, whether the rounds left it out: the solve that follows keeps that decision.
pub(super) fn segment_run(
    run: &mut LoadedRun,
    config: &SegmenterConfig,
    segmenter: &dyn Segmenter,
    opts: &SolveOptions,
    renderer: &dyn Backend,
    masks_out: Option<&Path>,
    note: &mut dyn FnMut(&str),
) -> Result<Option<Settle>> {
    let name = segmenter.name().to_string();
    let need: Vec<usize> = (0..run.views.len())
        .filter(|&i| run.views[i].needs_mask)
        .collect();
    if need.is_empty() {
        return Ok(None);
    }
    let frames = need
        .iter()
        .map(|&i| frame_of(run, i))
        .collect::<Result<Vec<_>>>()?;
    let robots: Vec<PosedRobot> = need
        .iter()
        .map(|&i| PosedRobot::new(&run.robot, &run.views[i].joints))
        .collect();
    let frame_refs: Vec<&easyhec_drivers::Frame> = frames.iter().collect();
    let guess = match run.initial_guess {
        Some(g) => Some(g),
        None if segmenter.uses_context() && frame_refs.len() >= 2 => {
            change_start(renderer, run, &frame_refs, &robots, &name, note)
        }
        None => None,
    };
    let camera = run.camera.clone();
    let start = |views: &[View]| -> Result<Isometry3<f64>> {
        match guess {
            Some(g) => Ok(g),
            None => Ok(initialise(
                renderer,
                &camera,
                &views[..views.len().min(3)],
                opts,
                &InitOptions::default(),
            )?
            .camera_from_base),
        }
    };
    let settled = segment_solve::segment_and_solve(
        renderer,
        &run.camera,
        segmenter,
        &frame_refs,
        &robots,
        &start,
        guess.as_ref().map(|g| (g, segment_solve::GUESS_BAND_PX)),
        config.min_band_px(),
        config.final_band_px(),
        opts,
        4,
    )?;
    note(&format!(
        "segmenter {name}: {} views segmented in {} segment-and-solve rounds (mean IoU {:.3} at the last solve)",
        need.len(),
        settled.rounds,
        settled.report.mean_iou()
    ));
    let settled = if settled.report.mean_iou() < POOR_FIT_IOU && segmenter.uses_context() {
        let joints: Vec<Vec<f64>> = need.iter().map(|&i| run.views[i].joints.clone()).collect();
        let scene = PairScene {
            renderer,
            run,
            segmenter,
            frames: &frame_refs,
            joints: &joints,
            need: &need,
            opts,
        };
        scene.search(settled, &name, note)?
    } else {
        settled
    };
    for (&i, mask) in need.iter().zip(&settled.masks) {
        if let Some(dir) = masks_out {
            crate::io::write_atomic(
                &dir.join(crate::run::mask_file_name(i)),
                &mask.to_png_bytes(),
            )?;
        }
        run.views[i].observed = run.camera.undistort_mask(mask);
        run.views[i].needs_mask = false;
    }
    Ok(
        (settled.report.mean_iou() >= POOR_FIT_IOU).then_some(Settle {
            camera_from_base: settled.report.camera_from_base,
            mount_contact_left_out: settled.report.mount_contact_left_out,
        }),
    )
}

/// Where [`segment_run`]'s rounds settled, when the fit there is good.
pub(super) struct Settle {
    /// The settled pose.
    pub camera_from_base: Isometry3<f64>,
    /// Whether its solve left the mount contact out.
    pub mount_contact_left_out: bool,
}

/// View `i`'s colour frame, read for a segmenter.
fn frame_of(run: &LoadedRun, i: usize) -> Result<easyhec_drivers::Frame> {
    let path = run.views[i].image.as_ref().ok_or_else(|| {
        Error::input(
            run.dir.join("run.json"),
            format!("views[{i}].image"),
            "absent",
        )
    })?;
    crate::segment::read_frame(path, run.camera.width, run.camera.height)
}

/// The views of a fitted run whose masks a segmenter drew.
pub(super) struct SegmentedViews<'a> {
    /// The run.
    pub run: &'a LoadedRun,
    /// The views used, in the report's order (indices into `run.views`).
    pub order: &'a [usize],
    /// The views whose masks the segmenter drew (indices into `run.views`).
    pub segmented: &'a [usize],
}

impl SegmentedViews<'_> {
    /// `report` with the segmentation term ([`crate::pipeline::undecided`]) when a segmenter
    /// with per-pixel evidence drew masks of the views used; as it was otherwise. A term that
    /// cannot be measured is recorded as such ([`solve::with_segmentation_term`]).
    pub(super) fn with_segmentation_term(
        &self,
        config: &SegmenterConfig,
        renderer: &dyn Backend,
        used: &[View],
        report: SolveReport,
        opts: &SolveOptions,
    ) -> SolveReport {
        // Only the builtin segmenter has the evidence; building another would load its
        // model again for nothing.
        if !matches!(config, SegmenterConfig::Builtin { .. }) {
            return report;
        }
        let measured = self.measure_segmentation_term(config, renderer, used, &report, opts);
        solve::with_segmentation_term(report, measured)
    }

    /// The segmentation term's covariance for `report` (see [`undecided_term`]).
    fn measure_segmentation_term(
        &self,
        config: &SegmenterConfig,
        renderer: &dyn Backend,
        used: &[View],
        report: &SolveReport,
        opts: &SolveOptions,
    ) -> Result<Option<Matrix6<f64>>> {
        let segmenter = crate::segment::build(config, &self.run.dir.join("run.json"))?;
        let frames = self
            .segmented
            .iter()
            .map(|&i| frame_of(self.run, i))
            .collect::<Result<Vec<_>>>()?;
        let drawn: Vec<SegmentedFrame> = self
            .segmented
            .iter()
            .zip(&frames)
            .map(|(&i, frame)| SegmentedFrame {
                frame,
                robot: PosedRobot::new(&self.run.robot, &self.run.views[i].joints),
                view: self.order.iter().position(|&o| o == i),
            })
            .collect();
        // The band the final masks were drawn with (`segment_and_solve`'s last round).
        let band_px = if report.mean_iou() >= POOR_FIT_IOU {
            config.final_band_px().min(config.min_band_px())
        } else {
            config.min_band_px()
        };
        undecided_term(
            renderer,
            &self.run.camera,
            segmenter.as_ref(),
            &drawn,
            used,
            report,
            band_px,
            opts,
        )
    }
}

/// With no guess, a start from what changed between the views ([`initialise_from_change`]),
/// which a segmenter's first, pose-less masks are too poor to find by their fit; `None` (the
/// mask-fit initialisation then runs on those masks) when no pose explains the change. The
/// pose found is then used as a guess is, band and all: like a tape-measured guess it is a
/// few degrees and centimetres off, and the settled fit, not the start, decides the result.
fn change_start(
    renderer: &dyn Backend,
    run: &LoadedRun,
    frames: &[&easyhec_drivers::Frame],
    robots: &[PosedRobot],
    name: &str,
    note: &mut dyn FnMut(&str),
) -> Option<Isometry3<f64>> {
    match initialise_from_change(
        renderer,
        &run.camera,
        frames,
        robots,
        &InitOptions::default(),
    ) {
        Ok(found) => {
            note(&format!(
                "segmenter {name}: no initial guess; started from the camera pose that explains what changed between the views (overlap {:.2})",
                found.score
            ));
            Some(found.camera_from_base)
        }
        Err(e) => {
            note(&format!(
                "segmenter {name}: {e}; initialising from its first masks instead"
            ));
            None
        }
    }
}

/// What the view-pair search needs of the run being segmented.
struct PairScene<'a> {
    renderer: &'a dyn Backend,
    run: &'a LoadedRun,
    segmenter: &'a dyn crate::segment::Segmenter,
    frames: &'a [&'a easyhec_drivers::Frame],
    joints: &'a [Vec<f64>],
    need: &'a [usize],
    opts: &'a SolveOptions,
}

impl PairScene<'_> {
    /// No pose fits the masks: some views' joints may not describe their images. Finds the
    /// two views that agree on a pose, from the images alone; keeps `settled` when none do.
    fn search(
        &self,
        settled: segment_solve::Settled,
        name: &str,
        note: &mut dyn FnMut(&str),
    ) -> Result<segment_solve::Settled> {
        let t = Instant::now();
        let need = self.need;
        let found = segment_solve::search_view_pairs(
            self.renderer,
            &self.run.camera,
            self.segmenter,
            self.frames,
            &self.run.robot,
            self.joints,
            &settled.report.camera_from_base,
            self.opts,
            &PairSearchOptions::default(),
        )?;
        let Some(found) = found else {
            note(&format!(
                "segmenter {name}: the masks fit no pose and no pair of views agrees on one ({:.1} s)",
                t.elapsed().as_secs_f64()
            ));
            return Ok(settled);
        };
        let (i, j) = found.pair;
        let runner_up = found.runner_up.map_or(String::new(), |((a, b), s)| {
            format!(", next views {} and {} at {s:.3}", need[a], need[b])
        });
        note(&format!(
            "segmenter {name}: the masks fit no pose, so every pair of views was tried: views {} and {} agree best (IoU {:.3} on masks under their own pose{runner_up}; {:.1} s); masks redrawn around joints refitted to each image, the pair fits them at IoU {:.3}",
            need[i],
            need[j],
            found.score,
            t.elapsed().as_secs_f64(),
            found.settled.report.mean_iou()
        ));
        Ok(found.settled)
    }
}

//! When a calibration stops: the sandwich bound first, the views' disagreement only when that
//! passes, convergence of the best variance, and every camera of a list done.

use std::time::Instant;

use rayon::prelude::*;

use crate::pipeline::segment_solve::POOR_FIT_IOU;
use crate::solve::with_view_disagreement;

use super::{Session, Track};
use crate::backend::Backend;
use crate::calibrate::StopReason;
use crate::solve::{SolveOptions, SolveReport};

impl Session<'_> {
    /// The uncertainty rule: enough views, every one fitting, and the reported 95% bound on
    /// the camera centre within `stop_centre_95_mm`, for every camera. The bound is
    /// calibrated to cover the true error (docs/uncertainty.md), so stopping on it keeps the
    /// promise.
    ///
    /// The statistical bound is checked first; only when it passes does each camera's view
    /// jackknife run (it costs about a solve), and the widened bound must pass too; then,
    /// for masks a segmenter drew, the segmentation term (three solves) and the bound again.
    pub(super) fn precise_enough(&mut self) -> Option<StopReason> {
        let target = self.settings.stop_centre_95_mm?;
        if !self.bounds_within(target) {
            return None;
        }
        self.measure_view_disagreement();
        if !self.bounds_within(target) {
            return None;
        }
        self.measure_segmentation_terms();
        if !self.bounds_within(target) {
            return None;
        }
        let worst = self
            .tracks
            .iter()
            .map(|t| t.report().uncertainty.camera_centre_95_mm)
            .fold(0.0, f64::max);
        Some(StopReason::Precise {
            worst_mm: worst,
            several: self.several(),
            views: self.views(),
            target_mm: target,
        })
    }

    /// Enough views, every one fitting, and every camera's 95% centre bound within `target`.
    pub(super) fn bounds_within(&self, target: f64) -> bool {
        self.views() >= self.settings.min_views
            && self.tracks.iter().all(|t| {
                t.report.as_ref().is_some_and(|report| {
                    let fits = report.per_view_iou.iter().all(|&iou| iou >= POOR_FIT_IOU);
                    let bound = report.uncertainty.camera_centre_95_mm;
                    // A NaN bound promises nothing: it never stops the loop.
                    fits && !bound.is_nan() && bound <= target
                })
            })
    }

    /// Widens every camera's covariance by what its views' disagreement shows (once per
    /// solve: a report that has it keeps it).
    pub(super) fn measure_view_disagreement(&mut self) {
        self.widen_reports(|t, renderer, report, opts| {
            with_view_disagreement(renderer, &t.camera, &t.views, report, opts)
        });
    }

    /// Widens the covariance of every camera whose masks a segmenter drew by what the pixels
    /// it could not decide could move the pose (once per solve, as the jackknife).
    pub(super) fn measure_segmentation_terms(&mut self) {
        self.widen_reports(|t, renderer, report, opts| {
            t.with_segmentation_term(renderer, report, opts)
        });
    }

    /// Replaces every camera's report by `widen` of it, the cameras in parallel, timed as
    /// solving.
    fn widen_reports(
        &mut self,
        widen: impl Fn(&Track<'_>, &dyn Backend, SolveReport, &SolveOptions) -> SolveReport + Sync,
    ) {
        let started = Instant::now();
        let renderer = self.renderer.as_ref();
        let opts = &self.solve_opts;
        self.tracks.par_iter_mut().for_each(|t| {
            if let Some(report) = t.report.take() {
                t.report = Some(widen(t, renderer, report, opts));
            }
        });
        self.solve_s += started.elapsed().as_secs_f64();
    }

    /// The variance rule of a single camera: the best disagreement settled, enough views,
    /// and the estimate barely moved in the last round. (A rig's cameras each converge on
    /// their own: [`Session::mark_converged`].)
    pub(super) fn converged(&self, best: Option<f64>) -> Option<StopReason> {
        if self.several() {
            return None;
        }
        let s = &self.settings;
        let last = self.rounds.last()?;
        let (Some(prev), Some(best), Some([deg, mm])) =
            (self.previous_best, best, last.pose_change)
        else {
            return None;
        };
        let settled = (prev - best).abs() <= s.variance_rel_tol * prev.max(1e-12);
        (settled && self.views() >= s.min_views && deg < s.pose_tol_deg && mm < s.pose_tol_mm).then(
            || StopReason::VarianceConverged {
                views: self.views(),
            },
        )
    }

    /// A rig's cameras that have converged: enough views, and the estimate moved less than
    /// the pose tolerances in the last round. Such a camera stops asking for views; it keeps
    /// every view the others ask for.
    pub(super) fn mark_converged(&mut self) {
        if !self.several() {
            return;
        }
        let (s, n) = (&self.settings, self.taken.len());
        for t in self.tracks.iter_mut().filter(|t| t.done.is_none()) {
            if let Some([deg, mm]) = t.change {
                if n >= s.min_views && deg < s.pose_tol_deg && mm < s.pose_tol_mm {
                    t.done = Some(StopReason::CameraConverged {
                        views: n,
                        moved_deg: deg,
                        moved_mm: mm,
                    });
                }
            }
        }
    }

    /// The rig's stop: every camera converged.
    pub(super) fn rig_converged(&self) -> Option<StopReason> {
        (self.several() && self.tracks.iter().all(|t| t.done.is_some())).then(|| {
            StopReason::EveryCameraConverged {
                views: self.views(),
            }
        })
    }
}

//! Views whose joints do not describe their image.
//!
//! A joint vector read while the arm was still settling, or a frame from a different moment
//! than its joints, cannot be fitted by any camera pose. In a multi-view solve such views pull
//! the pose away from every view, and which wrong pose wins depends on where the solve started.
//! After a solve that leaves views below [`ConsensusOptions::trigger_iou`], this module looks for
//! the largest set of views that one pose fits well: it re-solves from the views that fit,
//! re-admits every view that fits the new pose, and repeats until the set settles. The views it
//! leaves out are reported, never dropped silently.

use nalgebra::Isometry3;

use crate::backend::Backend;
use crate::camera::Intrinsics;
use crate::error::Result;
use crate::render::SilhouetteRenderer;
use crate::solve::{solve, SolveOptions, SolveReport, View};

/// Thresholds of the consistency check.
#[derive(Clone, Debug)]
pub struct ConsensusOptions {
    /// A solve with any view below this IoU is checked.
    pub trigger_iou: f64,
    /// A view fitting the consensus pose at or above this IoU belongs to the consensus.
    pub inlier_iou: f64,
    /// The consensus needs at least this many views (one view leaves depth weakly fixed).
    pub min_views: usize,
    /// Re-solve rounds at most.
    pub max_rounds: usize,
}

impl Default for ConsensusOptions {
    fn default() -> Self {
        ConsensusOptions {
            trigger_iou: 0.8,
            inlier_iou: 0.85,
            min_views: 2,
            max_rounds: 5,
        }
    }
}

/// A pose that a subset of the views agrees on.
#[derive(Clone, Debug)]
pub struct Consensus {
    /// Indices (into the views given) that the pose fits, ascending.
    pub kept: Vec<usize>,
    /// Indices left out, with their IoU at the consensus pose.
    pub rejected: Vec<(usize, f64)>,
    /// The solve from the kept views.
    pub report: SolveReport,
}

/// Mask IoU of every view at `camera_from_base`.
pub fn ious_at(
    renderer: &dyn SilhouetteRenderer,
    camera: &Intrinsics,
    views: &[View],
    camera_from_base: &Isometry3<f64>,
) -> Vec<f64> {
    let pinhole = camera.undistorted();
    let robots: Vec<_> = views.iter().map(|v| &v.robot).collect();
    renderer
        .render_many(&robots, &pinhole, camera_from_base, None)
        .iter()
        .zip(views)
        .map(|(s, v)| s.mask.iou(&v.observed))
        .collect()
}

fn best_n(ious: &[f64], n: usize) -> Vec<usize> {
    let mut order: Vec<usize> = (0..ious.len()).collect();
    order.sort_by(|&a, &b| ious[b].total_cmp(&ious[a]));
    order.truncate(n);
    order.sort_unstable();
    order
}

/// Checks the solve `report` of `views`; returns the consensus when some views do not fit and
/// a subset of at least `min_views` views agrees on a pose that fits them at `inlier_iou`, and
/// `None` when every view fits or no such subset is found (the caller then keeps `report` and
/// warns).
pub fn find_consensus(
    renderer: &dyn Backend,
    camera: &Intrinsics,
    views: &[View],
    report: &SolveReport,
    solve_opts: &SolveOptions,
    opts: &ConsensusOptions,
) -> Result<Option<Consensus>> {
    let ious = &report.per_view_iou;
    if ious.len() != views.len()
        || views.len() <= opts.min_views
        || ious.iter().all(|&v| v >= opts.trigger_iou)
    {
        return Ok(None);
    }
    let mut kept: Vec<usize> = (0..views.len())
        .filter(|&i| ious[i] >= opts.trigger_iou)
        .collect();
    if kept.len() < opts.min_views {
        kept = best_n(ious, opts.min_views);
    }
    let mut pose = report.camera_from_base;
    let mut last = None;
    for _ in 0..opts.max_rounds {
        let subset: Vec<View> = kept.iter().map(|&i| views[i].clone()).collect();
        let solved = solve(renderer, camera, &subset, &pose, solve_opts)?;
        pose = solved.camera_from_base;
        let all = ious_at(renderer, camera, views, &pose);
        let mut next: Vec<usize> = (0..views.len())
            .filter(|&i| all[i] >= opts.inlier_iou)
            .collect();
        if next.len() < opts.min_views {
            next = best_n(&all, opts.min_views);
        }
        let settled = next == kept;
        last = Some((std::mem::replace(&mut kept, next), solved, all));
        if settled {
            break;
        }
    }
    let Some((kept, solved, all)) = last else {
        return Ok(None);
    };
    // The kept views must fit the pose they were solved for, and the set must differ from
    // "all views" (otherwise the original solve already was the consensus).
    let fits = kept.iter().all(|&i| all[i] >= opts.inlier_iou);
    if !fits || kept.len() == views.len() || solved.per_view_iou.len() != kept.len() {
        return Ok(None);
    }
    let rejected = (0..views.len())
        .filter(|i| !kept.contains(i))
        .map(|i| (i, all[i]))
        .collect();
    Ok(Some(Consensus {
        kept,
        rejected,
        report: solved,
    }))
}

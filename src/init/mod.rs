//! Automatic initial pose (docs/method.md §6): no trained network, no hand-tuned guess.
//!
//! Camera hypotheses are placed on shells around the robot (0.6–2.5 m, every 15° of azimuth,
//! six elevations, three rolls), each looking at the robot's centre, and scored by mask IoU at
//! 1/8 resolution with decimated meshes over the first views. The best few are refined by the
//! cross-entropy search and the full solver; the best result wins. A low final IoU is reported
//! as a failure, never returned as a pose.

pub mod change;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rayon::prelude::*;

use crate::backend::Backend;
use crate::camera::Intrinsics;
use crate::error::{Error, Result};
use crate::geometry::look_at_camera_from_base;
use crate::mask::Mask;
use crate::render::PosedRobot;
use crate::solve::{coarse_search, solve, SolveOptions, SolveReport, View};

/// Settings of the automatic initialisation.
#[derive(Clone, Debug)]
pub struct InitOptions {
    /// Camera distances tried, metres.
    pub distances_m: Vec<f64>,
    /// Azimuth step, degrees.
    pub azimuth_step_deg: f64,
    /// Elevations tried, degrees above the base plane.
    pub elevations_deg: Vec<f64>,
    /// Camera rolls tried, degrees.
    pub rolls_deg: Vec<f64>,
    /// Views used for scoring hypotheses.
    pub scoring_views: usize,
    /// Hypotheses refined.
    pub refine_best: usize,
    /// Below this mean IoU the initialisation reports failure.
    pub min_iou: f64,
    /// A refined hypothesis at or above this mean IoU ends the search early.
    pub accept_iou: f64,
}

impl Default for InitOptions {
    fn default() -> Self {
        InitOptions {
            distances_m: vec![0.6, 0.8, 1.05, 1.4, 1.85, 2.5],
            azimuth_step_deg: 15.0,
            elevations_deg: vec![-10.0, 10.0, 30.0, 50.0, 70.0, 85.0],
            rolls_deg: vec![-30.0, 0.0, 30.0],
            scoring_views: 3,
            refine_best: 6,
            min_iou: 0.8,
            accept_iou: 0.95,
        }
    }
}

fn centre_of(robot: &PosedRobot) -> Vector3<f64> {
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for p in &robot.vertices_base {
        lo = lo.inf(&p.coords);
        hi = hi.sup(&p.coords);
    }
    (lo + hi) / 2.0
}

/// Camera hypotheses around `centre` (see the module docs), each turned so the centre appears
/// at pixel `aim` (the observed robot's centroid) instead of the principal point.
pub fn hypotheses(
    centre: &Vector3<f64>,
    camera: &Intrinsics,
    aim: [f64; 2],
    opts: &InitOptions,
) -> Vec<Isometry3<f64>> {
    let ray = Vector3::new(
        (aim[0] - camera.cx) / camera.fx,
        (aim[1] - camera.cy) / camera.fy,
        1.0,
    );
    let turn = UnitQuaternion::rotation_between(&Vector3::z(), &ray)
        .unwrap_or_else(UnitQuaternion::identity);
    let turn = Isometry3::from_parts(Translation3::identity(), turn);
    let mut out = Vec::new();
    let steps = (360.0 / opts.azimuth_step_deg).round().max(1.0) as usize;
    for &d in &opts.distances_m {
        for &el in &opts.elevations_deg {
            for a in 0..steps {
                let az = (a as f64 * opts.azimuth_step_deg).to_radians();
                let el = el.to_radians();
                let eye =
                    centre + Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin()) * d;
                let look = look_at_camera_from_base(&eye, centre, &Vector3::z());
                for &roll in &opts.rolls_deg {
                    let r = UnitQuaternion::from_scaled_axis(Vector3::z() * roll.to_radians());
                    out.push(turn * Isometry3::from_parts(Translation3::identity(), r) * look);
                }
            }
        }
    }
    out
}

/// Finds `camera_from_base` with no initial guess, or says why it could not.
pub fn initialise(
    renderer: &dyn Backend,
    camera: &Intrinsics,
    views: &[View],
    solve_opts: &SolveOptions,
    opts: &InitOptions,
) -> Result<SolveReport> {
    if views.is_empty() {
        return Err(Error::Solve("no views to initialise from".into()));
    }
    let pinhole = camera.undistorted();
    let factor = 8;
    let low = pinhole.downsampled(factor);
    let cell_m = 0.5 * f64::from(factor) / pinhole.fx.max(pinhole.fy);
    let scoring: Vec<(PosedRobot, Mask)> = views
        .iter()
        .take(opts.scoring_views.max(1))
        .map(|v| (v.robot.decimated(cell_m), v.observed.downsample(factor)))
        .collect();
    let centre = centre_of(&views[0].robot);
    let aim = centroid(&views[0].observed).unwrap_or([pinhole.cx, pinhole.cy]);
    let mut scored: Vec<(f64, Isometry3<f64>)> = hypotheses(&centre, &pinhole, aim, opts)
        .into_par_iter()
        .map(|pose| {
            let iou = scoring
                .iter()
                .map(|(r, m)| renderer.render(r, &low, &pose, None).mask.iou(m))
                .sum::<f64>()
                / scoring.len() as f64;
            (iou, pose)
        })
        .collect();
    scored.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut best: Option<SolveReport> = None;
    for start in &distinct_starts(&scored, opts.refine_best) {
        let refined = coarse_search(renderer, &pinhole, views, start, solve_opts);
        let Ok(report) = solve(renderer, &pinhole, views, &refined, solve_opts) else {
            continue;
        };
        let iou = report.mean_iou();
        if best.as_ref().is_none_or(|b| iou > b.mean_iou()) {
            best = Some(report);
        }
        if iou >= opts.accept_iou {
            break;
        }
    }
    match best {
        Some(r) if r.mean_iou() >= opts.min_iou => Ok(r),
        Some(r) => Err(Error::Solve(format!(
            "automatic initialisation failed: best mean mask IoU {:.2} < {:.2}; give initial_guess.camera_from_base or check the masks and the robot model",
            r.mean_iou(),
            opts.min_iou
        ))),
        None => Err(Error::Solve("automatic initialisation failed: no hypothesis could be refined".into())),
    }
}

/// Up to `count` of `scored` (best first) that differ from each other: the top scores are
/// mostly neighbours of one pose, and a wrong (e.g. mirrored) pose must not take every slot.
fn distinct_starts(scored: &[(f64, Isometry3<f64>)], count: usize) -> Vec<Isometry3<f64>> {
    let mut starts: Vec<Isometry3<f64>> = Vec::new();
    for (_, pose) in scored {
        if starts.len() >= count.max(1) {
            break;
        }
        let distinct = starts.iter().all(|s| {
            crate::geometry::rotation_error_deg(s, pose) > 25.0
                || crate::geometry::camera_centre_error_mm(s, pose) > 300.0
        });
        if distinct {
            starts.push(*pose);
        }
    }
    starts
}

/// Centroid of the robot pixels, or `None` for an empty mask.
fn centroid(mask: &Mask) -> Option<[f64; 2]> {
    let (mut su, mut sv, mut n) = (0.0, 0.0, 0usize);
    for v in 0..mask.height {
        for u in 0..mask.width {
            if mask.data[(v * mask.width + u) as usize] != 0 {
                su += f64::from(u);
                sv += f64::from(v);
                n += 1;
            }
        }
    }
    (n > 0).then(|| [su / n as f64, sv / n as f64])
}

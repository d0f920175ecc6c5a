//! The boundary residual model LM minimises: per pyramid level, rendered outline samples are
//! matched to the observed mask's outline (both ways) and summed into normal equations.

use std::sync::Arc;

use nalgebra::{Isometry3, Matrix6};
use rayon::prelude::*;

use super::{MountContact, SolveOptions, View};
use crate::camera::Intrinsics;
use crate::geometry::Twist;
use crate::mask::Mask;
use crate::render::{
    BoundarySample, Mount, PosedRobot, Silhouette, SilhouetteRenderer, ROW_CROSSING,
};

/// One pyramid level: the downsampled camera and observations, and the Cauchy scale there.
pub(super) struct Level {
    pub(super) camera: Intrinsics,
    /// Downsampling factor from the full-resolution image.
    pub(super) factor: u32,
    /// Cauchy scale at this level, pixels.
    pub(super) robust_scale_px: f64,
    /// Shared, so a level over a subset of the views costs no copy (the view jackknife).
    pub(super) views: Vec<Arc<ObservedLevel>>,
}

/// How far along a pixel row/column the observed transition is searched, pixels.
const SCAN_REACH_PX: i64 = 12;

/// Signed distance (outward positive, in the outline-normal direction) from a rendered outline
/// crossing to the nearest observed transition of the same sense on the same pixel row or
/// column; `None` when there is none within `reach` pixels.
fn scanline_residual(observed: &Mask, s: &BoundarySample, reach: i64) -> Option<f64> {
    let (along, normal_along, fixed) = if s.axis == ROW_CROSSING {
        (s.pixel[0], s.normal[0], s.pixel[1].round() as i64)
    } else {
        (s.pixel[1], s.normal[1], s.pixel[0].round() as i64)
    };
    let dir: i64 = if normal_along >= 0.0 { 1 } else { -1 };
    let at = |k: i64| {
        if s.axis == ROW_CROSSING {
            observed.get(k, fixed)
        } else {
            observed.get(fixed, k)
        }
    };
    let (w, h) = (i64::from(observed.width), i64::from(observed.height));
    let limit = if s.axis == ROW_CROSSING { w } else { h };
    let base = along.floor() as i64;
    let mut best: Option<f64> = None;
    for offset in 0..=reach {
        for k in [base + offset, base - offset] {
            // Transition between k and k+1, robot on the inner side (opposite `dir`).
            if k < 0 || k + 1 >= limit {
                continue;
            }
            let (inner, outer) = if dir > 0 { (k, k + 1) } else { (k + 1, k) };
            if at(inner) && !at(outer) {
                let x = k as f64 + 0.5;
                let d = (along - x) * f64::from(dir as i32);
                if best.is_none_or(|b: f64| d.abs() < b.abs()) {
                    best = Some(d);
                }
            }
        }
        if best.is_some() {
            break;
        }
    }
    best.map(|d| d * normal_along.abs())
}

impl Level {
    /// The observations of `views` at pyramid `factor` with Cauchy scale `robust_scale_px`.
    pub(super) fn new(
        camera: &Intrinsics,
        views: &[View],
        factor: u32,
        robust_scale_px: f64,
    ) -> Level {
        Level {
            camera: camera.downsampled(factor),
            factor,
            robust_scale_px,
            views: views
                .par_iter()
                .map(|v| Arc::new(ObservedLevel::new(&v.observed, factor)))
                .collect(),
        }
    }

    /// The same level over the views at `kept` only.
    pub(super) fn keeping(&self, kept: &[usize]) -> Level {
        Level {
            camera: self.camera.clone(),
            factor: self.factor,
            robust_scale_px: self.robust_scale_px,
            views: kept.iter().map(|&i| self.views[i].clone()).collect(),
        }
    }
}

/// One view's observation at one pyramid level.
pub(super) struct ObservedLevel {
    mask: Mask,
    /// Observed outline crossings: position, outline length they stand for.
    outline: Vec<([f64; 2], f64)>,
}

impl ObservedLevel {
    pub(super) fn new(observed: &Mask, factor: u32) -> ObservedLevel {
        let mask = observed.downsample(factor);
        let outline = mask
            .outline_crossings()
            .into_iter()
            .map(|x| {
                // Outline normal from a 3x3 Sobel of the mask around the crossing; a crossing
                // stands for 1 / (|n_x| + |n_y|) px of outline (see `render::outline_samples`).
                let (u, v) = (x[0].round() as i64, x[1].round() as i64);
                let m = |du: i64, dv: i64| f64::from(u8::from(mask.get(u + du, v + dv)));
                let gx = m(1, -1) + 2.0 * m(1, 0) + m(1, 1) - m(-1, -1) - 2.0 * m(-1, 0) - m(-1, 1);
                let gy = m(-1, 1) + 2.0 * m(0, 1) + m(1, 1) - m(-1, -1) - 2.0 * m(0, -1) - m(1, -1);
                let norm = gx.hypot(gy);
                let ds = if norm > 0.0 {
                    norm / (gx.abs() + gy.abs())
                } else {
                    1.0
                };
                (x, ds)
            })
            .collect();
        ObservedLevel { mask, outline }
    }
}

/// Normal equations (`h`, `g`) of Cauchy-weighted outline residuals, with their robust cost,
/// weighted squared sum and the outline length (px) they cover.
#[derive(Clone)]
pub(super) struct Normal {
    cost: f64,
    pub(super) h: Matrix6<f64>,
    pub(super) g: Twist,
    /// Cross term of the pose and the mask offset, the offset's curvature and gradient.
    pub(super) h_pose_offset: Twist,
    pub(super) h_offset: f64,
    pub(super) g_offset: f64,
    pub(super) weighted_sq: f64,
    pub(super) length: f64,
}

impl Normal {
    fn zero() -> Normal {
        Normal {
            cost: 0.0,
            h: Matrix6::zeros(),
            g: Twist::zeros(),
            h_pose_offset: Twist::zeros(),
            h_offset: 0.0,
            g_offset: 0.0,
            weighted_sq: 0.0,
            length: 0.0,
        }
    }

    /// Adds one Cauchy-weighted residual `r` with Jacobian `j` standing for `ds` px of outline.
    #[inline]
    fn add(&mut self, r: f64, j: &Twist, j_offset: f64, ds: f64, c: f64) {
        let u = (r / c) * (r / c);
        let (w, cost) = (1.0 / (1.0 + u), 0.5 * c * c * (1.0 + u).ln());
        self.cost += ds * cost;
        self.h += j * j.transpose() * (w * ds);
        self.g += j * (w * r * ds);
        self.h_pose_offset += j * (w * j_offset * ds);
        self.h_offset += w * j_offset * j_offset * ds;
        self.g_offset += w * r * j_offset * ds;
        self.weighted_sq += w * r * r * ds;
        self.length += ds;
    }

    /// A residual beyond the search reach: costs the capped amount, pulls nothing.
    #[inline]
    fn add_outlier(&mut self, cap: f64, ds: f64, c: f64) {
        let u = (cap / c) * (cap / c);
        self.cost += ds * 0.5 * c * c * (1.0 + u).ln();
    }

    /// The pose's normal matrix, with the mask offset eliminated (its Schur complement) when
    /// `with_offset`: the curvature left to the pose once the offset is fitted too.
    pub(super) fn pose_normal(&self, with_offset: bool) -> Matrix6<f64> {
        if !with_offset || self.h_offset <= 0.0 {
            return self.h;
        }
        self.h - self.h_pose_offset * self.h_pose_offset.transpose() / self.h_offset
    }

    fn merge(mut self, o: Normal) -> Normal {
        self.cost += o.cost;
        self.h += o.h;
        self.g += o.g;
        self.h_pose_offset += o.h_pose_offset;
        self.h_offset += o.h_offset;
        self.g_offset += o.g_offset;
        self.weighted_sq += o.weighted_sq;
        self.length += o.length;
        self
    }
}

/// Bucket grid over the rendered outline samples for nearest-sample queries.
struct SampleGrid {
    cell: f64,
    cols: usize,
    rows: usize,
    starts: Vec<u32>,
    items: Vec<u32>,
}

impl SampleGrid {
    fn new(samples: &[BoundarySample], width: u32, height: u32, cell: f64) -> SampleGrid {
        let cols = (f64::from(width) / cell).ceil() as usize + 1;
        let rows = (f64::from(height) / cell).ceil() as usize + 1;
        let key = |s: &BoundarySample| {
            let cx = ((s.pixel[0] + 0.5) / cell)
                .floor()
                .clamp(0.0, (cols - 1) as f64) as usize;
            let cy = ((s.pixel[1] + 0.5) / cell)
                .floor()
                .clamp(0.0, (rows - 1) as f64) as usize;
            cy * cols + cx
        };
        let mut counts = vec![0u32; cols * rows + 1];
        for s in samples {
            counts[key(s) + 1] += 1;
        }
        for i in 1..counts.len() {
            counts[i] += counts[i - 1];
        }
        let mut fill = counts.clone();
        let mut items = vec![0u32; samples.len()];
        for (i, s) in samples.iter().enumerate() {
            let k = key(s);
            items[fill[k] as usize] = i as u32;
            fill[k] += 1;
        }
        SampleGrid {
            cell,
            cols,
            rows,
            starts: counts,
            items,
        }
    }

    /// Nearest sample within `reach` cells of `p`.
    fn nearest(&self, samples: &[BoundarySample], p: [f64; 2], reach: i64) -> Option<usize> {
        let cx = ((p[0] + 0.5) / self.cell).floor() as i64;
        let cy = ((p[1] + 0.5) / self.cell).floor() as i64;
        let mut best = (f64::INFINITY, None);
        for y in (cy - reach).max(0)..=(cy + reach).min(self.rows as i64 - 1) {
            for x in (cx - reach).max(0)..=(cx + reach).min(self.cols as i64 - 1) {
                let k = y as usize * self.cols + x as usize;
                for &i in &self.items[self.starts[k] as usize..self.starts[k + 1] as usize] {
                    let s = &samples[i as usize];
                    let d = (s.pixel[0] - p[0]).powi(2) + (s.pixel[1] - p[1]).powi(2);
                    if d < best.0 {
                        best = (d, Some(i as usize));
                    }
                }
            }
        }
        best.1
    }
}

/// Outline grid cell, pixels of the level's image.
const GRID_CELL_PX: f64 = 8.0;
/// Search reach of the observed→rendered match, cells (beyond it a residual counts as the cap).
const GRID_REACH: i64 = 2;

/// Normal equations of the boundary residuals of `robots` (one per observation in `level`).
pub(super) fn accumulate(
    renderer: &dyn SilhouetteRenderer,
    robots: &[&PosedRobot],
    level: &Level,
    pose: &Isometry3<f64>,
    offset_px: f64,
    opts: &SolveOptions,
) -> Normal {
    accumulate_keeping(renderer, robots, level, pose, offset_px, opts).0
}

/// [`accumulate`], also handing back the silhouettes it rendered (their masks score the
/// final pose without a second render).
pub(super) fn accumulate_keeping(
    renderer: &dyn SilhouetteRenderer,
    robots: &[&PosedRobot],
    level: &Level,
    pose: &Isometry3<f64>,
    offset_px: f64,
    opts: &SolveOptions,
) -> (Normal, Vec<Silhouette>) {
    // One call for all views: a GPU backend draws them in one submission.
    let silhouettes =
        renderer.render_many(robots, &level.camera, pose, Some(opts.boundary_step_px));
    let normal = view_normals(&silhouettes, robots, level, pose, offset_px, opts)
        .reduce(Normal::zero, Normal::merge);
    (normal, silhouettes)
}

/// Each of `silhouettes`' normal equations against its observation in `level`.
fn view_normals<'a>(
    silhouettes: &'a [Silhouette],
    robots: &'a [&PosedRobot],
    level: &'a Level,
    pose: &'a Isometry3<f64>,
    offset_px: f64,
    opts: &'a SolveOptions,
) -> impl IndexedParallelIterator<Item = Normal> + 'a {
    silhouettes
        .par_iter()
        .zip(&level.views)
        .zip(robots)
        .map(move |((sil, obs), robot)| {
            view_normal(sil, obs, level, offset_px, &LeftOut::of(robot, opts, pose))
        })
}

/// Each view's normal equations at `pose`, apart: summed over some of the views
/// ([`sum_over`]) they are those views' [`accumulate`] without rendering them again.
pub(super) fn per_view_normals(
    renderer: &dyn SilhouetteRenderer,
    robots: &[&PosedRobot],
    level: &Level,
    pose: &Isometry3<f64>,
    offset_px: f64,
    opts: &SolveOptions,
) -> Vec<Normal> {
    let silhouettes =
        renderer.render_many(robots, &level.camera, pose, Some(opts.boundary_step_px));
    view_normals(&silhouettes, robots, level, pose, offset_px, opts).collect()
}

/// The normal equations of the views at `kept`, from [`per_view_normals`].
pub(super) fn sum_over(normals: &[Normal], kept: &[usize]) -> Normal {
    kept.iter()
        .map(|&i| normals[i].clone())
        .fold(Normal::zero(), Normal::merge)
}

/// One view's Cauchy-weighted normal equations, with the observed outline lying
/// `offset_px` (full-resolution pixels) outward of the rendered one.
fn view_normal(
    sil: &Silhouette,
    obs: &ObservedLevel,
    level: &Level,
    offset_px: f64,
    left_out: &LeftOut<'_>,
) -> Normal {
    let c = level.robust_scale_px;
    let per_level_px = 1.0 / f64::from(level.factor);
    let mut n = Normal::zero();
    view_residuals(sil, obs, &level.camera, left_out, |res| match res.r {
        Some(r) => {
            let j_offset = res.offset_sign * per_level_px;
            n.add(r + j_offset * offset_px, &res.j, j_offset, res.ds, c)
        }
        None => n.add_outlier(res.cap, res.ds, c),
    });
    n
}

/// The rendered outline samples a fit leaves out: those at the robot's mount contact when
/// [`SolveOptions::mount_contact`] is [`MountContact::LeaveOut`] ([`Mount::holds`]), else none.
pub(super) struct LeftOut<'a> {
    mount: Option<&'a Mount>,
    base_from_camera: Isometry3<f64>,
}

impl<'a> LeftOut<'a> {
    /// What `opts` leaves out of `robot`'s outline rendered at `camera_from_base`.
    pub(super) fn of(
        robot: &'a PosedRobot,
        opts: &SolveOptions,
        camera_from_base: &Isometry3<f64>,
    ) -> LeftOut<'a> {
        LeftOut::mount_if(
            robot,
            opts.mount_contact == MountContact::LeaveOut,
            camera_from_base,
        )
    }

    /// Whether anything is left out.
    pub(super) fn any(&self) -> bool {
        self.mount.is_some()
    }

    /// The mount contact of `robot` when `leave_out`, else nothing.
    pub(super) fn mount_if(
        robot: &'a PosedRobot,
        leave_out: bool,
        camera_from_base: &Isometry3<f64>,
    ) -> LeftOut<'a> {
        LeftOut {
            mount: leave_out.then(|| robot.mount()).flatten(),
            base_from_camera: camera_from_base.inverse(),
        }
    }

    /// Whether outline sample `s` is left out.
    pub(super) fn sample(&self, s: &BoundarySample) -> bool {
        self.mount
            .is_some_and(|m| m.holds(s, &self.base_from_camera))
    }
}

/// One outline residual of a view: where it sits, what it is and how it moves with the pose.
pub(super) struct Residual {
    /// Signed distance (pixels); `None` when no match lies within reach.
    pub(super) r: Option<f64>,
    /// What an unmatched residual counts as, pixels.
    pub(super) cap: f64,
    /// Derivative of `r` with respect to the left increment of `camera_from_base`.
    pub(super) j: Twist,
    /// How the mask offset enters the model residual `r + offset_sign * b` (`b` the observed
    /// outline's outward offset, pixels of the level): +1 for a rendered crossing, whose raw
    /// `r` reads `-b` at the true pose (the observed outline lies `b` outside it), -1 for an
    /// observed crossing, whose raw `r` reads `+b`.
    pub(super) offset_sign: f64,
    /// Outline length it stands for, pixels.
    pub(super) ds: f64,
    /// Image position, pixels.
    pub(super) pixel: [f64; 2],
    /// The rendered outline sample it is measured against (its vertex gives its link).
    pub(super) sample: usize,
}

/// Every outline residual of one view, both ways: rendered outline -> observed outline along
/// the same pixel row (or column), then observed outline -> nearest rendered sample's tangent.
/// The normal equations and the covariance read the same residuals from here.
///
/// Samples that `left_out` holds, and observed crossings whose nearest sample is one, give no
/// residual.
pub(super) fn view_residuals(
    sil: &Silhouette,
    obs: &ObservedLevel,
    camera: &Intrinsics,
    left_out: &LeftOut<'_>,
    mut sink: impl FnMut(Residual),
) {
    let is_left_out = |i: usize| sil.boundary.get(i).is_some_and(|s| left_out.sample(s));
    let mut jacobians = Vec::with_capacity(sil.boundary.len());
    // The observed transition of the same sense nearest the rendered crossing. Both sit on the
    // same grid, so the residual is unbiased (uniform in +-0.5 px at the truth).
    for (i, s) in sil.boundary.iter().enumerate() {
        let jp = s.pixel_jacobian(camera);
        let jn: Twist = (jp.row(0) * s.normal[0] + jp.row(1) * s.normal[1]).transpose();
        jacobians.push(jn);
        if is_left_out(i) {
            continue;
        }
        sink(Residual {
            r: scanline_residual(&obs.mask, s, SCAN_REACH_PX),
            cap: SCAN_REACH_PX as f64,
            j: jn,
            offset_sign: 1.0,
            ds: s.length_px,
            pixel: s.pixel,
            sample: i,
        });
    }
    // Signed distance to the tangent of the nearest rendered sample; keeps the render from
    // sliding out of view or shrinking.
    let grid = SampleGrid::new(&sil.boundary, camera.width, camera.height, GRID_CELL_PX);
    for &(y, ds) in &obs.outline {
        let nearest = grid.nearest(&sil.boundary, y, GRID_REACH);
        let r = nearest.map(|i| {
            let s = &sil.boundary[i];
            s.normal[0] * (y[0] - s.pixel[0]) + s.normal[1] * (y[1] - s.pixel[1])
        });
        if nearest.is_some_and(is_left_out) {
            continue;
        }
        let i = nearest.unwrap_or(0);
        sink(Residual {
            r,
            cap: GRID_CELL_PX * GRID_REACH as f64,
            j: jacobians.get(i).map_or(Twist::zeros(), |j| -j),
            offset_sign: -1.0,
            ds,
            pixel: y,
            sample: i,
        });
    }
}

/// How far (pixels, full resolution) the masks' outline at the mount contact may lie from the
/// rendered robot's, beyond where the rest of the outline lies, before the contact counts as
/// disagreeing: well past a segmenter's rim error (under a pixel or two on real frames),
/// well under a flange or a plate (several pixels).
pub const MOUNT_DISAGREEMENT_PX: f64 = 2.0;

/// Fewest matched outline samples at the mount contact for a view to take part.
const MOUNT_MIN_SAMPLES: usize = 20;

/// Lowest mask IoU at which a view takes part: below it the view is not fitted (wrong joints,
/// a round that has not settled), and its outline's offsets say nothing about the mount.
const MOUNT_MIN_VIEW_IOU: f64 = 0.85;

/// Fewest well-fitted views showing the contact that can decide.
const MOUNT_MIN_VIEWS: usize = 3;

/// Whether the masks disagree with the rendered robot at its mount contact, at `pose`: in two
/// thirds of the views that show the contact and fit (at least three), the median signed
/// distance from the rendered outline there to the observed one differs by more than
/// [`MOUNT_DISAGREEMENT_PX`] from the median over the rest of the outline. Measured against
/// the rest, so that masks fat or thin all round do not count; over most views, so that one
/// view's blob does not decide; only on views that fit, so that a view with wrong joints or
/// an unsettled round does not either. The real xArm7 set disagrees in 7 to 10 of 10 views
/// (SAM 2 leaves out the base's flange: 7–10 px; the `builtin` masks take in the plate:
/// 2–4 px); the simulator never does.
pub fn mount_contact_disagrees(
    renderer: &dyn SilhouetteRenderer,
    camera: &Intrinsics,
    views: &[View],
    pose: &Isometry3<f64>,
    opts: &SolveOptions,
) -> bool {
    let robots: Vec<&PosedRobot> = views.iter().map(|v| &v.robot).collect();
    if robots.iter().all(|r| r.mount().is_none()) {
        return false;
    }
    let level = Level::new(camera, views, 1, opts.fine_robust_scale_px);
    let silhouettes =
        renderer.render_many(&robots, &level.camera, pose, Some(opts.boundary_step_px));
    let gaps: Vec<f64> = silhouettes
        .par_iter()
        .zip(&level.views)
        .zip(&robots)
        .filter_map(|((sil, obs), robot)| mount_gap_px(sil, obs, &level.camera, robot, pose))
        .collect();
    let disagreeing = gaps
        .iter()
        .filter(|g| g.abs() > MOUNT_DISAGREEMENT_PX)
        .count();
    let verdict = gaps.len() >= MOUNT_MIN_VIEWS && 3 * disagreeing >= 2 * gaps.len();
    tracing::debug!(
        "mount contact: outline gaps {:?} px over {} views: {}",
        gaps.iter()
            .map(|g| (g * 100.0).round() / 100.0)
            .collect::<Vec<_>>(),
        views.len(),
        if verdict { "left out" } else { "fitted" }
    );
    verdict
}

/// One view's median outward offset of the observed outline at the mount contact's rendered
/// samples, less the median over its other samples; `None` when the view shows too little
/// of the contact or does not fit.
fn mount_gap_px(
    sil: &Silhouette,
    obs: &ObservedLevel,
    camera: &Intrinsics,
    robot: &PosedRobot,
    pose: &Isometry3<f64>,
) -> Option<f64> {
    let mount = robot.mount()?;
    if sil.mask.iou(&obs.mask) < MOUNT_MIN_VIEW_IOU {
        return None;
    }
    let base_from_camera = pose.inverse();
    let everything = LeftOut {
        mount: None,
        base_from_camera,
    };
    let (mut foot, mut rest) = (Vec::new(), Vec::new());
    view_residuals(sil, obs, camera, &everything, |res| {
        // Rendered crossings only: their raw residual reads minus the outward offset.
        if let (Some(r), true) = (res.r, res.offset_sign > 0.0) {
            match mount.holds(&sil.boundary[res.sample], &base_from_camera) {
                true => foot.push(-r),
                false => rest.push(-r),
            }
        }
    });
    if foot.len() < MOUNT_MIN_SAMPLES || rest.len() < MOUNT_MIN_SAMPLES {
        return None;
    }
    Some(median(&mut foot) - median(&mut rest))
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Robust cost per pixel of outline (infinite when nothing of the robot is in view).
pub(super) fn total_cost(n: &Normal) -> f64 {
    if n.length > 0.0 {
        n.cost / n.length
    } else {
        f64::INFINITY
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{exp_se3, look_at_camera_from_base};
    use crate::render::CpuRenderer;
    use crate::robot::RobotModel;
    use nalgebra::Vector3;

    #[test]
    fn per_view_normals_summed_over_some_views_are_those_views_accumulated() {
        let urdf = concat!(env!("CARGO_MANIFEST_DIR"), "/robots/xarm6/robot.urdf");
        let robot = RobotModel::from_urdf(urdf).unwrap();
        let camera = Intrinsics::pinhole(320, 240, 300.0, 300.0, 159.5, 119.5);
        let truth = look_at_camera_from_base(
            &Vector3::new(1.2, 0.5, 0.7),
            &Vector3::new(0.2, 0.0, 0.3),
            &Vector3::z(),
        );
        let views: Vec<View> = (0..3)
            .map(|k| {
                let posed =
                    PosedRobot::new(&robot, &[0.4 * f64::from(k), -0.4, -0.5, 0.2, 0.9, 0.1]);
                let observed = CpuRenderer.render(&posed, &camera, &truth, None).mask;
                View {
                    robot: posed,
                    observed,
                }
            })
            .collect();
        let opts = SolveOptions::default();
        let level = Level::new(&camera, &views, 1, 0.5);
        let pose = exp_se3(&Twist::new(0.004, -0.003, 0.002, 0.01, -0.005, 0.007)) * truth;
        let robots: Vec<&PosedRobot> = views.iter().map(|v| &v.robot).collect();
        let normals = per_view_normals(&CpuRenderer, &robots, &level, &pose, 0.3, &opts);
        let kept = [0, 2];
        let summed = sum_over(&normals, &kept);
        let kept_robots = [robots[0], robots[2]];
        let direct = accumulate(
            &CpuRenderer,
            &kept_robots,
            &level.keeping(&kept),
            &pose,
            0.3,
            &opts,
        );
        assert!(direct.length > 100.0 && direct.cost > 0.0);
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1e-12);
        assert!(close(summed.cost, direct.cost) && close(summed.length, direct.length));
        assert!((summed.h - direct.h).norm() <= 1e-9 * direct.h.norm());
        assert!((summed.g - direct.g).norm() <= 1e-9 * direct.g.norm());
        // Leaving the middle view out changes them: the sum is over the kept views only.
        let all = sum_over(&normals, &[0, 1, 2]);
        assert!(all.length > summed.length + 50.0);
    }
}

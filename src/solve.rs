//! Camera-pose solvers over many views.
//!
//! - [`Optimizer::Lm`] (default): coarse-to-fine Levenberg–Marquardt on a sub-pixel boundary
//!   residual — every outline sample of the rendered silhouette should lie on the observed
//!   mask's boundary; its residual is the observed mask's signed distance at the sample, with
//!   Cauchy weights so segmentation blobs and missed parts do not drag the pose.
//! - [`Optimizer::Adam`]: the paper's setting (Adam, lr 3e-3, 1000 full-resolution steps on the
//!   mask loss, best iterate), kept as the baseline the benchmark compares against.
//!
//! Both optimise a left se(3) increment of `camera_from_base` (see [`crate::geometry`]).

use nalgebra::{Isometry3, Matrix6, Vector3};
use rayon::prelude::*;

use crate::backend::Backend;
use crate::camera::Intrinsics;
use crate::error::{Error, Result};
use crate::geometry::{exp_se3, skew, Twist};
use crate::mask::Mask;
use crate::objective::{loss_gradient, mask_loss};
use crate::render::{BoundarySample, PosedRobot, Silhouette, SilhouetteRenderer, ROW_CROSSING};

/// One observation: the robot posed at the view's joints and the observed mask in the
/// undistorted pinhole image.
#[derive(Clone, Debug)]
pub struct View {
    /// Robot geometry at this view's joint vector.
    pub robot: PosedRobot,
    /// Observed robot mask (pinhole image, camera size).
    pub observed: Mask,
}

/// Which optimiser to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Optimizer {
    /// Coarse-to-fine Levenberg–Marquardt on the boundary residual (default).
    #[default]
    Lm,
    /// The paper's Adam baseline.
    Adam,
}

impl std::str::FromStr for Optimizer {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "lm" => Ok(Optimizer::Lm),
            "adam" => Ok(Optimizer::Adam),
            other => Err(format!("unknown optimizer '{other}': use lm or adam")),
        }
    }
}

/// Solver settings.
#[derive(Clone, Debug)]
pub struct SolveOptions {
    /// Optimiser.
    pub optimizer: Optimizer,
    /// Image-pyramid downsampling factors, coarse to fine (LM).
    pub pyramid: Vec<u32>,
    /// Iteration cap per pyramid level (LM).
    pub max_iterations_per_level: usize,
    /// Cauchy scale of the boundary residual at coarse levels, pixels of the level's image
    /// (LM): wide enough to pull in a rough start.
    pub robust_scale_px: f64,
    /// Cauchy scale at full resolution (LM): tight, so segmentation noise and blobs lose
    /// their pull (chosen by `easyhec bench accuracy`).
    pub fine_robust_scale_px: f64,
    /// Outline sample spacing, pixels.
    pub boundary_step_px: f64,
    /// Adam steps.
    pub adam_steps: usize,
    /// Adam learning rate (rad and m per step).
    pub adam_learning_rate: f64,
    /// Inflation of the covariance for the correlation of neighbouring outline samples
    /// (pixels of outline per independent observation).
    pub correlation_length_px: f64,
    /// Below this mean IoU the LM result triggers a wide coarse search and a second solve.
    pub recover_below_iou: f64,
    /// Seed of the coarse search and the posterior refinement.
    pub search_seed: u64,
    /// Poses drawn in the posterior refinement after LM (0 or 1 disables it).
    pub refine_samples: usize,
    /// Best-scoring samples averaged by the refinement.
    pub refine_keep: usize,
    /// Covariance inflation for the refinement's sampling.
    pub refine_inflation: f64,
    /// Vertex-clustering cell at coarse pyramid levels, as a fraction of the level's pixel
    /// footprint at 1 m.
    pub coarse_cell_fraction: f64,
}

impl Default for SolveOptions {
    fn default() -> Self {
        SolveOptions {
            optimizer: Optimizer::Lm,
            pyramid: vec![8, 4, 2, 1],
            max_iterations_per_level: 25,
            robust_scale_px: 2.0,
            fine_robust_scale_px: 0.5,
            boundary_step_px: 1.0,
            adam_steps: 1000,
            adam_learning_rate: 3e-3,
            correlation_length_px: 16.0,
            recover_below_iou: 0.8,
            search_seed: 0,
            refine_samples: 64,
            refine_keep: 8,
            refine_inflation: 4.0,
            coarse_cell_fraction: 0.3,
        }
    }
}

/// 1-sigma uncertainty about the camera axes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Uncertainty {
    /// Rotation about camera x, y, z, degrees.
    pub rotation_deg: [f64; 3],
    /// Translation of `camera_from_base` along camera x, y, z, millimetres.
    pub translation_mm: [f64; 3],
}

/// What a solve found.
#[derive(Clone, Debug)]
pub struct SolveReport {
    /// The estimate.
    pub camera_from_base: Isometry3<f64>,
    /// 6x6 covariance of the left increment `(rho, phi)` at the estimate.
    pub covariance: Matrix6<f64>,
    /// 1-sigma uncertainty derived from `covariance`.
    pub uncertainty: Uncertainty,
    /// Residual variance of one pixel of outline at full resolution, px^2 (the per-sample
    /// variance times the correlation length): what one more view's outline is worth.
    pub outline_noise_px2: f64,
    /// Mask IoU per view at the estimate (full resolution).
    pub per_view_iou: Vec<f64>,
    /// The paper's mask loss at the estimate.
    pub loss: f64,
    /// Renders performed (each covers all views).
    pub iterations: usize,
    /// Accepted iterates, first to last (exploration's "trajectory" candidates).
    pub trajectory: Vec<Isometry3<f64>>,
}

struct Level {
    camera: Intrinsics,
    /// Cauchy scale at this level, pixels.
    robust_scale_px: f64,
    views: Vec<ObservedLevel>,
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
    fn new(camera: &Intrinsics, views: &[View], factor: u32, robust_scale_px: f64) -> Level {
        Level {
            camera: camera.downsampled(factor),
            robust_scale_px,
            views: views
                .par_iter()
                .map(|v| ObservedLevel::new(&v.observed, factor))
                .collect(),
        }
    }
}

/// One view's observation at one pyramid level.
struct ObservedLevel {
    mask: Mask,
    /// Observed outline crossings: position, outline length they stand for.
    outline: Vec<([f64; 2], f64)>,
}

impl ObservedLevel {
    fn new(observed: &Mask, factor: u32) -> ObservedLevel {
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

struct Normal {
    cost: f64,
    h: Matrix6<f64>,
    g: Twist,
    weighted_sq: f64,
    length: f64,
}

impl Normal {
    fn zero() -> Normal {
        Normal {
            cost: 0.0,
            h: Matrix6::zeros(),
            g: Twist::zeros(),
            weighted_sq: 0.0,
            length: 0.0,
        }
    }

    /// Adds one Cauchy-weighted residual `r` with Jacobian `j` standing for `ds` px of outline.
    #[inline]
    fn add(&mut self, r: f64, j: &Twist, ds: f64, c: f64) {
        let u = (r / c) * (r / c);
        let (w, cost) = (1.0 / (1.0 + u), 0.5 * c * c * (1.0 + u).ln());
        self.cost += ds * cost;
        self.h += j * j.transpose() * (w * ds);
        self.g += j * (w * r * ds);
        self.weighted_sq += w * r * r * ds;
        self.length += ds;
    }

    /// A residual beyond the search reach: costs the capped amount, pulls nothing.
    #[inline]
    fn add_outlier(&mut self, cap: f64, ds: f64, c: f64) {
        let u = (cap / c) * (cap / c);
        self.cost += ds * 0.5 * c * c * (1.0 + u).ln();
    }

    fn merge(mut self, o: Normal) -> Normal {
        self.cost += o.cost;
        self.h += o.h;
        self.g += o.g;
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
fn accumulate(
    renderer: &dyn SilhouetteRenderer,
    robots: &[&PosedRobot],
    level: &Level,
    pose: &Isometry3<f64>,
    opts: &SolveOptions,
) -> Normal {
    accumulate_keeping(renderer, robots, level, pose, opts).0
}

/// [`accumulate`], also handing back the silhouettes it rendered (their masks score the
/// final pose without a second render).
fn accumulate_keeping(
    renderer: &dyn SilhouetteRenderer,
    robots: &[&PosedRobot],
    level: &Level,
    pose: &Isometry3<f64>,
    opts: &SolveOptions,
) -> (Normal, Vec<Silhouette>) {
    let c = level.robust_scale_px;
    let cap = GRID_CELL_PX * GRID_REACH as f64;
    // One call for all views: a GPU backend draws them in one submission.
    let silhouettes =
        renderer.render_many(robots, &level.camera, pose, Some(opts.boundary_step_px));
    let normal = silhouettes
        .par_iter()
        .zip(&level.views)
        .map(|(sil, obs)| {
            let mut n = Normal::zero();
            let mut jacobians = Vec::with_capacity(sil.boundary.len());
            // Rendered outline -> observed outline along the same pixel row (or column): the
            // observed transition of the same sense nearest the rendered crossing. Both sit on
            // the same grid, so the residual is unbiased (uniform in +-0.5 px at the truth).
            for s in &sil.boundary {
                let jp = s.pixel_jacobian(&level.camera);
                let jn = (jp.row(0) * s.normal[0] + jp.row(1) * s.normal[1]).transpose();
                jacobians.push(jn);
                match scanline_residual(&obs.mask, s, SCAN_REACH_PX) {
                    Some(r) => n.add(r, &jn, s.length_px, c),
                    None => n.add_outlier(SCAN_REACH_PX as f64, s.length_px, c),
                }
            }
            // Observed outline -> rendered outline: signed distance to the tangent of the
            // nearest rendered sample; keeps the render from sliding out of view or shrinking.
            let grid = SampleGrid::new(
                &sil.boundary,
                level.camera.width,
                level.camera.height,
                GRID_CELL_PX,
            );
            for &(y, ds) in &obs.outline {
                match grid.nearest(&sil.boundary, y, GRID_REACH) {
                    Some(i) => {
                        let s = &sil.boundary[i];
                        let r =
                            s.normal[0] * (y[0] - s.pixel[0]) + s.normal[1] * (y[1] - s.pixel[1]);
                        n.add(r, &(-jacobians[i]), ds, c);
                    }
                    None => n.add_outlier(cap, ds, c),
                }
            }
            n
        })
        .reduce(Normal::zero, Normal::merge);
    (normal, silhouettes)
}

fn total_cost(n: &Normal) -> f64 {
    if n.length > 0.0 {
        n.cost / n.length
    } else {
        f64::INFINITY
    }
}

/// Solves for `camera_from_base` from `views`, starting at `initial`.
pub fn solve(
    renderer: &dyn Backend,
    camera: &Intrinsics,
    views: &[View],
    initial: &Isometry3<f64>,
    opts: &SolveOptions,
) -> Result<SolveReport> {
    if views.is_empty() {
        return Err(Error::Solve("no views to solve from".into()));
    }
    let camera = camera.undistorted();
    let (pose, iterations, trajectory) = match opts.optimizer {
        Optimizer::Lm => solve_lm(renderer, &camera, views, initial, opts)?,
        Optimizer::Adam => solve_adam(renderer, &camera, views, initial, opts),
    };
    let report = finish(renderer, &camera, views, pose, iterations, trajectory, opts)?;
    if opts.optimizer == Optimizer::Adam {
        return Ok(report);
    }
    if report.mean_iou() >= opts.recover_below_iou {
        return refine(renderer, &camera, views, report, opts);
    }
    // The fast path landed in a poor local minimum (or the guess was rough): search a wide
    // neighbourhood of the guess at low resolution, then refine from the best candidate.
    let start = coarse_search(renderer, &camera, views, initial, opts);
    let (pose, more, trajectory) = solve_lm(renderer, &camera, views, &start, opts)?;
    let retry = finish(
        renderer,
        &camera,
        views,
        pose,
        iterations + more,
        trajectory,
        opts,
    )?;
    let best = if retry.mean_iou() > report.mean_iou() {
        retry
    } else {
        report
    };
    refine(renderer, &camera, views, best, opts)
}

/// Largest band half-width (pixels) the refinement accepts; beyond it the posterior is too wide
/// for a local refinement and the LM estimate stands.
const REFINE_BAND_PX: i64 = 8;

/// Largest image displacement of any robot bounding-box corner, over all views and offsets.
fn max_displacement_px(
    camera: &Intrinsics,
    views: &[View],
    centre: &Isometry3<f64>,
    offsets: &[Twist],
) -> f64 {
    let mut worst: f64 = 0.0;
    for v in views {
        let (mut lo, mut hi) = (
            nalgebra::Point3::new(f64::MAX, f64::MAX, f64::MAX),
            nalgebra::Point3::new(f64::MIN, f64::MIN, f64::MIN),
        );
        for p in &v.robot.vertices_base {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        for k in 0..8 {
            let c = nalgebra::Point3::new(
                if k & 1 == 0 { lo.x } else { hi.x },
                if k & 2 == 0 { lo.y } else { hi.y },
                if k & 4 == 0 { lo.z } else { hi.z },
            );
            let p0 = centre * c;
            if p0.z <= 0.0 {
                continue;
            }
            let x0 = camera.project(&p0);
            for xi in offsets {
                let p = exp_se3(xi) * p0;
                if p.z > 0.0 {
                    let x = camera.project(&p);
                    worst = worst.max((x[0] - x0[0]).hypot(x[1] - x0[1]));
                }
            }
        }
    }
    worst
}

/// The part of a view that poses near `centre` can change: pixels within `radius` of the
/// rendered outline, and the triangles whose (dilated) bounds touch them. Samples render only
/// the band's window of the image and only the vertices its triangles use (see
/// [`crate::scoring::cpu::band_mismatches`]), so one sample costs a small fraction of a full
/// render.
struct Band {
    robot: PosedRobot,
    /// Disagreeing pixels outside the band (constant for nearby poses).
    outside_wrong: usize,
    /// Pixels of the whole image, the loss's denominator.
    image_pixels: usize,
    /// The band over the whole image, one byte a pixel (for
    /// [`crate::scoring::BatchScoring::band_mismatches`]).
    image_band: Vec<u8>,
}

impl Band {
    fn new(
        renderer: &dyn SilhouetteRenderer,
        camera: &Intrinsics,
        view: &View,
        centre: &Isometry3<f64>,
        radius: i64,
    ) -> Band {
        let rendered = renderer.render(&view.robot, camera, centre, None).mask;
        let (w, h) = (i64::from(camera.width), i64::from(camera.height));
        // Band = pixels within `radius` (Chebyshev) of a rendered outline pixel.
        let mut band = vec![0u8; (w * h) as usize];
        for v in 0..h {
            for u in 0..w {
                let here = rendered.get(u, v);
                let edge = (u + 1 < w && rendered.get(u + 1, v) != here)
                    || (v + 1 < h && rendered.get(u, v + 1) != here);
                if edge {
                    for dv in (v - radius).max(0)..=(v + radius).min(h - 1) {
                        let row = (dv * w) as usize;
                        band[row + (u - radius).max(0) as usize
                            ..=row + (u + radius).min(w - 1) as usize]
                            .fill(1);
                    }
                }
            }
        }
        // Summed-area table for rectangle queries.
        let stride = (w + 1) as usize;
        let mut sat = vec![0u32; stride * (h + 1) as usize];
        for v in 0..h as usize {
            let mut run = 0u32;
            for u in 0..w as usize {
                run += u32::from(band[v * w as usize + u]);
                sat[(v + 1) * stride + u + 1] = sat[v * stride + u + 1] + run;
            }
        }
        let any = |x0: i64, y0: i64, x1: i64, y1: i64| {
            let (x0, y0) = (x0.clamp(0, w) as usize, y0.clamp(0, h) as usize);
            let (x1, y1) = ((x1 + 1).clamp(0, w) as usize, (y1 + 1).clamp(0, h) as usize);
            x0 < x1
                && y0 < y1
                && sat[y1 * stride + x1] + sat[y0 * stride + x0]
                    > sat[y0 * stride + x1] + sat[y1 * stride + x0]
        };
        let (pixels_2d, _) =
            crate::render::project_vertices(&view.robot.vertices_base, camera, centre);
        let topology = &view.robot.topology;
        let kept: Vec<[u32; 3]> = topology
            .triangles
            .iter()
            .filter(|t| {
                let p = t.map(|i| pixels_2d[i as usize]);
                if p.iter().any(|q| q[0].is_nan()) {
                    return true;
                }
                let x0 = p[0][0].min(p[1][0]).min(p[2][0]).floor() as i64 - radius;
                let x1 = p[0][0].max(p[1][0]).max(p[2][0]).ceil() as i64 + radius;
                let y0 = p[0][1].min(p[1][1]).min(p[2][1]).floor() as i64 - radius;
                let y1 = p[0][1].max(p[1][1]).max(p[2][1]).ceil() as i64 + radius;
                any(x0, y0, x1, y1)
            })
            .copied()
            .collect();
        // Only the vertices the kept triangles use, renumbered.
        let mut renumber = vec![u32::MAX; view.robot.vertices_base.len()];
        let mut vertices_base = Vec::new();
        let mut vertex_link = Vec::new();
        let triangles: Vec<[u32; 3]> = kept
            .iter()
            .map(|t| {
                t.map(|i| {
                    let slot = &mut renumber[i as usize];
                    if *slot == u32::MAX {
                        *slot = vertices_base.len() as u32;
                        vertices_base.push(view.robot.vertices_base[i as usize]);
                        if let Some(&l) = view.robot.vertex_link.get(i as usize) {
                            vertex_link.push(l);
                        }
                    }
                    *slot
                })
            })
            .collect();
        let outside_wrong = band
            .iter()
            .zip(rendered.data.iter().zip(&view.observed.data))
            .filter(|(&b, (&r, &o))| b == 0 && (r != 0) != (o != 0))
            .count();
        let robot = PosedRobot {
            vertices_base,
            topology: std::sync::Arc::new(crate::mesh::TriMesh {
                vertices: Vec::new(),
                triangles,
                edges: Vec::new(),
            }),
            vertex_link: std::sync::Arc::new(vertex_link),
        };
        Band {
            robot,
            outside_wrong,
            image_pixels: (w * h) as usize,
            image_band: band,
        }
    }
}

/// Posterior refinement: the mask loss is flat and rough along weakly observed directions
/// (mostly depth), so its minimiser wanders within that valley. Sample poses from the LM's
/// Gaussian posterior (inflated), score each by the paper's mask loss over all views, and
/// average the best few in the tangent space — a cheap posterior mean under the mask loss.
/// On the benchmark it cuts the median translation error by ~40% (README).
fn refine(
    renderer: &dyn Backend,
    camera: &Intrinsics,
    views: &[View],
    report: SolveReport,
    opts: &SolveOptions,
) -> Result<SolveReport> {
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    if opts.refine_samples < 2 {
        return Ok(report);
    }
    if !report.covariance.iter().all(|v| v.is_finite()) {
        return Ok(report);
    }
    let Some(chol) = (report.covariance * opts.refine_inflation).cholesky() else {
        return Ok(report);
    };
    let started = std::time::Instant::now();
    let centre = report.camera_from_base;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(opts.search_seed);
    let keep = opts.refine_keep;
    let offsets: Vec<Twist> = (0..opts.refine_samples)
        .map(|i| {
            if i == 0 {
                Twist::zeros()
            } else {
                chol.l() * Twist::from_fn(|_, _| StandardNormal.sample(&mut rng))
            }
        })
        .collect();
    // The samples move the outline by a pixel or two: only a band around it can change, so
    // each view is scored on that band with just the triangles that can reach it.
    let worst = max_displacement_px(camera, views, &centre, &offsets);
    if !(worst.is_finite() && worst <= (REFINE_BAND_PX - 1) as f64) {
        // Too uncertain for a local refinement to be meaningful.
        return Ok(report);
    }
    let radius = worst.ceil() as i64 + 1;
    let bands: Vec<Band> = views
        .par_iter()
        .map(|v| Band::new(renderer, camera, v, &centre, radius))
        .collect();
    // All samples in one batch: a GPU backend renders them in one submission, the CPU one
    // renders each band's window on one thread, samples in parallel; both count exactly.
    let poses: Vec<Isometry3<f64>> = offsets.iter().map(|xi| exp_se3(xi) * centre).collect();
    let robots: Vec<&PosedRobot> = bands.iter().map(|b| &b.robot).collect();
    let band: Vec<&[u8]> = bands.iter().map(|b| b.image_band.as_slice()).collect();
    let observed: Vec<&[u8]> = views.iter().map(|v| v.observed.data.as_slice()).collect();
    let counts = renderer.band_mismatches(camera, &robots, &band, &observed, &poses);
    let mut scored: Vec<(f64, Twist)> = offsets
        .iter()
        .enumerate()
        .map(|(s, xi)| {
            let loss: f64 = bands
                .iter()
                .enumerate()
                .map(|(v, b)| {
                    (b.outside_wrong + counts[s * bands.len() + v] as usize) as f64
                        / b.image_pixels as f64
                })
                .sum();
            (loss, *xi)
        })
        .collect();
    if std::env::var_os("EASYHEC_DEBUG").is_some() {
        let tris: usize = bands.iter().map(|b| b.robot.topology.triangles.len()).sum();
        let px: usize = bands
            .iter()
            .map(|b| b.image_band.iter().filter(|&&p| p != 0).count())
            .sum();
        eprintln!(
            "refine: {} samples, band {tris} triangles, {px} pixels over {} views",
            offsets.len(),
            views.len()
        );
    }
    scored.sort_by(|a, b| a.0.total_cmp(&b.0));
    let keep = keep.clamp(1, scored.len());
    let mean_xi = scored[..keep]
        .iter()
        .fold(Twist::zeros(), |acc, s| acc + s.1)
        / keep as f64;
    let pose = exp_se3(&mean_xi) * centre;
    if std::env::var_os("EASYHEC_DEBUG").is_some() {
        eprintln!("refine: {:.3} s", started.elapsed().as_secs_f64());
    }
    let mut refined = finish(
        renderer,
        camera,
        views,
        pose,
        report.iterations + 1,
        report.trajectory,
        opts,
    )?;
    refined.iterations = report.iterations + 1;
    Ok(refined)
}

/// Mean of `v` (0 for an empty slice).
pub(crate) fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

impl SolveReport {
    /// Mean mask IoU over the views solved from.
    pub fn mean_iou(&self) -> f64 {
        mean(&self.per_view_iou)
    }
}

/// Cross-entropy search over left increments of `initial`, maximising the mean mask IoU of up
/// to four views at 1/8 resolution with decimated meshes.
pub fn coarse_search(
    renderer: &dyn SilhouetteRenderer,
    camera: &Intrinsics,
    views: &[View],
    initial: &Isometry3<f64>,
    opts: &SolveOptions,
) -> Isometry3<f64> {
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
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
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(opts.search_seed);
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

fn solve_lm(
    renderer: &dyn SilhouetteRenderer,
    camera: &Intrinsics,
    views: &[View],
    initial: &Isometry3<f64>,
    opts: &SolveOptions,
) -> Result<(Isometry3<f64>, usize, Vec<Isometry3<f64>>)> {
    let debug = std::env::var_os("EASYHEC_DEBUG").is_some();
    let mut pose = *initial;
    let mut iterations = 0;
    let mut trajectory = vec![pose];
    for &factor in &opts.pyramid {
        let started = std::time::Instant::now();
        let scale = if factor == 1 {
            opts.fine_robust_scale_px
        } else {
            opts.robust_scale_px
        };
        let level = Level::new(camera, views, factor, scale);
        // Coarse levels see the robot through big pixels: a mesh clustered to a fraction of a
        // pixel renders the same silhouette at a fraction of the cost.
        let cell_m = opts.coarse_cell_fraction * f64::from(factor) / camera.fx.max(camera.fy);
        let decimated: Vec<PosedRobot> = if factor > 1 && cell_m > 1e-3 {
            views
                .par_iter()
                .map(|v| v.robot.decimated(cell_m))
                .collect()
        } else {
            Vec::new()
        };
        let level_views: Vec<&PosedRobot> = if decimated.is_empty() {
            views.iter().map(|v| &v.robot).collect()
        } else {
            decimated.iter().collect()
        };
        let mut current = accumulate(renderer, &level_views, &level, &pose, opts);
        iterations += 1;
        if current.length == 0.0 {
            return Err(Error::Solve(
                "the robot is not visible from the initial guess in any view: check initial_guess.camera_from_base (direction and units)".into(),
            ));
        }
        let mut lambda = 1e-4;
        let mut level_iterations = 0;
        // Steps below ~1/100 pixel of the level are noise.
        let tolerance = 1e-5 * f64::from(factor);
        // Coarse levels only have to land in the next level's basin; at the finest, the
        // posterior refinement ([`refine`]) finishes what LM's rough end-game would grind on.
        // Fine levels get a render budget of ~40 view-renders (8 iterations at 5 views).
        let fine_cap = (40 / views.len().max(1))
            .max(8)
            .min(opts.max_iterations_per_level.max(1));
        let cap = if factor >= 4 {
            opts.max_iterations_per_level.min(10)
        } else {
            fine_cap
        };
        for _ in 0..cap {
            let mut a = current.h;
            for k in 0..6 {
                a[(k, k)] += lambda * current.h[(k, k)].max(1e-12);
            }
            let Some(step) = a.cholesky().map(|c| -c.solve(&current.g)) else {
                lambda *= 10.0;
                continue;
            };
            let candidate = exp_se3(&step) * pose;
            let next = accumulate(renderer, &level_views, &level, &candidate, opts);
            iterations += 1;
            level_iterations += 1;
            if next.length > 0.0 && total_cost(&next) <= total_cost(&current) {
                pose = candidate;
                current = next;
                trajectory.push(pose);
                lambda = (lambda / 3.0).max(1e-7);
                let rot = step.fixed_rows::<3>(3).norm();
                let trans = step.fixed_rows::<3>(0).norm();
                if rot < tolerance && trans < tolerance {
                    break;
                }
            } else {
                lambda *= 4.0;
                if lambda > 1e4 {
                    break;
                }
            }
        }
        if debug {
            eprintln!(
                "level {factor}: {level_iterations} iterations, {:.3} s, cost {:.1} over {:.0} px of outline",
                started.elapsed().as_secs_f64(),
                total_cost(&current),
                current.length
            );
        }
    }
    Ok((pose, iterations, trajectory))
}

fn solve_adam(
    renderer: &dyn SilhouetteRenderer,
    camera: &Intrinsics,
    views: &[View],
    initial: &Isometry3<f64>,
    opts: &SolveOptions,
) -> (Isometry3<f64>, usize, Vec<Isometry3<f64>>) {
    let (b1, b2, eps) = (0.9, 0.999, 1e-8);
    let mut pose = *initial;
    let mut m = Twist::zeros();
    let mut v = Twist::zeros();
    let mut best = (f64::INFINITY, pose);
    let mut trajectory = Vec::with_capacity(opts.adam_steps);
    for t in 1..=opts.adam_steps {
        let (loss, grad) = views
            .par_iter()
            .map(|view| {
                let sil = renderer.render(&view.robot, camera, &pose, Some(opts.boundary_step_px));
                (
                    mask_loss(&sil.mask, &view.observed),
                    loss_gradient(&sil, &view.observed, camera),
                )
            })
            .reduce(|| (0.0, Twist::zeros()), |a, b| (a.0 + b.0, a.1 + b.1));
        let n = views.len() as f64;
        let (loss, grad) = (loss / n, grad / n);
        if loss < best.0 {
            best = (loss, pose);
        }
        trajectory.push(pose);
        m = m * b1 + grad * (1.0 - b1);
        v = v * b2 + grad.component_mul(&grad) * (1.0 - b2);
        let mh = m / (1.0 - b1.powi(t as i32));
        let vh = v / (1.0 - b2.powi(t as i32));
        let step = mh.zip_map(&vh, |a, b| -opts.adam_learning_rate * a / (b.sqrt() + eps));
        pose = exp_se3(&step) * pose;
    }
    (best.1, opts.adam_steps, trajectory)
}

fn finish(
    renderer: &dyn SilhouetteRenderer,
    camera: &Intrinsics,
    views: &[View],
    pose: Isometry3<f64>,
    iterations: usize,
    trajectory: Vec<Isometry3<f64>>,
    opts: &SolveOptions,
) -> Result<SolveReport> {
    let level = Level::new(camera, views, 1, opts.fine_robust_scale_px);
    let robots: Vec<&PosedRobot> = views.iter().map(|v| &v.robot).collect();
    let (n, silhouettes) = accumulate_keeping(renderer, &robots, &level, &pose, opts);
    let dof = (n.length / opts.correlation_length_px - 6.0).max(1.0);
    let sigma2 = n.weighted_sq / opts.correlation_length_px / dof;
    let covariance = match n.h.try_inverse() {
        Some(inv) => inv * sigma2 * opts.correlation_length_px,
        None => Matrix6::from_diagonal_element(f64::INFINITY),
    };
    let uncertainty = uncertainty_of(&covariance, &pose);
    let renders: Vec<(f64, f64)> = silhouettes
        .par_iter()
        .zip(views)
        .map(|(s, v)| (s.mask.iou(&v.observed), mask_loss(&s.mask, &v.observed)))
        .collect();
    let loss = renders.iter().map(|r| r.1).sum::<f64>() / views.len() as f64;
    Ok(SolveReport {
        camera_from_base: pose,
        covariance,
        uncertainty,
        outline_noise_px2: sigma2 * opts.correlation_length_px,
        per_view_iou: renders.iter().map(|r| r.0).collect(),
        loss,
        iterations,
        trajectory,
    })
}

/// Covariance of the translation `camera_from_base` reports, from the covariance of its left
/// increment `(rho, phi)`: a left increment moves that translation by `rho - t x phi`.
pub fn translation_covariance(
    covariance: &Matrix6<f64>,
    camera_from_base: &Isometry3<f64>,
) -> nalgebra::Matrix3<f64> {
    let t: Vector3<f64> = camera_from_base.translation.vector;
    let mut a = nalgebra::Matrix3x6::zeros();
    a.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&nalgebra::Matrix3::identity());
    a.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-skew(&t)));
    a * covariance * a.transpose()
}

/// 1-sigma rotation (about camera axes) and translation of `camera_from_base`'s translation
/// part, from the covariance of the left increment (see [`translation_covariance`]).
pub fn uncertainty_of(covariance: &Matrix6<f64>, camera_from_base: &Isometry3<f64>) -> Uncertainty {
    let ct = translation_covariance(covariance, camera_from_base);
    Uncertainty {
        rotation_deg: [0, 1, 2].map(|k| covariance[(3 + k, 3 + k)].max(0.0).sqrt().to_degrees()),
        translation_mm: [0, 1, 2].map(|k| ct[(k, k)].max(0.0).sqrt() * 1000.0),
    }
}

//! Posterior refinement after LM: sample poses from the LM posterior, score them on the mask
//! loss within a band around the outline, and average the best.

use nalgebra::Isometry3;
use rayon::prelude::*;

use super::boundary::LeftOut;
use super::{finish, SolveOptions, SolveReport, View};
use crate::backend::Backend;
use crate::camera::Intrinsics;
use crate::error::Result;
use crate::geometry::{exp_se3, Twist};
use crate::mask::Mask;
use crate::render::{BoundarySample, PosedRobot, SilhouetteRenderer};

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
/// rendered outline (less the mount contact when the fit leaves it out), and the triangles
/// whose (dilated) bounds touch them. Samples render only the band's window of the image and
/// only the vertices its triangles use (see [`crate::scoring::cpu::band_mismatches`]), so one
/// sample costs a small fraction of a full render.
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
        observed: &Mask,
        centre: &Isometry3<f64>,
        radius: i64,
        left_out: &LeftOut,
    ) -> Band {
        // The outline samples are wanted only to find the mount contact.
        let step = left_out.any().then_some(CONTACT_STEP_PX);
        let silhouette = renderer.render(&view.robot, camera, centre, step);
        let rendered = silhouette.mask;
        let (w, h) = (i64::from(camera.width), i64::from(camera.height));
        // Band = pixels within `radius` (Chebyshev) of a rendered outline pixel.
        let mut band = vec![0u8; (w * h) as usize];
        for v in 0..h {
            for u in 0..w {
                let here = rendered.get(u, v);
                let edge = (u + 1 < w && rendered.get(u + 1, v) != here)
                    || (v + 1 < h && rendered.get(u, v + 1) != here);
                if edge {
                    fill_square(&mut band, w, h, [u, v], radius, 1);
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
        // Chosen before the mount contact leaves the band: the band's window still renders
        // the foot's triangles, so the pixels left in it are counted right.
        let contact = silhouette.boundary.iter().filter(|s| left_out.sample(s));
        leave_out_mount_contact(&mut band, camera, contact, radius);
        let outside_wrong = band
            .iter()
            .zip(rendered.data.iter().zip(&observed.data))
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
            joint_motions: view.robot.joint_motions.clone(),
            fixed_links: Default::default(),
            mount_cache: Default::default(),
        };
        Band {
            robot,
            outside_wrong,
            image_pixels: (w * h) as usize,
            image_band: band,
        }
    }
}

/// Outline sample spacing (pixels) used to find the mount contact in the band.
const CONTACT_STEP_PX: f64 = 1.0;

/// Takes the robot's mount contact out of a view's `band`: every pixel within one more than
/// `radius` (the band's own reach) of a rendered outline sample at the contact, chosen by
/// [`LeftOut`] as LM's are. A fit that leaves the contact out of LM's
/// outline residuals must not let the mask score read it either, or the flange or plate the
/// masks disagree on pulls again.
fn leave_out_mount_contact<'a>(
    band: &mut [u8],
    camera: &Intrinsics,
    contact: impl Iterator<Item = &'a BoundarySample>,
    radius: i64,
) {
    let (w, h) = (i64::from(camera.width), i64::from(camera.height));
    for s in contact {
        let at = [s.pixel[0].round() as i64, s.pixel[1].round() as i64];
        fill_square(band, w, h, at, radius + 1, 0);
    }
}

/// Sets the pixels of the `w` x `h` image `band` within `reach` (Chebyshev) of pixel `at` to
/// `value`, clipped to the image.
fn fill_square(band: &mut [u8], w: i64, h: i64, at: [i64; 2], reach: i64, value: u8) {
    let [u, v] = at;
    let (x0, x1) = ((u - reach).max(0), (u + reach).min(w - 1));
    if x0 > x1 {
        return;
    }
    for y in (v - reach).max(0)..=(v + reach).min(h - 1) {
        let row = (y * w) as usize;
        band[row + x0 as usize..=row + x1 as usize].fill(value);
    }
}

/// Posterior refinement: the mask loss is flat and rough along weakly observed directions
/// (mostly depth), so its minimiser wanders within that valley. Sample poses from the LM's
/// Gaussian posterior (inflated), score each by the paper's mask loss over all views, and
/// average the best few in the tangent space — a cheap posterior mean under the mask loss.
/// On the `segmenter` benchmark it cuts the median translation error by 23% at 1 view and
/// 37–39% at 3 and 5 (docs/benchmarks.md, `bench coverage --no-refine`).
pub(super) fn refine(
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
    if !report.sampling_covariance.iter().all(|v| v.is_finite()) {
        return Ok(report);
    }
    let Some(chol) = (report.sampling_covariance * opts.refine_inflation).cholesky() else {
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
    // Scored against masks with the estimated outline offset taken back out, so the mask
    // loss does not pull the pose towards what a fat or thin segmenter drew.
    let offset = report.mask_offset_px();
    let observed: Vec<std::borrow::Cow<Mask>> = views
        .par_iter()
        .map(|v| {
            if offset == 0.0 {
                std::borrow::Cow::Borrowed(&v.observed)
            } else {
                std::borrow::Cow::Owned(v.observed.with_outline_offset(-offset))
            }
        })
        .collect();
    let bands: Vec<Band> = views
        .par_iter()
        .zip(&observed)
        .map(|(v, o)| {
            let left_out = LeftOut::of(&v.robot, opts, &centre);
            Band::new(renderer, camera, v, o, &centre, radius, &left_out)
        })
        .collect();
    // All samples in one batch: a GPU backend renders them in one submission, the CPU one
    // renders each band's window on one thread, samples in parallel; both count exactly.
    let poses: Vec<Isometry3<f64>> = offsets.iter().map(|xi| exp_se3(xi) * centre).collect();
    let robots: Vec<&PosedRobot> = bands.iter().map(|b| &b.robot).collect();
    let band: Vec<&[u8]> = bands.iter().map(|b| b.image_band.as_slice()).collect();
    let observed: Vec<&[u8]> = observed.iter().map(|o| o.data.as_slice()).collect();
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
    if tracing::enabled!(tracing::Level::DEBUG) {
        let tris: usize = bands.iter().map(|b| b.robot.topology.triangles.len()).sum();
        let px: usize = bands
            .iter()
            .map(|b| b.image_band.iter().filter(|&&p| p != 0).count())
            .sum();
        tracing::debug!(
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
    if tracing::enabled!(tracing::Level::DEBUG) {
        tracing::debug!("refine: {:.3} s", started.elapsed().as_secs_f64());
    }
    let walk = super::lm::Walk {
        pose,
        offset_px: report.mask_offset_px(),
        iterations: report.iterations + 1,
        trajectory: report.trajectory,
    };
    let mut refined = finish(renderer, camera, views, walk, opts)?;
    refined.iterations = report.iterations + 1;
    Ok(refined)
}

//! The reference implementation of [`BatchScoring`] on the CPU rasteriser, and the fallback
//! every other backend uses for batches it cannot take.
//!
//! Both scores render a robot many times at a resolution (or window) where one render is a
//! small amount of work, so each render runs single-threaded on reused buffers and the poses
//! (or pool entries) run in parallel: per-render thread fan-out and allocation would cost
//! more than the rasterisation itself.

use nalgebra::Isometry3;
use rayon::prelude::*;

use super::BatchScoring;
use crate::camera::Intrinsics;
use crate::mask::Mask;
use crate::render::{fill_triangles, CpuRenderer, PosedRobot, NEAR_PLANE_M};

/// Rasterises `robot` at `pose` into `mask` (cleared first) on the calling thread, with the
/// CPU renderer's pixel rule; `pixels` holds the projected vertices (resized as needed, so a
/// caller's loop reuses it).
fn rasterize_at(
    camera: &Intrinsics,
    robot: &PosedRobot,
    pose: &Isometry3<f64>,
    pixels: &mut Vec<[f64; 2]>,
    mask: &mut Mask,
) {
    mask.data.fill(0);
    pixels.resize(robot.vertices_base.len(), [0.0; 2]);
    for (px, v) in pixels.iter_mut().zip(&robot.vertices_base) {
        let p = pose * v;
        *px = if p.z > NEAR_PLANE_M {
            camera.project(&p)
        } else {
            [f64::NAN, f64::NAN]
        };
    }
    fill_triangles(mask, &robot.topology.triangles, pixels);
}

/// Total per-pixel variance of the candidates' silhouettes of `robot`, in pixels of the
/// scoring image: `V = sum_p c_p (K - c_p) / K^2`, `c_p` the candidates covering pixel `p`
/// (docs/method.md §5). Single-threaded: callers score many pool entries in parallel.
pub fn disagreement(camera: &Intrinsics, robot: &PosedRobot, candidates: &[Isometry3<f64>]) -> f64 {
    let k = candidates.len() as f64;
    let mut counts = vec![0u16; (camera.width * camera.height) as usize];
    let mut mask = Mask::new(camera.width, camera.height);
    let mut pixels = Vec::new();
    for pose in candidates {
        rasterize_at(camera, robot, pose, &mut pixels, &mut mask);
        for (c, &v) in counts.iter_mut().zip(&mask.data) {
            *c += u16::from(v);
        }
    }
    counts
        .iter()
        .map(|&c| f64::from(c) * (k - f64::from(c)))
        .sum::<f64>()
        / (k * k)
}

/// [`BatchScoring::disagreement_many`] on the CPU: one single-threaded [`disagreement`] per
/// pool entry, pool entries in parallel.
pub fn disagreement_many(
    camera: &Intrinsics,
    pool: &[&PosedRobot],
    candidates: &[Isometry3<f64>],
) -> Vec<f64> {
    pool.par_iter()
        .map(|r| disagreement(camera, r, candidates))
        .collect()
}

/// One view's band, cut to the image window that holds it: a sample renders only the window,
/// a small fraction of the image when the band is a few pixels around the outline.
struct BandWindow {
    /// `camera` with its principal point shifted so that window pixel (0, 0) is the band's
    /// top-left image pixel; pixel centres stay put.
    window: Intrinsics,
    /// Band pixels as indices into the window, with whether the observation covers them.
    pixels: Vec<(u32, bool)>,
}

impl BandWindow {
    /// The window of `band` (its bounding box; a 1x1 window when the band is empty) over an
    /// image of `camera`'s size.
    fn new(camera: &Intrinsics, band: &[u8], observed: &[u8]) -> BandWindow {
        let (w, h) = (i64::from(camera.width), i64::from(camera.height));
        let (mut x0, mut y0, mut x1, mut y1) = (w, h, -1, -1);
        for v in 0..h {
            let row = &band[(v * w) as usize..((v + 1) * w) as usize];
            if let (Some(a), Some(b)) = (
                row.iter().position(|&b| b != 0),
                row.iter().rposition(|&b| b != 0),
            ) {
                x0 = x0.min(a as i64);
                x1 = x1.max(b as i64);
                y0 = y0.min(v);
                y1 = y1.max(v);
            }
        }
        if x1 < x0 {
            (x0, y0, x1, y1) = (0, 0, 0, 0);
        }
        let window = Intrinsics {
            width: (x1 - x0 + 1) as u32,
            height: (y1 - y0 + 1) as u32,
            cx: camera.cx - x0 as f64,
            cy: camera.cy - y0 as f64,
            ..camera.clone()
        };
        let ww = x1 - x0 + 1;
        let mut pixels = Vec::new();
        for v in y0..=y1 {
            for u in x0..=x1 {
                let i = (v * w + u) as usize;
                if band[i] != 0 {
                    pixels.push((((v - y0) * ww + (u - x0)) as u32, observed[i] != 0));
                }
            }
        }
        BandWindow { window, pixels }
    }

    /// Band pixels whose coverage by `robot` at `pose` differs from the observation.
    fn mismatches(&self, robot: &PosedRobot, pose: &Isometry3<f64>) -> u32 {
        let mut mask = Mask::new(self.window.width, self.window.height);
        rasterize_at(&self.window, robot, pose, &mut Vec::new(), &mut mask);
        self.pixels
            .iter()
            .filter(|&&(i, observed)| (mask.data[i as usize] != 0) != observed)
            .count() as u32
    }
}

/// [`BatchScoring::band_mismatches`] on the CPU: each view's band cut to its window once, then
/// every (pose, view) rendered in that window on one thread, poses in parallel.
pub fn band_mismatches(
    camera: &Intrinsics,
    robots: &[&PosedRobot],
    band: &[&[u8]],
    observed: &[&[u8]],
    poses: &[Isometry3<f64>],
) -> Vec<u32> {
    assert!(
        band.len() == robots.len() && observed.len() == robots.len(),
        "one band and one observation per view"
    );
    let windows: Vec<BandWindow> = band
        .par_iter()
        .zip(observed.par_iter())
        .map(|(b, o)| BandWindow::new(camera, b, o))
        .collect();
    let per_pose: Vec<Vec<u32>> = poses
        .par_iter()
        .map(|pose| {
            windows
                .iter()
                .zip(robots)
                .map(|(w, r)| w.mismatches(r, pose))
                .collect()
        })
        .collect();
    per_pose.concat()
}

impl BatchScoring for CpuRenderer {
    fn disagreement_many(
        &self,
        camera: &Intrinsics,
        pool: &[&PosedRobot],
        candidates: &[Isometry3<f64>],
    ) -> Vec<f64> {
        disagreement_many(camera, pool, candidates)
    }

    fn band_mismatches(
        &self,
        camera: &Intrinsics,
        robots: &[&PosedRobot],
        band: &[&[u8]],
        observed: &[&[u8]],
        poses: &[Isometry3<f64>],
    ) -> Vec<u32> {
        band_mismatches(camera, robots, band, observed, poses)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{exp_se3, look_at_camera_from_base, Twist};
    use crate::render::SilhouetteRenderer;
    use crate::robot::RobotModel;
    use nalgebra::Vector3;

    fn scene() -> (Intrinsics, PosedRobot, Isometry3<f64>) {
        let urdf = concat!(env!("CARGO_MANIFEST_DIR"), "/robots/xarm6/robot.urdf");
        let robot = RobotModel::from_urdf(urdf).unwrap();
        let posed = PosedRobot::new(&robot, &[0.3, -0.4, -0.5, 0.2, 0.9, 0.1]);
        let camera = Intrinsics::pinhole(160, 120, 150.0, 150.0, 79.5, 59.5);
        let pose = look_at_camera_from_base(
            &Vector3::new(1.3, 0.5, 0.8),
            &Vector3::new(0.1, 0.0, 0.3),
            &Vector3::z(),
        );
        (camera, posed, pose)
    }

    /// The windowed counts are the full-image render's: the window moves the principal point
    /// by whole pixels, which keeps every pixel centre where it was.
    #[test]
    fn band_counts_in_a_window_match_full_renders() {
        let (camera, posed, centre) = scene();
        let near = exp_se3(&Twist::new(0.01, -0.005, 0.02, 0.01, -0.004, 0.003)) * centre;
        let observed = CpuRenderer.render(&posed, &camera, &near, None).mask.data;
        // A band away from the image's corner, so the window is offset.
        let band: Vec<u8> = (0..camera.width * camera.height)
            .map(|i| {
                let (u, v) = (i % camera.width, i / camera.width);
                u8::from((37..101).contains(&u) && (23..88).contains(&v))
            })
            .collect();
        let poses: Vec<Isometry3<f64>> = (0..6)
            .map(|k| {
                let s = f64::from(k) / 6.0;
                exp_se3(&Twist::new(
                    0.02 * s,
                    0.0,
                    -0.03 * s,
                    0.0,
                    0.01 * s,
                    -0.006 * s,
                )) * centre
            })
            .collect();
        let counts = CpuRenderer.band_mismatches(
            &camera,
            &[&posed, &posed],
            &[&band, &observed],
            &[&observed, &band],
            &poses,
        );
        assert_eq!(counts.len(), 2 * poses.len());
        let mut distinct = std::collections::BTreeSet::new();
        for (s, pose) in poses.iter().enumerate() {
            let rendered = CpuRenderer.render(&posed, &camera, pose, None).mask.data;
            for (v, (b, o)) in [(&band, &observed), (&observed, &band)].iter().enumerate() {
                let want = (0..rendered.len())
                    .filter(|&i| b[i] != 0 && (rendered[i] != 0) != (o[i] != 0))
                    .count();
                assert_eq!(counts[s * 2 + v] as usize, want, "pose {s} view {v}");
                distinct.insert(want);
            }
        }
        assert!(distinct.len() > 4, "{distinct:?}");
    }

    /// Candidates that all agree have no variance; two halves that never overlap have the
    /// most, a quarter of a pixel per covered pixel.
    #[test]
    fn disagreement_is_the_per_pixel_variance() {
        let (camera, posed, pose) = scene();
        assert_eq!(disagreement(&camera, &posed, &[pose; 4]), 0.0);
        let away = exp_se3(&Twist::new(0.0, 0.0, -50.0, 0.0, 0.0, 0.0)) * pose;
        let covered = CpuRenderer
            .render(&posed, &camera, &pose, None)
            .mask
            .count() as f64;
        let v = disagreement(&camera, &posed, &[pose, pose, away, away]);
        assert!(covered > 100.0);
        assert_eq!(v, covered * 2.0 * 2.0 / 16.0);
        let many = disagreement_many(&camera, &[&posed, &posed], &[pose, away]);
        assert_eq!(many, vec![covered / 4.0; 2]);
    }
}

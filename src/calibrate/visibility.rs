//! Which poses show the robot to the camera: a pose is worth a view only when the silhouette
//! there can say something about the camera.
//!
//! A fixed camera sees the whole arm from afar, so the rule is the share of the robot's
//! surface inside the image (`[safety] min_in_image`). A camera on a link sees the robot
//! from close by and only in part (the base and lower links when the arm looks back at
//! itself), so the rule is the share of the image the robot covers
//! (`[calibration] min_robot_image_fraction`), and a pose where robot geometry passes through
//! the lens's near plane is refused: no pinhole silhouette of it is faithful.

use nalgebra::Isometry3;

use crate::camera::Intrinsics;
use crate::cell::Cell;
use crate::config::Mount;
use crate::render::{CpuRenderer, PosedRobot, SilhouetteRenderer};

/// Fraction of the robot's (decimated) surface points that land inside the image.
pub fn in_image_fraction(
    robot: &PosedRobot,
    camera: &Intrinsics,
    camera_from_base: &Isometry3<f64>,
) -> f64 {
    if robot.vertices_base.is_empty() {
        return 0.0;
    }
    let (w, h) = (f64::from(camera.width), f64::from(camera.height));
    let inside = robot
        .vertices_base
        .iter()
        .filter(|p| {
            let c = camera_from_base * **p;
            if c.z <= 0.05 {
                return false;
            }
            let x = camera.project(&c);
            x[0] >= 0.0 && x[1] >= 0.0 && x[0] <= w - 1.0 && x[1] <= h - 1.0
        })
        .count();
    inside as f64 / robot.vertices_base.len() as f64
}

/// Depth (metres) below which robot geometry counts as touching the lens.
const LENS_CLEARANCE_M: f64 = 0.05;

/// The rule of a cell's camera.
#[derive(Clone, Copy, Debug)]
pub enum VisibilityRule {
    /// Fixed camera: this share of the robot's surface points must be in the image.
    InImage(f64),
    /// Camera on a link: the robot must cover this share of the image, clear of the lens.
    ImageCoverage(f64),
}

impl VisibilityRule {
    /// The rule for a camera of `cell` on `mount`: each camera of a list has its own.
    pub fn of(cell: &Cell, mount: &Mount) -> VisibilityRule {
        if mount.is_fixed() {
            VisibilityRule::InImage(cell.checker.min_in_image)
        } else {
            VisibilityRule::ImageCoverage(cell.config.calibration.min_robot_image_fraction)
        }
    }

    /// What a view of `posed` (a coarse posed robot) from `camera_from_base` shows, when it
    /// shows enough: the in-image share or the image coverage. `camera` is a pinhole camera;
    /// coverage is rendered at a coarse resolution (`low`).
    pub fn shows(
        &self,
        posed: &PosedRobot,
        camera: &Intrinsics,
        low: &Intrinsics,
        camera_from_base: &Isometry3<f64>,
    ) -> Option<f64> {
        match *self {
            VisibilityRule::InImage(least) => {
                let share = in_image_fraction(posed, camera, camera_from_base);
                (share >= least).then_some(share)
            }
            VisibilityRule::ImageCoverage(least) => {
                if touches_lens(posed, camera, camera_from_base) {
                    return None;
                }
                let coverage = image_coverage(posed, low, camera_from_base);
                (coverage >= least).then_some(coverage)
            }
        }
    }
}

/// Share of the image's pixels the robot covers.
pub fn image_coverage(
    posed: &PosedRobot,
    camera: &Intrinsics,
    camera_from_base: &Isometry3<f64>,
) -> f64 {
    let mask = CpuRenderer
        .render(posed, camera, camera_from_base, None)
        .mask;
    let covered = mask.data.iter().filter(|&&m| m != 0).count();
    covered as f64 / mask.data.len().max(1) as f64
}

/// Whether a triangle in view reaches to within [`LENS_CLEARANCE_M`] of the camera or behind
/// it: the renderer drops triangles that cross the near plane, a real lens does not, and
/// geometry that close is out of focus and far from a pinhole's silhouette.
pub fn touches_lens(
    posed: &PosedRobot,
    camera: &Intrinsics,
    camera_from_base: &Isometry3<f64>,
) -> bool {
    let (w, h) = (f64::from(camera.width), f64::from(camera.height));
    let seen: Vec<(f64, bool)> = posed
        .vertices_base
        .iter()
        .map(|p| {
            let c = camera_from_base * p;
            if c.z <= crate::render::NEAR_PLANE_M {
                return (c.z, false);
            }
            let x = camera.project(&c);
            (
                c.z,
                x[0] >= 0.0 && x[1] >= 0.0 && x[0] <= w - 1.0 && x[1] <= h - 1.0,
            )
        })
        .collect();
    posed.topology.triangles.iter().any(|t| {
        let in_view = t.iter().any(|&v| seen[v as usize].1);
        in_view && t.iter().any(|&v| seen[v as usize].0 < LENS_CLEARANCE_M)
    })
}

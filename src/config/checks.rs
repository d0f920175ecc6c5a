//! The one validation pass over a whole cell config, run before anything is opened, computed
//! or moved. Each value is checked against its physical range and every size against a
//! documented upper bound (docs/config.md, "Bounds"), so a typo fails in a line that names the
//! file, the key and what is allowed, rather than as a hang, an allocation abort or a quietly
//! wrong calibration.

use std::path::Path;

use super::{
    ArmConfig, CalibrationSettings, CameraConfig, CellConfig, NoiseModel, SegmenterConfig,
};
use super::{AttachedConfig, ObstacleConfig, Ros2ArmSettings, SafetyConfig};
use crate::error::{Error, Result};

/// Upper bounds of every count a cell config sets. Each keeps one plan or solve within a few
/// seconds and a few hundred MB on a 2-core machine.
pub mod bounds {
    /// `calibration.max_views`.
    pub const MAX_VIEWS: usize = 100;
    /// `calibration.joint_samples`: the joint samples scored per exploration round.
    pub const JOINT_SAMPLES: usize = 100_000;
    /// `calibration.climb_steps`.
    pub const CLIMB_STEPS: usize = 10_000;
    /// `calibration.candidates`: camera hypotheses rendered per scored sample.
    pub const CANDIDATES: usize = 1_000;
    /// `calibration.max_motion_failures`.
    pub const MOTION_FAILURES: usize = 100;
    /// `calibration.score_downsample`.
    pub const SCORE_DOWNSAMPLE: u32 = 64;
    /// Any joint speed, rad/s (no arm this project drives turns faster than π rad/s).
    pub const SPEED_RAD_S: f64 = std::f64::consts::PI;
    /// Simulated seconds per wall second of the simulated arm.
    pub const SPEEDUP: f64 = 1_000.0;
    /// Joint noise, radians (about 6°: anything larger is not encoder noise).
    pub const JOINT_NOISE_RAD: f64 = 0.1;
    /// Model-error floor of the rotation, degrees (1 sigma per axis).
    pub const MODEL_FLOOR_DEG: f64 = 5.0;
    /// Model-error floor of the translation, millimetres (1 sigma per axis).
    pub const MODEL_FLOOR_MM: f64 = 100.0;
    /// Simulated boundary jitter, pixels.
    pub const BOUNDARY_JITTER_PX: f64 = 20.0;
    /// Correlation length of the simulated boundary displacement, pixels (the smoothing
    /// kernel spans six times this, so it stays a small fraction of any image).
    pub const BOUNDARY_CORRELATION_PX: f64 = 32.0;
    /// Blur of a synthetic segmenter's coverage, pixels (its kernel spans six of them).
    pub const MASK_BLUR_PX: f64 = 8.0;
    /// Systematic outline offset of a synthetic segmenter, pixels either way.
    pub const MASK_OUTLINE_OFFSET_PX: f64 = 8.0;
    /// Safety clearance, metres.
    pub const MARGIN_M: f64 = 0.5;
    /// Obstacle and workspace sizes, metres.
    pub const OBSTACLE_SIZE_M: f64 = 100.0;
    /// `[[safety.attached]]` bodies (each is checked against every link and obstacle).
    pub const ATTACHED: usize = 64;
}

/// A checker that names `path` in every message.
struct Check<'a> {
    path: &'a Path,
}

impl Check<'_> {
    fn fail(&self, field: impl Into<String>, got: impl std::fmt::Display, allowed: &str) -> Error {
        Error::input(self.path, field, format!("is {got}; allowed: {allowed}"))
    }

    /// `lo <= v <= hi` (or `lo < v` when `open_low`), and finite.
    fn within(&self, field: &str, v: f64, lo: f64, hi: f64, open_low: bool) -> Result<()> {
        let low_ok = if open_low { v > lo } else { v >= lo };
        if v.is_finite() && low_ok && v <= hi {
            return Ok(());
        }
        let bracket = if open_low { "(" } else { "[" };
        Err(self.fail(field, v, &format!("{bracket}{lo}, {hi}]")))
    }

    fn count(&self, field: &str, n: usize, lo: usize, hi: usize) -> Result<()> {
        if (lo..=hi).contains(&n) {
            return Ok(());
        }
        Err(self.fail(field, n, &format!("{lo} to {hi}")))
    }

    fn finite(&self, field: &str, values: &[f64]) -> Result<()> {
        match values.iter().position(|v| !v.is_finite()) {
            Some(k) if values.len() > 1 => {
                Err(self.fail(format!("{field}[{k}]"), values[k], "a finite number"))
            }
            Some(k) => Err(self.fail(field, values[k], "a finite number")),
            None => Ok(()),
        }
    }
}

impl CellConfig {
    /// Checks every value that needs only the file: finite numbers in their physical ranges,
    /// sizes within [`bounds`], no joint listed twice. Values that need the robot (start poses
    /// against joint limits, ranges against joint names) are checked when the cell is built.
    pub fn validate(&self, path: &Path) -> Result<()> {
        let c = Check { path };
        check_robot_joints(&c, self.robot.joints.as_deref())?;
        check_arm(&c, &self.arm)?;
        self.camera.validate(path)?;
        for (i, cam) in self.camera.cameras().iter().enumerate() {
            let rekey = |e| super::cameras::rekey(e, &self.camera, i);
            check_camera(&c, &cam.config).map_err(rekey)?;
            if let Some(seg) = &cam.segmenter {
                check_segmenter(&c, seg).map_err(|e| rekey_segmenter(e, &self.camera.key(i)))?;
            }
        }
        check_segmenter(&c, &self.segmenter)?;
        self.check_whole_run_segmenters(path, self.camera.cameras().len() > 1)?;
        if self.camera.cameras().len() > 1 && self.calibration.initial_guess.is_some() {
            return Err(Error::input(
                path,
                "calibration.initial_guess",
                "one starting pose cannot serve several cameras: give each [[camera]] table its own initial_guess, or leave it out for the automatic initialisation",
            ));
        }
        check_calibration(&c, &self.calibration)?;
        check_safety(&c, &self.safety)?;
        if let Some(r) = &self.ros2 {
            r.validate(path)?;
        }
        self.calibration.validate(path)
    }

    /// The one rule for segmenters that read a whole run (`builtin`: its background plate and
    /// priors come from the other views of the same camera): refused for every camera when
    /// `several` (a cell of several cameras; the daemon also counts a single `[[camera]]`
    /// table, whose bump check reads a run of a list), naming the key that chose it.
    pub fn check_whole_run_segmenters(&self, path: &Path, several: bool) -> Result<()> {
        if !several {
            return Ok(());
        }
        for (i, cam) in self.camera.cameras().iter().enumerate() {
            let seg = cam.segmenter.as_ref().unwrap_or(&self.segmenter);
            if !seg.reads_whole_run() {
                continue;
            }
            let key = if cam.segmenter.is_some() {
                format!("camera[{i}].segmenter.kind")
            } else {
                "segmenter.kind".to_string()
            };
            return Err(Error::input(
                path,
                key,
                format!("\"{}\" for camera '{}': it reads the whole run of one camera ({}), so it cannot serve a cell of [[camera]] tables (its loop and bump check read a run of a list); allowed there: per-frame segmenters (\"onnx\", \"sim-truth\")", seg.kind(), cam.name, seg.whole_run_reason()),
            ));
        }
        Ok(())
    }
}

fn check_robot_joints(c: &Check, joints: Option<&[String]>) -> Result<()> {
    let joints = joints.unwrap_or_default();
    for (k, name) in joints.iter().enumerate() {
        if let Some(first) = joints[..k].iter().position(|n| n == name) {
            return Err(c.fail(
                format!("robot.joints[{k}]"),
                format!("'{name}', already robot.joints[{first}]"),
                "each joint once",
            ));
        }
    }
    Ok(())
}

fn check_arm(c: &Check, arm: &ArmConfig) -> Result<()> {
    match arm {
        ArmConfig::Sim(t) => {
            c.finite("arm.start", &t.start)?;
            c.within(
                "arm.encoder_noise_rad",
                t.encoder_noise_rad,
                0.0,
                bounds::JOINT_NOISE_RAD,
                false,
            )?;
            if let Some(s) = t.speedup {
                c.within("arm.speedup", s, 0.0, bounds::SPEEDUP, true)?;
            }
            Ok(())
        }
        ArmConfig::Ros2(t) => check_ros2_arm(c, t),
        _ => Ok(()),
    }
}

/// `[arm] kind = "ros2"`: topic names, joint names once each, tolerances and times in range.
fn check_ros2_arm(c: &Check, t: &Ros2ArmSettings) -> Result<()> {
    for (key, topic) in [
        ("arm.joint_states_topic", &t.joint_states_topic),
        ("arm.command_topic", &t.command_topic),
    ] {
        crate::config::ros2::check_topic(topic)
            .map_err(|m| Error::input(c.path, key, format!("is {m}")))?;
    }
    if let Some(names) = &t.joint_names {
        let mut seen = std::collections::BTreeSet::new();
        for (i, n) in names.iter().enumerate() {
            let ok = !n.is_empty() && n.len() <= 256 && !n.chars().any(char::is_control);
            if !ok || !seen.insert(n) {
                return Err(Error::input(
                    c.path,
                    format!("arm.joint_names[{i}]"),
                    format!(
                        "is {n:?}; allowed: a non-empty name (at most 256 characters) listed once"
                    ),
                ));
            }
        }
    }
    c.within("arm.stale_after_s", t.stale_after_s, 0.05, 60.0, false)?;
    // No looser than the safe arm's start check (0.01 rad): a view must not be captured
    // while the arm still creeps toward the target.
    c.within(
        "arm.arrival_tolerance_rad",
        t.arrival_tolerance_rad,
        1e-5,
        0.01,
        false,
    )?;
    Ok(())
}

fn check_camera(c: &Check, camera: &CameraConfig) -> Result<()> {
    if let Some((field, allowed)) = camera.camera().and_then(|k| k.range_problem()) {
        return Err(Error::input(c.path, format!("camera.{field}"), allowed));
    }
    Ok(())
}

/// A camera's own segmenter errors as `camera[i].segmenter.…`.
fn rekey_segmenter(err: Error, key: &str) -> Error {
    match err {
        Error::Input {
            file,
            field,
            message,
        } => Error::input(file, format!("{key}.{field}"), message),
        other => other,
    }
}

fn check_segmenter(c: &Check, segmenter: &SegmenterConfig) -> Result<()> {
    if let SegmenterConfig::SimTruth { noise: Some(n), .. } = segmenter {
        check_noise(c, "segmenter.noise", n)?;
    }
    Ok(())
}

fn check_noise(c: &Check, field: &str, n: &NoiseModel) -> Result<()> {
    let jitter = format!("{field}.boundary_jitter_px");
    c.within(
        &jitter,
        n.boundary_jitter_px,
        0.0,
        bounds::BOUNDARY_JITTER_PX,
        false,
    )?;
    c.within(
        &format!("{field}.boundary_correlation_px"),
        n.boundary_correlation_px,
        0.0,
        bounds::BOUNDARY_CORRELATION_PX,
        false,
    )?;
    c.within(
        &format!("{field}.blur_px"),
        n.blur_px,
        0.0,
        bounds::MASK_BLUR_PX,
        false,
    )?;
    c.within(
        &format!("{field}.outline_offset_px"),
        n.outline_offset_px,
        -bounds::MASK_OUTLINE_OFFSET_PX,
        bounds::MASK_OUTLINE_OFFSET_PX,
        false,
    )?;
    c.within(
        &format!("{field}.blob_probability"),
        n.blob_probability,
        0.0,
        1.0,
        false,
    )?;
    let joint = format!("{field}.joint_noise_rad");
    c.within(
        &joint,
        n.joint_noise_rad,
        0.0,
        bounds::JOINT_NOISE_RAD,
        false,
    )
}

fn check_calibration(c: &Check, s: &CalibrationSettings) -> Result<()> {
    c.count("calibration.max_views", s.max_views, 1, bounds::MAX_VIEWS)?;
    c.count(
        "calibration.joint_samples",
        s.joint_samples,
        1,
        bounds::JOINT_SAMPLES,
    )?;
    c.count(
        "calibration.climb_steps",
        s.climb_steps,
        0,
        bounds::CLIMB_STEPS,
    )?;
    c.count(
        "calibration.candidates",
        s.candidates,
        2,
        bounds::CANDIDATES,
    )?;
    c.count(
        "calibration.max_motion_failures",
        s.max_motion_failures,
        0,
        bounds::MOTION_FAILURES,
    )?;
    let downsample = s.score_downsample as usize;
    c.count(
        "calibration.score_downsample",
        downsample,
        1,
        bounds::SCORE_DOWNSAMPLE as usize,
    )?;
    c.within(
        "calibration.speed_rad_s",
        s.speed_rad_s,
        0.0,
        bounds::SPEED_RAD_S,
        true,
    )?;
    c.within(
        "calibration.variance_rel_tol",
        s.variance_rel_tol,
        0.0,
        10.0,
        true,
    )?;
    c.within("calibration.pose_tol_deg", s.pose_tol_deg, 0.0, 10.0, true)?;
    c.within("calibration.pose_tol_mm", s.pose_tol_mm, 0.0, 100.0, true)?;
    if let Some(target) = s.stop_centre_95_mm {
        c.within("calibration.stop_centre_95_mm", target, 0.0, 1000.0, true)?;
    }
    if let Some(o) = s.view_overhead_s {
        c.within("calibration.view_overhead_s", o, 0.0, 3600.0, true)?;
    }
    c.within(
        "calibration.min_robot_image_fraction",
        s.min_robot_image_fraction,
        0.0,
        1.0,
        true,
    )?;
    check_model_floor(c, s)?;
    c.within(
        "calibration.joint_noise_rad",
        s.joint_noise_rad,
        0.0,
        bounds::JOINT_NOISE_RAD,
        false,
    )
}

/// The model-error floors, within their bounds and below what the uncertainty stop rule
/// needs: the translation floor alone widens the 95% camera-centre bound to 2.80 times itself
/// (the 95% radius of a 3-D Gaussian), so a larger floor would switch that rule off unseen.
fn check_model_floor(c: &Check, s: &CalibrationSettings) -> Result<()> {
    c.within(
        "calibration.model_floor_rotation_deg",
        s.model_floor_rotation_deg,
        0.0,
        bounds::MODEL_FLOOR_DEG,
        false,
    )?;
    let floor = s.model_floor_translation_mm;
    c.within(
        "calibration.model_floor_translation_mm",
        floor,
        0.0,
        bounds::MODEL_FLOOR_MM,
        false,
    )?;
    match s.stop_centre_95_mm {
        Some(target) if CENTRE_95_PER_SIGMA * floor >= target => Err(c.fail(
            "calibration.model_floor_translation_mm",
            floor,
            &format!(
                "below {:.3} mm with stop_centre_95_mm = {target}: the floor alone makes the 95% centre bound {:.2} mm, so the uncertainty stop rule could never fire (raise stop_centre_95_mm above that)",
                target / CENTRE_95_PER_SIGMA,
                CENTRE_95_PER_SIGMA * floor
            ),
        )),
        _ => Ok(()),
    }
}

/// The 95% radius of an isotropic 3-D Gaussian, in units of its per-axis sigma
/// (sqrt of the chi-square 95% quantile with 3 degrees of freedom, 7.815).
const CENTRE_95_PER_SIGMA: f64 = 2.7955;

fn check_safety(c: &Check, s: &SafetyConfig) -> Result<()> {
    c.within(
        "safety.speed_cap_rad_s",
        s.speed_cap_rad_s,
        0.0,
        bounds::SPEED_RAD_S,
        true,
    )?;
    c.within("safety.margin_m", s.margin_m, 0.0, bounds::MARGIN_M, false)?;
    c.within("safety.min_in_image", s.min_in_image, 0.0, 1.0, true)?;
    for (name, [lo, hi]) in &s.joint_ranges {
        let field = format!("safety.joint_ranges.{name}");
        c.finite(&field, &[*lo, *hi])?;
        if lo >= hi {
            return Err(c.fail(
                field,
                format!("[{lo}, {hi}]"),
                "[lower, upper] with lower < upper, radians",
            ));
        }
    }
    if let Some(w) = &s.workspace {
        c.finite("safety.workspace.centre", &w.centre)?;
        c.within(
            "safety.workspace.radius_m",
            w.radius_m,
            0.0,
            bounds::OBSTACLE_SIZE_M,
            true,
        )?;
    }
    for (i, o) in s.obstacles.iter().enumerate() {
        check_obstacle(c, &format!("safety.obstacles[{i}]"), o)?;
    }
    c.count("safety.attached", s.attached.len(), 0, bounds::ATTACHED)?;
    for (i, a) in s.attached.iter().enumerate() {
        let at = format!("safety.attached[{i}]");
        check_attached(c, &at, a)?;
        if s.attached[..i].iter().any(|b| b.name() == a.name()) {
            return Err(c.fail(
                format!("{at}.name"),
                format!("{:?} again", a.name()),
                "a name no other attached body has",
            ));
        }
    }
    Ok(())
}

/// Positive sizes up to [`bounds::OBSTACLE_SIZE_M`], per element of `v`.
fn check_sizes(c: &Check, at: &str, field: &str, v: &[f64]) -> Result<()> {
    for (k, x) in v.iter().enumerate() {
        let name = match v.len() {
            1 => format!("{at}.{field}"),
            _ => format!("{at}.{field}[{k}]"),
        };
        c.within(&name, *x, 0.0, bounds::OBSTACLE_SIZE_M, true)?;
    }
    Ok(())
}

fn check_attached(c: &Check, at: &str, a: &AttachedConfig) -> Result<()> {
    if a.name().trim().is_empty() {
        return Err(c.fail(format!("{at}.name"), "empty", "a label for messages"));
    }
    if a.link().trim().is_empty() {
        return Err(c.fail(format!("{at}.link"), "empty", "a link of the URDF"));
    }
    c.finite(&format!("{at}.xyz"), &a.xyz())?;
    match a {
        AttachedConfig::Box { size, rpy_deg, .. } => {
            check_sizes(c, at, "size", size)?;
            c.finite(&format!("{at}.rpy_deg"), rpy_deg)?;
        }
        AttachedConfig::Sphere { radius_m, .. } => {
            check_sizes(c, at, "radius_m", &[*radius_m])?;
        }
        AttachedConfig::Mesh { rpy_deg, scale, .. } => {
            check_sizes(c, at, "scale", scale)?;
            c.finite(&format!("{at}.rpy_deg"), rpy_deg)?;
        }
    }
    Ok(())
}

fn check_obstacle(c: &Check, at: &str, o: &ObstacleConfig) -> Result<()> {
    match o {
        ObstacleConfig::Plane {
            normal, offset_m, ..
        } => {
            c.finite(&format!("{at}.normal"), normal)?;
            c.finite(&format!("{at}.offset_m"), &[*offset_m])?;
            if normal.iter().map(|v| v * v).sum::<f64>() < 1e-12 {
                return Err(c.fail(format!("{at}.normal"), "[0, 0, 0]", "a non-zero vector"));
            }
        }
        ObstacleConfig::Box {
            centre,
            size,
            rpy_deg,
            ..
        } => {
            c.finite(&format!("{at}.centre"), centre)?;
            c.finite(&format!("{at}.rpy_deg"), rpy_deg)?;
            check_sizes(c, at, "size", size)?;
        }
        ObstacleConfig::Sphere {
            centre, radius_m, ..
        } => {
            c.finite(&format!("{at}.centre"), centre)?;
            check_sizes(c, at, "radius_m", &[*radius_m])?;
        }
        ObstacleConfig::Mesh {
            xyz,
            rpy_deg,
            scale,
            ..
        } => {
            c.finite(&format!("{at}.xyz"), xyz)?;
            c.finite(&format!("{at}.rpy_deg"), rpy_deg)?;
            check_sizes(c, at, "scale", scale)?;
        }
        ObstacleConfig::KeepOut { min, max, .. } => {
            c.finite(&format!("{at}.min"), min)?;
            c.finite(&format!("{at}.max"), max)?;
            if (0..3).any(|k| min[k] >= max[k]) {
                return Err(c.fail(
                    format!("{at}.max"),
                    format!("{max:?}"),
                    "above min on every axis",
                ));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(extra: &str) -> Result<()> {
        let text = format!(
            r#"
[robot]
urdf = "x.urdf"
[arm]
kind = "sim"
start = [0.0, 0.1]
[camera]
kind = "sim"
width = 640
height = 480
fx = 600.0
fy = 600.0
cx = 319.5
cy = 239.5
truth = {{ eye = [1.0, 0.5, 0.8], look_at = [0.0, 0.0, 0.3] }}
[segmenter]
kind = "sim-truth"
{extra}
"#
        );
        let path = Path::new("cell.toml");
        let cfg: CellConfig =
            toml::from_str(&text).map_err(|e| Error::input(path, "toml", e.to_string()))?;
        cfg.validate(path)
    }

    fn message(extra: &str) -> String {
        parse(extra).expect_err("should be refused").to_string()
    }

    #[test]
    fn a_plain_cell_passes() {
        parse("").unwrap();
    }

    #[test]
    fn nan_and_reversed_joint_ranges_are_refused() {
        let m = message("[safety]\njoint_ranges = { joint1 = [nan, 1.0] }");
        assert!(m.contains("safety.joint_ranges.joint1[0]"), "{m}");
        let m = message("[safety]\njoint_ranges = { joint1 = [1.0, -1.0] }");
        assert!(m.contains("lower < upper"), "{m}");
    }

    #[test]
    fn a_three_value_range_is_refused_not_truncated() {
        let m = message("[safety]\njoint_ranges = { joint1 = [0.0, 1.0, 2.0] }");
        assert!(m.contains("toml"), "{m}");
    }

    #[test]
    fn sizes_above_their_bounds_are_refused() {
        let m = message("[calibration]\njoint_samples = 100000000");
        assert!(
            m.contains("calibration.joint_samples") && m.contains("1 to 100000"),
            "{m}"
        );
        let m = message("[calibration]\nclimb_steps = 100000000");
        assert!(m.contains("calibration.climb_steps"), "{m}");
    }

    /// A whole cell with `arm_start`, `fx` and `robot_joints` substituted.
    fn cell(arm_start: &str, fx: &str, robot_joints: &str) -> Result<()> {
        let text = format!(
            "[robot]\nurdf='x'\n{robot_joints}\n[arm]\nkind='sim'\nstart={arm_start}\n[camera]\nkind='sim'\nwidth=640\nheight=480\nfx={fx}\nfy=600.0\ncx=319.5\ncy=239.5\ntruth={{ eye=[1.0, 0.5, 0.8], look_at=[0.0, 0.0, 0.3] }}\n[segmenter]\nkind='sim-truth'\n"
        );
        let cfg: CellConfig = toml::from_str(&text).unwrap();
        cfg.validate(Path::new("c.toml"))
    }

    #[test]
    fn absurd_intrinsics_and_nan_start_are_refused() {
        let m = cell("[0.0, nan]", "600.0", "").unwrap_err().to_string();
        assert!(m.contains("arm.start[1]"), "{m}");
        let m = cell("[0.0]", "1e300", "").unwrap_err().to_string();
        assert!(m.contains("camera.fx"), "{m}");
        cell("[0.0]", "600.0", "").unwrap();
    }

    #[test]
    fn a_joint_listed_twice_is_refused() {
        let m = cell("[0.0]", "600.0", "joints=['a','b','a']")
            .unwrap_err()
            .to_string();
        assert!(m.contains("robot.joints[2]"), "{m}");
    }
}

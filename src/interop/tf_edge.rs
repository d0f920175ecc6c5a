//! The one tf edge a calibration adds to a robot's frame tree, shared by the exports and by
//! `easyhec publish`.
//!
//! A result holds `camera_from_base`, whose camera frame is the OpenCV optical frame (x right,
//! y down, z forward). A camera driver usually publishes its own little tree under a root link
//! (`camera_link → … → camera_color_optical_frame`). In tf a frame has one parent, so an edge
//! from the base straight to the driver's optical frame would give it a second parent and break
//! the tree. The way out is to attach the camera's root link instead: with the driver's fixed
//! `optical_from_child` (the optical frame seen from the camera root link, inverted), the edge
//! becomes `base_from_child = base_from_optical · optical_from_child`.

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

use crate::error::{Error, Result};
use crate::run::ResultFile;

use crate::config::ros2::check_frame_name;
pub use crate::config::ros2::DEFAULT_CHILD_FRAME;

/// How far a given quaternion's norm may be from 1 (values copied from `tf2_echo` carry three
/// or four decimals) before it is refused rather than normalised.
const QUATERNION_NORM_TOLERANCE: f64 = 1e-2;

/// One directed tf edge: `parent_from_child` maps child-frame points into the parent frame,
/// which is what a `geometry_msgs/TransformStamped` with these frame ids carries.
#[derive(Clone, Debug, PartialEq)]
pub struct TfEdge {
    /// `header.frame_id`.
    pub parent: String,
    /// `child_frame_id`.
    pub child: String,
    /// Child-frame points to parent-frame points, metres.
    pub parent_from_child: Isometry3<f64>,
}

impl TfEdge {
    /// The edge from a result's base frame (or `parent`, when given) to `child`. Without
    /// `optical_from_child` the child is the optical frame itself. Frame names are checked
    /// here; an error names the flag or key the user set them with (`labels`: parent, child,
    /// e.g. `["--frame-id", "--child-frame-id"]`).
    pub fn from_result(
        result: &ResultFile,
        parent: Option<&str>,
        child: &str,
        optical_from_child: Option<&Isometry3<f64>>,
        labels: [&str; 2],
    ) -> Result<Self> {
        let [parent_label, child_label] = labels;
        let parent = parent.unwrap_or(&result.base_link);
        check_frame_name(parent).map_err(|m| Error::Usage(format!("{parent_label} is {m}")))?;
        check_frame_name(child).map_err(|m| Error::Usage(format!("{child_label} is {m}")))?;
        if parent == child {
            return Err(Error::Usage(format!(
                "{child_label} is {child:?}, the same as the parent frame; allowed: a different frame"
            )));
        }
        let base_from_optical = result.camera_from_base().inverse();
        let parent_from_child = match optical_from_child {
            Some(o) => base_from_optical * o,
            None => base_from_optical,
        };
        Ok(Self {
            parent: parent.to_string(),
            child: child.to_string(),
            parent_from_child,
        })
    }

    /// Translation in metres, `[x, y, z]`.
    pub fn translation(&self) -> [f64; 3] {
        let t = self.parent_from_child.translation.vector;
        [t.x, t.y, t.z]
    }

    /// Rotation as a unit quaternion `[x, y, z, w]`, with `w ≥ 0` so that the same rotation
    /// always prints the same numbers.
    pub fn quaternion_xyzw(&self) -> [f64; 4] {
        let q = self.parent_from_child.rotation;
        let s = if q.w < 0.0 { -1.0 } else { 1.0 };
        [s * q.i, s * q.j, s * q.k, s * q.w]
    }
}

/// Parses `x y z qx qy qz qw` (spaces or commas between them): the translation in metres and
/// a quaternion, the order `static_transform_publisher` and `tf2_echo` use. `what` names the
/// flag or field in the error.
pub fn parse_transform(text: &str, what: &str) -> Result<Isometry3<f64>> {
    let allowed = "allowed: 7 finite numbers 'x y z qx qy qz qw' (metres; a unit quaternion)";
    let mut v = Vec::new();
    for tok in text
        .split(|c: char| c.is_whitespace() || c == ',')
        .filter(|t| !t.is_empty())
    {
        match tok.parse::<f64>() {
            Ok(x) if x.is_finite() => v.push(x),
            _ => return Err(Error::Usage(format!("{what} has {tok:?}; {allowed}"))),
        }
    }
    if v.len() != 7 {
        return Err(Error::Usage(format!(
            "{what} has {} numbers; {allowed}",
            v.len()
        )));
    }
    transform_from_parts([v[0], v[1], v[2]], [v[3], v[4], v[5], v[6]])
        .map_err(|m| Error::Usage(format!("{what} {m}; {allowed}")))
}

/// Builds an isometry from a translation and an `[x, y, z, w]` quaternion whose norm is within
/// [`QUATERNION_NORM_TOLERANCE`] of 1 (then normalised).
pub fn transform_from_parts(
    t: [f64; 3],
    q_xyzw: [f64; 4],
) -> std::result::Result<Isometry3<f64>, String> {
    if t.iter().chain(q_xyzw.iter()).any(|v| !v.is_finite()) {
        return Err("has a non-finite number".into());
    }
    if let Some(problem) = crate::geometry::translation_problem(&t) {
        return Err(format!("has {problem}"));
    }
    let q = Quaternion::new(q_xyzw[3], q_xyzw[0], q_xyzw[1], q_xyzw[2]);
    let norm = q.norm();
    if (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
        return Err(format!("has a quaternion of norm {norm:.6}"));
    }
    Ok(Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_quaternion(q),
    ))
}

/// A listed camera's child frame from a child frame pattern (`--child-frame-id`, `[ros2]
/// child_frame_id`): `{name}` replaced by the camera's name, or, without `{name}`, the name
/// and `_` put in front.
pub fn camera_frame(pattern: &str, name: &str) -> String {
    if pattern.contains("{name}") {
        pattern.replace("{name}", name)
    } else {
        format!("{name}_{pattern}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{exp_se3, Twist};

    const FLAGS: [&str; 2] = ["--frame-id", "--child-frame-id"];

    #[test]
    fn the_edge_attaches_the_camera_root_link_through_the_optical_frame() {
        let camera_from_base = exp_se3(&Twist::new(0.3, -0.2, 1.1, 0.5, -1.2, 2.0));
        let result = ResultFile::new(&camera_from_base, "link_base");
        let optical_from_child = exp_se3(&Twist::new(0.01, 0.02, -0.03, 1.2, -1.1, 0.4));
        let edge = TfEdge::from_result(
            &result,
            None,
            "camera_link",
            Some(&optical_from_child),
            FLAGS,
        )
        .unwrap();
        assert_eq!(edge.parent, "link_base");
        // A point fixed in the camera root link reaches the base through the optical frame.
        let p_child = nalgebra::Point3::new(0.2, -0.1, 0.5);
        let via_optical = camera_from_base.inverse() * (optical_from_child * p_child);
        assert!((edge.parent_from_child * p_child - via_optical).norm() < 1e-12);
        let q = edge.quaternion_xyzw();
        assert!(q[3] >= 0.0 && (q.iter().map(|v| v * v).sum::<f64>() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn transforms_parse_and_bad_ones_are_refused_with_the_flag_named() {
        let t = parse_transform("0.1, 0.2 0.3 0 0 0.7071 0.7071", "--optical-from-child").unwrap();
        assert!((t.translation.vector.y - 0.2).abs() < 1e-15);
        assert!((t.rotation.angle() - std::f64::consts::FRAC_PI_2).abs() < 1e-4);
        for bad in ["1 2 3", "0 0 0 0 0 0 2", "0 0 nan 0 0 0 1", "0 0 0 0 0 0 x"] {
            let e = parse_transform(bad, "--optical-from-child").unwrap_err();
            let msg = e.to_string();
            assert!(
                msg.contains("--optical-from-child") && msg.contains("allowed"),
                "{msg}"
            );
        }
    }

    #[test]
    fn a_child_equal_to_the_parent_or_badly_named_is_refused() {
        let result = ResultFile::new(&Isometry3::identity(), "link_base");
        assert!(TfEdge::from_result(&result, None, "link_base", None, FLAGS).is_err());
        let e = TfEdge::from_result(&result, Some("a b"), "cam", None, FLAGS).unwrap_err();
        assert!(e.to_string().starts_with("--frame-id is"), "{e}");
        let e = TfEdge::from_result(&result, None, "cam:x", None, ["p", "ros2.child_frame_id"]);
        assert!(e
            .unwrap_err()
            .to_string()
            .starts_with("ros2.child_frame_id is"));
    }
}

//! A result in the forms other tools read. Every string embedded in YAML, URDF or a command
//! line is a ROS frame name, checked before anything is rendered: a name that could break
//! out of its field (a newline, a quote, a colon) is refused, not escaped into something the
//! reader would take for other keys.

use std::fmt::Write as _;

use nalgebra::{Isometry3, UnitQuaternion};

use crate::error::{Error, Result};
use crate::geometry::to_rows;
use crate::run::ResultFile;

/// Longest frame name accepted.
pub const MAX_FRAME_NAME_LEN: usize = 256;

/// Checks a tf frame name: ASCII letters, digits, `_` and `/` (namespaces), not starting with a
/// digit, at most [`MAX_FRAME_NAME_LEN`] long. These names need no quoting in YAML, XML or a
/// shell, so the exports cannot be made to say anything else.
pub fn check_frame_name(name: &str) -> std::result::Result<(), String> {
    let ok_char = |c: char| c.is_ascii_alphanumeric() || c == '_' || c == '/';
    let starts_ok = name.chars().next().is_some_and(|c| !c.is_ascii_digit());
    if !name.is_empty()
        && name.len() <= MAX_FRAME_NAME_LEN
        && starts_ok
        && name.chars().all(ok_char)
    {
        return Ok(());
    }
    Err(format!(
        "{name:?}; allowed: 1 to {MAX_FRAME_NAME_LEN} ASCII letters, digits, '_' or '/', not starting with a digit"
    ))
}

/// Export targets.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ExportFormat {
    /// OpenCV FileStorage YAML with the 4x4 `camera_from_base` and `base_from_camera`, plus a
    /// plain-text 4x4 when written to a `.txt` path.
    Opencv,
    /// ROS: `static_transform_publisher` arguments and a tf YAML with quaternion.
    Ros,
    /// easy_handeye calibration YAML (eye-on-base).
    EasyHandeye,
    /// A URDF `<joint>` snippet placing the camera optical frame on the base link.
    Urdf,
}

impl std::str::FromStr for ExportFormat {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        <ExportFormat as clap::ValueEnum>::from_str(s, false).map_err(|_| {
            format!("unknown export format '{s}': use opencv, ros, easy-handeye or urdf")
        })
    }
}

fn quat_xyzw(q: &UnitQuaternion<f64>) -> [f64; 4] {
    [q.i, q.j, q.k, q.w]
}

/// Renders `result` in `format`. `camera_frame` names the optical frame for ROS/URDF forms.
/// Fails, naming the field, when the camera frame or the result's `base_link` is not a plain
/// frame name ([`check_frame_name`]).
pub fn export(result: &ResultFile, format: ExportFormat, camera_frame: &str) -> Result<String> {
    check_frame_name(camera_frame).map_err(|m| Error::Usage(format!("--camera-frame is {m}")))?;
    check_frame_name(&result.base_link)
        .map_err(|m| Error::Usage(format!("the result's base_link is {m}")))?;
    let cfb = result.camera_from_base();
    let bfc: Isometry3<f64> = cfb.inverse();
    let base = &result.base_link;
    let t = bfc.translation.vector;
    let q = quat_xyzw(&bfc.rotation);
    let mut s = String::new();
    match format {
        ExportFormat::Opencv => {
            let mat = |s: &mut String, name: &str, rows: [[f64; 4]; 4]| {
                let data: Vec<String> =
                    rows.iter().flatten().map(|v| format!("{v:.12e}")).collect();
                let _ = writeln!(
                    s,
                    "{name}: !!opencv-matrix\n   rows: 4\n   cols: 4\n   dt: d\n   data: [ {} ]",
                    data.join(", ")
                );
            };
            s.push_str("%YAML:1.0\n---\n");
            let _ = writeln!(s, "# camera_from_base maps base-frame ({base}) points to the OpenCV optical frame, metres");
            mat(&mut s, "camera_from_base", to_rows(&cfb));
            mat(&mut s, "base_from_camera", to_rows(&bfc));
        }
        ExportFormat::Ros => {
            let _ = writeln!(s, "# static_transform_publisher x y z qx qy qz qw frame_id child_frame_id (parent = {base})");
            let _ = writeln!(
                s,
                "# rosrun tf2_ros static_transform_publisher {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {base} {camera_frame}",
                t.x, t.y, t.z, q[0], q[1], q[2], q[3]
            );
            let _ = writeln!(
                s,
                "header:\n  frame_id: {base}\nchild_frame_id: {camera_frame}\ntransform:"
            );
            let _ = writeln!(
                s,
                "  translation:\n    x: {:.12}\n    y: {:.12}\n    z: {:.12}",
                t.x, t.y, t.z
            );
            let _ = writeln!(
                s,
                "  rotation:\n    x: {:.12}\n    y: {:.12}\n    z: {:.12}\n    w: {:.12}",
                q[0], q[1], q[2], q[3]
            );
        }
        ExportFormat::EasyHandeye => {
            let _ = writeln!(s, "eye_on_hand: false\nrobot_base_frame: {base}\ntracking_base_frame: {camera_frame}\ntransformation:");
            let _ = writeln!(s, "  x: {:.12}\n  y: {:.12}\n  z: {:.12}\n  qx: {:.12}\n  qy: {:.12}\n  qz: {:.12}\n  qw: {:.12}", t.x, t.y, t.z, q[0], q[1], q[2], q[3]);
        }
        ExportFormat::Urdf => {
            let (r, p, y) = bfc.rotation.euler_angles();
            let _ = writeln!(s, "<!-- camera pose from easyhec: base_from_camera ({base} -> {camera_frame}, OpenCV optical frame) -->");
            let _ = writeln!(s, "<link name=\"{camera_frame}\"/>");
            let _ = writeln!(
                s,
                "<joint name=\"{camera_frame}_joint\" type=\"fixed\">\n  <parent link=\"{base}\"/>\n  <child link=\"{camera_frame}\"/>\n  <origin xyz=\"{:.12} {:.12} {:.12}\" rpy=\"{:.12} {:.12} {:.12}\"/>\n</joint>",
                t.x, t.y, t.z, r, p, y
            );
        }
    }
    Ok(s)
}

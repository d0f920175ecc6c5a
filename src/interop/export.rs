//! A result in the forms other tools read. Every string embedded in YAML, URDF, Python or a
//! command line is a ROS frame name, checked before anything is rendered: a name that could
//! break out of its field (a newline, a quote, a colon) is refused, not escaped into something
//! the reader would take for other keys. The ROS forms carry one tf edge ([`TfEdge`]): from the
//! base frame to the camera frame the user names.

use std::fmt::Write as _;

use crate::error::{Error, Result};
use crate::geometry::to_rows;
use crate::run::ResultFile;

use super::tf_edge::TfEdge;

pub use crate::config::ros2::{check_frame_name, MAX_FRAME_NAME_LEN};

/// Export targets: the one list of them. The CLI (`--format`, its help and errors), the
/// daemon's download route (its OpenAPI enum, file names and content types) and the web page
/// (which reads the names from `/openapi.json`) all take the names, extensions and content
/// types from here. The names are clap's and serde's kebab-case of the variants.
#[derive(
    Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize, utoipa::ToSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum ExportFormat {
    /// OpenCV FileStorage YAML with the 4x4 `camera_from_base` and `base_from_camera` (the
    /// optical frame, whatever child frame is named).
    Opencv,
    /// ROS 2: a Python launch file running tf2_ros's `static_transform_publisher`, with the
    /// equivalent `ros2 run` command in its header.
    Ros,
    /// easy_handeye2's calibration file (`~/.ros2/easy_handeye2/calibrations/NAME.calib`).
    EasyHandeye,
    /// The flat YAML of easy_handeye for ROS 1 (`eye_on_hand`, `transformation`).
    EasyHandeyeRos1,
    /// A URDF `<joint>` snippet placing the camera frame on the base link.
    Urdf,
}

/// What a file of one export format is: its extension (no leading dot; distinct per
/// format, so every format can be exported into one folder) and its HTTP content type.
struct FormatFile {
    extension: &'static str,
    content_type: &'static str,
}

impl ExportFormat {
    /// Every format, in the order help texts and the page list them.
    pub const ALL: [ExportFormat; 5] = [
        ExportFormat::Opencv,
        ExportFormat::Ros,
        ExportFormat::EasyHandeye,
        ExportFormat::EasyHandeyeRos1,
        ExportFormat::Urdf,
    ];

    fn file(self) -> FormatFile {
        let (extension, content_type) = match self {
            ExportFormat::Opencv => ("opencv.yaml", "application/yaml"),
            ExportFormat::Ros => ("launch.py", "text/x-python"),
            ExportFormat::EasyHandeye => ("calib", "application/yaml"),
            ExportFormat::EasyHandeyeRos1 => ("easy_handeye.yaml", "application/yaml"),
            ExportFormat::Urdf => ("urdf", "application/xml"),
        };
        FormatFile {
            extension,
            content_type,
        }
    }

    /// The name on the command line, in the route and on the page (`easy-handeye-ros1`).
    pub fn name(self) -> String {
        clap::ValueEnum::to_possible_value(&self)
            .map(|v| v.get_name().to_string())
            .unwrap_or_default()
    }

    /// The file extension, without the leading dot (`opencv.yaml`, `launch.py`).
    pub fn extension(self) -> &'static str {
        self.file().extension
    }

    /// The HTTP content type of a download.
    pub fn content_type(self) -> &'static str {
        self.file().content_type
    }

    /// `STEM.EXTENSION`: the CLI's file per camera and the daemon's download name.
    pub fn file_name(self, stem: &str) -> String {
        format!("{stem}.{}", self.extension())
    }

    /// Every name, comma-separated, for error messages.
    pub fn names() -> String {
        Self::ALL.map(Self::name).join(", ")
    }
}

impl std::str::FromStr for ExportFormat {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        <ExportFormat as clap::ValueEnum>::from_str(s, false)
            .map_err(|_| format!("unknown export format '{s}': use {}", Self::names()))
    }
}

/// The name easy_handeye2 files the calibration under (its `parameters.name`); the docs tell
/// the user to save the file as `easyhec.calib` to match.
pub const EASY_HANDEYE2_NAME: &str = "easyhec";

/// Renders `result` in `format`, with `edge` (built from the same result) as the ROS forms'
/// transform. Fails, naming the field, when the result's `base_link` is not a plain frame
/// name ([`check_frame_name`]).
pub fn export(result: &ResultFile, format: ExportFormat, edge: &TfEdge) -> Result<String> {
    check_frame_name(&result.base_link)
        .map_err(|m| Error::Usage(format!("the result's base_link is {m}")))?;
    Ok(match format {
        ExportFormat::Opencv => opencv_yaml(result),
        ExportFormat::Ros => ros2_launch_file(edge),
        ExportFormat::EasyHandeye => easy_handeye2_file(edge),
        ExportFormat::EasyHandeyeRos1 => easy_handeye_ros1_yaml(edge),
        ExportFormat::Urdf => urdf_joint(edge),
    })
}

/// `v` in the fewest digits that read back to the same f64, spelled so that every reader
/// takes it for a float: with a `.` in the mantissa and a signed exponent (`1.0`, `2.5e-7`,
/// `1.0e+300`). YAML 1.1 readers (PyYAML, used by easy_handeye) read `1e-7` or `1.5e0` as
/// strings, and an integer `1` would reach a float field as an int.
pub fn number(v: f64) -> String {
    let s = format!("{v:?}");
    let Some((mantissa, exponent)) = s.split_once('e') else {
        return s;
    };
    let mantissa = if mantissa.contains('.') {
        mantissa.to_string()
    } else {
        format!("{mantissa}.0")
    };
    let exponent = if exponent.starts_with('-') {
        exponent.to_string()
    } else {
        format!("+{exponent}")
    };
    format!("{mantissa}e{exponent}")
}

fn opencv_yaml(result: &ResultFile) -> String {
    let cfb = result.camera_from_base();
    let mut s = String::from("%YAML:1.0\n---\n");
    let mat = |s: &mut String, name: &str, rows: [[f64; 4]; 4]| {
        let data: Vec<String> = rows.iter().flatten().map(|v| format!("{v:.12e}")).collect();
        let _ = writeln!(
            s,
            "{name}: !!opencv-matrix\n   rows: 4\n   cols: 4\n   dt: d\n   data: [ {} ]",
            data.join(", ")
        );
    };
    let base = &result.base_link;
    let _ = writeln!(
        s,
        "# camera_from_base maps base-frame ({base}) points to the OpenCV optical frame, metres"
    );
    mat(&mut s, "camera_from_base", to_rows(&cfb));
    mat(&mut s, "base_from_camera", to_rows(&cfb.inverse()));
    s
}

/// `static_transform_publisher`'s named arguments (ROS 2 Humble and later), in order.
fn publisher_arguments(edge: &TfEdge) -> Vec<(&'static str, String)> {
    let t = edge.translation();
    let q = edge.quaternion_xyzw();
    let names = ["--x", "--y", "--z", "--qx", "--qy", "--qz", "--qw"];
    let mut args: Vec<(&'static str, String)> = names
        .iter()
        .zip(t.iter().chain(q.iter()))
        .map(|(n, v)| (*n, number(*v)))
        .collect();
    args.push(("--frame-id", edge.parent.clone()));
    args.push(("--child-frame-id", edge.child.clone()));
    args
}

fn ros2_launch_file(edge: &TfEdge) -> String {
    let args = publisher_arguments(edge);
    let command: Vec<String> = args.iter().map(|(n, v)| format!("{n} {v}")).collect();
    let listed: Vec<String> = args
        .iter()
        .map(|(n, v)| format!("                \"{n}\", \"{v}\","))
        .collect();
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# easyhec calibration as a ROS 2 launch file: {} -> {} (parent_from_child).",
        edge.parent, edge.child
    );
    let _ = writeln!(
        s,
        "# Run it with `ros2 launch ./FILE.launch.py`, or publish the same edge with:\n#"
    );
    let _ = writeln!(
        s,
        "#   ros2 run tf2_ros static_transform_publisher {}",
        command.join(" ")
    );
    let _ = writeln!(
        s,
        "\nfrom launch import LaunchDescription\nfrom launch_ros.actions import Node\n\n"
    );
    let _ = writeln!(s, "def generate_launch_description():");
    let _ = writeln!(s, "    return LaunchDescription([");
    let _ = writeln!(s, "        Node(");
    let _ = writeln!(s, "            package=\"tf2_ros\",");
    let _ = writeln!(s, "            executable=\"static_transform_publisher\",");
    let _ = writeln!(s, "            name=\"easyhec_camera_tf\",");
    let _ = writeln!(
        s,
        "            arguments=[\n{}\n            ],",
        listed.join("\n")
    );
    let _ = writeln!(s, "        ),\n    ])");
    s
}

fn yaml_translation_rotation(s: &mut String, indent: &str, edge: &TfEdge) {
    let t = edge.translation();
    let q = edge.quaternion_xyzw();
    let _ = writeln!(s, "{indent}translation:");
    for (k, v) in ["x", "y", "z"].iter().zip(t) {
        let _ = writeln!(s, "{indent}  {k}: {}", number(v));
    }
    let _ = writeln!(s, "{indent}rotation:");
    for (k, v) in ["x", "y", "z", "w"].iter().zip(q) {
        let _ = writeln!(s, "{indent}  {k}: {}", number(v));
    }
}

/// easy_handeye2 stores an `easy_handeye2_msgs/HandeyeCalibration` message as YAML and loads
/// it field by field, so every key here is one of that message's fields. Its publisher sends
/// `transform` from `robot_base_frame` (eye on base) to `tracking_base_frame`.
fn easy_handeye2_file(edge: &TfEdge) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "parameters:");
    let _ = writeln!(s, "  name: {EASY_HANDEYE2_NAME}");
    let _ = writeln!(s, "  calibration_type: eye_on_base");
    let _ = writeln!(s, "  robot_base_frame: {}", yaml_scalar(&edge.parent));
    let _ = writeln!(s, "  robot_effector_frame: ''");
    let _ = writeln!(s, "  tracking_base_frame: {}", yaml_scalar(&edge.child));
    let _ = writeln!(s, "  tracking_marker_frame: ''");
    let _ = writeln!(s, "  freehand_robot_movement: false");
    let _ = writeln!(s, "  move_group_namespace: /");
    let _ = writeln!(s, "  move_group: manipulator");
    let _ = writeln!(s, "transform:");
    yaml_translation_rotation(&mut s, "  ", edge);
    s
}

/// A frame name as a YAML string scalar: quoted when a YAML 1.1 reader (PyYAML, ROS 1's
/// rosparam) would take it for another type (`on`, `no`, `null`, `1e3`, `0x1f`), plain
/// otherwise. Frame names hold no quotes ([`check_frame_name`]), so single quotes suffice.
pub fn yaml_scalar(name: &str) -> std::borrow::Cow<'_, str> {
    const OTHER_TYPES: [&str; 16] = [
        "y", "n", "yes", "no", "true", "false", "on", "off", "null", "~", ".inf", "+.inf", "-.inf",
        ".nan", "<<", "=",
    ];
    let lower = name.to_ascii_lowercase();
    let digits_only = name.replace('_', "");
    let numeric = digits_only.parse::<f64>().is_ok()
        || lower.starts_with("0x")
        || lower.starts_with("0o")
        || lower.starts_with("0b")
        || lower.starts_with("+0")
        || lower.starts_with("-0");
    if name.is_empty() || OTHER_TYPES.contains(&lower.as_str()) || numeric {
        std::borrow::Cow::Owned(format!("'{name}'"))
    } else {
        std::borrow::Cow::Borrowed(name)
    }
}

fn easy_handeye_ros1_yaml(edge: &TfEdge) -> String {
    let t = edge.translation();
    let q = edge.quaternion_xyzw();
    let mut s = String::new();
    let _ = writeln!(
        s,
        "eye_on_hand: false\nrobot_base_frame: {}\ntracking_base_frame: {}\ntransformation:",
        yaml_scalar(&edge.parent),
        yaml_scalar(&edge.child)
    );
    for (k, v) in ["x", "y", "z", "qx", "qy", "qz", "qw"]
        .iter()
        .zip(t.iter().chain(q.iter()))
    {
        let _ = writeln!(s, "  {k}: {}", number(*v));
    }
    s
}

fn urdf_joint(edge: &TfEdge) -> String {
    let t = edge.translation();
    let (r, p, y) = edge.parent_from_child.rotation.euler_angles();
    let (parent, child) = (&edge.parent, &edge.child);
    let mut s = String::new();
    let _ = writeln!(
        s,
        "<!-- camera pose from easyhec: {parent} -> {child} (parent_from_child) -->"
    );
    let _ = writeln!(s, "<link name=\"{child}\"/>");
    let _ = writeln!(
        s,
        "<joint name=\"{child}_joint\" type=\"fixed\">\n  <parent link=\"{parent}\"/>\n  <child link=\"{child}\"/>\n  <origin xyz=\"{} {} {}\" rpy=\"{} {} {}\"/>\n</joint>",
        number(t[0]), number(t[1]), number(t[2]), number(r), number(p), number(y)
    );
    s
}

#[cfg(test)]
mod tests {
    use super::{number, ExportFormat};

    /// The names clap takes are the names serde writes (the OpenAPI enum the page reads),
    /// `ALL` holds every variant once, and no two formats share a file extension (so they
    /// can all be exported into one folder).
    #[test]
    fn one_list_of_formats_with_distinct_files() {
        let mut extensions = std::collections::BTreeSet::new();
        for f in ExportFormat::ALL {
            let json = serde_json::to_value(f).unwrap();
            assert_eq!(json.as_str(), Some(f.name().as_str()));
            assert_eq!(f.name().parse::<ExportFormat>(), Ok(f));
            assert!(extensions.insert(f.extension()), "{f:?}: {}", f.extension());
        }
        let all = <ExportFormat as clap::ValueEnum>::value_variants();
        assert_eq!(all, ExportFormat::ALL.as_slice());
        assert_eq!(
            ExportFormat::Opencv.file_name("cal-0003"),
            "cal-0003.opencv.yaml"
        );
    }

    #[test]
    fn numbers_read_back_exactly_and_always_look_like_floats() {
        for v in [
            0.0,
            -0.0,
            1.0,
            0.5,
            -2.25e-7,
            1.0e300,
            0.1 + 0.2,
            std::f64::consts::PI,
            123456789.0,
        ] {
            let s = number(v);
            assert_eq!(s.parse::<f64>().unwrap().to_bits(), v.to_bits(), "{s}");
            assert!(s.contains('.'), "{s}");
            if let Some((_, e)) = s.split_once('e') {
                assert!(e.starts_with('+') || e.starts_with('-'), "{s}");
            }
        }
        assert_eq!(number(1e-7), "1.0e-7");
        assert_eq!(number(1.0), "1.0");
    }
}

//! The ROS 2 messages easyhec speaks, as plain structs whose fields follow the `.msg`
//! definitions in order: ROS 2 puts them on the wire as CDR, which serialises a struct's
//! fields one after the other, so the order is the layout.

use serde::{Deserialize, Serialize};

/// `builtin_interfaces/Time`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Time {
    /// Seconds since the Unix epoch.
    pub sec: i32,
    /// Nanoseconds within the second.
    pub nanosec: u32,
}

impl Time {
    /// The system clock now (what tf2's static broadcaster stamps its edges with).
    pub fn now() -> Self {
        let since = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap_or_default();
        Self {
            sec: i32::try_from(since.as_secs()).unwrap_or(i32::MAX),
            nanosec: since.subsec_nanos(),
        }
    }
}

/// `std_msgs/Header`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// When the data was valid.
    pub stamp: Time,
    /// The frame the data is expressed in.
    pub frame_id: String,
}

/// `geometry_msgs/Vector3`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    /// x, metres.
    pub x: f64,
    /// y, metres.
    pub y: f64,
    /// z, metres.
    pub z: f64,
}

/// `geometry_msgs/Quaternion`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    /// i part.
    pub x: f64,
    /// j part.
    pub y: f64,
    /// k part.
    pub z: f64,
    /// Real part.
    pub w: f64,
}

/// `geometry_msgs/Transform`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Transform {
    /// Child origin in the parent frame.
    pub translation: Vector3,
    /// Child axes in the parent frame.
    pub rotation: Quaternion,
}

/// `geometry_msgs/TransformStamped`: `transform` is `parent_from_child`, with the parent in
/// `header.frame_id`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TransformStamped {
    /// Stamp and parent frame.
    pub header: Header,
    /// Child frame.
    pub child_frame_id: String,
    /// Child-frame points to parent-frame points.
    pub transform: Transform,
}

/// `tf2_msgs/TFMessage`, the type of `/tf` and `/tf_static`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TfMessage {
    /// The edges.
    pub transforms: Vec<TransformStamped>,
}

/// `builtin_interfaces/Duration`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Duration {
    /// Whole seconds.
    pub sec: i32,
    /// Nanoseconds within the second.
    pub nanosec: u32,
}

impl From<std::time::Duration> for Duration {
    fn from(d: std::time::Duration) -> Self {
        Self {
            sec: i32::try_from(d.as_secs()).unwrap_or(i32::MAX),
            nanosec: d.subsec_nanos(),
        }
    }
}

/// `sensor_msgs/JointState`: any subset of a robot's joints, by name.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JointState {
    /// Stamp and frame (unused).
    pub header: Header,
    /// Joint names.
    pub name: Vec<String>,
    /// Positions, rad or m, one per name (or empty).
    pub position: Vec<f64>,
    /// Velocities (may be empty).
    pub velocity: Vec<f64>,
    /// Efforts (may be empty).
    pub effort: Vec<f64>,
}

/// `trajectory_msgs/JointTrajectoryPoint`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JointTrajectoryPoint {
    /// Positions, one per joint name.
    pub positions: Vec<f64>,
    /// Velocities (empty: the controller interpolates positions linearly).
    pub velocities: Vec<f64>,
    /// Accelerations (empty).
    pub accelerations: Vec<f64>,
    /// Efforts (empty).
    pub effort: Vec<f64>,
    /// When the point is to be reached, from the trajectory's start.
    pub time_from_start: Duration,
}

/// `trajectory_msgs/JointTrajectory`: what ros2_control's joint_trajectory_controller takes
/// on its `~/joint_trajectory` topic (current versions refuse an empty `points` list).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JointTrajectory {
    /// Stamp zero: start now.
    pub header: Header,
    /// The joints the points name, in order.
    pub joint_names: Vec<String>,
    /// The points.
    pub points: Vec<JointTrajectoryPoint>,
}

/// `sensor_msgs/Image`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Image {
    /// Exposure stamp and the camera's optical frame.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Pixel layout: `rgb8`, `bgr8`, `mono8`, `yuv422` (UYVY), `yuv422_yuy2` (YUYV), ….
    pub encoding: String,
    /// 1 when multi-byte values are big-endian.
    pub is_bigendian: u8,
    /// Bytes per row.
    pub step: u32,
    /// `step × height` bytes.
    pub data: Vec<u8>,
}

/// `sensor_msgs/RegionOfInterest`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RegionOfInterest {
    /// Left edge.
    pub x_offset: u32,
    /// Top edge.
    pub y_offset: u32,
    /// Rows (0: the full image).
    pub height: u32,
    /// Columns (0: the full image).
    pub width: u32,
    /// Whether the region needs rectifying.
    pub do_rectify: bool,
}

/// `sensor_msgs/CameraInfo`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraInfo {
    /// Stamp and optical frame.
    pub header: Header,
    /// Calibrated rows.
    pub height: u32,
    /// Calibrated columns.
    pub width: u32,
    /// `plumb_bob`, `rational_polynomial`, `equidistant`, or empty.
    pub distortion_model: String,
    /// The model's coefficients.
    pub d: Vec<f64>,
    /// Camera matrix, row-major.
    pub k: [f64; 9],
    /// Rectification rotation, row-major.
    pub r: [f64; 9],
    /// Projection matrix, row-major.
    pub p: [f64; 12],
    /// Horizontal binning (0 or 1: none).
    pub binning_x: u32,
    /// Vertical binning.
    pub binning_y: u32,
    /// Region of interest.
    pub roi: RegionOfInterest,
}

//! `[camera]`: which camera backend grabs frames, its intrinsics, and the poses people measure
//! (`LookAt`).

use std::path::{Path, PathBuf};

use easyhec_drivers::aravis::PixelFormat as AravisPixelFormat;
use easyhec_drivers::intrinsics::{check_frame_size, load_intrinsics, IntrinsicsError};
use easyhec_drivers::v4l2::V4l2PixelFormat;
use easyhec_drivers::Intrinsics;
use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use super::arm::{ten, two, JOINT_STATES_TOPIC};
use super::mount::Mount;
use super::scene::SceneSettings;
use super::seconds;
use crate::error::{Error, Result};
use crate::geometry::{look_at_camera_from_base, point_problem};

/// A camera pose given the way people measure one: where it is and what it looks at.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct LookAt {
    /// Camera centre in the base frame, metres.
    pub eye: [f64; 3],
    /// A point the optical axis passes through, base frame, metres.
    pub look_at: [f64; 3],
    /// Rotation about the optical axis, degrees.
    #[serde(default)]
    pub roll_deg: f64,
}

impl LookAt {
    /// [`LookAt::camera_from_base`] after checking the numbers: finite, within
    /// [`crate::geometry::MAX_TRANSLATION_M`], and eye and target at least 1 mm apart (else
    /// there is no viewing direction).
    pub fn checked_camera_from_base(&self) -> std::result::Result<Isometry3<f64>, String> {
        let values = self.eye.iter().chain(&self.look_at).chain([&self.roll_deg]);
        if values.into_iter().any(|v| !v.is_finite()) {
            return Err("eye, look_at and roll_deg must be finite numbers".into());
        }
        for (name, point) in [("eye", &self.eye), ("look_at", &self.look_at)] {
            if let Some(problem) = point_problem(name, point) {
                return Err(problem);
            }
        }
        let apart = (0..3)
            .map(|k| (self.eye[k] - self.look_at[k]).powi(2))
            .sum::<f64>();
        if apart.sqrt() < 1e-3 {
            return Err(format!(
                "eye {:?} and look_at {:?} are less than 1 mm apart; allowed: a point the camera looks at, away from the camera",
                self.eye, self.look_at
            ));
        }
        Ok(self.camera_from_base())
    }

    /// As `camera_from_base` (OpenCV optical frame, base z up).
    pub fn camera_from_base(&self) -> Isometry3<f64> {
        let look = look_at_camera_from_base(
            &Vector3::from(self.eye),
            &Vector3::from(self.look_at),
            &Vector3::z(),
        );
        Isometry3::from_parts(
            nalgebra::Translation3::identity(),
            UnitQuaternion::from_scaled_axis(Vector3::z() * self.roll_deg.to_radians()),
        ) * look
    }
}

/// `[camera]`: one settings struct per `kind`, each holding the only copy of its defaults;
/// every kind has a [`Mount`].
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
// The simulated camera's scene dressing makes `Sim` large; a config is parsed once per cell.
#[allow(clippy::large_enum_variant)]
pub enum CameraConfig {
    /// The simulated camera.
    Sim(SimCameraSettings),
    /// A UVC webcam through V4L2. Needs the `v4l2` cargo feature; the variant exists without
    /// it so such a config gets a one-line "rebuild" error.
    V4l2(V4l2Settings),
    /// A GigE Vision or USB3 Vision camera through Aravis. Needs the `aravis` cargo feature;
    /// the variant exists without it so such a config gets a one-line "rebuild" error.
    Aravis(AravisSettings),
    /// A ROS 2 camera driver's topics (the `ros2` feature): `sensor_msgs/Image` frames and
    /// the intrinsics of its `sensor_msgs/CameraInfo`, in the `[ros2]` table's domain.
    Ros2(Ros2CameraSettings),
}

/// `[camera] kind = "sim"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SimCameraSettings {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Focal length x, pixels.
    pub fx: f64,
    /// Focal length y, pixels.
    pub fy: f64,
    /// Principal point x.
    pub cx: f64,
    /// Principal point y.
    pub cy: f64,
    /// `plumb_bob` k1 k2 p1 p2 k3.
    #[serde(default)]
    pub distortion: Option<[f64; 5]>,
    /// The true pose, which only the simulator sees: `camera_from_base`, or for a
    /// camera on a link `camera_from_<link>` (eye and target in that link's frame).
    pub truth: LookAt,
    /// Scene dressing.
    #[serde(default)]
    pub scene: SceneSettings,
    /// Where the true joints come from when the arm is not simulated (default: the
    /// simulated arm).
    #[serde(default)]
    pub joints_from: Option<JointsFrom>,
    /// Where the camera is fixed (default `"fixed"`; `{ link = "…" }` for eye-in-hand).
    #[serde(default)]
    pub mount: Mount,
}

impl SimCameraSettings {
    /// The camera model the table spells out.
    pub fn intrinsics(&self) -> Intrinsics {
        Intrinsics {
            width: self.width,
            height: self.height,
            fx: self.fx,
            fy: self.fy,
            cx: self.cx,
            cy: self.cy,
            distortion: self.distortion,
        }
    }
}

/// `[camera] kind = "v4l2"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct V4l2Settings {
    /// A device path (`/dev/video0`, `/dev/v4l/by-id/…`) or the camera's name as its
    /// driver reports it (a unique part of it is enough).
    pub device: String,
    /// Stream width, pixels: must equal the calibration file's `image_width`.
    pub width: u32,
    /// Stream height, pixels: must equal the calibration file's `image_height`.
    pub height: u32,
    /// `"YUYV"` or `"MJPG"`.
    pub pixel_format: String,
    /// Fixed exposure, microseconds (default: the camera's own, usually automatic).
    #[serde(default)]
    pub exposure_us: Option<u32>,
    /// The calibration file: ROS `camera_info` or OpenCV YAML.
    pub intrinsics: PathBuf,
    /// Limit for one frame, seconds.
    #[serde(default = "two")]
    pub frame_timeout_s: f64,
    /// Where the camera is fixed (default `"fixed"`; `{ link = "…" }` for eye-in-hand).
    #[serde(default)]
    pub mount: Mount,
}

/// `[camera] kind = "aravis"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct AravisSettings {
    /// Aravis device id (`<vendor>-<model>-<serial>`, `<vendor>-<serial>`, user id, MAC or
    /// IP; default: the first camera found). `"Fake_1"` is Aravis's built-in test camera.
    #[serde(default)]
    pub device_id: Option<String>,
    /// `"Mono8"`, `"BayerRG8"`, `"BayerGR8"`, `"BayerBG8"`, `"BayerGB8"` or `"RGB8"`.
    pub pixel_format: String,
    /// Fixed exposure, microseconds (default: the camera's setting).
    #[serde(default)]
    pub exposure_us: Option<f64>,
    /// Fixed gain, dB (default: the camera's setting).
    #[serde(default)]
    pub gain_db: Option<f64>,
    /// The calibration file: ROS `camera_info` or OpenCV YAML; its size must be the
    /// camera's region, which is checked when the camera opens.
    pub intrinsics: PathBuf,
    /// Limit for one frame, seconds.
    #[serde(default = "two")]
    pub frame_timeout_s: f64,
    /// Where the camera is fixed (default `"fixed"`; `{ link = "…" }` for eye-in-hand).
    #[serde(default)]
    pub mount: Mount,
}

/// `[camera] kind = "ros2"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Ros2CameraSettings {
    /// `sensor_msgs/Image` topic.
    #[serde(default = "Ros2CameraSettings::default_image_topic")]
    pub image_topic: String,
    /// `sensor_msgs/CameraInfo` topic.
    #[serde(default = "Ros2CameraSettings::default_camera_info_topic")]
    pub camera_info_topic: String,
    /// Longest wait for the first CameraInfo, seconds.
    #[serde(default = "ten")]
    pub connect_timeout_s: f64,
    /// Limit for one fresh frame, seconds.
    #[serde(default = "two")]
    pub frame_timeout_s: f64,
    /// Where the camera is fixed (default `"fixed"`; `{ link = "…" }` for eye-in-hand).
    #[serde(default)]
    pub mount: Mount,
}

impl Ros2CameraSettings {
    /// A RealSense's and most UVC drivers' colour stream.
    fn default_image_topic() -> String {
        "/camera/color/image_raw".into()
    }
    fn default_camera_info_topic() -> String {
        "/camera/color/camera_info".into()
    }
}

/// A hardware camera's calibration, read and checked when the cell is built, before the arm
/// is touched.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraCalibration {
    /// The intrinsics in the file.
    pub intrinsics: Intrinsics,
    /// The file (resolved against the config's folder).
    pub file: PathBuf,
}

/// The true-joint side channel of a simulated camera filming an arm that is not a
/// `kind = "sim"` arm.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum JointsFrom {
    /// An xArm controller's report port (30003 real or 30001 normal), mock or real.
    XarmReport {
        /// `host:port` of the report port.
        addr: String,
        /// Limit for receiving one report, seconds.
        #[serde(default = "two")]
        timeout_s: f64,
    },
    /// A UR controller's RTDE port (`actual_q`), mock or real.
    UrRtde {
        /// `host:port` of the RTDE port (30004).
        addr: String,
        /// Limit for connecting and receiving one data package, seconds.
        #[serde(default = "two")]
        timeout_s: f64,
    },
    /// A ROS 2 `sensor_msgs/JointState` topic (the `ros2` feature), in the `[ros2]` table's
    /// domain and namespace, with the `[arm]`'s joint names.
    Ros2 {
        /// The topic.
        #[serde(default = "joint_states_topic")]
        topic: String,
        /// Limit for the first complete message, seconds.
        #[serde(default = "ten")]
        timeout_s: f64,
    },
}

fn joint_states_topic() -> String {
    JOINT_STATES_TOPIC.into()
}

impl CameraConfig {
    /// Where the camera is fixed.
    pub fn mount(&self) -> &Mount {
        match self {
            CameraConfig::Sim(c) => &c.mount,
            CameraConfig::V4l2(c) => &c.mount,
            CameraConfig::Aravis(c) => &c.mount,
            CameraConfig::Ros2(c) => &c.mount,
        }
    }

    /// The camera model written in the config itself: a simulated camera's. Hardware cameras
    /// (`None` here) take theirs from their calibration file ([`CameraConfig::calibration`]).
    pub fn camera(&self) -> Option<Intrinsics> {
        match self {
            CameraConfig::Sim(c) => Some(c.intrinsics()),
            CameraConfig::V4l2(_) | CameraConfig::Aravis(_) | CameraConfig::Ros2(_) => None,
        }
    }

    /// Reads a hardware camera's calibration file (relative to the config at `config_path`)
    /// and checks what can be checked without the device: the pixel format and settings
    /// parse, and a V4L2 stream size equals the calibrated size. `None` for the simulated
    /// camera. Errors name the calibration file (or the config) and the field.
    pub fn calibration(&self, config_path: &Path) -> Result<Option<CameraCalibration>> {
        match self {
            CameraConfig::Sim(_) => Ok(None),
            CameraConfig::Ros2(c) => c.check(config_path).map(|()| None),
            CameraConfig::V4l2(c) => c.calibration(config_path).map(Some),
            CameraConfig::Aravis(c) => c.calibration(config_path).map(Some),
        }
    }
}

/// Reads a hardware camera's calibration file, relative to the config at `config_path`.
fn load_calibration(file: &Path, config_path: &Path) -> Result<CameraCalibration> {
    let dir = config_path.parent().unwrap_or(Path::new("."));
    let file = dir.join(file);
    let intrinsics = load_intrinsics(&file).map_err(|e| intrinsics_error(e, config_path))?;
    Ok(CameraCalibration { intrinsics, file })
}

impl Ros2CameraSettings {
    /// The topic names are legal ROS 2 names and the timeouts are in range.
    pub fn check(&self, config_path: &Path) -> Result<()> {
        for (key, topic) in [
            ("camera.image_topic", &self.image_topic),
            ("camera.camera_info_topic", &self.camera_info_topic),
        ] {
            crate::config::ros2::check_topic(topic)
                .map_err(|m| Error::input(config_path, key, format!("is {m}")))?;
        }
        seconds(
            config_path,
            "camera.connect_timeout_s",
            self.connect_timeout_s,
        )?;
        seconds(config_path, "camera.frame_timeout_s", self.frame_timeout_s)?;
        Ok(())
    }
}

impl V4l2Settings {
    /// The settings parse and the stream size equals the calibration file's.
    fn calibration(&self, config_path: &Path) -> Result<CameraCalibration> {
        self.pixel_format
            .parse::<V4l2PixelFormat>()
            .map_err(|e| Error::input(config_path, "camera.pixel_format", e))?;
        if self.exposure_us == Some(0) {
            return Err(Error::input(
                config_path,
                "camera.exposure_us",
                "0: give a positive exposure in microseconds, or leave it out for the camera's own",
            ));
        }
        seconds(config_path, "camera.frame_timeout_s", self.frame_timeout_s)?;
        let calibration = load_calibration(&self.intrinsics, config_path)?;
        check_frame_size(
            &calibration.intrinsics,
            &calibration.file,
            self.width,
            self.height,
        )
        .map_err(|e| intrinsics_error(e, config_path))?;
        Ok(calibration)
    }
}

impl AravisSettings {
    /// The settings parse; the region is checked against the file when the camera opens.
    fn calibration(&self, config_path: &Path) -> Result<CameraCalibration> {
        self.pixel_format
            .parse::<AravisPixelFormat>()
            .map_err(|e| Error::input(config_path, "camera.pixel_format", e))?;
        if let Some(us) = self.exposure_us.filter(|v| !(v.is_finite() && *v > 0.0)) {
            return Err(Error::input(
                config_path,
                "camera.exposure_us",
                format!("{us}: give a positive exposure in microseconds"),
            ));
        }
        if let Some(db) = self.gain_db.filter(|v| !v.is_finite()) {
            return Err(Error::input(
                config_path,
                "camera.gain_db",
                format!("{db}: give a finite gain in dB"),
            ));
        }
        seconds(config_path, "camera.frame_timeout_s", self.frame_timeout_s)?;
        load_calibration(&self.intrinsics, config_path)
    }
}

/// A calibration-file error as a library error: the file and field at fault, and which
/// config points at the file.
pub(crate) fn intrinsics_error(e: IntrinsicsError, config_path: &Path) -> Error {
    Error::input(
        &e.file,
        e.field,
        format!(
            "{} (the [camera] intrinsics of {})",
            e.message,
            config_path.display()
        ),
    )
}

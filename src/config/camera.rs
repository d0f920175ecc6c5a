//! `[camera]`: which camera backend grabs frames, its intrinsics, and the poses people measure
//! (`LookAt`).

use std::path::{Path, PathBuf};

use easyhec_drivers::aravis::PixelFormat as AravisPixelFormat;
use easyhec_drivers::intrinsics::{check_frame_size, load_intrinsics, IntrinsicsError};
use easyhec_drivers::v4l2::V4l2PixelFormat;
use easyhec_drivers::Intrinsics;
use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

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

/// `[camera]`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
// The simulated camera's scene dressing makes `Sim` large; a config is parsed once per cell,
// and boxing the field would change how every caller reaches `scene`.
#[allow(clippy::large_enum_variant)]
pub enum CameraConfig {
    /// The simulated camera.
    Sim {
        /// Image width.
        width: u32,
        /// Image height.
        height: u32,
        /// Focal length x, pixels.
        fx: f64,
        /// Focal length y, pixels.
        fy: f64,
        /// Principal point x.
        cx: f64,
        /// Principal point y.
        cy: f64,
        /// `plumb_bob` k1 k2 p1 p2 k3.
        #[serde(default)]
        distortion: Option<[f64; 5]>,
        /// The true pose, which only the simulator sees: `camera_from_base`, or for a
        /// camera on a link `camera_from_<link>` (eye and target in that link's frame).
        truth: LookAt,
        /// Scene dressing.
        #[serde(default)]
        scene: SceneSettings,
        /// Where the true joints come from when the arm is not simulated (default: the
        /// simulated arm).
        #[serde(default)]
        joints_from: Option<JointsFrom>,
        /// Where the camera is fixed (default `"fixed"`; `{ link = "…" }` for eye-in-hand).
        #[serde(default)]
        mount: Mount,
    },
    /// A UVC webcam through V4L2. Needs the `v4l2` cargo feature; the variant exists without
    /// it so such a config gets a one-line "rebuild" error.
    V4l2 {
        /// A device path (`/dev/video0`, `/dev/v4l/by-id/…`) or the camera's name as its
        /// driver reports it (a unique part of it is enough).
        device: String,
        /// Stream width, pixels: must equal the calibration file's `image_width`.
        width: u32,
        /// Stream height, pixels: must equal the calibration file's `image_height`.
        height: u32,
        /// `"YUYV"` or `"MJPG"`.
        pixel_format: String,
        /// Fixed exposure, microseconds (default: the camera's own, usually automatic).
        #[serde(default)]
        exposure_us: Option<u32>,
        /// The calibration file: ROS `camera_info` or OpenCV YAML.
        intrinsics: PathBuf,
        /// Limit for one frame, seconds (default 2).
        #[serde(default)]
        frame_timeout_s: Option<f64>,
        /// Where the camera is fixed (default `"fixed"`; `{ link = "…" }` for eye-in-hand).
        #[serde(default)]
        mount: Mount,
    },
    /// A GigE Vision or USB3 Vision camera through Aravis. Needs the `aravis` cargo feature;
    /// the variant exists without it so such a config gets a one-line "rebuild" error.
    Aravis {
        /// Aravis device id (`<vendor>-<model>-<serial>`, `<vendor>-<serial>`, user id, MAC or
        /// IP; default: the first camera found). `"Fake_1"` is Aravis's built-in test camera.
        #[serde(default)]
        device_id: Option<String>,
        /// `"Mono8"`, `"BayerRG8"`, `"BayerGR8"`, `"BayerBG8"`, `"BayerGB8"` or `"RGB8"`.
        pixel_format: String,
        /// Fixed exposure, microseconds (default: the camera's setting).
        #[serde(default)]
        exposure_us: Option<f64>,
        /// Fixed gain, dB (default: the camera's setting).
        #[serde(default)]
        gain_db: Option<f64>,
        /// The calibration file: ROS `camera_info` or OpenCV YAML; its size must be the
        /// camera's region, which is checked when the camera opens.
        intrinsics: PathBuf,
        /// Limit for one frame, seconds (default 2).
        #[serde(default)]
        frame_timeout_s: Option<f64>,
        /// Where the camera is fixed (default `"fixed"`; `{ link = "…" }` for eye-in-hand).
        #[serde(default)]
        mount: Mount,
    },
    /// A ROS 2 camera driver's topics (the `ros2` feature): `sensor_msgs/Image` frames and
    /// the intrinsics of its `sensor_msgs/CameraInfo`, in the `[ros2]` table's domain.
    Ros2 {
        /// `sensor_msgs/Image` topic (default `/camera/color/image_raw`).
        #[serde(default)]
        image_topic: Option<String>,
        /// `sensor_msgs/CameraInfo` topic (default `/camera/color/camera_info`).
        #[serde(default)]
        camera_info_topic: Option<String>,
        /// Longest wait for the first CameraInfo, seconds (default 10).
        #[serde(default)]
        connect_timeout_s: Option<f64>,
        /// Limit for one fresh frame, seconds (default 2).
        #[serde(default)]
        frame_timeout_s: Option<f64>,
        /// Where the camera is fixed (default `"fixed"`; `{ link = "…" }` for eye-in-hand).
        #[serde(default)]
        mount: Mount,
    },
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
        /// Limit for receiving one report, seconds (default 2).
        #[serde(default)]
        timeout_s: Option<f64>,
    },
    /// A UR controller's RTDE port (`actual_q`), mock or real.
    UrRtde {
        /// `host:port` of the RTDE port (30004).
        addr: String,
        /// Limit for connecting and receiving one data package, seconds (default 2).
        #[serde(default)]
        timeout_s: Option<f64>,
    },
    /// A ROS 2 `sensor_msgs/JointState` topic (the `ros2` feature), in the `[ros2]` table's
    /// domain and namespace, with the `[arm]`'s joint names.
    Ros2 {
        /// The topic (default `/joint_states`).
        #[serde(default)]
        topic: Option<String>,
        /// Limit for the first complete message, seconds (default 10).
        #[serde(default)]
        timeout_s: Option<f64>,
    },
}

impl CameraConfig {
    /// Where the camera is fixed.
    pub fn mount(&self) -> &Mount {
        match self {
            CameraConfig::Sim { mount, .. }
            | CameraConfig::V4l2 { mount, .. }
            | CameraConfig::Aravis { mount, .. }
            | CameraConfig::Ros2 { mount, .. } => mount,
        }
    }

    /// The camera model written in the config itself: a simulated camera's. Hardware cameras
    /// (`None` here) take theirs from their calibration file ([`CameraConfig::calibration`]).
    pub fn camera(&self) -> Option<Intrinsics> {
        Some(match self {
            CameraConfig::Sim {
                width,
                height,
                fx,
                fy,
                cx,
                cy,
                distortion,
                ..
            } => Intrinsics {
                width: *width,
                height: *height,
                fx: *fx,
                fy: *fy,
                cx: *cx,
                cy: *cy,
                distortion: *distortion,
            },
            CameraConfig::V4l2 { .. } | CameraConfig::Aravis { .. } | CameraConfig::Ros2 { .. } => {
                return None
            }
        })
    }

    /// Reads a hardware camera's calibration file (relative to the config at `config_path`)
    /// and checks what can be checked without the device: the pixel format and settings
    /// parse, and a V4L2 stream size equals the calibrated size. `None` for the simulated
    /// camera. Errors name the calibration file (or the config) and the field.
    pub fn calibration(&self, config_path: &Path) -> Result<Option<CameraCalibration>> {
        let dir = config_path.parent().unwrap_or(Path::new("."));
        let load = |file: &Path| -> Result<CameraCalibration> {
            let file = dir.join(file);
            let intrinsics =
                load_intrinsics(&file).map_err(|e| intrinsics_error(e, config_path))?;
            Ok(CameraCalibration { intrinsics, file })
        };
        match self {
            CameraConfig::Sim { .. } => Ok(None),
            CameraConfig::Ros2 {
                image_topic,
                camera_info_topic,
                ..
            } => {
                for (key, topic) in [
                    ("camera.image_topic", image_topic),
                    ("camera.camera_info_topic", camera_info_topic),
                ] {
                    if let Some(t) = topic {
                        crate::config::ros2::check_topic(t)
                            .map_err(|m| Error::input(config_path, key, format!("is {m}")))?;
                    }
                }
                Ok(None)
            }
            CameraConfig::V4l2 {
                width,
                height,
                pixel_format,
                exposure_us,
                intrinsics,
                frame_timeout_s,
                ..
            } => {
                pixel_format
                    .parse::<V4l2PixelFormat>()
                    .map_err(|e| Error::input(config_path, "camera.pixel_format", e))?;
                if *exposure_us == Some(0) {
                    return Err(Error::input(
                        config_path,
                        "camera.exposure_us",
                        "0: give a positive exposure in microseconds, or leave it out for the camera's own",
                    ));
                }
                seconds(config_path, "camera.frame_timeout_s", *frame_timeout_s, 2.0)?;
                let calibration = load(intrinsics)?;
                check_frame_size(&calibration.intrinsics, &calibration.file, *width, *height)
                    .map_err(|e| intrinsics_error(e, config_path))?;
                Ok(Some(calibration))
            }
            CameraConfig::Aravis {
                pixel_format,
                exposure_us,
                gain_db,
                intrinsics,
                frame_timeout_s,
                ..
            } => {
                pixel_format
                    .parse::<AravisPixelFormat>()
                    .map_err(|e| Error::input(config_path, "camera.pixel_format", e))?;
                if let Some(us) = exposure_us.filter(|v| !(v.is_finite() && *v > 0.0)) {
                    return Err(Error::input(
                        config_path,
                        "camera.exposure_us",
                        format!("{us}: give a positive exposure in microseconds"),
                    ));
                }
                if let Some(db) = gain_db.filter(|v| !v.is_finite()) {
                    return Err(Error::input(
                        config_path,
                        "camera.gain_db",
                        format!("{db}: give a finite gain in dB"),
                    ));
                }
                seconds(config_path, "camera.frame_timeout_s", *frame_timeout_s, 2.0)?;
                Ok(Some(load(intrinsics)?))
            }
        }
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

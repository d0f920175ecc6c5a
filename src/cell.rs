//! Cell configuration (`config/*.toml`): which arm, camera and segmenter to drive, the robot
//! description, the safety envelope and the calibration settings. Backends are picked by each
//! table's `kind`, so the calibration loop only ever sees `Arc<dyn Arm>` / `Arc<dyn Camera>`.
//!
//! Relative paths in a config are relative to the config file.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use easyhec_drivers::aravis::PixelFormat as AravisPixelFormat;
use easyhec_drivers::dynamixel::{Family, ServoArm, ServoArmConfig, ServoJoint};
use easyhec_drivers::intrinsics::{check_frame_size, load_intrinsics, IntrinsicsError};
use easyhec_drivers::v4l2::V4l2PixelFormat;
use easyhec_drivers::xarm::{Model as XArmModel, XArm, XArmConfig};
use easyhec_drivers::{Arm, Camera as CameraDevice, Intrinsics, JointLimit};
use easyhec_mocks::ur::UrRtdeJoints;
use easyhec_mocks::xarm::XArmReportJoints;
use easyhec_mocks::{Fault, JointSource, SimArm, SimArmConfig, SimCamera};
use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::calibrate::CalibrationSettings;
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::geometry::look_at_camera_from_base;
use crate::robot::{RobotModel, RobotSource};
use crate::safety::{SafetyChecker, SafetyConfig};
use crate::scene::{SceneSettings, SimScene};
use crate::segment::{Segmenter, SegmenterConfig};

/// A whole cell config file.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CellConfig {
    /// The robot description.
    pub robot: RobotConfig,
    /// The arm backend.
    pub arm: ArmConfig,
    /// The camera backend.
    pub camera: CameraConfig,
    /// How frames become masks.
    pub segmenter: SegmenterConfig,
    /// Loop settings.
    #[serde(default)]
    pub calibration: CalibrationSettings,
    /// Safety envelope.
    #[serde(default)]
    pub safety: SafetyConfig,
    /// `easyhec daemon` settings (ignored by the other commands).
    #[serde(default)]
    pub daemon: crate::daemon::DaemonSettings,
}

/// `[robot]`, as in a run's `robot` entry.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RobotConfig {
    /// URDF file.
    pub urdf: PathBuf,
    /// `package://NAME` roots.
    #[serde(default)]
    pub package_dirs: BTreeMap<String, PathBuf>,
    /// Frame `camera_from_base` refers to.
    #[serde(default)]
    pub base_link: Option<String>,
    /// Links not rendered (and not expected in masks).
    #[serde(default)]
    pub ignore_links: Vec<String>,
    /// Actuated joints in the arm's order; default every movable joint in URDF order.
    #[serde(default)]
    pub joints: Option<Vec<String>>,
}

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

/// `[arm]`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum ArmConfig {
    /// The simulated arm.
    Sim {
        /// True joints at start.
        start: Vec<f64>,
        /// Reported joint noise, radians.
        #[serde(default)]
        encoder_noise_rad: f64,
        /// Simulated seconds per wall second (omit for no waiting).
        #[serde(default)]
        speedup: Option<f64>,
        /// Injected faults.
        #[serde(default)]
        faults: Vec<FaultConfig>,
        /// Encoder-noise seed.
        #[serde(default)]
        seed: u64,
    },
    /// A UFACTORY arm (xArm 5/6/7, Lite 6, UF850) on its private TCP protocol: a real
    /// controller, or `easyhec-mock xarm`.
    Xarm {
        /// `host:port` of the command channel (port 502 on a real controller).
        addr: String,
        /// `xarm5`, `xarm6`, `xarm6-sn1305`, `xarm7`, `lite6` or `uf850`: the joint limits
        /// the driver enforces itself.
        model: String,
        /// The driver slows faster moves to this, rad/s (default 1.0, at most π).
        #[serde(default)]
        speed_cap_rad_s: Option<f64>,
        /// Joint acceleration of every move, rad/s² (default 5, at most 20).
        #[serde(default)]
        accel_rad_s2: Option<f64>,
        /// Limit for connecting, seconds (default 3).
        #[serde(default)]
        connect_timeout_s: Option<f64>,
        /// Limit for one request/reply, seconds (default 2).
        #[serde(default)]
        reply_timeout_s: Option<f64>,
        /// Slack beyond 1.5x a move's expected time before it is stopped as timed out,
        /// seconds (default 10).
        #[serde(default)]
        motion_timeout_margin_s: Option<f64>,
    },
    /// A Universal Robots e-Series arm (UR5e limits) through the vendor's `ur_rtde` Python
    /// package: a real controller, or `easyhec-mock ur`. Needs the `ur` cargo feature; the
    /// variant exists without it so such a config gets a one-line "rebuild" error. ur_rtde
    /// always uses ports 30004 (RTDE), 29999 (dashboard) and 30003 (script), so only the
    /// host is configurable.
    Ur {
        /// The controller's address (a host name or IP, no port).
        host: String,
        /// The driver slows faster moves to this, rad/s (default 1.0, at most π).
        #[serde(default)]
        speed_cap_rad_s: Option<f64>,
        /// Joint acceleration of every move, rad/s² (default 1.4, at most 40).
        #[serde(default)]
        accel_rad_s2: Option<f64>,
        /// RTDE frequency, Hz (default 125; e-Series up to 500).
        #[serde(default)]
        frequency_hz: Option<f64>,
        /// Limit for connecting (ur_rtde uploads and starts its control script), seconds
        /// (default 10).
        #[serde(default)]
        connect_timeout_s: Option<f64>,
        /// Limit for one SDK call, seconds (default 2).
        #[serde(default)]
        call_timeout_s: Option<f64>,
        /// Slack beyond 1.5x a move's expected time before it is stopped as stalled,
        /// seconds (default 10).
        #[serde(default)]
        motion_timeout_margin_s: Option<f64>,
    },
    /// ROBOTIS Dynamixel X-series servos on Protocol 2.0 (Koch, WidowX-class arms) on a
    /// serial port.
    Dynamixel(ServoArmToml),
    /// Feetech STS servos (SO-100/101) on a serial port.
    Feetech(ServoArmToml),
    /// An AgileX Piper on SocketCAN. Needs the `socketcan` cargo feature; the variant exists
    /// without it so such a config gets a one-line "rebuild" error.
    Piper {
        /// CAN interface, e.g. `can0` (up at 1 Mbit/s).
        interface: String,
        /// The driver's speed cap, rad/s (default 1.0).
        #[serde(default)]
        speed_cap_rad_s: Option<f64>,
        /// Joint speed at 100 % of the speed byte, rad/s (default π; measure it on the arm).
        #[serde(default)]
        full_speed_rad_s: Option<f64>,
        /// Limit for the drivers to report enabled, seconds (default 5).
        #[serde(default)]
        enable_timeout_s: Option<f64>,
        /// Slack beyond 1.5x a move's expected time before it is stopped as timed out,
        /// seconds (default 10).
        #[serde(default)]
        motion_timeout_margin_s: Option<f64>,
    },
}

/// `[arm] kind = "dynamixel" | "feetech"`: a serial servo bus and its joint table.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ServoArmToml {
    /// Serial device, e.g. `/dev/ttyUSB0`.
    pub port: String,
    /// Baud rate (default: 57 600 for Dynamixel, the factory setting; 1 000 000 for Feetech).
    #[serde(default)]
    pub baud: Option<u32>,
    /// One `[[arm.joints]]` per URDF actuated joint, in the URDF's order.
    pub joints: Vec<ServoJointToml>,
    /// The driver slows faster moves to this, rad/s (default 1.0).
    #[serde(default)]
    pub speed_cap_rad_s: Option<f64>,
    /// Acceleration of the fastest joint, rad/s² (default 4).
    #[serde(default)]
    pub accel_rad_s2: Option<f64>,
    /// Limit for one servo's reply, seconds (default 0.1).
    #[serde(default)]
    pub reply_timeout_s: Option<f64>,
    /// Slack beyond 1.5x a move's expected time before it is stopped as timed out,
    /// seconds (default 5).
    #[serde(default)]
    pub motion_timeout_margin_s: Option<f64>,
}

/// One `[[arm.joints]]` row of a servo arm.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ServoJointToml {
    /// URDF joint name.
    pub name: String,
    /// Servo id on the bus.
    pub id: u8,
    /// Joint angle at the servo's centre tick, radians (default 0).
    #[serde(default)]
    pub offset_rad: f64,
    /// 1, or -1 for a servo mounted reversed (default 1).
    #[serde(default = "plus_one")]
    pub direction: i8,
    /// Encoder ticks per revolution (default 4096).
    #[serde(default)]
    pub ticks_per_rev: Option<u32>,
    /// Lowest angle the driver allows, radians (default: the servo's range).
    #[serde(default)]
    pub lower_rad: Option<f64>,
    /// Highest angle the driver allows, radians (default: the servo's range).
    #[serde(default)]
    pub upper_rad: Option<f64>,
}

fn plus_one() -> i8 {
    1
}

/// A fault for the simulated arm.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum FaultConfig {
    /// Reject move `on_move`.
    Refuse {
        /// 0-based move count.
        on_move: usize,
    },
    /// Fault partway through move `on_move`.
    Error {
        /// 0-based move count.
        on_move: usize,
        /// Fraction of the path covered.
        at_fraction: f64,
    },
    /// Stall partway through move `on_move`.
    Stall {
        /// 0-based move count.
        on_move: usize,
        /// Fraction of the path covered.
        at_fraction: f64,
    },
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
        /// The true pose, which only the simulator sees.
        truth: LookAt,
        /// Scene dressing.
        #[serde(default)]
        scene: SceneSettings,
        /// Where the true joints come from when the arm is not simulated (default: the
        /// simulated arm).
        #[serde(default)]
        joints_from: Option<JointsFrom>,
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
}

impl CameraConfig {
    /// The camera model written in the config itself: a simulated camera's. Hardware cameras
    /// (`None` here) take theirs from their calibration file ([`CameraConfig::calibration`]).
    pub fn camera(&self) -> Option<Camera> {
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
            } => Camera {
                width: *width,
                height: *height,
                fx: *fx,
                fy: *fy,
                cx: *cx,
                cy: *cy,
                distortion: *distortion,
            },
            CameraConfig::V4l2 { .. } | CameraConfig::Aravis { .. } => return None,
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
fn intrinsics_error(e: IntrinsicsError, config_path: &Path) -> Error {
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

/// Handles into the simulated hardware, for tests and the truth report.
#[derive(Clone)]
pub struct SimHandles {
    /// The simulated arm (its command log).
    pub arm: Option<SimArm>,
    /// The simulated camera's true pose when the cell was built.
    pub camera_from_base: Option<Isometry3<f64>>,
    /// The simulated camera's scene: its true pose now, and a way to bump the camera
    /// ([`SimScene::set_camera_from_base`]).
    pub scene: Option<Arc<SimScene>>,
}

/// The camera a config builds, with the simulator's true pose and scene when simulated.
type BuiltCamera = (
    Arc<dyn CameraDevice>,
    Option<Isometry3<f64>>,
    Option<Arc<SimScene>>,
);

/// A built cell.
pub struct Cell {
    /// The parsed config.
    pub config: CellConfig,
    /// Where it was read from.
    pub config_path: PathBuf,
    /// Robot model (rendering, FK).
    pub robot: Arc<RobotModel>,
    /// The arm.
    pub arm: Arc<dyn Arm>,
    /// The camera.
    pub camera: Arc<dyn CameraDevice>,
    /// The segmenter.
    pub segmenter: Box<dyn Segmenter>,
    /// The safety checker.
    pub checker: SafetyChecker,
    /// Simulator handles (absent on real hardware).
    pub sim: SimHandles,
}

/// A duration from an optional config value in seconds (positive and finite).
fn seconds(path: &Path, key: &str, value: Option<f64>, default_s: f64) -> Result<Duration> {
    let v = value.unwrap_or(default_s);
    if v.is_finite() && v > 0.0 {
        Ok(Duration::from_secs_f64(v))
    } else {
        Err(Error::input(
            path,
            key,
            format!("{v} s: use a positive number of seconds"),
        ))
    }
}

/// Reads and parses a cell config, with one-line errors naming the key.
pub fn read_config(path: &Path) -> Result<CellConfig> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| Error::io(path, format!("cannot read cell config: {e}")))?;
    toml::from_str(&text).map_err(|e| {
        let line = e
            .span()
            .map(|s| text[..s.start.min(text.len())].lines().count().max(1))
            .unwrap_or(0);
        Error::input(path, format!("line {line}"), e.message().replace('\n', " "))
    })
}

impl Cell {
    /// Builds every backend named in the config at `path`.
    pub fn open(path: &Path) -> Result<Cell> {
        let config = read_config(path)?;
        Cell::build(config, path)
    }

    /// Builds from an already parsed config (`path` resolves relative paths).
    pub fn build(config: CellConfig, path: &Path) -> Result<Cell> {
        // A bad calibration file fails here, before any hardware is opened.
        let calibration = config.camera.calibration(path)?;
        // So does a bad segmentation model.
        let segmenter = config.segmenter.build(path)?;
        let dir = path.parent().unwrap_or(Path::new("."));
        let r = &config.robot;
        let source = RobotSource {
            urdf: dir.join(&r.urdf),
            package_dirs: r
                .package_dirs
                .iter()
                .map(|(k, v)| (k.clone(), dir.join(v)))
                .collect(),
            base_link: r.base_link.clone(),
            ignore_links: r.ignore_links.clone(),
            joints: r.joints.clone(),
        };
        let robot = Arc::new(RobotModel::load(&source)?);
        let n = robot.actuated.len();
        let urdf_limits = robot.joint_limits();
        let (arm, sim_arm): (Arc<dyn Arm>, Option<SimArm>) = match &config.arm {
            ArmConfig::Sim {
                start,
                encoder_noise_rad,
                speedup,
                faults,
                seed,
            } => {
                if start.len() != n {
                    return Err(Error::input(
                        path,
                        "arm.start",
                        format!("{} values for the {n} actuated joints", start.len()),
                    ));
                }
                let joints: Vec<JointLimit> = robot
                    .joint_names()
                    .iter()
                    .enumerate()
                    .map(|(k, name)| {
                        let v = robot.joints[robot.actuated[k]].velocity;
                        JointLimit {
                            name: name.to_string(),
                            lower: urdf_limits[k].0,
                            upper: urdf_limits[k].1,
                            max_velocity: if v > 0.0 { v } else { 1.0 },
                        }
                    })
                    .collect();
                let faults = faults
                    .iter()
                    .map(|f| match *f {
                        FaultConfig::Refuse { on_move } => Fault::Refuse { on_move },
                        FaultConfig::Error {
                            on_move,
                            at_fraction,
                        } => Fault::ErrorMidMove {
                            on_move,
                            at_fraction,
                        },
                        FaultConfig::Stall {
                            on_move,
                            at_fraction,
                        } => Fault::Stall {
                            on_move,
                            at_fraction,
                        },
                    })
                    .collect();
                let sim = SimArm::new(SimArmConfig {
                    joints,
                    start: start.clone(),
                    encoder_noise_rad: *encoder_noise_rad,
                    speedup: speedup.unwrap_or(f64::INFINITY),
                    faults,
                    seed: *seed,
                });
                (Arc::new(sim.clone()), Some(sim))
            }
            ArmConfig::Xarm {
                addr,
                model,
                speed_cap_rad_s,
                accel_rad_s2,
                connect_timeout_s,
                reply_timeout_s,
                motion_timeout_margin_s,
            } => {
                let model: XArmModel = model
                    .parse()
                    .map_err(|e: String| Error::input(path, "arm.model", e))?;
                if model.axes() != n {
                    return Err(Error::input(
                        path,
                        "arm.model",
                        format!(
                            "an {model} has {} joints; the URDF has {n} actuated joints",
                            model.axes()
                        ),
                    ));
                }
                let mut cfg = XArmConfig::new(addr.clone(), model);
                cfg.joint_names = Some(robot.joint_names().iter().map(|s| s.to_string()).collect());
                if let Some(v) = speed_cap_rad_s {
                    cfg.speed_cap_rad_s = *v;
                }
                if let Some(v) = accel_rad_s2 {
                    cfg.accel_rad_s2 = *v;
                }
                cfg.connect_timeout =
                    seconds(path, "arm.connect_timeout_s", *connect_timeout_s, 3.0)?;
                cfg.reply_timeout = seconds(path, "arm.reply_timeout_s", *reply_timeout_s, 2.0)?;
                cfg.motion_timeout_margin = seconds(
                    path,
                    "arm.motion_timeout_margin_s",
                    *motion_timeout_margin_s,
                    10.0,
                )?;
                let arm = XArm::new(cfg).map_err(|e| Error::input(path, "arm", e.to_string()))?;
                (Arc::new(arm), None)
            }
            ArmConfig::Ur { .. } => (ur_arm(&config.arm, &robot, path)?, None),
            ArmConfig::Dynamixel(t) => (servo_arm(Family::Dynamixel, t, &robot, path)?, None),
            ArmConfig::Feetech(t) => (servo_arm(Family::Feetech, t, &robot, path)?, None),
            ArmConfig::Piper { .. } => (piper_arm(&config.arm, &robot, path)?, None),
        };
        let (camera, truth, sim_scene): BuiltCamera = match &config.camera {
            CameraConfig::Sim {
                truth,
                scene,
                joints_from,
                ..
            } => {
                let source: Arc<dyn JointSource> = match (joints_from, &sim_arm) {
                    (Some(JointsFrom::XarmReport { addr, timeout_s }), _) => {
                        Arc::new(XArmReportJoints {
                            addr: addr.clone(),
                            axes: n,
                            timeout: seconds(path, "camera.joints_from.timeout_s", *timeout_s, 2.0)?,
                        })
                    }
                    (Some(JointsFrom::UrRtde { addr, timeout_s }), _) => Arc::new(UrRtdeJoints {
                        addr: addr.clone(),
                        timeout: seconds(path, "camera.joints_from.timeout_s", *timeout_s, 2.0)?,
                    }),
                    (None, Some(sim_arm)) => Arc::new(sim_arm.clone()),
                    (None, None) => {
                        return Err(Error::input(
                            path,
                            "camera.joints_from",
                            "a simulated camera needs the true joints of the arm it films: set [arm] kind = \"sim\", or joints_from = { kind = \"xarm-report\", addr = \"HOST:30003\" } or { kind = \"ur-rtde\", addr = \"HOST:30004\" }",
                        ))
                    }
                };
                let pose = truth.camera_from_base();
                let model = config.camera.camera().ok_or_else(|| {
                    Error::input(path, "camera", "a simulated camera without its intrinsics")
                })?;
                scene.validate(path, "camera.scene")?;
                let scene = Arc::new(SimScene::new(robot.clone(), model, pose, scene.clone()));
                (
                    Arc::new(SimCamera::watching(source, scene.clone())),
                    Some(pose),
                    Some(scene),
                )
            }
            CameraConfig::V4l2 { .. } => {
                (v4l2_camera(&config.camera, calibration, path)?, None, None)
            }
            CameraConfig::Aravis { .. } => (
                aravis_camera(&config.camera, calibration, path)?,
                None,
                None,
            ),
        };
        let controller: Vec<(f64, f64, f64)> = arm
            .joints()
            .iter()
            .map(|j| (j.lower, j.upper, j.max_velocity))
            .collect();
        let checker = SafetyChecker::new(robot.clone(), &config.safety, &controller, path)?;
        config.calibration.validate(path)?;
        config.daemon.validate(path, n)?;
        Ok(Cell {
            segmenter,
            config,
            config_path: path.to_path_buf(),
            robot,
            arm,
            camera,
            checker,
            sim: SimHandles {
                arm: sim_arm,
                camera_from_base: truth,
                scene: sim_scene,
            },
        })
    }
}

/// The UR arm of an `[arm] kind = "ur"` table.
#[cfg(feature = "ur")]
fn ur_arm(arm: &ArmConfig, robot: &RobotModel, path: &Path) -> Result<Arc<dyn Arm>> {
    use easyhec_drivers::ur::{UrArm, UrConfig};
    let ArmConfig::Ur {
        host,
        speed_cap_rad_s,
        accel_rad_s2,
        frequency_hz,
        connect_timeout_s,
        call_timeout_s,
        motion_timeout_margin_s,
    } = arm
    else {
        unreachable!("called for kind = \"ur\" only")
    };
    let n = robot.actuated.len();
    if n != 6 {
        return Err(Error::input(
            path,
            "robot.urdf",
            format!("a UR arm has 6 joints; the URDF has {n} actuated joints"),
        ));
    }
    if host.contains(':') {
        return Err(Error::input(
            path,
            "arm.host",
            format!(
                "{host:?}: give the address only; ur_rtde always uses ports 30004, 29999 and 30003"
            ),
        ));
    }
    let mut cfg = UrConfig::new(host.clone());
    cfg.joint_names = Some(robot.joint_names().iter().map(|s| s.to_string()).collect());
    if let Some(v) = speed_cap_rad_s {
        cfg.speed_cap_rad_s = *v;
    }
    if let Some(v) = accel_rad_s2 {
        cfg.accel_rad_s2 = *v;
    }
    if let Some(v) = frequency_hz {
        cfg.frequency_hz = *v;
    }
    cfg.connect_timeout = seconds(path, "arm.connect_timeout_s", *connect_timeout_s, 10.0)?;
    cfg.call_timeout = seconds(path, "arm.call_timeout_s", *call_timeout_s, 2.0)?;
    cfg.motion_timeout_margin = seconds(
        path,
        "arm.motion_timeout_margin_s",
        *motion_timeout_margin_s,
        10.0,
    )?;
    let arm = UrArm::new(cfg).map_err(|e| Error::input(path, "arm", e.to_string()))?;
    Ok(Arc::new(arm))
}

/// Without the `ur` feature a UR cell cannot be built: say how to get one.
#[cfg(not(feature = "ur"))]
fn ur_arm(_arm: &ArmConfig, _robot: &RobotModel, path: &Path) -> Result<Arc<dyn Arm>> {
    Err(Error::input(
        path,
        "arm.kind",
        "\"ur\" needs the UR driver, which this build lacks: rebuild with --features ur",
    ))
}

/// The arm of an `[arm] kind = "dynamixel" | "feetech"` table.
fn servo_arm(
    family: Family,
    t: &ServoArmToml,
    robot: &RobotModel,
    path: &Path,
) -> Result<Arc<dyn Arm>> {
    let urdf = robot.joint_names();
    let names: Vec<&str> = t.joints.iter().map(|j| j.name.as_str()).collect();
    if names != urdf {
        return Err(Error::input(
            path,
            "arm.joints",
            format!(
                "joints {names:?}: list one [[arm.joints]] per URDF actuated joint, in order: {urdf:?}"
            ),
        ));
    }
    let joints = t
        .joints
        .iter()
        .map(|j| ServoJoint {
            name: j.name.clone(),
            id: j.id,
            offset_rad: j.offset_rad,
            direction: j.direction,
            ticks_per_rev: j.ticks_per_rev.unwrap_or(4096),
            lower_rad: j.lower_rad,
            upper_rad: j.upper_rad,
        })
        .collect();
    let default_baud = match family {
        Family::Dynamixel => 57_600,
        Family::Feetech => 1_000_000,
    };
    let mut cfg = ServoArmConfig::new(
        family,
        t.port.clone(),
        t.baud.unwrap_or(default_baud),
        joints,
    );
    if let Some(v) = t.speed_cap_rad_s {
        cfg.speed_cap_rad_s = v;
    }
    if let Some(v) = t.accel_rad_s2 {
        cfg.accel_rad_s2 = v;
    }
    cfg.reply_timeout = seconds(path, "arm.reply_timeout_s", t.reply_timeout_s, 0.1)?;
    cfg.motion_timeout_margin = seconds(
        path,
        "arm.motion_timeout_margin_s",
        t.motion_timeout_margin_s,
        5.0,
    )?;
    let arm = ServoArm::new(cfg).map_err(|e| Error::input(path, "arm", e.to_string()))?;
    Ok(Arc::new(arm))
}

/// The arm of an `[arm] kind = "piper"` table.
#[cfg(feature = "socketcan")]
fn piper_arm(arm: &ArmConfig, robot: &RobotModel, path: &Path) -> Result<Arc<dyn Arm>> {
    use easyhec_drivers::piper::{PiperArm, PiperConfig, SocketCan};
    let ArmConfig::Piper {
        interface,
        speed_cap_rad_s,
        full_speed_rad_s,
        enable_timeout_s,
        motion_timeout_margin_s,
    } = arm
    else {
        unreachable!("called for kind = \"piper\" only")
    };
    let names = robot.joint_names();
    if names.len() != 6 {
        return Err(Error::input(
            path,
            "robot.urdf",
            format!(
                "a Piper has 6 joints; the URDF has {} actuated joints",
                names.len()
            ),
        ));
    }
    let mut cfg = PiperConfig {
        joint_names: names.iter().map(|s| s.to_string()).collect(),
        ..PiperConfig::default()
    };
    if let Some(v) = speed_cap_rad_s {
        cfg.speed_cap_rad_s = *v;
    }
    if let Some(v) = full_speed_rad_s {
        cfg.full_speed_rad_s = *v;
    }
    cfg.enable_timeout = seconds(path, "arm.enable_timeout_s", *enable_timeout_s, 5.0)?;
    cfg.motion_timeout_margin = seconds(
        path,
        "arm.motion_timeout_margin_s",
        *motion_timeout_margin_s,
        10.0,
    )?;
    let arm = PiperArm::new(cfg, Arc::new(SocketCan::new(interface)))
        .map_err(|e| Error::input(path, "arm", e.to_string()))?;
    Ok(Arc::new(arm))
}

/// Without the `socketcan` feature a Piper config is an error that says how to get one.
#[cfg(not(feature = "socketcan"))]
fn piper_arm(_: &ArmConfig, _: &RobotModel, path: &Path) -> Result<Arc<dyn Arm>> {
    Err(Error::input(
        path,
        "arm.kind",
        "\"piper\" drives SocketCAN, which this build leaves out: rebuild with --features socketcan",
    ))
}

/// The calibration [`CameraConfig::calibration`] read for a hardware camera kind.
#[cfg(any(feature = "v4l2", feature = "aravis"))]
fn calibration_of(
    calibration: Option<CameraCalibration>,
    path: &Path,
) -> Result<CameraCalibration> {
    calibration.ok_or_else(|| {
        Error::input(
            path,
            "camera.intrinsics",
            "a hardware camera needs its calibration file",
        )
    })
}

/// A driver error while opening a camera: a calibration-size mismatch names the calibration
/// file and field; anything else the config's `[camera]` table.
#[cfg(any(feature = "v4l2", feature = "aravis"))]
fn camera_open_error(e: easyhec_drivers::DriverError, path: &Path) -> Error {
    if let easyhec_drivers::DriverError::Backend(inner) = &e {
        if let Some(ie) = inner.downcast_ref::<IntrinsicsError>() {
            return intrinsics_error(ie.clone(), path);
        }
    }
    Error::input(path, "camera", e.to_string())
}

/// The webcam of a `[camera] kind = "v4l2"` table (opened and streaming).
#[cfg(feature = "v4l2")]
fn v4l2_camera(
    camera: &CameraConfig,
    calibration: Option<CameraCalibration>,
    path: &Path,
) -> Result<Arc<dyn CameraDevice>> {
    use easyhec_drivers::v4l2::{V4l2Camera, V4l2Config};
    let CameraConfig::V4l2 {
        device,
        width,
        height,
        pixel_format,
        exposure_us,
        frame_timeout_s,
        ..
    } = camera
    else {
        unreachable!("called for kind = \"v4l2\" only")
    };
    let calibration = calibration_of(calibration, path)?;
    let format = pixel_format
        .parse()
        .map_err(|e: String| Error::input(path, "camera.pixel_format", e))?;
    let mut cfg = V4l2Config::new(
        device.clone(),
        *width,
        *height,
        format,
        calibration.intrinsics,
        calibration.file,
    );
    cfg.exposure_us = *exposure_us;
    cfg.frame_timeout = seconds(path, "camera.frame_timeout_s", *frame_timeout_s, 2.0)?;
    let camera = V4l2Camera::open(cfg).map_err(|e| camera_open_error(e, path))?;
    Ok(Arc::new(camera))
}

/// Without the `v4l2` feature a webcam config is an error that says how to get one.
#[cfg(not(feature = "v4l2"))]
fn v4l2_camera(
    _: &CameraConfig,
    _: Option<CameraCalibration>,
    path: &Path,
) -> Result<Arc<dyn CameraDevice>> {
    Err(Error::input(
        path,
        "camera.kind",
        "\"v4l2\" needs the V4L2 camera driver, which this build leaves out: rebuild with --features v4l2",
    ))
}

/// The camera of a `[camera] kind = "aravis"` table (opened and streaming).
#[cfg(feature = "aravis")]
fn aravis_camera(
    camera: &CameraConfig,
    calibration: Option<CameraCalibration>,
    path: &Path,
) -> Result<Arc<dyn CameraDevice>> {
    use easyhec_drivers::aravis::{AravisCamera, AravisConfig};
    let CameraConfig::Aravis {
        device_id,
        pixel_format,
        exposure_us,
        gain_db,
        frame_timeout_s,
        ..
    } = camera
    else {
        unreachable!("called for kind = \"aravis\" only")
    };
    let calibration = calibration_of(calibration, path)?;
    let format = pixel_format
        .parse()
        .map_err(|e: String| Error::input(path, "camera.pixel_format", e))?;
    let mut cfg = AravisConfig::new(
        device_id.clone(),
        format,
        calibration.intrinsics,
        calibration.file,
    );
    cfg.exposure_us = *exposure_us;
    cfg.gain_db = *gain_db;
    cfg.frame_timeout = seconds(path, "camera.frame_timeout_s", *frame_timeout_s, 2.0)?;
    let camera = AravisCamera::open(cfg).map_err(|e| camera_open_error(e, path))?;
    Ok(Arc::new(camera))
}

/// Without the `aravis` feature a GenICam camera config is an error that says how to get one.
#[cfg(not(feature = "aravis"))]
fn aravis_camera(
    _: &CameraConfig,
    _: Option<CameraCalibration>,
    path: &Path,
) -> Result<Arc<dyn CameraDevice>> {
    Err(Error::input(
        path,
        "camera.kind",
        "\"aravis\" needs the Aravis (GigE Vision / USB3 Vision) driver, which this build leaves out: rebuild with --features aravis",
    ))
}

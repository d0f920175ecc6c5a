//! `[arm]`: which arm backend drives the robot, and its connection settings.

use serde::{Deserialize, Serialize};

/// `[arm]`: one settings struct per `kind`, each holding the only copy of its defaults. The
/// builder of each kind (in `crate::cell`) takes its own struct, so no builder can be handed
/// another kind's table.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum ArmConfig {
    /// The simulated arm.
    Sim(SimArmSettings),
    /// A UFACTORY arm (xArm 5/6/7, Lite 6, UF850) on its private TCP protocol: a real
    /// controller, or `easyhec-mock xarm`.
    Xarm(XarmSettings),
    /// A Universal Robots e-Series arm (UR5e limits) through the vendor's `ur_rtde` Python
    /// package: a real controller, or `easyhec-mock ur`. Needs the `ur` cargo feature; the
    /// variant exists without it so such a config gets a one-line "rebuild" error.
    Ur(UrSettings),
    /// ROBOTIS Dynamixel X-series servos on Protocol 2.0 (Koch, WidowX-class arms) on a
    /// serial port.
    Dynamixel(ServoArmSettings),
    /// Feetech STS servos (SO-100/101) on a serial port.
    Feetech(ServoArmSettings),
    /// An AgileX Piper on SocketCAN. Needs the `socketcan` cargo feature; the variant exists
    /// without it so such a config gets a one-line "rebuild" error.
    Piper(PiperSettings),
    /// An arm under ros2_control: positions from `/joint_states`, moves through the
    /// joint_trajectory_controller's topic. Needs the `ros2` cargo feature; the domain and
    /// namespace come from the `[ros2]` table (absent: `ROS_DOMAIN_ID`, `/`).
    Ros2(Ros2ArmSettings),
}

/// `[arm] kind = "sim"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SimArmSettings {
    /// True joints at start.
    pub start: Vec<f64>,
    /// Reported joint noise, radians (default 0).
    #[serde(default)]
    pub encoder_noise_rad: f64,
    /// Simulated seconds per wall second (omit for no waiting).
    #[serde(default)]
    pub speedup: Option<f64>,
    /// Injected faults.
    #[serde(default)]
    pub faults: Vec<FaultConfig>,
    /// Encoder-noise seed (default 0).
    #[serde(default)]
    pub seed: u64,
}

/// `[arm] kind = "xarm"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct XarmSettings {
    /// `host:port` of the command channel (port 502 on a real controller).
    pub addr: String,
    /// `xarm5`, `xarm6`, `xarm6-sn1305`, `xarm7`, `lite6` or `uf850`: the joint limits
    /// the driver enforces itself.
    pub model: String,
    /// The driver slows faster moves to this, rad/s (at most π).
    #[serde(default = "one")]
    pub speed_cap_rad_s: f64,
    /// Joint acceleration of every move, rad/s² (at most 20).
    #[serde(default = "XarmSettings::default_accel_rad_s2")]
    pub accel_rad_s2: f64,
    /// Limit for connecting, seconds.
    #[serde(default = "XarmSettings::default_connect_timeout_s")]
    pub connect_timeout_s: f64,
    /// Limit for one request/reply, seconds.
    #[serde(default = "two")]
    pub reply_timeout_s: f64,
    /// Slack beyond 1.5x a move's expected time before it is stopped as timed out, seconds.
    #[serde(default = "ten")]
    pub motion_timeout_margin_s: f64,
}

impl XarmSettings {
    fn default_accel_rad_s2() -> f64 {
        5.0
    }
    fn default_connect_timeout_s() -> f64 {
        3.0
    }
}

/// `[arm] kind = "ur"`. ur_rtde always uses ports 30004 (RTDE), 29999 (dashboard) and 30003
/// (script), so only the host is configurable.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct UrSettings {
    /// The controller's address (a host name or IP, no port).
    pub host: String,
    /// The driver slows faster moves to this, rad/s (at most π).
    #[serde(default = "one")]
    pub speed_cap_rad_s: f64,
    /// Joint acceleration of every move, rad/s² (at most 40).
    #[serde(default = "UrSettings::default_accel_rad_s2")]
    pub accel_rad_s2: f64,
    /// RTDE frequency, Hz (e-Series up to 500).
    #[serde(default = "UrSettings::default_frequency_hz")]
    pub frequency_hz: f64,
    /// Limit for connecting (ur_rtde uploads and starts its control script), seconds.
    #[serde(default = "ten")]
    pub connect_timeout_s: f64,
    /// Limit for one SDK call, seconds.
    #[serde(default = "two")]
    pub call_timeout_s: f64,
    /// Slack beyond 1.5x a move's expected time before it is stopped as stalled, seconds.
    #[serde(default = "ten")]
    pub motion_timeout_margin_s: f64,
}

impl UrSettings {
    fn default_accel_rad_s2() -> f64 {
        1.4
    }
    fn default_frequency_hz() -> f64 {
        125.0
    }
}

/// `[arm] kind = "dynamixel" | "feetech"`: a serial servo bus and its joint table.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ServoArmSettings {
    /// Serial device, e.g. `/dev/ttyUSB0`.
    pub port: String,
    /// Baud rate (default: [`ServoArmSettings::baud_or_factory`]).
    #[serde(default)]
    pub baud: Option<u32>,
    /// One `[[arm.joints]]` per URDF actuated joint, in the URDF's order.
    pub joints: Vec<ServoJointToml>,
    /// The driver slows faster moves to this, rad/s.
    #[serde(default = "one")]
    pub speed_cap_rad_s: f64,
    /// Acceleration of the fastest joint, rad/s².
    #[serde(default = "ServoArmSettings::default_accel_rad_s2")]
    pub accel_rad_s2: f64,
    /// Limit for one servo's reply, seconds.
    #[serde(default = "ServoArmSettings::default_reply_timeout_s")]
    pub reply_timeout_s: f64,
    /// Slack beyond 1.5x a move's expected time before it is stopped as timed out, seconds.
    #[serde(default = "ServoArmSettings::default_motion_timeout_margin_s")]
    pub motion_timeout_margin_s: f64,
}

impl ServoArmSettings {
    fn default_accel_rad_s2() -> f64 {
        4.0
    }
    fn default_reply_timeout_s() -> f64 {
        0.1
    }
    fn default_motion_timeout_margin_s() -> f64 {
        5.0
    }

    /// The baud rate: the one given, else the family's factory setting (57 600 for
    /// Dynamixel, 1 000 000 for Feetech).
    pub fn baud_or_factory(&self, feetech: bool) -> u32 {
        self.baud
            .unwrap_or(if feetech { 1_000_000 } else { 57_600 })
    }
}

/// `[arm] kind = "piper"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PiperSettings {
    /// CAN interface, e.g. `can0` (up at 1 Mbit/s).
    pub interface: String,
    /// The driver's speed cap, rad/s.
    #[serde(default = "one")]
    pub speed_cap_rad_s: f64,
    /// Joint speed at 100 % of the speed byte, rad/s (measure it on the arm).
    #[serde(default = "PiperSettings::default_full_speed_rad_s")]
    pub full_speed_rad_s: f64,
    /// Limit for the drivers to report enabled, seconds.
    #[serde(default = "PiperSettings::default_enable_timeout_s")]
    pub enable_timeout_s: f64,
    /// Slack beyond 1.5x a move's expected time before it is stopped as timed out, seconds.
    #[serde(default = "ten")]
    pub motion_timeout_margin_s: f64,
}

impl PiperSettings {
    fn default_full_speed_rad_s() -> f64 {
        std::f64::consts::PI
    }
    fn default_enable_timeout_s() -> f64 {
        5.0
    }
}

/// `[arm] kind = "ros2"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Ros2ArmSettings {
    /// `sensor_msgs/JointState` topic.
    #[serde(default = "Ros2ArmSettings::default_joint_states_topic")]
    pub joint_states_topic: String,
    /// `trajectory_msgs/JointTrajectory` topic: ros2_control's joint_trajectory_controller
    /// under its usual name unless set.
    #[serde(default = "Ros2ArmSettings::default_command_topic")]
    pub command_topic: String,
    /// The controller's joint names, in the URDF's actuated order (default: the URDF's).
    #[serde(default)]
    pub joint_names: Option<Vec<String>>,
    /// `/joint_states` older than this stops the run, seconds.
    #[serde(default = "Ros2ArmSettings::default_stale_after_s")]
    pub stale_after_s: f64,
    /// Arrival: every joint within this of the target, rad.
    #[serde(default = "Ros2ArmSettings::default_arrival_tolerance_rad")]
    pub arrival_tolerance_rad: f64,
    /// Longest wait for the first complete `/joint_states`, seconds.
    #[serde(default = "ten")]
    pub connect_timeout_s: f64,
    /// Slack beyond a move's trajectory time before it counts as stalled, seconds.
    #[serde(default = "ten")]
    pub motion_timeout_margin_s: f64,
}

/// The `/joint_states` topic when none is named.
pub const JOINT_STATES_TOPIC: &str = "/joint_states";

impl Ros2ArmSettings {
    fn default_joint_states_topic() -> String {
        JOINT_STATES_TOPIC.into()
    }
    fn default_command_topic() -> String {
        "/joint_trajectory_controller/joint_trajectory".into()
    }
    fn default_stale_after_s() -> f64 {
        0.5
    }
    fn default_arrival_tolerance_rad() -> f64 {
        0.002
    }
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
    /// Encoder ticks per revolution.
    #[serde(default = "ServoJointToml::default_ticks_per_rev")]
    pub ticks_per_rev: u32,
    /// Lowest angle the driver allows, radians (default: the servo's range).
    #[serde(default)]
    pub lower_rad: Option<f64>,
    /// Highest angle the driver allows, radians (default: the servo's range).
    #[serde(default)]
    pub upper_rad: Option<f64>,
}

impl ServoJointToml {
    fn default_ticks_per_rev() -> u32 {
        4096
    }
}

fn plus_one() -> i8 {
    1
}

/// Serde defaults that several kinds share (each kind's table in docs/config.md says which).
pub(super) fn one() -> f64 {
    1.0
}

/// As [`one`].
pub(super) fn two() -> f64 {
    2.0
}

/// As [`one`].
pub(super) fn ten() -> f64 {
    10.0
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

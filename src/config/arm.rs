//! `[arm]`: which arm backend drives the robot, and its connection settings.

use serde::{Deserialize, Serialize};

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
    /// An arm under ros2_control: positions from `/joint_states`, moves through the
    /// joint_trajectory_controller's topic. Needs the `ros2` cargo feature; the domain and
    /// namespace come from the `[ros2]` table (absent: `ROS_DOMAIN_ID`, `/`).
    Ros2 {
        /// `sensor_msgs/JointState` topic (default `/joint_states`).
        #[serde(default)]
        joint_states_topic: Option<String>,
        /// `trajectory_msgs/JointTrajectory` topic (default
        /// `/joint_trajectory_controller/joint_trajectory`).
        #[serde(default)]
        command_topic: Option<String>,
        /// The controller's joint names, in the URDF's actuated order (default: the URDF's).
        #[serde(default)]
        joint_names: Option<Vec<String>>,
        /// `/joint_states` older than this stops the run, seconds (default 0.5).
        #[serde(default)]
        stale_after_s: Option<f64>,
        /// Arrival: every joint within this of the target, rad (default 0.002).
        #[serde(default)]
        arrival_tolerance_rad: Option<f64>,
        /// Longest wait for the first complete `/joint_states`, seconds (default 10).
        #[serde(default)]
        connect_timeout_s: Option<f64>,
        /// Slack beyond a move's trajectory time before it counts as stalled, seconds
        /// (default 10).
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

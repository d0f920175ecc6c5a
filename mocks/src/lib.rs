//! Simulated hardware that implements the real [`easyhec_drivers`] traits, so the whole
//! calibration loop runs in CI: a [`SimArm`] that moves at finite speed along the joint-space
//! line the planner assumed, with encoder noise, injectable faults and a log of every command;
//! and a [`SimCamera`] that asks a [`SceneRenderer`] for a frame of the arm's *true* joints.
//!
//! [`xarm::MockXArm`] is a mock UFACTORY controller on loopback that speaks the real wire
//! protocol, for the xArm driver and the vendor SDK; a simulated camera can film it through
//! its report stream ([`xarm::XArmReportJoints`]). [`ur::MockUr`] does the same for a
//! Universal Robots controller (RTDE, dashboard, script port), for `ur_rtde` and the UR driver;
//! cameras film it through RTDE ([`ur::UrRtdeJoints`]). [`servo_bus::MockServoBus`] is a
//! chain of Dynamixel or Feetech servos behind a pseudo-terminal, and [`piper::MockPiper`] an
//! AgileX Piper on a CAN bus, each speaking its real protocol and recording every goal.
//!
//! The renderer is injected rather than owned so this crate stays below the `easyhec` library
//! (which owns robot models and rendering) in the dependency graph.

pub mod piper;
pub mod servo_bus;
mod sim_arm;
mod sim_camera;
pub mod ur;
pub mod xarm;

pub use sim_arm::{CommandRecord, Fault, SimArm, SimArmConfig};
pub use sim_camera::{JointSource, SceneFrame, SceneRenderer, SimCamera};

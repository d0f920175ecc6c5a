//! Simulated hardware that implements the real [`easyhec_drivers`] traits, so the whole
//! calibration loop runs in CI: a [`SimArm`] that moves at finite speed along the joint-space
//! line the planner assumed, with encoder noise, injectable faults and a log of every command;
//! and a [`SimCamera`] that asks a [`SceneRenderer`] for a frame of the arm's *true* joints.
//!
//! [`xarm::MockXArm`] is a mock UFACTORY controller on loopback that speaks the real wire
//! protocol, for the xArm driver and the vendor SDK; a simulated camera can film it through
//! its report stream ([`xarm::XArmReportJoints`]).
//!
//! The renderer is injected rather than owned so this crate stays below the `easyhec` library
//! (which owns robot models and rendering) in the dependency graph.

mod sim_arm;
mod sim_camera;
pub mod xarm;

pub use sim_arm::{CommandRecord, Fault, SimArm, SimArmConfig};
pub use sim_camera::{JointSource, SceneFrame, SceneRenderer, SimCamera};

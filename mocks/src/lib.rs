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

mod links;
pub mod piper;
pub mod servo_bus;
mod sim_arm;
mod sim_camera;
pub mod ur;
pub mod xarm;

pub use sim_arm::{CommandRecord, Fault, SimArm, SimArmConfig};
pub use sim_camera::{JointSource, SceneFrame, SceneRenderer, SimCamera};

/// A loopback address 127.x.y.z (x ≥ 100) unlikely to be used by anything else: for mocks that
/// must listen on a vendor's fixed ports (which its SDK cannot be told to change) while other
/// tests, or a mock someone started by hand, hold the same ports on 127.0.0.1.
pub(crate) fn fresh_loopback() -> std::net::IpAddr {
    use std::sync::atomic::{AtomicU32, Ordering};
    static NEXT_ALIAS: AtomicU32 = AtomicU32::new(0);
    let n = NEXT_ALIAS.fetch_add(1, Ordering::Relaxed);
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos());
    let mut h = (std::process::id() as u64) << 32 ^ (n as u64) << 20 ^ nanos as u64;
    h = h.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    let b = h.to_be_bytes();
    std::net::IpAddr::V4(std::net::Ipv4Addr::new(
        127,
        100 + b[0] % 150,
        1 + b[1] % 250,
        1 + b[2] % 250,
    ))
}

//! Hardware roles for easyhec: one object-safe async trait per role ([`Arm`], [`Camera`]),
//! the data they exchange, and the clients for real controllers ([`xarm`]; [`ur`], whose
//! `UrArm` goes through the vendor's `ur_rtde` Python package behind the `ur` feature;
//! [`dynamixel`] for Dynamixel and Feetech serial servo arms; [`piper`] for the AgileX Piper
//! on CAN, with its SocketCAN backend behind the `socketcan` feature), and cameras: [`v4l2`]
//! (UVC webcams, `V4l2Camera` behind the `v4l2` feature) and [`aravis`] (GigE Vision / USB3
//! Vision, `AravisCamera` behind the `aravis` feature), whose frame conversions are always
//! built, with [`intrinsics`] read from ROS or OpenCV calibration files.
//!
//! The calibration loop holds `Arc<dyn Arm>` / `Arc<dyn Camera>` and never knows which backend
//! it drives; a cell config's `kind = "…"` picks the backend. Motions return a [`Motion`]
//! handle so that "accepted" and "finished" are separate events, as on real controllers.

pub mod aravis;
mod arm;
mod camera;
pub mod dynamixel;
mod error;
pub mod intrinsics;
pub mod piper;
#[cfg(feature = "ros2")]
pub mod ros2;
pub mod ur;
pub mod v4l2;
pub mod xarm;

pub use arm::{Arm, ArmStatus, JointLimit, Motion};
pub use camera::{Camera, Frame, Intrinsics, MAX_IMAGE_SIDE};
pub use error::{DriverError, ErrorKind, Result};

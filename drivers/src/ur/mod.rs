//! Universal Robots e-Series arms (UR5e) through the vendor-maintained `ur_rtde` library
//! (SDU Robotics), driven from Rust through its Python package with pyo3: the protocol stays
//! the vendor library's problem, and what this crate adds is the safety envelope (limits,
//! speed and acceleration caps, mode checks), time limits on every call, and the [`crate::Arm`]
//! mapping.
//!
//! Layout: [`model`] (limits, mode codes, ports; always built, the mock controller in
//! `easyhec-mocks` shares it) and, with the `ur` cargo feature, `UrArm` (the
//! [`crate::Arm`]) over a worker thread that owns every Python object.

pub mod model;

#[cfg(feature = "ur")]
mod client;
#[cfg(feature = "ur")]
mod worker;

#[cfg(feature = "ur")]
pub use client::{UrArm, UrConfig, UrError};

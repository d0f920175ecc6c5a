//! Hardware roles for easyhec: one object-safe async trait per role ([`Arm`], [`Camera`]),
//! the data they exchange, and the clients for real controllers ([`xarm`]).
//!
//! The calibration loop holds `Arc<dyn Arm>` / `Arc<dyn Camera>` and never knows which backend
//! it drives; a cell config's `kind = "…"` picks the backend. Motions return a [`Motion`]
//! handle so that "accepted" and "finished" are separate events, as on real controllers.

mod arm;
mod camera;
mod error;
pub mod xarm;

pub use arm::{Arm, ArmStatus, JointLimit, Motion};
pub use camera::{Camera, Frame, Intrinsics};
pub use error::{DriverError, ErrorKind, Result};

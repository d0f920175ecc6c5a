//! AgileX Piper over CAN (docs/protocols.md §4), written from the protocol description.
//!
//! Layout: [`frame`] (the frame codec: ids, enable, mode, joint targets and feedback in
//! 0.001° i32 BE, status 0x2A1, driver-enable bits), [`CanBus`] (the transport trait) with
//! [`InProcessBus`] for tests and `SocketCan` behind the `socketcan` feature, and
//! [`PiperArm`], the [`crate::Arm`] implementation. The codec is public so the mock arm in
//! `easyhec-mocks` speaks the same frames.

mod arm;
mod bus;
pub mod frame;
#[cfg(feature = "socketcan")]
mod socketcan;

pub use arm::{PiperArm, PiperConfig, PIPER_LIMITS_RAD};
pub use bus::{CanBus, InProcessBus, InProcessCan};
pub use frame::CanFrame;
#[cfg(feature = "socketcan")]
pub use socketcan::SocketCan;

/// Failures particular to the Piper backend (inside [`crate::DriverError::Backend`]).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PiperError {
    /// Unusable settings; the message names the field.
    #[error("Piper config: {0}")]
    Config(String),
}

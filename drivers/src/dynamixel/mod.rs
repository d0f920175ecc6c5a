//! Serial-bus servo arms: ROBOTIS Dynamixel (Protocol 2.0, X series) and Feetech STS
//! (SO-100/101), written from docs/protocols.md §3.
//!
//! Layout: [`packet`] (framing of both protocols: headers, Dynamixel byte stuffing and CRC-16,
//! the Feetech checksum, parameter layouts), [`table`] (control tables, value encodings,
//! units, error bits), [`ServoBus`] (blocking transactions on a serial port: ping, read,
//! write, sync read, sync write, reboot) and [`ServoArm`], the [`crate::Arm`] implementation.
//! The two families share everything but the framing and the table; the codec is public so
//! the mock bus in `easyhec-mocks` speaks the same bytes.

mod arm;
mod bus;
pub mod packet;
pub mod table;

pub use arm::{ServoArm, ServoArmConfig, ServoJoint};
pub use bus::{PingReply, ReadReply, ServoBus};
pub use table::Family;

/// Failures particular to the servo backends (inside [`crate::DriverError::Backend`]).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ServoError {
    /// A reply that does not follow the protocol.
    #[error("servo protocol: {0}")]
    Protocol(String),
    /// Unusable settings; the message names the field.
    #[error("servo arm config: {0}")]
    Config(String),
}

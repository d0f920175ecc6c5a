//! UFACTORY xArm 5/6/7, Lite 6 and UF850 over the controller's private TCP protocol
//! (docs/protocols.md §1), written from the protocol description.
//!
//! Layout: [`frame`] (command-port framing, registers, status bits, parameter encodings),
//! [`report`] (push reports of ports 30001/30003), [`codes`] (error, warning and state codes
//! as sentences), [`model`] (axis counts and joint limits), and [`XArm`], the [`crate::Arm`]
//! implementation. The codec is public so the mock controller in `easyhec-mocks` speaks the
//! same bytes; its correctness rests on the documented test vectors (unit tests here) and on
//! the vendor SDK talking to that mock (the conformance test there).

pub mod codes;
pub mod frame;
pub mod model;
pub mod report;

mod client;

pub use client::{XArm, XArmConfig, XArmError, MAX_ACCEL_RAD_S2, MAX_SPEED_RAD_S};
pub use model::Model;
pub use report::{read_report, read_report_from, Report};

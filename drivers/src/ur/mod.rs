//! Universal Robots e-Series arms (UR5e) through the vendor-maintained `ur_rtde` library
//! (SDU Robotics), driven from Rust through its Python package with pyo3: the protocol stays
//! the vendor library's problem, and what this crate adds is the safety envelope (limits,
//! speed and acceleration caps, mode checks), time limits on every call, and the [`crate::Arm`]
//! mapping.
//!
//! Layout: [`model`] (limits, mode codes, ports; always built, the mock controller in
//! `easyhec-mocks` shares it) and, with the `ur` cargo feature, `UrArm` (the
//! [`crate::Arm`]) over a child process that owns every Python object, so that a crash of
//! ur_rtde kills only that process (see [`serve_worker_if_asked`]).

pub mod model;

#[cfg(feature = "ur")]
mod client;
#[cfg(feature = "ur")]
mod proto;
#[cfg(feature = "ur")]
mod serve;
#[cfg(feature = "ur")]
mod worker;

#[cfg(feature = "ur")]
pub use client::{UrArm, UrConfig, UrError};

/// Lets the calling executable serve as the UR driver's `ur_rtde` child process: call it
/// first thing in `main`. When the process was started as the worker (first argument
/// `--easyhec-ur-worker`) it serves requests on stdin/stdout and exits without returning;
/// otherwise it returns at once, and `UrArm` will use this executable as its worker. Without
/// the `ur` feature it does nothing.
pub fn serve_worker_if_asked() {
    #[cfg(feature = "ur")]
    {
        worker::HOST_EXE.store(true, std::sync::atomic::Ordering::Relaxed);
        if std::env::args_os()
            .nth(1)
            .is_some_and(|a| a == proto::WORKER_ARG)
        {
            std::process::exit(i32::from(serve::serve()));
        }
    }
}

/// The main of the `easyhec-ur-worker` executable: serves `UrArm` requests on stdin/stdout
/// until stdin closes.
#[cfg(feature = "ur")]
pub fn serve_worker() -> std::process::ExitCode {
    serve::serve_exit_code()
}

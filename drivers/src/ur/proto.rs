//! The line protocol between the UR driver and its `ur_rtde` child process: one JSON
//! [`Request`] per line on the child's stdin, one JSON [`Reply`] per line on its stdout, in
//! order. Requests mirror what the driver needs from ur_rtde, one SDK step each.

use serde::{Deserialize, Serialize};

use crate::DriverError;

/// Bumped whenever a request or reply changes shape; checked by the [`Request::Hello`]
/// handshake, so a stale worker executable is refused instead of misread.
pub(super) const PROTOCOL: u32 = 1;

/// The argument that makes a host executable serve as the worker (see
/// `ur::serve_worker_if_asked`).
pub(super) const WORKER_ARG: &str = "--easyhec-ur-worker";

/// One request to the child.
#[derive(Debug, Serialize, Deserialize)]
pub(super) enum Request {
    /// Handshake: answers [`PROTOCOL`]; touches no Python.
    Hello,
    /// `isConnected()` of the receive interface; `false` when there is none.
    ReceiveConnected,
    /// (Re)creates `rtde_receive.RTDEReceiveInterface(host, frequency, variables)`.
    ConnectReceive {
        host: String,
        frequency_hz: f64,
        variables: Vec<String>,
    },
    /// `isConnected()` of the control interface; `None` when there is none.
    ControlConnected,
    /// Everything the driver watches, read through both RTDE interfaces.
    ReadState,
    /// Creates `rtde_control.RTDEControlInterface(host, frequency)` (uploads the script).
    ConnectControl { host: String, frequency_hz: f64 },
    /// `isProgramRunning()` of the control interface.
    IsProgramRunning,
    /// `reuploadScript()` of the control interface.
    ReuploadScript,
    /// `moveJ(q, speed, acceleration, asynchronous)`; answers whether it was accepted.
    MoveJ {
        q: Vec<f64>,
        speed: f64,
        accel: f64,
        asynchronous: bool,
    },
    /// `stopJ(deceleration)` if the control interface is connected; answers whether it was
    /// sent.
    StopJ { decel: f64 },
    /// The dashboard's `isInRemoteControl()` (connecting the dashboard if needed).
    IsInRemoteControl { host: String },
    /// The dashboard's `stop` (ends the program, and with it any motion).
    DashboardStop { host: String },
    /// The dashboard's `closeSafetyPopup()` and `unlockProtectiveStop()`.
    ClearFault { host: String },
}

/// One reading of everything the driver watches.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub(super) struct State {
    pub q: Vec<f64>,
    pub qd: Vec<f64>,
    pub robot_mode: i32,
    pub safety_mode: i32,
    pub runtime_state: u32,
    /// Both RTDE interfaces (the control one if it exists) are connected.
    pub connected: bool,
    /// The control script reports an asynchronous operation running.
    pub async_running: bool,
}

/// A [`DriverError`] on the wire.
#[derive(Debug, Serialize, Deserialize)]
pub(super) enum WireError {
    Refused(String),
    MotionFailed(String),
    Connection(String),
    Timeout {
        ms: u64,
    },
    /// The ur_rtde package cannot be used (`UrError::Sdk`).
    Sdk(String),
    /// A malformed request or anything else.
    Other(String),
}

/// The child's answer to one request.
#[derive(Debug, Serialize, Deserialize)]
pub(super) enum Reply {
    Ok(serde_json::Value),
    Err(WireError),
}

impl WireError {
    /// The error as the child puts it on the wire.
    pub fn from_driver(e: DriverError) -> WireError {
        match e {
            DriverError::Refused(s) => WireError::Refused(s),
            DriverError::MotionFailed(s) | DriverError::Stalled(s) => WireError::MotionFailed(s),
            DriverError::Connection(s) => WireError::Connection(s),
            DriverError::Timeout(d) => WireError::Timeout {
                ms: d.as_millis().try_into().unwrap_or(u64::MAX),
            },
            DriverError::Backend(b) => match b.downcast::<super::UrError>() {
                Ok(u) => match *u {
                    super::UrError::Sdk(s) => WireError::Sdk(s),
                    other => WireError::Other(other.to_string()),
                },
                Err(b) => WireError::Other(b.to_string()),
            },
        }
    }

    /// The error as the driver reports it.
    pub fn into_driver(self) -> DriverError {
        match self {
            WireError::Refused(s) => DriverError::Refused(s),
            WireError::MotionFailed(s) => DriverError::MotionFailed(s),
            WireError::Connection(s) => DriverError::Connection(s),
            WireError::Timeout { ms } => DriverError::Timeout(std::time::Duration::from_millis(ms)),
            WireError::Sdk(s) => DriverError::Backend(Box::new(super::UrError::Sdk(s))),
            WireError::Other(s) => DriverError::Connection(format!("ur_rtde worker: {s}")),
        }
    }
}

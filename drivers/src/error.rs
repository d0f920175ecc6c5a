//! Driver errors, classified so that callers (the loop, the HTTP layer) can react to the kind
//! without matching every backend's details.

use std::time::Duration;

/// Result of a driver call.
pub type Result<T, E = DriverError> = std::result::Result<T, E>;

/// What went wrong talking to hardware.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DriverError {
    /// The controller rejected the command before moving (limits, state, protocol error code).
    #[error("command refused: {0}")]
    Refused(String),
    /// The motion started but ended in a fault.
    #[error("motion failed: {0}")]
    MotionFailed(String),
    /// The motion stopped making progress.
    #[error("motion stalled: {0}")]
    Stalled(String),
    /// The device is unreachable or the link dropped.
    #[error("connection: {0}")]
    Connection(String),
    /// No answer in time.
    #[error("no answer within {0:?}")]
    Timeout(Duration),
    /// Backend-specific failure (downcast to the backend's own error type).
    #[error(transparent)]
    Backend(Box<dyn std::error::Error + Send + Sync>),
}

/// Coarse classification of a [`DriverError`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum ErrorKind {
    /// Rejected before motion; the arm is where it was.
    Refused,
    /// The arm may be somewhere between start and target: re-read its joints.
    Motion,
    /// Link or timeout problems.
    Connection,
    /// Anything else.
    Other,
}

impl DriverError {
    /// The error's class.
    pub fn kind(&self) -> ErrorKind {
        match self {
            DriverError::Refused(_) => ErrorKind::Refused,
            DriverError::MotionFailed(_) | DriverError::Stalled(_) => ErrorKind::Motion,
            DriverError::Connection(_) | DriverError::Timeout(_) => ErrorKind::Connection,
            DriverError::Backend(_) => ErrorKind::Other,
        }
    }
}

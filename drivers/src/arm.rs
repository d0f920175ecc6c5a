//! The arm role.

use std::future::Future;
use std::pin::Pin;

use async_trait::async_trait;

use crate::Result;

/// One actuated joint as the controller knows it (radians, rad/s; metres for prismatic).
#[derive(Clone, Debug, PartialEq)]
pub struct JointLimit {
    /// Joint name, matching the URDF.
    pub name: String,
    /// Lowest position the controller accepts.
    pub lower: f64,
    /// Highest position the controller accepts.
    pub upper: f64,
    /// Highest speed the controller accepts.
    pub max_velocity: f64,
}

/// What the arm is doing.
#[derive(Clone, Debug, PartialEq)]
pub enum ArmStatus {
    /// Ready for a command.
    Idle,
    /// Executing a motion.
    Moving,
    /// Halted by `stop` or a protective stop; needs no reset.
    Stopped,
    /// Faulted; the message is the controller's.
    Fault(String),
}

/// Completion of an accepted motion. Dropping it does not stop the arm: call
/// [`Arm::stop`] for that.
#[must_use = "a motion handle must be awaited to know whether the arm arrived"]
pub struct Motion(Pin<Box<dyn Future<Output = Result<()>> + Send>>);

impl Motion {
    /// Wraps the future that resolves when the motion ends.
    pub fn new(done: impl Future<Output = Result<()>> + Send + 'static) -> Motion {
        Motion(Box::pin(done))
    }

    /// Waits for the arm to arrive (or fail).
    pub async fn wait(self) -> Result<()> {
        self.0.await
    }
}

impl std::fmt::Debug for Motion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Motion")
    }
}

/// A position-controlled arm. Implementations move linearly in joint space (every joint
/// starts and ends together), which is the path the safety checker validates.
#[async_trait]
pub trait Arm: Send + Sync {
    /// The actuated joints, in the order of every joint vector.
    fn joints(&self) -> &[JointLimit];

    /// Current joint positions as the encoders report them.
    async fn read_joints(&self) -> Result<Vec<f64>>;

    /// Starts a joint-space move to `target`, the fastest joint at `speed_rad_s`. Returns
    /// when the controller accepted the command.
    async fn move_to(&self, target: &[f64], speed_rad_s: f64) -> Result<Motion>;

    /// Stops any motion now.
    async fn stop(&self) -> Result<()>;

    /// Controller state.
    async fn status(&self) -> Result<ArmStatus>;

    /// Clears a fault or protective stop so the arm accepts commands again. Arms that need
    /// an operator at the pendant keep this default.
    async fn clear_fault(&self) -> Result<()> {
        Err(crate::DriverError::Refused(
            "this arm's faults must be cleared at its controller".into(),
        ))
    }
}

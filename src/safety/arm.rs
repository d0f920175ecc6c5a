//! The gated arm: the only way a cell reaches the driver, so every target went through
//! [`SafetyChecker::check_move`](super::SafetyChecker::check_move).

use std::sync::Arc;

use super::{CheckedMove, SafetyChecker};
use crate::error::{Error, Result};

/// An arm that only accepts [`CheckedMove`]s. Before sending one it re-reads the joints and
/// checks the move again from where the arm really is, since the controller moves from
/// there, not from the start the plan assumed. The raw driver stays inside: a cell hands out
/// only this, so no code path can send a target the safety checker has not passed.
#[derive(Clone)]
pub struct SafeArm {
    arm: Arc<dyn easyhec_drivers::Arm>,
    checker: Arc<SafetyChecker>,
    /// Largest difference between the checked start and the arm's reading, radians: beyond
    /// it the arm moved since the plan, and the plan is stale.
    pub start_tolerance_rad: f64,
}

impl SafeArm {
    /// Wraps `arm`, whose every move `checker` passes first.
    pub fn new(arm: Arc<dyn easyhec_drivers::Arm>, checker: Arc<SafetyChecker>) -> SafeArm {
        SafeArm {
            arm,
            checker,
            start_tolerance_rad: 0.01,
        }
    }

    /// The controller's joint limits and speeds.
    pub fn joints(&self) -> &[easyhec_drivers::JointLimit] {
        self.arm.joints()
    }

    /// Reads the joints as the controller reports them.
    pub async fn read_joints(&self) -> Result<Vec<f64>> {
        Ok(self.arm.read_joints().await?)
    }

    /// The controller's state.
    pub async fn status(&self) -> Result<easyhec_drivers::ArmStatus> {
        Ok(self.arm.status().await?)
    }

    /// Stops any motion (always allowed: stopping never needs a check).
    pub async fn stop(&self) -> Result<()> {
        Ok(self.arm.stop().await?)
    }

    /// Clears a fault so the arm accepts moves again.
    pub async fn clear_fault(&self) -> Result<()> {
        Ok(self.arm.clear_fault().await?)
    }

    /// Sends a checked move, checked once more from the arm's current reading.
    pub async fn execute(&self, mv: &CheckedMove) -> Result<easyhec_drivers::Motion> {
        let now = self
            .arm
            .read_joints()
            .await
            .map_err(|e| Error::driver("reading joints before a move", e))?;
        if now.len() != mv.from().len() || now.iter().any(|v| !v.is_finite()) {
            return Err(Error::Hardware(format!(
                "the arm reported joints {now:?}; expected {} finite values; not moving",
                mv.from().len()
            )));
        }
        let drift = now
            .iter()
            .zip(mv.from())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        if drift > self.start_tolerance_rad {
            return Err(Error::Hardware(format!(
                "the arm moved {drift:.4} rad since its path was checked; not moving"
            )));
        }
        let from_here = self
            .checker
            .check_move(&now, mv.to(), mv.speed_rad_s())
            .map_err(|v| {
                Error::Hardware(format!(
                    "from where the arm is now ({drift:.4} rad off the planned start) the move fails its check: {v}; not moving"
                ))
            })?;
        self.arm
            .move_to(from_here.to(), from_here.speed_rad_s())
            .await
            .map_err(|e| Error::driver("arm", e))
    }
}

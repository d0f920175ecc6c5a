//! The gated arm: the only way a cell reaches the driver, so every target went through
//! [`SafetyChecker::check_move`](super::SafetyChecker::check_move).

use std::sync::Arc;

use super::CheckedMove;
use crate::error::{Error, Result};

/// An arm that only accepts [`CheckedMove`]s, re-reading the joints first to make sure the
/// arm is still where the check assumed. The raw driver stays inside: a cell hands out only
/// this, so no code path can send a target the safety checker has not passed.
#[derive(Clone)]
pub struct SafeArm {
    arm: Arc<dyn easyhec_drivers::Arm>,
    /// Largest difference between the checked start and the arm's reading, radians.
    pub start_tolerance_rad: f64,
}

impl SafeArm {
    /// Wraps `arm`.
    pub fn new(arm: Arc<dyn easyhec_drivers::Arm>) -> SafeArm {
        SafeArm {
            arm,
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

    /// Sends a checked move.
    pub async fn execute(&self, mv: &CheckedMove) -> Result<easyhec_drivers::Motion> {
        let now = self
            .arm
            .read_joints()
            .await
            .map_err(|e| Error::driver("reading joints before a move", e))?;
        let drift = now
            .iter()
            .zip(mv.from())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        if now.len() != mv.from().len() || drift > self.start_tolerance_rad {
            return Err(Error::Hardware(format!(
                "the arm moved {drift:.4} rad since its path was checked; not moving"
            )));
        }
        self.arm
            .move_to(mv.to(), mv.speed_rad_s())
            .await
            .map_err(|e| Error::driver("arm", e))
    }
}

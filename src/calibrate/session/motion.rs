//! Moving the arm to a planned pose: the operator's confirmation, the checked move watched
//! to its end, and a failed or refused move (its fault cleared, counted against the failure
//! budget, the round re-planned from where the arm stopped).

use std::time::Instant;

use easyhec_drivers::ArmStatus;

use crate::calibrate::{PlannedPose, Progress, StopReason};
use crate::error::{Error, Result};
use crate::safety::CheckedMove;

use super::{MoveOutcome, Session};

/// Whether a checked move may be sent ([`Session::approve`]).
pub(super) enum Approval {
    /// The operator said no.
    Declined,
    /// The run was cancelled.
    Cancelled,
    /// Send it.
    Approved,
}

impl Session<'_> {
    /// Asks the operator (when configured), then sends the checked move and watches it, the
    /// cancel flag included; a failed move is recorded and, within the failure budget,
    /// retried from wherever the arm stopped.
    pub(super) async fn move_to(
        &mut self,
        pose: &PlannedPose,
        mv: &CheckedMove,
    ) -> Result<MoveOutcome> {
        let n = self.views();
        match self.approve(pose) {
            Approval::Declined => {
                return Ok(MoveOutcome::Stop(StopReason::OperatorDeclined { views: n }))
            }
            Approval::Cancelled => {
                return Ok(MoveOutcome::Stop(StopReason::Cancelled { views: n }))
            }
            Approval::Approved => {}
        }
        self.last_round().next_joints = Some(pose.joints.clone());
        let moved = self
            .send(pose, mv, format!("moving to view {}", n + 1))
            .await;
        if self.opts.cancelled() {
            if moved.is_err() {
                let _ = self.cell.arm.stop().await;
                self.last_round()
                    .events
                    .push("move stopped: calibration cancelled".into());
            }
            return Ok(MoveOutcome::Stop(StopReason::Cancelled { views: n }));
        }
        match moved {
            Ok(()) => Ok(MoveOutcome::Arrived),
            Err(e) => self.after_failed_move(e).await,
        }
    }

    /// The operator's confirmation (when configured), then the cancel flag: the two things
    /// that may still keep a checked move from being sent.
    pub(super) fn approve(&self, pose: &PlannedPose) -> Approval {
        if let Some(confirm) = &self.opts.confirm {
            if !self.pb.suspend(|| confirm(pose)) {
                return Approval::Declined;
            }
        }
        if self.opts.cancelled() {
            return Approval::Cancelled;
        }
        Approval::Approved
    }

    /// Announces an approved move (the `Moving` event, the progress line), sends it and
    /// waits for it ([`Session::execute`]), timing it as motion.
    pub(super) async fn send(
        &mut self,
        pose: &PlannedPose,
        mv: &CheckedMove,
        message: String,
    ) -> Result<()> {
        self.opts.emit(Progress::Moving {
            view: self.views(),
            joints: pose.joints.clone(),
        });
        self.pb.set_message(message);
        let t = Instant::now();
        let moved = self.execute(mv).await;
        self.motion_s += t.elapsed().as_secs_f64();
        moved
    }

    /// Sends a checked move and waits for it, stopping the arm if the run is cancelled.
    pub(super) async fn execute(&self, mv: &CheckedMove) -> Result<()> {
        let motion = self.cell.arm.execute(mv).await?;
        tokio::select! {
            r = motion.wait() => r.map_err(Error::from),
            () = self.opts.wait_cancelled() => {
                // Stop first; the motion future is dropped, the arm halts where it is.
                let _ = self.cell.arm.stop().await;
                Err(Error::Hardware("move stopped: calibration cancelled".into()))
            }
        }
    }

    /// Records a failed move and decides: retry (clearing a fault when allowed) or stop.
    pub(super) async fn after_failed_move(&mut self, e: Error) -> Result<MoveOutcome> {
        self.failures += 1;
        let note = format!("move failed: {e}");
        self.last_round().events.push(note.clone());
        self.rec.write_rounds(&self.rounds)?;
        let _ = self.cell.arm.stop().await;
        let status = self.cell.arm.status().await?;
        let faulted = matches!(status, ArmStatus::Fault(_) | ArmStatus::Stopped);
        if self.failures > self.settings.max_motion_failures {
            return Ok(MoveOutcome::Stop(StopReason::GaveUp {
                failures: self.failures,
                note,
            }));
        }
        if faulted {
            if !self.settings.clear_faults {
                return Ok(MoveOutcome::Stop(StopReason::FaultNotCleared {
                    error: e.to_string(),
                }));
            }
            self.cell.arm.clear_fault().await?;
        }
        Ok(MoveOutcome::Retry)
    }
}

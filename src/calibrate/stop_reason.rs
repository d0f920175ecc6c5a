//! Why a calibration loop stopped. The loop decides on these values (a cancelled or faulted
//! run writes no final re-segmentation, a caller must not report a fault as success); the
//! files and the API keep the sentence each one reads as, unchanged.

use std::fmt;

/// Why the loop, or one camera of a list, stopped asking for views.
#[derive(Clone, Debug, PartialEq)]
pub enum StopReason {
    /// `RunOptions::cancel` was set.
    Cancelled {
        /// Views taken until then.
        views: usize,
    },
    /// `calibration.max_views` reached.
    MaxViews {
        /// The maximum.
        max: usize,
    },
    /// Every camera's 95% centre bound within `calibration.stop_centre_95_mm`.
    Precise {
        /// The widest bound, mm.
        worst_mm: f64,
        /// Whether there are several cameras ("for every camera").
        several: bool,
        /// Views taken.
        views: usize,
        /// The target, mm.
        target_mm: f64,
    },
    /// One camera: the best variance settled and the estimate barely moved.
    VarianceConverged {
        /// Views taken.
        views: usize,
    },
    /// One camera of a list stopped moving.
    CameraConverged {
        /// Views taken.
        views: usize,
        /// Rotation in the last round, degrees.
        moved_deg: f64,
        /// Translation in the last round, mm.
        moved_mm: f64,
    },
    /// Every camera of a list converged.
    EveryCameraConverged {
        /// Views taken.
        views: usize,
    },
    /// Planning found no safe pose showing enough of the robot.
    NoPoseShowsRobot {
        /// Views taken.
        views: usize,
        /// Whether there are several cameras ("every camera" must see it).
        several: bool,
    },
    /// Planning found poses, but none safe and reachable.
    NoReachablePose {
        /// Views taken.
        views: usize,
    },
    /// A dry run planned its sequence.
    DryRun {
        /// Poses planned.
        planned: usize,
    },
    /// The operator said no to a move.
    OperatorDeclined {
        /// Views taken.
        views: usize,
    },
    /// More failed moves than `calibration.max_motion_failures`.
    GaveUp {
        /// Failed moves.
        failures: usize,
        /// The last failure.
        note: String,
    },
    /// The arm faulted and `calibration.clear_faults` is off.
    FaultNotCleared {
        /// The fault.
        error: String,
    },
}

impl StopReason {
    /// Ended by a cancel: the views taken are kept, but nothing more is computed.
    pub fn is_cancel(&self) -> bool {
        matches!(self, StopReason::Cancelled { .. })
    }

    /// Ended by the arm: a caller must not report success.
    pub fn is_fault(&self) -> bool {
        matches!(
            self,
            StopReason::GaveUp { .. } | StopReason::FaultNotCleared { .. }
        )
    }
}

impl fmt::Display for StopReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            StopReason::Cancelled { views } => write!(f, "cancelled after {views} views"),
            StopReason::MaxViews { max } => write!(f, "reached the maximum of {max} views"),
            StopReason::Precise {
                worst_mm,
                several,
                views,
                target_mm,
            } => {
                let which = if *several { " for every camera" } else { "" };
                write!(
                    f,
                    "camera centre within {worst_mm:.2} mm (95%){which} after {views} views, target {target_mm} mm"
                )
            }
            StopReason::VarianceConverged { views } => {
                write!(f, "variance converged after {views} views")
            }
            StopReason::CameraConverged {
                views,
                moved_deg,
                moved_mm,
            } => write!(
                f,
                "converged after {views} views (moved {moved_deg:.4} deg / {moved_mm:.3} mm in the last round)"
            ),
            StopReason::EveryCameraConverged { views } => {
                write!(f, "every camera converged after {views} views")
            }
            StopReason::NoPoseShowsRobot { views, several } => {
                let seen_by = if *several { "every camera" } else { "the camera" };
                write!(
                    f,
                    "no safe pose shows enough of the robot to {seen_by} after {views} views (see the planning events in rounds.json; for a camera on a link, calibration.min_robot_image_fraction)"
                )
            }
            StopReason::NoReachablePose { views } => {
                write!(f, "no safe, reachable pose left after {views} views")
            }
            StopReason::DryRun { planned } => {
                write!(f, "dry run: planned {planned} poses, nothing moved")
            }
            StopReason::OperatorDeclined { views } => {
                write!(f, "operator declined a move after {views} views")
            }
            StopReason::GaveUp { failures, note } => {
                write!(f, "gave up after {failures} failed moves ({note})")
            }
            StopReason::FaultNotCleared { error } => write!(
                f,
                "arm fault, not cleared (calibration.clear_faults = false): {error}"
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_reason_reads_as_the_sentence_the_files_keep() {
        use StopReason::*;
        let cases = [
            (Cancelled { views: 3 }, "cancelled after 3 views"),
            (MaxViews { max: 8 }, "reached the maximum of 8 views"),
            (
                Precise {
                    worst_mm: 1.234,
                    several: true,
                    views: 4,
                    target_mm: 2.0,
                },
                "camera centre within 1.23 mm (95%) for every camera after 4 views, target 2 mm",
            ),
            (
                Precise {
                    worst_mm: 0.5,
                    several: false,
                    views: 3,
                    target_mm: 1.5,
                },
                "camera centre within 0.50 mm (95%) after 3 views, target 1.5 mm",
            ),
            (
                VarianceConverged { views: 6 },
                "variance converged after 6 views",
            ),
            (
                CameraConverged {
                    views: 5,
                    moved_deg: 0.01,
                    moved_mm: 0.2,
                },
                "converged after 5 views (moved 0.0100 deg / 0.200 mm in the last round)",
            ),
            (
                EveryCameraConverged { views: 7 },
                "every camera converged after 7 views",
            ),
            (
                NoPoseShowsRobot {
                    views: 2,
                    several: false,
                },
                "no safe pose shows enough of the robot to the camera after 2 views (see the planning events in rounds.json; for a camera on a link, calibration.min_robot_image_fraction)",
            ),
            (
                NoPoseShowsRobot {
                    views: 2,
                    several: true,
                },
                "no safe pose shows enough of the robot to every camera after 2 views (see the planning events in rounds.json; for a camera on a link, calibration.min_robot_image_fraction)",
            ),
            (
                NoReachablePose { views: 4 },
                "no safe, reachable pose left after 4 views",
            ),
            (
                DryRun { planned: 7 },
                "dry run: planned 7 poses, nothing moved",
            ),
            (
                OperatorDeclined { views: 1 },
                "operator declined a move after 1 views",
            ),
            (
                GaveUp {
                    failures: 4,
                    note: "move failed: stalled".into(),
                },
                "gave up after 4 failed moves (move failed: stalled)",
            ),
            (
                FaultNotCleared {
                    error: "joint 3 overcurrent".into(),
                },
                "arm fault, not cleared (calibration.clear_faults = false): joint 3 overcurrent",
            ),
        ];
        for (reason, text) in cases {
            assert_eq!(reason.to_string(), text);
        }
    }

    #[test]
    fn only_cancels_and_faults_say_so() {
        assert!(StopReason::Cancelled { views: 1 }.is_cancel());
        assert!(!StopReason::MaxViews { max: 5 }.is_cancel());
        assert!(StopReason::FaultNotCleared { error: "x".into() }.is_fault());
        assert!(StopReason::GaveUp {
            failures: 3,
            note: "n".into()
        }
        .is_fault());
        assert!(!StopReason::OperatorDeclined { views: 2 }.is_fault());
    }
}

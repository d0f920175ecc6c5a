//! What every Universal Robots component here agrees on, without the SDK: the UR5e's joint
//! limits, the controller's mode codes (docs/protocols.md §2.2) and the default ports. The mock
//! controller in `easyhec-mocks` uses the same tables, so the driver and the mock cannot drift
//! apart on what "out of limits" or "protective stop" means.

use std::f64::consts::PI;

/// RTDE port; ur_rtde hard-codes it.
pub const RTDE_PORT: u16 = 30004;
/// Dashboard server port.
pub const DASHBOARD_PORT: u16 = 29999;
/// Real-time client port, where ur_rtde uploads its control script.
pub const SCRIPT_PORT: u16 = 30003;

/// UR5e joint names in the controller's order (as in `ur_description`).
pub const UR5E_JOINT_NAMES: [&str; 6] = [
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
];

/// UR5e joint position limits, rad: ±360° everywhere except the elbow (±180°, as in
/// `ur_description`; wider folds the arm into itself).
pub const UR5E_LIMITS: [(f64, f64); 6] = [
    (-2.0 * PI, 2.0 * PI),
    (-2.0 * PI, 2.0 * PI),
    (-PI, PI),
    (-2.0 * PI, 2.0 * PI),
    (-2.0 * PI, 2.0 * PI),
    (-2.0 * PI, 2.0 * PI),
];

/// UR5e maximum joint speed, rad/s (180°/s on every joint).
pub const UR5E_MAX_SPEED_RAD_S: f64 = PI;

/// The largest `moveJ` acceleration ur_rtde accepts, rad/s².
pub const MAX_ACCEL_RAD_S2: f64 = 40.0;

/// `robot_mode` RUNNING: powered, brakes released, ready to move.
pub const ROBOT_MODE_RUNNING: i32 = 7;
/// `safety_mode` NORMAL.
pub const SAFETY_MODE_NORMAL: i32 = 1;
/// `safety_mode` REDUCED: still moves, slower.
pub const SAFETY_MODE_REDUCED: i32 = 2;
/// `safety_mode` PROTECTIVE_STOP.
pub const SAFETY_MODE_PROTECTIVE_STOP: i32 = 3;
/// `runtime_state` PLAYING: a program (ur_rtde's control script) is running.
pub const RUNTIME_PLAYING: u32 = 2;
/// `safety_status_bits` bit set during a protective stop.
pub const SAFETY_BIT_PROTECTIVE_STOP: u32 = 1 << 2;

/// The controller's name for a `robot_mode` value.
pub fn robot_mode_name(mode: i32) -> &'static str {
    match mode {
        -1 => "NO_CONTROLLER",
        0 => "DISCONNECTED",
        1 => "CONFIRM_SAFETY",
        2 => "BOOTING",
        3 => "POWER_OFF",
        4 => "POWER_ON",
        5 => "IDLE",
        6 => "BACKDRIVE",
        7 => "RUNNING",
        8 => "UPDATING_FIRMWARE",
        _ => "UNKNOWN",
    }
}

/// The controller's name for a `safety_mode` value.
pub fn safety_mode_name(mode: i32) -> &'static str {
    match mode {
        1 => "NORMAL",
        2 => "REDUCED",
        3 => "PROTECTIVE_STOP",
        4 => "RECOVERY",
        5 => "SAFEGUARD_STOP",
        6 => "SYSTEM_EMERGENCY_STOP",
        7 => "ROBOT_EMERGENCY_STOP",
        8 => "VIOLATION",
        9 => "FAULT",
        10 => "VALIDATE_JOINT_ID",
        11 => "UNDEFINED",
        12 => "AUTOMATIC_MODE_SAFEGUARD_STOP",
        13 => "SYSTEM_THREE_POSITION_ENABLING_STOP",
        _ => "UNKNOWN",
    }
}

/// The `robot_mode` value of a dashboard `Robotmode: NAME` word.
pub fn robot_mode_from_name(name: &str) -> Option<i32> {
    (-1..=8).find(|m| robot_mode_name(*m) == name)
}

/// What an operator must do about a safety mode that blocks motion, as one sentence.
pub fn safety_mode_advice(mode: i32) -> String {
    let name = safety_mode_name(mode);
    match mode {
        SAFETY_MODE_PROTECTIVE_STOP => format!(
            "controller in {name}: find the cause, then unlock the protective stop (pendant, or clear_faults)"
        ),
        5 | 12 | 13 => format!("controller in {name}: close the safeguard (fence, light curtain, enabling device)"),
        6 | 7 => format!("controller in {name}: release the emergency stop and re-enable the arm at the pendant"),
        _ => format!("controller in safety mode {mode} ({name}): resolve it at the pendant"),
    }
}

/// Whether `q` lies within `limits` (finite, one value per joint).
pub fn within_limits(q: &[f64], limits: &[(f64, f64)]) -> bool {
    q.len() == limits.len()
        && q.iter()
            .zip(limits)
            .all(|(v, (lo, hi))| v.is_finite() && *v >= *lo && *v <= *hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mode_names_round_trip_and_limits_hold() {
        for m in -1..=8 {
            assert_eq!(robot_mode_from_name(robot_mode_name(m)), Some(m));
        }
        assert_eq!(robot_mode_from_name("RUNNING"), Some(ROBOT_MODE_RUNNING));
        assert!(safety_mode_advice(3).contains("unlock"));
        assert!(within_limits(&[0.0; 6], &UR5E_LIMITS));
        assert!(!within_limits(
            &[0.0, 0.0, 3.2, 0.0, 0.0, 0.0],
            &UR5E_LIMITS
        ));
        assert!(!within_limits(
            &[f64::NAN, 0.0, 0.0, 0.0, 0.0, 0.0],
            &UR5E_LIMITS
        ));
        assert!(!within_limits(&[0.0; 5], &UR5E_LIMITS));
    }
}

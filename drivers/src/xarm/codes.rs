//! Controller error, warning and state codes as sentences an operator can act on
//! (docs/protocols.md §1.4, §1.8).

/// What a controller error code means, with the code in the text.
pub fn describe_error(code: u8) -> String {
    let what = match code {
        0 => "no error".to_string(),
        1 => "emergency stop button pressed".to_string(),
        2 => "control box emergency-stop input triggered".to_string(),
        3 => "three-state enabling switch released".to_string(),
        10..=17 => format!("servo fault on joint {}", code - 10),
        18 => "force/torque sensor communication failed".to_string(),
        19 | 28 => "end-effector module communication failed".to_string(),
        21 => "kinematics error".to_string(),
        22 => "self-collision predicted".to_string(),
        23 => "a joint angle exceeds its limit".to_string(),
        24 => "speed exceeds the limit".to_string(),
        25 => "motion planning failed".to_string(),
        31 => "collision detected (abnormal joint current)".to_string(),
        35 => "safety boundary reached".to_string(),
        38 => "abnormal joint angle".to_string(),
        40 => "no inverse-kinematics solution".to_string(),
        _ => "see the UFACTORY controller error table".to_string(),
    };
    format!("controller error C{code}: {what}")
}

/// What a controller warning code means, with the code in the text.
pub fn describe_warning(code: u8) -> String {
    let what = match code {
        0 => "no warning",
        11 => "command queue full",
        12 => "parameter error",
        13 => "unknown instruction",
        14 => "no solution for the command",
        15 => "Modbus command queue full",
        _ => "see the UFACTORY controller warning table",
    };
    format!("controller warning W{code}: {what}")
}

/// The name of a reported state (reg 13, or the low nibble of a report's state byte).
pub fn describe_state(state: u8) -> &'static str {
    match state {
        1 => "in motion",
        2 => "ready",
        3 => "paused",
        4 => "stopped",
        5 => "mode changed or system reset (needs SET_STATE 0)",
        6 => "decelerating stop",
        _ => "unknown state",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_read_as_sentences_with_their_numbers() {
        assert_eq!(
            describe_error(23),
            "controller error C23: a joint angle exceeds its limit"
        );
        assert_eq!(
            describe_error(12),
            "controller error C12: servo fault on joint 2"
        );
        assert!(describe_error(99).contains("C99"));
        assert_eq!(
            describe_warning(12),
            "controller warning W12: parameter error"
        );
        assert_eq!(describe_state(4), "stopped");
    }
}

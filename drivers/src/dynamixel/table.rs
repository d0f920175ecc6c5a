//! The two servo families' control tables, value encodings, units and error bits
//! (docs/protocols.md §3.3, §3.5): everything the arm driver and the mock bus need to agree on.

use std::f64::consts::PI;

use super::packet::Protocol;

/// One register: address and size in bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Field {
    /// Address in the control table.
    pub addr: u16,
    /// Size in bytes (1, 2 or 4).
    pub len: u16,
}

const fn f(addr: u16, len: u16) -> Field {
    Field { addr, len }
}

/// The registers the driver uses, per family.
#[derive(Clone, Copy, Debug)]
pub struct ControlTable {
    /// Model number (read after ping on Feetech, whose ping carries no data).
    pub model_number: Field,
    /// Operating mode (EEPROM: writable only with torque off).
    pub operating_mode: Field,
    /// The operating-mode value of (single-turn) position control.
    pub position_mode: u8,
    /// Torque enable (0/1).
    pub torque_enable: Field,
    /// EEPROM lock (Feetech): 0 while writing EEPROM, 1 otherwise.
    pub lock: Option<Field>,
    /// Hardware error status (Dynamixel; Feetech reports its conditions in every status).
    pub hardware_error: Option<Field>,
    /// Acceleration of the profile (Dynamixel profile acceleration, Feetech acceleration).
    pub profile_acceleration: Field,
    /// Speed of the profile (Dynamixel profile velocity, Feetech goal velocity).
    pub profile_velocity: Field,
    /// Feetech goal time (written 0 so the velocity governs).
    pub goal_time: Option<Field>,
    /// Goal position, ticks.
    pub goal_position: Field,
    /// Present position, ticks.
    pub present_position: Field,
    /// 1 while the servo moves.
    pub moving: Field,
    /// Every EEPROM address is below this one.
    pub ram_start: u16,
    /// Size of the control table.
    pub size: u16,
}

/// A servo family: framing plus control table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Family {
    /// ROBOTIS Dynamixel X series on Protocol 2.0.
    Dynamixel,
    /// Feetech STS3215 and kin (SO-100/101).
    Feetech,
}

const DYNAMIXEL: ControlTable = ControlTable {
    model_number: f(0, 2),
    operating_mode: f(11, 1),
    position_mode: 3,
    torque_enable: f(64, 1),
    lock: None,
    hardware_error: Some(f(70, 1)),
    profile_acceleration: f(108, 4),
    profile_velocity: f(112, 4),
    goal_time: None,
    goal_position: f(116, 4),
    present_position: f(132, 4),
    moving: f(122, 1),
    ram_start: 64,
    size: 147,
};

const FEETECH: ControlTable = ControlTable {
    model_number: f(3, 2),
    operating_mode: f(33, 1),
    position_mode: 0,
    torque_enable: f(40, 1),
    lock: Some(f(55, 1)),
    hardware_error: None,
    profile_acceleration: f(41, 1),
    profile_velocity: f(46, 2),
    goal_time: Some(f(44, 2)),
    goal_position: f(42, 2),
    present_position: f(56, 2),
    moving: f(66, 1),
    ram_start: 40,
    size: 71,
};

impl Family {
    /// The framing this family speaks.
    pub fn protocol(self) -> Protocol {
        match self {
            Family::Dynamixel => Protocol::Dynamixel2,
            Family::Feetech => Protocol::Feetech,
        }
    }

    /// The registers this family keeps where.
    pub fn table(self) -> &'static ControlTable {
        match self {
            Family::Dynamixel => &DYNAMIXEL,
            Family::Feetech => &FEETECH,
        }
    }

    /// Name for messages.
    pub fn name(self) -> &'static str {
        match self {
            Family::Dynamixel => "Dynamixel",
            Family::Feetech => "Feetech",
        }
    }

    /// Encodes a signed value into a register: two's complement LE on Dynamixel,
    /// sign-magnitude LE (sign in the top bit) on Feetech STS.
    pub fn encode(self, field: Field, value: i64) -> Vec<u8> {
        let n = usize::from(field.len);
        let raw: u64 = match self {
            Family::Dynamixel => value as u64,
            Family::Feetech if value < 0 && n >= 2 => value.unsigned_abs() | (1u64 << (8 * n - 1)),
            Family::Feetech => value as u64,
        };
        raw.to_le_bytes()[..n].to_vec()
    }

    /// Decodes a register's bytes (the inverse of [`Family::encode`]).
    pub fn decode(self, field: Field, bytes: &[u8]) -> i64 {
        let n = usize::from(field.len).min(bytes.len());
        let mut b = [0u8; 8];
        b[..n].copy_from_slice(&bytes[..n]);
        let raw = u64::from_le_bytes(b);
        let sign = 1u64 << (8 * n - 1);
        match self {
            Family::Dynamixel if n < 8 && raw & sign != 0 => raw as i64 - (1i64 << (8 * n)),
            Family::Feetech if n >= 2 && raw & sign != 0 => -((raw & !sign) as i64),
            _ => raw as i64,
        }
    }

    /// Radians per second of one profile-velocity unit. Dynamixel: 0.229 rev/min.
    /// Feetech STS: one step per second (STS3215 manual; not in docs/protocols.md, unverified).
    pub fn velocity_unit_rad_s(self, ticks_per_rev: u32) -> f64 {
        match self {
            Family::Dynamixel => 0.229 * 2.0 * PI / 60.0,
            Family::Feetech => 2.0 * PI / f64::from(ticks_per_rev),
        }
    }

    /// Radians per second² of one acceleration unit. Dynamixel: 214.577 rev/min².
    /// Feetech STS: 100 steps/s² (STS3215 manual; not in docs/protocols.md, unverified).
    pub fn accel_unit_rad_s2(self, ticks_per_rev: u32) -> f64 {
        match self {
            Family::Dynamixel => 214.577 * 2.0 * PI / 3600.0,
            Family::Feetech => 100.0 * 2.0 * PI / f64::from(ticks_per_rev),
        }
    }

    /// Largest profile velocity the register holds (0 means "unlimited": never sent).
    pub fn max_velocity_units(self) -> u32 {
        32767
    }

    /// Largest acceleration the register holds (0 means "unlimited": never sent).
    pub fn max_accel_units(self) -> u32 {
        match self {
            Family::Dynamixel => 32767,
            Family::Feetech => 254,
        }
    }

    /// The servo's reply error byte as a sentence, or `None` when it reports nothing.
    /// Dynamixel: bits 0–6 are the instruction's error number (bit 7 is the hardware alert,
    /// decoded from the hardware error register instead); Feetech: hardware condition bits.
    pub fn describe_status_error(self, error: u8) -> Option<String> {
        match self {
            Family::Dynamixel => {
                let text = match error & 0x7F {
                    0 => return None,
                    1 => "result fail",
                    2 => "instruction error",
                    3 => "CRC error",
                    4 => "data range error (value out of the register's range)",
                    5 => "data length error",
                    6 => "data limit error (value beyond the servo's limit)",
                    7 => "access error (read-only address, or an EEPROM write with torque on)",
                    _ => "unknown error number",
                };
                Some(format!("{text} (error {})", error & 0x7F))
            }
            Family::Feetech => (error != 0).then(|| describe_feetech_conditions(error)),
        }
    }

    /// Whether a reply's error byte says the servo has a hardware condition.
    pub fn has_alert(self, error: u8) -> bool {
        match self {
            Family::Dynamixel => error & 0x80 != 0,
            Family::Feetech => error != 0,
        }
    }
}

/// Dynamixel X-series Hardware Error Status (address 70) bits as a sentence. The bit
/// meanings are the X-series e-manual's (docs/protocols.md lists only the address).
pub fn describe_dynamixel_hardware_error(bits: u8) -> String {
    const NAMES: [(u8, &str); 5] = [
        (0x01, "input voltage out of range"),
        (0x04, "overheating"),
        (0x08, "motor encoder failure"),
        (0x10, "electrical shock (circuit failure)"),
        (0x20, "overload (persistent load above the maximum torque)"),
    ];
    join_bits(bits, &NAMES)
}

/// Feetech status error bits (docs/protocols.md §3.5) as a sentence.
pub fn describe_feetech_conditions(bits: u8) -> String {
    const NAMES: [(u8, &str); 5] = [
        (0x01, "input voltage out of range"),
        (0x02, "angle sensor error"),
        (0x04, "overheating"),
        (0x08, "over-current"),
        (0x20, "overload"),
    ];
    join_bits(bits, &NAMES)
}

fn join_bits(bits: u8, names: &[(u8, &str)]) -> String {
    let mut parts: Vec<String> = names
        .iter()
        .filter(|(b, _)| bits & b != 0)
        .map(|(_, n)| n.to_string())
        .collect();
    let known = names.iter().fold(0u8, |a, (b, _)| a | b);
    if bits & !known != 0 {
        parts.push(format!("unknown condition bits {:#04x}", bits & !known));
    }
    if parts.is_empty() {
        parts.push("no condition".into());
    }
    parts.join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn value_encodings() {
        let d = Family::Dynamixel;
        let pos = d.table().goal_position;
        assert_eq!(d.encode(pos, 512), vec![0x00, 0x02, 0x00, 0x00]);
        assert_eq!(d.encode(pos, -2), vec![0xFE, 0xFF, 0xFF, 0xFF]);
        assert_eq!(d.decode(pos, &[0xFE, 0xFF, 0xFF, 0xFF]), -2);
        let s = Family::Feetech;
        let pos = s.table().present_position;
        assert_eq!(s.encode(pos, 2048), vec![0x00, 0x08]);
        // Sign-magnitude: -5 is 0x8005, not 0xFFFB.
        assert_eq!(s.encode(pos, -5), vec![0x05, 0x80]);
        assert_eq!(s.decode(pos, &[0x05, 0x80]), -5);
        assert_eq!(s.decode(s.table().torque_enable, &[1]), 1);
    }

    #[test]
    fn motion_registers_are_one_contiguous_block() {
        // One sync write sets acceleration, speed and goal together on both families.
        for fam in [Family::Dynamixel, Family::Feetech] {
            let t = fam.table();
            let mut fields = vec![t.profile_acceleration, t.profile_velocity, t.goal_position];
            fields.extend(t.goal_time);
            fields.sort_by_key(|f| f.addr);
            for w in fields.windows(2) {
                assert_eq!(w[0].addr + w[0].len, w[1].addr, "{fam:?}");
            }
        }
    }

    #[test]
    fn error_texts() {
        let d = Family::Dynamixel;
        assert_eq!(
            d.describe_status_error(0x80),
            None,
            "alert alone: no instruction error"
        );
        assert!(d
            .describe_status_error(0x07)
            .unwrap()
            .starts_with("access error"));
        assert!(d.has_alert(0x80) && !d.has_alert(0x07));
        assert_eq!(
            describe_dynamixel_hardware_error(0x24),
            "overheating, overload (persistent load above the maximum torque)"
        );
        assert_eq!(
            describe_feetech_conditions(0x0A),
            "angle sensor error, over-current"
        );
        assert!(Family::Feetech.has_alert(0x20));
    }
}

//! Classic CAN frames of the AgileX Piper (docs/protocols.md §4.2–4.4): 11-bit ids, 8 data
//! bytes, every multi-byte field big-endian, joints in 0.001° as i32.

/// CAN ids this crate speaks.
pub mod id {
    /// Arm → host: status (control mode, arm status, motion status, limit/comm bits).
    pub const STATUS: u16 = 0x2A1;
    /// Arm → host: joint feedback J1, J2 (then J3, J4 at +1 and J5, J6 at +2).
    pub const JOINT_FEEDBACK_12: u16 = 0x2A5;
    /// Arm → host: joint feedback J3, J4.
    pub const JOINT_FEEDBACK_34: u16 = 0x2A6;
    /// Arm → host: joint feedback J5, J6.
    pub const JOINT_FEEDBACK_56: u16 = 0x2A7;
    /// Arm → host: low-speed driver feedback of joint 1 (joint n at 0x260 + n).
    pub const DRIVER_STATE_1: u16 = 0x261;
    /// Host → arm: motion control 1 (emergency stop / resume).
    pub const MOTION_CONTROL: u16 = 0x150;
    /// Host → arm: control mode, move mode, speed percentage.
    pub const MODE: u16 = 0x151;
    /// Host → arm: joint targets J1, J2 (then J3, J4 at +1 and J5, J6 at +2).
    pub const JOINT_TARGET_12: u16 = 0x155;
    /// Host → arm: joint targets J3, J4.
    pub const JOINT_TARGET_34: u16 = 0x156;
    /// Host → arm: joint targets J5, J6.
    pub const JOINT_TARGET_56: u16 = 0x157;
    /// Host → arm: enable or disable motors.
    pub const ENABLE: u16 = 0x471;
}

/// A classic CAN 2.0A data frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CanFrame {
    /// 11-bit identifier.
    pub id: u16,
    /// Data length (0–8).
    pub len: u8,
    /// Data; bytes past `len` are zero.
    pub data: [u8; 8],
}

impl CanFrame {
    /// A frame with `data` (at most 8 bytes) under an 11-bit `id`; `None` otherwise.
    pub fn new(id: u16, data: &[u8]) -> Option<CanFrame> {
        if id > 0x7FF || data.len() > 8 {
            return None;
        }
        let mut d = [0u8; 8];
        d[..data.len()].copy_from_slice(data);
        Some(CanFrame {
            id,
            len: data.len() as u8,
            data: d,
        })
    }

    /// An 8-byte frame (every Piper frame); `id` must be 11-bit.
    pub fn full(id: u16, data: [u8; 8]) -> CanFrame {
        debug_assert!(id <= 0x7FF);
        CanFrame { id, len: 8, data }
    }

    /// The data bytes.
    pub fn bytes(&self) -> &[u8] {
        &self.data[..usize::from(self.len)]
    }
}

/// Radians to the wire's 0.001° (None if not finite or beyond i32).
pub fn rad_to_millideg(rad: f64) -> Option<i32> {
    let v = (rad.to_degrees() * 1000.0).round();
    (v.is_finite() && v >= f64::from(i32::MIN) && v <= f64::from(i32::MAX)).then_some(v as i32)
}

/// The wire's 0.001° to radians.
pub fn millideg_to_rad(v: i32) -> f64 {
    (f64::from(v) / 1000.0).to_radians()
}

/// 0x471: enable (or disable) motor `motor` (1–6 a joint; the SDK's `EnableArm` sends 7).
pub fn enable_frame(motor: u8, enable: bool) -> CanFrame {
    CanFrame::full(
        id::ENABLE,
        [motor, if enable { 0x02 } else { 0x01 }, 0, 0, 0, 0, 0, 0],
    )
}

/// 0x150 byte 0: 1 = quick stop, 2 = resume/reset.
pub fn motion_control_frame(emergency: u8) -> CanFrame {
    CanFrame::full(id::MOTION_CONTROL, [emergency, 0, 0, 0, 0, 0, 0, 0])
}

/// Control mode byte of 0x151: commands over CAN.
pub const CONTROL_MODE_CAN: u8 = 0x01;
/// Move mode byte of 0x151: joint-space move.
pub const MOVE_J: u8 = 0x01;

/// 0x151: how the controller takes the following targets.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ModeCommand {
    /// 0x00 standby, 0x01 CAN, …
    pub control_mode: u8,
    /// 0x00 MOVE P, 0x01 MOVE J, …
    pub move_mode: u8,
    /// Speed, 0–100 % of the controller's maximum.
    pub speed_pct: u8,
    /// 0x00 position-velocity, 0xAD MIT.
    pub mit: u8,
}

impl ModeCommand {
    /// CAN command mode, MOVE J, position-velocity, at `speed_pct` %.
    pub fn move_j(speed_pct: u8) -> ModeCommand {
        ModeCommand {
            control_mode: CONTROL_MODE_CAN,
            move_mode: MOVE_J,
            speed_pct,
            mit: 0,
        }
    }

    /// The frame.
    pub fn encode(&self) -> CanFrame {
        CanFrame::full(
            id::MODE,
            [
                self.control_mode,
                self.move_mode,
                self.speed_pct,
                self.mit,
                0,
                0,
                0,
                0,
            ],
        )
    }

    /// Reads a 0x151 frame.
    pub fn decode(f: &CanFrame) -> Option<ModeCommand> {
        (f.id == id::MODE && f.len >= 4).then(|| ModeCommand {
            control_mode: f.data[0],
            move_mode: f.data[1],
            speed_pct: f.data[2],
            mit: f.data[3],
        })
    }
}

fn pair_frame(id: u16, a: i32, b: i32) -> CanFrame {
    let mut d = [0u8; 8];
    d[..4].copy_from_slice(&a.to_be_bytes());
    d[4..].copy_from_slice(&b.to_be_bytes());
    CanFrame::full(id, d)
}

/// 0x155–0x157: the six joint targets in 0.001°.
pub fn joint_target_frames(millideg: &[i32; 6]) -> [CanFrame; 3] {
    [0, 1, 2].map(|k| {
        pair_frame(
            id::JOINT_TARGET_12 + k,
            millideg[2 * k as usize],
            millideg[2 * k as usize + 1],
        )
    })
}

/// 0x2A5–0x2A7: joint feedback frames (what the arm, or our mock, sends).
pub fn joint_feedback_frames(millideg: &[i32; 6]) -> [CanFrame; 3] {
    [0, 1, 2].map(|k| {
        pair_frame(
            id::JOINT_FEEDBACK_12 + k,
            millideg[2 * k as usize],
            millideg[2 * k as usize + 1],
        )
    })
}

/// Reads one joint-pair frame whose first id is `base` (0x155 targets or 0x2A5 feedback):
/// (index of the first joint, its value, the next joint's value), values in 0.001°.
pub fn decode_joint_pair(base: u16, f: &CanFrame) -> Option<(usize, i32, i32)> {
    let k = f.id.checked_sub(base).filter(|k| *k < 3)?;
    if f.len != 8 {
        return None;
    }
    let a = i32::from_be_bytes(f.data[..4].try_into().ok()?);
    let b = i32::from_be_bytes(f.data[4..].try_into().ok()?);
    Some((2 * usize::from(k), a, b))
}

/// 0x2A1, the arm's status.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StatusFrame {
    /// 0 standby, 1 CAN, 2 teach, …
    pub control_mode: u8,
    /// 0 normal; otherwise a fault or a teaching state ([`StatusFrame::fault`]).
    pub arm_status: u8,
    /// MOVE P/J/L/C/M/CPV = 0–5.
    pub mode_feedback: u8,
    /// Teach state.
    pub teach_state: u8,
    /// 0 = target reached, 1 = not yet.
    pub motion_status: u8,
    /// Trajectory point index.
    pub trajectory_index: u8,
    /// Bit n: joint n+1 beyond its angle limit.
    pub over_limit: u8,
    /// Bit n: joint n+1 communication error.
    pub comm_error: u8,
}

impl StatusFrame {
    /// Reads a 0x2A1 frame.
    pub fn decode(f: &CanFrame) -> Option<StatusFrame> {
        (f.id == id::STATUS && f.len == 8).then(|| StatusFrame {
            control_mode: f.data[0],
            arm_status: f.data[1],
            mode_feedback: f.data[2],
            teach_state: f.data[3],
            motion_status: f.data[4],
            trajectory_index: f.data[5],
            over_limit: f.data[6],
            comm_error: f.data[7],
        })
    }

    /// The frame (for the mock).
    pub fn encode(&self) -> CanFrame {
        CanFrame::full(
            id::STATUS,
            [
                self.control_mode,
                self.arm_status,
                self.mode_feedback,
                self.teach_state,
                self.motion_status,
                self.trajectory_index,
                self.over_limit,
                self.comm_error,
            ],
        )
    }

    /// The fault this status reports, as a sentence; `None` when the arm is fine. Teaching
    /// states (0x0B–0x0D) are not faults but still stop us from commanding the arm.
    pub fn fault(&self) -> Option<String> {
        let status = match self.arm_status {
            0 => None,
            1 => Some("emergency stop".to_string()),
            2 => Some("no kinematic solution".into()),
            3 => Some("singularity".into()),
            4 => Some("target exceeds a joint limit".into()),
            5 => Some("joint communication error".into()),
            6 => Some("joint brake not released".into()),
            7 => Some("collision detected".into()),
            8 => Some("over-speed while dragging".into()),
            9 => Some("joint status error".into()),
            0x0A => Some("other error".into()),
            0x0B => Some("teach recording in progress".into()),
            0x0C => Some("teach playback in progress".into()),
            0x0D => Some("teach paused".into()),
            0x0E => Some("main controller over-temperature".into()),
            0x0F => Some("discharge resistor over-temperature".into()),
            other => Some(format!("unknown arm status {other:#04x}")),
        };
        let joints = |bits: u8| -> String {
            (0..6)
                .filter(|n| bits & (1 << n) != 0)
                .map(|n| format!("J{}", n + 1))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let mut parts: Vec<String> = status
            .map(|s| format!("arm status {:#04x}: {s}", self.arm_status))
            .into_iter()
            .collect();
        if self.over_limit & 0x3F != 0 {
            parts.push(format!("beyond angle limit: {}", joints(self.over_limit)));
        }
        if self.comm_error & 0x3F != 0 {
            parts.push(format!("communication error: {}", joints(self.comm_error)));
        }
        (!parts.is_empty()).then(|| parts.join("; "))
    }
}

/// Low-speed driver feedback (0x261–0x266): bit 6 of byte 5 = driver enabled.
pub fn decode_driver_enabled(f: &CanFrame) -> Option<(usize, bool)> {
    let k = f.id.checked_sub(id::DRIVER_STATE_1).filter(|k| *k < 6)?;
    (f.len == 8).then(|| (usize::from(k), f.data[5] & 0x40 != 0))
}

/// A low-speed driver feedback frame for joint `joint` (0-based; for the mock): 24.0 V,
/// 30 °C, the enabled bit.
pub fn driver_state_frame(joint: usize, enabled: bool) -> CanFrame {
    let mut d = [0u8; 8];
    d[..2].copy_from_slice(&240u16.to_be_bytes());
    d[2..4].copy_from_slice(&30i16.to_be_bytes());
    d[4] = 30;
    d[5] = if enabled { 0x40 } else { 0 };
    CanFrame::full(id::DRIVER_STATE_1 + joint as u16, d)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The frames docs/protocols.md §4.3 verified against piper_sdk's encoder and decoder.
    #[test]
    fn sdk_verified_vectors() {
        let t = joint_target_frames(&[10_000, -20_000, 0, 0, 0, 0]);
        assert_eq!(t[0].id, 0x155);
        assert_eq!(t[0].data, [0x00, 0x00, 0x27, 0x10, 0xFF, 0xFF, 0xB1, 0xE0]);
        assert_eq!((t[1].id, t[2].id), (0x156, 0x157));
        assert_eq!(rad_to_millideg(10f64.to_radians()), Some(10_000));
        assert_eq!(
            rad_to_millideg(1.0),
            Some(57_296),
            "the demo's 57 295.7795 per rad"
        );
        let m = ModeCommand::move_j(50).encode();
        assert_eq!((m.id, m.data), (0x151, [0x01, 0x01, 50, 0, 0, 0, 0, 0]));
        assert_eq!(ModeCommand::decode(&m), Some(ModeCommand::move_j(50)));
        let e = enable_frame(7, true);
        assert_eq!((e.id, e.data), (0x471, [0x07, 0x02, 0, 0, 0, 0, 0, 0]));
        assert_eq!(enable_frame(7, false).data[1], 0x01);
        // 0x2A5 with J1 = 10°, J2 = −20°, decoded as piper_sdk does.
        let fb = CanFrame::full(0x2A5, [0x00, 0x00, 0x27, 0x10, 0xFF, 0xFF, 0xB1, 0xE0]);
        assert_eq!(
            decode_joint_pair(id::JOINT_FEEDBACK_12, &fb),
            Some((0, 10_000, -20_000))
        );
        assert!((millideg_to_rad(-20_000) + 20f64.to_radians()).abs() < 1e-12);
        assert_eq!(joint_feedback_frames(&[1, 2, 3, 4, 5, 6])[2].id, 0x2A7);
        assert_eq!(
            decode_joint_pair(
                id::JOINT_FEEDBACK_12,
                &joint_feedback_frames(&[1, 2, 3, 4, 5, 6])[2]
            ),
            Some((4, 5, 6))
        );
        assert_eq!(
            decode_joint_pair(id::JOINT_FEEDBACK_12, &t[0]),
            None,
            "a target is not feedback"
        );
    }

    #[test]
    fn status_frame_decoding() {
        let f = CanFrame::full(
            0x2A1,
            [0x01, 0x07, 0x01, 0x00, 0x01, 0x00, 0b0000_0100, 0b0010_0001],
        );
        let s = StatusFrame::decode(&f).unwrap();
        assert_eq!((s.control_mode, s.arm_status, s.motion_status), (1, 7, 1));
        assert_eq!(s.encode(), f);
        assert_eq!(
            s.fault().unwrap(),
            "arm status 0x07: collision detected; beyond angle limit: J3; communication error: J1, J6"
        );
        let ok = StatusFrame {
            control_mode: 1,
            ..Default::default()
        };
        assert_eq!(ok.fault(), None);
        assert_eq!(
            decode_driver_enabled(&driver_state_frame(5, true)),
            Some((5, true))
        );
        assert_eq!(
            decode_driver_enabled(&driver_state_frame(0, false)),
            Some((0, false))
        );
        assert_eq!(CanFrame::new(0x800, &[]), None);
        assert_eq!(CanFrame::new(0x1, &[1, 2]).unwrap().bytes(), &[1, 2]);
    }
}

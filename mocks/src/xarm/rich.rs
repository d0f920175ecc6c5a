//! The "rich" report of port 30002 (docs/protocols.md §1.6.3): a complete 145-byte normal frame
//! followed by the arm's identity, motion limits, per-joint diagnostics, GPIO and settings.
//!
//! The first 145 bytes come from the driver's own encoder (`Report::encode`); this module only
//! appends the tail and rewrites the length header, so the fields shared with the normal report
//! cannot drift apart between ports.
//!
//! The layout is the one xarm-python-sdk 1.18.4 reads for `report_type='rich'` (its default):
//! the SDK parses the tail in blocks, each only when the frame is long enough to hold it
//! (252, 284, 288, 312, 314, 417, 433, 481, 482, 494, 495, 574 and 587 bytes). The mock sends
//! all of them, [`RICH_LEN`] bytes, so every field the SDK knows is present. Integers are
//! big-endian and floats f32 little-endian, as in the other reports.

use easyhec_drivers::xarm::frame::f32s_le;
use easyhec_drivers::xarm::report::NORMAL_LEN;

/// Size of the mock's rich frame: the last block SDK 1.18.4 reads ends at byte 587.
pub const RICH_LEN: usize = 587;

/// What the tail says. Everything not here (GPIO, force/torque sensor, world offset, reduced
/// mode and fence switches, collision tool, identification progress, monitor device, counter)
/// is zero: the mock has no such hardware and none of those settings turned on.
#[derive(Clone, Debug, PartialEq)]
pub struct RichFields {
    /// Device type (byte 145).
    pub arm_type: u8,
    /// Axis count (byte 146); the SDK adopts it when it is 5..=7.
    pub axes: u8,
    /// Firmware version text (bytes 151..181, NUL-padded, cut at 30 bytes).
    pub version: String,
    /// TCP jerk (mm/s³), min / max acceleration (mm/s²), min / max speed (mm/s).
    pub tcp_limits: [f32; 5],
    /// Joint jerk (rad/s³), min / max acceleration (rad/s²), min / max speed (rad/s).
    pub joint_limits: [f32; 5],
    /// Rotational jerk and maximum rotational acceleration.
    pub rot_limits: [f32; 2],
    /// Motor temperatures, °C (J1..J7; 0 for slots beyond the arm's axes).
    pub temperatures: [i8; 7],
    /// TCP speed (mm/s) now.
    pub tcp_speed: f32,
    /// Joint speeds (rad/s) now.
    pub joint_speeds: [f32; 7],
    /// Whether collision detection is on (byte 315).
    pub collision_detection: bool,
    /// Joint supply voltages in hundredths of a volt (the SDK divides by 100).
    pub voltages_cv: [u16; 7],
    /// Reduced-mode TCP speed cap (mm/s) and joint speed cap (rad/s).
    pub reduced_max_speeds: [f32; 2],
    /// Reduced-mode joint ranges, (min, max) per joint, rad.
    pub reduced_joint_ranges: [(f32, f32); 7],
}

/// Master and slave ids the SDK reads at bytes 147 and 148 (fixed on every controller).
const MASTER_ID: u8 = 0xAA;
const SLAVE_ID: u8 = 0x55;

/// The rich frame: `normal` (a whole 145-byte normal frame, its header included) with the
/// tail of `f` appended and the header set to the new length.
pub fn encode(mut normal: Vec<u8>, f: &RichFields) -> Vec<u8> {
    assert_eq!(
        normal.len(),
        NORMAL_LEN,
        "a rich frame starts with a normal one"
    );
    let out = &mut normal;
    let zeros = |out: &mut Vec<u8>, n: usize| out.resize(out.len() + n, 0);
    // 145: identity; motor tid / fid unknown, 0.
    out.extend_from_slice(&[f.arm_type, f.axes, MASTER_ID, SLAVE_ID, 0, 0]);
    // 151: version text.
    let mut version = f.version.as_bytes().to_vec();
    version.resize(30, 0);
    out.extend_from_slice(&version);
    // 181: TCP limits, 201: joint limits, 221: rotation limits.
    out.extend(f32s_le(&f.tcp_limits));
    out.extend(f32s_le(&f.joint_limits));
    out.extend(f32s_le(&f.rot_limits));
    // 229: servo (status, error) pairs for J1..J7 and the tool GPIO's pair: no servo faults.
    zeros(out, 16);
    debug_assert_eq!(out.len(), 245);
    // 245: temperatures, i8.
    out.extend(f.temperatures.iter().map(|&t| t as u8));
    // 252: TCP speed and joint speeds.
    out.extend(f32s_le(&[f.tcp_speed]));
    out.extend(f32s_le(&f.joint_speeds));
    // 284: the user counter (u32), 288: world offset (6 x f32), 312: C/T GPIO reset switches,
    // 314: simulation-robot flag (off: the mock plays a real arm).
    zeros(out, 4 + 24 + 2 + 1);
    // 315: collision detection, 316: collision tool type, 317: its 6 parameters.
    out.push(u8::from(f.collision_detection));
    zeros(out, 1 + 24);
    debug_assert_eq!(out.len(), 341);
    // 341: joint voltages (u16 BE), 355: joint currents (f32).
    for v in f.voltages_cv {
        out.extend_from_slice(&v.to_be_bytes());
    }
    zeros(out, 28);
    // 383: control-box GPIO module status, states, analog values and I/O configuration
    // (up to 433), then 433: external and raw force/torque (6 x f32 each), 481:
    // identification progress, 482: TCP orientation as axis-angle (the reported pose is 0),
    // 494: configuration bits, 495: reduced mode off, 496: reduced TCP boundary (6 x i16).
    zeros(out, 50 + 48 + 1 + 12 + 1 + 1 + 12);
    debug_assert_eq!(out.len(), 508);
    // 508: reduced-mode speed caps, 516: reduced-mode joint ranges.
    out.extend(f32s_le(&f.reduced_max_speeds));
    let ranges: Vec<f32> = f
        .reduced_joint_ranges
        .iter()
        .flat_map(|&(lo, hi)| [lo, hi])
        .collect();
    out.extend(f32s_le(&ranges));
    // 572: fence mode, 573: collision rebound, 574: control-box GPIO alarm (u32),
    // 578: switches (F/T sensor off), 579: monitored device type, state, position, speed,
    // current: none.
    zeros(out, 1 + 1 + 4 + 1 + 1 + 1 + 6);
    debug_assert_eq!(out.len(), RICH_LEN);
    out[..4].copy_from_slice(&(RICH_LEN as u32).to_be_bytes());
    normal
}

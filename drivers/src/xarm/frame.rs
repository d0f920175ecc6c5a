//! Frames of the private protocol on the command port (docs/protocols.md §1.2, §1.3).
//!
//! A frame is a Modbus-TCP-like header (transaction id, protocol id, length; all u16
//! big-endian) followed by `length` bytes: the register (command id), then the parameters
//! (requests) or a status byte and data (replies). Parsing is split as in mini-redis:
//! [`RawFrame::check`] says whether a buffer holds a whole frame ([`FrameError::Incomplete`]:
//! read more), [`RawFrame::parse`] cuts it out.

use std::fmt;

/// Header bytes before the register: transaction id, protocol id, length.
pub const HEADER_LEN: usize = 6;

/// Largest length field we accept; real frames are far smaller, so anything above is a
/// desynchronised stream, not a frame to wait for.
pub const MAX_BODY_LEN: usize = 4096;

/// Protocol ids (header bytes 2..4).
pub mod protocol {
    /// Standard Modbus-TCP on the same port (not used by this client).
    pub const MODBUS: u16 = 0;
    /// The SDK's optional heartbeat; controllers and our mock do not answer it.
    pub const HEARTBEAT: u16 = 1;
    /// The private protocol.
    pub const PRIVATE: u16 = 2;
    /// The private protocol with the SDK's keep-alive discipline (answered like 2).
    pub const PRIVATE_KEEPALIVE: u16 = 3;
}

/// Register numbers (command ids) this crate speaks (docs/protocols.md §1.3).
pub mod reg {
    /// Version string (40 bytes ASCII).
    pub const GET_VERSION: u8 = 0x01;
    /// Serial numbers (40 bytes).
    pub const GET_ROBOT_SN: u8 = 0x02;
    /// Reboot/shutdown control (u8).
    pub const SYSTEM_CONTROL: u8 = 0x0A;
    /// Servo enable: u8 axis (8 = all), u8 enable.
    pub const MOTION_EN: u8 = 0x0B;
    /// Set state: 0 ready, 3 pause, 4 stop, 6 decelerated stop.
    pub const SET_STATE: u8 = 0x0C;
    /// Get state (u8, §1.4).
    pub const GET_STATE: u8 = 0x0D;
    /// Number of queued commands (u16 BE).
    pub const GET_CMDNUM: u8 = 0x0E;
    /// Error code and warning code (u8, u8).
    pub const GET_ERROR: u8 = 0x0F;
    /// Clear the error.
    pub const CLEAN_ERR: u8 = 0x10;
    /// Clear the warning.
    pub const CLEAN_WAR: u8 = 0x11;
    /// Brake control.
    pub const SET_BRAKE: u8 = 0x12;
    /// Set mode: u8 mode, then u8 detection flag on firmware ≥ 1.10.
    pub const SET_MODE: u8 = 0x13;
    /// Joint move: 10×f32 LE (J1..J7 rad, speed rad/s, acc rad/s², mvtime).
    pub const MOVE_JOINT: u8 = 0x17;
    /// Joint move with blend radius (radius in place of mvtime).
    pub const MOVE_JOINTB: u8 = 0x18;
    /// TCP pose (6×f32).
    pub const GET_TCP_POSE: u8 = 0x29;
    /// Joint positions (7×f32 rad); with one parameter byte, positions/velocities/efforts.
    pub const GET_JOINT_POS: u8 = 0x2A;
    /// Feedback check.
    pub const FEEDBACK_CHECK: u8 = 0xFD;
    /// Motion feedback type (bitmask).
    pub const SET_FEEDBACK_TYPE: u8 = 0xFE;
    /// Byte 6 of an unsolicited motion feedback frame.
    pub const FEEDBACK: u8 = 0xFF;
}

/// Bits of a reply's status byte.
pub mod status {
    /// The SDK reads this as "result invalid"; the documentation calls it reserved.
    pub const INVALID: u8 = 0x08;
    /// Not ready to move: motion disabled, or state 4/5.
    pub const NOT_READY: u8 = 0x10;
    /// A warning is active.
    pub const WARNING: u8 = 0x20;
    /// An error is active.
    pub const ERROR: u8 = 0x40;
}

/// Why a byte buffer is not a frame.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FrameError {
    /// The buffer ends before the frame does: read more bytes.
    Incomplete,
    /// The bytes cannot be a frame (the stream is out of step).
    Invalid(String),
}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FrameError::Incomplete => f.write_str("incomplete frame"),
            FrameError::Invalid(why) => write!(f, "invalid frame: {why}"),
        }
    }
}

impl std::error::Error for FrameError {}

/// One frame as it travels: header fields plus the body (register and what follows).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RawFrame {
    /// Transaction id; replies echo the request's.
    pub transaction: u16,
    /// Protocol id ([`protocol`]).
    pub protocol: u16,
    /// Everything after the header: register byte first.
    pub body: Vec<u8>,
}

impl RawFrame {
    /// Total size of the frame at the start of `buf`, if it is all there.
    pub fn check(buf: &[u8]) -> Result<usize, FrameError> {
        if buf.len() < HEADER_LEN {
            return Err(FrameError::Incomplete);
        }
        let len = usize::from(u16::from_be_bytes([buf[4], buf[5]]));
        if len == 0 || len > MAX_BODY_LEN {
            return Err(FrameError::Invalid(format!("length field {len}")));
        }
        if buf.len() < HEADER_LEN + len {
            return Err(FrameError::Incomplete);
        }
        Ok(HEADER_LEN + len)
    }

    /// Cuts the frame at the start of `buf`; returns it and the bytes it used.
    pub fn parse(buf: &[u8]) -> Result<(RawFrame, usize), FrameError> {
        let total = RawFrame::check(buf)?;
        Ok((
            RawFrame {
                transaction: u16::from_be_bytes([buf[0], buf[1]]),
                protocol: u16::from_be_bytes([buf[2], buf[3]]),
                body: buf[HEADER_LEN..total].to_vec(),
            },
            total,
        ))
    }

    /// The frame's bytes.
    ///
    /// # Panics
    /// If the body is longer than a u16 length field can say (a programming error).
    pub fn encode(&self) -> Vec<u8> {
        let len = u16::try_from(self.body.len()).expect("frame body fits a u16 length");
        let mut out = Vec::with_capacity(HEADER_LEN + self.body.len());
        out.extend_from_slice(&self.transaction.to_be_bytes());
        out.extend_from_slice(&self.protocol.to_be_bytes());
        out.extend_from_slice(&len.to_be_bytes());
        out.extend_from_slice(&self.body);
        out
    }

    /// The register byte (0 for an empty body, which `check` never lets through).
    pub fn register(&self) -> u8 {
        self.body.first().copied().unwrap_or(0)
    }
}

/// A request's bytes: header, register, parameters.
pub fn encode_request(transaction: u16, protocol: u16, register: u8, params: &[u8]) -> Vec<u8> {
    let mut body = Vec::with_capacity(1 + params.len());
    body.push(register);
    body.extend_from_slice(params);
    RawFrame {
        transaction,
        protocol,
        body,
    }
    .encode()
}

/// A controller reply: the echoed header and register, the status byte and the data.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Reply {
    /// Echo of the request's transaction id.
    pub transaction: u16,
    /// Echo of the request's protocol id.
    pub protocol: u16,
    /// Echo of the request's register.
    pub register: u8,
    /// Status bits ([`status`]).
    pub status: u8,
    /// Returned data.
    pub data: Vec<u8>,
}

impl Reply {
    /// Reads a reply out of a frame (register, status, data).
    pub fn from_frame(frame: RawFrame) -> Result<Reply, FrameError> {
        if frame.body.len() < 2 {
            return Err(FrameError::Invalid(format!(
                "reply to register {:#04x} has no status byte",
                frame.register()
            )));
        }
        Ok(Reply {
            transaction: frame.transaction,
            protocol: frame.protocol,
            register: frame.body[0],
            status: frame.body[1],
            data: frame.body[2..].to_vec(),
        })
    }

    /// The reply's bytes (what a controller sends).
    pub fn encode(&self) -> Vec<u8> {
        let mut body = Vec::with_capacity(2 + self.data.len());
        body.push(self.register);
        body.push(self.status);
        body.extend_from_slice(&self.data);
        RawFrame {
            transaction: self.transaction,
            protocol: self.protocol,
            body,
        }
        .encode()
    }

    /// Status bit 6: an error is active.
    pub fn has_error(&self) -> bool {
        self.status & status::ERROR != 0
    }

    /// Status bit 5: a warning is active.
    pub fn has_warning(&self) -> bool {
        self.status & status::WARNING != 0
    }

    /// Status bit 4: the arm does not accept motion (disabled, or state 4/5).
    pub fn not_ready(&self) -> bool {
        self.status & status::NOT_READY != 0
    }
}

/// f32 values as little-endian bytes (the parameter encoding of angles, speeds, poses).
pub fn f32s_le(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// `n` little-endian f32 values from the start of `bytes`, if there are enough bytes.
pub fn read_f32s_le(bytes: &[u8], n: usize) -> Option<Vec<f32>> {
    if bytes.len() < 4 * n {
        return None;
    }
    Some(
        bytes[..4 * n]
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect(),
    )
}

/// Parameters of a MOVE_JOINT (or MOVE_JOINTB) request.
#[derive(Clone, Debug, PartialEq)]
pub struct MoveJoint {
    /// J1..J7, radians; slots beyond the arm's axes are 0.
    pub joints_rad: [f32; 7],
    /// Speed of the fastest joint, rad/s.
    pub speed_rad_s: f32,
    /// Acceleration, rad/s².
    pub accel_rad_s2: f32,
    /// Move time (MOVE_JOINT, reserved, 0) or blend radius (MOVE_JOINTB).
    pub last: f32,
}

impl MoveJoint {
    /// A move to `joints_rad` (at most 7 values; the rest are sent as 0).
    ///
    /// # Panics
    /// With more than 7 joints (a programming error: no UFACTORY arm has more).
    pub fn new(joints_rad: &[f64], speed_rad_s: f64, accel_rad_s2: f64) -> MoveJoint {
        assert!(
            joints_rad.len() <= 7,
            "xArm controllers drive at most 7 joints"
        );
        let mut j = [0f32; 7];
        for (slot, v) in j.iter_mut().zip(joints_rad) {
            *slot = *v as f32;
        }
        MoveJoint {
            joints_rad: j,
            speed_rad_s: speed_rad_s as f32,
            accel_rad_s2: accel_rad_s2 as f32,
            last: 0.0,
        }
    }

    /// The 40 parameter bytes.
    pub fn encode(&self) -> Vec<u8> {
        let mut v = self.joints_rad.to_vec();
        v.extend([self.speed_rad_s, self.accel_rad_s2, self.last]);
        f32s_le(&v)
    }

    /// Reads the 40 parameter bytes.
    pub fn decode(params: &[u8]) -> Option<MoveJoint> {
        if params.len() != 40 {
            return None;
        }
        let v = read_f32s_le(params, 10)?;
        let mut j = [0f32; 7];
        j.copy_from_slice(&v[..7]);
        Some(MoveJoint {
            joints_rad: j,
            speed_rad_s: v[7],
            accel_rad_s2: v[8],
            last: v[9],
        })
    }
}

/// The GET_VERSION string, parsed the way the vendor SDK reads it:
/// `<axis>,<type>,<robot SN>,<box SN>,v<major>.<minor>.<patch>`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Version {
    /// Number of axes (the SDK reads the first field as the axis count).
    pub axes: u8,
    /// Device type (6 xArm6, 9 Lite 6, 12 UF850, …).
    pub device_type: u8,
    /// Firmware (major, minor, patch).
    pub firmware: (u32, u32, u32),
    /// The whole string, NULs removed.
    pub text: String,
}

impl Version {
    /// Parses the 40 reply bytes (NUL-padded ASCII).
    pub fn parse(data: &[u8]) -> Option<Version> {
        let end = data.iter().position(|&b| b == 0).unwrap_or(data.len());
        let text = std::str::from_utf8(&data[..end]).ok()?.trim().to_string();
        let fields: Vec<&str> = text.split(',').collect();
        if fields.len() < 5 {
            return None;
        }
        let axes = fields[0].trim().parse().ok()?;
        let device_type = fields[1].trim().parse().ok()?;
        let v = fields[4].trim().trim_start_matches(['v', 'V']);
        let mut parts = v.split('.').map(|p| {
            p.chars()
                .take_while(char::is_ascii_digit)
                .collect::<String>()
                .parse::<u32>()
        });
        let firmware = (
            parts.next()?.ok()?,
            parts.next()?.ok()?,
            parts.next()?.ok()?,
        );
        Some(Version {
            axes,
            device_type,
            firmware,
            text,
        })
    }

    /// The 40-byte, NUL-padded reply a controller sends for `text`.
    pub fn encode_text(text: &str) -> Vec<u8> {
        let mut out = text.as_bytes().to_vec();
        out.resize(40, 0);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Parses a hex line as printed in docs/protocols.md (`00 01 0B …`).
    pub(crate) fn hex(s: &str) -> Vec<u8> {
        s.split_whitespace()
            .map(|b| u8::from_str_radix(b, 16).unwrap())
            .collect()
    }

    #[test]
    fn requests_match_the_documented_vectors() {
        let cases: [(u8, Vec<u8>, &str); 5] = [
            (reg::MOTION_EN, vec![8, 1], "00 01 00 02 00 03 0B 08 01"),
            (reg::SET_STATE, vec![0], "00 01 00 02 00 02 0C 00"),
            (reg::GET_STATE, vec![], "00 01 00 02 00 01 0D"),
            (reg::GET_ERROR, vec![], "00 01 00 02 00 01 0F"),
            (reg::SET_MODE, vec![0, 0], "00 01 00 02 00 03 13 00 00"),
        ];
        for (register, params, expect) in cases {
            assert_eq!(
                encode_request(1, protocol::PRIVATE, register, &params),
                hex(expect),
                "register {register:#04x}"
            );
        }
        assert_eq!(
            encode_request(1, protocol::PRIVATE, reg::GET_JOINT_POS, &[]),
            hex("00 01 00 02 00 01 2A")
        );
    }

    #[test]
    fn move_joint_matches_the_documented_vector() {
        let mv = MoveJoint::new(
            &[std::f64::consts::FRAC_PI_3, 0.0, 0.0, 0.0, 0.0, 0.0],
            20f64.to_radians(),
            500f64.to_radians(),
        );
        let bytes = encode_request(1, protocol::PRIVATE, reg::MOVE_JOINT, &mv.encode());
        let expect = hex(
            "00 01 00 02 00 29 17 92 0A 86 3F 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 \
             00 00 00 00 00 00 00 00 C2 B8 B2 3E 58 A0 0B 41 00 00 00 00",
        );
        assert_eq!(bytes, expect);
        let (frame, used) = RawFrame::parse(&bytes).unwrap();
        assert_eq!(used, bytes.len());
        assert_eq!(MoveJoint::decode(&frame.body[1..]).unwrap(), mv);
    }

    #[test]
    fn the_sdks_own_move_frame_decodes_to_its_degrees() {
        // set_servo_angle([10,-20,-30,0,40,0], speed=50) as the SDK sent it (protocol 3).
        let bytes = hex(
            "00 08 00 03 00 29 17 c2 b8 32 3e c2 b8 b2 be 92 0a 06 bf 00 00 00 00 c2 b8 32 3f \
             00 00 00 00 00 00 00 00 f3 66 5f 3f 58 a0 0b 41 00 00 00 00",
        );
        let (frame, _) = RawFrame::parse(&bytes).unwrap();
        assert_eq!(
            (frame.transaction, frame.protocol),
            (8, protocol::PRIVATE_KEEPALIVE)
        );
        assert_eq!(frame.register(), reg::MOVE_JOINT);
        let mv = MoveJoint::decode(&frame.body[1..]).unwrap();
        let deg: Vec<f64> = mv.joints_rad[..6]
            .iter()
            .map(|r| f64::from(*r).to_degrees())
            .collect();
        for (got, want) in deg.iter().zip([10.0, -20.0, -30.0, 0.0, 40.0, 0.0]) {
            assert!((got - want).abs() < 1e-4, "{deg:?}");
        }
        assert!((f64::from(mv.speed_rad_s).to_degrees() - 50.0).abs() < 1e-4);
        assert!((f64::from(mv.accel_rad_s2).to_degrees() - 500.0).abs() < 1e-3);
    }

    #[test]
    fn replies_parse_with_their_status_bits() {
        let cases = [
            ("00 01 00 02 00 02 0B 10", reg::MOTION_EN, 0x10, vec![]),
            ("00 01 00 02 00 02 0C 00", reg::SET_STATE, 0x00, vec![]),
            ("00 01 00 02 00 03 0D 00 02", reg::GET_STATE, 0x00, vec![2]),
            (
                "00 01 00 02 00 04 0F 00 00 00",
                reg::GET_ERROR,
                0,
                vec![0, 0],
            ),
            ("00 01 00 02 00 02 13 00", reg::SET_MODE, 0, vec![]),
            (
                "00 01 00 02 00 04 17 00 00 01",
                reg::MOVE_JOINT,
                0,
                vec![0, 1],
            ),
        ];
        for (line, register, st, data) in cases {
            let bytes = hex(line);
            let (frame, used) = RawFrame::parse(&bytes).unwrap();
            assert_eq!(used, bytes.len());
            let reply = Reply::from_frame(frame).unwrap();
            assert_eq!(
                (reply.transaction, reply.protocol, reply.register),
                (1, 2, register)
            );
            assert_eq!((reply.status, &reply.data), (st, &data), "{line}");
            assert_eq!(reply.encode(), bytes, "re-encodes byte for byte");
        }
        let enable =
            Reply::from_frame(RawFrame::parse(&hex("00 01 00 02 00 02 0B 10")).unwrap().0).unwrap();
        assert!(enable.not_ready() && !enable.has_error() && !enable.has_warning());
        let faulted = Reply {
            status: 0x70,
            ..enable
        };
        assert!(faulted.has_error() && faulted.has_warning() && faulted.not_ready());
    }

    #[test]
    fn joint_reply_vector_reads_pi_over_3() {
        let mut bytes = hex("00 01 00 02 00 1E 2A 00 92 0A 86 3F");
        bytes.extend([0u8; 24]);
        let reply = Reply::from_frame(RawFrame::parse(&bytes).unwrap().0).unwrap();
        let q = read_f32s_le(&reply.data, 7).unwrap();
        assert_eq!(q[0], std::f32::consts::FRAC_PI_3);
        assert!(q[1..].iter().all(|v| *v == 0.0));
    }

    #[test]
    fn framing_waits_for_whole_frames_and_rejects_garbage() {
        let bytes = hex("00 01 00 02 00 03 0D 00 02");
        for cut in 0..bytes.len() {
            assert_eq!(RawFrame::check(&bytes[..cut]), Err(FrameError::Incomplete));
        }
        // Two frames back to back come apart at the length field.
        let mut two = bytes.clone();
        two.extend(hex("00 02 00 03 00 02 0C 00"));
        let (a, used) = RawFrame::parse(&two).unwrap();
        let (b, _) = RawFrame::parse(&two[used..]).unwrap();
        assert_eq!((a.transaction, b.transaction, b.protocol), (1, 2, 3));
        assert!(matches!(
            RawFrame::check(&hex("00 01 00 02 00 00")),
            Err(FrameError::Invalid(_))
        ));
        assert!(matches!(
            RawFrame::check(&hex("00 01 00 02 FF FF")),
            Err(FrameError::Invalid(_))
        ));
        // A reply needs at least register and status.
        let (short, _) = RawFrame::parse(&hex("00 01 00 02 00 01 0D")).unwrap();
        assert!(Reply::from_frame(short).is_err());
    }

    #[test]
    fn version_string_reads_axis_first() {
        let v = Version::parse(&Version::encode_text("6,6,XI1202,AC1302,v1.12.10")).unwrap();
        assert_eq!((v.axes, v.device_type, v.firmware), (6, 6, (1, 12, 10)));
        let lite = Version::parse(&Version::encode_text("6,9,LI1006,AC1302,v2.4.0")).unwrap();
        assert_eq!(
            (lite.axes, lite.device_type, lite.firmware),
            (6, 9, (2, 4, 0))
        );
        assert!(Version::parse(b"garbage\0\0").is_none());
        assert!(Version::parse(&Version::encode_text("6,6,a,b,vX.1.2")).is_none());
    }
}

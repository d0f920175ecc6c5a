//! Push reports from the controller's report ports (docs/protocols.md §1.6): port 30003 "real"
//! (87 bytes, 100 Hz) and port 30001 "normal" (145 bytes, 5 Hz; 133 on old firmware).
//!
//! Every frame starts with its own length as u32 big-endian, the 4 length bytes included.
//! Inside, integers are big-endian and floats f32 little-endian.

use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt};
use tokio::net::TcpStream;

use super::frame::read_f32s_le;
use crate::{DriverError, Result};

/// Size of a "real" (30003) frame without force/torque data.
pub const REAL_LEN: usize = 87;
/// Size of a "normal" (30001) frame on current firmware.
pub const NORMAL_LEN: usize = 145;
/// Size of a "normal" frame on old firmware (no gravity direction).
pub const NORMAL_OLD_LEN: usize = 133;
/// Largest frame we read (the rich report reaches about 600 bytes).
pub const MAX_REPORT_LEN: usize = 2048;

/// The fields of the normal report beyond the real one.
#[derive(Clone, Debug, PartialEq)]
pub struct NormalFields {
    /// Bit i set: brake of joint i+1 released.
    pub brakes: u8,
    /// Bit i set: motor of joint i+1 enabled.
    pub motors_enabled: u8,
    /// Controller error code (0: none).
    pub error_code: u8,
    /// Controller warning code (0: none).
    pub warning_code: u8,
    /// TCP offset x, y, z (mm), roll, pitch, yaw (rad).
    pub tcp_offset: [f32; 6],
    /// Payload mass (kg) and centre of mass x, y, z (mm).
    pub payload: [f32; 4],
    /// Collision sensitivity 0..=5.
    pub collision_sensitivity: u8,
    /// Teach sensitivity 1..=5.
    pub teach_sensitivity: u8,
    /// Gravity direction (absent on old firmware's 133-byte frame).
    pub gravity: Option<[f32; 3]>,
}

/// One report frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Report {
    /// State (low nibble of byte 4, §1.4).
    pub state: u8,
    /// Mode (high nibble of byte 4).
    pub mode: u8,
    /// Queued commands.
    pub cmd_num: u16,
    /// Actual joint angles J1..J7, radians.
    pub joints_rad: [f32; 7],
    /// TCP pose x, y, z (mm), roll, pitch, yaw (rad).
    pub tcp_pose: [f32; 6],
    /// Estimated joint torques.
    pub torques: [f32; 7],
    /// Present in normal (30001) frames.
    pub normal: Option<NormalFields>,
}

/// The frame size announced by a 4-byte header, with the SDK's quirk: an announced 233 is
/// really 245 (old firmware reported the rich frame's size wrongly).
pub fn announced_len(header: [u8; 4]) -> usize {
    match u32::from_be_bytes(header) {
        233 => 245,
        n => n as usize,
    }
}

fn arr<const N: usize>(bytes: &[u8]) -> [f32; N] {
    let mut out = [0f32; N];
    if let Some(v) = read_f32s_le(bytes, N) {
        out.copy_from_slice(&v);
    }
    out
}

impl Report {
    /// Parses one whole frame (length header included), applying the SDK's sanity checks:
    /// the length matches, mode ≤ 11, state ≤ 9, sensitivities ≤ 5.
    pub fn parse(frame: &[u8]) -> std::result::Result<Report, String> {
        if frame.len() < REAL_LEN {
            return Err(format!(
                "report of {} bytes; at least {REAL_LEN} expected",
                frame.len()
            ));
        }
        let announced = announced_len([frame[0], frame[1], frame[2], frame[3]]);
        if announced != frame.len() {
            return Err(format!(
                "report announces {announced} bytes but has {}",
                frame.len()
            ));
        }
        let state = frame[4] & 0x0F;
        let mode = frame[4] >> 4;
        if mode > 11 || state > 9 {
            return Err(format!("report has mode {mode}, state {state}"));
        }
        let normal = if frame.len() >= NORMAL_OLD_LEN {
            let n = NormalFields {
                brakes: frame[87],
                motors_enabled: frame[88],
                error_code: frame[89],
                warning_code: frame[90],
                tcp_offset: arr(&frame[91..115]),
                payload: arr(&frame[115..131]),
                collision_sensitivity: frame[131],
                teach_sensitivity: frame[132],
                gravity: (frame.len() >= NORMAL_LEN).then(|| arr(&frame[133..145])),
            };
            if n.collision_sensitivity > 5 || n.teach_sensitivity > 5 {
                return Err(format!(
                    "report has sensitivities {} / {}",
                    n.collision_sensitivity, n.teach_sensitivity
                ));
            }
            Some(n)
        } else {
            None
        };
        Ok(Report {
            state,
            mode,
            cmd_num: u16::from_be_bytes([frame[5], frame[6]]),
            joints_rad: arr(&frame[7..35]),
            tcp_pose: arr(&frame[35..59]),
            torques: arr(&frame[59..87]),
            normal,
        })
    }

    /// The frame's bytes: 87 bytes without normal fields, 145 with (gravity 0 if absent).
    pub fn encode(&self) -> Vec<u8> {
        let len = if self.normal.is_some() {
            NORMAL_LEN
        } else {
            REAL_LEN
        };
        let mut out = Vec::with_capacity(len);
        out.extend_from_slice(&(len as u32).to_be_bytes());
        out.push((self.mode << 4) | (self.state & 0x0F));
        out.extend_from_slice(&self.cmd_num.to_be_bytes());
        let floats = |out: &mut Vec<u8>, v: &[f32]| {
            for x in v {
                out.extend_from_slice(&x.to_le_bytes());
            }
        };
        floats(&mut out, &self.joints_rad);
        floats(&mut out, &self.tcp_pose);
        floats(&mut out, &self.torques);
        if let Some(n) = &self.normal {
            out.extend_from_slice(&[n.brakes, n.motors_enabled, n.error_code, n.warning_code]);
            floats(&mut out, &n.tcp_offset);
            floats(&mut out, &n.payload);
            out.extend_from_slice(&[n.collision_sensitivity, n.teach_sensitivity]);
            floats(&mut out, &n.gravity.unwrap_or([0.0; 3]));
        }
        debug_assert_eq!(out.len(), len);
        out
    }
}

/// Reads the next whole report frame from a report stream.
pub async fn read_report<R: AsyncRead + Unpin>(stream: &mut R) -> Result<Report> {
    let lost = |e: std::io::Error| DriverError::Connection(format!("report stream: {e}"));
    let mut header = [0u8; 4];
    stream.read_exact(&mut header).await.map_err(lost)?;
    let len = announced_len(header);
    if !(REAL_LEN..=MAX_REPORT_LEN).contains(&len) {
        return Err(DriverError::Connection(format!(
            "report stream out of step: frame length {len}"
        )));
    }
    let mut frame = vec![0u8; len];
    frame[..4].copy_from_slice(&header);
    stream.read_exact(&mut frame[4..]).await.map_err(lost)?;
    Report::parse(&frame).map_err(DriverError::Connection)
}

/// Connects to a report port, reads the first frame it pushes and disconnects: a fresh
/// reading (the controller streams from the moment a client connects).
pub async fn read_report_from(addr: &str, timeout: Duration) -> Result<Report> {
    let work = async {
        let mut stream = TcpStream::connect(addr)
            .await
            .map_err(|e| DriverError::Connection(format!("report port {addr}: {e}")))?;
        read_report(&mut stream).await
    };
    tokio::time::timeout(timeout, work)
        .await
        .map_err(|_| DriverError::Timeout(timeout))?
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(normal: bool) -> Report {
        Report {
            state: 2,
            mode: 0,
            cmd_num: 3,
            joints_rad: [0.5, -0.25, -1.0, 0.0, 0.75, 0.125, 0.0],
            tcp_pose: [207.0, 0.0, 112.0, 3.0, 0.0, 0.0],
            torques: [0.0; 7],
            normal: normal.then(|| NormalFields {
                brakes: 0x3F,
                motors_enabled: 0x3F,
                error_code: 31,
                warning_code: 0,
                tcp_offset: [0.0; 6],
                payload: [0.5, 0.0, 0.0, 30.0],
                collision_sensitivity: 3,
                teach_sensitivity: 3,
                gravity: Some([0.0, 0.0, -1.0]),
            }),
        }
    }

    #[test]
    fn fields_sit_at_the_documented_offsets() {
        // Built byte by byte from the §1.6 tables, not with our encoder.
        let mut f = vec![0u8; NORMAL_LEN];
        f[..4].copy_from_slice(&145u32.to_be_bytes());
        f[4] = 0x12; // mode 1, state 2
        f[5..7].copy_from_slice(&[0x01, 0x02]);
        f[7..11].copy_from_slice(&std::f32::consts::FRAC_PI_3.to_le_bytes());
        f[35..39].copy_from_slice(&250.5f32.to_le_bytes());
        f[87] = 0x3F;
        f[88] = 0x1F;
        f[89] = 23;
        f[90] = 12;
        f[115..119].copy_from_slice(&1.5f32.to_le_bytes());
        f[131] = 4;
        f[132] = 2;
        f[141..145].copy_from_slice(&(-1.0f32).to_le_bytes());
        let r = Report::parse(&f).unwrap();
        assert_eq!((r.mode, r.state, r.cmd_num), (1, 2, 0x0102));
        assert_eq!(r.joints_rad[0], std::f32::consts::FRAC_PI_3);
        assert_eq!(r.tcp_pose[0], 250.5);
        let n = r.normal.unwrap();
        assert_eq!(
            (n.brakes, n.motors_enabled, n.error_code, n.warning_code),
            (0x3F, 0x1F, 23, 12)
        );
        assert_eq!(n.payload[0], 1.5);
        assert_eq!((n.collision_sensitivity, n.teach_sensitivity), (4, 2));
        assert_eq!(n.gravity, Some([0.0, 0.0, -1.0]));
    }

    #[test]
    fn encodes_and_parses_both_sizes() {
        for normal in [false, true] {
            let r = sample(normal);
            let bytes = r.encode();
            assert_eq!(bytes.len(), if normal { 145 } else { 87 });
            assert_eq!(&bytes[..4], &(bytes.len() as u32).to_be_bytes());
            assert_eq!(Report::parse(&bytes).unwrap(), r);
        }
        // Old firmware's 133-byte normal frame: no gravity.
        let mut old = sample(true).encode();
        old.truncate(NORMAL_OLD_LEN);
        old[..4].copy_from_slice(&133u32.to_be_bytes());
        let r = Report::parse(&old).unwrap();
        assert_eq!(r.normal.unwrap().gravity, None);
    }

    #[test]
    fn rejects_frames_the_sdk_would_reject() {
        let good = sample(true).encode();
        let mut wrong_len = good.clone();
        wrong_len[3] = 144;
        assert!(Report::parse(&wrong_len).unwrap_err().contains("announces"));
        let mut bad_mode = good.clone();
        bad_mode[4] = 0xC2;
        assert!(Report::parse(&bad_mode).is_err());
        let mut bad_sens = good.clone();
        bad_sens[131] = 6;
        assert!(Report::parse(&bad_sens).is_err());
        assert!(Report::parse(&good[..40]).is_err());
        assert_eq!(announced_len(233u32.to_be_bytes()), 245);
    }

    #[tokio::test]
    async fn reads_frames_out_of_a_byte_stream() {
        let mut bytes = sample(false).encode();
        bytes.extend(sample(true).encode());
        let mut cursor: &[u8] = &bytes;
        let a = read_report(&mut cursor).await.unwrap();
        let b = read_report(&mut cursor).await.unwrap();
        assert!(a.normal.is_none() && b.normal.is_some());
        assert!(matches!(
            read_report(&mut cursor).await,
            Err(DriverError::Connection(_))
        ));
    }
}

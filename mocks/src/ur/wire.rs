//! RTDE framing and field types (docs/protocols.md §2.2), shared by the mock controller's server
//! side and the small client behind [`super::UrRtdeJoints`].
//!
//! Every package is `u16 size (BE, including the 3-byte header) | u8 type | payload`; all
//! numbers are big-endian. Field types are looked up by variable name from the same table a
//! controller uses, because ur_rtde ignores the type names the controller answers and decodes
//! each field with its own built-in table.

use std::io;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};

/// Package type bytes.
pub mod kind {
    /// REQUEST_PROTOCOL_VERSION.
    pub const PROTOCOL_VERSION: u8 = b'V';
    /// GET_URCONTROL_VERSION.
    pub const CONTROL_VERSION: u8 = b'v';
    /// TEXT_MESSAGE.
    pub const TEXT_MESSAGE: u8 = b'M';
    /// DATA_PACKAGE.
    pub const DATA: u8 = b'U';
    /// CONTROL_PACKAGE_SETUP_OUTPUTS.
    pub const SETUP_OUTPUTS: u8 = b'O';
    /// CONTROL_PACKAGE_SETUP_INPUTS.
    pub const SETUP_INPUTS: u8 = b'I';
    /// CONTROL_PACKAGE_START.
    pub const START: u8 = b'S';
    /// CONTROL_PACKAGE_PAUSE.
    pub const PAUSE: u8 = b'P';
}

/// Largest package accepted (the name list alone is limited to 2048 bytes).
pub const MAX_PACKAGE: usize = 8192;

/// One RTDE package.
#[derive(Clone, Debug, PartialEq)]
pub struct Package {
    /// Type byte (see [`kind`]).
    pub kind: u8,
    /// Everything after the header.
    pub payload: Vec<u8>,
}

impl Package {
    /// The bytes on the wire.
    pub fn encode(&self) -> Vec<u8> {
        let size = (self.payload.len() + 3) as u16;
        let mut out = Vec::with_capacity(size as usize);
        out.extend_from_slice(&size.to_be_bytes());
        out.push(self.kind);
        out.extend_from_slice(&self.payload);
        out
    }
}

/// Reads one package; `Ok(None)` on a clean end of stream before a header.
pub async fn read_package<R: AsyncRead + Unpin>(r: &mut R) -> io::Result<Option<Package>> {
    let mut header = [0u8; 3];
    match r.read_exact(&mut header[..1]).await {
        Ok(_) => {}
        Err(e) if e.kind() == io::ErrorKind::UnexpectedEof => return Ok(None),
        Err(e) => return Err(e),
    }
    r.read_exact(&mut header[1..]).await?;
    let size = u16::from_be_bytes([header[0], header[1]]) as usize;
    if !(3..=MAX_PACKAGE).contains(&size) {
        return Err(io::Error::new(
            io::ErrorKind::InvalidData,
            format!("RTDE package size {size} outside 3..={MAX_PACKAGE}"),
        ));
    }
    let mut payload = vec![0u8; size - 3];
    r.read_exact(&mut payload).await?;
    Ok(Some(Package {
        kind: header[2],
        payload,
    }))
}

/// Writes one package.
pub async fn write_package<W: AsyncWrite + Unpin>(
    w: &mut W,
    kind: u8,
    payload: &[u8],
) -> io::Result<()> {
    let p = Package {
        kind,
        payload: payload.to_vec(),
    };
    w.write_all(&p.encode()).await
}

/// An RTDE field type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FieldType {
    /// 1 byte, 0 or 1.
    Bool,
    /// 1 byte.
    Uint8,
    /// 4 bytes.
    Uint32,
    /// 8 bytes.
    Uint64,
    /// 4 bytes.
    Int32,
    /// f64.
    Double,
    /// 3 × f64.
    Vector3d,
    /// 6 × f64.
    Vector6d,
    /// 6 × i32.
    Vector6Int32,
    /// 6 × u32.
    Vector6Uint32,
}

impl FieldType {
    /// The name a controller answers in a recipe reply.
    pub fn name(self) -> &'static str {
        match self {
            FieldType::Bool => "BOOL",
            FieldType::Uint8 => "UINT8",
            FieldType::Uint32 => "UINT32",
            FieldType::Uint64 => "UINT64",
            FieldType::Int32 => "INT32",
            FieldType::Double => "DOUBLE",
            FieldType::Vector3d => "VECTOR3D",
            FieldType::Vector6d => "VECTOR6D",
            FieldType::Vector6Int32 => "VECTOR6INT32",
            FieldType::Vector6Uint32 => "VECTOR6UINT32",
        }
    }

    /// Bytes on the wire.
    pub fn size(self) -> usize {
        match self {
            FieldType::Bool | FieldType::Uint8 => 1,
            FieldType::Uint32 | FieldType::Int32 => 4,
            FieldType::Uint64 | FieldType::Double => 8,
            FieldType::Vector3d => 24,
            FieldType::Vector6d => 48,
            FieldType::Vector6Int32 | FieldType::Vector6Uint32 => 24,
        }
    }
}

/// `prefix` followed by a register number in `range`.
fn register(name: &str, prefix: &str, range: std::ops::Range<usize>) -> Option<usize> {
    let n: usize = name.strip_prefix(prefix)?.parse().ok()?;
    range.contains(&n).then_some(n)
}

/// The type of an output variable, `None` for names a controller answers NOT_FOUND.
pub fn output_type(name: &str) -> Option<FieldType> {
    use FieldType::*;
    if register(name, "output_int_register_", 0..48).is_some() {
        return Some(Int32);
    }
    if register(name, "output_double_register_", 0..48).is_some() {
        return Some(Double);
    }
    if register(name, "output_bit_register_", 64..128).is_some() {
        return Some(Bool);
    }
    if register(name, "input_int_register_", 0..48).is_some() {
        return Some(Int32);
    }
    if register(name, "input_double_register_", 0..48).is_some() {
        return Some(Double);
    }
    Some(match name {
        "timestamp"
        | "actual_execution_time"
        | "speed_scaling"
        | "target_speed_fraction"
        | "actual_momentum"
        | "actual_main_voltage"
        | "actual_robot_voltage"
        | "actual_robot_current"
        | "standard_analog_input0"
        | "standard_analog_input1"
        | "standard_analog_output0"
        | "standard_analog_output1"
        | "payload"
        | "tool_analog_input0"
        | "tool_analog_input1"
        | "tool_output_current"
        | "tool_temperature"
        | "io_current"
        | "tcp_force_scalar" => Double,
        "target_q"
        | "target_qd"
        | "target_qdd"
        | "target_current"
        | "target_moment"
        | "actual_q"
        | "actual_qd"
        | "actual_current"
        | "joint_control_output"
        | "actual_TCP_pose"
        | "actual_TCP_speed"
        | "actual_TCP_force"
        | "target_TCP_pose"
        | "target_TCP_speed"
        | "joint_temperatures"
        | "actual_joint_voltage"
        | "ft_raw_wrench"
        | "payload_inertia"
        | "actual_current_as_torque" => Vector6d,
        "actual_tool_accelerometer" | "payload_cog" | "elbow_position" | "elbow_velocity" => {
            Vector3d
        }
        "robot_mode" | "safety_mode" | "tool_output_voltage" => Int32,
        "runtime_state"
        | "robot_status_bits"
        | "safety_status_bits"
        | "analog_io_types"
        | "tool_analog_input_types"
        | "tool_mode"
        | "output_bit_registers0_to_31"
        | "output_bit_registers32_to_63"
        | "input_bit_registers0_to_31"
        | "input_bit_registers32_to_63" => Uint32,
        "actual_digital_input_bits" | "actual_digital_output_bits" => Uint64,
        "joint_mode" => Vector6Int32,
        "tool_output_mode" | "tool_digital_output0_mode" | "tool_digital_output1_mode" => Uint8,
        _ => return None,
    })
}

/// The type of an input variable, `None` for names a controller answers NOT_FOUND.
pub fn input_type(name: &str) -> Option<FieldType> {
    use FieldType::*;
    if register(name, "input_int_register_", 0..48).is_some() {
        return Some(Int32);
    }
    if register(name, "input_double_register_", 0..48).is_some() {
        return Some(Double);
    }
    if register(name, "input_bit_register_", 64..128).is_some() {
        return Some(Bool);
    }
    Some(match name {
        "standard_digital_output_mask"
        | "standard_digital_output"
        | "configurable_digital_output_mask"
        | "configurable_digital_output"
        | "tool_digital_output_mask"
        | "tool_digital_output"
        | "standard_analog_output_mask"
        | "standard_analog_output_type" => Uint8,
        "standard_analog_output_0" | "standard_analog_output_1" | "speed_slider_fraction" => Double,
        "speed_slider_mask" | "input_bit_registers0_to_31" | "input_bit_registers32_to_63" => {
            Uint32
        }
        "external_force_torque" => Vector6d,
        _ => return None,
    })
}

/// A decoded field value.
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    /// Any integer type (BOOL, UINT8, UINT32, UINT64, INT32), widened.
    Int(i64),
    /// DOUBLE.
    Double(f64),
    /// VECTOR3D, VECTOR6D.
    Doubles(Vec<f64>),
    /// VECTOR6INT32, VECTOR6UINT32.
    Ints(Vec<i64>),
}

impl Value {
    /// As a float (integers converted), for registers.
    pub fn as_f64(&self) -> f64 {
        match self {
            Value::Int(v) => *v as f64,
            Value::Double(v) => *v,
            Value::Doubles(v) => v.first().copied().unwrap_or(0.0),
            Value::Ints(v) => v.first().copied().unwrap_or(0) as f64,
        }
    }
}

/// Appends `value` encoded as `ty` (numbers converted; short vectors padded with 0).
pub fn encode_value(out: &mut Vec<u8>, ty: FieldType, value: &Value) {
    let int = || match value {
        Value::Int(v) => *v,
        other => other.as_f64() as i64,
    };
    let doubles = |n: usize| -> Vec<f64> {
        let mut v = match value {
            Value::Doubles(v) => v.clone(),
            Value::Ints(v) => v.iter().map(|x| *x as f64).collect(),
            other => vec![other.as_f64()],
        };
        v.resize(n, 0.0);
        v
    };
    let ints = || -> Vec<i64> {
        let mut v = match value {
            Value::Ints(v) => v.clone(),
            Value::Doubles(v) => v.iter().map(|x| *x as i64).collect(),
            other => vec![other.as_f64() as i64],
        };
        v.resize(6, 0);
        v
    };
    match ty {
        FieldType::Bool | FieldType::Uint8 => out.push(int() as u8),
        FieldType::Uint32 => out.extend_from_slice(&(int() as u32).to_be_bytes()),
        FieldType::Int32 => out.extend_from_slice(&(int() as i32).to_be_bytes()),
        FieldType::Uint64 => out.extend_from_slice(&(int() as u64).to_be_bytes()),
        FieldType::Double => out.extend_from_slice(&value.as_f64().to_be_bytes()),
        FieldType::Vector3d => doubles(3)
            .iter()
            .for_each(|v| out.extend_from_slice(&v.to_be_bytes())),
        FieldType::Vector6d => doubles(6)
            .iter()
            .for_each(|v| out.extend_from_slice(&v.to_be_bytes())),
        FieldType::Vector6Int32 => ints()
            .iter()
            .for_each(|v| out.extend_from_slice(&(*v as i32).to_be_bytes())),
        FieldType::Vector6Uint32 => ints()
            .iter()
            .for_each(|v| out.extend_from_slice(&(*v as u32).to_be_bytes())),
    }
}

/// Decodes the fields of `types` from `bytes`; `None` when the length does not match.
pub fn decode_values(types: &[FieldType], bytes: &[u8]) -> Option<Vec<Value>> {
    let total: usize = types.iter().map(|t| t.size()).sum();
    if total != bytes.len() {
        return None;
    }
    let mut at = 0;
    let mut take = |n: usize| {
        let s = &bytes[at..at + n];
        at += n;
        s
    };
    let f64_at = |s: &[u8]| f64::from_be_bytes(s.try_into().expect("8 bytes"));
    let mut out = Vec::with_capacity(types.len());
    for ty in types {
        let s = take(ty.size());
        out.push(match ty {
            FieldType::Bool | FieldType::Uint8 => Value::Int(s[0] as i64),
            FieldType::Uint32 => Value::Int(u32::from_be_bytes(s.try_into().ok()?) as i64),
            FieldType::Int32 => Value::Int(i32::from_be_bytes(s.try_into().ok()?) as i64),
            FieldType::Uint64 => Value::Int(u64::from_be_bytes(s.try_into().ok()?) as i64),
            FieldType::Double => Value::Double(f64_at(s)),
            FieldType::Vector3d | FieldType::Vector6d => {
                Value::Doubles(s.chunks(8).map(f64_at).collect())
            }
            FieldType::Vector6Int32 => Value::Ints(
                s.chunks(4)
                    .map(|c| i32::from_be_bytes(c.try_into().expect("4 bytes")) as i64)
                    .collect(),
            ),
            FieldType::Vector6Uint32 => Value::Ints(
                s.chunks(4)
                    .map(|c| u32::from_be_bytes(c.try_into().expect("4 bytes")) as i64)
                    .collect(),
            ),
        });
    }
    Some(out)
}

/// Splits a comma-separated name list, dropping the empty names ur_rtde's trailing comma
/// leaves.
pub fn split_names(bytes: &[u8]) -> Vec<String> {
    String::from_utf8_lossy(bytes)
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(str::to_string)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn test_vectors_of_the_protocol_brief() {
        // §2.2: V request and reply, the O request at 125 Hz, and its reply.
        let v = Package {
            kind: kind::PROTOCOL_VERSION,
            payload: vec![0, 2],
        };
        assert_eq!(v.encode(), [0x00, 0x05, 0x56, 0x00, 0x02]);
        let mut o = 125.0f64.to_be_bytes().to_vec();
        o.extend_from_slice(b"actual_q,robot_mode");
        let o = Package {
            kind: kind::SETUP_OUTPUTS,
            payload: o,
        }
        .encode();
        assert_eq!(&o[..3], &[0x00, 0x1E, 0x4F]);
        assert_eq!(&o[3..11], &[0x40, 0x5F, 0x40, 0, 0, 0, 0, 0]);
        assert_eq!(
            split_names(b"actual_q,robot_mode,"),
            ["actual_q", "robot_mode"]
        );
        let types: Vec<&str> = ["actual_q", "robot_mode"]
            .iter()
            .map(|n| output_type(n).unwrap().name())
            .collect();
        assert_eq!(types.join(","), "VECTOR6D,INT32");
        assert_eq!(output_type("output_int_register_48"), None);
        assert_eq!(output_type("nonsense"), None);
        assert_eq!(
            input_type("input_double_register_7"),
            Some(FieldType::Double)
        );
    }

    #[test]
    fn values_round_trip() {
        let types = [
            FieldType::Vector6d,
            FieldType::Int32,
            FieldType::Uint32,
            FieldType::Bool,
        ];
        let values = [
            Value::Doubles(vec![0.1, -0.2, 0.3, -0.4, 0.5, -0.6]),
            Value::Int(-3),
            Value::Int(0xDEAD_BEEF),
            Value::Int(1),
        ];
        let mut bytes = Vec::new();
        for (t, v) in types.iter().zip(&values) {
            encode_value(&mut bytes, *t, v);
        }
        assert_eq!(bytes.len(), 48 + 4 + 4 + 1);
        assert_eq!(&bytes[48..52], &(-3i32).to_be_bytes());
        assert_eq!(decode_values(&types, &bytes).unwrap(), values);
        assert!(decode_values(&types, &bytes[1..]).is_none());
    }
}

//! A half-duplex servo bus on a serial port: one transaction at a time, blocking (the arm
//! driver runs it in `spawn_blocking`). Replies are matched by id and order; a missing reply
//! is [`DriverError::Timeout`], an instruction error in a reply is [`DriverError::Refused`].

use std::io::{Read, Write};
use std::time::{Duration, Instant};

use serialport::{ClearBuffer, SerialPort};

use super::packet::{instruction, PacketError, Status, BROADCAST_ID};
use super::table::Family;
use super::ServoError;
use crate::{DriverError, Result};

/// What a ping found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PingReply {
    /// Model number (Dynamixel: in the ping reply; Feetech: read from the table).
    pub model: u16,
    /// Firmware version (Dynamixel only).
    pub firmware: Option<u8>,
}

/// One servo's answer to a read: its error byte and the data.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ReadReply {
    /// The answering servo.
    pub id: u8,
    /// The status error byte (see [`Family::has_alert`]).
    pub error: u8,
    /// The bytes read.
    pub data: Vec<u8>,
}

/// A serial bus of servos of one family.
pub struct ServoBus {
    family: Family,
    port: Box<dyn SerialPort>,
    name: String,
    buf: Vec<u8>,
    reply_timeout: Duration,
}

impl std::fmt::Debug for ServoBus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "ServoBus({} on {})", self.family.name(), self.name)
    }
}

fn io_error(name: &str, e: impl std::fmt::Display) -> DriverError {
    DriverError::Connection(format!("serial port {name}: {e}"))
}

impl ServoBus {
    /// Opens `path` at `baud` (8N1, no flow control).
    pub fn open(
        path: &str,
        baud: u32,
        family: Family,
        reply_timeout: Duration,
    ) -> Result<ServoBus> {
        let port = serialport::new(path, baud)
            .timeout(Duration::from_millis(5))
            .open()
            .map_err(|e| io_error(path, e))?;
        Ok(ServoBus::from_port(port, family, reply_timeout))
    }

    /// A bus on an already open port (tests: one end of a pseudo-terminal pair).
    pub fn from_port(
        mut port: Box<dyn SerialPort>,
        family: Family,
        reply_timeout: Duration,
    ) -> ServoBus {
        // Short reads: the reply deadline is ours, not the port's.
        let _ = port.set_timeout(Duration::from_millis(5));
        let name = port.name().unwrap_or_else(|| "(unnamed)".into());
        ServoBus {
            family,
            port,
            name,
            buf: Vec::new(),
            reply_timeout,
        }
    }

    /// The family on this bus.
    pub fn family(&self) -> Family {
        self.family
    }

    /// The port's name, for messages.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Sends one instruction packet, first dropping anything unread (late replies of an
    /// abandoned transaction must not be taken for this one's).
    fn send(&mut self, id: u8, ins: u8, params: &[u8]) -> Result<()> {
        let _ = self.port.clear(ClearBuffer::Input);
        self.buf.clear();
        let packet = self.family.protocol().encode_instruction(id, ins, params);
        self.port
            .write_all(&packet)
            .and_then(|()| self.port.flush())
            .map_err(|e| io_error(&self.name, e))
    }

    /// Receives the next status packet from `id` before `deadline`.
    fn receive(&mut self, id: u8, deadline: Instant) -> Result<Status> {
        let protocol = self.family.protocol();
        loop {
            match protocol.parse_status(&self.buf) {
                Ok((status, used)) => {
                    self.buf.drain(..used);
                    if status.id == id {
                        return Ok(status);
                    }
                    return Err(DriverError::Backend(Box::new(ServoError::Protocol(
                        format!(
                            "reply from servo {} while waiting for servo {id}",
                            status.id
                        ),
                    ))));
                }
                Err(PacketError::Skip(n)) => {
                    self.buf.drain(..n);
                }
                Err(PacketError::Invalid { skip, why }) => {
                    self.buf.drain(..skip);
                    return Err(DriverError::Backend(Box::new(ServoError::Protocol(
                        format!("corrupt reply from servo {id}: {why}"),
                    ))));
                }
                Err(PacketError::Incomplete) => {
                    if Instant::now() >= deadline {
                        return Err(DriverError::Timeout(self.reply_timeout));
                    }
                    let mut chunk = [0u8; 256];
                    match self.port.read(&mut chunk) {
                        Ok(0) => {}
                        Ok(n) => self.buf.extend_from_slice(&chunk[..n]),
                        Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
                        Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                        Err(e) => return Err(io_error(&self.name, e)),
                    }
                }
            }
        }
    }

    /// Turns an instruction error in a reply into [`DriverError::Refused`].
    fn check(&self, status: &Status) -> Result<()> {
        match self.family.describe_status_error(status.error) {
            Some(text) if self.family == super::Family::Dynamixel => {
                Err(DriverError::Refused(format!("servo {}: {text}", status.id)))
            }
            _ => Ok(()),
        }
    }

    /// Pings servo `id`.
    pub fn ping(&mut self, id: u8) -> Result<PingReply> {
        self.send(id, instruction::PING, &[])?;
        let status = self.receive(id, Instant::now() + self.reply_timeout)?;
        match self.family {
            Family::Dynamixel => match status.params.as_slice() {
                [lo, hi, fw, ..] => Ok(PingReply {
                    model: u16::from_le_bytes([*lo, *hi]),
                    firmware: Some(*fw),
                }),
                _ => Err(DriverError::Backend(Box::new(ServoError::Protocol(
                    format!("ping reply of servo {id} without model number"),
                )))),
            },
            Family::Feetech => {
                let field = self.family.table().model_number;
                let r = self.read(id, field.addr, field.len)?;
                Ok(PingReply {
                    model: self.family.decode(field, &r.data) as u16,
                    firmware: None,
                })
            }
        }
    }

    /// Reads `len` bytes at `addr` of servo `id`.
    pub fn read(&mut self, id: u8, addr: u16, len: u16) -> Result<ReadReply> {
        let protocol = self.family.protocol();
        self.send(id, instruction::READ, &protocol.read_params(addr, len))?;
        let status = self.receive(id, Instant::now() + self.reply_timeout)?;
        self.check(&status)?;
        Self::reply(status, len)
    }

    fn reply(status: Status, len: u16) -> Result<ReadReply> {
        if status.params.len() != usize::from(len) {
            return Err(DriverError::Backend(Box::new(ServoError::Protocol(
                format!(
                    "servo {} sent {} bytes for a {len}-byte read",
                    status.id,
                    status.params.len()
                ),
            ))));
        }
        Ok(ReadReply {
            id: status.id,
            error: status.error,
            data: status.params,
        })
    }

    /// Writes `data` at `addr` of servo `id` and waits for its acknowledgement; returns the
    /// reply's error byte (hardware alerts are the caller's to interpret).
    pub fn write(&mut self, id: u8, addr: u16, data: &[u8]) -> Result<u8> {
        let protocol = self.family.protocol();
        self.send(id, instruction::WRITE, &protocol.write_params(addr, data))?;
        let status = self.receive(id, Instant::now() + self.reply_timeout)?;
        self.check(&status)?;
        Ok(status.error)
    }

    /// Reads the same range from every servo in `ids` with one request; one reply per id.
    pub fn sync_read(&mut self, addr: u16, len: u16, ids: &[u8]) -> Result<Vec<ReadReply>> {
        let protocol = self.family.protocol();
        self.send(
            BROADCAST_ID,
            instruction::SYNC_READ,
            &protocol.sync_read_params(addr, len, ids),
        )?;
        // The replies follow one another: the deadline covers them all.
        let deadline = Instant::now() + self.reply_timeout;
        ids.iter()
            .map(|&id| {
                let status = self.receive(id, deadline)?;
                self.check(&status)?;
                Self::reply(status, len)
            })
            .collect()
    }

    /// Writes per-servo data to the same range of several servos (no reply).
    pub fn sync_write(&mut self, addr: u16, len: u16, items: &[(u8, Vec<u8>)]) -> Result<()> {
        if let Some((id, d)) = items.iter().find(|(_, d)| d.len() != usize::from(len)) {
            return Err(DriverError::Backend(Box::new(ServoError::Protocol(
                format!(
                    "sync write of {len} bytes with {} bytes for servo {id}",
                    d.len()
                ),
            ))));
        }
        let protocol = self.family.protocol();
        self.send(
            BROADCAST_ID,
            instruction::SYNC_WRITE,
            &protocol.sync_write_params(addr, len, items),
        )
    }

    /// Reboots servo `id` (Dynamixel: clears a hardware error; torque comes back off).
    pub fn reboot(&mut self, id: u8) -> Result<()> {
        self.send(id, instruction::REBOOT, &[])?;
        let status = self.receive(id, Instant::now() + self.reply_timeout)?;
        self.check(&status)
    }
}

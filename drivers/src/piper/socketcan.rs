//! The SocketCAN backend of [`CanBus`] (Linux, feature `socketcan`): a raw CAN socket on an
//! interface such as `can0` (set up with `ip link set can0 type can bitrate 1000000 && ip
//! link set can0 up`) or a `vcan` for tests.

use async_trait::async_trait;
use socketcan::{EmbeddedFrame, StandardId};

use super::bus::CanBus;
use super::frame::CanFrame;
use crate::{DriverError, Result};

/// A raw CAN socket bound to one interface, opened on first use (building a cell never
/// touches the bus, and the socket needs the runtime it is used on).
pub struct SocketCan {
    socket: tokio::sync::OnceCell<socketcan::tokio::CanSocket>,
    interface: String,
}

impl std::fmt::Debug for SocketCan {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "SocketCan({})", self.interface)
    }
}

impl SocketCan {
    /// A socket on `interface` (e.g. `can0`), opened at the first send or receive.
    pub fn new(interface: &str) -> SocketCan {
        SocketCan {
            socket: tokio::sync::OnceCell::new(),
            interface: interface.to_string(),
        }
    }

    async fn socket(&self) -> Result<&socketcan::tokio::CanSocket> {
        self.socket
            .get_or_try_init(|| async {
                socketcan::tokio::CanSocket::open(&self.interface).map_err(|e| {
                    DriverError::Connection(format!(
                        "CAN interface {}: {e} (is it up? `ip link set {} up`)",
                        self.interface, self.interface
                    ))
                })
            })
            .await
    }
}

#[async_trait]
impl CanBus for SocketCan {
    async fn send(&self, frame: &CanFrame) -> Result<()> {
        let id = StandardId::new(frame.id).ok_or_else(|| {
            DriverError::Refused(format!("CAN id {:#x} is not an 11-bit id", frame.id))
        })?;
        let data = socketcan::CanDataFrame::new(id, frame.bytes())
            .ok_or_else(|| DriverError::Refused(format!("CAN frame of {} bytes", frame.len)))?;
        self.socket()
            .await?
            .write_frame(socketcan::CanFrame::Data(data))
            .await
            .map_err(|e| DriverError::Connection(format!("CAN interface {}: {e}", self.interface)))
    }

    async fn recv(&self) -> Result<CanFrame> {
        loop {
            let frame = self.socket().await?.read_frame().await.map_err(|e| {
                DriverError::Connection(format!("CAN interface {}: {e}", self.interface))
            })?;
            // Only standard data frames carry Piper traffic; skip remote, error and 29-bit ones.
            if let socketcan::CanFrame::Data(d) = frame {
                if let socketcan::Id::Standard(id) = d.id() {
                    if let Some(f) = CanFrame::new(id.as_raw(), d.data()) {
                        return Ok(f);
                    }
                }
            }
        }
    }
}

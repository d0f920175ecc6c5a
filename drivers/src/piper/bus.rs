//! CAN transport behind a small object-safe trait, so the Piper driver runs on SocketCAN on
//! hardware and on an in-process bus in CI (no `vcan` there, docs/protocols.md §4.5).

use async_trait::async_trait;
use tokio::sync::{broadcast, Mutex};

use super::frame::CanFrame;
use crate::{DriverError, Result};

/// A node on a classic CAN bus: what it sends every other node receives.
#[async_trait]
pub trait CanBus: Send + Sync {
    /// Sends one frame.
    async fn send(&self, frame: &CanFrame) -> Result<()>;
    /// Waits for the next frame from another node.
    async fn recv(&self) -> Result<CanFrame>;
}

/// An in-process CAN bus: every [`InProcessCan`] endpoint made from it receives the frames
/// the others send (not its own, like a SocketCAN socket). Bounded: a node that falls more
/// than `capacity` frames behind loses the oldest, as a real socket's queue overflows.
#[derive(Clone, Debug)]
pub struct InProcessBus {
    tx: broadcast::Sender<(u64, CanFrame)>,
    next: std::sync::Arc<std::sync::atomic::AtomicU64>,
}

impl InProcessBus {
    /// A bus whose nodes buffer up to `capacity` frames each.
    pub fn new(capacity: usize) -> InProcessBus {
        let (tx, _) = broadcast::channel(capacity.max(1));
        InProcessBus {
            tx,
            next: Default::default(),
        }
    }

    /// A new node on this bus.
    pub fn endpoint(&self) -> InProcessCan {
        let node = self.next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        InProcessCan {
            node,
            tx: self.tx.clone(),
            rx: Mutex::new(self.tx.subscribe()),
        }
    }
}

/// One node of an [`InProcessBus`].
#[derive(Debug)]
pub struct InProcessCan {
    node: u64,
    tx: broadcast::Sender<(u64, CanFrame)>,
    rx: Mutex<broadcast::Receiver<(u64, CanFrame)>>,
}

#[async_trait]
impl CanBus for InProcessCan {
    async fn send(&self, frame: &CanFrame) -> Result<()> {
        // No other node listening is not an error on CAN (the frame just goes unacknowledged).
        let _ = self.tx.send((self.node, *frame));
        Ok(())
    }

    async fn recv(&self) -> Result<CanFrame> {
        let mut rx = self.rx.lock().await;
        loop {
            match rx.recv().await {
                Ok((node, frame)) if node != self.node => return Ok(frame),
                Ok(_) | Err(broadcast::error::RecvError::Lagged(_)) => continue,
                Err(broadcast::error::RecvError::Closed) => {
                    return Err(DriverError::Connection("in-process CAN bus closed".into()))
                }
            }
        }
    }
}

//! The camera role.

use std::time::SystemTime;

use async_trait::async_trait;

use crate::Result;

/// Pinhole intrinsics with optional `plumb_bob` distortion (k1 k2 p1 p2 k3), pixels.
#[derive(Clone, Debug, PartialEq)]
pub struct Intrinsics {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Focal length x.
    pub fx: f64,
    /// Focal length y.
    pub fy: f64,
    /// Principal point x.
    pub cx: f64,
    /// Principal point y.
    pub cy: f64,
    /// `plumb_bob` coefficients, when the lens is modelled.
    pub distortion: Option<[f64; 5]>,
}

/// One captured colour frame.
#[derive(Clone, Debug)]
pub struct Frame {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Row-major RGB8.
    pub rgb: Vec<u8>,
    /// When the exposure happened (sensor or host clock).
    pub captured_at: SystemTime,
    /// The camera's frame counter (a V4L2 buffer's sequence, a GigE Vision block id, a
    /// simulator's frame index): it tells frames apart, and lets a simulator look up what it
    /// rendered for a frame without the frame carrying anything a real camera would not.
    pub sequence: u64,
}

/// A camera that grabs colour frames on request.
#[async_trait]
pub trait Camera: Send + Sync {
    /// Calibrated intrinsics of the frames it returns.
    fn intrinsics(&self) -> &Intrinsics;

    /// Grabs the next frame exposed after this call.
    async fn grab(&self) -> Result<Frame>;
}

/// A camera whose device is owned by one capture thread (V4L2, Aravis: their handles are not
/// `Send` or block): the thread's queue of frame requests, each answered on its own channel.
#[cfg(any(feature = "v4l2", feature = "aravis"))]
pub(crate) type FrameRequests =
    std::sync::mpsc::SyncSender<tokio::sync::oneshot::Sender<Result<Frame>>>;

/// Asks the capture thread behind `requests` for the next frame; `backend` names it in the
/// error when the thread is gone.
#[cfg(any(feature = "v4l2", feature = "aravis"))]
pub(crate) async fn request_frame(requests: &FrameRequests, backend: &str) -> Result<Frame> {
    let (tx, rx) = tokio::sync::oneshot::channel();
    let lost =
        || crate::DriverError::Connection(format!("the {backend} worker thread has stopped"));
    let requests = requests.clone();
    // The queue holds one request; a full queue waits off the async runtime.
    tokio::task::spawn_blocking(move || requests.send(tx))
        .await
        .map_err(|e| crate::DriverError::Backend(Box::new(e)))?
        .map_err(|_| lost())?;
    rx.await.map_err(|_| lost())?
}

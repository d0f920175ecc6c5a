//! The camera role.

use std::time::SystemTime;

use async_trait::async_trait;

use crate::Result;

use nalgebra::Point3;

/// Pinhole intrinsics with optional `plumb_bob` distortion (k1 k2 p1 p2 k3), pixels; pixel
/// centres sit at integer coordinates (the OpenCV and ROS convention). The one camera model of
/// the whole project: drivers report it, and the solver, renderer and formats use it as is.
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

impl Intrinsics {
    /// An ideal pinhole camera.
    pub fn pinhole(width: u32, height: u32, fx: f64, fy: f64, cx: f64, cy: f64) -> Intrinsics {
        Intrinsics {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            distortion: None,
        }
    }

    /// Whether any distortion coefficient is non-zero.
    pub fn is_distorted(&self) -> bool {
        self.distortion.is_some_and(|d| d.iter().any(|&k| k != 0.0))
    }

    /// The same camera without distortion (the image the solver works in).
    pub fn undistorted(&self) -> Intrinsics {
        Intrinsics {
            distortion: None,
            ..self.clone()
        }
    }

    /// Intrinsics for an image downsampled by `factor` (an image-pyramid level). Pixel centres
    /// stay at integer coordinates: `c' = (c + 0.5) / f - 0.5`.
    pub fn downsampled(&self, factor: u32) -> Intrinsics {
        let f = f64::from(factor);
        Intrinsics {
            width: self.width.div_ceil(factor),
            height: self.height.div_ceil(factor),
            fx: self.fx / f,
            fy: self.fy / f,
            cx: (self.cx + 0.5) / f - 0.5,
            cy: (self.cy + 0.5) / f - 0.5,
            distortion: self.distortion,
        }
    }

    /// Pinhole projection of a camera-frame point (ignores distortion).
    #[inline]
    pub fn project(&self, p: &Point3<f64>) -> [f64; 2] {
        [self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy]
    }

    /// Applies distortion to normalised coordinates `(x/z, y/z)`.
    pub fn distort_normalized(&self, x: f64, y: f64) -> (f64, f64) {
        let Some([k1, k2, p1, p2, k3]) = self.distortion else {
            return (x, y);
        };
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        (
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        )
    }

    /// Inverts [`Intrinsics::distort_normalized`] by fixed-point iteration (as OpenCV does).
    pub fn undistort_normalized(&self, xd: f64, yd: f64) -> (f64, f64) {
        if self.distortion.is_none() {
            return (xd, yd);
        }
        let (mut x, mut y) = (xd, yd);
        for _ in 0..20 {
            let (dx, dy) = self.distort_normalized(x, y);
            x += xd - dx;
            y += yd - dy;
        }
        (x, y)
    }

    /// Full projection of a camera-frame point including distortion.
    pub fn project_distorted(&self, p: &Point3<f64>) -> [f64; 2] {
        let (x, y) = self.distort_normalized(p.x / p.z, p.y / p.z);
        [self.fx * x + self.cx, self.fy * y + self.cy]
    }
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
    /// simulator's frame number, from 1): it tells frames apart, and lets a simulator look up
    /// what it rendered for a frame without the frame carrying anything a real camera would
    /// not. 0 for a frame that did not come from a camera (an image read from disk).
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

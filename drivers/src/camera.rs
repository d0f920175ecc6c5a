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

/// Longest image side accepted, pixels (a 16K sensor): it bounds every per-pixel buffer a
/// run or a config can make the solver allocate.
pub const MAX_IMAGE_SIDE: u32 = 16_384;
/// Shortest image side accepted, pixels.
pub const MIN_IMAGE_SIDE: u32 = 8;
/// Focal lengths accepted, as multiples of the longer image side: from about a 170° field of
/// view (0.05) to about 1° (50). Outside that a value is a unit slip or a corrupt file, and the
/// solver would fit a meaningless pose with a tight uncertainty.
pub const FOCAL_RANGE_PER_SIDE: (f64, f64) = (0.05, 50.0);
/// Largest `fx / fy` or `fy / fx` accepted: real pixels are square to within a few percent.
pub const MAX_PIXEL_ASPECT: f64 = 2.0;
/// Largest magnitude of a `plumb_bob` coefficient accepted.
pub const MAX_DISTORTION_COEFFICIENT: f64 = 1e3;

impl Intrinsics {
    /// The first value outside its physical range, as `(field, what is allowed)`: image sides in
    /// [`MIN_IMAGE_SIDE`, `MAX_IMAGE_SIDE`], focal lengths within [`FOCAL_RANGE_PER_SIDE`] of
    /// the longer side and within [`MAX_PIXEL_ASPECT`] of each other, the principal point
    /// strictly inside the image, finite distortion coefficients. Every reader of intrinsics
    /// (run files, cell configs, calibration files, imports) calls this before using them.
    pub fn range_problem(&self) -> Option<(&'static str, String)> {
        for (name, side) in [("width", self.width), ("height", self.height)] {
            if !(MIN_IMAGE_SIDE..=MAX_IMAGE_SIDE).contains(&side) {
                return Some((
                    name,
                    format!("is {side} px; allowed: {MIN_IMAGE_SIDE} to {MAX_IMAGE_SIDE}"),
                ));
            }
        }
        let side = f64::from(self.width.max(self.height));
        let (lo, hi) = (FOCAL_RANGE_PER_SIDE.0 * side, FOCAL_RANGE_PER_SIDE.1 * side);
        for (name, f) in [("fx", self.fx), ("fy", self.fy)] {
            if !(f.is_finite() && f >= lo && f <= hi) {
                return Some((
                    name,
                    format!(
                        "is {f} px; allowed for a {}x{} image: {lo} to {hi}",
                        self.width, self.height
                    ),
                ));
            }
        }
        let aspect = self.fx / self.fy;
        if !(1.0 / MAX_PIXEL_ASPECT..=MAX_PIXEL_ASPECT).contains(&aspect) {
            return Some((
                "fy",
                format!(
                    "fx/fy is {aspect:.3}; allowed: {} to {MAX_PIXEL_ASPECT} (are fx and fy in the same pixels?)",
                    1.0 / MAX_PIXEL_ASPECT
                ),
            ));
        }
        for (name, c, extent) in [("cx", self.cx, self.width), ("cy", self.cy, self.height)] {
            if !(c.is_finite() && c > 0.0 && c < f64::from(extent)) {
                return Some((
                    name,
                    format!(
                        "is {c} px; allowed: inside the image, 0 < {name} < {extent} (a transposed camera matrix puts the principal point at 0)"
                    ),
                ));
            }
        }
        let bad_k = self.distortion.and_then(|d| {
            d.into_iter()
                .find(|k| !(k.is_finite() && k.abs() <= MAX_DISTORTION_COEFFICIENT))
        });
        bad_k.map(|k| {
            (
                "distortion",
                format!("coefficient {k}; allowed: finite, at most {MAX_DISTORTION_COEFFICIENT} in magnitude"),
            )
        })
    }

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

//! [`V4l2Camera`]: one `/dev/video*` capture node on a worker thread.
//!
//! The device and its memory-mapped stream (four buffers) live on a dedicated thread, since a
//! dequeue blocks; `grab` sends it a request and awaits the reply. The stream runs from `open`
//! on, so its buffers fill with frames older than any request: a grab skips every frame whose
//! kernel timestamp (`CLOCK_MONOTONIC`) is before the request, then converts the first one
//! after it. Drivers that do not stamp frames with the monotonic clock get their queued
//! buffers skipped instead.

use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::{Duration, Instant, SystemTime};

use async_trait::async_trait;
use tokio::sync::oneshot;
use v4l::buffer::{Flags as BufferFlags, Type as BufferType};
use v4l::capability::Flags as CapabilityFlags;
use v4l::control::{Control, Value as ControlValue};
use v4l::format::Quantization;
use v4l::io::mmap::Stream as MmapStream;
use v4l::io::traits::CaptureStream;
use v4l::video::Capture;
use v4l::{Device, Format, FourCC};

use super::{
    mjpeg_to_rgb, pick_device_by_name, yuyv_to_rgb, DeviceCandidate, V4l2PixelFormat, YuvRange,
};
use crate::camera::{request_frame, FrameRequests};
use crate::intrinsics::check_frame_size;
use crate::{Camera, DriverError, Frame, Intrinsics, Result};

/// `V4L2_CID_EXPOSURE_AUTO` (camera class base 0x009a0900 + 1), from `linux/v4l2-controls.h`.
const CID_EXPOSURE_AUTO: u32 = 0x009a_0901;
/// `V4L2_EXPOSURE_MANUAL`: the value of `CID_EXPOSURE_AUTO` that fixes the exposure.
const EXPOSURE_MANUAL: i64 = 1;
/// `V4L2_CID_EXPOSURE_ABSOLUTE`, in units of 100 µs.
const CID_EXPOSURE_ABSOLUTE: u32 = 0x009a_0902;
/// Buffers in the mmap stream.
const BUFFER_COUNT: u32 = 4;

/// How to open and configure a webcam.
#[derive(Clone, Debug)]
pub struct V4l2Config {
    /// A device path (`/dev/video0`, `/dev/v4l/by-id/…`) or the camera's name as the driver
    /// reports it (`HD Pro Webcam C920`; a unique part of it is enough).
    pub device: String,
    /// Stream width, pixels.
    pub width: u32,
    /// Stream height, pixels.
    pub height: u32,
    /// Stream format.
    pub pixel_format: V4l2PixelFormat,
    /// Fixed exposure, microseconds (manual exposure, in the driver's 100 µs steps); `None`
    /// leaves the camera's setting (usually automatic).
    pub exposure_us: Option<u32>,
    /// Intrinsics from the calibration file; the stream must have their size.
    pub intrinsics: Intrinsics,
    /// The calibration file, named in size-mismatch errors.
    pub intrinsics_file: PathBuf,
    /// Limit for one grab, default 2 s.
    pub frame_timeout: Duration,
}

impl V4l2Config {
    /// A config with the default frame timeout and the camera's own exposure.
    pub fn new(
        device: String,
        width: u32,
        height: u32,
        pixel_format: V4l2PixelFormat,
        intrinsics: Intrinsics,
        intrinsics_file: PathBuf,
    ) -> V4l2Config {
        V4l2Config {
            device,
            width,
            height,
            pixel_format,
            exposure_us: None,
            intrinsics,
            intrinsics_file,
            frame_timeout: Duration::from_secs(2),
        }
    }
}

type Reply = oneshot::Sender<Result<Frame>>;

/// A UVC webcam (see the module docs for how frames are picked).
pub struct V4l2Camera {
    intrinsics: Intrinsics,
    path: PathBuf,
    requests: FrameRequests,
}

impl std::fmt::Debug for V4l2Camera {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("V4l2Camera")
            .field("path", &self.path)
            .finish_non_exhaustive()
    }
}

/// Every `/dev/video*` node with its driver name and whether it captures video.
pub fn list_devices() -> Vec<DeviceCandidate> {
    let mut nodes: Vec<DeviceCandidate> = v4l::context::enum_devices()
        .into_iter()
        .map(|node| {
            let path = node.path().to_path_buf();
            let can_capture = Device::with_path(&path)
                .and_then(|d| d.query_caps())
                .map(|caps| caps.capabilities.contains(CapabilityFlags::VIDEO_CAPTURE))
                .unwrap_or(false);
            DeviceCandidate {
                name: node.name().unwrap_or_default(),
                path,
                can_capture,
            }
        })
        .collect();
    nodes.sort_by(|a, b| a.path.cmp(&b.path));
    nodes
}

/// The node a configured `device` means: a path as given, else a name looked up.
fn resolve_device(device: &str) -> Result<PathBuf> {
    if device.starts_with('/') || Path::new(device).exists() {
        return Ok(PathBuf::from(device));
    }
    pick_device_by_name(&list_devices(), device).map_err(DriverError::Connection)
}

impl V4l2Camera {
    /// Opens the device, sets the format (and exposure) and starts streaming; blocks until
    /// done. Fails with `Connection` when the device is missing or unreadable, `Refused` when
    /// it rejects the format or a control, and `Backend(IntrinsicsError)` when the stream size
    /// differs from the calibration's.
    pub fn open(config: V4l2Config) -> Result<V4l2Camera> {
        let path = resolve_device(&config.device)?;
        let (ready_tx, ready_rx) = mpsc::sync_channel(1);
        let (requests, request_rx) = mpsc::sync_channel::<Reply>(1);
        let cfg = config.clone();
        let worker_path = path.clone();
        std::thread::Builder::new()
            .name("v4l2-camera".to_string())
            .spawn(move || match Worker::open(&worker_path, &cfg) {
                Ok(mut worker) => {
                    if ready_tx.send(Ok(())).is_ok() {
                        for reply in request_rx {
                            let _ = reply.send(worker.grab());
                        }
                    }
                }
                Err(e) => {
                    let _ = ready_tx.send(Err(e));
                }
            })
            .map_err(|e| DriverError::Backend(Box::new(e)))?;
        ready_rx.recv().map_err(|_| {
            DriverError::Connection("the V4L2 worker thread ended while opening".to_string())
        })??;
        Ok(V4l2Camera {
            intrinsics: config.intrinsics,
            path,
            requests,
        })
    }

    /// The device node in use.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[async_trait]
impl Camera for V4l2Camera {
    fn intrinsics(&self) -> &Intrinsics {
        &self.intrinsics
    }

    async fn grab(&self) -> Result<Frame> {
        request_frame(&self.requests, "V4L2").await
    }
}

/// `CLOCK_MONOTONIC` now, as a duration since its origin.
fn monotonic_now() -> Duration {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: a valid out-pointer; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    Duration::new(
        ts.tv_sec.max(0) as u64,
        ts.tv_nsec.clamp(0, 999_999_999) as u32,
    )
}

/// The thread-owned device and stream.
struct Worker {
    path: PathBuf,
    // The stream keeps its own handle to the device; the device is kept for controls.
    _device: Device,
    stream: MmapStream<'static>,
    format: Format,
    pixel_format: V4l2PixelFormat,
    frame_timeout: Duration,
}

fn io_error(path: &Path, what: &str, e: std::io::Error, timeout: Duration) -> DriverError {
    match e.kind() {
        std::io::ErrorKind::TimedOut => DriverError::Timeout(timeout),
        _ if e.raw_os_error() == Some(libc::ENODEV) => DriverError::Connection(format!(
            "{}: {what}: the device is gone ({e})",
            path.display()
        )),
        _ => DriverError::Connection(format!("{}: {what}: {e}", path.display())),
    }
}

impl Worker {
    fn open(path: &Path, cfg: &V4l2Config) -> Result<Worker> {
        let shown = path.display();
        let device = Device::with_path(path)
            .map_err(|e| DriverError::Connection(format!("{shown}: cannot open: {e}")))?;
        let caps = device
            .query_caps()
            .map_err(|e| DriverError::Connection(format!("{shown}: not a V4L2 device: {e}")))?;
        if !caps.capabilities.contains(CapabilityFlags::VIDEO_CAPTURE) {
            return Err(DriverError::Refused(format!(
                "{shown} ({}) does not capture video (a metadata node?): use the capture node",
                caps.card
            )));
        }
        let wanted = Format::new(
            cfg.width,
            cfg.height,
            FourCC::new(&cfg.pixel_format.fourcc()),
        );
        let format = device
            .set_format(&wanted)
            .map_err(|e| DriverError::Refused(format!("{shown}: set format: {e}")))?;
        if format.fourcc != wanted.fourcc
            || (format.width, format.height) != (cfg.width, cfg.height)
        {
            return Err(DriverError::Refused(format!(
                "{shown} ({}): asked for {}x{} {}, the driver offers {}x{} {}",
                caps.card,
                cfg.width,
                cfg.height,
                wanted.fourcc,
                format.width,
                format.height,
                format.fourcc
            )));
        }
        check_frame_size(
            &cfg.intrinsics,
            &cfg.intrinsics_file,
            format.width,
            format.height,
        )
        .map_err(|e| DriverError::Backend(Box::new(e)))?;
        if let Some(us) = cfg.exposure_us {
            let set = |id: u32, value: i64, what: &str| {
                device
                    .set_control(Control {
                        id,
                        value: ControlValue::Integer(value),
                    })
                    .map_err(|e| DriverError::Refused(format!("{shown}: {what}: {e}")))
            };
            set(CID_EXPOSURE_AUTO, EXPOSURE_MANUAL, "manual exposure")?;
            let steps = i64::from(us.div_ceil(100).max(1));
            set(CID_EXPOSURE_ABSOLUTE, steps, &format!("exposure {us} us"))?;
        }
        let mut stream = MmapStream::with_buffers(&device, BufferType::VideoCapture, BUFFER_COUNT)
            .map_err(|e| DriverError::Connection(format!("{shown}: map buffers: {e}")))?;
        stream.set_timeout(cfg.frame_timeout);
        Ok(Worker {
            path: path.to_path_buf(),
            _device: device,
            stream,
            format,
            pixel_format: cfg.pixel_format,
            frame_timeout: cfg.frame_timeout,
        })
    }

    fn grab(&mut self) -> Result<Frame> {
        let requested = monotonic_now();
        let deadline = Instant::now() + self.frame_timeout;
        let mut skipped = 0u32;
        loop {
            if Instant::now() >= deadline {
                return Err(DriverError::Timeout(self.frame_timeout));
            }
            let (data, meta) = CaptureStream::next(&mut self.stream)
                .map_err(|e| io_error(&self.path, "dequeue", e, self.frame_timeout))?;
            let stamp = Duration::new(
                meta.timestamp.sec.max(0) as u64,
                (meta.timestamp.usec.clamp(0, 999_999) * 1000) as u32,
            );
            let monotonic =
                meta.flags & BufferFlags::TIMESTAMP_MASK == BufferFlags::TIMESTAMP_MONOTONIC;
            let fresh = if monotonic {
                stamp >= requested
            } else {
                skipped >= BUFFER_COUNT
            };
            if !fresh || meta.flags.contains(BufferFlags::ERROR) {
                skipped += 1;
                continue;
            }
            let used = (meta.bytesused as usize).min(data.len());
            let (w, h) = (self.format.width, self.format.height);
            let rgb = match self.pixel_format {
                V4l2PixelFormat::Yuyv => {
                    let range = if matches!(self.format.quantization, Quantization::FullRange) {
                        YuvRange::Full
                    } else {
                        YuvRange::Limited
                    };
                    let stride = self.format.stride.max(2 * w);
                    yuyv_to_rgb(&data[..used], w, h, stride, range)
                }
                V4l2PixelFormat::Mjpeg => mjpeg_to_rgb(&data[..used], w, h),
            }
            .map_err(|e| DriverError::Backend(Box::new(e)))?;
            let captured_at = if monotonic {
                SystemTime::now() - monotonic_now().saturating_sub(stamp)
            } else {
                SystemTime::now()
            };
            return Ok(Frame {
                width: w,
                height: h,
                rgb,
                captured_at,
                sequence: u64::from(meta.sequence),
            });
        }
    }
}

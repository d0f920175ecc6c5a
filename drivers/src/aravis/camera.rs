//! [`AravisCamera`]: one GenICam camera on a worker thread that owns every libaravis object.
//!
//! libaravis objects are not `Sync`, and a pop with a timeout blocks, so the camera, its
//! stream and its buffers live on a dedicated thread; `grab` sends it a request and awaits the
//! reply. The stream runs continuously (four buffers). A grab first hands back every buffer
//! that was already waiting, then drops the first frame to arrive (its exposure may have begun
//! before the call) and returns the next, so the frame shows the scene after the call.

use std::path::PathBuf;
use std::sync::mpsc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use ::aravis::glib;
use ::aravis::prelude::*;
use ::aravis::{Auto, Buffer, BufferStatus, Camera as ArvCamera, Stream};
use async_trait::async_trait;
use tokio::sync::oneshot;

use super::{raw_to_rgb, PixelFormat};
use crate::camera::{request_frame, FrameRequests};
use crate::intrinsics::check_frame_size;
use crate::{Camera, DriverError, Frame, Intrinsics, Result};

/// How to open and configure a GenICam camera.
#[derive(Clone, Debug)]
pub struct AravisConfig {
    /// Aravis device id (`<vendor>-<model>-<serial>`, `<vendor>-<serial>`, user id, MAC or IP);
    /// `None` opens the first camera found. Ids starting with `Fake_` (e.g. `Fake_1`) enable
    /// Aravis's in-process fake camera first, for tests and demos.
    pub device_id: Option<String>,
    /// Sensor output format.
    pub pixel_format: PixelFormat,
    /// Fixed exposure, microseconds (auto exposure is turned off); `None` leaves the camera's
    /// setting.
    pub exposure_us: Option<f64>,
    /// Fixed analog gain, dB (auto gain off); `None` leaves the camera's setting.
    pub gain_db: Option<f64>,
    /// Intrinsics from the calibration file; the camera's region must have their size.
    pub intrinsics: Intrinsics,
    /// The calibration file, named in size-mismatch errors.
    pub intrinsics_file: PathBuf,
    /// Limit for one grab (two frame periods plus exposure must fit), default 2 s.
    pub frame_timeout: Duration,
}

impl AravisConfig {
    /// A config with the default frame timeout and the camera's own exposure and gain.
    pub fn new(
        device_id: Option<String>,
        pixel_format: PixelFormat,
        intrinsics: Intrinsics,
        intrinsics_file: PathBuf,
    ) -> AravisConfig {
        AravisConfig {
            device_id,
            pixel_format,
            exposure_us: None,
            gain_db: None,
            intrinsics,
            intrinsics_file,
            frame_timeout: Duration::from_secs(2),
        }
    }
}

/// Makes Aravis's in-process "Fake" interface (device `Fake_1`, a 512×512 Mono8 test pattern
/// at 25 fps) visible to device lookups. It is off by default in Aravis 0.8.
pub fn enable_fake_interface() {
    // SAFETY: a NUL-terminated static string; libaravis copies what it needs.
    unsafe { aravis_sys::arv_enable_interface(c"Fake".as_ptr()) }
}

type Reply = oneshot::Sender<Result<Frame>>;

/// A GigE Vision / USB3 Vision camera (see the module docs for how frames are picked).
pub struct AravisCamera {
    intrinsics: Intrinsics,
    device_id: String,
    requests: FrameRequests,
}

impl std::fmt::Debug for AravisCamera {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AravisCamera")
            .field("device_id", &self.device_id)
            .finish_non_exhaustive()
    }
}

impl AravisCamera {
    /// Opens and configures the camera and starts its stream; blocks until that is done.
    /// Fails with `Connection` when no such camera answers, `Refused` when it rejects a
    /// setting, and `Backend(IntrinsicsError)` when its image size differs from the
    /// calibration's.
    pub fn open(config: AravisConfig) -> Result<AravisCamera> {
        let (ready_tx, ready_rx) = mpsc::sync_channel(1);
        let (requests, request_rx) = mpsc::sync_channel::<Reply>(1);
        let cfg = config.clone();
        std::thread::Builder::new()
            .name("aravis-camera".to_string())
            .spawn(move || match Worker::open(&cfg) {
                Ok(worker) => {
                    let id = worker.device_id.clone();
                    if ready_tx.send(Ok(id)).is_ok() {
                        worker.serve(request_rx);
                    }
                }
                Err(e) => {
                    let _ = ready_tx.send(Err(e));
                }
            })
            .map_err(|e| DriverError::Backend(Box::new(e)))?;
        let device_id = ready_rx.recv().map_err(|_| {
            DriverError::Connection("the Aravis worker thread ended while opening".to_string())
        })??;
        Ok(AravisCamera {
            intrinsics: config.intrinsics,
            device_id,
            requests,
        })
    }

    /// The configured device id, or `<model>-<serial>` of the first camera found.
    pub fn device_id(&self) -> &str {
        &self.device_id
    }
}

#[async_trait]
impl Camera for AravisCamera {
    fn intrinsics(&self) -> &Intrinsics {
        &self.intrinsics
    }

    async fn grab(&self) -> Result<Frame> {
        request_frame(&self.requests, "Aravis").await
    }
}

/// The thread-owned camera and stream.
struct Worker {
    camera: ArvCamera,
    stream: Stream,
    device_id: String,
    pixel_format: PixelFormat,
    width: u32,
    height: u32,
    frame_timeout: Duration,
}

fn refused(what: &str, e: glib::Error) -> DriverError {
    DriverError::Refused(format!("{what}: {e}"))
}

impl Worker {
    fn open(cfg: &AravisConfig) -> Result<Worker> {
        if cfg
            .device_id
            .as_deref()
            .is_some_and(|id| id.starts_with("Fake_"))
        {
            enable_fake_interface();
        }
        let camera = ArvCamera::new(cfg.device_id.as_deref()).map_err(|e| {
            DriverError::Connection(format!(
                "no Aravis camera {}: {e}",
                cfg.device_id.as_deref().unwrap_or("(first found)")
            ))
        })?;
        // The id asked for; for "first found", the camera's model and serial.
        let device_id = cfg.device_id.clone().unwrap_or_else(|| {
            let model = camera
                .model_name()
                .map(|s| s.to_string())
                .unwrap_or_default();
            let serial = camera
                .device_serial_number()
                .map(|s| s.to_string())
                .unwrap_or_default();
            format!("{model}-{serial}")
        });
        let format = cfg.pixel_format;
        camera
            .set_pixel_format(::aravis::PixelFormat::from_raw(format.pfnc()))
            .map_err(|e| refused(&format!("pixel format {format}"), e))?;
        let set = camera
            .pixel_format()
            .map_err(|e| refused("pixel format", e))?;
        if set.raw() != format.pfnc() {
            return Err(DriverError::Refused(format!(
                "pixel format {format}: the camera kept 0x{:08x}",
                set.raw()
            )));
        }
        if let Some(us) = cfg.exposure_us {
            if camera.is_exposure_auto_available().unwrap_or(false) {
                camera
                    .set_exposure_time_auto(Auto::Off)
                    .map_err(|e| refused("auto exposure off", e))?;
            }
            camera
                .set_exposure_time(us)
                .map_err(|e| refused(&format!("exposure {us} us"), e))?;
        }
        if let Some(db) = cfg.gain_db {
            if camera.is_gain_auto_available().unwrap_or(false) {
                camera
                    .set_gain_auto(Auto::Off)
                    .map_err(|e| refused("auto gain off", e))?;
            }
            camera
                .set_gain(db)
                .map_err(|e| refused(&format!("gain {db} dB"), e))?;
        }
        let (_, _, w, h) = camera.region().map_err(|e| refused("region", e))?;
        let (width, height) = (w.max(0) as u32, h.max(0) as u32);
        check_frame_size(&cfg.intrinsics, &cfg.intrinsics_file, width, height)
            .map_err(|e| DriverError::Backend(Box::new(e)))?;
        let payload = camera.payload().map_err(|e| refused("payload size", e))?;
        let stream = camera
            .create_stream()
            .map_err(|e| DriverError::Connection(format!("stream of {device_id}: {e}")))?;
        for _ in 0..4 {
            stream.push_buffer(Buffer::new_allocate(payload as usize));
        }
        camera
            .start_acquisition()
            .map_err(|e| refused("start acquisition", e))?;
        Ok(Worker {
            camera,
            stream,
            device_id,
            pixel_format: format,
            width,
            height,
            frame_timeout: cfg.frame_timeout,
        })
    }

    /// Answers grab requests until the camera handle is dropped, then stops the stream.
    fn serve(self, requests: mpsc::Receiver<Reply>) {
        for reply in requests {
            let _ = reply.send(self.grab());
        }
        let _ = self.camera.stop_acquisition();
    }

    fn grab(&self) -> Result<Frame> {
        // Hand back frames captured before the request.
        while let Some(stale) = self.stream.try_pop_buffer() {
            self.stream.push_buffer(stale);
        }
        let deadline = Instant::now() + self.frame_timeout;
        let mut arrivals = 0u32;
        let mut failures = Vec::new();
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(DriverError::Timeout(self.frame_timeout));
            }
            let Some(buffer) = self.stream.timeout_pop_buffer(left.as_micros() as u64) else {
                return Err(DriverError::Timeout(self.frame_timeout));
            };
            arrivals += 1;
            let status = buffer.status();
            if status != BufferStatus::Success {
                self.stream.push_buffer(buffer);
                failures.push(format!("{status:?}"));
                if failures.len() >= 10 {
                    return Err(DriverError::Connection(format!(
                        "{}: 10 incomplete frames in a row ({})",
                        self.device_id,
                        failures.join(", ")
                    )));
                }
                continue;
            }
            if arrivals == 1 {
                self.stream.push_buffer(buffer);
                continue;
            }
            let frame = self.to_frame(&buffer);
            self.stream.push_buffer(buffer);
            return frame;
        }
    }

    fn to_frame(&self, buffer: &Buffer) -> Result<Frame> {
        let (w, h) = (buffer.image_width(), buffer.image_height());
        let (width, height) = (w.max(0) as u32, h.max(0) as u32);
        if (width, height) != (self.width, self.height) {
            return Err(DriverError::Refused(format!(
                "{}: delivered {width}x{height}, configured {}x{}",
                self.device_id, self.width, self.height
            )));
        }
        let code = buffer.image_pixel_format().raw();
        let format = PixelFormat::from_pfnc(code).ok_or_else(|| {
            DriverError::Refused(format!(
                "{}: delivered pixel format 0x{code:08x}, configured {}",
                self.device_id, self.pixel_format
            ))
        })?;
        let rgb = raw_to_rgb(&buffer.image_data(), width, height, format)
            .map_err(|e| DriverError::Backend(Box::new(e)))?;
        let ns = buffer.system_timestamp();
        let captured_at = if ns > 0 {
            UNIX_EPOCH + Duration::from_nanos(ns)
        } else {
            SystemTime::now()
        };
        Ok(Frame {
            width,
            height,
            rgb,
            captured_at,
            sequence: buffer.frame_id(),
        })
    }
}

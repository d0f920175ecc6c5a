//! `[camera] kind = "ros2"`: colour frames from a `sensor_msgs/Image` topic, intrinsics from
//! its `sensor_msgs/CameraInfo`. A thread keeps the newest image; a grab waits for one exposed
//! after the grab began (its header stamp, which camera drivers set to the exposure time; a
//! zero stamp counts as the time it arrived), so a frame never predates the arm's arrival.
//! The camera driver and easyhec must share a clock, as ROS 2 nodes on one machine do.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use async_trait::async_trait;
use ros2_client::qos::History;
use ros2_client::{Context, MessageTypeName, Node, QosProfile, Subscription};

use super::msgs::{CameraInfo, Image};
use super::GraphPlace;
use crate::{Camera, DriverError, Frame, Intrinsics, Result};

/// How often the thread drains the readers, and a grab checks for a fresh image.
const POLL: Duration = Duration::from_millis(2);

/// What the ROS 2 camera needs; the cell config's `[camera]` table fills it.
#[derive(Clone, Debug)]
pub struct Ros2CameraOptions {
    /// Domain, namespace and node name.
    pub place: GraphPlace,
    /// `sensor_msgs/Image` topic.
    pub image_topic: String,
    /// `sensor_msgs/CameraInfo` topic.
    pub camera_info_topic: String,
    /// Longest wait for the first CameraInfo when opening.
    pub connect_timeout: Duration,
    /// Longest wait for a fresh image in a grab.
    pub frame_timeout: Duration,
}

struct Latest {
    image: Option<(Image, SystemTime)>,
    info: Option<CameraInfo>,
}

/// The ROS 2 camera.
pub struct Ros2Camera {
    options: Ros2CameraOptions,
    intrinsics: Intrinsics,
    latest: Arc<Mutex<Latest>>,
    sequence: Mutex<u64>,
    stop: Arc<AtomicBool>,
    _graph: Mutex<(Context, Node)>,
}

impl Ros2Camera {
    /// Joins the graph, subscribes, and waits (blocking) for the first CameraInfo, whose
    /// intrinsics every frame must then match.
    pub fn open(options: Ros2CameraOptions) -> Result<Self> {
        let (context, mut node) = super::join(&options.place)?;
        let image: Subscription<Image> =
            subscribe(&mut node, &options, &options.image_topic, "Image")?;
        let info: Subscription<CameraInfo> = subscribe(
            &mut node,
            &options,
            &options.camera_info_topic,
            "CameraInfo",
        )?;
        let latest = Arc::new(Mutex::new(Latest {
            image: None,
            info: None,
        }));
        let stop = Arc::new(AtomicBool::new(false));
        let (l, s) = (latest.clone(), stop.clone());
        std::thread::Builder::new()
            .name("easyhec-ros2-camera".into())
            .spawn(move || follow(image, info, l, s))
            .map_err(|e| DriverError::Connection(format!("starting the camera thread: {e}")))?;
        let opened = wait_for_info(&latest, &options)
            .and_then(|info| intrinsics_of(&info, &options.camera_info_topic));
        let intrinsics = match opened {
            Ok(k) => k,
            Err(e) => {
                stop.store(true, Ordering::Relaxed);
                return Err(e);
            }
        };
        Ok(Self {
            options,
            intrinsics,
            latest,
            sequence: Mutex::new(0),
            stop,
            _graph: Mutex::new((context, node)),
        })
    }
}

impl Drop for Ros2Camera {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

fn subscribe<M: 'static + serde::de::DeserializeOwned>(
    node: &mut Node,
    o: &Ros2CameraOptions,
    topic: &str,
    kind: &str,
) -> Result<Subscription<M>> {
    // Best effort matches every writer (camera drivers publish images best effort or reliable).
    let qos = QosProfile::subscription_default()
        .reliability_best_effort()
        .history(History::KeepLast { depth: 2 });
    let t = node
        .create_topic(
            &super::topic(&o.place.namespace, topic)?,
            MessageTypeName::new("sensor_msgs", kind),
            &qos,
        )
        .map_err(|e| DriverError::Connection(format!("creating {topic}: {e}")))?;
    node.create_subscription(&t, None)
        .map_err(|e| DriverError::Connection(format!("subscribing to {topic}: {e}")))
}

fn follow(
    image: Subscription<Image>,
    info: Subscription<CameraInfo>,
    latest: Arc<Mutex<Latest>>,
    stop: Arc<AtomicBool>,
) {
    while !stop.load(Ordering::Relaxed) {
        while let Ok(Some((m, _))) = info.take() {
            latest.lock().unwrap_or_else(|p| p.into_inner()).info = Some(m);
        }
        while let Ok(Some((m, _))) = image.take() {
            let exposed = stamp_of(&m).unwrap_or_else(SystemTime::now);
            latest.lock().unwrap_or_else(|p| p.into_inner()).image = Some((m, exposed));
        }
        std::thread::sleep(POLL);
    }
}

/// The image's header stamp, `None` when the driver leaves it zero.
fn stamp_of(m: &Image) -> Option<SystemTime> {
    let t = &m.header.stamp;
    if t.sec <= 0 && t.nanosec == 0 {
        return None;
    }
    let since = Duration::new(u64::try_from(t.sec).ok()?, t.nanosec.min(999_999_999));
    SystemTime::UNIX_EPOCH.checked_add(since)
}

fn wait_for_info(latest: &Mutex<Latest>, o: &Ros2CameraOptions) -> Result<CameraInfo> {
    let deadline = Instant::now() + o.connect_timeout;
    loop {
        if let Some(info) = latest
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .info
            .clone()
        {
            return Ok(info);
        }
        if Instant::now() >= deadline {
            return Err(DriverError::Connection(format!(
                "no sensor_msgs/CameraInfo on {} within {:.1} s",
                o.camera_info_topic,
                o.connect_timeout.as_secs_f64()
            )));
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// The intrinsics a CameraInfo holds, refused when easyhec's one camera model (pinhole with
/// `plumb_bob`) cannot carry them exactly.
pub fn intrinsics_of(info: &CameraInfo, topic: &str) -> Result<Intrinsics> {
    let refuse = |what: String| Err(DriverError::Refused(format!("{topic}: {what}")));
    if info.binning_x > 1 || info.binning_y > 1 || info.roi.width != 0 || info.roi.height != 0 {
        return refuse(
            "binning or a region of interest is set; allowed: the full, unbinned image".into(),
        );
    }
    let k = &info.k;
    let distortion = match (info.distortion_model.as_str(), info.d.as_slice()) {
        (_, d) if d.iter().all(|v| *v == 0.0) => None,
        ("plumb_bob", [k1, k2, p1, p2, k3]) => Some([*k1, *k2, *p1, *p2, *k3]),
        ("rational_polynomial", [k1, k2, p1, p2, k3, rest @ ..]) if rest.iter().all(|v| *v == 0.0) => {
            Some([*k1, *k2, *p1, *p2, *k3])
        }
        (model, d) => {
            return refuse(format!(
                "distortion model {model:?} with {} coefficients; allowed: plumb_bob (5), or rational_polynomial whose k4..k6 are 0",
                d.len()
            ))
        }
    };
    if k[1] != 0.0 || k[3] != 0.0 || k[6] != 0.0 || k[7] != 0.0 || k[8] != 1.0 {
        return refuse(format!(
            "camera matrix k = {k:?}; allowed: [fx, 0, cx, 0, fy, cy, 0, 0, 1]"
        ));
    }
    let intrinsics = Intrinsics {
        width: info.width,
        height: info.height,
        fx: k[0],
        fy: k[4],
        cx: k[2],
        cy: k[5],
        distortion,
    };
    if let Some((field, allowed)) = intrinsics.range_problem() {
        return refuse(format!("{field} {allowed}"));
    }
    Ok(intrinsics)
}

/// Row-major RGB8 from an image in one of the encodings cameras publish.
pub fn rgb_of(m: &Image) -> std::result::Result<Vec<u8>, String> {
    let (w, h) = (m.width as usize, m.height as usize);
    let bytes_per_pixel = match m.encoding.as_str() {
        "rgb8" | "bgr8" => 3,
        "mono8" => 1,
        "yuv422" | "uyvy" | "yuv422_yuy2" | "yuyv" => 2,
        other => {
            return Err(format!(
                "encoding {other:?}; allowed: rgb8, bgr8, mono8, yuv422 (UYVY), yuv422_yuy2 (YUYV)"
            ))
        }
    };
    let step = m.step as usize;
    if step < w * bytes_per_pixel || m.data.len() < step * h || (bytes_per_pixel == 2 && w % 2 == 1)
    {
        return Err(format!(
            "{}x{} {} with step {} and {} bytes: the rows do not fit",
            w,
            h,
            m.encoding,
            m.step,
            m.data.len()
        ));
    }
    let mut rgb = Vec::with_capacity(w * h * 3);
    for row in m.data.chunks(step).take(h) {
        match m.encoding.as_str() {
            "rgb8" => rgb.extend_from_slice(&row[..w * 3]),
            "bgr8" => row[..w * 3]
                .chunks(3)
                .for_each(|p| rgb.extend([p[2], p[1], p[0]])),
            "mono8" => row[..w].iter().for_each(|v| rgb.extend([*v, *v, *v])),
            "yuv422" | "uyvy" => row[..w * 2]
                .chunks(4)
                .for_each(|q| push_yuv_pair(&mut rgb, q[1], q[3], q[0], q[2])),
            _ => row[..w * 2]
                .chunks(4)
                .for_each(|q| push_yuv_pair(&mut rgb, q[0], q[2], q[1], q[3])),
        }
    }
    Ok(rgb)
}

/// Two pixels sharing chroma, BT.601 limited range (what UVC and most drivers send).
fn push_yuv_pair(rgb: &mut Vec<u8>, y0: u8, y1: u8, u: u8, v: u8) {
    for y in [y0, y1] {
        let c = 1.164 * (f64::from(y) - 16.0);
        let (d, e) = (f64::from(u) - 128.0, f64::from(v) - 128.0);
        let clamp = |x: f64| x.round().clamp(0.0, 255.0) as u8;
        rgb.extend([
            clamp(c + 1.596 * e),
            clamp(c - 0.392 * d - 0.813 * e),
            clamp(c + 2.017 * d),
        ]);
    }
}

#[async_trait]
impl Camera for Ros2Camera {
    fn intrinsics(&self) -> &Intrinsics {
        &self.intrinsics
    }

    async fn grab(&self) -> Result<Frame> {
        let (asked, asked_at) = (Instant::now(), SystemTime::now());
        let topic = &self.options.image_topic;
        let (image, exposed) = loop {
            let fresh = {
                let l = self.latest.lock().unwrap_or_else(|p| p.into_inner());
                l.image
                    .as_ref()
                    .filter(|(_, exposed)| *exposed >= asked_at)
                    .map(|(m, exposed)| (m.clone(), *exposed))
            };
            if let Some(found) = fresh {
                break found;
            }
            if asked.elapsed() > self.options.frame_timeout {
                return Err(DriverError::Connection(format!(
                    "no image on {topic} within {:.1} s",
                    self.options.frame_timeout.as_secs_f64()
                )));
            }
            tokio::time::sleep(POLL).await;
        };
        let k = &self.intrinsics;
        if image.width != k.width || image.height != k.height {
            return Err(DriverError::Refused(format!(
                "{topic}: {}x{} images, but {} calibrates {}x{}",
                image.width, image.height, self.options.camera_info_topic, k.width, k.height
            )));
        }
        let rgb = rgb_of(&image).map_err(|m| DriverError::Refused(format!("{topic}: {m}")))?;
        let mut sequence = self.sequence.lock().unwrap_or_else(|p| p.into_inner());
        *sequence += 1;
        Ok(Frame {
            width: image.width,
            height: image.height,
            rgb,
            captured_at: exposed,
            sequence: *sequence,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ros2::msgs::{Header, RegionOfInterest, Time};

    fn info(k: [f64; 9], model: &str, d: Vec<f64>) -> CameraInfo {
        CameraInfo {
            header: Header {
                stamp: Time { sec: 0, nanosec: 0 },
                frame_id: String::new(),
            },
            height: 480,
            width: 640,
            distortion_model: model.into(),
            d,
            k,
            r: [0.0; 9],
            p: [0.0; 12],
            binning_x: 0,
            binning_y: 0,
            roi: RegionOfInterest {
                x_offset: 0,
                y_offset: 0,
                height: 0,
                width: 0,
                do_rectify: false,
            },
        }
    }

    #[test]
    fn camera_info_gives_the_intrinsics_or_a_reason() {
        let k = [600.0, 0.0, 320.0, 0.0, 601.0, 240.0, 0.0, 0.0, 1.0];
        let got = intrinsics_of(
            &info(k, "plumb_bob", vec![0.1, -0.2, 0.001, 0.002, 0.03]),
            "t",
        )
        .unwrap();
        assert_eq!(
            (got.fx, got.fy, got.cx, got.cy),
            (600.0, 601.0, 320.0, 240.0)
        );
        assert_eq!(got.distortion, Some([0.1, -0.2, 0.001, 0.002, 0.03]));
        let rational = vec![0.1, -0.2, 0.001, 0.002, 0.03, 0.0, 0.0, 0.0];
        assert!(intrinsics_of(&info(k, "rational_polynomial", rational), "t").is_ok());
        assert_eq!(
            intrinsics_of(&info(k, "", vec![]), "t").unwrap().distortion,
            None
        );
        let transposed = [600.0, 0.0, 0.0, 0.0, 601.0, 0.0, 320.0, 240.0, 1.0];
        assert!(intrinsics_of(&info(transposed, "plumb_bob", vec![]), "t").is_err());
        let fisheye = vec![0.1, 0.2, 0.3, 0.4];
        let e = intrinsics_of(&info(k, "equidistant", fisheye), "t").unwrap_err();
        assert!(e.to_string().contains("equidistant"), "{e}");
    }

    fn image(encoding: &str, width: u32, step: u32, data: Vec<u8>) -> Image {
        Image {
            header: Header {
                stamp: Time { sec: 0, nanosec: 0 },
                frame_id: String::new(),
            },
            height: 1,
            width,
            encoding: encoding.into(),
            is_bigendian: 0,
            step,
            data,
        }
    }

    #[test]
    fn every_encoding_becomes_the_same_rgb() {
        let rgb = rgb_of(&image("rgb8", 2, 8, vec![1, 2, 3, 4, 5, 6, 0, 0])).unwrap();
        assert_eq!(rgb, [1, 2, 3, 4, 5, 6], "padding after the row is skipped");
        let bgr = rgb_of(&image("bgr8", 2, 6, vec![3, 2, 1, 6, 5, 4])).unwrap();
        assert_eq!(bgr, [1, 2, 3, 4, 5, 6]);
        assert_eq!(rgb_of(&image("mono8", 1, 1, vec![9])).unwrap(), [9, 9, 9]);
        // Grey in UYVY and YUYV: Y = 126, U = V = 128 gives 128 in every channel.
        let uyvy = rgb_of(&image("yuv422", 2, 4, vec![128, 126, 128, 126])).unwrap();
        let yuyv = rgb_of(&image("yuv422_yuy2", 2, 4, vec![126, 128, 126, 128])).unwrap();
        assert_eq!(uyvy, yuyv);
        assert!(
            uyvy.iter().all(|v| (*v as i32 - 128).abs() <= 1),
            "{uyvy:?}"
        );
        assert!(
            rgb_of(&image("rgb8", 2, 5, vec![0; 5])).is_err(),
            "a short row"
        );
        assert!(rgb_of(&image("bayer_rggb8", 2, 2, vec![0; 2])).is_err());
    }
}

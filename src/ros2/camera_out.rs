//! Publishing frames as a ROS 2 camera driver does: `sensor_msgs/Image` (rgb8) and the
//! matching `sensor_msgs/CameraInfo` (plumb_bob), both stamped with the exposure time.

use std::time::SystemTime;

use easyhec_drivers::{Frame, Intrinsics};
use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{Context, MessageTypeName, Node, Publisher, QosProfile};

use super::msgs::{CameraInfo, Header, Image, RegionOfInterest, Time};
use super::{join, GraphPlace};
use crate::error::{Error, Result};

/// The two writers, on a node of their own.
pub struct CameraPublisher {
    image: Publisher<Image>,
    info: Publisher<CameraInfo>,
    frame_id: String,
    _graph: (Context, Node),
}

impl CameraPublisher {
    /// Joins the graph and makes the writers (reliable, volatile, depth 2).
    pub fn new(
        place: &GraphPlace,
        image_topic: &str,
        info_topic: &str,
        frame_id: &str,
    ) -> Result<Self> {
        let (context, mut node) = join(place)?;
        let qos = QosProfile::publisher_default()
            .reliability_reliable(WhenFull::DEFAULT)
            .durability(Durability::Volatile)
            .history(History::KeepLast { depth: 2 });
        let writer = |topic: &str, kind: &str| {
            let name = easyhec_drivers::ros2::topic(&place.namespace, topic)
                .map_err(|e| Error::Usage(e.to_string()))?;
            node.create_topic(&name, MessageTypeName::new("sensor_msgs", kind), &qos)
                .map_err(|e| Error::Ros2(format!("creating {topic}: {e}")))
        };
        let (image_t, info_t) = (
            writer(image_topic, "Image")?,
            writer(info_topic, "CameraInfo")?,
        );
        let image = node
            .create_publisher(&image_t, None)
            .map_err(|e| Error::Ros2(format!("publishing on {image_topic}: {e}")))?;
        let info = node
            .create_publisher(&info_t, None)
            .map_err(|e| Error::Ros2(format!("publishing on {info_topic}: {e}")))?;
        Ok(Self {
            image,
            info,
            frame_id: frame_id.to_string(),
            _graph: (context, node),
        })
    }

    /// Sends one frame and its CameraInfo.
    pub fn send(&self, frame: &Frame, k: &Intrinsics, exposed: SystemTime) -> Result<()> {
        let since = exposed
            .duration_since(SystemTime::UNIX_EPOCH)
            .unwrap_or_default();
        let header = Header {
            stamp: Time {
                sec: i32::try_from(since.as_secs()).unwrap_or(i32::MAX),
                nanosec: since.subsec_nanos(),
            },
            frame_id: self.frame_id.clone(),
        };
        let info = CameraInfo {
            header: header.clone(),
            height: k.height,
            width: k.width,
            distortion_model: "plumb_bob".into(),
            d: k.distortion.map_or_else(|| vec![0.0; 5], |d| d.to_vec()),
            k: [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
            r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: [
                k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0,
            ],
            binning_x: 0,
            binning_y: 0,
            roi: RegionOfInterest {
                x_offset: 0,
                y_offset: 0,
                height: 0,
                width: 0,
                do_rectify: false,
            },
        };
        self.info
            .publish(info)
            .map_err(|e| Error::Ros2(format!("publishing CameraInfo: {e}")))?;
        let image = Image {
            header,
            height: frame.height,
            width: frame.width,
            encoding: "rgb8".into(),
            is_bigendian: 0,
            step: frame.width * 3,
            data: frame.rgb.clone(),
        };
        self.image
            .publish(image)
            .map_err(|e| Error::Ros2(format!("publishing Image: {e}")))
    }
}

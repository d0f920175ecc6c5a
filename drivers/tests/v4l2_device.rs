//! `V4l2Camera` where no webcam exists (CI): a missing path and an unknown name are connection
//! errors that say what is there. Frame conversion is tested in `drivers/src/v4l2/mod.rs`.
//! Needs the `v4l2` feature.
#![cfg(feature = "v4l2")]

use std::path::PathBuf;

use easyhec_drivers::v4l2::{list_devices, V4l2Camera, V4l2Config, V4l2PixelFormat};
use easyhec_drivers::{DriverError, Intrinsics};

fn config(device: &str) -> V4l2Config {
    V4l2Config::new(
        device.to_string(),
        640,
        480,
        V4l2PixelFormat::Yuyv,
        Intrinsics {
            width: 640,
            height: 480,
            fx: 600.0,
            fy: 600.0,
            cx: 320.0,
            cy: 240.0,
            distortion: None,
        },
        PathBuf::from("cam.yaml"),
    )
}

#[test]
fn missing_device_path_is_a_connection_error() {
    match V4l2Camera::open(config("/dev/video-easyhec-missing")) {
        Err(DriverError::Connection(m)) => {
            assert!(
                m.starts_with("/dev/video-easyhec-missing: cannot open"),
                "{m}"
            )
        }
        other => panic!("expected a connection error, got {other:?}"),
    }
}

#[test]
fn unknown_device_name_lists_the_capture_devices() {
    let capture: Vec<String> = list_devices()
        .into_iter()
        .filter(|d| d.can_capture)
        .map(|d| d.path.display().to_string())
        .collect();
    match V4l2Camera::open(config("No Such Webcam 9000")) {
        Err(DriverError::Connection(m)) => {
            assert!(
                m.contains("no capture device named \"No Such Webcam 9000\""),
                "{m}"
            );
            for path in &capture {
                assert!(m.contains(path.as_str()), "{m} lacks {path}");
            }
            if capture.is_empty() {
                assert!(m.ends_with("capture devices: none"), "{m}");
            }
        }
        other => panic!("expected a connection error, got {other:?}"),
    }
}

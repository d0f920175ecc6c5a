//! `AravisCamera` against Aravis's in-process Fake camera (`Fake_1`, docs/protocols.md §5.3): a
//! 512×512 sensor region drawing a diagonal ramp at 25 fps. Needs the `aravis` feature
//! (libaravis 0.8).
#![cfg(feature = "aravis")]

use std::path::PathBuf;
use std::time::{Duration, SystemTime};

use easyhec_drivers::aravis::{AravisCamera, AravisConfig, PixelFormat};
use easyhec_drivers::intrinsics::IntrinsicsError;
use easyhec_drivers::{Camera, DriverError, ErrorKind, Intrinsics};

fn intrinsics(width: u32, height: u32) -> Intrinsics {
    Intrinsics {
        width,
        height,
        fx: 500.0,
        fy: 500.0,
        cx: f64::from(width) / 2.0,
        cy: f64::from(height) / 2.0,
        distortion: None,
    }
}

fn fake(format: &str, width: u32, height: u32) -> AravisConfig {
    AravisConfig::new(
        Some("Fake_1".to_string()),
        format.parse().unwrap(),
        intrinsics(width, height),
        PathBuf::from("fake.yaml"),
    )
}

/// Distinct RGB triples in a frame (the ramp has many; a blank or constant frame has one).
fn distinct_colours(rgb: &[u8]) -> usize {
    let mut seen: Vec<[u8; 3]> = rgb.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect();
    seen.sort_unstable();
    seen.dedup();
    seen.len()
}

// One camera at a time: the fake device is a single process-wide object.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fake_camera_grabs_mono_and_bayer_frames_and_reports_typed_errors() {
    // Mono8 with fixed exposure and gain.
    let mut cfg = fake("Mono8", 512, 512);
    cfg.exposure_us = Some(5000.0);
    cfg.gain_db = Some(1.0);
    let before = SystemTime::now();
    let camera = AravisCamera::open(cfg).expect("open Fake_1");
    assert_eq!(camera.device_id(), "Fake_1");
    assert_eq!(camera.intrinsics().width, 512);
    for _ in 0..2 {
        let frame = camera.grab().await.expect("grab");
        assert_eq!((frame.width, frame.height), (512, 512));
        assert_eq!(frame.rgb.len(), 512 * 512 * 3);
        // Mono is replicated: R = G = B everywhere.
        assert!(frame
            .rgb
            .chunks_exact(3)
            .all(|p| p[0] == p[1] && p[1] == p[2]));
        assert!(distinct_colours(&frame.rgb) > 16, "the fake draws a ramp");
        assert!(frame.captured_at >= before);
    }
    drop(camera);

    // BayerRG8, demosaiced to colour.
    let camera = AravisCamera::open(fake("BayerRG8", 512, 512)).expect("open Fake_1 Bayer");
    let frame = camera.grab().await.expect("grab Bayer");
    assert_eq!(
        (frame.width, frame.height, frame.rgb.len()),
        (512, 512, 512 * 512 * 3)
    );
    assert!(distinct_colours(&frame.rgb) > 16);
    drop(camera);

    // A grab that cannot finish in time is a Timeout (two frame periods are 80 ms).
    let mut cfg = fake("Mono8", 512, 512);
    cfg.frame_timeout = Duration::from_millis(5);
    let camera = AravisCamera::open(cfg).expect("open Fake_1");
    match camera.grab().await {
        Err(e @ DriverError::Timeout(_)) => assert_eq!(e.kind(), ErrorKind::Connection),
        other => panic!("expected a timeout, got {other:?}"),
    }
    drop(camera);

    // Intrinsics calibrated at another size are refused before streaming.
    match AravisCamera::open(fake("Mono8", 640, 480)) {
        Err(DriverError::Backend(e)) => {
            let e = e
                .downcast_ref::<IntrinsicsError>()
                .expect("an IntrinsicsError");
            assert_eq!(e.field, "image_width");
            assert!(
                e.message.contains("640x480") && e.message.contains("512x512"),
                "{e}"
            );
        }
        other => panic!("expected a size mismatch, got {other:?}"),
    }

    // A camera that is not there is a connection error naming it.
    match AravisCamera::open(AravisConfig::new(
        Some("Fake_1-no-such-camera".to_string()),
        PixelFormat::Mono8,
        intrinsics(512, 512),
        PathBuf::from("fake.yaml"),
    )) {
        Err(DriverError::Connection(m)) => assert!(m.contains("Fake_1-no-such-camera"), "{m}"),
        other => panic!("expected a connection error, got {other:?}"),
    }
}

//! `[camera] kind = "v4l2" | "aravis"` cells: the calibration file is read and checked against
//! the configured stream size when the cell is built (a mismatch names the file and field);
//! ROS and OpenCV calibration files with the same numbers give the same intrinsics; the
//! shipped template parses; without a camera's feature the cell says how to rebuild; with it,
//! a camera that is not there is one line naming it, and Aravis's Fake camera builds a cell.

mod common;

use std::path::{Path, PathBuf};

use easyhec::cell::Cell;
use easyhec::config::{AravisSettings, V4l2Settings};

use easyhec::config::{read_config, CameraCalibration, CameraConfig};
use easyhec_drivers::intrinsics::load_intrinsics;
use easyhec_drivers::Intrinsics;

fn fixture(name: &str) -> PathBuf {
    common::repo_root().join("tests/fixtures").join(name)
}

/// A cell on the shipped xArm6 URDF with a simulated arm and `camera` as its camera table.
fn cell_text(camera: &str) -> String {
    format!(
        r#"[robot]
urdf = "{}"

[arm]
kind = "sim"
start = [0.0, -0.35, -0.6, 0.0, 0.95, 0.0]

{camera}

[segmenter]
kind = "sim-truth"
"#,
        common::repo_root()
            .join("robots/xarm6/robot.urdf")
            .display()
    )
}

fn v4l2_table(width: u32, height: u32, intrinsics: &Path) -> String {
    format!(
        "[camera]\nkind = \"v4l2\"\ndevice = \"/dev/video-easyhec-missing\"\nwidth = {width}\nheight = {height}\npixel_format = \"YUYV\"\nintrinsics = \"{}\"\n",
        intrinsics.display()
    )
}

fn open_error(dir: &Path, text: &str) -> String {
    let p = dir.join("cell.toml");
    std::fs::write(&p, text).unwrap();
    match Cell::open(&p) {
        Ok(_) => panic!("accepted:\n{text}"),
        Err(e) => e.to_string(),
    }
}

fn expected() -> Intrinsics {
    Intrinsics {
        width: 640,
        height: 480,
        fx: 612.25,
        fy: 611.75,
        cx: 318.5,
        cy: 242.125,
        distortion: Some([0.0875, -0.1625, 0.00125, -0.00075, 0.0625]),
    }
}

#[test]
fn ros_and_opencv_files_give_the_same_intrinsics() {
    let ros = load_intrinsics(&fixture("webcam_ros.yaml")).unwrap();
    let opencv = load_intrinsics(&fixture("webcam_opencv.yaml")).unwrap();
    assert_eq!(ros, expected());
    assert_eq!(opencv, expected());
    // Through the cell config, relative to the config's folder.
    let config = common::repo_root().join("tests/cell.toml");
    for name in ["webcam_ros.yaml", "webcam_opencv.yaml"] {
        let camera: CameraConfig = toml::from_str(
            &v4l2_table(640, 480, &Path::new("fixtures").join(name)).replace("[camera]\n", ""),
        )
        .unwrap();
        assert_eq!(
            camera.camera(),
            None,
            "a hardware camera has no inline model"
        );
        assert_eq!(
            camera.calibration(&config).unwrap(),
            Some(CameraCalibration {
                intrinsics: expected(),
                file: common::repo_root().join("tests/fixtures").join(name),
            })
        );
    }
}

#[test]
fn a_size_mismatch_fails_the_build_naming_the_file_and_field() {
    let dir = tempfile::tempdir().unwrap();
    for (w, h, field) in [(1280, 720, "image_width"), (640, 360, "image_height")] {
        for name in ["webcam_ros.yaml", "webcam_opencv.yaml"] {
            let e = open_error(dir.path(), &cell_text(&v4l2_table(w, h, &fixture(name))));
            assert!(
                e.starts_with(&format!("{}: {field}: ", fixture(name).display())),
                "{e}"
            );
            assert!(
                e.contains("640x480") && e.contains(&format!("{w}x{h}")) && e.contains("cell.toml"),
                "{e}"
            );
            assert!(!e.contains('\n'), "{e}");
        }
    }
}

#[test]
fn bad_camera_tables_get_one_line_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let ros = fixture("webcam_ros.yaml");
    let good = v4l2_table(640, 480, &ros);
    let aravis = format!(
        "[camera]\nkind = \"aravis\"\ndevice_id = \"Fake_1\"\npixel_format = \"Mono8\"\nintrinsics = \"{}\"\n",
        ros.display()
    );
    let cases = [
        (
            good.replace("\"YUYV\"", "\"RGB3\""),
            "cell.toml: camera.pixel_format: \"RGB3\"",
        ),
        (
            good.replace("height = 480\n", "height = 480\nexposure_us = 0\n"),
            "cell.toml: camera.exposure_us",
        ),
        (
            good.replace("height = 480\n", "height = 480\nframe_timeout_s = -1.0\n"),
            "cell.toml: camera.frame_timeout_s",
        ),
        (
            good.replace("height = 480\n", "height = 480\nfps = 30\n"),
            "cell.toml: line",
        ),
        (
            good.replace("webcam_ros.yaml", "no_such.yaml"),
            "no_such.yaml: intrinsics: cannot read",
        ),
        (
            aravis.replace("Mono8", "Mono16"),
            "cell.toml: camera.pixel_format: \"Mono16\"",
        ),
        (
            aravis.replace("Mono8\"\n", "Mono8\"\ngain_db = nan\n"),
            "cell.toml: camera.gain_db",
        ),
        (
            aravis.replace("Mono8\"\n", "Mono8\"\nexposure_us = -5.0\n"),
            "cell.toml: camera.exposure_us",
        ),
    ];
    for (i, (table, needle)) in cases.iter().enumerate() {
        assert_ne!(table, &good, "case {i} changed nothing");
        let e = open_error(dir.path(), &cell_text(table));
        assert!(e.contains(needle) && !e.contains('\n'), "case {i}: {e}");
    }
}

#[test]
fn v4l2_cell_without_the_feature_says_how_to_rebuild() {
    let dir = tempfile::tempdir().unwrap();
    let e = open_error(
        dir.path(),
        &cell_text(&v4l2_table(640, 480, &fixture("webcam_opencv.yaml"))),
    );
    if cfg!(feature = "v4l2") {
        // The driver is built: the missing device is reported instead.
        assert!(
            e.contains("cell.toml: camera: ") && e.contains("/dev/video-easyhec-missing"),
            "{e}"
        );
    } else {
        assert!(
            e.contains("cell.toml: camera.kind: ") && e.ends_with("rebuild with --features v4l2"),
            "{e}"
        );
    }
}

#[test]
fn aravis_cell_without_the_feature_says_how_to_rebuild_and_with_it_opens_the_fake() {
    let dir = tempfile::tempdir().unwrap();
    // Aravis's Fake camera streams 512x512; our calibration file says so.
    let calib = dir.path().join("fake.yaml");
    std::fs::write(
        &calib,
        std::fs::read_to_string(fixture("webcam_ros.yaml"))
            .unwrap()
            .replace("image_width: 640", "image_width: 512")
            .replace("image_height: 480", "image_height: 512"),
    )
    .unwrap();
    let table = "[camera]\nkind = \"aravis\"\ndevice_id = \"Fake_1\"\npixel_format = \"BayerRG8\"\nexposure_us = 4000.0\nintrinsics = \"fake.yaml\"\n";
    let p = dir.path().join("cell.toml");
    std::fs::write(&p, cell_text(table)).unwrap();
    match (cfg!(feature = "aravis"), Cell::open(&p)) {
        (true, Ok(cell)) => {
            assert_eq!(cell.units[0].device.intrinsics().width, 512);
            assert_eq!(cell.units[0].device.intrinsics().fx, 612.25);
            let rt = tokio::runtime::Runtime::new().unwrap();
            let frame = rt.block_on(cell.units[0].device.grab()).unwrap();
            assert_eq!((frame.width, frame.height), (512, 512));
            assert!(
                frame.rgb.iter().any(|&v| v != frame.rgb[0]),
                "a constant frame"
            );
        }
        (false, Err(e)) => {
            let e = e.to_string();
            assert!(
                e.contains("cell.toml: camera.kind: ")
                    && e.ends_with("rebuild with --features aravis"),
                "{e}"
            );
        }
        (true, Err(e)) => panic!("the Fake camera cell failed: {e}"),
        (false, Ok(_)) => panic!("built without the driver, yet the cell opened"),
    }
}

#[test]
fn shipped_camera_template_parses_with_either_table() {
    let path = common::repo_root().join("config/webcam-xarm6.toml.example");
    let cfg = read_config(&path).unwrap();
    let CameraConfig::V4l2(V4l2Settings {
        device,
        width,
        height,
        pixel_format,
        exposure_us,
        ..
    }) = cfg.camera.first()
    else {
        panic!("{:?}", cfg.camera)
    };
    assert_eq!(
        (
            device.as_str(),
            *width,
            *height,
            pixel_format.as_str(),
            *exposure_us
        ),
        ("HD Pro Webcam C920", 640, 480, "MJPG", Some(8000))
    );
    // Swap in the commented Aravis table.
    let text = std::fs::read_to_string(&path).unwrap();
    let start = text.find("[camera]\nkind = \"v4l2\"").unwrap();
    let end = text.find("# Or a GigE").unwrap();
    let aravis: String = text[end..]
        .lines()
        .skip_while(|l| !l.starts_with("# [camera]"))
        .take_while(|l| l.starts_with("# "))
        .map(|l| format!("{}\n", &l[2..]))
        .collect();
    let swapped = format!(
        "{}{aravis}\n[segmenter]\nkind = \"sim-truth\"\n",
        &text[..start]
    );
    let p = tempfile::tempdir().unwrap();
    let copy = p.path().join("gige.toml");
    std::fs::write(&copy, swapped).unwrap();
    let cfg = read_config(&copy).unwrap();
    let CameraConfig::Aravis(AravisSettings {
        device_id,
        pixel_format,
        gain_db,
        ..
    }) = cfg.camera.first()
    else {
        panic!("{:?}", cfg.camera)
    };
    assert_eq!(device_id.as_deref(), Some("Basler-acA1300-60gc-21234567"));
    assert_eq!((pixel_format.as_str(), *gain_db), ("BayerRG8", Some(0.0)));
}

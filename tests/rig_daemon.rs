//! The daemon over a cell of three fixed cameras (`[[camera]]`): one calibration solves every
//! camera from one motion and activates each; a bump check compares every camera; a knocked
//! camera alone is marked stale and recalibrated, warm-started from its stale pose, while the
//! other two keep their active calibrations untouched, across a restart too. A wrist camera
//! beside a fixed one is activated and checked against its own mount, and each camera's
//! downloads are what `easyhec export` writes for it.

mod common;

use std::path::{Path, PathBuf};

use common::daemon::{
    assert_refused, call, get_bytes, start, wait_final, write_shipped_config, TOKEN,
};
use easyhec::geometry::{from_rows, rotation_error_deg, translation_error_mm};
use easyhec::interop::ExportFormat;
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use serde_json::{json, Value};

/// Writes `DIR/cell.toml`: the shipped three-camera cell, four views per calibration, a
/// light planner, bump recalibration on.
fn write_rig_config(dir: &Path) -> PathBuf {
    write_shipped_config(dir, "sim-xarm6-three-cameras.toml")
}

/// `GET /api/v1/cameras`, as (camera, active entry or null) pairs.
fn cameras(base: &str) -> Vec<(String, Value)> {
    let (code, body) = call("GET", &format!("{base}/api/v1/cameras"), None);
    assert_eq!(code, 200, "{body}");
    body["cameras"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            (
                c["camera"].as_str().unwrap().to_string(),
                c["active"].clone(),
            )
        })
        .collect()
}

/// Every camera's download in every format is byte for byte what `easyhec export` writes
/// for that camera of the run's result.json; the camera must be named, and be one of the
/// cell's.
fn assert_exports_match_the_cli(base: &str, data: &Path, id: &str, names: &[&str]) {
    let out = data.parent().unwrap().join("exported");
    let result = data.join("runs").join(id).join("result.json");
    for kind in ExportFormat::ALL {
        let format = kind.name();
        let cli = std::process::Command::new(env!("CARGO_BIN_EXE_easyhec"))
            .args([
                "export",
                result.to_str().unwrap(),
                "--format",
                &format,
                "--out",
            ])
            .arg(&out)
            .output()
            .unwrap();
        assert!(
            cli.status.success(),
            "{}",
            String::from_utf8_lossy(&cli.stderr)
        );
        for name in names {
            let url = format!("{base}/api/v1/calibrations/{id}/export/{format}?camera={name}");
            let (code, content_type, body) = get_bytes(&url);
            assert_eq!(code, 200, "{url}: {}", String::from_utf8_lossy(&body));
            assert!(
                content_type.starts_with(kind.content_type()),
                "{url}: {content_type}"
            );
            let want = std::fs::read(out.join(kind.file_name(name))).unwrap();
            assert_eq!(body, want, "{url}");
        }
    }
    let url = format!("{base}/api/v1/calibrations/{id}/export/urdf");
    for (query, needle) in [("", "name the camera"), ("?camera=nope", "is no camera")] {
        assert_refused("GET", &format!("{url}{query}"), None, needle);
    }
}

/// An active entry's pose.
fn pose_of(active: &Value) -> Isometry3<f64> {
    let rows: [[f64; 4]; 4] =
        serde_json::from_value(active["result"]["camera_from_base"].clone()).unwrap();
    from_rows(&rows).unwrap()
}

/// Each camera's overlay of view 0 decodes at that camera's own size; the query is
/// required, and must name a camera of the cell.
fn assert_overlays_per_camera(base: &str, id: &str, sizes: &[(u32, u32)]) {
    let url = format!("{base}/api/v1/calibrations/{id}/views/0/overlay.png");
    assert_png_per_camera(base, &url, sizes);
}

/// Each camera's image from `url?camera=NAME` decodes at that camera's own size; the query
/// is required, and must name a camera of the cell.
fn assert_png_per_camera(base: &str, url: &str, sizes: &[(u32, u32)]) {
    for ((name, _), size) in cameras(base).iter().zip(sizes) {
        let (code, ctype, png) = get_bytes(&format!("{url}?camera={name}"));
        assert_eq!((code, ctype.as_str()), (200, "image/png"), "{name}");
        let img = image::load_from_memory(&png).unwrap();
        assert_eq!((img.width(), img.height()), *size, "{name}");
    }
    for (query, needle) in [
        ("", "name the camera"),
        ("?camera=nope", "is no camera of this cell"),
        ("?camera=front&camera=front", "given twice"),
        ("?view=1", "only camera=NAME"),
    ] {
        assert_refused("GET", &format!("{url}{query}"), None, needle);
    }
}

fn assert_near(name: &str, est: &Isometry3<f64>, truth: &Isometry3<f64>) {
    let (r, t) = (
        rotation_error_deg(est, truth),
        translation_error_mm(est, truth),
    );
    eprintln!("{name}: {r:.4} deg, {t:.3} mm from the truth");
    assert!(r < 0.2 && t < 1.5, "{name}: off by {r:.4} deg {t:.3} mm");
}

#[test]
fn a_knocked_camera_is_recalibrated_alone_and_the_others_keep_their_results() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_rig_config(dir.path());
    let data = dir.path().join("data");
    let d = start(&config, &data);
    let base = d.base.clone();
    let scenes: Vec<_> = d
        .daemon
        .cell()
        .cameras()
        .iter()
        .map(|c| (c.name.to_string(), c.sim.scene.clone().unwrap()))
        .collect();

    // Requests naming cameras the cell does not have are refused before anything moves.
    for bad in [
        json!({"cameras": []}),
        json!({"cameras": ["nope"]}),
        json!({"cameras": ["side", "side"]}),
    ] {
        let (code, body) = call("POST", &format!("{base}/api/v1/calibrations"), Some(&bad));
        assert_eq!(code, 400, "{bad}: {body}");
        assert!(
            body["error"].as_str().unwrap().starts_with("cameras"),
            "{body}"
        );
    }

    let (code, body) = call(
        "POST",
        &format!("{base}/api/v1/calibrations"),
        Some(&json!({"cameras": null})),
    );
    assert_eq!(code, 400, "a null list never means every camera: {body}");

    let (code, body) = call("POST", &format!("{base}/api/v1/calibrations"), None);
    assert_eq!(code, 202, "{body}");
    let first = body["id"].as_str().unwrap().to_string();
    let s = wait_final(&base, &first);
    assert_eq!(s["state"], "succeeded", "{s}");
    assert_eq!(s["cameras"], json!(["front", "side", "high"]), "{s}");
    assert_eq!(s["camera_results"].as_array().unwrap().len(), 3, "{s}");
    // A download names its camera.
    let url = format!("{base}/api/v1/calibrations/{first}/export/opencv");
    assert_refused("GET", &url, None, "name the camera");
    let (code, _) = call("GET", &format!("{base}/api/v1/calibration"), None);
    assert_eq!(
        code, 409,
        "a list of cameras has no single active calibration"
    );

    let sizes = [(640, 480), (800, 600), (512, 384)];
    assert_overlays_per_camera(&base, &first, &sizes);
    // The live preview grabs the camera named, at its own size.
    assert_png_per_camera(&base, &format!("{base}/api/v1/camera/preview.png"), &sizes);

    let before = cameras(&base);
    for ((name, active), (_, scene)) in before.iter().zip(&scenes) {
        assert_eq!(
            active["id"].as_str(),
            Some(first.as_str()),
            "{name}: {active}"
        );
        assert_near(name, &pose_of(active), &scene.camera_from_base());
    }
    let (code, ok) = call("POST", &format!("{base}/api/v1/checks"), None);
    assert_eq!(code, 200, "{ok}");
    let checks = ok["checks"].as_array().unwrap();
    assert_eq!(checks.len(), 3, "{ok}");
    assert!(checks.iter().all(|c| c["stale"] == false), "{ok}");

    // Knock the side camera: about 1 degree and 15 mm.
    let (_, side) = &scenes[1];
    let old = side.camera_from_base();
    let knock = Isometry3::from_parts(
        Translation3::new(0.010, -0.008, 0.008),
        UnitQuaternion::from_euler_angles(0.010, -0.012, 0.006),
    );
    side.set_camera_from_base(knock * old);
    let (code, bad) = call("POST", &format!("{base}/api/v1/checks"), None);
    assert_eq!(code, 200, "{bad}");
    let checks = bad["checks"].as_array().unwrap();
    let stale: Vec<&str> = checks
        .iter()
        .filter(|c| c["stale"] == true)
        .map(|c| c["camera"].as_str().unwrap())
        .collect();
    assert_eq!(stale, ["side"], "{bad}");
    let second = checks
        .iter()
        .find(|c| c["camera"] == "side")
        .and_then(|c| c["recalibration"].as_str())
        .expect("a recalibration of the side camera");
    let others = checks.iter().filter(|c| c["camera"] != "side");
    assert!(
        others.clone().count() == 2 && others.into_iter().all(|c| c["recalibration"].is_null())
    );

    let s = wait_final(&base, second);
    assert_eq!(s["state"], "succeeded", "{s}");
    assert_eq!(s["trigger"], "bump");
    assert_eq!(s["cameras"], json!(["side"]), "{s}");
    assert_eq!(s["camera_results"].as_array().unwrap().len(), 1, "{s}");
    let run: Value = serde_json::from_str(
        &std::fs::read_to_string(data.join("runs").join(second).join("run.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(
        run["cameras"].as_array().unwrap().len(),
        1,
        "only the side camera grabbed"
    );

    let check_after = |base: &str| {
        let after = cameras(base);
        for ((name, now), (_, was)) in after.iter().zip(&before) {
            if name == "side" {
                assert_eq!(now["id"].as_str(), Some(second), "{now}");
                assert_eq!(now["stale"], false, "{now}");
                assert_near(name, &pose_of(now), &side.camera_from_base());
            } else {
                assert_eq!(now["id"], was["id"], "{name} kept its calibration");
                assert_eq!(now["result"], was["result"], "{name} kept its result");
                assert_eq!(now["stale"], false, "{name}: {now}");
            }
        }
    };
    check_after(&base);
    // A download names a camera the run calibrated: the recalibration took only `side`.
    let url = format!("{base}/api/v1/calibrations/{second}/export/urdf");
    let (code, body) = call("GET", &format!("{url}?camera=front"), None);
    assert_eq!(code, 404, "{body}");
    assert!(
        body["error"]
            .as_str()
            .unwrap()
            .contains("did not calibrate camera \"front\""),
        "{body}"
    );
    let (code, _, urdf) = get_bytes(&format!("{url}?camera=side"));
    assert_eq!(code, 200, "{}", String::from_utf8_lossy(&urdf));
    let active: Value =
        serde_json::from_str(&std::fs::read_to_string(data.join("active.json")).unwrap()).unwrap();
    assert_eq!(active["format"], "easyhec-daemon-active/2");

    // The per-camera state reads back after a restart.
    d.stop();
    let d = start(&config, &data);
    check_after(&d.base);
    d.stop();

    // A cell of one camera does not take this folder's per-camera calibrations as its own.
    std::fs::create_dir_all(dir.path().join("one")).unwrap();
    let single = common::daemon::write_config(&dir.path().join("one"), |_| {});
    let cell = easyhec::cell::Cell::open(&single).unwrap();
    let refused = easyhec::daemon::Daemon::open(cell, &data, TOKEN.into())
        .err()
        .expect("a single-camera daemon refuses a list's active.json")
        .to_string();
    assert!(
        refused.contains("active.json") && refused.contains("cameras") && !refused.contains('\n'),
        "{refused}"
    );
}

/// A fixed camera and a wrist camera: the calibration activates each against its own mount
/// (the wrist's result is `camera_from_link6`, which a fixed camera's check would refuse), and
/// a bump check right after compares both without finding either moved.
#[test]
fn a_wrist_camera_beside_a_fixed_one_is_activated_against_its_own_mount() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_shipped_config(dir.path(), "sim-xarm6-fixed-and-wrist.toml");
    let d = start(&config, &dir.path().join("data"));
    let base = d.base.clone();
    let truths: Vec<Isometry3<f64>> = d
        .daemon
        .cell()
        .cameras()
        .iter()
        .map(|c| c.sim.camera_from_base.unwrap())
        .collect();
    let (code, body) = call("POST", &format!("{base}/api/v1/calibrations"), None);
    assert_eq!(code, 202, "{body}");
    let id = body["id"].as_str().unwrap().to_string();
    let s = wait_final(&base, &id);
    assert_eq!(s["state"], "succeeded", "{s}");
    let active = cameras(&base);
    let names: Vec<&str> = active.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["front", "wrist"]);
    for (((name, a), truth), frame) in active.iter().zip(&truths).zip(["world", "link6"]) {
        assert_eq!(a["id"], id.as_str(), "{name}: {a}");
        assert_eq!(a["result"]["base_link"], frame, "{name}: {a}");
        assert_near(name, &pose_of(a), truth);
    }
    let (code, ok) = call("POST", &format!("{base}/api/v1/checks"), None);
    assert_eq!(code, 200, "{ok}");
    let checks = ok["checks"].as_array().unwrap();
    let checked: Vec<&str> = checks
        .iter()
        .map(|c| c["camera"].as_str().unwrap())
        .collect();
    assert_eq!(checked, ["front", "wrist"], "{ok}");
    assert!(checks.iter().all(|c| c["stale"] == false), "{ok}");
    assert_overlays_per_camera(&base, &id, &[(640, 480), (640, 480)]);
    assert_exports_match_the_cli(&base, &dir.path().join("data"), &id, &["front", "wrist"]);
}

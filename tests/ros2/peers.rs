//! Shared by the ROS 2 tests: a private network namespace to run DDS peers in, and what the
//! Cyclone DDS peer (tf_peer.py) received.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

use easyhec::config::{SimArmSettings, SimCameraSettings};

pub fn peer() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/ros2/tf_peer.py")
}

/// Whether this machine can make a private network namespace and run the peer; under CI it
/// must.
pub fn can_run_peers() -> bool {
    let unshare = Command::new("unshare")
        .args(["--net", "true"])
        .output()
        .is_ok_and(|o| o.status.success());
    let cyclone = Command::new("python3")
        .args(["-c", "import cyclonedds.domain"])
        .output()
        .is_ok_and(|o| o.status.success());
    if unshare && cyclone {
        return true;
    }
    let why =
        format!("needs `unshare --net` (root) ({unshare}) and python3 with cyclonedds ({cyclone})");
    if std::env::var("CI").is_ok_and(|v| v == "true" || v == "1") {
        panic!("under CI this test {why}: ./test installs cyclonedds");
    }
    eprintln!("SKIPPED: this test {why}");
    false
}

/// Runs `body` (bash) in a fresh network namespace with multicast on loopback, in `dir`, with
/// `$EASYHEC` and `$PEER` set. Returns the script's exit status and its stderr.
pub fn in_private_network(dir: &Path, body: &str) -> (bool, String) {
    let script = format!(
        "set -u\nip link set lo up\nip link set lo multicast on\nip route add 224.0.0.0/4 dev lo\n\
         wait_for() {{ for _ in $(seq 300); do grep -q \"$2\" \"$1\" 2>/dev/null && return 0; sleep 0.1; done; return 1; }}\n{body}"
    );
    let out = Command::new("timeout")
        .args(["120", "unshare", "--net", "bash", "-c", &script])
        .current_dir(dir)
        .env("EASYHEC", PathBuf::from(env!("CARGO_BIN_EXE_easyhec")))
        .env("PEER", peer())
        .output()
        .unwrap();
    (
        out.status.success(),
        format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ),
    )
}

/// The one edge the peer received for `child`: (parent, parent_from_child).
pub fn received_edge(dir: &Path, child: &str) -> (String, Isometry3<f64>) {
    let edges = received_edges(dir);
    assert_eq!(edges.len(), 1, "{edges:?}");
    let (parent, got_child, pose) = edges.into_iter().next().unwrap();
    assert_eq!(got_child, child);
    (parent, pose)
}

/// Every edge of the `TFMessage` the peer wrote to `got.json`: (parent, child, transform),
/// each stamped with a real time.
pub fn received_edges(dir: &Path) -> Vec<(String, String, Isometry3<f64>)> {
    let text = std::fs::read_to_string(dir.join("got.json")).unwrap();
    let message: serde_json::Value = serde_json::from_str(text.trim()).unwrap();
    let edges = message["transforms"].as_array().unwrap();
    let n = |v: &serde_json::Value| v.as_f64().unwrap();
    edges
        .iter()
        .map(|e| {
            let (t, r) = (&e["transform"]["translation"], &e["transform"]["rotation"]);
            let pose = Isometry3::from_parts(
                Translation3::new(n(&t["x"]), n(&t["y"]), n(&t["z"])),
                UnitQuaternion::new_unchecked(Quaternion::new(
                    n(&r["w"]),
                    n(&r["x"]),
                    n(&r["y"]),
                    n(&r["z"]),
                )),
            );
            assert!(e["header"]["stamp"]["sec"].as_i64().unwrap() > 1_600_000_000);
            (
                e["header"]["frame_id"].as_str().unwrap().to_string(),
                e["child_frame_id"].as_str().unwrap().to_string(),
                pose,
            )
        })
        .collect()
}

/// Largest difference between two transforms' matrix entries.
pub fn max_difference(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    (a.to_homogeneous() - b.to_homogeneous()).abs().max()
}

/// The shipped simulated xArm6 cell on ROS 2 (domain `domain`): its arm is a ROS 2 arm (two
/// seconds of silence before staleness, since a loaded 2-core CI machine can stall the Python
/// controller for a fraction of a second) and its simulated camera films `/joint_states`.
/// Returns the config and the arm's start, for the fake controller.
pub fn ros2_sim_cell(domain: u16) -> (easyhec::config::CellConfig, Vec<f64>) {
    use easyhec::config::{read_config, ArmConfig, CameraConfig, JointsFrom};
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut cfg = read_config(&root.join("config/sim-xarm6.toml")).unwrap();
    cfg.robot.urdf = root.join("robots/xarm6/robot.urdf");
    let ArmConfig::Sim(SimArmSettings { start, .. }) = &cfg.arm else {
        panic!("the shipped cell's arm is simulated")
    };
    let start = start.clone();
    cfg.arm = toml::from_str("kind = \"ros2\"\nstale_after_s = 2.0").unwrap();
    let CameraConfig::Sim(SimCameraSettings { joints_from, .. }) = cfg.camera.first_mut() else {
        panic!("the shipped cell's camera is simulated")
    };
    let from_ros2: JointsFrom = toml::from_str("kind = \"ros2\"").unwrap();
    *joints_from = Some(from_ros2);
    let mut ros2: easyhec::config::ros2::Ros2Settings =
        toml::from_str("publish_tf = false").unwrap();
    ros2.domain_id = Some(domain);
    cfg.ros2 = Some(ros2);
    (cfg, start)
}

/// Asserts the calibration is within 0.1° / 1 mm of `truth` (the bound) and returns the
/// errors, degrees and millimetres; `log` is shown on failure.
pub fn assert_near_truth(
    result: &easyhec::run::ResultFile,
    truth: &Isometry3<f64>,
    log: &str,
) -> (f64, f64) {
    use easyhec::geometry::{rotation_error_deg, translation_error_mm};
    let (rot, trans) = (
        rotation_error_deg(&result.camera_from_base(), truth),
        translation_error_mm(&result.camera_from_base(), truth),
    );
    assert!(
        rot < 0.1 && trans < 1.0,
        "{rot:.4} deg, {trans:.3} mm\n{log}"
    );
    (rot, trans)
}

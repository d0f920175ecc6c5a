//! `[camera] kind = "ros2"` with `[arm] kind = "ros2"`: a whole `easyhec calibrate` beside a
//! ROS 2 stack, with no hardware. The fake joint_trajectory_controller (Cyclone DDS,
//! tests/ros2/fake_controller.py) plays the arm. `easyhec sim-camera` renders the simulated
//! cell at the controller's `/joint_states` onto `/sim/…`, and a Cyclone DDS relay
//! (tests/ros2/image_relay.py) publishes those frames as the camera driver, bgr8 on
//! `/camera/color/image_raw` with best-effort QoS, and their CameraInfo. The calibration
//! segments the frames with the builtin segmenter. Everything runs in a private network
//! namespace (tests/ros2/peers.rs).

#![cfg(feature = "ros2")]

mod common;
#[path = "ros2/peers.rs"]
mod peers;

use std::path::Path;

use easyhec::config::SimCameraSettings;
use easyhec::config::{CameraConfig, CellConfig};
use easyhec::robot::RobotModel;
use easyhec::run::ResultFile;
use peers::{assert_near_truth, can_run_peers, in_private_network, ros2_sim_cell};

const DOMAIN: u16 = 24;

fn write(dir: &Path, name: &str, cfg: &CellConfig) {
    std::fs::write(dir.join(name), toml::to_string(cfg).unwrap()).unwrap();
}

#[test]
fn calibration_from_ros2_topics_alone_reaches_the_truth_safely() {
    if !can_run_peers() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (sim, start) = ros2_sim_cell(DOMAIN);
    write(dir.path(), "sim.toml", &sim);
    let CameraConfig::Sim(SimCameraSettings { truth, .. }) = sim.camera.first() else {
        unreachable!()
    };
    let truth = truth.camera_from_base();
    let mut cell = sim.clone();
    cell.camera = toml::from_str("kind = \"ros2\"").unwrap();
    cell.segmenter = easyhec::config::SegmenterConfig::by_name("builtin").unwrap();
    write(dir.path(), "cell.toml", &cell);
    let robot = RobotModel::from_urdf(&sim.robot.urdf).unwrap();
    let names = robot.joint_names();
    let start: Vec<String> = start.iter().map(|v| format!("{v:?}")).collect();
    let body = format!(
        r#"
python3 "$(dirname "$PEER")/fake_controller.py" {DOMAIN} {names} {start} commands.jsonl > controller.log 2>&1 &
controller=$!
wait_for controller.log "controller up" || {{ cat controller.log; exit 3; }}
python3 "$(dirname "$PEER")/image_relay.py" {DOMAIN} > relay.log 2>&1 &
relay=$!
wait_for relay.log "relay up" || {{ cat relay.log; exit 5; }}
"$EASYHEC" sim-camera --config sim.toml --image-topic /sim/image_raw --camera-info-topic /sim/camera_info 2> camera.log &
camera=$!
wait_for camera.log "publishing" || {{ cat camera.log; exit 4; }}
"$EASYHEC" calibrate --config cell.toml --out run > calibrate.log 2>&1
echo "calibrate exited $?"
kill $controller $camera $relay
cat calibrate.log camera.log relay.log
"#,
        names = names.join(","),
        start = start.join(",")
    );
    let (ok, log) = in_private_network(dir.path(), &body);
    assert!(ok && log.contains("calibrate exited 0"), "{log}");
    let result = ResultFile::read(&dir.path().join("run/result.json")).unwrap();
    let (rot, trans) = assert_near_truth(&result, &truth, &log);
    let commands = std::fs::read_to_string(dir.path().join("commands.jsonl")).unwrap();
    let moves = common::assert_logged_commands_safe(&sim, &dir.path().join("sim.toml"), &commands);
    assert!(
        moves + 1 >= result.views_used.len(),
        "{moves} moves\n{commands}"
    );
    eprintln!(
        "ros2 arm + ros2 camera: {rot:.4} deg, {trans:.3} mm, {} views, {moves} moves",
        result.views_used.len()
    );
}

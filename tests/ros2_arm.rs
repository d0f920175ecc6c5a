//! `[arm] kind = "ros2"` against a fake joint_trajectory_controller on Cyclone DDS
//! (tests/ros2/fake_controller.py): a whole `easyhec calibrate` on the simulated xArm6 cell
//! whose camera films the controller's `/joint_states`, and a controller that falls silent.
//! Everything runs in a private network namespace (tests/ros2/peers.rs).

#![cfg(feature = "ros2")]

mod common;
#[path = "ros2/peers.rs"]
mod peers;

use std::path::{Path, PathBuf};

use easyhec::config::CellConfig;
use easyhec::geometry::from_rows;
use easyhec::robot::RobotModel;
use easyhec::run::{GroundTruth, ResultFile};
use peers::{assert_near_truth, can_run_peers, in_private_network, ros2_sim_cell};

/// [`ros2_sim_cell`] written to `DIR/cell.toml`: the config, its path and the arm's start.
fn ros2_cell(dir: &Path, domain: u16) -> (CellConfig, PathBuf, Vec<f64>) {
    let (cfg, start) = ros2_sim_cell(domain);
    let path = dir.join("cell.toml");
    std::fs::write(&path, toml::to_string(&cfg).unwrap()).unwrap();
    (cfg, path, start)
}

fn controller_line(names: &[&str], start: &[f64], extra: &str, domain: u16) -> String {
    let start: Vec<String> = start.iter().map(|v| format!("{v:?}")).collect();
    format!(
        "python3 \"$(dirname \"$PEER\")/fake_controller.py\" {domain} {} {} commands.jsonl {extra} > controller.log 2>&1 &\n\
         controller=$!\nwait_for controller.log \"controller up\" || {{ cat controller.log; exit 3; }}\n",
        names.join(","),
        start.join(",")
    )
}

#[test]
fn calibration_through_a_ros2_trajectory_controller_reaches_the_truth_safely() {
    if !can_run_peers() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (cfg, path, start) = ros2_cell(dir.path(), 21);
    let robot = RobotModel::from_urdf(&cfg.robot.urdf).unwrap();
    let names = robot.joint_names();
    let body = format!(
        "{}\"$EASYHEC\" calibrate --config cell.toml --out run > calibrate.log 2>&1\n\
         echo \"calibrate exited $?\"\nkill $controller\ncat calibrate.log\n",
        controller_line(&names, &start, "", 21)
    );
    let (ok, log) = in_private_network(dir.path(), &body);
    assert!(ok && log.contains("calibrate exited 0"), "{log}");
    let result = ResultFile::read(&dir.path().join("run/result.json")).unwrap();
    let truth: GroundTruth = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("run/ground_truth.json")).unwrap(),
    )
    .unwrap();
    let truth = from_rows(&truth.camera_from_base).unwrap();
    let (rot, trans) = assert_near_truth(&result, &truth, &log);
    let commands = std::fs::read_to_string(dir.path().join("commands.jsonl")).unwrap();
    let moves = common::assert_logged_commands_safe(&cfg, &path, &commands);
    let views = result.views_used.len();
    assert!(
        views >= 2 && moves >= views - 1,
        "{moves} moves for {views} views\n{commands}"
    );
    eprintln!("ros2 arm: {rot:.4} deg, {trans:.3} mm, {moves} moves");
}

#[test]
fn a_controller_that_falls_silent_stops_the_run_with_one_clear_error() {
    if !can_run_peers() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (cfg, _, start) = ros2_cell(dir.path(), 22);
    let robot = RobotModel::from_urdf(&cfg.robot.urdf).unwrap();
    let body = format!(
        "{}\"$EASYHEC\" calibrate --config cell.toml --out run > calibrate.log 2>&1\n\
         echo \"calibrate exited $?\"\nkill $controller\ncat calibrate.log\n",
        controller_line(&robot.joint_names(), &start, "--silent-after 4", 22)
    );
    let (ok, log) = in_private_network(dir.path(), &body);
    assert!(ok, "{log}");
    // The loop ends on the fault and keeps what it had, as for any arm fault; the stop reason
    // names the topic and how long it has been silent.
    let result = ResultFile::read(&dir.path().join("run/result.json")).unwrap();
    assert!(
        result.stop_reason.contains("/joint_states went stale")
            && result.stop_reason.contains("limit 2.00 s"),
        "{}\n{log}",
        result.stop_reason
    );
    // Once the positions are older than the 2 s limit (the silence began 4 s in), nothing but
    // a hold was commanded: every later point is where the joints already were (the stop), and
    // no command was refused. A move may start within the limit, from the last positions heard.
    let commands = std::fs::read_to_string(dir.path().join("commands.jsonl")).unwrap();
    for line in commands.lines() {
        let c: serde_json::Value = serde_json::from_str(line).unwrap();
        assert!(c["rejected"].is_null(), "{commands}");
        if c["t"].as_f64().unwrap() > 4.0 + 2.0 {
            let (from, to) = (c["from"].as_array().unwrap(), c["to"].as_array().unwrap());
            let widest = from
                .iter()
                .zip(to)
                .map(|(a, b)| (a.as_f64().unwrap() - b.as_f64().unwrap()).abs())
                .fold(0.0, f64::max);
            assert!(widest < 0.05, "a move after the silence: {line}");
        }
    }
}

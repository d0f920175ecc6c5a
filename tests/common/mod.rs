//! Shared helpers for integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

use easyhec::robot::RobotModel;

/// `../shared/robots/NAME/robot.urdf` beside the checkout.
pub fn robot_urdf(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/robots")
        .join(name)
        .join("robot.urdf")
}

/// Loads one of the vendor robots.
pub fn load_robot(name: &str) -> RobotModel {
    RobotModel::from_urdf(robot_urdf(name)).expect("vendor robot loads")
}

/// The `easyhec` binary built for this test run.
pub fn easyhec_bin() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_easyhec"))
}

/// Runs `easyhec synth --robot <vendor NAME> --out OUT ARGS…` and checks it succeeded.
pub fn synth_run(out: &std::path::Path, robot: &str, args: &[&str]) {
    let status = std::process::Command::new(easyhec_bin())
        .args(["synth", "--robot"])
        .arg(robot_urdf(robot))
        .arg("--out")
        .arg(out)
        .args(args)
        .status()
        .expect("easyhec runs");
    assert!(status.success(), "synth failed");
}

/// Runs `easyhec solve RUN EXTRA…`.
pub fn solve_run(run: &std::path::Path, extra: &[&str]) -> std::process::Output {
    std::process::Command::new(easyhec_bin())
        .arg("solve")
        .arg(run)
        .args(extra)
        .output()
        .expect("easyhec runs")
}

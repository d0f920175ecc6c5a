//! Shared helpers for integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

use easyhec::robot::{RobotModel, RobotSource};

/// `../shared/robots/NAME/robot.urdf` beside the checkout.
pub fn robot_urdf(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/robots")
        .join(name)
        .join("robot.urdf")
}

/// Loads one of the vendor robots.
pub fn load_robot(name: &str) -> RobotModel {
    RobotModel::load(&RobotSource {
        urdf: robot_urdf(name),
        ..Default::default()
    })
    .expect("vendor robot loads")
}

/// The `easyhec` binary built for this test run.
pub fn easyhec_bin() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_easyhec"))
}

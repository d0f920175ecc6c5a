//! `package://` mesh URIs resolve through `robot.package_dirs`, then `ROS_PACKAGE_PATH`
//! (searched like ROS does: `package.xml` names, nested workspace folders).

mod common;

use std::path::Path;
use std::process::Command;

/// A run whose URDF refers to its meshes as `package://xarm_description/meshes/...`.
fn packaged_run(dir: &Path) -> std::path::PathBuf {
    let run = dir.join("run");
    common::synth_run(
        &run,
        "xarm6",
        &[
            "--views", "1", "--seed", "2", "--width", "320", "--height", "240", "--focal", "300",
        ],
    );
    // A catkin-style workspace: ws/src/xarm_ros/xarm_description/{package.xml,meshes -> vendor meshes}.
    let pkg = dir.join("ws/src/xarm_ros/xarm_description");
    std::fs::create_dir_all(&pkg).unwrap();
    std::fs::write(
        pkg.join("package.xml"),
        "<package format=\"2\">\n  <name>xarm_description</name>\n</package>\n",
    )
    .unwrap();
    std::os::unix::fs::symlink(
        common::robot_urdf("xarm6").parent().unwrap().join("meshes"),
        pkg.join("meshes"),
    )
    .unwrap();
    let text = std::fs::read_to_string(common::robot_urdf("xarm6"))
        .unwrap()
        .replace(
            "filename=\"meshes/",
            "filename=\"package://xarm_description/meshes/",
        );
    std::fs::write(run.join("robot.urdf"), text).unwrap();
    let p = run.join("run.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    v["robot"]["urdf"] = "robot.urdf".into();
    std::fs::write(&p, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    run
}

fn solve(run: &Path, ros_package_path: Option<&Path>) -> std::process::Output {
    let mut cmd = Command::new(common::easyhec_bin());
    cmd.arg("solve").arg(run).env_remove("ROS_PACKAGE_PATH");
    if let Some(p) = ros_package_path {
        cmd.env("ROS_PACKAGE_PATH", p);
    }
    cmd.output().unwrap()
}

#[test]
fn unresolved_package_names_the_fix() {
    let d = tempfile::tempdir().unwrap();
    let run = packaged_run(d.path());
    let out = solve(&run, None);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("xarm_description")
            && err.contains("package_dirs")
            && err.contains("ROS_PACKAGE_PATH"),
        "{err}"
    );
}

#[test]
fn ros_package_path_finds_nested_workspace_packages() {
    let d = tempfile::tempdir().unwrap();
    let run = packaged_run(d.path());
    let out = solve(&run, Some(&d.path().join("ws")));
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn package_dirs_take_precedence() {
    let d = tempfile::tempdir().unwrap();
    let run = packaged_run(d.path());
    let p = run.join("run.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    // Relative to the run folder, as docs/formats.md says.
    v["robot"]["package_dirs"] =
        serde_json::json!({ "xarm_description": "../ws/src/xarm_ros/xarm_description" });
    std::fs::write(&p, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    let out = solve(&run, Some(Path::new("/nonexistent")));
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

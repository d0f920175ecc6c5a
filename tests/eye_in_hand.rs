//! Cameras on a link (eye-in-hand): the loop solves `camera_from_<link>` on the simulated
//! xArm6 and UR5e wrist cells, every commanded pose passes the safety checker, the run
//! records the mount and re-solves offline to the same transform, and a mount the robot
//! cannot carry is refused before anything moves.

mod common;

use easyhec::cell::Cell;
use easyhec::config::{read_config, CellConfig, Mount};
use easyhec::geometry::{rotation_error_deg, translation_error_mm};
use easyhec::run::load_run;

fn quick(mut cfg: CellConfig, views: usize) -> CellConfig {
    cfg.calibration.max_views = views;
    cfg.calibration.min_views = views;
    cfg.calibration.candidates = 24;
    cfg
}

#[test]
fn wrist_cameras_on_two_robots_reach_the_truth_safely() {
    for (name, link) in [
        ("sim-xarm6-eye-in-hand.toml", "link6"),
        ("sim-ur5e-eye-in-hand.toml", "wrist_3_link"),
    ] {
        let path = common::config_path(name);
        let cell = Cell::build(quick(read_config(&path).unwrap(), 4), &path).unwrap();
        assert_eq!(
            cell.config.camera.first().mount(),
            &Mount::Link(link.into())
        );
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("run");
        let outcome = common::run_loop(&cell, &out);
        let truth = cell.units[0].sim.camera_from_base.unwrap();
        let est = outcome.result.camera_from_base();
        let (r, t) = (
            rotation_error_deg(&est, &truth),
            translation_error_mm(&est, &truth),
        );
        assert!(
            r < 0.2 && t < 1.0,
            "{name}: camera_from_{link} off by {r:.4} deg {t:.3} mm"
        );
        // The result is named by the mount: the transform goes from the link.
        assert_eq!(outcome.result.base_link, link);
        let views = outcome.result.views_used.len();
        assert_eq!(views, 4, "{name}: {}", outcome.result.stop_reason);
        assert_eq!(
            common::assert_every_command_safe(&cell),
            views - 1,
            "{name}"
        );

        // The run records the mount, and the offline solve finds the same transform.
        let loaded = load_run(&out).unwrap();
        assert_eq!(loaded.file.camera.mount, Mount::Link(link.into()));
        assert_eq!(loaded.robot.links[loaded.robot.base], link);
        let solved = dir.path().join("solved.json");
        let status = std::process::Command::new(env!("CARGO_BIN_EXE_easyhec"))
            .args(["solve", "-q"])
            .arg(&out)
            .arg("--out")
            .arg(&solved)
            .output()
            .unwrap();
        assert!(
            status.status.success(),
            "{}",
            String::from_utf8_lossy(&status.stderr)
        );
        let stdout = String::from_utf8_lossy(&status.stdout);
        assert!(
            stdout.starts_with(&format!("camera_from_{link} solved from 4 views")),
            "{stdout}"
        );
        let offline = easyhec::run::ResultFile::read(&solved).unwrap();
        assert_eq!(offline.base_link, link);
        let drift = rotation_error_deg(&offline.camera_from_base(), &est);
        assert!(drift < 0.05, "{name}: offline solve moved {drift:.4} deg");
    }
}

#[test]
fn a_mount_the_robot_cannot_carry_is_refused_with_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let base = common::shipped_config_text("sim-xarm6-eye-in-hand.toml");
    let guess_line = base
        .lines()
        .find(|l| l.starts_with("initial_guess"))
        .unwrap()
        .to_string();
    let cases = [
        (
            base.replace(
                "mount = { link = \"link6\" }",
                "mount = { link = \"link9\" }",
            ),
            "camera.mount.link: no link named 'link9'",
        ),
        (
            base.replace(
                "mount = { link = \"link6\" }",
                "mount = { link = \"link_base\" }",
            ),
            "does not move with any actuated joint",
        ),
        (
            base.replace("mount = { link = \"link6\" }", "mount = \"wrist\""),
            "\"fixed\" or { link",
        ),
        (base.replace(&guess_line, ""), "calibration.initial_guess"),
        (
            base.replace(
                "scene = { seed = 1 }",
                "scene = { seed = 1, preset = \"hard\" }",
            ),
            "camera.scene.distractors",
        ),
        (
            base.replace(
                "max_views = 5",
                "max_views = 5\nmin_robot_image_fraction = 1.5",
            ),
            "calibration.min_robot_image_fraction",
        ),
    ];
    common::assert_configs_refused(dir.path(), &base, &cases);
}

/// When no pose shows the robot to the wrist camera, the loop says so and stops after the
/// first view instead of wandering.
#[test]
fn no_pose_that_shows_the_robot_is_said_plainly() {
    let path = common::config_path("sim-xarm6-eye-in-hand.toml");
    let mut cfg = quick(read_config(&path).unwrap(), 4);
    // Nothing can cover 95% of the image clear of the lens.
    cfg.calibration.min_robot_image_fraction = 0.95;
    let cell = Cell::build(cfg, &path).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let outcome = common::run_loop(&cell, &dir.path().join("run"));
    assert!(
        outcome
            .result
            .stop_reason
            .contains("no safe pose shows enough of the robot to the camera after 1 views"),
        "{}",
        outcome.result.stop_reason
    );
    assert_eq!(common::assert_every_command_safe(&cell), 0);
}

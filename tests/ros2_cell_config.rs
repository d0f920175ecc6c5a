//! `[arm] kind = "ros2"` and `[ros2]` in a cell config: bad keys get one line naming the key in
//! every build; without the `ros2` feature such a cell says how to rebuild. Nothing here joins
//! a DDS graph (tests/ros2_arm.rs drives a real one, in a private network namespace).

mod common;

/// The shipped simulated xArm6 cell with its arm on ROS 2 and its camera filming
/// `/joint_states`.
fn base() -> String {
    std::fs::read_to_string(common::repo_root().join("config/sim-xarm6.toml"))
        .unwrap()
        .replace(
            "../robots/xarm6/robot.urdf",
            &common::repo_root().join("robots/xarm6/robot.urdf").display().to_string(),
        )
        .replace(
            "kind = \"sim\"\nstart = [0.0, -0.35, -0.6, 0.0, 0.95, 0.0]\nencoder_noise_rad = 0.0005\nseed = 1\n",
            "kind = \"ros2\"\nstale_after_s = 0.5\n",
        )
        .replace(
            "scene = { seed = 1 }\n",
            "scene = { seed = 1 }\njoints_from = { kind = \"ros2\" }\n",
        )
        + "\n[ros2]\ndomain_id = 5\n"
}

/// `base` with its camera replaced by a ROS 2 camera table holding `keys`.
fn ros2_camera(base: &str, keys: &str) -> String {
    let start = base.find("[camera]").unwrap();
    let end = base.find("[segmenter]").unwrap();
    format!(
        "{}[camera]\nkind = \"ros2\"\n{keys}\n{}",
        &base[..start],
        &base[end..]
    )
}

#[test]
fn bad_ros2_keys_get_one_line_errors_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let base = base();
    let arm = "kind = \"ros2\"\n";
    let mut cases =
        vec![
        (
            base.replace(arm, "kind = \"ros2\"\njoint_states_topic = \"/joint states\"\n"),
            "arm.joint_states_topic",
        ),
        (
            base.replace(arm, "kind = \"ros2\"\ncommand_topic = \"\"\n"),
            "arm.command_topic",
        ),
        (
            base.replace(
                arm,
                "kind = \"ros2\"\njoint_names = [\"j1\", \"j1\", \"j3\", \"j4\", \"j5\", \"j6\"]\n",
            ),
            "arm.joint_names[1]",
        ),
        (
            base.replace("stale_after_s = 0.5", "stale_after_s = 0.0"),
            "arm.stale_after_s",
        ),
        (
            base.replace(arm, "kind = \"ros2\"\narrival_tolerance_rad = 1.0\n"),
            "arm.arrival_tolerance_rad",
        ),
        (base.replace("domain_id = 5", "domain_id = 300"), "ros2.domain_id"),
        (
            base.replace("domain_id = 5", "domain_id = 5\nnamespace = \"/a__b\""),
            "ros2.namespace",
        ),
        (
            base.replace(arm, "kind = \"ros2\"\nport = 1\n"),
            "line",
        ),
        (ros2_camera(&base, "image_topic = \"/camera/image raw\"\n"), "camera.image_topic"),
        (ros2_camera(&base, "camera_info_topic = \"info/\"\n"), "camera.camera_info_topic"),
    ];
    if cfg!(feature = "ros2") {
        cases.push((
            base.replace(arm, "kind = \"ros2\"\njoint_names = [\"a\", \"b\"]\n"),
            "arm.joint_names",
        ));
    }
    for (i, (text, needle)) in cases.iter().enumerate() {
        assert_ne!(text, &base, "case {i} changed nothing");
        let e = common::cell_open_error(dir.path(), &format!("bad{i}.toml"), text);
        assert!(
            e.contains(&format!("bad{i}.toml")) && e.contains(needle),
            "case {i}: {e}"
        );
        assert!(!e.contains('\n'), "case {i}: {e}");
    }
}

#[cfg(not(feature = "ros2"))]
#[test]
fn without_the_feature_a_ros2_cell_says_how_to_rebuild() {
    let dir = tempfile::tempdir().unwrap();
    let e = common::cell_open_error(dir.path(), "ros2.toml", &base());
    assert!(
        e.contains("arm.kind") && e.contains("rebuild with --features ros2"),
        "{e}"
    );
    assert!(!e.contains('\n'), "{e}");
    // A ROS 2 camera beside a simulated arm.
    let sim_arm = std::fs::read_to_string(common::repo_root().join("config/sim-xarm6.toml"))
        .unwrap()
        .replace(
            "../robots/xarm6/robot.urdf",
            &common::repo_root()
                .join("robots/xarm6/robot.urdf")
                .display()
                .to_string(),
        );
    let e = common::cell_open_error(dir.path(), "camera.toml", &ros2_camera(&sim_arm, ""));
    assert!(
        e.contains("camera.kind") && e.contains("rebuild with --features ros2"),
        "{e}"
    );
}

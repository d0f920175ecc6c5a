//! `[arm] kind = "ur"` cells: the shipped `config/mock-ur.toml` parses in every build; bad
//! UR tables get one line naming the key; without the `ur` feature building such a cell says
//! how to get the driver.

mod common;

use easyhec::config::UrSettings;

use easyhec::config::{read_config, ArmConfig};

fn config_path() -> std::path::PathBuf {
    common::config_path("mock-ur.toml")
}

/// The shipped config with its robot path made absolute (it is written to a temp dir).
fn base() -> String {
    std::fs::read_to_string(config_path()).unwrap().replace(
        "../robots/ur5e/robot.urdf",
        &common::repo_root()
            .join("robots/ur5e/robot.urdf")
            .display()
            .to_string(),
    )
}

#[test]
fn shipped_mock_ur_config_parses() {
    let cfg = read_config(&config_path()).unwrap();
    assert!(matches!(&cfg.arm, ArmConfig::Ur(UrSettings { host, .. }) if host == "127.0.0.1"));
}

#[test]
fn bad_ur_tables_get_one_line_errors_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let base = base();
    let mut cases = vec![(
        base.replace("host = \"127.0.0.1\"", "host = \"127.0.0.1\"\nport = 30004"),
        "line",
    )];
    if cfg!(feature = "ur") {
        cases.extend([
            (
                base.replace(
                    "joints_from = { kind = \"ur-rtde\", addr = \"127.0.0.1:30004\" }\n",
                    "",
                ),
                "camera.joints_from",
            ),
            (
                base.replace("host = \"127.0.0.1\"", "host = \"127.0.0.1:30004\""),
                "arm.host",
            ),
            (
                base.replace("speed_cap_rad_s = 1.0", "speed_cap_rad_s = -1.0"),
                "speed cap",
            ),
            (
                base.replace(
                    "accel_rad_s2 = 1.4",
                    "accel_rad_s2 = 1.4\ncall_timeout_s = 0.0",
                ),
                "arm.call_timeout_s",
            ),
            (base.replace(&base_urdf(), &panda_urdf()), "6 joints"),
        ]);
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

fn base_urdf() -> String {
    common::repo_root()
        .join("robots/ur5e/robot.urdf")
        .display()
        .to_string()
}

fn panda_urdf() -> String {
    // A Panda: 7 arm joints (and fingers), the wrong arm for a UR driver.
    common::repo_root()
        .join("robots/panda/robot.urdf")
        .display()
        .to_string()
}

#[cfg(not(feature = "ur"))]
#[test]
fn without_the_feature_a_ur_cell_says_how_to_rebuild() {
    let dir = tempfile::tempdir().unwrap();
    let e = common::cell_open_error(dir.path(), "ur.toml", &base());
    assert!(
        e.contains("arm.kind") && e.contains("rebuild with --features ur"),
        "{e}"
    );
    assert!(!e.contains('\n'), "{e}");
}

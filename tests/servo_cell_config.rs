//! `[arm] kind = "dynamixel" | "feetech" | "piper"` cells: the SO-101 example parses; a servo
//! table builds into a driver with the configured limits (nothing is opened at build time);
//! bad tables get one line naming the key; a Piper cell without the `socketcan` feature says
//! how to get it.

mod common;

use std::path::Path;

use easyhec::cell::Cell;

use easyhec::config::{read_config, ArmConfig};
use easyhec_drivers::piper::PIPER_LIMITS_RAD;

/// A cell on the shipped xArm6 URDF (six joints `joint1`…`joint6`) with `arm` as its arm
/// table; the simulated camera takes its joints from an (absent) report port, which building
/// never contacts.
fn cell_text(arm: &str) -> String {
    format!(
        r#"[robot]
urdf = "{}"

{arm}

[camera]
kind = "sim"
width = 64
height = 48
fx = 60.0
fy = 60.0
cx = 32.0
cy = 24.0
truth = {{ eye = [1.2, 0.5, 0.7], look_at = [0.1, 0.0, 0.3] }}
joints_from = {{ kind = "xarm-report", addr = "127.0.0.1:9" }}

[segmenter]
kind = "sim-truth"
"#,
        common::repo_root()
            .join("robots/xarm6/robot.urdf")
            .display()
    )
}

fn servo_table(kind: &str, rows: &str) -> String {
    format!("[arm]\nkind = \"{kind}\"\nport = \"/dev/ttyNOTHERE\"\nspeed_cap_rad_s = 0.7\n{rows}")
}

fn rows(n: usize, extra: &str) -> String {
    (1..=n)
        .map(|i| {
            format!(
                "[[arm.joints]]\nname = \"joint{i}\"\nid = {i}\n{}",
                if i == 2 { extra } else { "" }
            )
        })
        .collect::<Vec<_>>()
        .join("\n")
}

fn open(dir: &Path, text: &str) -> easyhec::error::Result<Cell> {
    let p = dir.join("cell.toml");
    std::fs::write(&p, text).unwrap();
    Cell::open(&p)
}

#[test]
fn so101_example_parses_as_a_feetech_arm() {
    let cfg = read_config(&common::repo_root().join("config/so101-feetech.toml.example")).unwrap();
    let ArmConfig::Feetech(t) = &cfg.arm else {
        panic!("{:?}", cfg.arm)
    };
    assert_eq!((t.port.as_str(), t.baud), ("/dev/ttyACM0", Some(1_000_000)));
    let names: Vec<&str> = t.joints.iter().map(|j| j.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "shoulder_pan",
            "shoulder_lift",
            "elbow_flex",
            "wrist_flex",
            "wrist_roll",
            "gripper"
        ]
    );
    assert_eq!(
        t.joints.iter().map(|j| j.id).collect::<Vec<_>>(),
        [1, 2, 3, 4, 5, 6]
    );
}

#[test]
fn servo_tables_build_into_drivers_with_their_limits() {
    let dir = tempfile::tempdir().unwrap();
    for kind in ["dynamixel", "feetech"] {
        let text = cell_text(&servo_table(
            kind,
            &rows(6, "direction = -1\nlower_rad = -1.0\nupper_rad = 0.5\n"),
        ));
        let cell = open(dir.path(), &text).unwrap_or_else(|e| panic!("{kind}: {e}"));
        let j = cell.arm.joints();
        assert_eq!(j.len(), 6);
        assert_eq!(
            (j[1].name.as_str(), j[1].lower, j[1].upper),
            ("joint2", -1.0, 0.5)
        );
        // Unlimited rows get the servo's position range, ticks 0…4095 around offset 0.
        let pi = std::f64::consts::PI;
        assert!((j[0].lower + pi).abs() < 1e-12);
        assert!((j[0].upper - (pi - 2.0 * pi / 4096.0)).abs() < 1e-12);
        assert!(j.iter().all(|l| l.max_velocity == 0.7));
    }
}

#[test]
fn bad_servo_tables_get_one_line_errors_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (servo_table("dynamixel", &rows(5, "")), "arm.joints"),
        (
            servo_table(
                "feetech",
                &rows(6, "id = 1\n").replace("id = 2\nid = 1", "id = 1"),
            ),
            "id 1 is also joint joint1's",
        ),
        (
            servo_table("feetech", &rows(6, "direction = 2\n")),
            "direction 2: use 1 or -1",
        ),
        (
            servo_table("dynamixel", &rows(6, "upper_rad = 4.0\n")),
            "leave the servo's position range",
        ),
        (
            servo_table("dynamixel", &rows(6, "gear = 2\n")),
            "unknown field `gear`",
        ),
        (
            servo_table("dynamixel", &rows(6, ""))
                .replace("speed_cap_rad_s = 0.7", "reply_timeout_s = 0"),
            "arm.reply_timeout_s",
        ),
    ];
    for (table, needle) in cases {
        let err = match open(dir.path(), &cell_text(&table)) {
            Ok(_) => panic!("accepted: {table}"),
            Err(e) => e.to_string(),
        };
        assert!(err.contains(needle), "{needle:?} not in {err:?}");
        assert_eq!(err.lines().count(), 1, "{err}");
    }
}

#[test]
fn piper_cells_need_the_socketcan_feature() {
    let dir = tempfile::tempdir().unwrap();
    let text = cell_text("[arm]\nkind = \"piper\"\ninterface = \"can0\"\nspeed_cap_rad_s = 0.6");
    let built = open(dir.path(), &text);
    if cfg!(feature = "socketcan") {
        let cell = built.unwrap();
        let j = cell.arm.joints();
        assert_eq!((j.len(), j[0].max_velocity), (6, 0.6));
        assert_eq!(
            (j[1].lower, j[1].upper),
            PIPER_LIMITS_RAD[1],
            "J2: the SDK's 0 … 3.14"
        );
    } else {
        let e = built
            .err()
            .expect("a Piper cell without the feature")
            .to_string();
        assert!(
            e.contains("arm.kind") && e.contains("rebuild with --features socketcan"),
            "{e}"
        );
        assert_eq!(e.lines().count(), 1);
    }
}

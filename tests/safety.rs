//! The safety checker on its own: thin obstacles between path samples, self-collision,
//! limits and speed caps, SRDF pairs.

use std::path::PathBuf;
use std::sync::Arc;

use easyhec::config::{ObstacleConfig, SafetyConfig};
use easyhec::robot::RobotModel;
use easyhec::safety::{SafetyChecker, Violation};

fn xarm6() -> Arc<RobotModel> {
    Arc::new(
        RobotModel::from_urdf(
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots/xarm6/robot.urdf"),
        )
        .unwrap(),
    )
}

fn checker(robot: &Arc<RobotModel>, cfg: &SafetyConfig) -> SafetyChecker {
    let limits: Vec<(f64, f64, f64)> = robot
        .joint_limits()
        .iter()
        .map(|&(lo, hi)| (lo, hi, 3.0))
        .collect();
    SafetyChecker::new(robot.clone(), cfg, &limits, &PathBuf::from("cell.toml")).unwrap()
}

#[test]
fn a_thin_plate_between_the_ends_of_a_path_is_caught() {
    let robot = xarm6();
    let mid = vec![0.0, 0.3, -0.6, 0.0, 0.6, 0.0];
    // A 2 mm plate across the wrist's sweep at azimuth 0, thin along the sweep direction.
    let wrist = robot.base_from_links(&mid)[robot.link_index("link5").unwrap()]
        .translation
        .vector;
    let plate = ObstacleConfig::Box {
        name: "plate".into(),
        centre: [wrist.x, wrist.y, wrist.z],
        size: [0.2, 0.002, 0.2],
        rpy_deg: [0.0; 3],
    };
    let cfg = SafetyConfig {
        obstacles: vec![plate],
        ..SafetyConfig::default()
    };
    let c = checker(&robot, &cfg);
    let mut from = mid.clone();
    from[0] = -0.8;
    let mut to = mid.clone();
    to[0] = 0.8;
    c.check_pose(&from).unwrap();
    c.check_pose(&to).unwrap();
    assert!(matches!(
        c.check_pose(&mid),
        Err(Violation::Environment { .. })
    ));
    match c.check_path(&from, &to) {
        Err(Violation::Path { inner, at_fraction }) => {
            assert!(matches!(*inner, Violation::Environment { .. }), "{inner}");
            assert!(at_fraction > 0.2 && at_fraction < 0.5, "{at_fraction}");
        }
        other => panic!("path through the plate accepted: {other:?}"),
    }
    // The sampling is fine enough for the margin: at most margin/2 of motion between samples.
    let n = c.path_samples(&from, &to);
    assert!(n as f64 >= 1.6 * 0.7 / 0.005, "{n} samples");
}

#[test]
fn folding_the_arm_into_itself_is_refused_and_adjacent_links_are_skipped() {
    let robot = xarm6();
    let c = checker(&robot, &SafetyConfig::default());
    assert!(c
        .skipped_pairs
        .iter()
        .any(|(a, b, why)| a == "link1" && b == "link2" && *why == "adjacent"));
    // Sweep the elbow until the forearm folds onto the upper arm or base.
    let (lo, hi) = c.limits()[2];
    let mut found = None;
    for k in 0..=200 {
        let q = vec![0.0, 0.0, lo + (hi - lo) * k as f64 / 200.0, 0.0, 0.0, 0.0];
        if let Err(v @ Violation::SelfCollision { .. }) = c.check_pose(&q) {
            found = Some(v);
            break;
        }
    }
    let Some(Violation::SelfCollision { links, clearance_m }) = found else {
        panic!("no self-collision found over the elbow's range");
    };
    assert!(clearance_m < 0.01);
    let (a, b) = (
        robot.link_index(&links.0).unwrap(),
        robot.link_index(&links.1).unwrap(),
    );
    assert!(robot
        .joints
        .iter()
        .all(|j| !((j.parent == a && j.child == b) || (j.parent == b && j.child == a))));
}

#[test]
fn limits_ranges_and_speed_caps_are_enforced() {
    let robot = xarm6();
    let cfg = SafetyConfig {
        joint_ranges: [("joint1".to_string(), [-0.5, 0.5])].into_iter().collect(),
        speed_cap_rad_s: 0.4,
        ..SafetyConfig::default()
    };
    let c = checker(&robot, &cfg);
    let home = vec![0.0, 0.3, -0.6, 0.0, 0.6, 0.0];
    let mut far = home.clone();
    far[0] = 0.7;
    assert!(matches!(
        c.check_pose(&far),
        Err(Violation::JointLimit { .. })
    ));
    let mut near = home.clone();
    near[0] = 0.4;
    assert!(matches!(
        c.check_move(&home, &near, 0.5),
        Err(Violation::Speed { .. })
    ));
    assert!(c.check_move(&home, &near, 0.4).is_ok());
    let mut nan = home.clone();
    nan[3] = f64::NAN;
    assert!(matches!(c.check_pose(&nan), Err(Violation::Malformed(_))));
    assert!(matches!(
        c.check_pose(&home[..5]),
        Err(Violation::Malformed(_))
    ));
}

#[test]
fn srdf_disable_collisions_are_honoured() {
    let robot = xarm6();
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("r.srdf"),
        r#"<robot name="xarm6"><disable_collisions link1="link_base" link2="link3" reason="Never"/></robot>"#,
    )
    .unwrap();
    let cfg = SafetyConfig {
        srdf: Some("r.srdf".into()),
        ..SafetyConfig::default()
    };
    let limits: Vec<(f64, f64, f64)> = robot
        .joint_limits()
        .iter()
        .map(|&(l, h)| (l, h, 3.0))
        .collect();
    let c =
        SafetyChecker::new(robot.clone(), &cfg, &limits, &dir.path().join("cell.toml")).unwrap();
    assert!(c
        .skipped_pairs
        .iter()
        .any(|(a, b, why)| a == "link_base" && b == "link3" && *why == "disabled in SRDF"));
}

//! The safety checker on its own: thin obstacles between path samples, self-collision,
//! limits and speed caps, SRDF pairs.

use std::path::PathBuf;
use std::sync::Arc;

use easyhec::config::{AttachedConfig, ObstacleConfig, SafetyConfig};
use easyhec::nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion};
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

/// The checker of `cfg`, or why it was refused.
fn try_checker(robot: &Arc<RobotModel>, cfg: &SafetyConfig) -> Result<SafetyChecker, String> {
    let limits: Vec<(f64, f64, f64)> = robot
        .joint_limits()
        .iter()
        .map(|&(lo, hi)| (lo, hi, 3.0))
        .collect();
    SafetyChecker::new(robot.clone(), cfg, &limits, &PathBuf::from("cell.toml"))
        .map_err(|e| e.to_string())
}

fn checker(robot: &Arc<RobotModel>, cfg: &SafetyConfig) -> SafetyChecker {
    try_checker(robot, cfg).unwrap()
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
    let Some(Violation::SelfCollision {
        links, clearance_m, ..
    }) = found
    else {
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

/// The table and, optionally, a 2 cm ball attached to link6 with its centre `ball_height_m`
/// above the table, straight below the flange at `q`.
fn table_and_ball_below_flange(
    robot: &Arc<RobotModel>,
    q: &[f64],
    ball_height_m: Option<f64>,
) -> SafetyConfig {
    let table = ObstacleConfig::Plane {
        name: "table".into(),
        normal: [0.0, 0.0, 1.0],
        offset_m: 0.0,
    };
    let attached = ball_height_m.map(|h| {
        let base_from_flange = robot.base_from_links(q)[robot.link_index("link6").unwrap()];
        let above = base_from_flange.translation.vector;
        let centre = base_from_flange.inverse() * Point3::new(above.x, above.y, h);
        AttachedConfig::Sphere {
            name: "probe".into(),
            link: "link6".into(),
            radius_m: 0.02,
            xyz: [centre.x, centre.y, centre.z],
        }
    });
    SafetyConfig {
        obstacles: vec![table],
        attached: attached.into_iter().collect(),
        margin_m: 0.01,
        ..SafetyConfig::default()
    }
}

#[test]
fn a_body_attached_to_a_link_is_checked_as_part_of_it() {
    let robot = xarm6();
    let q = [0.0, -0.35, -0.6, 0.0, 0.95, 0.0];
    let flange_z = robot.base_from_links(&q)[robot.link_index("link6").unwrap()]
        .translation
        .z;
    assert!(
        flange_z > 0.2,
        "the flange is well above the table: {flange_z}"
    );
    let bare = checker(&robot, &table_and_ball_below_flange(&robot, &q, None));
    let clear = bare.check_pose(&q).unwrap().environment_m;
    assert!(
        clear > 0.1,
        "without the ball the arm is far from the table: {clear}"
    );

    // The ball's lowest point 20 mm above the table: allowed, and it is the nearest piece.
    let held = checker(&robot, &table_and_ball_below_flange(&robot, &q, Some(0.04)));
    let clear = held.check_pose(&q).unwrap().environment_m;
    assert!((clear - 0.02).abs() < 1e-6, "{clear}");

    // 5 mm above the table, inside the 10 mm margin: refused, naming the body and its link.
    let low = checker(
        &robot,
        &table_and_ball_below_flange(&robot, &q, Some(0.025)),
    );
    let refusal = low.check_pose(&q).unwrap_err();
    assert_eq!(
        refusal.to_string(),
        "probe (attached to link6) within 5.0 mm of table"
    );
    match refusal {
        Violation::Environment {
            link,
            body,
            clearance_m,
            ..
        } => {
            assert_eq!((link.as_str(), body.as_deref()), ("link6", Some("probe")));
            assert!((clearance_m - 0.005).abs() < 1e-6, "{clearance_m}");
        }
        other => panic!("{other:?}"),
    }

    // Self-clearance counts it too: a ball on link6 put where link3 is.
    let mut cfg = table_and_ball_below_flange(&robot, &q, Some(0.5));
    let poses = robot.base_from_links(&q);
    let at_link3 = poses[robot.link_index("link6").unwrap()].inverse()
        * Point3::from(poses[robot.link_index("link3").unwrap()].translation.vector);
    if let AttachedConfig::Sphere { xyz, .. } = &mut cfg.attached[0] {
        *xyz = [at_link3.x, at_link3.y, at_link3.z];
    }
    match checker(&robot, &cfg).check_pose(&q) {
        Err(Violation::SelfCollision { links, bodies, .. }) => {
            let probe = (String::from("link6"), Some(String::from("probe")));
            let pieces = [(links.0, bodies.0), (links.1, bodies.1)];
            assert!(pieces.contains(&probe), "{pieces:?}");
        }
        other => panic!("{other:?}"),
    }

    // A body far out on the wrist sweeps faster: the path is sampled more finely for it.
    let mut from = q.to_vec();
    from[0] = -0.5;
    assert!(
        held.path_samples(&from, &q) > bare.path_samples(&from, &q),
        "{} vs {}",
        held.path_samples(&from, &q),
        bare.path_samples(&from, &q)
    );
}

#[test]
fn an_attached_body_on_a_link_the_urdf_lacks_is_refused() {
    let robot = xarm6();
    let mut cfg = table_and_ball_below_flange(&robot, &[0.0; 6], Some(0.5));
    if let AttachedConfig::Sphere { link, .. } = &mut cfg.attached[0] {
        *link = "flange".into();
    }
    let err = try_checker(&robot, &cfg)
        .err()
        .expect("an unknown link is refused");
    assert!(err.contains("safety.attached[0].link"), "{err}");
    assert!(err.contains("no link named 'flange'"), "{err}");
}

/// `world_from_body` (base frame) as a body's `(xyz, rpy_deg)` in link6's frame at `q`.
fn in_link6(
    robot: &RobotModel,
    q: &[f64],
    world_from_body: Isometry3<f64>,
) -> ([f64; 3], [f64; 3]) {
    let link6_from_world = robot.base_from_links(q)[robot.link_index("link6").unwrap()].inverse();
    let pose = link6_from_world * world_from_body;
    let (r, p, y) = pose.rotation.euler_angles();
    let t = pose.translation.vector;
    (
        [t.x, t.y, t.z],
        [r.to_degrees(), p.to_degrees(), y.to_degrees()],
    )
}

/// A 20 mm cube as an ASCII STL in millimetres, centred on its origin.
fn cube_stl_mm() -> String {
    let c = |i: usize| -> [f64; 3] {
        [(i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64].map(|v| v * 20.0 - 10.0)
    };
    // Two triangles per face, as corner indices (bit 0: x, bit 1: y, bit 2: z).
    let faces = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let mut stl = String::from("solid cube\n");
    for f in faces {
        for tri in [[f[0], f[1], f[2]], [f[0], f[2], f[3]]] {
            stl.push_str("facet normal 0 0 0\nouter loop\n");
            for i in tri {
                let v = c(i);
                stl.push_str(&format!("vertex {} {} {}\n", v[0], v[1], v[2]));
            }
            stl.push_str("endloop\nendfacet\n");
        }
    }
    stl.push_str("endsolid cube\n");
    stl
}

#[test]
fn a_turned_box_and_a_scaled_mesh_sit_where_the_config_puts_them() {
    let robot = xarm6();
    let q = [0.0, -0.35, -0.6, 0.0, 0.95, 0.0];
    let flange = robot.base_from_links(&q)[robot.link_index("link6").unwrap()]
        .translation
        .vector;
    // Level with the table in the base frame, centred 50 mm above it below the flange: its
    // lowest face is 40 mm up only if its turn in the link frame was applied as given.
    let world_from_body = Isometry3::from_parts(
        Translation3::new(flange.x, flange.y, 0.05),
        UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3),
    );
    let (xyz, rpy_deg) = in_link6(&robot, &q, world_from_body);
    assert!(
        rpy_deg.iter().any(|a| a.abs() > 10.0),
        "the link frame is turned: {rpy_deg:?}"
    );
    let mut cfg = table_and_ball_below_flange(&robot, &q, None);
    cfg.attached = vec![AttachedConfig::Box {
        name: "bar".into(),
        link: "link6".into(),
        size: [0.2, 0.02, 0.02],
        xyz,
        rpy_deg,
    }];
    let clear = checker(&robot, &cfg).check_pose(&q).unwrap().environment_m;
    assert!((clear - 0.04).abs() < 1e-6, "{clear}");

    // The same place for a 20 mm cube given in millimetres, scaled to metres.
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("cube.stl");
    std::fs::write(&file, cube_stl_mm()).unwrap();
    let cube = |scale: f64| AttachedConfig::Mesh {
        name: "cube".into(),
        link: "link6".into(),
        file: file.clone(),
        xyz,
        rpy_deg,
        scale: [scale; 3],
    };
    cfg.attached = vec![cube(0.001)];
    let clear = checker(&robot, &cfg).check_pose(&q).unwrap().environment_m;
    assert!((clear - 0.04).abs() < 1e-6, "{clear}");

    // Left in millimetres it would reach metres from the flange: refused, naming the fix.
    cfg.attached = vec![cube(1.0)];
    let err = try_checker(&robot, &cfg)
        .err()
        .expect("a body metres from its link is refused");
    assert!(
        err.contains("safety.attached[0]") && err.contains("scale = [0.001"),
        "{err}"
    );
}

/// An arm whose joint reading the test sets, recording every move it is sent.
struct ReadingArm {
    joints: Vec<easyhec_drivers::JointLimit>,
    reading: std::sync::Mutex<Vec<f64>>,
    moves: std::sync::Mutex<Vec<Vec<f64>>>,
}

#[async_trait::async_trait]
impl easyhec_drivers::Arm for ReadingArm {
    fn joints(&self) -> &[easyhec_drivers::JointLimit] {
        &self.joints
    }
    async fn read_joints(&self) -> easyhec_drivers::Result<Vec<f64>> {
        Ok(self.reading.lock().unwrap().clone())
    }
    async fn move_to(
        &self,
        target: &[f64],
        _speed_rad_s: f64,
    ) -> easyhec_drivers::Result<easyhec_drivers::Motion> {
        self.moves.lock().unwrap().push(target.to_vec());
        Ok(easyhec_drivers::Motion::new(async { Ok(()) }))
    }
    async fn stop(&self) -> easyhec_drivers::Result<()> {
        Ok(())
    }
    async fn status(&self) -> easyhec_drivers::Result<easyhec_drivers::ArmStatus> {
        Ok(easyhec_drivers::ArmStatus::Idle)
    }
}

/// The gated arm checks a move again from the arm's own reading: a non-finite reading, or
/// one (within the drift tolerance) from which the path fails its check, sends nothing.
#[test]
fn the_gated_arm_rechecks_each_move_from_where_the_arm_is() {
    let robot = xarm6();
    let c = Arc::new(checker(&robot, &SafetyConfig::default()));
    // A start 4 mrad inside a joint's upper limit, with a safe move away from it.
    let mid = [0.0, 0.3, -0.6, 0.0, 0.6, 0.0];
    let (k, upper, start, target, mv) = (0..mid.len())
        .find_map(|k| {
            let (_, upper) = robot.joint_limits()[k];
            let mut start = mid.to_vec();
            start[k] = upper - 0.004;
            let mut target = start.clone();
            target[k] -= 0.2;
            let mv = c.check_move(&start, &target, 0.5).ok()?;
            Some((k, upper, start, target, mv))
        })
        .expect("some joint can start at its upper limit");
    let arm = Arc::new(ReadingArm {
        joints: Vec::new(),
        reading: std::sync::Mutex::new(start.clone()),
        moves: std::sync::Mutex::new(Vec::new()),
    });
    let gated = easyhec::safety::SafeArm::new(arm.clone(), c.clone());
    let rt = tokio::runtime::Builder::new_current_thread()
        .build()
        .unwrap();
    let send = |reading: Vec<f64>| {
        *arm.reading.lock().unwrap() = reading;
        rt.block_on(gated.execute(&mv)).map(|_| ())
    };
    let mut nan = start.clone();
    nan[3] = f64::NAN;
    let e = send(nan).unwrap_err().to_string();
    assert!(e.contains("finite"), "{e}");
    // 0.008 rad off the planned start (inside the 0.01 rad tolerance) but past the joint's
    // upper limit: the path from there is refused.
    let mut past_limit = start.clone();
    past_limit[k] = upper + 0.004;
    let e = send(past_limit).unwrap_err().to_string();
    assert!(e.contains("fails its check"), "{e}");
    assert!(arm.moves.lock().unwrap().is_empty());
    send(start).unwrap();
    assert_eq!(*arm.moves.lock().unwrap(), vec![target]);
}

//! FK and visual geometry of the four vendor robots against `fk_reference.json`
//! (computed independently with yourdfpy + trimesh).

use std::path::PathBuf;

use easyhec::robot::{RobotModel, RobotSource};

fn shared() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/robots")
}

/// The reference file, its actuated joints, and `urdf` loaded with them (base link as stated).
fn load(robot: &str, urdf: PathBuf) -> (serde_json::Value, Vec<String>, RobotModel) {
    let reference: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(shared().join(robot).join("fk_reference.json")).unwrap(),
    )
    .unwrap();
    let joints: Vec<String> = reference["actuated_joints"]
        .as_array()
        .unwrap()
        .iter()
        .map(|j| j.as_str().unwrap().to_string())
        .collect();
    let model = RobotModel::load(&RobotSource {
        urdf,
        base_link: Some(reference["base_link"].as_str().unwrap().to_string()),
        joints: Some(joints.clone()),
        ..Default::default()
    })
    .unwrap();
    (reference, joints, model)
}

/// Compares every reference link pose the model has (all of them when `every_link`) to 1e-6;
/// returns how many were compared.
fn compare_links(
    label: &str,
    reference: &serde_json::Value,
    joints: &[String],
    model: &RobotModel,
    every_link: bool,
) -> usize {
    let mut checked = 0;
    for pose in reference["poses"].as_array().unwrap() {
        let q: Vec<f64> = joints
            .iter()
            .map(|j| pose["q"][j].as_f64().unwrap())
            .collect();
        let fk = model.base_from_links(&q);
        for (link, m) in pose["link_poses"].as_object().unwrap() {
            let Some(li) = model.link_index(link) else {
                assert!(!every_link, "{label}: link {link} missing");
                continue;
            };
            let got = fk[li].to_homogeneous();
            for r in 0..4 {
                for c in 0..4 {
                    let want = m[r][c].as_f64().unwrap();
                    assert!(
                        (got[(r, c)] - want).abs() < 1e-6,
                        "{label} {} {link} [{r}][{c}]: {} vs {want}",
                        pose["label"],
                        got[(r, c)]
                    );
                }
            }
            checked += 1;
        }
    }
    checked
}

fn check(robot: &str) {
    let (reference, joints, model) = load(robot, shared().join(robot).join("robot.urdf"));
    let poses = reference["poses"].as_array().unwrap();
    assert!(poses.len() >= 2);
    assert!(compare_links(robot, &reference, &joints, &model, true) > 10);
    for pose in poses {
        let q: Vec<f64> = joints
            .iter()
            .map(|j| pose["q"][j].as_f64().unwrap())
            .collect();
        // Visual bounds: DAE node transforms, units, visual origins and scales all applied.
        let verts = model.posed_vertices(&q);
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for v in &verts {
            for k in 0..3 {
                lo[k] = lo[k].min(v[k]);
                hi[k] = hi[k].max(v[k]);
            }
        }
        for k in 0..3 {
            let (wl, wh) = (
                pose["visual_aabb"]["min"][k].as_f64().unwrap(),
                pose["visual_aabb"]["max"][k].as_f64().unwrap(),
            );
            assert!(
                (lo[k] - wl).abs() < 1.5e-3 && (hi[k] - wh).abs() < 1.5e-3,
                "{robot} {} aabb axis {k}: [{}, {}] vs [{wl}, {wh}]",
                pose["label"],
                lo[k],
                hi[k]
            );
        }
    }
}

#[test]
fn xarm6_matches_reference() {
    check("xarm6");
}

#[test]
fn xarm7_matches_reference() {
    check("xarm7");
}

#[test]
fn ur5e_matches_reference() {
    check("ur5e");
}

#[test]
fn panda_matches_reference() {
    check("panda");
}

/// Our own simplified descriptions (robots/) carry the vendors' kinematics exactly.
fn check_own(robot: &str) {
    let urdf = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("robots")
        .join(robot)
        .join("robot.urdf");
    let (reference, joints, model) = load(robot, urdf);
    let compared = compare_links(&format!("own {robot}"), &reference, &joints, &model, false);
    assert!(
        compared >= 8 * reference["poses"].as_array().unwrap().len(),
        "own {robot}: only {compared} link poses compared"
    );
}

#[test]
fn own_descriptions_carry_vendor_kinematics() {
    for robot in ["xarm6", "ur5e", "panda"] {
        check_own(robot);
    }
}

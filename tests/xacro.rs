//! A vendor-style xacro description (properties, a link macro, arguments, a conditional, meshes
//! by `package://`) installed in a ROS 2 prefix: easyhec expands it with the xacro tool, finds
//! the meshes through `AMENT_PREFIX_PATH`, and gets the same robot as the URDF the xacro tool
//! writes. Needs `xacro` on PATH (`./test` installs it from PyPI).

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

use easyhec::collision::CollisionModel;
use easyhec::robot::{RobotModel, RobotSource};

const PACKAGE: &str = "demo_arm_description";

const XACRO: &str = r#"<?xml version="1.0"?>
<robot xmlns:xacro="http://www.ros.org/wiki/xacro" name="demo_arm">
  <xacro:arg name="prefix" default=""/>
  <xacro:arg name="with_tool" default="false"/>
  <xacro:property name="prefix" value="$(arg prefix)"/>
  <xacro:property name="upper_length" value="0.35"/>
  <xacro:property name="pi" value="3.141592653589793"/>

  <xacro:macro name="segment" params="name length">
    <link name="${prefix}${name}">
      <visual>
        <origin xyz="0 0 ${length / 2}" rpy="0 0 0"/>
        <geometry>
          <mesh filename="package://demo_arm_description/meshes/unit_box.obj"
                scale="0.08 0.08 ${length}"/>
        </geometry>
      </visual>
      <collision>
        <origin xyz="0 0 ${length / 2}" rpy="0 0 0"/>
        <geometry><box size="0.08 0.08 ${length}"/></geometry>
      </collision>
    </link>
  </xacro:macro>

  <link name="${prefix}base_link"/>
  <xacro:segment name="shoulder" length="0.2"/>
  <xacro:segment name="upper_arm" length="${upper_length}"/>
  <xacro:segment name="forearm" length="${upper_length * 0.8}"/>

  <joint name="${prefix}joint1" type="revolute">
    <parent link="${prefix}base_link"/><child link="${prefix}shoulder"/>
    <origin xyz="0 0 0.1" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit lower="${-pi}" upper="${pi}" effort="10" velocity="2"/>
  </joint>
  <joint name="${prefix}joint2" type="revolute">
    <parent link="${prefix}shoulder"/><child link="${prefix}upper_arm"/>
    <origin xyz="0 0 0.2" rpy="${pi / 2} 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-2" upper="2" effort="10" velocity="2"/>
  </joint>
  <joint name="${prefix}joint3" type="revolute">
    <parent link="${prefix}upper_arm"/><child link="${prefix}forearm"/>
    <origin xyz="0 ${upper_length} 0" rpy="0 0 0.3"/><axis xyz="0 0 1"/>
    <limit lower="-2.5" upper="2.5" effort="10" velocity="2"/>
  </joint>
  <xacro:if value="$(arg with_tool)">
    <xacro:segment name="tool" length="0.1"/>
    <joint name="${prefix}tool_joint" type="fixed">
      <parent link="${prefix}forearm"/><child link="${prefix}tool"/>
      <origin xyz="0 0 ${upper_length * 0.8}"/>
    </joint>
  </xacro:if>
</robot>
"#;

/// A unit cube centred on the origin, as an OBJ mesh.
const UNIT_BOX: &str = "v -0.5 -0.5 -0.5\nv 0.5 -0.5 -0.5\nv 0.5 0.5 -0.5\nv -0.5 0.5 -0.5\n\
v -0.5 -0.5 0.5\nv 0.5 -0.5 0.5\nv 0.5 0.5 0.5\nv -0.5 0.5 0.5\n\
f 1 3 2\nf 1 4 3\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\nf 3 4 8\nf 3 8 7\nf 4 1 5\nf 4 5 8\n";

/// Installs the package as `colcon build` would: `PREFIX/share/PKG` plus its ament index entry.
fn install(prefix: &Path) -> std::path::PathBuf {
    let share = prefix.join("share").join(PACKAGE);
    std::fs::create_dir_all(share.join("urdf")).unwrap();
    std::fs::create_dir_all(share.join("meshes")).unwrap();
    std::fs::write(
        share.join("package.xml"),
        format!("<?xml version=\"1.0\"?>\n<package format=\"3\"><name>{PACKAGE}</name><version>0.1.0</version></package>\n"),
    )
    .unwrap();
    std::fs::write(share.join("meshes/unit_box.obj"), UNIT_BOX).unwrap();
    let index = prefix.join("share/ament_index/resource_index/packages");
    std::fs::create_dir_all(&index).unwrap();
    std::fs::write(index.join(PACKAGE), "").unwrap();
    let xacro = share.join("urdf/demo_arm.urdf.xacro");
    std::fs::write(&xacro, XACRO).unwrap();
    xacro
}

#[test]
fn xacro_description_with_ament_meshes_matches_the_expanded_urdf() {
    let dir = tempfile::tempdir().unwrap();
    let prefix = dir.path().join("install");
    let xacro = install(&prefix);
    // A second, empty prefix first on the path, as in an overlay workspace.
    let empty = dir.path().join("empty_overlay");
    std::fs::create_dir_all(&empty).unwrap();
    let path = std::env::join_paths([&empty, &prefix]).unwrap();
    // This test binary has no other test, so no thread reads the environment meanwhile.
    std::env::set_var("AMENT_PREFIX_PATH", &path);
    std::env::remove_var("ROS_PACKAGE_PATH");

    let args = BTreeMap::from([
        ("prefix".to_string(), "left_".to_string()),
        ("with_tool".to_string(), "true".to_string()),
    ]);
    let from_xacro = RobotModel::load(&RobotSource {
        urdf: xacro.clone(),
        xacro_args: args.clone(),
        ..Default::default()
    })
    .unwrap_or_else(|e| panic!("{e} (is `xacro` installed? ./test installs it)"));

    let expanded = Command::new("xacro")
        .arg(&xacro)
        .args(args.iter().map(|(k, v)| format!("{k}:={v}")))
        .output()
        .expect("the xacro tool runs");
    assert!(
        expanded.status.success(),
        "{}",
        String::from_utf8_lossy(&expanded.stderr)
    );
    let urdf = dir.path().join("demo_arm.urdf");
    std::fs::write(&urdf, &expanded.stdout).unwrap();
    let from_urdf = RobotModel::from_urdf(&urdf).unwrap();

    assert_eq!(
        from_xacro.joint_names(),
        ["left_joint1", "left_joint2", "left_joint3"]
    );
    assert!(
        from_xacro.links.iter().any(|l| l == "left_tool"),
        "with_tool:=true reached xacro"
    );
    assert_eq!(from_xacro.links, from_urdf.links);
    // Four boxes of 12 triangles, found through AMENT_PREFIX_PATH.
    assert_eq!(from_xacro.visual.triangles.len(), 48);
    assert_eq!(
        from_xacro.visual.vertices.len(),
        from_urdf.visual.vertices.len()
    );
    for q in [[0.0, 0.0, 0.0], [0.4, -1.1, 2.0], [-2.9, 1.7, -0.6]] {
        let (a, b) = (
            from_xacro.base_from_links(&q),
            from_urdf.base_from_links(&q),
        );
        for (x, y) in a.iter().zip(&b) {
            assert!((x.translation.vector - y.translation.vector).norm() < 1e-12);
            assert!(x.rotation.angle_to(&y.rotation) < 1e-12);
        }
    }
    // The safety checker's collision geometry comes from the same expansion: one box per
    // segment, none lost to the xacro markup.
    let collision = CollisionModel::load(&from_xacro).unwrap();
    assert_eq!(collision.elements.len(), 4);
    assert_eq!(
        collision.elements.len(),
        CollisionModel::load(&from_urdf).unwrap().elements.len()
    );
    // The tool link sits at the forearm's end: 0.1 + 0.2 up, then the arm in the lifted plane.
    let tool = from_xacro
        .links
        .iter()
        .position(|l| l == "left_tool")
        .unwrap();
    let at_zero = from_xacro.base_from_links(&[0.0, 0.0, 0.0])[tool];
    assert!(at_zero.translation.vector.norm() > 0.5, "{at_zero:?}");

    // Without the default arguments' override, and with a bad one, as a user would see them.
    let plain = RobotModel::load(&RobotSource {
        urdf: xacro.clone(),
        ..Default::default()
    })
    .unwrap();
    assert_eq!(plain.joint_names(), ["joint1", "joint2", "joint3"]);
    let bad = RobotModel::load(&RobotSource {
        urdf: xacro.clone(),
        xacro_args: BTreeMap::from([("bad name".to_string(), "x".to_string())]),
        ..Default::default()
    })
    .unwrap_err()
    .to_string();
    assert!(
        bad.contains("robot.xacro_args") && bad.lines().count() == 1,
        "{bad}"
    );
    std::env::remove_var("AMENT_PREFIX_PATH");
    let unresolved = RobotModel::load(&RobotSource {
        urdf: xacro,
        ..Default::default()
    })
    .unwrap_err()
    .to_string();
    assert!(
        unresolved.contains(PACKAGE) && unresolved.contains("AMENT_PREFIX_PATH"),
        "{unresolved}"
    );
}

//! A robot described as vendors ship ROS 2 descriptions, for a robot that is not in robots/:
//! two packages, the top-level `.xacro` in one (`acme_bringup`) including the other's macro
//! file through `$(find acme_description)`, joint limits read with `xacro.load_yaml`, `$(arg)`s,
//! and `package://` COLLADA visuals and STL collision meshes. easyhec must load it with nothing
//! of ROS but PyPI's `xacro`, both from an install prefix on `AMENT_PREFIX_PATH` and from a
//! cloned source tree named in `package_paths`, and get the same robot as the URDF that xacro
//! writes with the real `ament_index_python` (PyPI's `ros-ament-index-python`, which `./test`
//! installs); then calibrate a simulated cell of it.

mod common;

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

use easyhec::cell::Cell;
use easyhec::config::read_config;
use easyhec::geometry::{rotation_error_deg, translation_error_mm};
use easyhec::robot::{RobotModel, RobotSource};

const SEGMENTS: usize = 24;

/// A cylinder of radius 0.5 and length 1 along z, centred on the origin (URDF's convention,
/// so `scale="2r 2r L"` makes a `<cylinder radius="r" length="L"/>`), as triangles.
fn unit_cylinder() -> Vec<[[f64; 3]; 3]> {
    let ring = |k: usize, z: f64| {
        let a = std::f64::consts::TAU * k as f64 / SEGMENTS as f64;
        [0.5 * a.cos(), 0.5 * a.sin(), z]
    };
    let mut t = Vec::new();
    for k in 0..SEGMENTS {
        let (a0, a1) = (ring(k, -0.5), ring(k + 1, -0.5));
        let (b0, b1) = (ring(k, 0.5), ring(k + 1, 0.5));
        t.push([a0, a1, b1]);
        t.push([a0, b1, b0]);
        t.push([[0.0, 0.0, 0.5], b0, b1]);
        t.push([[0.0, 0.0, -0.5], a1, a0]);
    }
    t
}

fn stl(tris: &[[[f64; 3]; 3]]) -> String {
    let mut s = String::from("solid cylinder\n");
    for tri in tris {
        s.push_str("facet normal 0 0 0\nouter loop\n");
        for v in tri {
            let _ = writeln!(s, "vertex {} {} {}", v[0], v[1], v[2]);
        }
        s.push_str("endloop\nendfacet\n");
    }
    s + "endsolid cylinder\n"
}

fn collada(tris: &[[[f64; 3]; 3]]) -> String {
    let floats: Vec<String> = tris
        .iter()
        .flatten()
        .flatten()
        .map(|v| v.to_string())
        .collect();
    let indices: Vec<String> = (0..tris.len() * 3).map(|i| i.to_string()).collect();
    format!(
        r##"<?xml version="1.0"?>
<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
  <asset><unit name="meter" meter="1"/><up_axis>Z_UP</up_axis></asset>
  <library_geometries><geometry id="g"><mesh>
    <source id="p"><float_array id="pa" count="{n}">{floats}</float_array>
      <technique_common><accessor source="#pa" count="{v}" stride="3"><param name="X" type="float"/><param name="Y" type="float"/><param name="Z" type="float"/></accessor></technique_common></source>
    <vertices id="v"><input semantic="POSITION" source="#p"/></vertices>
    <triangles count="{t}"><input semantic="VERTEX" source="#v" offset="0"/><p>{indices}</p></triangles>
  </mesh></geometry></library_geometries>
  <library_visual_scenes><visual_scene id="s"><node id="n"><instance_geometry url="#g"/></node></visual_scene></library_visual_scenes>
  <scene><instance_visual_scene url="#s"/></scene>
</COLLADA>
"##,
        n = floats.len(),
        floats = floats.join(" "),
        v = tris.len() * 3,
        t = tris.len(),
        indices = indices.join(" "),
    )
}

/// The value of attribute `name` in one line of URDF.
fn attr<'a>(line: &'a str, name: &str) -> &'a str {
    let start = line.find(&format!("{name}=\"")).unwrap() + name.len() + 2;
    &line[start..start + line[start..].find('"').unwrap()]
}

/// The xArm6 of robots/ rewritten as a vendor's macro: names behind `${prefix}`, limits from
/// the YAML file, every cylinder a `package://` mesh. Returns the macro and the YAML.
fn vendor_macro() -> (String, String) {
    let urdf = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots/xarm6/robot.urdf"),
    )
    .unwrap();
    let mut body = String::new();
    let mut yaml = String::new();
    let mut joint = String::new();
    for line in urdf.lines() {
        let t = line.trim_start();
        if t.starts_with("<?xml")
            || t.starts_with("<!--")
            || t.starts_with("<robot")
            || t.starts_with("</robot")
        {
            continue;
        }
        let mut out = line
            .replace("<link name=\"", "<link name=\"${prefix}")
            .replace("link=\"", "link=\"${prefix}")
            .replace("<joint name=\"", "<joint name=\"${prefix}");
        if t.starts_with("<joint ") {
            joint = attr(t, "name").to_string();
        }
        if t.starts_with("<limit ") {
            let _ = writeln!(
                yaml,
                "{joint}:\n  lower: {}\n  upper: {}",
                attr(t, "lower"),
                attr(t, "upper")
            );
            out = out
                .replace(
                    &format!("lower=\"{}\"", attr(t, "lower")),
                    &format!("lower=\"${{limits['{joint}']['lower']}}\""),
                )
                .replace(
                    &format!("upper=\"{}\"", attr(t, "upper")),
                    &format!("upper=\"${{limits['{joint}']['upper']}}\""),
                );
        }
        if let Some(at) = out.find("<cylinder ") {
            let end = at + out[at..].find("/>").unwrap() + 2;
            let (r, l): (f64, &str) = (
                attr(&out[at..end], "radius").parse().unwrap(),
                attr(&out[at..end], "length"),
            );
            let (kind, ext) = if t.starts_with("<visual>") {
                ("visual", "dae")
            } else {
                ("collision", "stl")
            };
            let mesh = format!(
                "<mesh filename=\"package://acme_description/meshes/{kind}/unit_cylinder.{ext}\" scale=\"{d} {d} {l}\"/>",
                d = 2.0 * r
            );
            out.replace_range(at..end, &mesh);
        }
        body.push_str(&out);
        body.push('\n');
    }
    let text = format!(
        r#"<?xml version="1.0"?>
<robot xmlns:xacro="http://www.ros.org/wiki/xacro">
  <xacro:macro name="acme_arm" params="prefix limits_file">
    <xacro:property name="limits" value="${{xacro.load_yaml(limits_file)}}"/>
{body}  </xacro:macro>
</robot>
"#
    );
    (text, yaml)
}

const BRINGUP: &str = r#"<?xml version="1.0"?>
<robot xmlns:xacro="http://www.ros.org/wiki/xacro" name="$(arg robot_name)">
  <xacro:arg name="robot_name" default="acme"/>
  <xacro:arg name="prefix" default=""/>
  <xacro:arg name="limits" default="$(find acme_description)/config/joint_limits.yaml"/>
  <xacro:include filename="$(find acme_description)/urdf/acme_macro.xacro"/>
  <xacro:acme_arm prefix="$(arg prefix)" limits_file="$(arg limits)"/>
</robot>
"#;

fn manifest(name: &str) -> String {
    format!("<?xml version=\"1.0\"?>\n<package format=\"3\"><name>{name}</name><version>1.0.0</version><description>d</description><maintainer email=\"a@b.c\">a</maintainer><license>none</license></package>\n")
}

/// Writes both packages under `root/<dir of each>`; returns the top-level xacro.
fn write_packages(description: &Path, bringup: &Path) -> PathBuf {
    let (macro_text, yaml) = vendor_macro();
    let tris = unit_cylinder();
    for (path, text) in [
        (
            description.join("package.xml"),
            manifest("acme_description"),
        ),
        (description.join("urdf/acme_macro.xacro"), macro_text),
        (description.join("config/joint_limits.yaml"), yaml),
        (
            description.join("meshes/visual/unit_cylinder.dae"),
            collada(&tris),
        ),
        (
            description.join("meshes/collision/unit_cylinder.stl"),
            stl(&tris),
        ),
        (bringup.join("package.xml"), manifest("acme_bringup")),
        (bringup.join("urdf/cell.urdf.xacro"), BRINGUP.to_string()),
    ] {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, text).unwrap();
    }
    bringup.join("urdf/cell.urdf.xacro")
}

/// As `colcon build` installs it: `PREFIX/share/PKG`, with the ament index or without it.
fn install_prefix(prefix: &Path, with_index: bool) -> PathBuf {
    let share = prefix.join("share");
    let top = write_packages(&share.join("acme_description"), &share.join("acme_bringup"));
    if with_index {
        let index = share.join("ament_index/resource_index/packages");
        std::fs::create_dir_all(&index).unwrap();
        for p in ["acme_description", "acme_bringup"] {
            std::fs::write(index.join(p), "").unwrap();
        }
    }
    top
}

/// As `git clone` leaves a description repository: both packages in one folder.
fn source_tree(repo: &Path) -> PathBuf {
    write_packages(&repo.join("acme_description"), &repo.join("acme_bringup"))
}

fn args() -> BTreeMap<String, String> {
    BTreeMap::from([("robot_name".to_string(), "acme_xarm6".to_string())])
}

/// The reference: xacro's own expansion with the real `ament_index_python` resolving `$(find)`
/// from the install prefix, loaded as a plain URDF with the meshes' packages named.
fn reference(top: &Path, prefix: &Path, dir: &Path) -> RobotModel {
    let out = Command::new("xacro")
        .arg(top)
        .arg("robot_name:=acme_xarm6")
        .env("AMENT_PREFIX_PATH", prefix)
        .env_remove("PYTHONPATH")
        .output()
        .expect("the xacro tool runs (./test installs it)");
    assert!(
        out.status.success(),
        "xacro with the real resolver (./test installs ros-ament-index-python): {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let urdf = dir.join("reference.urdf");
    std::fs::write(&urdf, &out.stdout).unwrap();
    let share = prefix.join("share");
    RobotModel::load(&RobotSource {
        urdf,
        package_dirs: BTreeMap::from([(
            "acme_description".to_string(),
            share.join("acme_description"),
        )]),
        ..Default::default()
    })
    .unwrap()
}

fn assert_same_robot(a: &RobotModel, b: &RobotModel, what: &str) {
    assert_eq!(a.name, "acme_xarm6", "{what}: xacro_args reached xacro");
    assert_eq!(a.links, b.links, "{what}");
    assert_eq!(a.joint_names(), b.joint_names(), "{what}");
    assert_eq!(
        a.joint_limits(),
        b.joint_limits(),
        "{what}: limits from load_yaml"
    );
    assert_eq!(
        a.visual.vertices.len(),
        b.visual.vertices.len(),
        "{what}: .dae meshes"
    );
    assert_eq!(
        a.visual.triangles.len(),
        11 * SEGMENTS * 4,
        "{what}: one mesh per cylinder"
    );
    for q in [
        [0.0; 6],
        [0.4, -1.1, -0.6, 0.3, 1.2, -2.0],
        [-2.9, 1.7, -0.1, 2.0, -0.8, 0.6],
    ] {
        for (x, y) in a.base_from_links(&q).iter().zip(&b.base_from_links(&q)) {
            assert!(
                (x.translation.vector - y.translation.vector).norm() < 1e-12,
                "{what}"
            );
            assert!(x.rotation.angle_to(&y.rotation) < 1e-12, "{what}");
        }
    }
    let collision = easyhec::collision::CollisionModel::load(a).unwrap();
    assert_eq!(
        collision.elements.len(),
        11,
        "{what}: .stl collision meshes"
    );
}

#[test]
fn a_vendor_description_loads_from_a_prefix_or_a_clone_and_calibrates() {
    std::env::remove_var("AMENT_PREFIX_PATH");
    std::env::remove_var("ROS_PACKAGE_PATH");
    let errors = tempfile::tempdir().unwrap();
    missing_twice_and_failing_each_say_why(errors.path());
    let dir = tempfile::tempdir().unwrap();
    let prefix = dir.path().join("install");
    let installed = install_prefix(&prefix, true);
    let reference = reference(&installed, &prefix, dir.path());

    // 1. Installed under a prefix on AMENT_PREFIX_PATH (this test binary's only test that
    //    touches the environment, and the only one running when it does).
    std::env::set_var("AMENT_PREFIX_PATH", &prefix);
    std::env::remove_var("ROS_PACKAGE_PATH");
    let from_prefix = RobotModel::load(&RobotSource {
        urdf: installed.clone(),
        xacro_args: args(),
        ..Default::default()
    })
    .unwrap_or_else(|e| panic!("{e}"));
    assert_same_robot(&from_prefix, &reference, "install prefix");
    let bare = dir.path().join("install_without_index");
    let bare_top = install_prefix(&bare, false);
    std::env::set_var("AMENT_PREFIX_PATH", &bare);
    let from_bare = RobotModel::load(&RobotSource {
        urdf: bare_top,
        xacro_args: args(),
        ..Default::default()
    })
    .unwrap_or_else(|e| panic!("{e}"));
    assert_same_robot(&from_bare, &reference, "prefix without the ament index");
    std::env::remove_var("AMENT_PREFIX_PATH");

    // 2. A clone anywhere, named in package_paths: a simulated cell of it, calibrated.
    let clone = dir.path().join("src/acme_robots");
    let top = source_tree(&clone);
    let from_clone = RobotModel::load(&RobotSource {
        urdf: top.clone(),
        xacro_args: args(),
        package_paths: vec![dir.path().join("src")],
        ..Default::default()
    })
    .unwrap_or_else(|e| panic!("{e}"));
    assert_same_robot(&from_clone, &reference, "source tree in package_paths");

    let text = common::shipped_config_text("sim-xarm6.toml");
    let robot_line = text
        .lines()
        .find(|l| l.starts_with("urdf = "))
        .unwrap()
        .to_string();
    let text = text.replace(
        &robot_line,
        &format!(
            "urdf = {:?}\npackage_paths = [{:?}]\nxacro_args = {{ robot_name = \"acme_xarm6\" }}",
            top.display().to_string(),
            "src"
        ),
    );
    let config = dir.path().join("cell.toml");
    std::fs::write(&config, text).unwrap();
    let mut cfg = read_config(&config).unwrap();
    cfg.calibration.max_views = 5;
    let cell = Cell::build(cfg, &config).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(cell.robot.name, "acme_xarm6");
    let outcome = common::run_loop(&cell, &dir.path().join("run"));
    let truth = cell.units[0].sim.camera_from_base.unwrap();
    let estimate = outcome.result.camera_from_base();
    let (deg, mm) = (
        rotation_error_deg(&estimate, &truth),
        translation_error_mm(&estimate, &truth),
    );
    println!("vendor description, closed loop: {deg:.4} deg, {mm:.3} mm");
    assert!(deg <= 0.08 && mm <= 0.5, "{deg} deg, {mm} mm");
    // The run records the search folders, so `easyhec solve` finds the packages again.
    let solved = common::solve_run(&dir.path().join("run"), &[]);
    assert!(
        solved.status.success(),
        "{}",
        String::from_utf8_lossy(&solved.stderr)
    );
}

/// A missing package, a package found twice and a failing xacro each say why in one line.
/// Called before the other checks set `AMENT_PREFIX_PATH`, which would answer `$(find)`.
fn missing_twice_and_failing_each_say_why(dir: &Path) {
    let clone = dir.join("src");
    let top = source_tree(&clone);
    let load = |urdf: &Path, paths: Vec<PathBuf>| {
        RobotModel::load(&RobotSource {
            urdf: urdf.to_path_buf(),
            package_paths: paths,
            xacro_args: args(),
            ..Default::default()
        })
        .err()
        .map(|e| e.to_string())
        .unwrap_or_else(|| panic!("{} loaded", urdf.display()))
    };
    // The description package is not where the search looks.
    let e = load(&top, vec![dir.join("elsewhere")]);
    assert!(
        e.contains("acme_description")
            && e.contains("not found")
            && e.contains("robot.package_paths"),
        "{e}"
    );
    assert_eq!(e.lines().count(), 1, "{e}");
    assert!(!e.contains("when processing file"), "{e}");
    // Found twice: two clones both searched.
    let twin = dir.join("twin");
    source_tree(&twin);
    let e = load(&top, vec![clone.clone(), twin]);
    assert!(
        e.contains("acme_description") && e.contains("found twice"),
        "{e}"
    );
    // A macro with a typo: xacro's own cause, not its location line.
    let bad = top.with_file_name("bad.urdf.xacro");
    std::fs::write(
        &bad,
        BRINGUP.replace("prefix=\"$(arg prefix)\"", "prefix=\"${prefx}\""),
    )
    .unwrap();
    let e = load(&bad, vec![clone]);
    assert!(e.contains("prefx") && e.contains("not defined"), "{e}");
    assert_eq!(e.lines().count(), 1, "{e}");
}

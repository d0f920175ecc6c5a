//! `easyhec export`: every form parses back, with its own reader where one is at hand, to the
//! transform the result holds (or to the camera root link's edge with --optical-from-child).

mod common;

use std::io::Write as _;
use std::path::Path;
use std::process::{Command, Stdio};

use easyhec::geometry::{exp_se3, from_rows, rotation_error_deg, translation_error_mm, Twist};
use easyhec::run::ResultFile;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

fn export(result: &Path, args: &[&str]) -> String {
    let out = Command::new(common::easyhec_bin())
        .arg("export")
        .arg(result)
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

fn pose_from(t: [f64; 3], q_xyzw: [f64; 4]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_quaternion(Quaternion::new(
            q_xyzw[3], q_xyzw[0], q_xyzw[1], q_xyzw[2],
        )),
    )
}

fn assert_same(got: &Isometry3<f64>, want: &Isometry3<f64>, what: &str) {
    let (rot, trans) = (
        rotation_error_deg(got, want),
        translation_error_mm(got, want),
    );
    assert!(rot < 1e-9 && trans < 1e-9, "{what}: {rot} deg, {trans} mm");
}

/// A result on disk and the `base_from_optical` it holds.
fn result_file(dir: &Path) -> (std::path::PathBuf, Isometry3<f64>) {
    let camera_from_base = exp_se3(&Twist::new(0.3, -0.2, 1.1, 0.5, -1.2, 2.0));
    let path = dir.join("result.json");
    easyhec::io::write_json_atomic(&path, &ResultFile::new(&camera_from_base, "link_base"))
        .unwrap();
    (path, camera_from_base.inverse())
}

fn yaml(text: &str) -> serde_yaml_ng::Value {
    serde_yaml_ng::from_str(text).unwrap()
}

fn f(v: &serde_yaml_ng::Value) -> f64 {
    v.as_f64().unwrap()
}

fn yaml_edge(v: &serde_yaml_ng::Value) -> Isometry3<f64> {
    let (t, r) = (&v["translation"], &v["rotation"]);
    pose_from(
        ["x", "y", "z"].map(|k| f(&t[k])),
        ["x", "y", "z", "w"].map(|k| f(&r[k])),
    )
}

/// Runs a Python `script` with `args`, `stdin` on its standard input.
fn python(script: &str, args: &[&str], stdin: &str) -> std::process::Output {
    let mut child = Command::new("python3")
        .arg("-c")
        .arg(script)
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("python3 runs");
    child
        .stdin
        .take()
        .unwrap()
        .write_all(stdin.as_bytes())
        .unwrap();
    child.wait_with_output().unwrap()
}

/// Parses `text` with PyYAML (YAML 1.1, the parser easy_handeye and easy_handeye2 load their
/// files with) and checks that every number under `key` came back a Python float.
fn assert_pyyaml_floats(text: &str, key: &str) {
    let script = "import sys, yaml\n\
        d = yaml.safe_load(sys.stdin)[sys.argv[1]]\n\
        def leaves(v):\n\
        \x20   if isinstance(v, dict):\n\
        \x20       for x in v.values(): yield from leaves(x)\n\
        \x20   else: yield v\n\
        bad = [v for v in leaves(d) if not isinstance(v, float)]\n\
        assert not bad, bad\n";
    let out = python(script, &[key], text);
    assert!(
        out.status.success(),
        "PyYAML reads non-floats under {key}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The launch file's `arguments=[...]`, read by Python's own parser (so the file is valid
/// Python), and the `ros2 run` command in its header, split into words.
fn launch_arguments(text: &str) -> (Vec<String>, Vec<String>) {
    let script = "import ast, json, sys\n\
        tree = ast.parse(sys.stdin.read())\n\
        kw = [k for k in ast.walk(tree) if isinstance(k, ast.keyword) and k.arg == 'arguments']\n\
        assert len(kw) == 1\n\
        print(json.dumps(ast.literal_eval(kw[0].value)))\n";
    let out = python(script, &[], text);
    assert!(out.status.success(), "the launch file is not valid Python");
    let listed: Vec<String> = serde_json::from_slice(&out.stdout).unwrap();
    let command = text
        .lines()
        .find_map(|l| l.strip_prefix("#   ros2 run tf2_ros static_transform_publisher "))
        .expect("the ros2 run command is in the header");
    (
        listed,
        command.split_whitespace().map(str::to_string).collect(),
    )
}

fn named(args: &[String], name: &str) -> String {
    let i = args.iter().position(|a| a == name).unwrap();
    args[i + 1].clone()
}

fn publisher_edge(args: &[String]) -> Isometry3<f64> {
    let n = |k: &str| named(args, k).parse::<f64>().unwrap();
    pose_from(
        [n("--x"), n("--y"), n("--z")],
        [n("--qx"), n("--qy"), n("--qz"), n("--qw")],
    )
}

#[test]
fn every_form_parses_back_to_the_results_transform() {
    let dir = tempfile::tempdir().unwrap();
    let (path, base_from_optical) = result_file(dir.path());
    let frames = ["--child-frame-id", "cam_optical"];

    let cv = export(&path, &[&["--format", "opencv"][..], &frames].concat());
    let body: String = cv
        .lines()
        .filter(|l| !l.starts_with('%') && !l.starts_with("---"))
        .collect::<Vec<_>>()
        .join("\n")
        .replace("!!opencv-matrix", "");
    let data: Vec<f64> = yaml(&body)["camera_from_base"]["data"]
        .as_sequence()
        .unwrap()
        .iter()
        .map(f)
        .collect();
    let rows = [0, 1, 2, 3].map(|r| [0, 1, 2, 3].map(|c| data[r * 4 + c]));
    assert_same(
        &from_rows(&rows).unwrap(),
        &base_from_optical.inverse(),
        "opencv",
    );

    let (listed, command) = launch_arguments(&export(
        &path,
        &[&["--format", "ros"][..], &frames].concat(),
    ));
    assert_eq!(listed, command, "the launch file and the command agree");
    assert_eq!(named(&listed, "--frame-id"), "link_base");
    assert_eq!(named(&listed, "--child-frame-id"), "cam_optical");
    assert_same(&publisher_edge(&listed), &base_from_optical, "ros");

    let text = export(
        &path,
        &[&["--format", "easy-handeye-ros1"][..], &frames].concat(),
    );
    assert_pyyaml_floats(&text, "transformation");
    let y = yaml(&text);
    let t = &y["transformation"];
    let flat = pose_from(
        ["x", "y", "z"].map(|k| f(&t[k])),
        ["qx", "qy", "qz", "qw"].map(|k| f(&t[k])),
    );
    assert_same(&flat, &base_from_optical, "easy-handeye-ros1");
    assert_eq!(y["eye_on_hand"].as_bool(), Some(false));
    assert_eq!(y["tracking_base_frame"].as_str(), Some("cam_optical"));

    let urdf = export(&path, &[&["--format", "urdf"][..], &frames].concat());
    let robot = urdf_rs::read_from_string(&format!(
        "<robot name=\"r\"><link name=\"link_base\"/>{urdf}</robot>"
    ))
    .unwrap();
    let o = &robot.joints[0].origin;
    assert_eq!(robot.joints[0].child.link, "cam_optical");
    assert_same(
        &easyhec::geometry::from_xyz_rpy(o.xyz.0, o.rpy.0),
        &base_from_optical,
        "urdf",
    );
}

/// easy_handeye2 loads its file into an `easy_handeye2_msgs/HandeyeCalibration` field by
/// field: the file must hold exactly that message's fields, and its publisher sends
/// `transform` from `robot_base_frame` to `tracking_base_frame`.
#[test]
fn the_easy_handeye2_file_holds_that_messages_fields() {
    let dir = tempfile::tempdir().unwrap();
    let (path, base_from_optical) = result_file(dir.path());
    let text = export(
        &path,
        &[
            "--format",
            "easy-handeye",
            "--child-frame-id",
            "cam_optical",
        ],
    );
    assert_pyyaml_floats(&text, "transform");
    let y = yaml(&text);
    let keys = |v: &serde_yaml_ng::Value| -> Vec<String> {
        v.as_mapping()
            .unwrap()
            .keys()
            .map(|k| k.as_str().unwrap().to_string())
            .collect()
    };
    assert_eq!(keys(&y), ["parameters", "transform"]);
    assert_eq!(
        keys(&y["parameters"]),
        [
            "name",
            "calibration_type",
            "robot_base_frame",
            "robot_effector_frame",
            "tracking_base_frame",
            "tracking_marker_frame",
            "freehand_robot_movement",
            "move_group_namespace",
            "move_group",
        ]
    );
    assert_eq!(keys(&y["transform"]), ["translation", "rotation"]);
    let p = &y["parameters"];
    assert_eq!(p["calibration_type"].as_str(), Some("eye_on_base"));
    assert_eq!(p["robot_base_frame"].as_str(), Some("link_base"));
    assert_eq!(p["tracking_base_frame"].as_str(), Some("cam_optical"));
    assert_eq!(p["freehand_robot_movement"].as_bool(), Some(false));
    assert_same(
        &yaml_edge(&y["transform"]),
        &base_from_optical,
        "easy-handeye",
    );
}

/// With the driver's `optical_from_child`, the exported edge attaches the camera's root link,
/// and composing it back with the driver's edge gives the optical frame the result holds.
#[test]
fn optical_from_child_moves_the_edge_to_the_camera_root_link() {
    let dir = tempfile::tempdir().unwrap();
    let (path, base_from_optical) = result_file(dir.path());
    // A RealSense-like root link: optical = link rotated by (-90° about z, then -90° about x).
    let link_from_optical = pose_from([0.0, 0.015, 0.0], [-0.5, 0.5, -0.5, 0.5]);
    let optical_from_link = link_from_optical.inverse();
    let t = optical_from_link.translation.vector;
    let q = optical_from_link.rotation;
    let given = format!(
        "{:.17e} {:.17e} {:.17e} {:.17e} {:.17e} {:.17e} {:.17e}",
        t.x, t.y, t.z, q.i, q.j, q.k, q.w
    );
    let (listed, _) = launch_arguments(&export(
        &path,
        &[
            "--format",
            "ros",
            "--frame-id",
            "world",
            "--child-frame-id",
            "camera_link",
            "--optical-from-child",
            &given,
        ],
    ));
    assert_eq!(named(&listed, "--frame-id"), "world");
    assert_eq!(named(&listed, "--child-frame-id"), "camera_link");
    let base_from_link = publisher_edge(&listed);
    assert_same(
        &(base_from_link * link_from_optical),
        &base_from_optical,
        "base_from_link · link_from_optical",
    );
}

/// The page takes the export formats from the download route's `format` parameter in
/// `/openapi.json`: that enum is `ExportFormat`'s list, in its order.
#[test]
fn the_api_description_lists_every_export_format() {
    let doc: serde_json::Value =
        serde_json::from_str(easyhec::daemon::openapi::document()).unwrap();
    let route = &doc["paths"][easyhec::daemon::openapi::EXPORT_PATH]["get"];
    let param = route["parameters"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["name"] == "format")
        .expect("a format parameter");
    let listed: Vec<&str> = param["schema"]["enum"]
        .as_array()
        .unwrap_or_else(|| panic!("{}", param["schema"]))
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    let names = easyhec::interop::ExportFormat::ALL.map(easyhec::interop::ExportFormat::name);
    assert_eq!(listed, names);
}

/// The download route's 200 answer lists each format's content type, taken from
/// `ExportFormat` (a new format needs no edit of the route's annotation).
#[test]
fn the_api_description_lists_every_export_content_type() {
    let doc: serde_json::Value =
        serde_json::from_str(easyhec::daemon::openapi::document()).unwrap();
    let ok = &doc["paths"][easyhec::daemon::openapi::EXPORT_PATH]["get"]["responses"]["200"];
    let listed: std::collections::BTreeSet<&str> = ok["content"]
        .as_object()
        .unwrap_or_else(|| panic!("{ok}"))
        .keys()
        .map(String::as_str)
        .collect();
    let kinds: std::collections::BTreeSet<&str> = easyhec::interop::ExportFormat::ALL
        .iter()
        .map(|f| f.content_type())
        .collect();
    assert_eq!(listed, kinds);
}

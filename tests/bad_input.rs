//! Each kind of bad input: one line naming the file and field, non-zero exit, no result file.

mod common;

use std::path::Path;
use std::process::Command;

fn make_run(dir: &Path) -> std::path::PathBuf {
    let run = dir.join("run");
    common::synth_run(
        &run,
        "xarm6",
        &[
            "--views", "2", "--seed", "1", "--width", "320", "--height", "240", "--focal", "300",
        ],
    );
    run
}

fn edit_json(run: &Path, f: impl FnOnce(&mut serde_json::Value)) {
    let p = run.join("run.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    f(&mut v);
    std::fs::write(&p, serde_json::to_string_pretty(&v).unwrap()).unwrap();
}

/// Runs solve and checks: failure, one stderr line containing every `needle`, no result.
fn expect_error(run: &Path, needles: &[&str]) {
    let out = Command::new(common::easyhec_bin())
        .arg("solve")
        .arg(run)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "solve succeeded on bad input");
    assert_eq!(
        stderr.trim_end().lines().count(),
        1,
        "not one line: {stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
    for n in needles {
        assert!(stderr.contains(n), "'{n}' missing from: {stderr}");
    }
    assert!(!run.join("result.json").exists(), "a result was written");
}

fn urdf_copy(run: &Path, edit: impl FnOnce(String) -> String) {
    let src = common::robot_urdf("xarm6");
    let text = std::fs::read_to_string(&src).unwrap();
    let meshes = src.parent().unwrap().join("meshes");
    let text = text.replace(
        "filename=\"meshes/",
        &format!("filename=\"{}/", meshes.display()),
    );
    std::fs::write(run.join("robot.urdf"), edit(text)).unwrap();
    edit_json(run, |v| v["robot"]["urdf"] = "robot.urdf".into());
}

fn replace_first_mesh(urdf: &str, with: &Path) -> String {
    let start = urdf.find("filename=\"").unwrap() + "filename=\"".len();
    let end = start + urdf[start..].find('"').unwrap();
    format!("{}{}{}", &urdf[..start], with.display(), &urdf[end..])
}

#[test]
fn malformed_urdf() {
    let d = tempfile::tempdir().unwrap();
    let run = make_run(d.path());
    urdf_copy(&run, |t| t.replace("</robot>", ""));
    expect_error(&run, &["robot.urdf", "malformed URDF"]);
}

#[test]
fn missing_mesh() {
    let d = tempfile::tempdir().unwrap();
    let run = make_run(d.path());
    urdf_copy(&run, |t| t.replacen("link1.stl", "no_such_link.stl", 1));
    expect_error(&run, &["no_such_link.stl", "not found"]);
}

#[test]
fn unreadable_mesh() {
    let d = tempfile::tempdir().unwrap();
    let run = make_run(d.path());
    std::fs::write(run.join("garbage.stl"), b"solid x\nfacet nonsense\n").unwrap();
    let garbage = run.join("garbage.stl");
    urdf_copy(&run, |t| replace_first_mesh(&t, &garbage));
    expect_error(&run, &["garbage.stl", "mesh"]);
}

#[test]
fn mesh_in_millimetres_without_scale() {
    let d = tempfile::tempdir().unwrap();
    let run = make_run(d.path());
    // A 400 mm box written in millimetres (400 units).
    let mut stl = String::from("solid box\n");
    let c = [
        [0.0, 0.0, 0.0],
        [400.0, 0.0, 0.0],
        [0.0, 400.0, 0.0],
        [0.0, 0.0, 400.0],
    ];
    for t in [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]] {
        stl.push_str("facet normal 0 0 0\nouter loop\n");
        for k in t {
            stl.push_str(&format!("vertex {} {} {}\n", c[k][0], c[k][1], c[k][2]));
        }
        stl.push_str("endloop\nendfacet\n");
    }
    stl.push_str("endsolid box\n");
    std::fs::write(run.join("mm.stl"), stl).unwrap();
    let mm = run.join("mm.stl");
    urdf_copy(&run, |t| replace_first_mesh(&t, &mm));
    expect_error(
        &run,
        &["mm.stl", "millimetres", "scale=\"0.001 0.001 0.001\""],
    );
}

#[test]
fn mask_of_wrong_size() {
    let d = tempfile::tempdir().unwrap();
    let run = make_run(d.path());
    image::GrayImage::new(100, 80)
        .save(run.join("views/001.mask.png"))
        .unwrap();
    expect_error(&run, &["001.mask.png", "views[1].mask", "100x80"]);
}

#[test]
fn empty_mask() {
    let d = tempfile::tempdir().unwrap();
    let run = make_run(d.path());
    image::GrayImage::new(320, 240)
        .save(run.join("views/000.mask.png"))
        .unwrap();
    expect_error(&run, &["000.mask.png", "views[0].mask", "no robot pixels"]);
}

#[test]
fn nan_joints() {
    let d = tempfile::tempdir().unwrap();
    let run = make_run(d.path());
    let p = run.join("run.json");
    let text = std::fs::read_to_string(&p).unwrap();
    let i = text
        .find("\"joints\": [\n")
        .map(|i| i + "\"joints\": [\n".len());
    // Replace the first view's first joint value with NaN (not valid JSON).
    let views_at = text.find("\"views\"").unwrap();
    let at = text[views_at..].find("\"joints\": [").unwrap() + views_at + "\"joints\": [".len();
    let _ = i;
    let rest = &text[at..];
    let end = rest.find(',').unwrap();
    std::fs::write(&p, format!("{}NaN{}", &text[..at], &rest[end..])).unwrap();
    expect_error(&run, &["run.json", "line", "NaN"]);
}

#[test]
fn wrong_length_joints() {
    let d = tempfile::tempdir().unwrap();
    let run = make_run(d.path());
    edit_json(&run, |v| {
        v["views"][1]["joints"] = serde_json::json!([0.1, 0.2])
    });
    expect_error(&run, &["run.json", "views[1].joints", "has 2 values"]);
}

#[test]
fn corrupt_png() {
    let d = tempfile::tempdir().unwrap();
    let run = make_run(d.path());
    std::fs::write(
        run.join("views/000.mask.png"),
        b"\x89PNG\r\n\x1a\nthis is not a png",
    )
    .unwrap();
    expect_error(&run, &["000.mask.png", "cannot decode"]);
}

#[test]
fn unknown_format_version() {
    let d = tempfile::tempdir().unwrap();
    let run = make_run(d.path());
    edit_json(&run, |v| v["format"] = "easyhec-run/9".into());
    expect_error(
        &run,
        &["run.json", "format", "easyhec-run/9", "easyhec-run/1"],
    );
}

#[test]
fn bad_command_line_is_one_line() {
    let out = Command::new(common::easyhec_bin())
        .args(["solve", "--views", "abc", "x"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains("--views") && stderr.contains("abc"),
        "{stderr}"
    );
}

#[test]
fn malformed_collada_is_an_error_not_a_panic() {
    let d = tempfile::tempdir().unwrap();
    let run = make_run(d.path());
    // Triangles whose index stream refers past the end of the position array.
    let dae = r##"<?xml version="1.0"?>
<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
  <asset><unit name="meter" meter="1"/><up_axis>Z_UP</up_axis></asset>
  <library_geometries><geometry id="g"><mesh>
    <source id="p"><float_array id="pa" count="9">0 0 0 0.1 0 0 0 0.1 0</float_array>
      <technique_common><accessor source="#pa" count="3" stride="3"><param name="X" type="float"/><param name="Y" type="float"/><param name="Z" type="float"/></accessor></technique_common></source>
    <vertices id="v"><input semantic="POSITION" source="#p"/></vertices>
    <triangles count="1"><input semantic="VERTEX" source="#v" offset="0"/><p>0 1 7</p></triangles>
  </mesh></geometry></library_geometries>
  <library_visual_scenes><visual_scene id="s"><node id="n"><instance_geometry url="#g"/></node></visual_scene></library_visual_scenes>
  <scene><instance_visual_scene url="#s"/></scene>
</COLLADA>"##;
    std::fs::write(run.join("bad.dae"), dae).unwrap();
    let bad = run.join("bad.dae");
    urdf_copy(&run, |t| replace_first_mesh(&t, &bad));
    expect_error(&run, &["bad.dae", "mesh"]);
}

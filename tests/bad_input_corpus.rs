//! The bad-input corpus: well over a hundred malformed runs, cell configs, import folders,
//! results and flags, each fed to the `easyhec` binary as a careless or hostile user would.
//!
//! Every case must end with a non-zero exit code (not a signal) within 10 s, print exactly one
//! line on stderr that contains the file and field it names (the case's needles), never panic,
//! and leave its folder exactly as it was: no partial output, and existing runs, results and
//! imports unchanged. All failures are collected and reported together.

mod common;

use std::collections::BTreeMap;
use std::hash::{Hash, Hasher};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, Instant};

use serde_json::{json, Value};

/// Hang guard of one case (the issue's bound), not a performance measurement.
const CASE_LIMIT: Duration = Duration::from_secs(10);

type Setup = Box<dyn Fn(&Path) + Send + Sync>;

struct Case {
    name: String,
    args: Vec<String>,
    setup: Setup,
    needles: Vec<String>,
}

fn case(
    name: &str,
    args: &[&str],
    needles: &[&str],
    setup: impl Fn(&Path) + Send + Sync + 'static,
) -> Case {
    Case {
        name: name.to_string(),
        args: args.iter().map(|s| s.to_string()).collect(),
        setup: Box::new(setup),
        needles: needles.iter().map(|s| s.to_string()).collect(),
    }
}

// ---------------------------------------------------------------------------------------------
// The fixture: one synthetic run, a cell config, an EasyHeC import folder and a result, made
// once and copied into a fresh folder for every case.

fn fixture() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap().keep();
        let run = dir.join("run");
        common::synth_run(
            &run,
            "xarm6",
            &[
                "--views", "2", "--seed", "3", "--width", "320", "--height", "240", "--focal",
                "300",
            ],
        );
        std::fs::remove_file(run.join("ground_truth.json")).ok();
        write_cell_config(&dir.join("cell.toml"));
        common::write_easyhec_source(&run, &dir.join("src"), false);
        write_result(&dir.join("result.json"));
        std::fs::write(
            dir.join("outside.png"),
            std::fs::read(run.join("views/000.mask.png")).unwrap(),
        )
        .unwrap();
        dir
    })
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn write_cell_config(path: &Path) {
    let text = std::fs::read_to_string(repo().join("config/sim-xarm6.toml")).unwrap();
    let urdf = repo().join("robots/xarm6/robot.urdf");
    let text = text.replace(
        "\"../robots/xarm6/robot.urdf\"",
        &format!("{:?}", urdf.display().to_string()),
    );
    std::fs::write(path, text).unwrap();
}

fn write_result(path: &Path) {
    let cfb = [
        [0.0, -1.0, 0.0, 0.1],
        [0.0, 0.0, -1.0, 0.4],
        [1.0, 0.0, 0.0, 1.2],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let bfc = [
        [0.0, 0.0, 1.0, -1.2],
        [-1.0, 0.0, 0.0, 0.1],
        [0.0, -1.0, 0.0, 0.4],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let v = json!({
        "format": "easyhec-result/1",
        "camera_from_base": cfb,
        "base_from_camera": bfc,
        "base_link": "link_base",
        "views_used": [0, 1],
        "per_view": [{"view": 0, "iou": 0.95}, {"view": 1, "iou": 0.95}],
        "stop_reason": "test",
        "timings_s": {}
    });
    std::fs::write(path, serde_json::to_string_pretty(&v).unwrap()).unwrap();
}

/// Replaces the fixture's result by an `easyhec-result/2` of two cameras (both the
/// fixture's transform) carrying `joint_corrections`.
fn rig_result_with(joint_corrections: Value) -> impl Fn(&Path) + Send + Sync {
    move |d: &Path| {
        let path = d.join("result.json");
        let one: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        let camera = |name: &str| {
            let mut c = one.clone();
            let fields = c.as_object_mut().unwrap();
            fields.remove("format");
            fields.remove("timings_s");
            fields.insert("name".into(), name.into());
            c
        };
        let rig = json!({
            "format": "easyhec-result/2",
            "cameras": [camera("front"), camera("side")],
            "stop_reason": "test",
            "timings_s": {},
            "joint_corrections": joint_corrections.clone(),
        });
        std::fs::write(&path, serde_json::to_string_pretty(&rig).unwrap()).unwrap();
    }
}

fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let dest = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_tree(&e.path(), &dest);
        } else {
            std::fs::copy(e.path(), dest).unwrap();
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Edits.

fn edit_json(path: &Path, f: impl FnOnce(&mut Value)) {
    let mut v: Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    f(&mut v);
    std::fs::write(path, serde_json::to_string_pretty(&v).unwrap()).unwrap();
}

fn run_json(f: impl Fn(&mut Value) + Send + Sync + 'static) -> impl Fn(&Path) + Send + Sync {
    move |d: &Path| edit_json(&d.join("run/run.json"), &f)
}

fn replace_in(path: &Path, from: &str, to: &str) {
    let text = std::fs::read_to_string(path).unwrap();
    assert!(text.contains(from), "{} lacks {from:?}", path.display());
    std::fs::write(path, text.replacen(from, to, 1)).unwrap();
}

/// The cell config with `table` gaining (or replacing) `line`.
fn cell_line(table: &'static str, key_line: &'static str) -> impl Fn(&Path) + Send + Sync {
    move |d: &Path| {
        let p = d.join("cell.toml");
        let text = std::fs::read_to_string(&p).unwrap();
        let key = key_line.split('=').next().unwrap().trim();
        let mut out = String::new();
        let mut in_table = false;
        let mut placed = false;
        for line in text.lines() {
            if line.starts_with('[') {
                if in_table && !placed {
                    out.push_str(key_line);
                    out.push('\n');
                    placed = true;
                }
                in_table = line.trim() == format!("[{table}]");
            }
            let same_key = line.split('=').next().map(str::trim) == Some(key);
            if in_table && same_key {
                if !placed {
                    out.push_str(key_line);
                    out.push('\n');
                    placed = true;
                }
                continue;
            }
            out.push_str(line);
            out.push('\n');
        }
        if !placed {
            if !in_table {
                out.push_str(&format!("[{table}]\n"));
            }
            out.push_str(key_line);
            out.push('\n');
        }
        std::fs::write(&p, out).unwrap();
    }
}

/// A private copy of the xArm6 URDF (meshes by absolute path) edited by `f`, used by the run.
fn urdf_edit(f: impl Fn(String) -> String + Send + Sync + 'static) -> impl Fn(&Path) + Send + Sync {
    move |d: &Path| {
        let src = common::robot_urdf("xarm6");
        let text = std::fs::read_to_string(&src).unwrap();
        let meshes = src.parent().unwrap().join("meshes");
        let text = text.replace(
            "filename=\"meshes/",
            &format!("filename=\"{}/", meshes.display()),
        );
        std::fs::write(d.join("run/robot.urdf"), f(text)).unwrap();
        edit_json(&d.join("run/run.json"), |v| {
            v["robot"]["urdf"] = "robot.urdf".into()
        });
    }
}

fn first_mesh_scale(text: String, scale: &str) -> String {
    let i = text.find("<mesh filename=").unwrap();
    let end = i + text[i..].find("/>").unwrap();
    format!("{} scale=\"{scale}\"{}", &text[..end], &text[end..])
}

fn nothing(_: &Path) {}

/// `DIR/guess.json` holding `text`, for `solve --initial-guess guess.json`.
fn guess_file(text: &'static str) -> impl Fn(&Path) + Send + Sync {
    move |d: &Path| std::fs::write(d.join("guess.json"), text).unwrap()
}

/// The cell config with `text` appended (a new `[[table]]` entry).
fn append_cell(text: &'static str) -> impl Fn(&Path) + Send + Sync {
    move |d: &Path| {
        let p = d.join("cell.toml");
        let mut t = std::fs::read_to_string(&p).unwrap();
        t.push('\n');
        t.push_str(text);
        std::fs::write(&p, t).unwrap();
    }
}

// ---------------------------------------------------------------------------------------------
// The cases.

const SOLVE: &[&str] = &["solve", "run"];

fn solve_cases() -> Vec<Case> {
    let rj = "run.json";
    vec![
        case(
            "format missing",
            SOLVE,
            &[rj, "format"],
            run_json(|v| {
                v.as_object_mut().unwrap().remove("format");
            }),
        ),
        case(
            "format unknown",
            SOLVE,
            &[rj, "format", "easyhec-run/9"],
            run_json(|v| v["format"] = "easyhec-run/9".into()),
        ),
        case("truncated JSON", SOLVE, &[rj, "line"], |d: &Path| {
            let p = d.join("run/run.json");
            let t = std::fs::read_to_string(&p).unwrap();
            std::fs::write(&p, &t[..t.len() / 2]).unwrap();
        }),
        case("NaN literal", SOLVE, &[rj, "NaN"], |d: &Path| {
            replace_in(&d.join("run/run.json"), "\"fx\": ", "\"fx\": NaN, \"x\": ")
        }),
        case(
            "top level is an array",
            SOLVE,
            &[rj, "format"],
            |d: &Path| std::fs::write(d.join("run/run.json"), "[1, 2]").unwrap(),
        ),
        case(
            "robot missing",
            SOLVE,
            &[rj, "robot"],
            run_json(|v| {
                v.as_object_mut().unwrap().remove("robot");
            }),
        ),
        case(
            "robot.joints empty",
            SOLVE,
            &[rj, "robot.joints"],
            run_json(|v| v["robot"]["joints"] = json!([])),
        ),
        case(
            "robot.joints repeated",
            SOLVE,
            &[rj, "robot.joints[5]", "twice"],
            run_json(|v| v["robot"]["joints"][5] = v["robot"]["joints"][0].clone()),
        ),
        case(
            "robot.joints unknown",
            SOLVE,
            &["robot.joints", "no_such_joint"],
            run_json(|v| v["robot"]["joints"][0] = "no_such_joint".into()),
        ),
        case(
            "robot.joints not strings",
            SOLVE,
            &[rj, "robot.joints[0]"],
            run_json(|v| v["robot"]["joints"][0] = json!(3)),
        ),
        case(
            "robot.urdf missing",
            SOLVE,
            &["nope.urdf"],
            run_json(|v| v["robot"]["urdf"] = "nope.urdf".into()),
        ),
        case(
            "robot.urdf is /etc/passwd",
            SOLVE,
            &["/etc/passwd", "URDF"],
            run_json(|v| v["robot"]["urdf"] = "/etc/passwd".into()),
        ),
        case(
            "robot.urdf is a folder",
            SOLVE,
            &["regular file"],
            run_json(|v| v["robot"]["urdf"] = "views".into()),
        ),
        case(
            "robot.base_link unknown",
            SOLVE,
            &["robot.base_link", "nowhere"],
            run_json(|v| v["robot"]["base_link"] = "nowhere".into()),
        ),
        case(
            "robot.ignore_links unknown",
            SOLVE,
            &["robot.ignore_links", "ghost"],
            run_json(|v| v["robot"]["ignore_links"] = json!(["ghost"])),
        ),
        case(
            "camera.fx zero",
            SOLVE,
            &[rj, "camera.fx"],
            run_json(|v| v["camera"]["fx"] = json!(0.0)),
        ),
        case(
            "camera.fx negative",
            SOLVE,
            &[rj, "camera.fx"],
            run_json(|v| v["camera"]["fx"] = json!(-300.0)),
        ),
        case(
            "camera.fx absurd",
            SOLVE,
            &[rj, "camera.fx", "allowed"],
            run_json(|v| v["camera"]["fx"] = json!(1e300)),
        ),
        case(
            "camera.fy tiny",
            SOLVE,
            &[rj, "camera.fy"],
            run_json(|v| v["camera"]["fy"] = json!(1e-3)),
        ),
        case(
            "camera.fy aspect",
            SOLVE,
            &[rj, "camera.fy", "fx/fy"],
            run_json(|v| v["camera"]["fy"] = json!(900.0)),
        ),
        case(
            "camera.cx zero (transposed K)",
            SOLVE,
            &[rj, "camera.cx", "transposed"],
            run_json(|v| v["camera"]["cx"] = json!(0.0)),
        ),
        case(
            "camera.cy negative",
            SOLVE,
            &[rj, "camera.cy"],
            run_json(|v| v["camera"]["cy"] = json!(-4.0)),
        ),
        case(
            "camera.cx beyond the image",
            SOLVE,
            &[rj, "camera.cx"],
            run_json(|v| v["camera"]["cx"] = json!(1e9)),
        ),
        case(
            "camera.width zero",
            SOLVE,
            &[rj, "camera.width"],
            run_json(|v| v["camera"]["width"] = json!(0)),
        ),
        case(
            "camera.width huge",
            SOLVE,
            &[rj, "camera.width", "16384"],
            run_json(|v| v["camera"]["width"] = json!(100000)),
        ),
        case(
            "camera.width negative",
            SOLVE,
            &[rj, "camera.width"],
            run_json(|v| v["camera"]["width"] = json!(-640)),
        ),
        case(
            "camera.fx null",
            SOLVE,
            &[rj, "camera.fx"],
            run_json(|v| v["camera"]["fx"] = Value::Null),
        ),
        case(
            "camera.fx string",
            SOLVE,
            &[rj, "camera.fx"],
            run_json(|v| v["camera"]["fx"] = "300".into()),
        ),
        case(
            "camera missing",
            SOLVE,
            &[rj, "camera"],
            run_json(|v| {
                v.as_object_mut().unwrap().remove("camera");
            }),
        ),
        case(
            "distortion of 4",
            SOLVE,
            &[rj, "camera.distortion"],
            run_json(|v| v["camera"]["distortion"] = json!([0.1, 0.0, 0.0, 0.0])),
        ),
        case(
            "distortion model unknown",
            SOLVE,
            &[rj, "camera.distortion_model", "fisheye"],
            run_json(|v| v["camera"]["distortion_model"] = "fisheye".into()),
        ),
        case(
            "distortion huge",
            SOLVE,
            &[rj, "camera.distortion"],
            run_json(|v| v["camera"]["distortion"] = json!([1e9, 0.0, 0.0, 0.0, 0.0])),
        ),
        case(
            "views empty",
            SOLVE,
            &[rj, "views"],
            run_json(|v| v["views"] = json!([])),
        ),
        case(
            "views not a list",
            SOLVE,
            &[rj, "views"],
            run_json(|v| v["views"] = json!({"a": 1})),
        ),
        case(
            "too many views",
            SOLVE,
            &[rj, "views", "500"],
            run_json(|v| {
                let one = v["views"][0].clone();
                v["views"] = Value::Array(
                    (0..600)
                        .map(|i| {
                            let mut x = one.clone();
                            x["joints"][0] = json!(i as f64 * 1e-3);
                            x
                        })
                        .collect(),
                );
            }),
        ),
        case(
            "joints short",
            SOLVE,
            &[rj, "views[1].joints"],
            run_json(|v| {
                v["views"][1]["joints"].as_array_mut().unwrap().pop();
            }),
        ),
        case(
            "joints long",
            SOLVE,
            &[rj, "views[1].joints"],
            run_json(|v| {
                v["views"][1]["joints"]
                    .as_array_mut()
                    .unwrap()
                    .push(json!(0.0))
            }),
        ),
        case(
            "joint null",
            SOLVE,
            &[rj, "views[1].joints[2]"],
            run_json(|v| v["views"][1]["joints"][2] = Value::Null),
        ),
        case(
            "joint string",
            SOLVE,
            &[rj, "views[1].joints[2]"],
            run_json(|v| v["views"][1]["joints"][2] = "0.1".into()),
        ),
        case("joint overflow", SOLVE, &[rj], |d: &Path| {
            edit_json(&d.join("run/run.json"), |v| {
                v["views"][0]["joints"][0] = json!(12345.678)
            });
            replace_in(&d.join("run/run.json"), "12345.678", "1e999");
        }),
        case(
            "view repeated",
            SOLVE,
            &[rj, "views[1].joints", "views[0]"],
            run_json(|v| v["views"][1] = v["views"][0].clone()),
        ),
        case(
            "view joints repeated with another mask",
            SOLVE,
            &[rj, "views[1].joints", "repeats"],
            run_json(|v| v["views"][1]["joints"] = v["views"][0]["joints"].clone()),
        ),
        case(
            "mask shared by two views",
            SOLVE,
            &[rj, "views[1].mask", "repeats"],
            run_json(|v| v["views"][1]["mask"] = v["views"][0]["mask"].clone()),
        ),
        case(
            "mask path escapes with ..",
            SOLVE,
            &[rj, "views[0].mask", ".."],
            run_json(|v| v["views"][0]["mask"] = "../outside.png".into()),
        ),
        case(
            "mask path absolute",
            SOLVE,
            &[rj, "views[0].mask", "relative"],
            run_json(|v| v["views"][0]["mask"] = "/etc/passwd".into()),
        ),
        case(
            "mask path empty",
            SOLVE,
            &[rj, "views[0].mask"],
            run_json(|v| v["views"][0]["mask"] = "".into()),
        ),
        case(
            "mask missing file",
            SOLVE,
            &[rj, "views[0].mask", "does not exist"],
            run_json(|v| v["views"][0]["mask"] = "views/none.png".into()),
        ),
        case(
            "mask is a FIFO",
            SOLVE,
            &[rj, "views[0].mask", "regular file"],
            |d: &Path| {
                let st = Command::new("mkfifo")
                    .arg(d.join("run/views/fifo.png"))
                    .status()
                    .unwrap();
                assert!(st.success());
                edit_json(&d.join("run/run.json"), |v| {
                    v["views"][0]["mask"] = "views/fifo.png".into()
                });
            },
        ),
        case(
            "mask is a folder",
            SOLVE,
            &[rj, "views[0].mask", "regular file"],
            run_json(|v| v["views"][0]["mask"] = "views".into()),
        ),
        case(
            "mask symlink leaves the run",
            SOLVE,
            &[rj, "views[0].mask", "outside"],
            |d: &Path| {
                std::os::unix::fs::symlink(d.join("outside.png"), d.join("run/views/link.png"))
                    .unwrap();
                edit_json(&d.join("run/run.json"), |v| {
                    v["views"][0]["mask"] = "views/link.png".into()
                });
            },
        ),
        case("mask not a PNG", SOLVE, &["000.mask.png"], |d: &Path| {
            std::fs::write(d.join("run/views/000.mask.png"), b"not a png").unwrap()
        }),
        case(
            "mask wrong size",
            SOLVE,
            &["000.mask.png", "views[0].mask", "100x80"],
            |d: &Path| {
                image::GrayImage::new(100, 80)
                    .save(d.join("run/views/000.mask.png"))
                    .unwrap();
            },
        ),
        case(
            "mask empty",
            SOLVE,
            &["000.mask.png", "no robot pixels"],
            |d: &Path| {
                image::GrayImage::new(320, 240)
                    .save(d.join("run/views/000.mask.png"))
                    .unwrap();
            },
        ),
        case(
            "mask all robot",
            SOLVE,
            &["000.mask.png", "views[0].mask", "inverted"],
            |d: &Path| {
                image::GrayImage::from_pixel(320, 240, image::Luma([255]))
                    .save(d.join("run/views/000.mask.png"))
                    .unwrap();
            },
        ),
        case(
            "mask field missing",
            SOLVE,
            &[rj, "views[0].mask"],
            run_json(|v| {
                v["views"][0].as_object_mut().unwrap().remove("mask");
            }),
        ),
        case(
            "image path escapes",
            SOLVE,
            &[rj, "views[0].image"],
            run_json(|v| v["views"][0]["image"] = "../../x.png".into()),
        ),
        case(
            "initial guess not rigid",
            SOLVE,
            &[rj, "initial_guess"],
            run_json(|v| v["initial_guess"]["camera_from_base"][0][0] = json!(3.0)),
        ),
        case(
            "initial guess 3 rows",
            SOLVE,
            &[rj, "initial_guess"],
            run_json(|v| {
                v["initial_guess"]["camera_from_base"]
                    .as_array_mut()
                    .unwrap()
                    .pop();
            }),
        ),
        case(
            "initial guess bottom row",
            SOLVE,
            &[rj, "initial_guess"],
            run_json(|v| v["initial_guess"]["camera_from_base"][3][0] = json!(1.0)),
        ),
        case(
            "mount link unknown",
            SOLVE,
            &[rj, "camera.mount.link", "no link named 'link9'"],
            run_json(|v| v["camera"]["mount"] = json!({"link": "link9"})),
        ),
        case(
            "mount spelled wrong",
            SOLVE,
            &[rj, "\"fixed\" or { link"],
            run_json(|v| v["camera"]["mount"] = json!("wrist")),
        ),
        case(
            "mount link without initial guess",
            SOLVE,
            &[rj, "initial_guess", "camera_from_link6"],
            run_json(|v| {
                v["camera"]["mount"] = json!({"link": "link6"});
                v.as_object_mut().unwrap().remove("initial_guess");
            }),
        ),
        case(
            "URDF origin NaN",
            SOLVE,
            &["robot.urdf", "origin xyz", "NaN"],
            urdf_edit(|t| t.replacen("xyz=\"0 0 0.267\"", "xyz=\"0 NaN 0.267\"", 1)),
        ),
        case(
            "URDF mesh scale zero",
            SOLVE,
            &["robot.urdf", "mesh scale"],
            urdf_edit(|t| first_mesh_scale(t, "0 0 0")),
        ),
        case(
            "URDF mesh scale NaN",
            SOLVE,
            &["robot.urdf", "mesh scale"],
            urdf_edit(|t| first_mesh_scale(t, "NaN 1 1")),
        ),
        case(
            "URDF limits reversed",
            SOLVE,
            &["robot.urdf", "limit"],
            urdf_edit(|t| {
                let i = t.find("lower=\"").unwrap();
                let j = i + t[i..].find("upper=\"").unwrap();
                let lower_end = i + 7 + t[i + 7..].find('"').unwrap();
                let upper_end = j + 7 + t[j + 7..].find('"').unwrap();
                format!(
                    "{}lower=\"5\"{}upper=\"-5\"{}",
                    &t[..i],
                    &t[lower_end + 1..j],
                    &t[upper_end + 1..]
                )
            }),
        ),
        case(
            "URDF axis zero",
            SOLVE,
            &["robot.urdf", "axis"],
            urdf_edit(|t| t.replacen("<axis xyz=\"0 0 1\"", "<axis xyz=\"0 0 0\"", 1)),
        ),
        case(
            "URDF malformed",
            SOLVE,
            &["robot.urdf", "malformed"],
            urdf_edit(|t| t.replace("</robot>", "")),
        ),
        case(
            "URDF mesh missing",
            SOLVE,
            &["no_such.stl"],
            urdf_edit(|t| t.replacen(".stl\"", "_x/no_such.stl\"", 1)),
        ),
        case(
            "URDF box negative",
            SOLVE,
            &["robot.urdf", "box size"],
            urdf_edit(|t| {
                let i = t.find("<mesh filename=").unwrap();
                let end = i + t[i..].find("/>").unwrap() + 2;
                format!("{}<box size=\"-1 0.1 0.1\"/>{}", &t[..i], &t[end..])
            }),
        ),
        case(
            "poor fit",
            &["solve", "run", "--views", "1"],
            &["poor fit", "--allow-poor-fit"],
            run_json(|v| {
                for view in v["views"].as_array_mut().unwrap() {
                    view["joints"][1] = json!(view["joints"][1].as_f64().unwrap() + 0.6);
                    view["joints"][2] = json!(view["joints"][2].as_f64().unwrap() - 0.7);
                }
            }),
        ),
        case(
            "--initial-guess without camera_from_base",
            &["solve", "run", "--initial-guess", "guess.json"],
            &["guess.json", "camera_from_base"],
            guess_file(r#"{"pose": 1}"#),
        ),
        case(
            "--initial-guess not a rigid transform",
            &["solve", "run", "--initial-guess", "guess.json"],
            &["guess.json", "camera_from_base"],
            guess_file(r#"{"camera_from_base": [[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}"#),
        ),
        case(
            "--initial-guess from another frame",
            &["solve", "run", "--initial-guess", "guess.json"],
            &["guess.json", "base_link", "link6"],
            guess_file(
                r#"{"camera_from_base": [[1,0,0,0],[0,1,0,0],[0,0,1,1],[0,0,0,1]], "base_link": "link6"}"#,
            ),
        ),
        case(
            "--initial-guess that is also --out",
            &[
                "solve",
                "run",
                "--initial-guess",
                "guess.json",
                "--out",
                "guess.json",
            ],
            &["--out", "reads"],
            guess_file(r#"{"camera_from_base": [[1,0,0,0],[0,1,0,0],[0,0,1,1],[0,0,0,1]]}"#),
        ),
        case(
            "--views 0",
            &["solve", "run", "--views", "0"],
            &["--views"],
            nothing,
        ),
        case(
            "--views beyond the run",
            &["solve", "run", "--views", "9"],
            &["--views", "2 views"],
            nothing,
        ),
        case(
            "--select unknown",
            &["solve", "run", "--select", "best"],
            &["--select"],
            nothing,
        ),
        case(
            "--optimizer unknown",
            &["solve", "run", "--optimizer", "sgd"],
            &["sgd"],
            nothing,
        ),
        case(
            "--renderer unknown",
            &["solve", "run", "--renderer", "vulkan"],
            &["vulkan"],
            nothing,
        ),
        case(
            "--joint-noise-rad huge",
            &["solve", "run", "--joint-noise-rad", "1"],
            &["--joint-noise-rad", "allowed: 0 to 0.1"],
            nothing,
        ),
        case(
            "--model-floor-rotation-deg huge",
            &["solve", "run", "--model-floor-rotation-deg", "90"],
            &["--model-floor-rotation-deg", "allowed: 0 to 5"],
            nothing,
        ),
        case(
            "--model-floor-translation-mm NaN",
            &["solve", "run", "--model-floor-translation-mm", "nan"],
            &["--model-floor-translation-mm", "allowed"],
            nothing,
        ),
        case(
            "--joint-noise-rad NaN",
            &["solve", "run", "--joint-noise-rad", "nan"],
            &["--joint-noise-rad", "allowed"],
            nothing,
        ),
        case(
            "--segmenter unknown",
            &["solve", "run", "--segmenter", "nosuch"],
            &["--segmenter nosuch: unknown segmenter and no such file"],
            nothing,
        ),
        case(
            "run folder missing",
            &["solve", "no_run"],
            &["no_run"],
            nothing,
        ),
        case(
            "run.json is a folder",
            SOLVE,
            &["run.json", "regular file"],
            |d: &Path| {
                std::fs::rename(d.join("run/run.json"), d.join("run.json.bak")).unwrap();
                std::fs::create_dir(d.join("run/run.json")).unwrap();
            },
        ),
        case(
            "run.json is a FIFO",
            SOLVE,
            &["run.json", "regular file"],
            |d: &Path| {
                std::fs::remove_file(d.join("run/run.json")).unwrap();
                assert!(Command::new("mkfifo")
                    .arg(d.join("run/run.json"))
                    .status()
                    .unwrap()
                    .success());
            },
        ),
    ]
}

const CAL: &[&str] = &["calibrate", "--config", "cell.toml", "--dry-run"];

fn calibrate_cases() -> Vec<Case> {
    let c = "cell.toml";
    let mut v = vec![
        case("TOML syntax", CAL, &[c, "line"], |d: &Path| replace_in(&d.join("cell.toml"), "[arm]", "[arm")),
        case("unknown key", CAL, &[c, "bogus_key"], cell_line("calibration", "bogus_key = 1")),
        case("config missing", &["calibrate", "--config", "none.toml", "--dry-run"], &["none.toml"], nothing),
        case("config is a folder", &["calibrate", "--config", "run", "--dry-run"], &["run", "regular file"], nothing),
        case("arm.start NaN", CAL, &[c, "arm.start[1]"], cell_line("arm", "start = [0.0, nan, -0.6, 0.0, 0.95, 0.0]")),
        case("arm.start outside limits", CAL, &[c, "arm.start[2]", "limits"], cell_line("arm", "start = [0.0, -0.35, -9.0, 0.0, 0.95, 0.0]")),
        case("arm.start wrong length", CAL, &[c, "arm.start"], cell_line("arm", "start = [0.0, -0.35]")),
        case("encoder noise negative", CAL, &[c, "arm.encoder_noise_rad"], cell_line("arm", "encoder_noise_rad = -1.0")),
        case("speedup zero", CAL, &[c, "arm.speedup"], cell_line("arm", "speedup = 0.0")),
        case("speedup NaN", CAL, &[c, "arm.speedup"], cell_line("arm", "speedup = nan")),
        case("joint range NaN", CAL, &[c, "safety.joint_ranges.joint1"], cell_line("safety", "joint_ranges = { joint1 = [nan, 2.0] }")),
        case("joint range reversed", CAL, &[c, "safety.joint_ranges.joint1"], cell_line("safety", "joint_ranges = { joint1 = [2.0, -2.0] }")),
        case("joint range of three", CAL, &[c, "line"], cell_line("safety", "joint_ranges = { joint1 = [-2.0, 0.0, 2.0] }")),
        case("joint range unknown joint", CAL, &[c, "joint_ranges", "joint9"], cell_line("safety", "joint_ranges = { joint9 = [-2.0, 2.0] }")),
        case("speed cap zero", CAL, &[c, "safety.speed_cap_rad_s"], cell_line("safety", "speed_cap_rad_s = 0.0")),
        case("speed cap negative", CAL, &[c, "safety.speed_cap_rad_s"], cell_line("safety", "speed_cap_rad_s = -1.0")),
        case("speed cap absurd", CAL, &[c, "safety.speed_cap_rad_s"], cell_line("safety", "speed_cap_rad_s = 100.0")),
        case("margin negative", CAL, &[c, "safety.margin_m"], cell_line("safety", "margin_m = -0.01")),
        case("min_in_image zero", CAL, &[c, "safety.min_in_image"], cell_line("safety", "min_in_image = 0.0")),
        case("min_in_image above one", CAL, &[c, "safety.min_in_image"], cell_line("safety", "min_in_image = 2.0")),
        case("workspace radius zero", CAL, &[c, "safety.workspace.radius_m"], cell_line("safety", "workspace = { centre = [0.0, 0.0, 0.35], radius_m = 0.0 }")),
        case("workspace centre NaN", CAL, &[c, "safety.workspace.centre"], cell_line("safety", "workspace = { centre = [nan, 0.0, 0.35], radius_m = 0.9 }")),
        case("obstacle sphere radius negative", CAL, &[c, "safety.obstacles[1].radius_m"], append_cell("[[safety.obstacles]]\nkind = \"sphere\"\ncentre = [1.0, 1.0, 1.0]\nradius_m = -0.1\n")),
        case("obstacle plane normal zero", CAL, &[c, "safety.obstacles[1].normal"], append_cell("[[safety.obstacles]]\nkind = \"plane\"\nnormal = [0.0, 0.0, 0.0]\noffset_m = 0.0\n")),
        case("keep-out inverted", CAL, &[c, "safety.obstacles[1].max"], append_cell("[[safety.obstacles]]\nkind = \"keep-out\"\nmin = [1.0, 1.0, 1.0]\nmax = [0.0, 2.0, 2.0]\n")),
        case("box size zero", CAL, &[c, "safety.obstacles[1].size[1]"], append_cell("[[safety.obstacles]]\nkind = \"box\"\ncentre = [1.0, 1.0, 1.0]\nsize = [0.1, 0.0, 0.1]\n")),
        case("attached box size zero", CAL, &[c, "safety.attached[0].size[2]"], append_cell("[[safety.attached]]\nkind = \"box\"\nname = \"camera\"\nlink = \"link6\"\nsize = [0.1, 0.03, 0.0]\n")),
        case("attached unknown link", CAL, &[c, "safety.attached[0].link", "no link named 'tool0'"], append_cell("[[safety.attached]]\nkind = \"sphere\"\nname = \"camera\"\nlink = \"tool0\"\nradius_m = 0.03\n")),
        case("attached name twice", CAL, &[c, "safety.attached[1].name", "camera"], append_cell("[[safety.attached]]\nkind = \"sphere\"\nname = \"camera\"\nlink = \"link6\"\nradius_m = 0.03\n\n[[safety.attached]]\nkind = \"sphere\"\nname = \"camera\"\nlink = \"link5\"\nradius_m = 0.03\n")),
        case("joint_samples huge", CAL, &[c, "calibration.joint_samples", "100000"], cell_line("calibration", "joint_samples = 100000000")),
        case("joint_samples zero", CAL, &[c, "calibration.joint_samples"], cell_line("calibration", "joint_samples = 0")),
        case("climb_steps huge", CAL, &[c, "calibration.climb_steps"], cell_line("calibration", "climb_steps = 100000000")),
        case("max_views zero", CAL, &[c, "calibration.max_views"], cell_line("calibration", "max_views = 0")),
        case("max_views huge", CAL, &[c, "calibration.max_views"], cell_line("calibration", "max_views = 1000")),
        case("candidates one", CAL, &[c, "calibration.candidates"], cell_line("calibration", "candidates = 1")),
        case("candidates huge", CAL, &[c, "calibration.candidates"], cell_line("calibration", "candidates = 1000000")),
        case("score_downsample zero", CAL, &[c, "calibration.score_downsample"], cell_line("calibration", "score_downsample = 0")),
        case("score_downsample huge", CAL, &[c, "calibration.score_downsample"], cell_line("calibration", "score_downsample = 1000")),
        case("speed NaN", CAL, &[c, "calibration.speed_rad_s"], cell_line("calibration", "speed_rad_s = nan")),
        case("pose tolerance zero", CAL, &[c, "calibration.pose_tol_mm"], cell_line("calibration", "pose_tol_mm = 0.0")),
        case("variance tolerance negative", CAL, &[c, "calibration.variance_rel_tol"], cell_line("calibration", "variance_rel_tol = -0.1")),
        case("joint noise negative", CAL, &[c, "calibration.joint_noise_rad"], cell_line("calibration", "joint_noise_rad = -0.1")),
        case("max_views negative", CAL, &[c, "line"], cell_line("calibration", "max_views = -3")),
        case("camera fx absurd", CAL, &[c, "camera.fx"], cell_line("camera", "fx = 1e300")),
        case("camera fx zero", CAL, &[c, "camera.fx"], cell_line("camera", "fx = 0.0")),
        case("camera cx zero", CAL, &[c, "camera.cx"], cell_line("camera", "cx = 0.0")),
        case("camera width huge", CAL, &[c, "camera.width"], cell_line("camera", "width = 100000")),
        case("camera height zero", CAL, &[c, "camera.height"], cell_line("camera", "height = 0")),
        case("noise blob probability", CAL, &[c, "segmenter.noise.blob_probability"], cell_line("segmenter", "noise = { boundary_jitter_px = 0.5, blob_probability = 2.0, joint_noise_rad = 0.0 }")),
        case("noise preset unknown", CAL, &[c, "unknown noise preset 'fancy'", "segmenter"], cell_line("segmenter", "noise = \"fancy\"")),
        case("noise correlation huge", CAL, &[c, "segmenter.noise.boundary_correlation_px"], cell_line("segmenter", "noise = { boundary_jitter_px = 0.5, boundary_correlation_px = 1e9, blob_probability = 0.3, joint_noise_rad = 0.0 }")),
        case("stop centre bound zero", CAL, &[c, "calibration.stop_centre_95_mm"], cell_line("calibration", "stop_centre_95_mm = 0.0")),
        case("noise jitter NaN", CAL, &[c, "segmenter.noise.boundary_jitter_px"], cell_line("segmenter", "noise = { boundary_jitter_px = nan, blob_probability = 0.3, joint_noise_rad = 0.0 }")),
        case("robot joints repeated", CAL, &[c, "robot.joints[1]"], cell_line("robot", "joints = [\"joint1\", \"joint1\", \"joint3\", \"joint4\", \"joint5\", \"joint6\"]")),
        case("robot urdf missing", CAL, &["missing.urdf"], cell_line("robot", "urdf = \"missing.urdf\"")),
        case("initial guess not rigid", CAL, &[c, "calibration.initial_guess"], cell_line("calibration", "initial_guess = { camera_from_base = [[2.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 1.0], [0.0, 0.0, 0.0, 1.0]] }")),
        case("mount on a link that never moves", CAL, &[c, "camera.mount.link", "mount = \"fixed\""], cell_line("camera", "mount = { link = \"link_base\" }")),
        case("view overhead negative", CAL, &[c, "calibration.view_overhead_s"], cell_line("calibration", "view_overhead_s = -1.0")),
        case("robot image fraction zero", CAL, &[c, "calibration.min_robot_image_fraction"], cell_line("calibration", "min_robot_image_fraction = 0.0")),
        case("model floor huge", CAL, &[c, "calibration.model_floor_translation_mm"], cell_line("calibration", "model_floor_translation_mm = 1000.0")),
        case("model floor above the stop target", CAL, &[c, "calibration.model_floor_translation_mm", "stop_centre_95_mm"], cell_line("calibration", "model_floor_translation_mm = 0.5")),
        case("model floor negative", CAL, &[c, "calibration.model_floor_rotation_deg"], cell_line("calibration", "model_floor_rotation_deg = -1.0")),
        case("check interval beyond a timer", CAL, &[c, "check_interval_s"], cell_line("daemon", "check_interval_s = 1e20")),
        case("mount contact unknown", CAL, &[c, "line", "calibration.mount_contact", "`auto`, `fit`, `leave-out`"], cell_line("calibration", "mount_contact = \"sometimes\"")),
        case("bump mask offset negative", CAL, &[c, "bump_max_mask_offset_px"], cell_line("daemon", "bump_max_mask_offset_px = -1.0")),
        case("table extent NaN", CAL, &[c, "camera.scene.table_extent_m"], cell_line("camera", "scene = { seed = 1, table_extent_m = [nan, 1.0, -0.8, 0.8] }")),
        case("floor above the table", CAL, &[c, "camera.scene.floor_height_m"], cell_line("camera", "scene = { seed = 1, floor_height_m = 0.5 }")),
        case("sim truth eye on its target", CAL, &[c, "camera.truth", "1 mm apart"], cell_line("camera", "truth = { eye = [0.1, 0.0, 0.3], look_at = [0.1, 0.0, 0.3] }")),
        case("sim truth far away", CAL, &[c, "camera.truth", "eye[0]"], cell_line("camera", "truth = { eye = [1e300, 0.0, 0.3], look_at = [0.1, 0.0, 0.3] }")),
    ];
    v.push(case(
        "renderer unknown",
        &[
            "calibrate",
            "--config",
            "cell.toml",
            "--dry-run",
            "--renderer",
            "metal",
        ],
        &["metal"],
        nothing,
    ));
    v
}

const IMPORT: &[&str] = &[
    "import", "easyhec", "src", "--out", "imported", "--urdf", "URDF",
];

fn import_cases() -> Vec<Case> {
    let k = "K.txt";
    vec![
        case(
            "K of eight numbers",
            IMPORT,
            &[k, "9 numbers"],
            |d: &Path| std::fs::write(d.join("src/K.txt"), "300 0 159.5 0 300 119.5 0 0").unwrap(),
        ),
        case("K transposed", IMPORT, &[k, "transposed"], |d: &Path| {
            std::fs::write(d.join("src/K.txt"), "300 0 0\n0 300 0\n159.5 119.5 1\n").unwrap()
        }),
        case("K fx zero", IMPORT, &[k, "fx"], |d: &Path| {
            std::fs::write(d.join("src/K.txt"), "0 0 159.5\n0 300 119.5\n0 0 1\n").unwrap()
        }),
        case("K fx negative", IMPORT, &[k, "fx"], |d: &Path| {
            std::fs::write(d.join("src/K.txt"), "-300 0 159.5\n0 300 119.5\n0 0 1\n").unwrap()
        }),
        case("K NaN", IMPORT, &[k, "line 1"], |d: &Path| {
            std::fs::write(d.join("src/K.txt"), "nan 0 159.5\n0 300 119.5\n0 0 1\n").unwrap()
        }),
        case("K word", IMPORT, &[k, "line 2"], |d: &Path| {
            std::fs::write(d.join("src/K.txt"), "300 0 159.5\n0 abc 119.5\n0 0 1\n").unwrap()
        }),
        case("K missing", IMPORT, &[k], |d: &Path| {
            std::fs::remove_file(d.join("src/K.txt")).unwrap()
        }),
        case(
            "qpos without a mask",
            IMPORT,
            &["0007.txt", "no mask"],
            |d: &Path| {
                std::fs::copy(d.join("src/qpos/0000.txt"), d.join("src/qpos/0007.txt"))
                    .map(|_| ())
                    .unwrap()
            },
        ),
        case(
            "mask without a qpos",
            IMPORT,
            &["0001.png", "no qpos"],
            |d: &Path| std::fs::remove_file(d.join("src/qpos/0001.txt")).unwrap(),
        ),
        case("stems differ", IMPORT, &["qpos"], |d: &Path| {
            std::fs::rename(d.join("src/qpos/0001.txt"), d.join("src/qpos/x0001.txt")).unwrap()
        }),
        case("qpos short", IMPORT, &["0001.txt", "qpos"], |d: &Path| {
            std::fs::write(d.join("src/qpos/0001.txt"), "0.1 0.2").unwrap()
        }),
        case(
            "qpos not numbers",
            IMPORT,
            &["0001.txt", "line 1"],
            |d: &Path| std::fs::write(d.join("src/qpos/0001.txt"), "a b c d e f").unwrap(),
        ),
        case(
            "qpos infinite",
            IMPORT,
            &["0001.txt", "finite"],
            |d: &Path| std::fs::write(d.join("src/qpos/0001.txt"), "inf 0 0 0 0 0").unwrap(),
        ),
        case(
            "qpos repeated",
            IMPORT,
            &["views[1].joints", "repeats"],
            |d: &Path| {
                std::fs::copy(d.join("src/qpos/0000.txt"), d.join("src/qpos/0001.txt"))
                    .map(|_| ())
                    .unwrap()
            },
        ),
        case("mask garbage", IMPORT, &["0001.png"], |d: &Path| {
            std::fs::write(d.join("src/mask/0001.png"), b"junk").unwrap()
        }),
        case(
            "mask empty",
            IMPORT,
            &["0001.png", "no robot pixels"],
            |d: &Path| {
                image::GrayImage::new(320, 240)
                    .save(d.join("src/mask/0001.png"))
                    .unwrap()
            },
        ),
        case(
            "mask header states a huge image",
            IMPORT,
            &["0001.png", "sides up to 16384"],
            |d: &Path| {
                let mut img = image::GrayImage::new(20_000, 1);
                img.put_pixel(5, 0, image::Luma([255]));
                img.save(d.join("src/mask/0001.png")).unwrap();
            },
        ),
        case(
            "mask sizes differ",
            IMPORT,
            &["0001.png", "320x240"],
            |d: &Path| {
                let mut img = image::GrayImage::new(160, 120);
                img.put_pixel(5, 5, image::Luma([255]));
                img.save(d.join("src/mask/0001.png")).unwrap();
            },
        ),
        case(
            "mask is a FIFO",
            IMPORT,
            &["0002.png", "regular file"],
            |d: &Path| {
                assert!(Command::new("mkfifo")
                    .arg(d.join("src/mask/0002.png"))
                    .status()
                    .unwrap()
                    .success());
                std::fs::write(d.join("src/qpos/0002.txt"), "0.01 0.02 0.03 0.04 0.05 0.06")
                    .unwrap();
            },
        ),
        case("no masks", IMPORT, &["mask", "no mask PNGs"], |d: &Path| {
            for e in std::fs::read_dir(d.join("src/mask")).unwrap() {
                std::fs::remove_file(e.unwrap().path()).unwrap();
            }
        }),
        case(
            "initial guess not rigid",
            IMPORT,
            &["initial_guess.txt", "camera_from_base"],
            |d: &Path| {
                std::fs::write(
                    d.join("src/initial_guess.txt"),
                    "2 0 0 0\n0 1 0 0\n0 0 1 1\n0 0 0 1\n",
                )
                .unwrap()
            },
        ),
        case(
            "initial guess short",
            IMPORT,
            &["initial_guess.txt", "16 numbers"],
            |d: &Path| {
                std::fs::write(d.join("src/initial_guess.txt"), "1 0 0 0\n0 1 0 0\n").unwrap()
            },
        ),
        case(
            "target holds a run",
            IMPORT,
            &["imported", "--force"],
            |d: &Path| copy_tree(&d.join("run"), &d.join("imported")),
        ),
        case(
            "--joints unknown",
            &[
                "import",
                "easyhec",
                "src",
                "--out",
                "imported",
                "--urdf",
                "URDF",
                "--joints",
                "joint1,jointX",
            ],
            &["jointX"],
            nothing,
        ),
        case(
            "--joints repeated",
            &[
                "import",
                "easyhec",
                "src",
                "--out",
                "imported",
                "--urdf",
                "URDF",
                "--joints",
                "joint1,joint1",
            ],
            &["joint1", "twice"],
            nothing,
        ),
        case(
            "source missing",
            &[
                "import", "easyhec", "nowhere", "--out", "imported", "--urdf", "URDF",
            ],
            &["nowhere"],
            nothing,
        ),
        case(
            "URDF missing",
            &[
                "import",
                "easyhec",
                "src",
                "--out",
                "imported",
                "--urdf",
                "none.urdf",
            ],
            &["none.urdf"],
            nothing,
        ),
    ]
}

const EXPORT: &[&str] = &["export", "result.json", "--format", "ros"];

fn export_cases() -> Vec<Case> {
    const R: &str = "result.json";
    vec![
        case(
            "translation that overflows when inverted",
            &["export", R, "--format", "opencv"],
            &[R, "camera_from_base", "translation[0]"],
            |d: &Path| {
                edit_json(&d.join(R), |v| {
                    v["camera_from_base"][0][3] = json!(1.5e308);
                })
            },
        ),
        case(
            "frame with a newline",
            &[
                "export",
                R,
                "--format",
                "easy-handeye",
                "--child-frame-id",
                "cam\nkey: 1",
            ],
            &["--child-frame-id", "allowed"],
            nothing,
        ),
        case(
            "frame with a colon",
            &["export", R, "--format", "ros", "--child-frame-id", "cam: x"],
            &["--child-frame-id"],
            nothing,
        ),
        case(
            "frame with a quote",
            &[
                "export",
                R,
                "--format",
                "urdf",
                "--child-frame-id",
                "cam\"/><evil",
            ],
            &["--child-frame-id"],
            nothing,
        ),
        case(
            "frame empty",
            &["export", R, "--format", "urdf", "--child-frame-id", ""],
            &["--child-frame-id"],
            nothing,
        ),
        case(
            "frame starts with a digit",
            &[
                "export",
                R,
                "--format",
                "opencv",
                "--child-frame-id",
                "9cam",
            ],
            &["--child-frame-id"],
            nothing,
        ),
        case(
            "parent frame with a space",
            &["export", R, "--format", "ros", "--frame-id", "base link"],
            &["--frame-id", "allowed"],
            nothing,
        ),
        case(
            "child frame equal to the parent",
            &[
                "export",
                R,
                "--format",
                "ros",
                "--child-frame-id",
                "link_base",
            ],
            &["--child-frame-id", "same as the parent"],
            nothing,
        ),
        case(
            "optical_from_child too short",
            &[
                "export",
                R,
                "--format",
                "ros",
                "--optical-from-child",
                "0 0 0 1",
            ],
            &["--optical-from-child", "4 numbers", "allowed"],
            nothing,
        ),
        case(
            "optical_from_child not finite",
            &[
                "export",
                R,
                "--format",
                "ros",
                "--optical-from-child",
                "0 0 inf 0 0 0 1",
            ],
            &["--optical-from-child", "inf", "allowed"],
            nothing,
        ),
        case(
            "optical_from_child beyond a kilometre",
            &[
                "export",
                R,
                "--format",
                "ros",
                "--optical-from-child",
                "2000 0 0 0 0 0 1",
            ],
            &["--optical-from-child", "translation[0] = 2000 m", "allowed"],
            nothing,
        ),
        case(
            "optical_from_child quaternion not unit",
            &[
                "export",
                R,
                "--format",
                "urdf",
                "--optical-from-child",
                "0 0 0 0 0 0 3",
            ],
            &["--optical-from-child", "norm 3", "allowed"],
            nothing,
        ),
        case(
            "format unknown",
            &["export", R, "--format", "yaml"],
            &["yaml"],
            nothing,
        ),
        case(
            "base_link injected",
            EXPORT,
            &[R, "base_link"],
            |d: &Path| edit_json(&d.join(R), |v| v["base_link"] = "base\nevil: 1".into()),
        ),
        case(
            "result not rigid",
            EXPORT,
            &[R, "camera_from_base"],
            |d: &Path| edit_json(&d.join(R), |v| v["camera_from_base"][0][0] = json!(2.0)),
        ),
        case(
            "result wrong format",
            EXPORT,
            &[R, "format", "easyhec-result/7"],
            |d: &Path| edit_json(&d.join(R), |v| v["format"] = "easyhec-result/7".into()),
        ),
        case(
            "result field null",
            EXPORT,
            &[R, "camera_from_base[1][2]"],
            |d: &Path| edit_json(&d.join(R), |v| v["camera_from_base"][1][2] = Value::Null),
        ),
        case(
            "result centre bound negative",
            EXPORT,
            &[R, "uncertainty.camera_centre_95_mm", "allowed"],
            |d: &Path| {
                edit_json(
                    &d.join(R),
                    |v| v["uncertainty"] = json!({"rotation_deg": [0.01, 0.01, 0.01], "translation_mm": [0.1, 0.1, 0.1], "camera_centre_95_mm": -1.0}),
                )
            },
        ),
        case(
            "result covariance not symmetric",
            EXPORT,
            &[R, "uncertainty.covariance[0][1]", "symmetric"],
            |d: &Path| {
                edit_json(&d.join(R), |v| {
                    let mut c = vec![vec![0.0; 6]; 6];
                    for (k, row) in c.iter_mut().enumerate() {
                        row[k] = 1e-8;
                    }
                    c[0][1] = 1e-9;
                    v["uncertainty"] = json!({"rotation_deg": [0.01, 0.01, 0.01], "translation_mm": [0.1, 0.1, 0.1], "covariance": c})
                })
            },
        ),
        case(
            "rig result corrects a view twice",
            EXPORT,
            &[R, "joint_corrections.views[1]", "listed twice"],
            rig_result_with(
                json!({"views": [0, 0], "per_view_rad": [[0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, 0]]}),
            ),
        ),
        case(
            "rig result lists a view without a correction",
            EXPORT,
            &[
                R,
                "joint_corrections.views",
                "lists 2 views for 1 corrections",
            ],
            rig_result_with(json!({"views": [0, 1], "per_view_rad": [[0, 0, 0, 0, 0, 0]]})),
        ),
        case(
            "rig result correction short of a joint",
            EXPORT,
            &[R, "joint_corrections.per_view_rad[1]", "has 5 joints"],
            rig_result_with(
                json!({"views": [0, 1], "per_view_rad": [[0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0]]}),
            ),
        ),
        case(
            "result missing",
            &["export", "none.json", "--format", "ros"],
            &["none.json"],
            nothing,
        ),
        case(
            "result is a FIFO",
            EXPORT,
            &[R, "regular file"],
            |d: &Path| {
                std::fs::remove_file(d.join(R)).unwrap();
                assert!(Command::new("mkfifo")
                    .arg(d.join(R))
                    .status()
                    .unwrap()
                    .success());
            },
        ),
    ]
}

const SYNTH: &[&str] = &["synth", "--robot", "URDF", "--out", "made"];

fn synth_cases() -> Vec<Case> {
    fn with(extra: &[&'static str]) -> Vec<&'static str> {
        SYNTH.iter().chain(extra).copied().collect()
    }
    vec![
        case(
            "width huge",
            &with(&["--width", "100000"]),
            &["--width", "16384"],
            nothing,
        ),
        case(
            "height zero",
            &with(&["--height", "0"]),
            &["--height"],
            nothing,
        ),
        case(
            "views huge",
            &with(&["--views", "1000"]),
            &["--views", "100"],
            nothing,
        ),
        case(
            "views zero",
            &with(&["--views", "0"]),
            &["--views"],
            nothing,
        ),
        case(
            "focal zero",
            &with(&["--focal", "0"]),
            &["--focal"],
            nothing,
        ),
        case(
            "focal NaN",
            &with(&["--focal", "NaN"]),
            &["--focal"],
            nothing,
        ),
        case(
            "focal absurd",
            &with(&["--focal", "1e300"]),
            &["--focal"],
            nothing,
        ),
        case(
            "distortion of three",
            &with(&["--distortion", "0.1,0,0"]),
            &["--distortion"],
            nothing,
        ),
        case(
            "distortion infinite",
            &with(&["--distortion", "inf,0,0,0,0"]),
            &["--distortion"],
            nothing,
        ),
        case(
            "robot missing",
            &["synth", "--robot", "none.urdf", "--out", "made"],
            &["none.urdf"],
            nothing,
        ),
        case(
            "memory",
            &with(&[
                "--views", "100", "--width", "16384", "--height", "16384", "--focal", "16000",
            ]),
            &["GB"],
            nothing,
        ),
    ]
}

// ---------------------------------------------------------------------------------------------
// Running one case.

/// Every file under `dir` with its kind and content hash (FIFOs are never opened).
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, String> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let e = e.unwrap();
            let p = e.path();
            let rel = p.strip_prefix(dir).unwrap().to_path_buf();
            let ft = std::fs::symlink_metadata(&p).unwrap().file_type();
            let entry = if ft.is_dir() {
                stack.push(p.clone());
                "dir".to_string()
            } else if ft.is_file() {
                let mut h = std::collections::hash_map::DefaultHasher::new();
                std::fs::read(&p).unwrap().hash(&mut h);
                format!("file {:x}", h.finish())
            } else {
                format!("{ft:?}")
            };
            out.insert(rel, entry);
        }
    }
    out
}

fn run_case(c: &Case) -> Result<(), String> {
    let dir = tempfile::tempdir().unwrap();
    copy_tree(fixture(), dir.path());
    (c.setup)(dir.path());
    let before = snapshot(dir.path());
    let urdf = common::robot_urdf("xarm6").display().to_string();
    let args: Vec<String> = c
        .args
        .iter()
        .map(|a| if a == "URDF" { urdf.clone() } else { a.clone() })
        .collect();
    let mut child = Command::new(common::easyhec_bin())
        .args(&args)
        .current_dir(dir.path())
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let started = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if started.elapsed() > CASE_LIMIT {
            child.kill().ok();
            child.wait().ok();
            return Err(format!("did not end within {CASE_LIMIT:?}"));
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let mut stderr = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut stderr).unwrap();
    check_outcome(c, status, &stderr)?;
    let after = snapshot(dir.path());
    if before != after {
        let changed: Vec<_> = after
            .iter()
            .filter(|(k, v)| before.get(*k) != Some(v))
            .map(|(k, _)| k.display().to_string())
            .collect();
        let gone: Vec<_> = before
            .keys()
            .filter(|k| !after.contains_key(*k))
            .map(|k| k.display().to_string())
            .collect();
        return Err(format!(
            "left output behind: changed/new {changed:?}, removed {gone:?}"
        ));
    }
    Ok(())
}

fn check_outcome(c: &Case, status: std::process::ExitStatus, stderr: &str) -> Result<(), String> {
    let Some(code) = status.code() else {
        return Err(format!("killed by a signal ({status:?}): {stderr}"));
    };
    if code == 0 {
        return Err("exited 0".into());
    }
    if stderr.contains("panicked") {
        return Err(format!("panicked: {stderr}"));
    }
    // Exactly one error line; other lines may only be progress notes (the renderer chosen).
    let lines: Vec<&str> = stderr
        .trim_end()
        .lines()
        .filter(|l| !l.starts_with("renderer: "))
        .collect();
    if lines.len() != 1 || !lines[0].starts_with("error: ") {
        return Err(format!("not one error line on stderr: {stderr}"));
    }
    let missing: Vec<&String> = c
        .needles
        .iter()
        .filter(|n| !lines[0].contains(n.as_str()))
        .collect();
    if !missing.is_empty() {
        return Err(format!("{missing:?} missing from: {}", lines[0]));
    }
    Ok(())
}

/// A FIFO at `path` (as `mkfifo` makes it).
fn make_fifo(path: &Path) {
    let status = Command::new("mkfifo").arg(path).status().unwrap();
    assert!(status.success(), "mkfifo {}", path.display());
}

/// Outputs that are inputs, links or not regular files, and targets that hold their sources:
/// the one output policy refuses each before anything is written or deleted.
fn output_cases() -> Vec<Case> {
    let out_is = |name: &str, target: &'static str, needles: &[&str]| {
        case(name, &["solve", "run", "--out", target], needles, nothing)
    };
    let import_into = |name: &str, target: &'static str, needle: &'static str| {
        case(
            name,
            &[
                "import", "easyhec", "src", "--force", "--out", target, "--urdf", "URDF",
            ],
            &["--out", needle],
            nothing,
        )
    };
    let export_to = |name: &str, setup: fn(&Path), needle: &'static str| {
        case(
            name,
            &[
                "export",
                "result.json",
                "--format",
                "opencv",
                "--out",
                "out.yaml",
            ],
            &["out.yaml", "--out", needle],
            setup,
        )
    };
    vec![
        out_is(
            "solve --out run.json",
            "run/run.json",
            &["--out", "run.json", "reads"],
        ),
        out_is(
            "solve --out a mask",
            "run/views/000.mask.png",
            &["--out", "000.mask.png", "reads"],
        ),
        case(
            "solve --out ground_truth.json",
            &["solve", "run", "--out", "run/ground_truth.json"],
            &["--out", "ground_truth.json", "reads"],
            |d: &Path| std::fs::write(d.join("run/ground_truth.json"), "{}").unwrap(),
        ),
        case(
            "export --out its own result",
            &[
                "export",
                "result.json",
                "--format",
                "opencv",
                "--out",
                "result.json",
            ],
            &["--out", "result.json", "reads"],
            nothing,
        ),
        export_to(
            "export --out a FIFO",
            |d| make_fifo(&d.join("out.yaml")),
            "not a regular file",
        ),
        export_to(
            "export --out a symbolic link",
            |d| std::os::unix::fs::symlink(d.join("outside.png"), d.join("out.yaml")).unwrap(),
            "symbolic link",
        ),
        export_to(
            "export --out a folder",
            |d| std::fs::create_dir(d.join("out.yaml")).unwrap(),
            "not a regular file",
        ),
        case(
            "solve --masks-out over the recorded masks",
            &[
                "solve",
                "run",
                "--segmenter",
                "builtin",
                "--masks-out",
                "run/views",
            ],
            &["--masks-out", "000.mask.png", "reads"],
            nothing,
        ),
        case(
            "synth into an existing run",
            &["synth", "--robot", "URDF", "--out", "run"],
            &["--out", "not empty", "--force"],
            nothing,
        ),
        case(
            "synth --force into the robot's folder",
            &[
                "synth",
                "--robot",
                "urdf_dir/robot.urdf",
                "--out",
                "urdf_dir",
                "--force",
            ],
            &["--out", "holds"],
            |d: &Path| {
                std::fs::create_dir(d.join("urdf_dir")).unwrap();
                std::fs::copy(common::robot_urdf("xarm6"), d.join("urdf_dir/robot.urdf")).unwrap();
            },
        ),
        import_into("import --force over its source", "src", "holds"),
        case(
            "import --force over a folder that is no run",
            &[
                "import", "easyhec", "src", "--force", "--out", "other", "--urdf", "URDF",
            ],
            &["--out", "no run.json"],
            |d: &Path| std::fs::create_dir_all(d.join("other/keep")).unwrap(),
        ),
        case(
            "synth --force over a folder that is no run",
            &["synth", "--robot", "URDF", "--out", "other", "--force"],
            &["--out", "no run.json"],
            |d: &Path| std::fs::create_dir_all(d.join("other/keep")).unwrap(),
        ),
        import_into("import --force over its source's parent", ".", "holds"),
        import_into(
            "import --force inside its source",
            "src/mask",
            "lies inside",
        ),
        case(
            "import colour frame linked outside the source",
            IMPORT,
            &["color", "outside the source"],
            |d: &Path| {
                std::fs::create_dir(d.join("src/color")).unwrap();
                std::os::unix::fs::symlink("/etc/passwd", d.join("src/color/0000.png")).unwrap();
            },
        ),
        case(
            "import colour frame that is no image",
            IMPORT,
            &["0000.png", "color"],
            |d: &Path| {
                std::fs::create_dir(d.join("src/color")).unwrap();
                std::fs::write(d.join("src/color/0000.png"), "not an image").unwrap();
            },
        ),
        case(
            "import mask stems that differ only in case",
            IMPORT,
            &["mask", "0000", "same view"],
            |d: &Path| {
                std::fs::copy(d.join("src/mask/0000.png"), d.join("src/mask/0000.Png")).unwrap();
            },
        ),
    ]
}

/// Values that would otherwise be used or echoed whole.
fn value_cases() -> Vec<Case> {
    let rj = "run.json";
    vec![
        case(
            "joint of 1e300 rad",
            SOLVE,
            &[rj, "views[0].joints[0]", "URDF limits"],
            run_json(|v| v["views"][0]["joints"][0] = json!(1e300)),
        ),
        case(
            "joint of 7 rad past a revolute limit",
            SOLVE,
            &[rj, "views[1].joints[1]", "URDF limits"],
            run_json(|v| v["views"][1]["joints"][1] = json!(7.0)),
        ),
        case(
            "ignore_links repeating one name",
            SOLVE,
            &[rj, "ignore_links", "twice"],
            run_json(|v| v["robot"]["ignore_links"] = json!(vec!["link1"; 5000])),
        ),
        case(
            "ignore_links longer than any robot",
            SOLVE,
            &[rj, "ignore_links", "more than 1024"],
            run_json(|v| {
                let names: Vec<String> = (0..2000).map(|i| format!("l{i}")).collect();
                v["robot"]["ignore_links"] = json!(names);
            }),
        ),
        case(
            "a 20 MB base link is cut in the message",
            SOLVE,
            &["robot.urdf", "robot.base_link", "bytes cut"],
            run_json(|v| v["robot"]["base_link"] = json!("b".repeat(20 << 20))),
        ),
    ]
}

fn all_cases() -> Vec<Case> {
    let mut v = output_cases();
    v.extend(value_cases());
    v.extend(solve_cases());
    v.extend(calibrate_cases());
    v.extend(import_cases());
    v.extend(export_cases());
    v.extend(synth_cases());
    v
}

#[test]
fn every_bad_input_fails_in_one_line_and_leaves_nothing_behind() {
    let cases = all_cases();
    assert!(
        cases.len() >= 100,
        "the corpus has only {} cases",
        cases.len()
    );
    fixture();
    let next = AtomicUsize::new(0);
    let failures = Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..2 {
            s.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::SeqCst);
                let Some(c) = cases.get(i) else { break };
                if let Err(why) = run_case(c) {
                    failures
                        .lock()
                        .unwrap()
                        .push(format!("{}: {}", c.name, why));
                }
            });
        }
    });
    let failures = failures.into_inner().unwrap();
    println!("{} bad-input cases, {} failed", cases.len(), failures.len());
    assert!(
        failures.is_empty(),
        "{} of {} cases failed:\n{}",
        failures.len(),
        cases.len(),
        failures.join("\n")
    );
}

#[test]
fn the_fixture_itself_is_accepted() {
    // Each case changes one thing; the unchanged fixture must pass, or the cases prove nothing.
    let dir = tempfile::tempdir().unwrap();
    copy_tree(fixture(), dir.path());
    let urdf = common::robot_urdf("xarm6");
    let ok = |args: &[&str]| {
        let out = Command::new(common::easyhec_bin())
            .args(args)
            .current_dir(dir.path())
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    };
    ok(&["solve", "run", "--out", "solved.json"]);
    ok(&["export", "result.json", "--format", "ros"]);
    ok(&[
        "import",
        "easyhec",
        "src",
        "--out",
        "imported",
        "--urdf",
        urdf.to_str().unwrap(),
    ]);
    ok(&["solve", "imported", "--out", "imported_result.json"]);
    ok(&[
        "calibrate",
        "--config",
        "cell.toml",
        "--dry-run",
        "--out",
        "dry",
    ]);
}

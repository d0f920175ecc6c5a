//! Several cameras in one cell (`[[camera]]`): one arm motion serves the three fixed cameras of
//! the simulated xArm6 rig, each camera's transform reaches the truth, every commanded pose
//! passes the safety checker, the run and result are the rig formats (`easyhec-run/2`,
//! `easyhec-result/2`) and each camera's part reads back as a run of its own; configs a rig
//! cannot serve are refused before anything moves.

mod common;

use std::path::PathBuf;

use easyhec::cell::Cell;
use easyhec::config::read_config;
use easyhec::geometry::{rotation_error_deg, translation_error_mm};
use easyhec::run::rig::{RigResultFile, RIG_RESULT_FORMAT};
use easyhec::run::{load_cameras_with, MaskSource};

const RIG: &str = "sim-xarm6-three-cameras.toml";

fn config_path() -> PathBuf {
    shipped(RIG)
}

fn shipped(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("config")
        .join(name)
}

/// The shipped config `name` with four views and a light planner.
fn quick_config(name: &str) -> easyhec::config::CellConfig {
    let mut cfg = read_config(&shipped(name)).unwrap();
    cfg.calibration.max_views = 4;
    cfg.calibration.min_views = 4;
    cfg.calibration.joint_samples = 1000;
    cfg.calibration.candidates = 24;
    cfg
}

/// Every camera of the loop's outcome took 4 views and lies within `deg` / `mm` of its
/// simulated truth (whatever frame its mount solves for).
fn assert_each_camera_near(cell: &Cell, outcome: &easyhec::calibrate::Outcome, deg: f64, mm: f64) {
    for (unit, cam) in cell.cameras().iter().zip(&outcome.cameras) {
        let truth = unit.sim.camera_from_base.unwrap();
        let est = cam.result.camera_from_base();
        let (r, t) = (
            rotation_error_deg(&est, &truth),
            translation_error_mm(&est, &truth),
        );
        assert!(
            r < deg && t < mm,
            "{}: camera_from_{} off by {r:.4} deg {t:.3} mm",
            cam.name,
            cam.result.base_link
        );
        assert_eq!(cam.result.views_used.len(), 4, "{}", cam.name);
    }
}

/// `easyhec export RESULT --format urdf --out DIR`, which must succeed.
fn export_urdf(result: &std::path::Path, dir: &std::path::Path) {
    let status = std::process::Command::new(common::easyhec_bin())
        .arg("export")
        .arg(result)
        .args(["--format", "urdf", "--out"])
        .arg(dir)
        .output()
        .unwrap();
    assert!(
        status.status.success(),
        "{}",
        String::from_utf8_lossy(&status.stderr)
    );
}

/// `easyhec solve`'s stdout has one truth line per camera, each within 0.2° / 1.5 mm. (The
/// tests write the truth file with the library call `easyhec calibrate` uses; the CLI's own
/// write is not run here.)
fn assert_truth_lines(stdout: &str, outcome: &easyhec::calibrate::Outcome) {
    for cam in &outcome.cameras {
        let prefix = format!("{}: error against the simulated truth: rotation ", cam.name);
        let line = stdout
            .lines()
            .find_map(|l| l.strip_prefix(&prefix))
            .unwrap_or_else(|| panic!("no truth line for {}:\n{stdout}", cam.name));
        let numbers: Vec<f64> = line
            .split(|c: char| !(c.is_ascii_digit() || c == '.'))
            .filter_map(|w| w.parse().ok())
            .collect();
        assert_eq!(numbers.len(), 2, "{line}");
        assert!(numbers[0] < 0.2 && numbers[1] < 1.5, "{}: {line}", cam.name);
    }
}

/// The result lists every view's joint correction, and the corrections take out much of
/// the simulated encoder error where the silhouettes show it: joints 1 and 2's (base yaw
/// and shoulder) error from view to view. (The true joints are where each move ended, the
/// first view's where the arm stood; the recorded ones carry 0.5 mrad of noise per joint.
/// The base joint's error common to every view cannot show, and the wrist joints barely do.)
fn assert_corrections_near_the_encoder_error(
    cell: &Cell,
    result: &RigResultFile,
    recorded: &[Vec<f64>],
) {
    let corrections = result
        .joint_corrections
        .as_ref()
        .expect("three cameras correct joints");
    assert_eq!(corrections.views, [0, 1, 2, 3]);
    let commands = cell.sim_arm().unwrap().commands();
    let truth: Vec<&Vec<f64>> = std::iter::once(&commands[0].from)
        .chain(commands.iter().map(|c| &c.target))
        .collect();
    // RMS over joints 1 and 2 of each view's error less its mean over views.
    let spread = |corrected: bool| {
        let mut sum = 0.0;
        for j in 0..2 {
            let errors: Vec<f64> = recorded
                .iter()
                .zip(&truth)
                .zip(&corrections.per_view_rad)
                .map(|((q, t), d)| q[j] - t[j] + if corrected { d[j] } else { 0.0 })
                .collect();
            let mean = errors.iter().sum::<f64>() / errors.len() as f64;
            sum += errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>();
        }
        (sum / (2 * recorded.len()) as f64).sqrt()
    };
    let (before, after) = (spread(false), spread(true));
    assert!(before > 2e-4, "the simulated encoder noise is on: {before}");
    assert!(
        after < 0.7 * before,
        "joints 1 and 2: error spread {before:.6} rad, after the corrections {after:.6}"
    );
}

/// One motion served every camera: 3 moves for 4 views, each accepted and each path safe.
fn assert_three_safe_moves(cell: &Cell) {
    assert_eq!(common::assert_every_command_safe(cell), 3);
}

#[test]
fn three_cameras_reach_the_truth_from_one_motion() {
    let cell = Cell::build(quick_config(RIG), &config_path()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let outcome = common::run_loop(&cell, &out);
    let names: Vec<&str> = outcome.cameras.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["front", "side", "high"]);
    assert_each_camera_near(&cell, &outcome, 0.2, 1.5);
    assert_three_safe_moves(&cell);

    // The result names every camera, and each part reads as a run of its own.
    let result = RigResultFile::read(&out.join("result.json")).unwrap();
    assert_eq!(result.format, RIG_RESULT_FORMAT);
    assert_eq!(result.cameras.len(), 3);
    for (c, cam) in result.cameras.iter().zip(&outcome.cameras) {
        assert_eq!(c.name, cam.name);
        assert_eq!(c.camera_from_base, cam.result.camera_from_base);
        assert!(c.uncertainty.is_some(), "{}", c.name);
    }
    let parts = load_cameras_with(&out, MaskSource::Recorded).unwrap();
    assert_eq!(parts.len(), 3);
    for ((name, run), unit) in parts.iter().zip(cell.cameras()) {
        assert_eq!(name, unit.name);
        assert_eq!(run.views.len(), 4, "{name}");
        assert_eq!(run.camera.width, unit.device.intrinsics().width, "{name}");
    }
    // The side camera's lens distortion is recorded with its part.
    assert!(parts[1].1.camera.distortion.is_some());
    let recorded: Vec<Vec<f64>> = parts[0].1.views.iter().map(|v| v.joints.clone()).collect();
    assert_corrections_near_the_encoder_error(&cell, &result, &recorded);

    // `easyhec solve` reads the rig run and, correcting each view's joints from all cameras
    // as the loop does, finds each camera's transform again.
    // With the simulator's truth beside the run, it prints each camera's error against it.
    let truth = easyhec::cell::sim::rig_ground_truth(&cell).unwrap();
    easyhec::io::write_json_atomic(&out.join("ground_truth.json"), &truth).unwrap();
    let resolved = dir.path().join("resolved.json");
    let solved = common::solve_run(&out, &["--out", resolved.to_str().unwrap()]);
    assert!(
        solved.status.success(),
        "{}",
        String::from_utf8_lossy(&solved.stderr)
    );
    assert_truth_lines(&String::from_utf8_lossy(&solved.stdout), &outcome);
    let again = RigResultFile::read(&resolved).unwrap();
    assert_eq!(again.cameras.len(), 3);
    assert_corrections_near_the_encoder_error(&cell, &again, &recorded);
    // ... and estimates the same corrections the loop did.
    let (loop_fix, solve_fix) = (
        result.joint_corrections.as_ref().unwrap(),
        again.joint_corrections.as_ref().unwrap(),
    );
    let apart = (loop_fix.per_view_rad.iter().flatten())
        .zip(solve_fix.per_view_rad.iter().flatten())
        .fold(0.0_f64, |m, (a, b)| m.max((a - b).abs()));
    assert!(apart < 1e-7, "loop and solve corrections {apart} rad apart");
    for (a, b) in again.cameras.iter().zip(&result.cameras) {
        assert_eq!(a.name, b.name);
        let (ea, eb) = (
            easyhec::geometry::from_rows(&a.camera_from_base).unwrap(),
            easyhec::geometry::from_rows(&b.camera_from_base).unwrap(),
        );
        let (r, t) = (rotation_error_deg(&ea, &eb), translation_error_mm(&ea, &eb));
        assert!(
            r < 0.002 && t < 0.02,
            "{}: re-solve moved {r:.4} deg {t:.3} mm",
            a.name
        );
    }

    // `easyhec export` writes every camera, each under its own frame.
    let exported = dir.path().join("export");
    export_urdf(&resolved, &exported);
    for name in ["front", "side", "high"] {
        let text = std::fs::read_to_string(exported.join(format!("{name}.urdf"))).unwrap();
        assert!(
            text.contains(&format!("{name}_easyhec_camera_optical_frame")),
            "{text}"
        );
    }
}

#[test]
fn configs_a_rig_cannot_serve_are_refused_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let base = common::shipped_config_text(RIG);
    let cases = vec![
        (
            base.replacen("name = \"side\"", "name = \"front\"", 1),
            "camera[1].name",
        ),
        (
            base.replacen("name = \"high\"", "name = \"../high\"", 1),
            "camera[2].name",
        ),
        // A camera on a link needs its own starting pose in the link's frame.
        (
            base.replacen(
                "initial_guess = { eye = [0.35, -1.25, 0.85], look_at = [0.2, 0.0, 0.35] }",
                "mount = { link = \"link6\" }",
                1,
            ),
            "camera[1].initial_guess",
        ),
        (
            base.replacen(
                "name = \"side\"",
                "name = \"side\"\nmount = { link = \"no_such_link\" }",
                1,
            ),
            "camera[1].mount.link",
        ),
        (
            base.replacen("max_views = 5", "max_views = 5\ninitial_guess = { eye = [1.0, 0.0, 1.0], look_at = [0.0, 0.0, 0.3] }", 1),
            "calibration.initial_guess",
        ),
        (base.replacen("fx = 700.0", "fx = -700.0", 1), "camera[1].fx"),
        (
            base.replacen(
                "kind = \"sim-truth\"\nnoise = { boundary_jitter_px = 0.5, blob_probability = 0.3, joint_noise_rad = 0.0 }",
                "kind = \"builtin\"",
                1,
            ),
            "segmenter.kind",
        ),
        (
            base.replacen(
                "name = \"high\"",
                "name = \"high\"\nsegmenter = { kind = \"builtin\" }",
                1,
            ),
            "camera[2].segmenter.kind",
        ),
        (
            base.replacen(
                "name = \"high\"",
                "name = \"high\"\nsegmenter = { kind = \"sam\", encoder = \"e.onnx\", decoder = \"d.onnx\" }",
                1,
            ),
            "camera[2].segmenter.kind: \"sam\" for camera 'high': it reads the whole run of one camera (views with no estimate yet are drawn by builtin",
        ),
        (
            base.replacen(
                "initial_guess = { eye = [0.35, -1.25, 0.85], look_at = [0.2, 0.0, 0.35] }",
                "initial_guess = { eye = [0.35, -1.25, 0.85], look_at = [0.35, -1.25, 0.85] }",
                1,
            ),
            "camera[1].initial_guess",
        ),
        (
            base.replacen("name = \"front\"\n", "", 1),
            "camera[0].name",
        ),
    ];
    common::assert_configs_refused(dir.path(), &base, &cases);
}

#[test]
fn the_daemon_serves_camera_lists_and_refuses_tf_settings_that_fit_one_camera() {
    // One camera written as a [[camera]] table is a list too: the daemon keeps its active
    // calibration by name. Its /tf_static broadcast sends one edge per camera, so a driver's
    // optical_from_child (one camera's) and a frame_id over a wrist camera beside fixed ones
    // are refused before the data folder is touched.
    let dir = tempfile::tempdir().unwrap();
    let three = common::shipped_config_text(RIG);
    let cut = three.find("[[camera]]\nname = \"side\"").unwrap();
    let rest = three[cut..].find("[segmenter]").unwrap() + cut;
    let one = format!("{}{}", &three[..cut], &three[rest..]);
    let wrist = common::shipped_config_text("sim-xarm6-fixed-and-wrist.toml");
    let cases = [
        (
            three.clone(),
            3,
            "optical_from_child = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]",
            "ros2.optical_from_child",
        ),
        (
            one,
            1,
            "optical_from_child = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]",
            "ros2.optical_from_child",
        ),
        (wrist, 2, "frame_id = \"world\"", "ros2.frame_id"),
    ];
    for (i, (text, n, ros2, field)) in cases.into_iter().enumerate() {
        let path = dir.path().join(format!("rig{i}.toml"));
        std::fs::write(&path, &text).unwrap();
        let cell = Cell::open(&path).unwrap();
        assert_eq!(cell.cameras().len(), n);
        let data = dir.path().join(format!("data{i}"));
        assert!(easyhec::daemon::Daemon::open(cell, &data, "token".into()).is_ok());

        let path = dir.path().join(format!("rig{i}-ros2.toml"));
        std::fs::write(&path, format!("{text}\n[ros2]\n{ros2}\n")).unwrap();
        let cell = Cell::open(&path).unwrap();
        let data = dir.path().join(format!("data{i}-ros2"));
        std::fs::create_dir(&data).unwrap();
        let e = match easyhec::daemon::Daemon::open(cell, &data, "token".into()) {
            Ok(_) => panic!("a daemon took `{ros2}` for {n} listed camera(s)"),
            Err(e) => e.to_string(),
        };
        assert!(e.contains(&format!("rig{i}-ros2.toml: {field}")), "{e}");
        assert!(!e.contains('\n'), "{e}");
        assert_eq!(std::fs::read_dir(&data).unwrap().count(), 0);
    }
    // A segmenter that reads a whole run serves no `[[camera]]` table, even a single one (the
    // daemon's bump check reads a run of a list): refused at start, naming the key, before
    // the data folder is touched; `calibrate` takes the same config (one camera).
    let single = dir.path().join("rig-one-builtin.toml");
    let text = one_builtin(&three);
    std::fs::write(&single, &text).unwrap();
    let cell = Cell::open(&single).unwrap();
    let data = dir.path().join("data-builtin");
    std::fs::create_dir(&data).unwrap();
    let e = match easyhec::daemon::Daemon::open(cell, &data, "token".into()) {
        Ok(_) => panic!("a daemon took a builtin segmenter for a [[camera]] table"),
        Err(e) => e.to_string(),
    };
    assert!(e.contains("rig-one-builtin.toml: segmenter.kind"), "{e}");
    assert!(e.contains("[[camera]]") && !e.contains('\n'), "{e}");
    assert_eq!(std::fs::read_dir(&data).unwrap().count(), 0);
    // One parent for cameras that all hang from the base is fine: whatever refuses this
    // config (a build without ROS 2), it is not the frames.
    let path = dir.path().join("rig-frame.toml");
    std::fs::write(
        &path,
        format!("{three}\n[ros2]\nframe_id = \"world\"\npublish_tf = false\n"),
    )
    .unwrap();
    let cell = Cell::open(&path).unwrap();
    let data = dir.path().join("data-frame");
    if let Err(e) = easyhec::daemon::Daemon::open(cell, &data, "token".into()) {
        assert!(!e.to_string().contains("ros2.frame_id"), "{e}");
    }
}

/// `three` (the shipped three-camera config) cut to its first `[[camera]]` table, with the
/// `builtin` segmenter.
fn one_builtin(three: &str) -> String {
    let cut = three.find("[[camera]]\nname = \"side\"").unwrap();
    let rest = three[cut..].find("[segmenter]").unwrap() + cut;
    let end = three[rest..].find("\n\n").map_or(three.len(), |e| rest + e);
    format!(
        "{}[segmenter]\nkind = \"builtin\"{}",
        &three[..cut],
        &three[end..]
    )
}

/// Each camera stops asking for views once its estimate settles; the loop stops when all
/// have, and rounds.json follows every camera.
#[test]
fn cameras_that_converge_stop_asking_and_the_loop_stops_when_all_have() {
    let path = config_path();
    let mut cfg = read_config(&path).unwrap();
    cfg.calibration.max_views = 8;
    cfg.calibration.min_views = 3;
    cfg.calibration.pose_tol_deg = 0.1;
    cfg.calibration.pose_tol_mm = 1.0;
    cfg.calibration.joint_samples = 1000;
    cfg.calibration.candidates = 24;
    let cell = Cell::build(cfg, &path).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let outcome = common::run_loop(&cell, &out);
    let views = outcome.cameras[0].result.views_used.len();
    assert!(views < 8, "{}", outcome.result.stop_reason);
    assert_eq!(
        outcome.result.stop_reason,
        format!("every camera converged after {views} views")
    );
    for cam in &outcome.cameras {
        assert!(
            cam.result.stop_reason.starts_with("converged after "),
            "{}: {}",
            cam.name,
            cam.result.stop_reason
        );
    }
    let rounds: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("rounds.json")).unwrap()).unwrap();
    let rounds = rounds["rounds"].as_array().unwrap();
    for r in rounds {
        let names: Vec<&str> = r["cameras"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| c["name"].as_str().unwrap())
            .collect();
        assert_eq!(names, ["front", "side", "high"]);
    }
    let last = rounds.last().unwrap()["cameras"].as_array().unwrap();
    assert!(last.iter().all(|c| c["done"].is_string()), "{last:?}");
}

/// A single `[camera]` table keeps the single-camera formats: `easyhec-run/1`,
/// `easyhec-result/1`, and rounds without a `cameras` list.
#[test]
fn a_single_camera_table_keeps_the_first_formats() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/sim-xarm6.toml");
    let mut cfg = read_config(&path).unwrap();
    cfg.calibration.max_views = 2;
    cfg.calibration.min_views = 2;
    cfg.calibration.joint_samples = 500;
    cfg.calibration.candidates = 16;
    let cell = Cell::build(cfg, &path).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    common::run_loop(&cell, &out);
    let read = |f: &str| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(out.join(f)).unwrap()).unwrap()
    };
    assert_eq!(read("run.json")["format"], "easyhec-run/1");
    assert_eq!(read("result.json")["format"], "easyhec-result/1");
    let rounds = read("rounds.json");
    let rounds = rounds["rounds"].as_array().unwrap();
    assert!(!rounds.is_empty());
    assert!(rounds.iter().all(|r| r.get("cameras").is_none()));
}

/// A fixed camera and a wrist camera in one run: each transform is named by its own mount
/// (`camera_from_base`, `camera_from_link6`) and reaches its truth, every view shows the
/// robot to both cameras by each one's rule, and every commanded pose passes the checker.
#[test]
fn a_fixed_and_a_wrist_camera_calibrate_from_one_motion() {
    use easyhec::config::Mount;
    let name = "sim-xarm6-fixed-and-wrist.toml";
    let cfg = quick_config(name);
    let coverage_needed = cfg.calibration.min_robot_image_fraction;
    let cell = Cell::build(cfg, &shipped(name)).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let outcome = common::run_loop(&cell, &out);
    let frames = ["world", "link6"];
    let bases: Vec<&str> = outcome
        .cameras
        .iter()
        .map(|c| c.result.base_link.as_str())
        .collect();
    assert_eq!(bases, frames);
    assert_each_camera_near(&cell, &outcome, 0.2, 1.0);
    assert_three_safe_moves(&cell);
    // The run records each mount, and every recorded wrist mask shows the robot over at
    // least the share of the image the planner asked for.
    let parts = load_cameras_with(&out, MaskSource::Recorded).unwrap();
    assert_eq!(parts[0].1.file.camera.mount, Mount::Fixed);
    assert_eq!(parts[1].1.file.camera.mount, Mount::Link("link6".into()));
    assert_eq!(parts[1].1.robot.links[parts[1].1.robot.base], "link6");
    for (k, view) in parts[1].1.views.iter().enumerate() {
        let mask = &view.observed;
        let covered = mask.data.iter().filter(|&&m| m != 0).count() as f64 / mask.data.len() as f64;
        assert!(
            covered >= 0.8 * coverage_needed,
            "wrist view {k}: the robot covers {covered:.3} of the image"
        );
    }
    let result = RigResultFile::read(&out.join("result.json")).unwrap();
    let bases: Vec<&str> = result
        .cameras
        .iter()
        .map(|c| c.base_link.as_str())
        .collect();
    assert_eq!(bases, frames);
    // `easyhec solve` names each camera's transform by its mount, and with the simulator's
    // truth beside the run (the wrist camera's in link6's frame) prints each one's error.
    let truth = easyhec::cell::sim::rig_ground_truth(&cell).unwrap();
    assert_eq!(truth.cameras[1].transform, "camera_from_link6");
    easyhec::io::write_json_atomic(&out.join("ground_truth.json"), &truth).unwrap();
    let resolved = dir.path().join("resolved.json");
    let solved = common::solve_run(&out, &["--out", resolved.to_str().unwrap()]);
    let stdout = String::from_utf8_lossy(&solved.stdout);
    assert!(
        solved.status.success(),
        "{}",
        String::from_utf8_lossy(&solved.stderr)
    );
    assert!(
        stdout.contains("wrist: camera_from_link6 solved from 4 views"),
        "{stdout}"
    );
    assert!(
        stdout.contains("front: camera_from_base solved from 4 views"),
        "{stdout}"
    );
    assert_truth_lines(&stdout, &outcome);
    // Exported, each camera hangs from its own mount's frame.
    let exported = dir.path().join("urdf");
    export_urdf(&out.join("result.json"), &exported);
    // One parent for every camera would hang the wrist camera from the wrong frame.
    let refused = std::process::Command::new(common::easyhec_bin())
        .arg("export")
        .arg(out.join("result.json"))
        .args(["--format", "urdf", "--frame-id", "world", "--out"])
        .arg(dir.path().join("refused"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(
        !refused.status.success() && stderr.contains("--frame-id"),
        "{stderr}"
    );
    assert!(!dir.path().join("refused").exists());
    for (name, frame) in ["front", "wrist"].iter().zip(frames) {
        let urdf = std::fs::read_to_string(exported.join(format!("{name}.urdf"))).unwrap();
        assert!(
            urdf.contains(&format!("<parent link=\"{frame}\"/>")),
            "{urdf}"
        );
    }
}

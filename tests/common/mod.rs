//! Shared helpers for integration tests: one module tree, included by a test file as
//! `mod common;`. `daemon` holds the daemon tests' helpers (a test daemon on a loopback port
//! and a plain HTTP client). Each test binary compiles all of it and uses a part, so dead code
//! is allowed here.
#![allow(dead_code)]

pub mod daemon;
pub mod onnx_pb;

use std::path::PathBuf;

/// The repository's root (the crate's manifest folder).
pub fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// A config shipped in `config/`.
pub fn config_path(name: &str) -> PathBuf {
    repo_root().join("config").join(name)
}

use easyhec::robot::RobotModel;

/// `../shared/robots/NAME/robot.urdf` beside the checkout.
pub fn robot_urdf(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/robots")
        .join(name)
        .join("robot.urdf")
}

/// Loads one of the vendor robots.
pub fn load_robot(name: &str) -> RobotModel {
    RobotModel::from_urdf(robot_urdf(name)).expect("vendor robot loads")
}

/// The `easyhec` binary built for this test run.
pub fn easyhec_bin() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_easyhec"))
}

/// Runs `easyhec synth --robot <vendor NAME> --out OUT ARGS…` and checks it succeeded.
pub fn synth_run(out: &std::path::Path, robot: &str, args: &[&str]) {
    let status = std::process::Command::new(easyhec_bin())
        .args(["synth", "--robot"])
        .arg(robot_urdf(robot))
        .arg("--out")
        .arg(out)
        .args(args)
        .status()
        .expect("easyhec runs");
    assert!(status.success(), "synth failed");
}

/// Runs `easyhec solve RUN EXTRA…`.
pub fn solve_run(run: &std::path::Path, extra: &[&str]) -> std::process::Output {
    std::process::Command::new(easyhec_bin())
        .arg("solve")
        .arg(run)
        .args(extra)
        .output()
        .expect("easyhec runs")
}

/// Writes `text` as `dir/name` and opens it as a cell: the one-line error that gives
/// (panics when the cell opens).
pub fn cell_open_error(dir: &std::path::Path, name: &str, text: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    match easyhec::cell::Cell::open(&p) {
        Ok(_) => panic!("{name} accepted"),
        Err(e) => e.to_string(),
    }
}

/// The runtime the mock-controller tests drive a calibration on: two workers, as CI has
/// two cores.
pub fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap()
}

/// Command `i` from `from` to `target` at `speed_rad_s` passes the checker, and so does every
/// pose of its straight joint-space path sampled 20x finer than the checker's own sampling
/// (an independent re-check of what the arm executed).
pub fn assert_commanded_path_safe(
    checker: &easyhec::safety::SafetyChecker,
    i: usize,
    from: &[f64],
    target: &[f64],
    speed_rad_s: f64,
) {
    checker
        .check_move(from, target, speed_rad_s)
        .unwrap_or_else(|v| panic!("command {i} unsafe: {v}"));
    let n = checker.path_samples(from, target) * 20;
    for k in 0..=n {
        let s = k as f64 / n as f64;
        let q: Vec<f64> = from
            .iter()
            .zip(target)
            .map(|(a, b)| a + (b - a) * s)
            .collect();
        checker
            .check_pose(&q)
            .unwrap_or_else(|v| panic!("command {i} at {s:.4} of its path: {v}"));
    }
}

/// Every point a fake ROS 2 trajectory controller logged (tests/ros2/fake_controller.py): within the limits, at or under the speed cap, and
/// its straight path from where the joints were passes the checker.
pub fn assert_logged_commands_safe(
    cfg: &easyhec::config::CellConfig,
    path: &std::path::Path,
    commands: &str,
) -> usize {
    let robot =
        std::sync::Arc::new(easyhec::robot::RobotModel::from_urdf(&cfg.robot.urdf).unwrap());
    let controller: Vec<(f64, f64, f64)> = robot
        .actuated
        .iter()
        .map(|&i| {
            let j = &robot.joints[i];
            (j.lower, j.upper, j.velocity)
        })
        .collect();
    let checker =
        easyhec::safety::SafetyChecker::new(robot.clone(), &cfg.safety, &controller, path).unwrap();
    let mut moves = 0;
    for (i, line) in commands.lines().enumerate() {
        let c: serde_json::Value = serde_json::from_str(line).unwrap();
        assert!(c["rejected"].is_null(), "command {i} refused: {c}");
        assert_eq!(c["points"], 1, "command {i}: one point per move");
        // Positions only, starting now: the controller then interpolates linearly.
        assert_eq!(
            c["extras"], false,
            "command {i}: velocities or efforts sent"
        );
        assert_eq!(
            c["stamp"],
            serde_json::json!([0, 0]),
            "command {i}: a future start"
        );
        let floats = |v: &serde_json::Value| -> Vec<f64> {
            v.as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap())
                .collect()
        };
        let (from, to) = (floats(&c["from"]), floats(&c["to"]));
        let widest = from
            .iter()
            .zip(&to)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        let speed = widest / c["time_s"].as_f64().unwrap();
        let cap = checker.speed_cap_rad_s();
        assert!(
            speed <= cap * (1.0 + 1e-6),
            "command {i}: {speed} rad/s over {cap}"
        );
        for (k, (v, (lo, hi))) in to.iter().zip(checker.limits()).enumerate() {
            assert!(*v >= *lo && *v <= *hi, "command {i} joint {k} at {v}");
        }
        assert_commanded_path_safe(&checker, i, &from, &to, speed.max(1e-9));
        moves += 1;
    }
    moves
}

/// Each `(config text, needle)` written into `dir` as `bad{i}.toml` is refused by
/// `Cell::open` with one line that names the file and contains `needle`; `base` is the valid
/// text every case was edited from (a case that changed nothing is itself an error).
pub fn assert_configs_refused(dir: &std::path::Path, base: &str, cases: &[(String, &str)]) {
    for (i, (text, needle)) in cases.iter().enumerate() {
        assert_ne!(text, base, "case {i} changed nothing");
        let p = dir.join(format!("bad{i}.toml"));
        std::fs::write(&p, text).unwrap();
        let e = match easyhec::cell::Cell::open(&p) {
            Ok(_) => panic!("case {i} accepted"),
            Err(e) => e.to_string(),
        };
        assert!(
            e.contains(&format!("bad{i}.toml")) && e.contains(needle),
            "case {i}: {e}"
        );
        assert!(!e.contains('\n'), "case {i}: {e}");
    }
}

/// The text of the shipped `config/NAME` with its `../robots/` paths made absolute, so an
/// edited copy written anywhere still finds the checkout's robot descriptions.
pub fn shipped_config_text(name: &str) -> String {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    std::fs::read_to_string(root.join("config").join(name))
        .unwrap()
        .replace(
            "\"../robots/",
            &format!("\"{}/", root.join("robots").display()),
        )
}

/// The closed loop on `cell` with default options, recorded into `out`, on a runtime of its
/// own (tests are synchronous).
pub fn run_loop(cell: &easyhec::cell::Cell, out: &std::path::Path) -> easyhec::calibrate::Outcome {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
        .block_on(easyhec::calibrate::calibrate(
            cell,
            out,
            &easyhec::calibrate::RunOptions::default(),
        ))
        .unwrap()
}

/// EasyHeC's offline layout (`mask/ qpos/ K.txt`, and `color/` with `with_color`) written
/// from the synthetic run at `run`.
pub fn write_easyhec_source(run: &std::path::Path, src: &std::path::Path, with_color: bool) {
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("run.json")).unwrap()).unwrap();
    for sub in ["mask", "qpos", "color"]
        .iter()
        .take(if with_color { 3 } else { 2 })
    {
        std::fs::create_dir_all(src.join(sub)).unwrap();
    }
    for (i, v) in json["views"].as_array().unwrap().iter().enumerate() {
        let mask = run.join(v["mask"].as_str().unwrap());
        std::fs::copy(&mask, src.join(format!("mask/{i:04}.png"))).unwrap();
        if with_color {
            let image = run.join(v["image"].as_str().unwrap());
            std::fs::copy(&image, src.join(format!("color/{i:04}.png"))).unwrap();
        }
        let q: Vec<String> = v["joints"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.to_string())
            .collect();
        std::fs::write(src.join(format!("qpos/{i:04}.txt")), q.join(" ")).unwrap();
    }
    let c = &json["camera"];
    let k = format!(
        "{} 0 {}\n0 {} {}\n0 0 1\n",
        c["fx"], c["cx"], c["fy"], c["cy"]
    );
    std::fs::write(src.join("K.txt"), k).unwrap();
}

/// Every command the simulated arm received was accepted by it and passes the checker from
/// where the arm truly was; each executed path is also re-checked 20x finer than the
/// checker's own sampling. Returns the number of commands.
pub fn assert_every_command_safe(cell: &easyhec::cell::Cell) -> usize {
    let sim = cell.sim_arm().expect("simulated arm");
    let commands = sim.commands();
    let speed_cap = cell.checker.speed_cap_rad_s();
    for (i, c) in commands.iter().enumerate() {
        assert!(
            c.accepted,
            "command {i} was refused by the arm: {:?}",
            c.outcome
        );
        assert!(
            c.speed_rad_s <= speed_cap,
            "command {i} speed {}",
            c.speed_rad_s
        );
        assert_commanded_path_safe(&cell.checker, i, &c.from, &c.target, c.speed_rad_s);
    }
    commands.len()
}

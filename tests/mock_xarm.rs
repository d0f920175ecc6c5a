//! The closed loop through the real xArm driver and a mock controller on free loopback ports
//! (`config/mock-xarm.toml`): the calibration reaches the simulated truth, every command the
//! controller received was accepted, within its caps and safe; and a link lost mid-move
//! ends the calibration with the arm stopped short of its target.

mod common;

use std::path::PathBuf;
use std::time::{Duration, Instant};

use easyhec::calibrate::{calibrate, Outcome, RunOptions};
use easyhec::cell::Cell;
use easyhec::config::{read_config, ArmConfig, CameraConfig, CellConfig, JointsFrom};
use easyhec::config::{SimCameraSettings, XarmSettings};
use easyhec::geometry::{rotation_error_deg, translation_error_mm};
use easyhec_drivers::xarm::Model;
use easyhec_mocks::xarm::{MockFault, MockXArm, MockXArmConfig, MoveRecord};

/// The start pose of the shipped simulated cell (the camera sees the whole arm).
const START: [f64; 6] = [0.0, -0.35, -0.6, 0.0, 0.95, 0.0];

fn config_path() -> PathBuf {
    common::config_path("mock-xarm.toml")
}

fn spawn_mock(
    rt: &tokio::runtime::Runtime,
    speedup: f64,
    faults: Vec<MockFault>,
    halt: bool,
) -> MockXArm {
    let mut cfg = MockXArmConfig::free_ports(Model::Xarm6);
    cfg.start = Some(START.to_vec());
    // The driver's cap (config: 1 rad/s) is the controller's: anything faster is refused.
    cfg.speed_cap_rad_s = 1.0;
    cfg.speedup = speedup;
    cfg.faults = faults;
    cfg.halt_on_disconnect = halt;
    rt.block_on(MockXArm::spawn(cfg)).unwrap()
}

/// The shipped config pointed at `mock`'s ports.
fn cell_config(mock: &MockXArm, views: usize) -> CellConfig {
    let mut cfg = read_config(&config_path()).unwrap();
    let ArmConfig::Xarm(XarmSettings { addr, .. }) = &mut cfg.arm else {
        panic!("config/mock-xarm.toml drives an xArm")
    };
    *addr = mock.command_addr().to_string();
    let CameraConfig::Sim(SimCameraSettings { joints_from, .. }) = cfg.camera.first_mut() else {
        panic!("the camera is simulated")
    };
    let Some(JointsFrom::XarmReport { addr, .. }) = joints_from else {
        panic!("the camera films the controller's report stream")
    };
    *addr = mock.real_report_addr().unwrap().to_string();
    cfg.calibration.max_views = views;
    cfg.calibration.joint_samples = 600;
    cfg.calibration.candidates = 24;
    cfg
}

fn run(
    rt: &tokio::runtime::Runtime,
    cell: &Cell,
    out: &std::path::Path,
) -> easyhec::Result<Outcome> {
    rt.block_on(calibrate(cell, out, &RunOptions::default()))
}

/// Every command the controller received was accepted, within the checker's limits and
/// speed cap, passes the checker from where the arm truly was, and its executed path passes
/// 20x finer than the checker's own sampling.
fn assert_every_command_safe(cell: &Cell, commands: &[MoveRecord]) {
    let cap = cell.checker.speed_cap_rad_s();
    for (i, c) in commands.iter().enumerate() {
        assert!(c.accepted, "command {i} refused: {:?}", c.outcome);
        assert!(c.unused_slots.iter().all(|v| *v == 0.0));
        // f32 on the wire: allow its rounding.
        assert!(
            c.speed_rad_s <= cap * (1.0 + 1e-6),
            "command {i} speed {}",
            c.speed_rad_s
        );
        for (k, (v, (lo, hi))) in c.target.iter().zip(cell.checker.limits()).enumerate() {
            assert!(
                *v >= lo - 1e-6 && *v <= hi + 1e-6,
                "command {i} joint {k} at {v}"
            );
        }
        common::assert_commanded_path_safe(
            &cell.checker,
            i,
            &c.from,
            &c.target,
            c.speed_rad_s.min(cap),
        );
    }
}

#[test]
fn calibration_through_the_xarm_driver_reaches_the_truth_safely() {
    let rt = common::runtime();
    let mock = spawn_mock(&rt, 5.0, vec![], false);
    let path = config_path();
    let cell = Cell::build(cell_config(&mock, 5), &path).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let t = Instant::now();
    let outcome = run(&rt, &cell, &dir.path().join("run")).unwrap();
    let elapsed = t.elapsed();
    let truth = cell.units[0].sim.camera_from_base.unwrap();
    let est = outcome.result.camera_from_base();
    let (r, tr) = (
        rotation_error_deg(&est, &truth),
        translation_error_mm(&est, &truth),
    );
    eprintln!(
        "mock xArm calibration: {} views, {r:.4} deg, {tr:.3} mm, {:.1} s ({})",
        outcome.result.views_used.len(),
        elapsed.as_secs_f64(),
        outcome.result.stop_reason
    );
    assert!(r <= 0.05 && tr <= 1.0, "error {r:.4} deg {tr:.3} mm");
    let commands = mock.commands();
    assert_eq!(commands.len(), outcome.result.views_used.len() - 1);
    assert!(commands
        .iter()
        .all(|c| c.outcome.as_deref() == Some("arrived")));
    assert_every_command_safe(&cell, &commands);
    // Each recorded view's joints are where the controller put the arm.
    let run = easyhec::run::load_run(&dir.path().join("run")).unwrap();
    for (view, c) in run.views.iter().skip(1).zip(&commands) {
        let off = view
            .joints
            .iter()
            .zip(&c.target)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(
            off < 1e-5,
            "view joints {:?} vs target {:?}",
            view.joints,
            c.target
        );
    }
}

/// A controller that already reports an error is not cleared by the first move: with
/// `clear_faults = false` the calibration ends without any move reaching the arm.
#[test]
fn an_error_present_at_start_is_not_cleared_by_the_first_move() {
    let rt = common::runtime();
    let mock = spawn_mock(&rt, 5.0, Vec::new(), false);
    mock.inject_error(22);
    let mut cfg = cell_config(&mock, 3);
    cfg.calibration.clear_faults = false;
    let cell = Cell::build(cfg, &config_path()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let reason = match run(&rt, &cell, &dir.path().join("run")) {
        Ok(outcome) => outcome.result.stop_reason,
        Err(e) => e.to_string(),
    };
    assert!(reason.contains("before the first move"), "{reason}");
    assert!(mock.commands().is_empty(), "{:?}", mock.commands());
    assert_eq!(mock.reported_state(), 4, "the error stays for the operator");
}

#[test]
fn link_lost_mid_move_ends_the_calibration_with_the_arm_stopped() {
    let rt = common::runtime();
    // The controller keeps executing after the drop (worst case); only the driver's stop,
    // sent on a new connection, halts it.
    let drop = MockFault::DropMidMove {
        on_move: 0,
        at_fraction: 0.2,
        refuse_reconnect: false,
    };
    // Real-time motion: the stop must win against the arm, not against a 5x clock.
    let mock = spawn_mock(&rt, 1.0, vec![drop], false);
    let path = config_path();
    let cell = Cell::build(cell_config(&mock, 4), &path).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let outcome = run(&rt, &cell, &dir.path().join("run")).unwrap();
    let reason = &outcome.result.stop_reason;
    assert!(
        reason.contains("link lost") && reason.contains("not cleared"),
        "{reason}"
    );
    assert_eq!(outcome.result.views_used.len(), 1);
    let commands = mock.commands();
    assert_eq!(commands.len(), 1, "no move after the loss");
    let target = commands[0].target.clone();
    let q = mock.true_joints();
    rt.block_on(async { tokio::time::sleep(Duration::from_millis(200)).await });
    assert_eq!(mock.true_joints(), q, "the arm stands still");
    let short = q
        .iter()
        .zip(&target)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(short > 0.05, "stopped {short} rad short of the target");
    assert_eq!(mock.reported_state(), 4);
    assert_every_command_safe(&cell, &commands);

    // A controller that cannot be reached again: the calibration aborts with one line.
    let drop = MockFault::DropMidMove {
        on_move: 0,
        at_fraction: 0.2,
        refuse_reconnect: true,
    };
    let mock = spawn_mock(&rt, 1.0, vec![drop], true);
    let cell = Cell::build(cell_config(&mock, 4), &path).unwrap();
    let e = run(&rt, &cell, &dir.path().join("run2"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("connection") && !e.contains('\n'), "{e}");
    let q = mock.true_joints();
    rt.block_on(async { tokio::time::sleep(Duration::from_millis(100)).await });
    assert_eq!(
        mock.true_joints(),
        q,
        "the controller halted on the lost link"
    );
    assert!(!dir.path().join("run2/result.json").exists());
}

#[test]
fn bad_xarm_cell_configs_get_one_line_errors_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let base = std::fs::read_to_string(config_path()).unwrap().replace(
        "../robots/xarm6/robot.urdf",
        &PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("robots/xarm6/robot.urdf")
            .display()
            .to_string(),
    );
    let joints_from = "joints_from = { kind = \"xarm-report\", addr = \"127.0.0.1:30003\" }\n";
    let cases = [
        (
            base.replace("model = \"xarm6\"", "model = \"xarm9\""),
            "arm.model",
        ),
        (
            base.replace("model = \"xarm6\"", "model = \"xarm7\""),
            "arm.model",
        ),
        (
            base.replace("speed_cap_rad_s = 1.0", "speed_cap_rad_s = -1.0"),
            "speed cap",
        ),
        (
            base.replace(
                "accel_rad_s2 = 5.0",
                "accel_rad_s2 = 5.0\nreply_timeout_s = 0.0",
            ),
            "arm.reply_timeout_s",
        ),
        (base.replace(joints_from, ""), "camera.joints_from"),
        (
            base.replace("kind = \"xarm-report\"", "kind = \"no-such-source\""),
            "line",
        ),
    ];
    common::assert_configs_refused(dir.path(), &base, &cases);
}

/// `DIR/cell.toml` for `easyhec calibrate` against `mock` (the URDF made absolute).
fn write_cell(mock: &MockXArm, views: usize, dir: &std::path::Path) -> PathBuf {
    let mut cfg = cell_config(mock, views);
    cfg.robot.urdf = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots/xarm6/robot.urdf");
    let path = dir.join("cell.toml");
    std::fs::write(&path, toml::to_string(&cfg).unwrap()).unwrap();
    path
}

fn calibrate_process(config: &std::path::Path, out: &std::path::Path) -> std::process::Child {
    std::process::Command::new(env!("CARGO_BIN_EXE_easyhec"))
        .args(["--quiet", "calibrate", "--renderer", "cpu", "--config"])
        .arg(config)
        .arg("--out")
        .arg(out)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("easyhec runs")
}

/// Stop requests (SET_STATE 4) the mock controller has received.
fn stops(mock: &MockXArm) -> usize {
    mock.requests()
        .iter()
        .filter(|r| r.register == 0x0C && r.params == [4])
        .count()
}

#[test]
fn sigterm_mid_move_sends_the_arm_a_stop_before_calibrate_exits() {
    let rt = common::runtime();
    // Real-time motion, so the signal lands while the arm moves.
    let mock = spawn_mock(&rt, 1.0, vec![], false);
    let dir = tempfile::tempdir().unwrap();
    let config = write_cell(&mock, 6, dir.path());
    let run = dir.path().join("run");
    let mut child = calibrate_process(&config, &run);
    let started = Instant::now();
    while mock.commands().is_empty() {
        assert!(
            child.try_wait().unwrap().is_none(),
            "calibrate ended before moving"
        );
        assert!(
            started.elapsed() < Duration::from_secs(120),
            "no move within 120 s"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    std::thread::sleep(Duration::from_millis(200));
    let stops_before = stops(&mock);
    let killed = std::process::Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(143), "{err}");
    assert!(
        stops(&mock) > stops_before,
        "no stop command reached the controller before the process exited"
    );
    assert!(
        err.contains("SIGTERM") && err.contains("easyhec solve"),
        "{err}"
    );
    let q = mock.true_joints();
    std::thread::sleep(Duration::from_millis(200));
    assert_eq!(mock.true_joints(), q, "the arm stands still");
    assert!(
        run.join("run.json").is_file(),
        "the run folder keeps its views"
    );
}

#[test]
fn a_loop_stopped_by_an_arm_fault_exits_with_its_own_code() {
    let rt = common::runtime();
    let fault = MockFault::ErrorMidMove {
        on_move: 0,
        at_fraction: 0.3,
        code: 31,
    };
    let mock = spawn_mock(&rt, 5.0, vec![fault], false);
    let dir = tempfile::tempdir().unwrap();
    let config = write_cell(&mock, 4, dir.path());
    let out = calibrate_process(&config, &dir.path().join("run"))
        .wait_with_output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{err}");
    assert!(
        err.contains("error: the loop stopped on an arm fault"),
        "{err}"
    );
}

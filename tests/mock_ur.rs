//! The closed loop through the UR driver (`UrArm`: pyo3 + the vendor's ur_rtde) and a mock
//! controller on a loopback address of its own (`config/mock-ur.toml`): the calibration
//! reaches the simulated truth, every moveJ the controller received was accepted, within its
//! caps and safe; a protective stop mid-move ends the calibration with the arm stopped short;
//! a controller lost for good aborts it with one line.
//!
//! Needs the `ur` feature and `ur-rtde==1.6.5` for python3:
//! `cargo test --release --features ur --test mock_ur`.
#![cfg(feature = "ur")]

mod common;

use std::path::PathBuf;
use std::time::{Duration, Instant};

use easyhec::calibrate::{calibrate, Outcome, RunOptions};
use easyhec::cell::Cell;
use easyhec::config::{read_config, ArmConfig, CameraConfig, CellConfig, JointsFrom};
use easyhec::config::{SimCameraSettings, UrSettings};
use easyhec::geometry::{rotation_error_deg, translation_error_mm};
use easyhec_mocks::ur::{MockUr, MockUrConfig, MockUrFault, UrMoveRecord};

/// One UR test at a time: ur_rtde's calls hold the GIL (some for seconds, e.g. while its
/// control interface retries a lost controller), and every driver in this process shares it,
/// so parallel tests would starve each other's time-limited calls.
static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn serial() -> std::sync::MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

fn config_path() -> PathBuf {
    common::config_path("mock-ur.toml")
}

fn spawn_mock(
    rt: &tokio::runtime::Runtime,
    speedup: f64,
    faults: Vec<MockUrFault>,
    halt: bool,
) -> MockUr {
    let mut cfg = MockUrConfig::free_ports();
    // The driver's cap (config: 1 rad/s) is the controller's: anything faster is refused.
    cfg.speed_cap_rad_s = 1.0;
    cfg.speedup = speedup;
    cfg.faults = faults;
    cfg.halt_on_disconnect = halt;
    rt.block_on(MockUr::spawn(cfg)).unwrap()
}

/// The shipped config pointed at `mock`.
fn cell_config(mock: &MockUr, views: usize) -> CellConfig {
    let mut cfg = read_config(&config_path()).unwrap();
    let ArmConfig::Ur(UrSettings { host, .. }) = &mut cfg.arm else {
        panic!("config/mock-ur.toml drives a UR arm")
    };
    *host = mock.host().to_string();
    let CameraConfig::Sim(SimCameraSettings { joints_from, .. }) = cfg.camera.first_mut() else {
        panic!("the camera is simulated")
    };
    let Some(JointsFrom::UrRtde { addr, .. }) = joints_from else {
        panic!("the camera films the controller's RTDE stream")
    };
    *addr = mock.rtde_addr().to_string();
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

/// Every moveJ the controller received was accepted, within the checker's limits and speed
/// cap, passes the checker from where the arm truly was, and its executed path passes 20x
/// finer than the checker's own sampling.
fn assert_every_command_safe(cell: &Cell, commands: &[UrMoveRecord]) {
    let cap = cell.checker.speed_cap_rad_s();
    for (i, c) in commands.iter().enumerate() {
        assert!(c.accepted, "command {i} refused: {:?}", c.outcome);
        assert!(c.speed_rad_s <= cap, "command {i} speed {}", c.speed_rad_s);
        assert!(
            c.accel_rad_s2 <= 1.4,
            "command {i} acceleration {}",
            c.accel_rad_s2
        );
        for (k, (v, (lo, hi))) in c.target.iter().zip(cell.checker.limits()).enumerate() {
            assert!(*v >= *lo && *v <= *hi, "command {i} joint {k} at {v}");
        }
        common::assert_commanded_path_safe(&cell.checker, i, &c.from, &c.target, c.speed_rad_s);
    }
}

#[test]
fn calibration_through_the_ur_driver_reaches_the_truth_safely() {
    let _serial = serial();
    let rt = common::runtime();
    let mock = spawn_mock(&rt, 5.0, vec![], false);
    let cell = Cell::build(cell_config(&mock, 5), &config_path()).unwrap();
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
        "mock UR calibration: {} views, {r:.4} deg, {tr:.3} mm, {:.1} s ({})",
        outcome.result.views_used.len(),
        elapsed.as_secs_f64(),
        outcome.result.stop_reason
    );
    assert!(r <= 0.05 && tr <= 1.0, "error {r:.4} deg {tr:.3} mm");
    let commands = mock.commands();
    assert_eq!(commands.len(), outcome.result.views_used.len() - 1);
    assert!(commands
        .iter()
        .all(|c| c.asynchronous && c.outcome.as_deref() == Some("arrived")));
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
            off < 1e-9,
            "view joints {:?} vs target {:?}",
            view.joints,
            c.target
        );
    }
}

#[test]
fn protective_stop_mid_move_ends_the_calibration_with_the_arm_stopped() {
    let _serial = serial();
    let rt = common::runtime();
    let stop = MockUrFault::ProtectiveStop {
        on_move: 0,
        at_fraction: 0.3,
    };
    // Real-time motion, so the fault lands well after ur_rtde accepted the move.
    let mock = spawn_mock(&rt, 1.0, vec![stop], false);
    let cell = Cell::build(cell_config(&mock, 4), &config_path()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let outcome = run(&rt, &cell, &dir.path().join("run")).unwrap();
    let reason = &outcome.result.stop_reason;
    assert!(
        reason.contains("PROTECTIVE_STOP") && reason.contains("not cleared"),
        "{reason}"
    );
    assert_eq!(outcome.result.views_used.len(), 1);
    let commands = mock.commands();
    assert_eq!(commands.len(), 1, "no move after the stop");
    assert_eq!(commands[0].outcome.as_deref(), Some("protective stop"));
    let q = mock.true_joints();
    rt.block_on(async { tokio::time::sleep(Duration::from_millis(100)).await });
    assert_eq!(mock.true_joints(), q, "the arm stands still");
    let short = q
        .iter()
        .zip(&commands[0].target)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(short > 0.02, "stopped {short} rad short of the target");
    assert_every_command_safe(&cell, &commands);
}

#[test]
fn controller_lost_for_good_aborts_with_one_line_and_the_arm_stopped() {
    let _serial = serial();
    let rt = common::runtime();
    let drop = MockUrFault::DropMidMove {
        on_move: 0,
        at_fraction: 0.2,
        refuse_reconnect: true,
    };
    let mock = spawn_mock(&rt, 1.0, vec![drop], true);
    let cell = Cell::build(cell_config(&mock, 4), &config_path()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let e = run(&rt, &cell, &dir.path().join("run"))
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
    assert_eq!(mock.commands().len(), 1);
    assert!(!dir.path().join("run/result.json").exists());
}

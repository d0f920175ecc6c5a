//! Planning that counts motion time: on an arm whose moves take time, weighing it shortens
//! the commanded travel and the motion time, keeps every command safe and still reaches the
//! simulated truth.

mod common;

use std::path::PathBuf;

use easyhec::calibrate::{calibrate, Outcome, RunOptions};
use easyhec::cell::Cell;
use easyhec::config::SimArmSettings;
use easyhec::config::{read_config, ArmConfig, CellConfig};
use easyhec::geometry::{rotation_error_deg, translation_error_mm};

fn config(speedup: Option<f64>, weigh: bool) -> (CellConfig, PathBuf) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/sim-xarm6.toml");
    let mut cfg = read_config(&path).unwrap();
    if let ArmConfig::Sim(SimArmSettings { speedup: s, .. }) = &mut cfg.arm {
        *s = speedup;
    }
    cfg.calibration.weigh_motion_time = weigh;
    // A fixed overhead keeps the ranking independent of this machine's speed.
    cfg.calibration.view_overhead_s = Some(1.5);
    cfg.calibration.max_views = 4;
    cfg.calibration.min_views = 4;
    cfg.calibration.joint_samples = 800;
    cfg.calibration.candidates = 24;
    (cfg, path)
}

/// Calibrates; returns the outcome, the commanded travel (sum over moves of the farthest
/// joint's distance, rad) and the cell.
fn run(cfg: CellConfig, path: &std::path::Path) -> (Outcome, f64, Cell) {
    let cell = Cell::build(cfg, path).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let outcome = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
        .block_on(calibrate(
            &cell,
            &dir.path().join("run"),
            &RunOptions::default(),
        ))
        .unwrap();
    common::assert_every_command_safe(&cell);
    let commands = cell.sim_arm().unwrap().commands();
    let travel = commands
        .iter()
        .map(|c| {
            c.from
                .iter()
                .zip(&c.target)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max)
        })
        .sum();
    (outcome, travel, cell)
}

fn error(outcome: &Outcome, cell: &Cell) -> (f64, f64) {
    let truth = cell.units[0].sim.camera_from_base.unwrap();
    let est = outcome.result.camera_from_base();
    (
        rotation_error_deg(&est, &truth),
        translation_error_mm(&est, &truth),
    )
}

#[test]
fn weighing_motion_time_shortens_the_travel_on_an_arm_that_takes_time() {
    // 20x real time: moves take time the planner must count, the test stays short.
    let (cfg, path) = config(Some(20.0), false);
    let (plain, plain_travel, cell) = run(cfg, &path);
    let (cfg, path) = config(Some(20.0), true);
    let (weighed, weighed_travel, weighed_cell) = run(cfg, &path);
    eprintln!("travel {weighed_travel:.2} rad weighed, {plain_travel:.2} rad by information alone");
    assert!(
        weighed_travel < 0.7 * plain_travel,
        "travel {weighed_travel:.2} rad weighed vs {plain_travel:.2} rad by information alone"
    );
    let motion = |o: &Outcome| o.result.timings_s["motion"];
    assert!(
        motion(&weighed) < motion(&plain),
        "{} vs {} s",
        motion(&weighed),
        motion(&plain)
    );
    for (o, c) in [(&plain, &cell), (&weighed, &weighed_cell)] {
        let (r, t) = error(o, c);
        assert!(r < 0.15 && t < 1.5, "error {r:.4} deg {t:.3} mm");
        assert_eq!(o.result.views_used.len(), 4, "{}", o.result.stop_reason);
    }
}

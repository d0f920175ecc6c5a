//! `easyhec bench motion`: planning that counts motion time against planning that ranks by
//! information alone, on the mock xArm in real time.
//!
//! Each seeded cell (camera, start pose and guess as in `bench loop`) is calibrated twice
//! through the real xArm driver against `easyhec-mock xarm` at the config's speed caps, once
//! with `weigh_motion_time = false` (information only) and once with `true`, each from a
//! fresh controller at the same start. The loop stops by its own rules. Reported: total wall
//! time (motion included), motion time, views and the error against the simulated truth.

use std::path::PathBuf;

use super::{median, seeded_sim_cell, Report};
use crate::calibrate::{calibrate, RunOptions};
use crate::cell::Cell;
use crate::config::{read_config, ArmConfig, CameraConfig, CellConfig, JointsFrom};
use crate::config::{SimArmSettings, SimCameraSettings, XarmSettings};
use crate::error::{Error, Result};
use crate::geometry::{rotation_error_deg, translation_error_mm};

/// One calibration of the benchmark.
#[derive(Clone, Debug)]
pub struct MotionTrial {
    /// Total wall seconds, setup and motion included.
    pub total_s: f64,
    /// Seconds the arm moved.
    pub motion_s: f64,
    /// Views taken.
    pub views: usize,
    /// Error against the simulated truth, degrees and millimetres.
    pub error: (f64, f64),
    /// Why the loop stopped.
    pub stop_reason: String,
}

/// Motion-aware planning against information-only planning on the mock xArm.
#[derive(clap::Args, Clone, Debug)]
pub struct MotionBench {
    /// The mock xArm cell (arm caps, loop settings); its ports are replaced by the mock's.
    #[arg(long, default_value = "config/mock-xarm.toml")]
    pub config: PathBuf,
    /// The simulated cell whose seeded variants give each cell's camera, start and guess.
    #[arg(long, default_value = "config/sim-xarm6.toml")]
    pub cells_from: PathBuf,
    /// Number of cells (seeds FIRST..FIRST+N-1).
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u64).range(1..=200))]
    pub cells: u64,
    /// First cell seed.
    #[arg(long, default_value_t = 0)]
    pub first_seed: u64,
}

impl MotionBench {
    /// Runs the benchmark: per-cell lines go to `log`, the summary into the report.
    pub fn run(&self, log: &mut dyn FnMut(&str)) -> Result<Report> {
        let base = read_config(&self.config)?;
        let sim_base = read_config(&self.cells_from)?;
        base.camera.require_one(&self.config, "bench motion")?;
        sim_base
            .camera
            .require_one(&self.cells_from, "bench motion")?;
        let mut pairs: Vec<(MotionTrial, MotionTrial)> = Vec::new();
        let mut failed: Vec<u64> = Vec::new();
        for seed in self.first_seed..self.first_seed + self.cells {
            let seeded = seeded_sim_cell(&sim_base, &self.cells_from, seed)?;
            let trial = |weigh: bool| -> Result<MotionTrial> {
                let mut cfg = on_mock_arm(&base, &seeded);
                cfg.calibration.weigh_motion_time = weigh;
                run_on_mock(cfg, &self.config, start_of(&seeded))
            };
            let (old, new) = match (trial(false), trial(true)) {
                (Ok(old), Ok(new)) => (old, new),
                (old, new) => {
                    // A failed calibration is a result too: counted, never hidden.
                    let say = |r: &Result<MotionTrial>| match r {
                        Ok(_) => "ok".to_string(),
                        Err(e) => format!("failed: {e}"),
                    };
                    log(&format!(
                        "seed {seed}: information only {}; per second {}",
                        say(&old),
                        say(&new)
                    ));
                    failed.push(seed);
                    continue;
                }
            };
            log(&format!(
                "seed {seed}: information only {:.1} s ({:.1} s moving, {} views, {:.4} deg {:.3} mm); per second {:.1} s ({:.1} s moving, {} views, {:.4} deg {:.3} mm); {} | {}",
                old.total_s, old.motion_s, old.views, old.error.0, old.error.1,
                new.total_s, new.motion_s, new.views, new.error.0, new.error.1,
                old.stop_reason, new.stop_reason
            ));
            pairs.push((old, new));
        }
        let mut report = summary(&pairs);
        if !failed.is_empty() {
            report.line(format!(
                "cells where either calibration failed (left out above): seeds {failed:?}"
            ));
        }
        Ok(report)
    }
}

/// The median table of both planners, and the wall-time ratio per cell.
fn summary(pairs: &[(MotionTrial, MotionTrial)]) -> Report {
    let mut report = Report::default();
    report.line(
        "| planner | wall time (s) | motion (s) | views | rotation (deg) | translation (mm) |",
    );
    report.line("|---|---|---|---|---|---|");
    for (name, pick) in [("information only", 0usize), ("information per second", 1)] {
        let trials: Vec<&MotionTrial> = pairs
            .iter()
            .map(|p| if pick == 0 { &p.0 } else { &p.1 })
            .collect();
        let m = |f: &dyn Fn(&MotionTrial) -> f64| {
            median(&trials.iter().map(|t| f(t)).collect::<Vec<_>>())
        };
        report.line(format!(
            "| {name} | {:.1} | {:.1} | {:.0} | {:.4} | {:.3} |",
            m(&|t| t.total_s),
            m(&|t| t.motion_s),
            m(&|t| t.views as f64),
            m(&|t| t.error.0),
            m(&|t| t.error.1)
        ));
    }
    let ratios: Vec<f64> = pairs.iter().map(|(o, n)| n.total_s / o.total_s).collect();
    report.line(format!(
        "wall time, per second / information only: median {:.2} over {} cells (min {:.2}, max {:.2})",
        median(&ratios),
        ratios.len(),
        ratios.iter().copied().fold(f64::INFINITY, f64::min),
        ratios.iter().copied().fold(0.0, f64::max)
    ));
    report
}

/// The seeded simulated cell's start pose.
fn start_of(seeded: &CellConfig) -> Vec<f64> {
    match &seeded.arm {
        ArmConfig::Sim(SimArmSettings { start, .. }) => start.clone(),
        _ => unreachable!("seeded cells have a simulated arm"),
    }
}

/// The mock xArm cell with the seeded cell's camera, segmenter, guess and seed.
fn on_mock_arm(base: &CellConfig, seeded: &CellConfig) -> CellConfig {
    let mut cfg = base.clone();
    let joints_from = match base.camera.first() {
        CameraConfig::Sim(SimCameraSettings { joints_from, .. }) => joints_from.clone(),
        _ => None,
    };
    cfg.camera = seeded.camera.clone();
    if let CameraConfig::Sim(SimCameraSettings { joints_from: j, .. }) = cfg.camera.first_mut() {
        *j = joints_from;
    }
    cfg.segmenter = seeded.segmenter.clone();
    cfg.calibration.initial_guess = seeded.calibration.initial_guess.clone();
    cfg.calibration.seed = seeded.calibration.seed;
    cfg
}

/// Spawns a real-time mock xArm at `start`, points `cfg` at its ports and calibrates.
fn run_on_mock(
    mut cfg: CellConfig,
    config_path: &std::path::Path,
    start: Vec<f64>,
) -> Result<MotionTrial> {
    use easyhec_drivers::xarm::Model;
    use easyhec_mocks::xarm::{MockXArm, MockXArmConfig};
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(|e| Error::Solve(format!("async runtime: {e}")))?;
    let mut mock_cfg = MockXArmConfig::free_ports(Model::Xarm6);
    mock_cfg.start = Some(start);
    if let ArmConfig::Xarm(t) = &cfg.arm {
        mock_cfg.speed_cap_rad_s = t.speed_cap_rad_s;
    }
    mock_cfg.speedup = 1.0;
    let mock = runtime
        .block_on(MockXArm::spawn(mock_cfg))
        .map_err(|e| Error::Hardware(format!("mock xArm: {e}")))?;
    if let ArmConfig::Xarm(XarmSettings { addr, .. }) = &mut cfg.arm {
        *addr = mock.command_addr().to_string();
    }
    if let CameraConfig::Sim(SimCameraSettings {
        joints_from: Some(JointsFrom::XarmReport { addr, .. }),
        ..
    }) = cfg.camera.first_mut()
    {
        if let Some(a) = mock.real_report_addr() {
            *addr = a.to_string();
        }
    }
    let cell = Cell::build(cfg, config_path)?;
    let truth = cell.units[0]
        .sim
        .camera_from_base
        .ok_or_else(|| Error::Solve("the benchmark needs a simulated camera".into()))?;
    let dir = tempfile::tempdir().map_err(|e| Error::io(std::env::temp_dir(), e))?;
    let outcome = runtime.block_on(calibrate(
        &cell,
        &dir.path().join("run"),
        &RunOptions::default(),
    ))?;
    let r = &outcome.result;
    let est = r.camera_from_base();
    let t = |k: &str| r.timings_s.get(k).copied().unwrap_or(0.0);
    Ok(MotionTrial {
        total_s: t("total"),
        motion_s: t("motion"),
        views: r.views_used.len(),
        error: (
            rotation_error_deg(&est, &truth),
            translation_error_mm(&est, &truth),
        ),
        stop_reason: r.stop_reason.clone(),
    })
}

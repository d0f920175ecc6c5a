//! `easyhec bench rig`: several cameras calibrated in one run against each camera calibrated
//! alone, on seeded simulated cells: each camera's median error with the same number of
//! views, and the wall time of the run against a single-camera calibration.

use std::path::{Path, PathBuf};
use std::time::Instant;

use rand::{Rng, SeedableRng};

use super::coverage::errors_in_sigmas;
use super::{median, paired_median_difference, Report};
use crate::calibrate::VisibilityRule;
use crate::calibrate::{calibrate, RunOptions};
use crate::cell::Cell;
use crate::config::{read_config, CameraConfig, CellConfig, InitialGuess};
use crate::config::{SimArmSettings, SimCameraSettings};
use crate::error::{Error, Result};
use crate::geometry::{camera_centre_error_mm, rotation_error_deg, to_rows, translation_error_mm};

/// Several cameras in one run against each alone (docs/benchmarks.md).
#[derive(clap::Args, Clone, Debug)]
pub struct RigBench {
    /// A cell config with `[[camera]]` tables of simulated fixed cameras.
    #[arg(long, default_value = "config/sim-xarm6-three-cameras.toml")]
    pub config: PathBuf,
    /// Number of cells (seeds FIRST..FIRST+N-1).
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u64).range(1..=1000))]
    pub cells: u64,
    /// First cell seed.
    #[arg(long, default_value_t = 0)]
    pub first_seed: u64,
    /// Views per calibration (no early stop), for the rig and for each camera alone.
    #[arg(long, default_value_t = 5, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=100))]
    pub views: usize,
}

/// One calibration's errors per camera (degrees, mm) and against its reported uncertainty,
/// its wall time, and the time its moves take on an arm at the commanded speed.
struct Trial {
    errors: Vec<(f64, f64)>,
    honesty: Vec<Honesty>,
    wall_s: f64,
    motion_s: f64,
}

/// One camera's true error against what it reported.
struct Honesty {
    /// True error per camera axis in units of the reported 1σ.
    z: [f64; 6],
    /// Whether the true camera centre lies within the reported 95% bound.
    centre_inside: bool,
}

impl Honesty {
    fn axes_within_2_sigma(&self) -> usize {
        self.z.iter().filter(|z| **z <= 2.0).count()
    }
}

impl Trial {
    /// Wall time with the moves taking their commanded time (the simulated arm arrives at
    /// once, a real one does not).
    fn with_motion_s(&self) -> f64 {
        self.wall_s + self.motion_s
    }
}

impl RigBench {
    /// Runs the benchmark: per-cell lines go to `log`, the summary into the report.
    pub fn run(&self, log: &mut dyn FnMut(&str)) -> Result<Report> {
        let base = read_config(&self.config)?;
        base.validate(&self.config)?;
        let names: Vec<String> = base
            .camera
            .cameras()
            .iter()
            .map(|c| c.name.clone())
            .collect();
        if names.len() < 2 {
            return Err(Error::input(
                &self.config,
                "camera",
                "bench rig needs a config with several [[camera]] tables",
            ));
        }
        let mut rig_trials = Vec::new();
        let mut alone_trials: Vec<Vec<Trial>> = Vec::new();
        let mut failures = 0;
        for seed in self.first_seed..self.first_seed + self.cells {
            match self.cell(&base, seed) {
                Ok((rig, alone)) => {
                    let line = names
                        .iter()
                        .enumerate()
                        .map(|(k, n)| {
                            format!(
                                "{n} {:.3} deg / {:.3} mm (alone {:.3} / {:.3})",
                                rig.errors[k].0,
                                rig.errors[k].1,
                                alone[k].errors[0].0,
                                alone[k].errors[0].1
                            )
                        })
                        .collect::<Vec<_>>()
                        .join(", ");
                    let single = alone.iter().map(|t| t.wall_s).sum::<f64>() / alone.len() as f64;
                    let single_motion =
                        alone.iter().map(|t| t.motion_s).sum::<f64>() / alone.len() as f64;
                    log(&format!(
                        "seed {seed}: {line}; wall {:.1} s + motion {:.1} s, one camera {:.1} s + {:.1} s",
                        rig.wall_s, rig.motion_s, single, single_motion
                    ));
                    rig_trials.push(rig);
                    alone_trials.push(alone);
                }
                Err(e) => {
                    failures += 1;
                    log(&format!("seed {seed}: failed: {e}"));
                }
            }
        }
        Ok(self.summary(&names, &rig_trials, &alone_trials, failures))
    }

    /// The rig's run and each camera's own run on the seeded cell `seed`.
    fn cell(&self, base: &CellConfig, seed: u64) -> Result<(Trial, Vec<Trial>)> {
        let cfg = seeded_rig(base, &self.config, seed, self.views)?;
        let rig = trial(&cfg, &self.config)?;
        let alone = (0..cfg.camera.cameras().len())
            .map(|k| {
                let mut one = cfg.for_camera(k);
                one.calibration.initial_guess = cfg.camera.cameras()[k].initial_guess.clone();
                trial(&one, &self.config)
            })
            .collect::<Result<Vec<_>>>()?;
        Ok((rig, alone))
    }

    fn summary(
        &self,
        names: &[String],
        rig: &[Trial],
        alone: &[Vec<Trial>],
        failures: usize,
    ) -> Report {
        let mut report = Report::default();
        report.line(format!(
            "{} cells ({} failed), {} views each, config {}",
            rig.len(),
            failures,
            self.views,
            self.config.display()
        ));
        report.line("| camera | median in the rig (deg / mm) | median alone (deg / mm) | cells the rig is better in (rotation / translation) | rig minus alone, 95% interval (deg; mm) |");
        report.line("|---|---|---|---|---|");
        for (k, n) in names.iter().enumerate() {
            let col = |v: Vec<f64>| median(&v);
            let in_rig = (
                col(rig.iter().map(|t| t.errors[k].0).collect()),
                col(rig.iter().map(|t| t.errors[k].1).collect()),
            );
            let by_itself = (
                col(alone.iter().map(|a| a[k].errors[0].0).collect()),
                col(alone.iter().map(|a| a[k].errors[0].1).collect()),
            );
            let better = |axis: fn(&(f64, f64)) -> f64| {
                rig.iter()
                    .zip(alone)
                    .filter(|(r, a)| axis(&r.errors[k]) < axis(&a[k].errors[0]))
                    .count()
            };
            let difference = |axis: fn(&(f64, f64)) -> f64, digits: usize| {
                let (d, (lo, hi)) = paired_median_difference(
                    &rig.iter().map(|t| axis(&t.errors[k])).collect::<Vec<_>>(),
                    &alone
                        .iter()
                        .map(|a| axis(&a[k].errors[0]))
                        .collect::<Vec<_>>(),
                );
                format!("{d:+.digits$} [{lo:+.digits$}, {hi:+.digits$}]")
            };
            report.line(format!(
                "| {n} | {:.4} / {:.3} | {:.4} / {:.3} | {} / {} of {} | {}; {} |",
                in_rig.0,
                in_rig.1,
                by_itself.0,
                by_itself.1,
                better(|e| e.0),
                better(|e| e.1),
                rig.len(),
                difference(|e| e.0, 4),
                difference(|e| e.1, 3),
            ));
        }
        report.line("");
        self.honesty_table(names, rig, alone, &mut report);
        report.line("");
        let ratio = |f: &dyn Fn(&Trial) -> f64| -> Vec<f64> {
            rig.iter()
                .zip(alone)
                .map(|(r, a)| f(r) / (a.iter().map(f).sum::<f64>() / a.len() as f64))
                .collect()
        };
        let all = |f: &dyn Fn(&Trial) -> f64| -> (f64, f64) {
            (
                median(&rig.iter().map(f).collect::<Vec<_>>()),
                median(&alone.iter().flatten().map(f).collect::<Vec<_>>()),
            )
        };
        let max = |v: &[f64]| v.iter().copied().fold(0.0, f64::max);
        let (compute, with_motion) = (ratio(&|t| t.wall_s), ratio(&|t| t.with_motion_s()));
        let (c_rig, c_one) = all(&|t| t.wall_s);
        let (m_rig, m_one) = all(&|t| t.with_motion_s());
        report.line(format!(
            "wall time, arm arriving at once: rig median {c_rig:.1} s, one camera median {c_one:.1} s; rig / one camera per cell: median {:.2}, max {:.2}",
            median(&compute),
            max(&compute)
        ));
        report.line(format!(
            "wall time with each move at its commanded speed: rig median {m_rig:.1} s, one camera median {m_one:.1} s; rig / one camera per cell: median {:.2}, max {:.2}",
            median(&with_motion),
            max(&with_motion)
        ));
        report
    }

    /// Per camera, how often its reported uncertainty covered the true error, in the rig and
    /// alone (the promise: 95.4% of axes within 2σ, 95% of centres within the bound).
    fn honesty_table(
        &self,
        names: &[String],
        rig: &[Trial],
        alone: &[Vec<Trial>],
        report: &mut Report,
    ) {
        report.line(
            "| camera | axes within 2σ, rig / alone | centres within the 95% bound, rig / alone |",
        );
        report.line("|---|---|---|");
        let share = |of: Vec<&Honesty>| {
            let n = of.len().max(1) as f64;
            (
                100.0 * of.iter().map(|h| h.axes_within_2_sigma()).sum::<usize>() as f64
                    / (6.0 * n),
                100.0 * of.iter().filter(|h| h.centre_inside).count() as f64 / n,
            )
        };
        for (k, n) in names.iter().enumerate() {
            let r = share(rig.iter().map(|t| &t.honesty[k]).collect());
            let a = share(alone.iter().map(|a| &a[k].honesty[0]).collect());
            report.line(format!(
                "| {n} | {:.1}% / {:.1}% | {:.1}% / {:.1}% |",
                r.0, a.0, r.1, a.1
            ));
        }
    }
}

/// Calibrates `cfg` and measures each camera's error against the simulator's truth.
fn trial(cfg: &CellConfig, path: &Path) -> Result<Trial> {
    let started = Instant::now();
    let cell = Cell::build(cfg.clone(), path)?;
    let dir = tempfile::tempdir().map_err(|e| Error::io(std::env::temp_dir(), e))?;
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| Error::Solve(format!("async runtime: {e}")))?;
    let outcome = runtime.block_on(calibrate(
        &cell,
        &dir.path().join("run"),
        &RunOptions::default(),
    ))?;
    let wall_s = started.elapsed().as_secs_f64();
    let mut errors = Vec::new();
    let mut honesty = Vec::new();
    for (unit, cam) in cell.cameras().iter().zip(&outcome.cameras) {
        let truth = unit
            .sim
            .camera_from_base
            .ok_or_else(|| Error::Solve("bench rig needs simulated cameras".into()))?;
        let estimate = cam.result.camera_from_base();
        errors.push((
            rotation_error_deg(&estimate, &truth),
            translation_error_mm(&estimate, &truth),
        ));
        let u = &cam.report.uncertainty;
        honesty.push(Honesty {
            z: errors_in_sigmas(&estimate, &truth, u),
            centre_inside: camera_centre_error_mm(&estimate, &truth) <= u.camera_centre_95_mm,
        });
    }
    Ok(Trial {
        errors,
        honesty,
        wall_s,
        motion_s: commanded_motion_s(&cell),
    })
}

/// Seconds the simulated arm's accepted moves take at their commanded speed: the farthest
/// joint's travel over the speed, as `SafeArm` commands a move and the planner's time model
/// counts it.
fn commanded_motion_s(cell: &Cell) -> f64 {
    let Some(arm) = cell.sim_arm() else {
        return 0.0;
    };
    arm.commands()
        .iter()
        .filter(|c| c.accepted && c.speed_rad_s > 0.0)
        .map(|c| crate::calibrate::motion_cost::travel_s(&c.from, &c.target, c.speed_rad_s))
        .sum()
}

/// A seeded variant of a rig config: each fixed camera's true pose moved by up to 10 cm and a
/// few degrees, each camera on a link moved on its bracket by up to 1 cm and about 5° (as
/// `bench loop` seeds a wrist camera), every guess 2–6° / 2–8 cm off the truth, and a start
/// pose that every camera sees.
fn seeded_rig(base: &CellConfig, path: &Path, seed: u64, views: usize) -> Result<CellConfig> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed + 7000);
    let mut cfg = base.clone();
    cfg.calibration.seed = seed;
    cfg.calibration.max_views = views;
    cfg.calibration.min_views = views;
    for (k, cam) in cfg.camera.cameras_mut().iter_mut().enumerate() {
        let fixed = cam.config.mount().is_fixed();
        let CameraConfig::Sim(SimCameraSettings { truth, scene, .. }) = &mut cam.config else {
            return Err(Error::input(
                path,
                format!("camera[{k}].kind"),
                "bench rig needs simulated cameras",
            ));
        };
        let (eye_m, roll_deg) = match fixed {
            true => (0.1, 3.0),
            false => (0.01, 5.0),
        };
        for v in &mut truth.eye {
            *v += rng.random_range(-eye_m..eye_m);
        }
        for v in &mut truth.look_at {
            *v += rng.random_range(-0.05..0.05);
        }
        truth.roll_deg += rng.random_range(-roll_deg..roll_deg);
        scene.seed = seed * 16 + k as u64;
        let guess = crate::synth::perturb(
            &mut rng,
            &truth.camera_from_base(),
            (2.0, 6.0),
            (0.02, 0.08),
        );
        cam.initial_guess = Some(InitialGuess::Matrix {
            camera_from_base: to_rows(&guess),
        });
    }
    if let crate::config::SegmenterConfig::SimTruth { seed: s, .. } = &mut cfg.segmenter {
        *s = seed;
    }
    visible_start(cfg, path, seed, &mut rng)
}

/// What a start pose must show one camera: its robot, lens and rule, and the poses (truth,
/// and for a camera on a link its guess too) under which it must show it.
struct StartView {
    seen: std::sync::Arc<crate::robot::RobotModel>,
    camera: crate::camera::Intrinsics,
    low: crate::camera::Intrinsics,
    rule: VisibilityRule,
    poses: Vec<nalgebra::Isometry3<f64>>,
}

impl StartView {
    fn shows(&self, q: &[f64]) -> bool {
        let posed = crate::render::PosedRobot::new(&self.seen, q).decimated(0.01);
        self.poses.iter().all(|p| {
            self.rule
                .shows(&posed, &self.camera, &self.low, p)
                .is_some()
        })
    }
}

/// `cfg` with a safe start pose that keeps 97% of the robot in every fixed camera's image and
/// shows each camera on a link its share of robot, under its truth and its guess (an operator
/// starts where the wrist camera sees the robot).
fn visible_start(
    mut cfg: CellConfig,
    path: &Path,
    seed: u64,
    rng: &mut rand_chacha::ChaCha8Rng,
) -> Result<CellConfig> {
    let cell = Cell::build(cfg.clone(), path)?;
    let views: Vec<StartView> = cell
        .cameras()
        .iter()
        .filter_map(|u| {
            let camera = u.device.intrinsics().undistorted();
            let rule = match VisibilityRule::of(&cell, u.config.mount()) {
                VisibilityRule::InImage(_) => VisibilityRule::InImage(0.97),
                coverage => coverage,
            };
            let mut poses = vec![u.sim.camera_from_base?];
            if !u.config.mount().is_fixed() {
                poses.extend(u.initial_guess.and_then(|g| g.camera_from_base().ok()));
            }
            Some(StartView {
                seen: u.seen.clone(),
                low: camera.downsampled(cfg.calibration.score_downsample),
                camera,
                rule,
                poses,
            })
        })
        .collect();
    for _ in 0..10_000 {
        let q = super::uniform_joints(cell.checker.limits(), rng);
        if cell.checker.check_pose(&q).is_err() || !views.iter().all(|v| v.shows(&q)) {
            continue;
        }
        let crate::config::ArmConfig::Sim(SimArmSettings { start, seed: s, .. }) = &mut cfg.arm
        else {
            return Err(Error::Solve("bench cells need [arm] kind = \"sim\"".into()));
        };
        *start = q;
        *s = seed;
        return Ok(cfg);
    }
    Err(Error::Solve(format!(
        "seed {seed}: no safe start pose shows the robot to every camera"
    )))
}

//! Benchmarks behind `easyhec bench`: accuracy over seeded synthetic scenes and solve speed.
//! Figures go in the README; nothing here asserts timings.

use std::time::Instant;

use rayon::prelude::*;

use crate::error::Result;
use crate::geometry::{rotation_error_deg, translation_error_mm};
use crate::render::{CpuRenderer, PosedRobot};
use crate::robot::RobotModel;
use crate::solve::{solve, Optimizer, SolveOptions, View};
use crate::synth::{generate, Scene, SynthOptions};

/// One solve's outcome in the accuracy benchmark.
#[derive(Clone, Debug)]
pub struct Trial {
    /// Scene seed.
    pub seed: u64,
    /// Views used (first k).
    pub views: usize,
    /// Rotation error, degrees.
    pub rotation_deg: f64,
    /// Translation error of `camera_from_base`, mm.
    pub translation_mm: f64,
    /// Reported 1-sigma rotation (norm over axes), degrees.
    pub sigma_rotation_deg: f64,
    /// Reported 1-sigma translation (norm over axes), mm.
    pub sigma_translation_mm: f64,
    /// Wall time, seconds.
    pub seconds: f64,
}

/// Builds solver views from a synthetic scene.
pub fn scene_views(robot: &RobotModel, scene: &Scene) -> Vec<View> {
    scene
        .masks
        .par_iter()
        .zip(&scene.recorded_joints)
        .map(|(m, q)| View {
            robot: PosedRobot::new(robot, q),
            observed: scene.camera.undistort_mask(m),
        })
        .collect()
}

/// Median of a slice (NaN-free).
pub fn median(values: &[f64]) -> f64 {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        return f64::NAN;
    }
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Runs the accuracy benchmark: for each seed, solves from the first k views for each k in
/// `view_counts` with `optimizer`, starting from the scene's perturbed initial guess.
pub fn accuracy(
    robot: &RobotModel,
    seeds: &[u64],
    view_counts: &[usize],
    optimizer: Optimizer,
    synth: &SynthOptions,
    mut progress: impl FnMut(&Trial),
) -> Result<Vec<Trial>> {
    let max_views = view_counts.iter().copied().max().unwrap_or(1);
    let mut trials = Vec::new();
    for &seed in seeds {
        let scene = generate(
            robot,
            &SynthOptions {
                seed,
                views: max_views,
                ..synth.clone()
            },
        )?;
        let views = scene_views(robot, &scene);
        let init = scene
            .initial_guess
            .expect("benchmark scenes carry an initial guess");
        for &k in view_counts {
            let opts = SolveOptions {
                optimizer,
                ..SolveOptions::default()
            };
            let t = Instant::now();
            let rep = solve(&CpuRenderer, &scene.camera, &views[..k], &init, &opts)?;
            let u = rep.uncertainty;
            let trial = Trial {
                seed,
                views: k,
                rotation_deg: rotation_error_deg(&rep.camera_from_base, &scene.camera_from_base),
                translation_mm: translation_error_mm(
                    &rep.camera_from_base,
                    &scene.camera_from_base,
                ),
                sigma_rotation_deg: u.rotation_deg.iter().map(|x| x * x).sum::<f64>().sqrt(),
                sigma_translation_mm: u.translation_mm.iter().map(|x| x * x).sum::<f64>().sqrt(),
                seconds: t.elapsed().as_secs_f64(),
            };
            progress(&trial);
            trials.push(trial);
        }
    }
    Ok(trials)
}

/// Markdown table row per view count: median errors, median reported sigma, mean time.
pub fn summarize(label: &str, trials: &[Trial], view_counts: &[usize]) -> String {
    let mut s = format!(
        "| {label} | views | median rotation error (deg) | median translation error (mm) | median reported 1σ rot (deg) / trans (mm) | mean solve time (s) |\n|---|---|---|---|---|---|\n"
    );
    for &k in view_counts {
        let t: Vec<&Trial> = trials.iter().filter(|t| t.views == k).collect();
        let f = |g: fn(&Trial) -> f64| median(&t.iter().map(|x| g(x)).collect::<Vec<_>>());
        let mean_time = t.iter().map(|x| x.seconds).sum::<f64>() / t.len().max(1) as f64;
        s.push_str(&format!(
            "| {label} | {k} | {:.4} | {:.3} | {:.4} / {:.3} | {:.2} |\n",
            f(|x| x.rotation_deg),
            f(|x| x.translation_mm),
            f(|x| x.sigma_rotation_deg),
            f(|x| x.sigma_translation_mm),
            mean_time
        ));
    }
    s
}

/// Peak resident set size of this process, bytes (Linux `VmHWM`).
pub fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// One simulated calibration in the closed-loop benchmark.
#[derive(Clone, Debug)]
pub struct LoopTrial {
    /// Cell seed.
    pub seed: u64,
    /// `explore` or `random`.
    pub selection: String,
    /// Error after each view count `(views, rotation deg, translation mm)`.
    pub errors: Vec<(usize, f64, f64)>,
    /// Seconds per planning round (joint sampling, checks, scoring).
    pub explore_round_s: Vec<f64>,
    /// Compute seconds of the whole calibration (total minus simulated motion).
    pub compute_s: f64,
    /// Why the loop stopped (a trial short of its views says why here).
    pub stop_reason: String,
}

/// A seeded variant of a simulated cell config: true camera anywhere on a band of the
/// hemisphere around the robot, a random safe visible start pose, a guess 2–6° / 2–8 cm off.
pub fn seeded_sim_cell(
    base: &crate::cell::CellConfig,
    config_path: &std::path::Path,
    seed: u64,
) -> Result<crate::cell::CellConfig> {
    use crate::calibrate::InitialGuess;
    use crate::cell::{ArmConfig, CameraConfig, Cell, LookAt};
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed + 9000);
    let mut cfg = base.clone();
    let distance = rng.random_range(1.1..1.6);
    let azimuth: f64 = rng.random_range(0.0..std::f64::consts::TAU);
    let elevation: f64 = rng.random_range(15f64..45.0).to_radians();
    let centre = [0.1 * azimuth.cos(), 0.1 * azimuth.sin(), 0.3];
    let truth = LookAt {
        eye: [
            centre[0] + distance * elevation.cos() * azimuth.cos(),
            centre[1] + distance * elevation.cos() * azimuth.sin(),
            centre[2] + distance * elevation.sin(),
        ],
        look_at: [
            centre[0] + rng.random_range(-0.05..0.05),
            centre[1] + rng.random_range(-0.05..0.05),
            centre[2] + rng.random_range(-0.05..0.05),
        ],
        roll_deg: rng.random_range(-5.0..5.0),
    };
    let pose = truth.camera_from_base();
    let CameraConfig::Sim {
        truth: t, scene, ..
    } = &mut cfg.camera
    else {
        return Err(crate::Error::input(
            config_path,
            "camera.kind",
            "the loop benchmark needs a simulated camera (kind = \"sim\")",
        ));
    };
    *t = truth;
    scene.seed = seed;
    cfg.calibration.seed = seed;
    cfg.calibration.initial_guess = Some(InitialGuess::Matrix {
        camera_from_base: crate::geometry::to_rows(&crate::synth::perturb(
            &mut rng,
            &pose,
            (2.0, 6.0),
            (0.02, 0.08),
        )),
    });
    if let crate::segment::SegmenterConfig::SimTruth { seed: s, .. } = &mut cfg.segmenter {
        *s = seed;
    }
    // A start pose that is safe and shows the robot to the true camera.
    let cell = Cell::build(cfg.clone(), config_path)?;
    let camera = cfg
        .camera
        .camera()
        .ok_or_else(|| crate::Error::input(config_path, "camera.kind", "needs a simulated camera"))?
        .undistorted();
    for _ in 0..10_000 {
        let q: Vec<f64> = cell
            .checker
            .limits()
            .iter()
            .map(|&(lo, hi)| rng.random_range(lo..=hi))
            .collect();
        if cell.checker.check_pose(&q).is_err() {
            continue;
        }
        let posed = PosedRobot::new(&cell.robot, &q).decimated(0.01);
        if crate::calibrate::in_image_fraction(&posed, &camera, &pose) < 0.97 {
            continue;
        }
        let ArmConfig::Sim { start, seed: s, .. } = &mut cfg.arm else {
            return Err(crate::Error::Solve(
                "bench cells need [arm] kind = \"sim\"".into(),
            ));
        };
        *start = q;
        *s = seed;
        return Ok(cfg);
    }
    Err(crate::Error::Solve(format!(
        "seed {seed}: no safe start pose shows the robot"
    )))
}

/// Runs the simulated calibration of `cfg` with `selection`, `views` views, no early stop.
pub fn run_loop_trial(
    cfg: &crate::cell::CellConfig,
    config_path: &std::path::Path,
    seed: u64,
    selection: crate::calibrate::SelectionSetting,
    views: usize,
) -> Result<LoopTrial> {
    use crate::calibrate::{calibrate, RunOptions};
    let mut cfg = cfg.clone();
    cfg.calibration.selection = selection;
    cfg.calibration.max_views = views;
    cfg.calibration.min_views = views;
    let cell = crate::cell::Cell::build(cfg, config_path)?;
    let truth = cell
        .sim
        .camera_from_base
        .ok_or_else(|| crate::Error::Solve("benchmark needs a simulated camera".into()))?;
    let dir = tempfile::tempdir().map_err(|e| crate::Error::io(std::env::temp_dir(), e))?;
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| crate::Error::Solve(format!("async runtime: {e}")))?;
    let outcome = runtime.block_on(calibrate(
        &cell,
        &dir.path().join("run"),
        &RunOptions::default(),
    ))?;
    let errors = outcome
        .rounds
        .iter()
        .map(|r| {
            let est = crate::geometry::from_rows(&r.camera_from_base).expect("valid rows");
            (
                r.views,
                rotation_error_deg(&est, &truth),
                translation_error_mm(&est, &truth),
            )
        })
        .collect();
    let t = &outcome.result.timings_s;
    let get = |k: &str| t.get(k).copied().unwrap_or(0.0);
    let rounds_planned = outcome
        .rounds
        .iter()
        .filter(|r| r.best_variance.is_some())
        .count();
    Ok(LoopTrial {
        seed,
        selection: format!("{selection:?}").to_lowercase(),
        errors,
        explore_round_s: vec![get("explore") / rounds_planned.max(1) as f64],
        compute_s: get("total") - get("motion"),
        stop_reason: outcome.result.stop_reason.clone(),
    })
}

/// Median of `(views → rotation, translation)` over trials.
pub fn loop_medians(trials: &[LoopTrial], views: usize) -> Option<(f64, f64)> {
    let mut r: Vec<f64> = Vec::new();
    let mut t: Vec<f64> = Vec::new();
    for trial in trials {
        if let Some(&(_, a, b)) = trial.errors.iter().find(|e| e.0 == views) {
            r.push(a);
            t.push(b);
        }
    }
    if r.is_empty() {
        return None;
    }
    Some((median(&r), median(&t)))
}

/// Timings of [`explore_round`].
#[derive(Clone, Debug)]
pub struct ExploreTiming {
    /// Posing and decimating the joint samples, seconds per round.
    pub posing_s: Vec<f64>,
    /// Scoring every sample against every candidate, seconds per round.
    pub scoring_s: Vec<f64>,
    /// Best score of the last round (a check that the rounds did real work).
    pub best_score: f64,
}

/// Times exploration's scoring on `renderer`: a 2-view solve of a seeded scene gives the
/// posterior, `candidates` camera hypotheses are drawn from it (widened as the loop does),
/// and `samples` random joint vectors are posed, decimated and scored at 1/4 resolution.
pub fn explore_round(
    renderer: &dyn crate::render::SilhouetteRenderer,
    robot: &RobotModel,
    samples: usize,
    candidates: usize,
    width: u32,
    height: u32,
    rounds: usize,
) -> Result<ExploreTiming> {
    use rand::{Rng, SeedableRng};
    let scene = generate(
        robot,
        &SynthOptions {
            seed: 1,
            views: 2,
            width,
            height,
            focal_px: 600.0 * f64::from(width) / 640.0,
            ..SynthOptions::default()
        },
    )?;
    let views = scene_views(robot, &scene);
    let guess = scene
        .initial_guess
        .ok_or_else(|| crate::Error::Solve("benchmark scene without a guess".into()))?;
    let mut report = solve(
        &CpuRenderer,
        &scene.camera,
        &views,
        &guess,
        &SolveOptions::default(),
    )?;
    report.covariance *= 400.0;
    let cands = crate::explore::camera_candidates(
        &report,
        &crate::explore::ExploreOptions {
            candidates,
            ..Default::default()
        },
    );
    let low = scene.camera.undistorted().downsampled(4);
    let cell_m = 4.0 / scene.camera.fx;
    let mut timing = ExploreTiming {
        posing_s: Vec::new(),
        scoring_s: Vec::new(),
        best_score: 0.0,
    };
    for round in 0..rounds.max(1) {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(round as u64);
        let qs: Vec<Vec<f64>> = (0..samples)
            .map(|_| {
                robot
                    .joint_limits()
                    .iter()
                    .map(|&(lo, hi)| rng.random_range(lo.max(-3.0)..=hi.min(3.0)))
                    .collect()
            })
            .collect();
        let t = Instant::now();
        let coarse = crate::render::CoarseRobot::new(robot, cell_m);
        let posed: Vec<PosedRobot> = qs.par_iter().map(|q| coarse.pose(robot, q)).collect();
        timing.posing_s.push(t.elapsed().as_secs_f64());
        let pool: Vec<&PosedRobot> = posed.iter().collect();
        let t = Instant::now();
        let scores = renderer.disagreement_many(&low, &pool, &cands);
        timing.scoring_s.push(t.elapsed().as_secs_f64());
        timing.best_score = scores.iter().copied().fold(0.0, f64::max);
    }
    Ok(timing)
}

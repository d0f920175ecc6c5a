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
    base: &crate::config::CellConfig,
    config_path: &std::path::Path,
    seed: u64,
) -> Result<crate::config::CellConfig> {
    use crate::cell::Cell;
    use crate::config::InitialGuess;
    use crate::config::{ArmConfig, CameraConfig, LookAt};
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
    if let crate::config::SegmenterConfig::SimTruth { seed: s, .. } = &mut cfg.segmenter {
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
        let q = uniform_joints(cell.checker.limits(), &mut rng);
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

/// A joint vector drawn uniformly within `limits` (how the planner and the random selection
/// draw their samples).
fn uniform_joints(limits: &[(f64, f64)], rng: &mut impl rand::Rng) -> Vec<f64> {
    limits
        .iter()
        .map(|&(lo, hi)| rng.random_range(lo..=hi))
        .collect()
}

/// Runs the simulated calibration of `cfg` with `selection`, `views` views, no early stop.
pub fn run_loop_trial(
    cfg: &crate::config::CellConfig,
    config_path: &std::path::Path,
    seed: u64,
    selection: crate::config::SelectionSetting,
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
    renderer: &dyn crate::backend::Backend,
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

/// One set of views of a [`ViewSetCell`]: what the selection score's model predicts for its
/// 3-view error and what repeated noisy solves measure.
#[derive(Clone, Debug)]
pub struct ViewSet {
    /// `explore` (the loop's planner) or `random N`.
    pub name: String,
    /// Joints of each view, view 0 (the start pose) first.
    pub joints: Vec<Vec<f64>>,
    /// Predicted RMS rotation error (root of the trace of the rotation block of
    /// [`crate::explore::estimate_covariance`]), degrees.
    pub predicted_deg: f64,
    /// Predicted RMS error of `camera_from_base`'s translation, millimetres.
    pub predicted_mm: f64,
    /// `(rotation deg, translation mm)` of each noisy solve of this set.
    pub errors: Vec<(f64, f64)>,
}

impl ViewSet {
    /// RMS of the measured errors over `trials` (`0` rotation, `1` translation).
    pub fn rms(&self, which: usize, trials: std::ops::Range<usize>) -> f64 {
        let e = &self.errors[trials];
        let sq: f64 = e
            .iter()
            .map(|v| if which == 0 { v.0 * v.0 } else { v.1 * v.1 })
            .sum();
        (sq / e.len().max(1) as f64).sqrt()
    }

    /// Predicted RMS error (`0` rotation, `1` translation).
    pub fn predicted(&self, which: usize) -> f64 {
        if which == 0 {
            self.predicted_deg
        } else {
            self.predicted_mm
        }
    }
}

/// The view sets of one seeded cell: the loop's explored pair first, then random pairs.
#[derive(Clone, Debug)]
pub struct ViewSetCell {
    /// Cell seed.
    pub seed: u64,
    /// Explore's set first.
    pub sets: Vec<ViewSet>,
}

/// Why a 3-view ratio is what it is: on the seeded cell of `cfg`, the start pose plus the
/// pair the loop's planner picks ([`crate::calibrate::rank_poses`], its hill climb and path
/// check, from real noisy solves of the views before), and `random_pairs` random pairs of
/// safe poses that show the robot (each move path-checked, as the random selection's are).
/// Every set is solved `trials` times from the guess, each time with fresh encoder noise and
/// mask noise as the cell config sets them, so each set's expected error is measured, not
/// one draw of it; the score's model predicts each set's error at the truth. Masks are
/// rendered on the undistorted camera (the cell's lens model plays no part here).
pub fn view_set_cell(
    cfg: &crate::config::CellConfig,
    config_path: &std::path::Path,
    seed: u64,
    random_pairs: usize,
    trials: usize,
) -> Result<ViewSetCell> {
    use crate::calibrate::{choose_reachable, in_image_fraction, rank_poses};
    use crate::cell::Cell;
    use crate::config::{ArmConfig, SelectionSetting};
    use crate::explore::{estimate_covariance, view_terms, ViewTerms};
    use crate::render::SilhouetteRenderer;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    let bad = |why: &str| crate::Error::Solve(format!("seed {seed}: {why}"));
    let mut cfg = cfg.clone();
    cfg.calibration.selection = SelectionSetting::Explore;
    let ArmConfig::Sim {
        start,
        encoder_noise_rad,
        ..
    } = &cfg.arm
    else {
        return Err(bad("view sets need [arm] kind = \"sim\""));
    };
    let (q0, encoder) = (start.clone(), *encoder_noise_rad);
    let mask_noise = match &cfg.segmenter {
        crate::config::SegmenterConfig::SimTruth { noise, .. } => noise.clone(),
        _ => return Err(bad("view sets need [segmenter] kind = \"sim-truth\"")),
    };
    let guess = cfg
        .calibration
        .initial_guess
        .as_ref()
        .ok_or_else(|| bad("no initial guess"))?
        .camera_from_base()
        .map_err(|e| bad(&e))?;
    let cell = Cell::build(cfg, config_path)?;
    let settings = &cell.config.calibration;
    let truth = cell
        .sim
        .camera_from_base
        .ok_or_else(|| bad("view sets need a simulated camera"))?;
    let camera = cell
        .config
        .camera
        .camera()
        .ok_or_else(|| bad("view sets need a simulated camera"))?
        .undistorted();
    let robot = &cell.robot;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed.wrapping_mul(7717) + 3);
    let encoder_noise = Normal::new(0.0, encoder.max(0.0)).map_err(|e| bad(&e.to_string()))?;
    // One noisy capture of each of `qs`: the true mask with segmentation noise, the joints
    // as the encoders report them.
    let capture = |qs: &[Vec<f64>], rng: &mut rand_chacha::ChaCha8Rng| -> Vec<View> {
        qs.iter()
            .map(|q| {
                let exact = CpuRenderer
                    .render(&PosedRobot::new(robot, q), &camera, &truth, None)
                    .mask;
                let observed = match &mask_noise {
                    Some(n) => crate::synth::apply_mask_noise(rng, &exact, n),
                    None => exact,
                };
                let reported: Vec<f64> = q.iter().map(|v| v + encoder_noise.sample(rng)).collect();
                View {
                    robot: PosedRobot::new(robot, &reported),
                    observed,
                }
            })
            .collect()
    };
    let opts = SolveOptions::default();
    // The explored pair, planned as the loop plans it.
    let mut taken = vec![q0.clone()];
    let mut report = solve(
        &CpuRenderer,
        &camera,
        &capture(&taken, &mut rng),
        &guess,
        &opts,
    )?;
    let noise_px2 = report.outline_noise_px2;
    for round in 0..2 {
        let (ranked, _) = rank_poses(
            &CpuRenderer,
            &cell,
            &camera,
            &report,
            &taken,
            settings,
            round,
        );
        let from = taken.last().expect("view 0").clone();
        let (next, _) = choose_reachable(
            &cell,
            &ranked,
            &from,
            settings.speed_rad_s,
            |_| false,
            &mut Vec::new(),
        )
        .ok_or_else(|| bad("the planner found no reachable pose"))?;
        taken.push(next.joints);
        let views = capture(&taken, &mut rng);
        report = solve(
            &CpuRenderer,
            &camera,
            &views,
            &report.camera_from_base,
            &opts,
        )?;
    }
    let mut sets = vec![("explore".to_string(), taken)];
    // Random pairs, drawn as the random selection draws its poses.
    let visible = |q: &[f64]| {
        cell.checker.check_pose(q).is_ok()
            && in_image_fraction(&PosedRobot::new(robot, q).decimated(0.01), &camera, &truth)
                >= cell.checker.min_in_image
    };
    let reachable =
        |a: &[f64], b: &[f64]| cell.checker.check_move(a, b, settings.speed_rad_s).is_ok();
    let mut draws = 0usize;
    while sets.len() < random_pairs + 1 {
        let mut pair: Vec<Vec<f64>> = Vec::new();
        while pair.len() < 2 {
            draws += 1;
            if draws > 200_000 {
                return Err(bad("no random pair of safe, visible, reachable poses"));
            }
            let q = uniform_joints(cell.checker.limits(), &mut rng);
            let from = pair.last().unwrap_or(&q0);
            if visible(&q) && reachable(from, &q) {
                pair.push(q);
            }
        }
        let mut joints = vec![q0.clone()];
        joints.extend(pair);
        sets.push((format!("random {}", sets.len()), joints));
    }
    // The score's model of each set, at the truth, at the planner's scoring resolution.
    let low = camera.downsampled(settings.score_downsample.max(1));
    let cell_m = f64::from(settings.score_downsample.max(1)) / camera.fx.max(camera.fy);
    let terms = |q: &[f64]| {
        view_terms(
            &low,
            camera.fx,
            &PosedRobot::new(robot, q).decimated(cell_m),
            &robot.joint_motions(q),
            &truth,
            noise_px2,
            settings.joint_noise_rad,
        )
    };
    let mut out = Vec::new();
    for (name, joints) in sets {
        let total = joints
            .iter()
            .map(|q| terms(q))
            .fold(ViewTerms::zeros(), |a, b| a + b);
        let cov =
            estimate_covariance(&total).ok_or_else(|| bad("a set leaves the pose unpinned"))?;
        // RMS over the camera axes of the 1-sigma errors the covariance reports.
        let u = crate::solve::uncertainty_of(&cov, &truth);
        let norm = |v: [f64; 3]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
        let (predicted_deg, predicted_mm) = (norm(u.rotation_deg), norm(u.translation_mm));
        let mut errors = Vec::with_capacity(trials);
        for _ in 0..trials {
            let rep = solve(
                &CpuRenderer,
                &camera,
                &capture(&joints, &mut rng),
                &guess,
                &opts,
            )?;
            errors.push((
                rotation_error_deg(&rep.camera_from_base, &truth),
                translation_error_mm(&rep.camera_from_base, &truth),
            ));
        }
        out.push(ViewSet {
            name,
            joints,
            predicted_deg,
            predicted_mm,
            errors,
        });
    }
    Ok(ViewSetCell { seed, sets: out })
}

/// Figures over [`ViewSetCell`]s, each per error (`[rotation, translation]`); ratios are
/// geometric means over cells of explore's figure over the median of the cell's random pairs.
#[derive(Clone, Debug)]
pub struct ViewSetSummary {
    /// Explore's predicted RMS error over the random pairs' median prediction.
    pub predicted_ratio: [f64; 2],
    /// Explore's measured RMS error over the random pairs' median measured RMS error.
    pub measured_ratio: [f64; 2],
    /// The best random pair's measured RMS error over the median (picked on the same trials
    /// it is scored on, so biased low: an optimistic bound for choosing among those pairs).
    pub best_random_ratio: [f64; 2],
    /// Spread (standard deviation of the log) of the random pairs' measured RMS error within a
    /// cell, mean over cells.
    pub random_log_sd: [f64; 2],
    /// The part of that spread the finite trials explain (from the two halves of the trials).
    pub trial_log_sd: [f64; 2],
    /// Within-cell correlation of the predicted and measured log error over all sets, and the
    /// same with the trials' noise taken out of the measured spread (`None` when the trials'
    /// noise explains all of it).
    pub correlation: [(f64, Option<f64>); 2],
}

/// Summarises [`view_set_cell`] results (cells with fewer than 3 random pairs are skipped).
pub fn view_set_summary(cells: &[ViewSetCell]) -> Option<ViewSetSummary> {
    use crate::solve::mean;
    let cells: Vec<&ViewSetCell> = cells.iter().filter(|c| c.sets.len() >= 4).collect();
    if cells.is_empty() {
        return None;
    }
    let gm = |v: &[f64]| (v.iter().map(|x| x.ln()).sum::<f64>() / v.len() as f64).exp();
    let sd = |v: &[f64]| {
        let m = mean(v);
        mean(&v.iter().map(|x| (x - m) * (x - m)).collect::<Vec<_>>()).sqrt()
    };
    let mut s = ViewSetSummary {
        predicted_ratio: [0.0; 2],
        measured_ratio: [0.0; 2],
        best_random_ratio: [0.0; 2],
        random_log_sd: [0.0; 2],
        trial_log_sd: [0.0; 2],
        correlation: [(0.0, None); 2],
    };
    for which in 0..2 {
        let (mut pred, mut meas, mut best, mut spread) = (vec![], vec![], vec![], vec![]);
        let (mut halves, mut pairs) = (Vec::new(), Vec::new());
        for c in &cells {
            let n = c.sets[0].errors.len();
            let full = |v: &ViewSet| v.rms(which, 0..n);
            let random = &c.sets[1..];
            let rp: Vec<f64> = random.iter().map(|v| v.predicted(which)).collect();
            let rm: Vec<f64> = random.iter().map(full).collect();
            pred.push(c.sets[0].predicted(which) / median(&rp));
            meas.push(full(&c.sets[0]) / median(&rm));
            best.push(rm.iter().copied().fold(f64::INFINITY, f64::min) / median(&rm));
            spread.push(sd(&rm.iter().map(|x| x.ln()).collect::<Vec<_>>()));
            let lp: Vec<f64> = c.sets.iter().map(|v| v.predicted(which).ln()).collect();
            let lm: Vec<f64> = c.sets.iter().map(|v| full(v).ln()).collect();
            let (mp, mm) = (mean(&lp), mean(&lm));
            pairs.extend(lp.iter().zip(&lm).map(|(p, m)| (p - mp, m - mm)));
            if n >= 2 {
                halves.extend(
                    c.sets
                        .iter()
                        .map(|v| (v.rms(which, 0..n / 2) / v.rms(which, n / 2..n)).ln()),
                );
            }
        }
        let sxy: f64 = pairs.iter().map(|p| p.0 * p.1).sum();
        let sxx: f64 = pairs.iter().map(|p| p.0 * p.0).sum();
        let syy: f64 = pairs.iter().map(|p| p.1 * p.1).sum();
        let r = sxy / (sxx * syy).sqrt();
        // log RMS over all trials ~ the mean of the halves' logs: a quarter of the variance of
        // their difference.
        let trial = if halves.is_empty() {
            0.0
        } else {
            (halves.iter().map(|h| h * h).sum::<f64>() / halves.len() as f64 / 4.0).sqrt()
        };
        let measured_var = syy / pairs.len() as f64;
        let true_var = measured_var - trial * trial;
        s.predicted_ratio[which] = gm(&pred);
        s.measured_ratio[which] = gm(&meas);
        s.best_random_ratio[which] = gm(&best);
        s.random_log_sd[which] = mean(&spread);
        s.trial_log_sd[which] = trial;
        s.correlation[which] = (
            r,
            (true_var > 0.0).then(|| r * (measured_var / true_var).sqrt()),
        );
    }
    Some(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn set(name: &str, predicted: f64, errors: &[f64]) -> ViewSet {
        ViewSet {
            name: name.into(),
            joints: Vec::new(),
            predicted_deg: predicted,
            predicted_mm: 10.0 * predicted,
            errors: errors.iter().map(|&e| (e, 10.0 * e)).collect(),
        }
    }

    #[test]
    fn view_set_summary_reads_ratios_spread_and_correlation() {
        // Explore's errors are half the middle random pair's; every set's errors follow its
        // prediction exactly, and its two halves of trials agree (no trial noise).
        let cell = |seed| ViewSetCell {
            seed,
            sets: vec![
                set("explore", 0.5, &[0.5, 0.5, 0.5, 0.5]),
                set("random 1", 0.8, &[0.8, 0.8, 0.8, 0.8]),
                set("random 2", 1.0, &[1.0, 1.0, 1.0, 1.0]),
                set("random 3", 1.25, &[1.25, 1.25, 1.25, 1.25]),
            ],
        };
        let s = view_set_summary(&[cell(0), cell(1)]).expect("two cells");
        for which in 0..2 {
            assert!((s.predicted_ratio[which] - 0.5).abs() < 1e-12);
            assert!((s.measured_ratio[which] - 0.5).abs() < 1e-12);
            assert!((s.best_random_ratio[which] - 0.8).abs() < 1e-12);
            let spread = ((0.8f64.ln().powi(2) + 1.25f64.ln().powi(2)) / 3.0).sqrt();
            assert!((s.random_log_sd[which] - spread).abs() < 1e-12);
            assert!(s.trial_log_sd[which].abs() < 1e-12);
            assert!((s.correlation[which].0 - 1.0).abs() < 1e-12);
            assert!((s.correlation[which].1.expect("no trial noise") - 1.0).abs() < 1e-12);
        }
        // Too few random pairs to take a median from: nothing to summarise.
        let mut short = cell(2);
        short.sets.truncate(3);
        assert!(view_set_summary(&[short]).is_none());
    }
}

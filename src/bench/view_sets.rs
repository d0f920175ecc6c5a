//! `easyhec bench view-sets`: how far 3-view selection can go. Per seeded cell, the loop's
//! explored pair and random pairs, each solved many times with fresh noise, against the
//! selection score's prediction.

use std::path::PathBuf;

use nalgebra::Isometry3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use super::{median, seeded_sim_cell, uniform_joints, Report};
use crate::calibrate::{choose_reachable, in_image_fraction, rank_poses, PlanCamera};
use crate::camera::Intrinsics;
use crate::cell::Cell;
use crate::config::SimArmSettings;
use crate::config::{read_config, ArmConfig, NoiseModel, SelectionSetting};
use crate::error::{Error, Result};
use crate::explore::{estimate_covariance, view_terms, ViewTerms};
use crate::geometry::{rotation_error_deg, translation_error_mm};
use crate::render::{CpuRenderer, PosedRobot, SilhouetteRenderer};
use crate::solve::{solve, SolveOptions, View};

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
    let trial_cell = TrialCell::new(cfg, config_path, seed)?;
    // One stream for everything, in this order: the explored pair's captures, the random
    // pairs' draws, then every set's trials.
    let mut rng = ChaCha8Rng::seed_from_u64(seed.wrapping_mul(7717) + 3);
    // The explored pair, planned as the loop plans it.
    let (taken, noise_px2) = trial_cell.explored_set(&mut rng)?;
    let mut sets = vec![("explore".to_string(), taken)];
    trial_cell.add_random_pairs(&mut sets, random_pairs, &mut rng)?;
    let mut out = Vec::new();
    for (name, joints) in sets {
        out.push(trial_cell.measure_set(name, joints, noise_px2, trials, &mut rng)?);
    }
    Ok(ViewSetCell { seed, sets: out })
}

/// A view-set failure, naming the cell seed that produced it.
fn bad(seed: u64, why: &str) -> Error {
    Error::Solve(format!("seed {seed}: {why}"))
}

/// One seeded cell set up for view-set trials (see [`view_set_cell`]): the built cell, its
/// undistorted camera, the true and guessed poses, and the noise every capture draws.
struct TrialCell {
    seed: u64,
    cell: Cell,
    camera: Intrinsics,
    truth: Isometry3<f64>,
    guess: Isometry3<f64>,
    /// The start pose, view 0 of every set.
    q0: Vec<f64>,
    encoder_noise: Normal<f64>,
    mask_noise: Option<NoiseModel>,
    opts: SolveOptions,
}

impl TrialCell {
    /// Builds the cell of `cfg` with explore selection; view sets need a sim arm, a sim-truth
    /// segmenter, a simulated camera and an initial guess.
    fn new(
        cfg: &crate::config::CellConfig,
        config_path: &std::path::Path,
        seed: u64,
    ) -> Result<TrialCell> {
        let bad = |why: &str| bad(seed, why);
        let mut cfg = cfg.clone();
        cfg.calibration.selection = SelectionSetting::Explore;
        let ArmConfig::Sim(SimArmSettings {
            start,
            encoder_noise_rad,
            ..
        }) = &cfg.arm
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
        let truth = cell.units[0]
            .sim
            .camera_from_base
            .ok_or_else(|| bad("view sets need a simulated camera"))?;
        let camera = cell
            .config
            .camera
            .first()
            .camera()
            .ok_or_else(|| bad("view sets need a simulated camera"))?
            .undistorted();
        let encoder_noise = Normal::new(0.0, encoder.max(0.0)).map_err(|e| bad(&e.to_string()))?;
        Ok(TrialCell {
            seed,
            cell,
            camera,
            truth,
            guess,
            q0,
            encoder_noise,
            mask_noise,
            opts: SolveOptions::default(),
        })
    }

    /// One noisy capture of each of `qs`: the true mask with segmentation noise, the joints
    /// as the encoders report them.
    fn capture(&self, qs: &[Vec<f64>], rng: &mut ChaCha8Rng) -> Vec<View> {
        let robot = &self.cell.robot;
        qs.iter()
            .map(|q| {
                let exact = CpuRenderer
                    .render(&PosedRobot::new(robot, q), &self.camera, &self.truth, None)
                    .mask;
                let observed = match &self.mask_noise {
                    Some(n) => crate::mask_noise::apply_mask_noise(rng, &exact, n),
                    None => exact,
                };
                let reported: Vec<f64> = q
                    .iter()
                    .map(|v| v + self.encoder_noise.sample(rng))
                    .collect();
                View {
                    robot: PosedRobot::new(robot, &reported),
                    observed,
                }
            })
            .collect()
    }

    /// The start pose plus the two poses the loop's planner picks, each from a noisy solve of
    /// the views before; also the first solve's outline noise (the score's model uses it).
    fn explored_set(&self, rng: &mut ChaCha8Rng) -> Result<(Vec<Vec<f64>>, f64)> {
        let (cell, camera, opts) = (&self.cell, &self.camera, &self.opts);
        let settings = &cell.config.calibration;
        let mut taken = vec![self.q0.clone()];
        let mut report = solve(
            &CpuRenderer,
            camera,
            &self.capture(&taken, rng),
            &self.guess,
            opts,
        )?;
        let noise_px2 = report.outline_noise_px2;
        for round in 0..2 {
            let request = crate::calibrate::PlanRequest {
                round,
                taken: &taken,
                motion: None,
            };
            let one = [PlanCamera {
                camera,
                mount: cell.config.camera.first().mount(),
                seen: &cell.units[0].seen,
                report: &report,
                wants_views: true,
            }];
            let (ranked, _) = rank_poses(&CpuRenderer, cell, &one, settings, &request);
            let from = taken.last().expect("view 0").clone();
            let (next, _) = choose_reachable(
                cell,
                &ranked,
                &from,
                settings.speed_rad_s,
                |_| false,
                &mut Vec::new(),
            )
            .ok_or_else(|| bad(self.seed, "the planner found no reachable pose"))?;
            taken.push(next.joints);
            let views = self.capture(&taken, rng);
            report = solve(&CpuRenderer, camera, &views, &report.camera_from_base, opts)?;
        }
        Ok((taken, noise_px2))
    }

    /// Adds random pairs (after the start pose) to `sets` until it holds `random_pairs` of
    /// them, drawn as the random selection draws its poses: safe, visible, path-checked.
    fn add_random_pairs(
        &self,
        sets: &mut Vec<(String, Vec<Vec<f64>>)>,
        random_pairs: usize,
        rng: &mut ChaCha8Rng,
    ) -> Result<()> {
        let (cell, camera, truth, q0) = (&self.cell, &self.camera, &self.truth, &self.q0);
        let (robot, settings) = (&cell.robot, &cell.config.calibration);
        let visible = |q: &[f64]| {
            cell.checker.check_pose(q).is_ok()
                && in_image_fraction(&PosedRobot::new(robot, q).decimated(0.01), camera, truth)
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
                    return Err(bad(
                        self.seed,
                        "no random pair of safe, visible, reachable poses",
                    ));
                }
                let q = uniform_joints(cell.checker.limits(), rng);
                let from = pair.last().unwrap_or(q0);
                if visible(&q) && reachable(from, &q) {
                    pair.push(q);
                }
            }
            let mut joints = vec![q0.clone()];
            joints.extend(pair);
            sets.push((format!("random {}", sets.len()), joints));
        }
        Ok(())
    }

    /// The selection score's model of `joints` at the truth, at the planner's scoring
    /// resolution: predicted RMS rotation (deg) and translation (mm) error.
    fn predicted_errors(&self, joints: &[Vec<f64>], noise_px2: f64) -> Result<(f64, f64)> {
        let (camera, truth) = (&self.camera, &self.truth);
        let (robot, settings) = (&self.cell.robot, &self.cell.config.calibration);
        let low = camera.downsampled(settings.score_downsample.max(1));
        let cell_m = f64::from(settings.score_downsample.max(1)) / camera.fx.max(camera.fy);
        let terms = |q: &[f64]| {
            view_terms(
                &low,
                camera.fx,
                &PosedRobot::new(robot, q).decimated(cell_m),
                &robot.joint_motions(q),
                truth,
                noise_px2,
                settings.joint_noise_rad,
            )
        };
        let total = joints
            .iter()
            .map(|q| terms(q))
            .fold(ViewTerms::zeros(), |a, b| a + b);
        let cov = estimate_covariance(&total)
            .ok_or_else(|| bad(self.seed, "a set leaves the pose unpinned"))?;
        // RMS over the camera axes of the 1-sigma errors the covariance reports.
        let u = crate::solve::uncertainty_of(&cov, truth);
        let norm = |v: [f64; 3]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
        Ok((norm(u.rotation_deg), norm(u.translation_mm)))
    }

    /// One [`ViewSet`]: its predicted errors, then `trials` solves of fresh noisy captures.
    fn measure_set(
        &self,
        name: String,
        joints: Vec<Vec<f64>>,
        noise_px2: f64,
        trials: usize,
        rng: &mut ChaCha8Rng,
    ) -> Result<ViewSet> {
        let (predicted_deg, predicted_mm) = self.predicted_errors(&joints, noise_px2)?;
        let mut errors = Vec::with_capacity(trials);
        for _ in 0..trials {
            let rep = solve(
                &CpuRenderer,
                &self.camera,
                &self.capture(&joints, rng),
                &self.guess,
                &self.opts,
            )?;
            errors.push((
                rotation_error_deg(&rep.camera_from_base, &self.truth),
                translation_error_mm(&rep.camera_from_base, &self.truth),
            ));
        }
        Ok(ViewSet {
            name,
            joints,
            predicted_deg,
            predicted_mm,
            errors,
        })
    }
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

/// How far 3-view selection can go: per seeded cell, the loop's explored pair and random
/// pairs, each solved many times with fresh noise, against the selection score's
/// prediction (README: closed loop).
#[derive(clap::Args, Clone, Debug)]
pub struct ViewSetsBench {
    /// Base cell config (seeded variants move the camera, start pose and guess).
    #[arg(long, default_value = "config/sim-xarm6.toml")]
    pub config: PathBuf,
    /// Number of cells (seeds FIRST..FIRST+N-1).
    #[arg(long, default_value_t = 12, value_parser = clap::value_parser!(u64).range(1..=1000))]
    pub cells: u64,
    /// First cell seed.
    #[arg(long, default_value_t = 0)]
    pub first_seed: u64,
    /// Random pairs per cell.
    #[arg(long, default_value_t = 12, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=10000))]
    pub random_pairs: usize,
    /// Noisy solves per set.
    #[arg(long, default_value_t = 10, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=1000))]
    pub trials: usize,
}

impl ViewSetsBench {
    /// Runs the benchmark: per-seed lines go to `log`, the summary into the report.
    pub fn run(&self, log: &mut dyn FnMut(&str)) -> Result<Report> {
        let mut report = Report::default();
        let ViewSetsBench {
            config,
            cells,
            first_seed,
            random_pairs,
            trials,
        } = self.clone();
        if random_pairs < 3 || trials < 2 {
            return Err(Error::Usage(
                "--random-pairs must be at least 3 and --trials at least 2".to_string(),
            ));
        }
        let base = read_config(&config)?;
        if !base.camera.first().mount().is_fixed() {
            return Err(crate::Error::input(
                &config,
                "camera.mount",
                "bench view-sets measures fixed cameras only: use bench loop for a camera on a link",
            ));
        }
        let mut results = Vec::new();
        for seed in first_seed..first_seed + cells {
            let cfg = seeded_sim_cell(&base, &config, seed)?;
            let c = view_set_cell(&cfg, &config, seed, random_pairs, trials)?;
            let n = c.sets[0].errors.len();
            let median_of = |f: &dyn Fn(&ViewSet) -> f64| {
                median(&c.sets[1..].iter().map(f).collect::<Vec<_>>())
            };
            let e = &c.sets[0];
            log(&format!(
                "seed {seed}: explore predicted {:.4} deg {:.3} mm, measured RMS {:.4} deg {:.3} mm; random pairs' median predicted {:.4} deg {:.3} mm, measured {:.4} deg {:.3} mm",
                e.predicted_deg,
                e.predicted_mm,
                e.rms(0, 0..n),
                e.rms(1, 0..n),
                median_of(&|v| v.predicted_deg),
                median_of(&|v| v.predicted_mm),
                median_of(&|v| v.rms(0, 0..n)),
                median_of(&|v| v.rms(1, 0..n)),
            ));
            results.push(c);
        }
        let s = view_set_summary(&results)
            .ok_or_else(|| Error::Solve("no cell to summarise".into()))?;
        report.line(format!("| over {cells} cells, {random_pairs} random pairs, {trials} solves each | rotation | translation |"));
        report.line("|---|---|---|");
        let mut row = |name: &str, v: [f64; 2]| {
            report.line(format!("| {name} | {:.2}x | {:.2}x |", v[0], v[1]))
        };
        row(
            "explore / random, predicted by the score's model",
            s.predicted_ratio,
        );
        row("explore / random, measured", s.measured_ratio);
        row(
            "best random pair / random (picked on its own trials)",
            s.best_random_ratio,
        );
        report.line(format!(
            "| spread of the random pairs' error (sd of log) | {:.2} ({:.2} from the finite trials) | {:.2} ({:.2}) |",
            s.random_log_sd[0], s.trial_log_sd[0], s.random_log_sd[1], s.trial_log_sd[1]
        ));
        let corr = |c: (f64, Option<f64>)| match c.1 {
            Some(r) => format!("{:.2} ({r:.2})", c.0),
            None => format!("{:.2} (-)", c.0),
        };
        report.line(format!(
            "| correlation of predicted and measured log error within a cell (trial noise removed) | {} | {} |",
            corr(s.correlation[0]),
            corr(s.correlation[1])
        ));
        Ok(report)
    }
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

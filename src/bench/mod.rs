//! Benchmarks behind `easyhec bench` (figures in docs/benchmarks.md, each with its command).
//! Nothing here asserts timings: performance is measured here, never in tests. Each benchmark
//! is an options struct (its flags) with a `run` that logs per-seed lines and returns the
//! summary the CLI prints. Benchmark-only protocols live here, not in the product loop.
//!
//! - [`accuracy`]: pose error over seeded synthetic scenes by view count.
//! - [`coverage`]: how often the reported uncertainty covers the true error.
//! - [`init`]: automatic initialisation over cameras anywhere on a hemisphere.
//! - [`closed_loop`]: exploration against random selection on seeded simulated cells.
//! - [`motion`]: planning that weighs motion time, on the mock xArm in real time.
//! - [`view_sets`]: how far choosing two views can go, against the score's model.
//! - [`segmentation`]: the builtin segmenter's masks and RGB-only calibrations.
//! - [`speed`]: solve time and memory, and one exploration round's scoring time.

pub mod accuracy;
pub mod closed_loop;
pub mod coverage;
pub mod init;
pub mod motion;
pub mod real;
pub mod rig;
pub mod segmentation;
pub mod speed;
pub mod view_sets;

use rayon::prelude::*;

use crate::camera::LensWarp;
use crate::config::{SimArmSettings, SimCameraSettings};
use crate::error::Result;
use crate::render::PosedRobot;
use crate::robot::RobotModel;
use crate::solve::View;
use crate::synth::Scene;

pub use accuracy::AccuracyBench;
pub use closed_loop::LoopBench;
pub use coverage::CoverageBench;
pub use init::InitBench;
pub use motion::MotionBench;
pub use real::RealBench;
pub use rig::RigBench;
pub use segmentation::SegmentBench;
pub use speed::{ExploreBench, SpeedBench};
pub use view_sets::ViewSetsBench;

/// The summary a benchmark prints on standard output, line by line.
#[derive(Clone, Debug, Default)]
pub struct Report {
    text: String,
}

impl Report {
    /// Adds one line (a newline follows it).
    pub fn line(&mut self, line: impl AsRef<str>) {
        self.text.push_str(line.as_ref());
        self.text.push('\n');
    }

    /// Everything added, each line ending in a newline.
    pub fn text(&self) -> &str {
        &self.text
    }
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

/// A seeded benchmark scene of `views` views, its solver views and its initial guess.
pub fn seeded_scene(
    robot: &RobotModel,
    seed: u64,
    views: usize,
    synth: &crate::synth::SynthOptions,
) -> Result<(Scene, Vec<View>, nalgebra::Isometry3<f64>)> {
    let scene = crate::synth::generate(
        robot,
        &crate::synth::SynthOptions {
            seed,
            views,
            ..synth.clone()
        },
    )?;
    let solver_views = scene_views(robot, &scene);
    let init = scene.initial_guess.ok_or_else(|| {
        crate::error::Error::Solve("benchmark scenes carry an initial guess".into())
    })?;
    Ok((scene, solver_views, init))
}

/// Resamples of [`paired_median_difference`]'s bootstrap.
const BOOTSTRAP_RESAMPLES: usize = 2000;

/// `median(a) - median(b)` over paired cells, with its 95% interval from a seeded paired
/// bootstrap (cells drawn with replacement, each keeping both its figures).
///
/// Why: per-cell errors scatter by a factor of several, so two medians over a few dozen
/// cells differ by chance alone; the interval says whether a difference is more than that.
pub fn paired_median_difference(a: &[f64], b: &[f64]) -> (f64, (f64, f64)) {
    use rand::{Rng, SeedableRng};
    assert_eq!(a.len(), b.len(), "paired figures come in pairs");
    let n = a.len();
    let observed = median(a) - median(b);
    if n == 0 {
        return (observed, (f64::NAN, f64::NAN));
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
    let mut diffs: Vec<f64> = (0..BOOTSTRAP_RESAMPLES)
        .map(|_| {
            let picks: Vec<usize> = (0..n).map(|_| rng.random_range(0..n)).collect();
            let pick = |v: &[f64]| picks.iter().map(|&i| v[i]).collect::<Vec<_>>();
            median(&pick(a)) - median(&pick(b))
        })
        .collect();
    diffs.sort_by(f64::total_cmp);
    let at = |q: f64| diffs[((q * BOOTSTRAP_RESAMPLES as f64) as usize).min(diffs.len() - 1)];
    (observed, (at(0.025), at(0.975)))
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

/// Peak resident set size of this process, bytes (Linux `VmHWM`).
pub fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// A seeded variant of a simulated cell config: true camera anywhere on a band of the
/// hemisphere around the robot, a random safe visible start pose, a guess 2–6° / 2–8 cm off.
pub fn seeded_sim_cell(
    base: &crate::config::CellConfig,
    config_path: &std::path::Path,
    seed: u64,
) -> Result<crate::config::CellConfig> {
    use crate::config::InitialGuess;
    use crate::config::{CameraConfig, LookAt};
    use rand::{Rng, SeedableRng};
    base.camera.require_one(
        config_path,
        "this benchmark (bench rig measures several cameras)",
    )?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed + 9000);
    if !base.camera.first().mount().is_fixed() {
        return seeded_wrist_cell(base, config_path, seed, &mut rng);
    }
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
    let CameraConfig::Sim(SimCameraSettings {
        truth: t, scene, ..
    }) = cfg.camera.first_mut()
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
    with_visible_start(cfg, config_path, seed, &mut rng, None)
}

/// A seeded variant of a cell whose camera is on a link: the config's mount pose moved by up
/// to 1 cm and about 3° (brackets differ that much from their drawing), a random safe start
/// pose that shows the robot, a guess 2–6° / 2–8 cm off, as for a fixed camera.
fn seeded_wrist_cell(
    base: &crate::config::CellConfig,
    config_path: &std::path::Path,
    seed: u64,
    rng: &mut rand_chacha::ChaCha8Rng,
) -> Result<crate::config::CellConfig> {
    use crate::config::{CameraConfig, InitialGuess};
    use rand::Rng;
    let mut cfg = base.clone();
    let CameraConfig::Sim(SimCameraSettings { truth, scene, .. }) = cfg.camera.first_mut() else {
        return Err(crate::Error::input(
            config_path,
            "camera.kind",
            "the loop benchmark needs a simulated camera (kind = \"sim\")",
        ));
    };
    for v in &mut truth.eye {
        *v += rng.random_range(-0.01..0.01);
    }
    for v in &mut truth.look_at {
        *v += rng.random_range(-0.05..0.05);
    }
    truth.roll_deg += rng.random_range(-5.0..5.0);
    let pose = truth.camera_from_base();
    scene.seed = seed;
    cfg.calibration.seed = seed;
    let guess = crate::synth::perturb(rng, &pose, (2.0, 6.0), (0.02, 0.08));
    cfg.calibration.initial_guess = Some(InitialGuess::Matrix {
        camera_from_base: crate::geometry::to_rows(&guess),
    });
    if let crate::config::SegmenterConfig::SimTruth { seed: s, .. } = &mut cfg.segmenter {
        *s = seed;
    }
    // An operator starts where the wrist camera sees the robot, under the drawing's pose too.
    with_visible_start(cfg, config_path, seed, rng, Some(guess))
}

/// `cfg` with a start pose that is safe and shows the robot to the true camera (by the
/// camera's own visibility rule, with a margin for a fixed camera).
fn with_visible_start(
    mut cfg: crate::config::CellConfig,
    config_path: &std::path::Path,
    seed: u64,
    rng: &mut rand_chacha::ChaCha8Rng,
    also_under: Option<nalgebra::Isometry3<f64>>,
) -> Result<crate::config::CellConfig> {
    use crate::calibrate::VisibilityRule;
    use crate::cell::Cell;
    use crate::config::ArmConfig;
    let cell = Cell::build(cfg.clone(), config_path)?;
    let pose = cell.units[0].sim.camera_from_base.ok_or_else(|| {
        crate::Error::input(config_path, "camera.kind", "needs a simulated camera")
    })?;
    let rule = match VisibilityRule::of(&cell, cfg.camera.first().mount()) {
        VisibilityRule::InImage(_) => VisibilityRule::InImage(0.97),
        coverage => coverage,
    };
    let camera = cfg
        .camera
        .first()
        .camera()
        .ok_or_else(|| crate::Error::input(config_path, "camera.kind", "needs a simulated camera"))?
        .undistorted();
    let low = camera.downsampled(cfg.calibration.score_downsample);
    for _ in 0..10_000 {
        let q = uniform_joints(cell.checker.limits(), rng);
        if cell.checker.check_pose(&q).is_err() {
            continue;
        }
        let posed = PosedRobot::new(&cell.units[0].seen, &q).decimated(0.01);
        let shown = |p: &nalgebra::Isometry3<f64>| rule.shows(&posed, &camera, &low, p).is_some();
        if !shown(&pose) || also_under.is_some_and(|g| !shown(&g)) {
            continue;
        }
        let ArmConfig::Sim(SimArmSettings { start, seed: s, .. }) = &mut cfg.arm else {
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
pub(crate) fn uniform_joints(limits: &[(f64, f64)], rng: &mut impl rand::Rng) -> Vec<f64> {
    limits
        .iter()
        .map(|&(lo, hi)| rng.random_range(lo..=hi))
        .collect()
}

/// A command-line choice's spelling (`lm`, `explore`), from its value enum, for report lines.
fn value_name(value: &impl clap::ValueEnum) -> String {
    value
        .to_possible_value()
        .map_or_else(String::new, |v| v.get_name().to_string())
}

#[cfg(test)]
mod tests {
    use super::paired_median_difference;

    #[test]
    fn the_paired_interval_holds_a_constant_shift_exactly_and_a_chance_one_loosely() {
        let b: Vec<f64> = (0..40).map(|i| ((i * 37) % 40) as f64 * 0.01).collect();
        let shifted: Vec<f64> = b.iter().map(|v| v + 0.5).collect();
        let (d, (lo, hi)) = paired_median_difference(&shifted, &b);
        assert!((d - 0.5).abs() < 1e-12 && (lo - 0.5).abs() < 1e-12 && (hi - 0.5).abs() < 1e-12);
        // The same values in another order: no real difference, and the interval says so.
        let a: Vec<f64> = b.iter().rev().copied().collect();
        let (d, (lo, hi)) = paired_median_difference(&a, &b);
        assert_eq!(d, 0.0);
        assert!(lo < 0.0 && hi > 0.0 && hi - lo > 0.05, "[{lo}, {hi}]");
    }
}

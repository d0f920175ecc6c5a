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

//! `easyhec bench accuracy`: median pose error over seeded synthetic scenes, by view count and
//! optimiser.

use std::path::PathBuf;
use std::time::Instant;

use super::{median, seeded_scene, Report};
use crate::config::NoiseModel;
use crate::error::Result;
use crate::geometry::{rotation_error_deg, translation_error_mm};
use crate::render::CpuRenderer;
use crate::robot::RobotModel;
use crate::solve::{solve, Optimizer, SolveOptions};
use crate::synth::SynthOptions;

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

/// Runs the accuracy benchmark: for each seed, solves from the first k views for each k in
/// `view_counts` with `opts`, starting from the scene's perturbed initial guess.
pub fn accuracy(
    robot: &RobotModel,
    seeds: &[u64],
    view_counts: &[usize],
    opts: &SolveOptions,
    synth: &SynthOptions,
    mut progress: impl FnMut(&Trial),
) -> Result<Vec<Trial>> {
    let max_views = view_counts.iter().copied().max().unwrap_or(1);
    let mut trials = Vec::new();
    for &seed in seeds {
        let (scene, views, init) = seeded_scene(robot, seed, max_views, synth)?;
        for &k in view_counts {
            let t = Instant::now();
            let rep = solve(&CpuRenderer, &scene.camera, &views[..k], &init, opts)?;
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

/// Median pose error over seeded synthetic scenes, views 1..K, LM and/or Adam.
#[derive(clap::Args, Clone, Debug)]
pub struct AccuracyBench {
    /// Robot URDF.
    #[arg(long, default_value = "../shared/robots/xarm6/robot.urdf")]
    pub robot: PathBuf,
    /// Number of scenes (seeds 0..N-1).
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u64).range(1..=1000))]
    pub scenes: u64,
    /// View counts to evaluate.
    #[arg(long, value_delimiter = ',', default_value = "1,2,3,4,5")]
    pub views: Vec<usize>,
    /// Optimisers to run.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "lm")]
    pub optimizers: Vec<Optimizer>,
    /// Segmentation-noise preset of the scenes (docs/uncertainty.md).
    #[arg(long, default_value = "standard", value_parser = clap::builder::PossibleValuesParser::new(NoiseModel::PRESETS))]
    pub noise: String,
    /// Estimate the masks' outline offset with the pose, as `easyhec solve
    /// --estimate-mask-offset` does.
    #[arg(long)]
    pub mask_offset: bool,
}

impl AccuracyBench {
    /// Runs the benchmark: per-seed lines go to `log`, the summary into the report.
    pub fn run(&self, log: &mut dyn FnMut(&str)) -> Result<Report> {
        let mut report = Report::default();
        let AccuracyBench {
            robot,
            scenes,
            views,
            optimizers,
            noise,
            mask_offset,
        } = self.clone();
        let synth = SynthOptions {
            noise: NoiseModel::preset(&noise)
                .ok_or_else(|| crate::Error::Usage(format!("--noise {noise}: no such preset")))?,
            ..SynthOptions::default()
        };
        let model = RobotModel::from_urdf(robot)?;
        let seeds: Vec<u64> = (0..scenes).collect();
        for optimizer in optimizers {
            let name = super::value_name(&optimizer);
            let base = SolveOptions {
                optimizer,
                estimate_mask_offset: mask_offset,
                ..SolveOptions::default()
            };
            let trials = accuracy(&model, &seeds, &views, &base, &synth, |t| {
                log(&format!(
                    "{name} seed {} views {}: {:.4} deg {:.3} mm (1-sigma {:.4} deg {:.3} mm) {:.2} s",
                    t.seed, t.views, t.rotation_deg, t.translation_mm, t.sigma_rotation_deg, t.sigma_translation_mm, t.seconds
                ))
            })?;
            report.line(summarize(&name, &trials, &views));
        }
        Ok(report)
    }
}

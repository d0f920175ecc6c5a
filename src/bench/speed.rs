//! `easyhec bench speed` (K-view solve time and peak memory) and `easyhec bench explore` (one
//! exploration round's scoring on the renderer).

use std::path::PathBuf;
use std::time::Instant;

use rayon::prelude::*;

use super::{median, peak_rss_bytes, scene_views, Report};
use crate::backend::open_renderer;
use crate::config::RendererChoice;
use crate::error::{Error, Result};
use crate::render::{CpuRenderer, PosedRobot};
use crate::robot::RobotModel;
use crate::solve::{solve, SolveOptions};
use crate::synth::{generate, SynthOptions};

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
    report.sampling_covariance *= 400.0;
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

/// Wall time of K-view solves, and peak memory.
#[derive(clap::Args, Clone, Debug)]
pub struct SpeedBench {
    /// Robot URDF.
    #[arg(long, default_value = "../shared/robots/xarm6/robot.urdf")]
    pub robot: PathBuf,
    /// Views per solve.
    #[arg(long, default_value_t = 5, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=100))]
    pub views: usize,
    /// Image width.
    #[arg(long, default_value_t = 640, value_parser = clap::builder::RangedU64ValueParser::<u32>::new().range(8..=4096))]
    pub width: u32,
    /// Image height.
    #[arg(long, default_value_t = 480, value_parser = clap::builder::RangedU64ValueParser::<u32>::new().range(8..=4096))]
    pub height: u32,
    /// Number of scenes (seeds) timed.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u64).range(1..=1000))]
    pub scenes: u64,
    /// Renderer: cpu, wgpu or auto.
    #[arg(long, default_value = "auto")]
    pub renderer: RendererChoice,
}

impl SpeedBench {
    /// Runs the benchmark: per-seed lines go to `log`, the summary into the report.
    pub fn run(&self, _log: &mut dyn FnMut(&str)) -> Result<Report> {
        let mut report = Report::default();
        let SpeedBench {
            robot,
            views,
            width,
            height,
            scenes,
            renderer,
        } = self.clone();
        let renderer =
            open_renderer(renderer, false).map_err(|e| Error::Usage(format!("--renderer: {e}")))?;
        let model = RobotModel::from_urdf(robot)?;
        let mut times = Vec::new();
        for seed in 0..scenes {
            let scene = generate(
                &model,
                &SynthOptions {
                    seed,
                    views,
                    width,
                    height,
                    focal_px: 600.0 * f64::from(width) / 640.0,
                    ..Default::default()
                },
            )?;
            let v = scene_views(&model, &scene);
            let t = Instant::now();
            solve(
                renderer.as_ref(),
                &scene.camera,
                &v,
                &scene.initial_guess.expect("guess"),
                &SolveOptions::default(),
            )?;
            times.push(t.elapsed().as_secs_f64());
        }
        report.line(format!(
            "{views}-view {width}x{height} solve on {} threads: median {:.3} s, min {:.3} s, max {:.3} s over {scenes} scenes; peak RSS {:.0} MB",
            rayon::current_num_threads(),
            median(&times),
            times.iter().copied().fold(f64::INFINITY, f64::min),
            times.iter().copied().fold(0.0, f64::max),
            peak_rss_bytes().unwrap_or(0) as f64 / 1e6
        ));
        Ok(report)
    }
}
/// One exploration round on the renderer: N joint samples x K camera candidates scored by
/// silhouette variance (docs/method.md §5), with its posing/decimation time separate.
#[derive(clap::Args, Clone, Debug)]
pub struct ExploreBench {
    /// Robot URDF.
    #[arg(long, default_value = "../shared/robots/xarm6/robot.urdf")]
    pub robot: PathBuf,
    /// Joint samples.
    #[arg(long, default_value_t = 2000, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=100000))]
    pub samples: usize,
    /// Camera candidates.
    #[arg(long, default_value_t = 50, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(2..=1000))]
    pub candidates: usize,
    /// Image width (scored at 1/4).
    #[arg(long, default_value_t = 640, value_parser = clap::builder::RangedU64ValueParser::<u32>::new().range(8..=4096))]
    pub width: u32,
    /// Image height.
    #[arg(long, default_value_t = 480, value_parser = clap::builder::RangedU64ValueParser::<u32>::new().range(8..=4096))]
    pub height: u32,
    /// Rounds timed.
    #[arg(long, default_value_t = 5, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=100))]
    pub rounds: usize,
    /// Renderer: cpu, wgpu or auto.
    #[arg(long, default_value = "auto")]
    pub renderer: RendererChoice,
}

impl ExploreBench {
    /// Runs the benchmark: per-seed lines go to `log`, the summary into the report.
    pub fn run(&self, _log: &mut dyn FnMut(&str)) -> Result<Report> {
        let mut report = Report::default();
        let ExploreBench {
            robot,
            samples,
            candidates,
            width,
            height,
            rounds,
            renderer,
        } = self.clone();
        let renderer =
            open_renderer(renderer, false).map_err(|e| Error::Usage(format!("--renderer: {e}")))?;
        let model = RobotModel::from_urdf(robot)?;
        let r = explore_round(
            renderer.as_ref(),
            &model,
            samples,
            candidates,
            width,
            height,
            rounds,
        )?;
        report.line(format!(
            "exploration round, {samples} joint samples x {candidates} candidates at {}x{} on {}: median {:.3} s scoring (min {:.3} s) + {:.3} s posing and decimation on {} threads; best score {:.1}",
            width / 4,
            height / 4,
            renderer.name(),
            median(&r.scoring_s),
            r.scoring_s.iter().copied().fold(f64::INFINITY, f64::min),
            median(&r.posing_s),
            rayon::current_num_threads(),
            r.best_score
        ));
        Ok(report)
    }
}

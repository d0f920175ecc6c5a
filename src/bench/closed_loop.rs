//! `easyhec bench loop`: the closed loop on seeded simulated cells, exploration against random
//! selection (median error after each view), planning time per round and compute per
//! calibration.

use std::path::PathBuf;

use super::{median, seeded_sim_cell, Report};
use crate::config::{read_config, RendererChoice, ScoreSetting, SelectionSetting};
use crate::error::Result;
use crate::geometry::{rotation_error_deg, translation_error_mm};

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
    let truth = cell.units[0]
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

/// Closed loop on seeded simulated cells: exploration vs random pose selection (median
/// error after each view), planning time per round and compute per calibration.
#[derive(clap::Args, Clone, Debug)]
pub struct LoopBench {
    /// Base cell config (seeded variants move the camera, start pose and guess).
    #[arg(long, default_value = "config/sim-xarm6.toml")]
    pub config: PathBuf,
    /// Number of cells (seeds FIRST..FIRST+N-1).
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u64).range(1..=1000))]
    pub cells: u64,
    /// First cell seed (a seed set the settings were not chosen on).
    #[arg(long, default_value_t = 0)]
    pub first_seed: u64,
    /// Views per calibration (no early stop).
    #[arg(long, default_value_t = 5, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=100))]
    pub views: usize,
    /// Hill-climbing steps per start (`[calibration] climb_steps`; default: the config's).
    #[arg(long)]
    pub climb_steps: Option<usize>,
    /// Selections to run.
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "explore,random"
    )]
    pub selections: Vec<SelectionSetting>,
    /// The renderer backend.
    #[arg(long, value_enum, default_value_t = RendererChoice::Auto)]
    pub renderer: RendererChoice,
    /// Exploration score (default: the config's).
    #[arg(long, value_enum)]
    pub score: Option<ScoreSetting>,
}

impl LoopBench {
    /// Runs the benchmark: per-seed lines go to `log`, the summary into the report.
    pub fn run(&self, log: &mut dyn FnMut(&str)) -> Result<Report> {
        let mut report = Report::default();
        let LoopBench {
            config,
            cells,
            first_seed,
            views,
            climb_steps,
            selections,
            renderer,
            score,
        } = self.clone();
        let mut base = read_config(&config)?;
        base.calibration.renderer = renderer;
        if let Some(n) = climb_steps {
            base.calibration.climb_steps = n;
        }
        if let Some(score) = score {
            base.calibration.score = score;
        }
        let mut all: Vec<(String, Vec<LoopTrial>)> = Vec::new();
        let mut failed: Vec<String> = Vec::new();
        for &selection in &selections {
            let name = super::value_name(&selection);
            let mut trials = Vec::new();
            for seed in first_seed..first_seed + cells {
                let cfg = seeded_sim_cell(&base, &config, seed)?;
                let t = match run_loop_trial(&cfg, &config, seed, selection, views) {
                    Ok(t) => t,
                    Err(e) => {
                        // A failed calibration is a result too: counted, never hidden.
                        log(&format!("{name} seed {seed}: failed: {e}"));
                        failed.push(format!("{name} {seed}"));
                        continue;
                    }
                };
                let last = t.errors.last().copied().unwrap_or((0, f64::NAN, f64::NAN));
                // Every view count's error, so medians over any subset of seeds can be
                // taken from one run.
                let per_view: Vec<String> = t
                    .errors
                    .iter()
                    .map(|e| format!("{}:{:.5}:{:.4}", e.0, e.1, e.2))
                    .collect();
                log(&format!(
                    "{name} seed {seed}: {} views {:.4} deg {:.3} mm; planning {:.2} s/round; compute {:.1} s; per view (views:deg:mm) {}; {}",
                    last.0,
                    last.1,
                    last.2,
                    t.explore_round_s[0],
                    t.compute_s,
                    per_view.join(" "),
                    t.stop_reason
                ));
                trials.push(t);
            }
            all.push((name, trials));
        }
        report.line(format!(
            "| selection | {} |",
            (1..=views)
                .map(|k| format!("{k} views"))
                .collect::<Vec<_>>()
                .join(" | ")
        ));
        report.line(format!("|---|{}", "---|".repeat(views)));
        for (name, trials) in &all {
            let cells: Vec<String> = (1..=views)
                .map(|k| match loop_medians(trials, k) {
                    Some((r, t)) => format!("{r:.3}° / {t:.2} mm"),
                    None => "-".into(),
                })
                .collect();
            report.line(format!("| {name} | {} |", cells.join(" | ")));
        }
        for (name, trials) in &all {
            let plan: Vec<f64> = trials
                .iter()
                .flat_map(|t| t.explore_round_s.clone())
                .collect();
            let compute: Vec<f64> = trials.iter().map(|t| t.compute_s).collect();
            report.line(format!(
                "{name}: planning per round median {:.2} s (max {:.2}); compute per {views}-view calibration median {:.1} s (max {:.1})",
                median(&plan),
                plan.iter().cloned().fold(0.0, f64::max),
                median(&compute),
                compute.iter().cloned().fold(0.0, f64::max)
            ));
        }
        if !failed.is_empty() {
            report.line(format!(
                "failed calibrations (selection and seed; left out of the medians): {}",
                failed.join(", ")
            ));
        }
        if all.len() == 2 {
            if let (Some(e), Some(r)) = (loop_medians(&all[0].1, 3), loop_medians(&all[1].1, 3)) {
                report.line(format!(
                    "3 views, {} / {}: rotation {:.2}x, translation {:.2}x",
                    all[0].0,
                    all[1].0,
                    e.0 / r.0,
                    e.1 / r.1
                ));
            }
        }
        Ok(report)
    }
}

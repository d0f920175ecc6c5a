//! `easyhec bench segment`: the builtin segmenter's mask IoU against the simulator's truth and
//! the RGB-only closed-loop calibration error on seeded cells, and its figures on the Panda
//! photographs (masks withheld) against the provided masks. Nothing here asserts.

use std::path::{Path, PathBuf};

use super::{median, seeded_sim_cell, Report};
use crate::calibrate::{calibrate, RunOptions};
use crate::camera::LensWarp;
use crate::cell::Cell;
use crate::config::SegmenterConfig;
use crate::config::SimCameraSettings;
use crate::config::{read_config, RendererChoice, ScenePreset};
use crate::config::{CellConfig, SelectionSetting};
use crate::error::{Error, Result};
use crate::explore::Selection;
use crate::geometry::{rotation_error_deg, translation_error_mm};
use crate::mask::Mask;
use crate::pipeline::offline::{solve_run, OfflineSolve};
use crate::run::load_run;
use crate::solve::{Optimizer, SolveOptions};

/// How far (pixels) a mask's outline is searched for the reference's when measuring boundary
/// bias: further away it is a miss or a blob, which the IoU counts.
const OFFSET_REACH_PX: u32 = 5;

/// Mean and mean absolute value of boundary offsets, pixels (0 for none).
fn offset_summary(offsets: &[f64]) -> (f64, f64) {
    let n = offsets.len().max(1) as f64;
    (
        offsets.iter().sum::<f64>() / n,
        offsets.iter().map(|d| d.abs()).sum::<f64>() / n,
    )
}

/// One seeded cell calibrated from colour frames alone.
#[derive(Clone, Debug)]
pub struct CellTrial {
    /// Cell seed.
    pub seed: u64,
    /// IoU of each final mask against the true silhouette.
    pub ious: Vec<f64>,
    /// Boundary offsets of all final masks against the true silhouettes (see
    /// [`Mask::boundary_offsets`]), pixels, positive outward.
    pub boundary_offsets: Vec<f64>,
    /// Rotation error of the final estimate, degrees.
    pub rotation_deg: f64,
    /// Translation error of the final estimate, mm.
    pub translation_mm: f64,
}

/// Calibrates `cfg` (a seeded simulated cell) with the builtin segmenter, `views` views, no
/// early stop; each final mask (as written in the run directory) is compared with the
/// simulator's truth for its frame. `preset` dresses the frames (easy or hard).
pub fn cell_trial(
    cfg: &CellConfig,
    config_path: &Path,
    seed: u64,
    views: usize,
    preset: crate::config::ScenePreset,
) -> Result<CellTrial> {
    let mut cfg = cfg.clone();
    if let crate::config::CameraConfig::Sim(SimCameraSettings { scene, .. }) =
        cfg.camera.first_mut()
    {
        scene.preset = preset;
    }
    cfg.segmenter = SegmenterConfig::by_name("builtin").map_err(Error::Solve)?;
    cfg.calibration.selection = SelectionSetting::Explore;
    cfg.calibration.max_views = views;
    cfg.calibration.min_views = views;
    let mut cell = Cell::build(cfg, config_path)?;
    let truths = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    let inner = std::mem::replace(
        &mut cell.units[0].segmenter,
        crate::segment::build(
            &SegmenterConfig::by_name("builtin").map_err(Error::Solve)?,
            config_path,
        )?,
    );
    let camera = cell.units[0].sim.camera.clone().ok_or_else(|| {
        Error::Solve("the segmentation benchmark needs a simulated camera".into())
    })?;
    cell.units[0].segmenter = Box::new(TruthRecorder {
        inner,
        truth: camera,
        truths: truths.clone(),
    });
    let truth = cell.units[0]
        .sim
        .camera_from_base
        .ok_or_else(|| Error::Solve("the segment benchmark needs a simulated camera".into()))?;
    let dir = tempfile::tempdir().map_err(|e| Error::io(std::env::temp_dir(), e))?;
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| Error::Solve(format!("async runtime: {e}")))?;
    let out = dir.path().join("run");
    let outcome = runtime.block_on(calibrate(&cell, &out, &RunOptions::default()))?;
    let run = load_run(&out)?;
    let truths = truths
        .lock()
        .map_err(|_| Error::Solve("truth recorder poisoned".into()))?;
    let mut ious = Vec::new();
    let mut boundary_offsets = Vec::new();
    for (i, v) in run.file.views.iter().enumerate() {
        let mask_rel = v
            .mask
            .as_ref()
            .ok_or_else(|| Error::Solve("view without mask".into()))?;
        let mask = Mask::load(&run.dir.join(mask_rel))?;
        let truth_mask = truths
            .get(i)
            .and_then(Option::as_ref)
            .ok_or_else(|| Error::Solve("the simulated camera sent no truth mask".into()))?;
        let t = Mask {
            width: mask.width,
            height: mask.height,
            data: truth_mask.iter().map(|&b| u8::from(b >= 128)).collect(),
        };
        ious.push(mask.iou(&t));
        boundary_offsets.extend(mask.boundary_offsets(&t, OFFSET_REACH_PX));
    }
    let est = outcome.report.camera_from_base;
    Ok(CellTrial {
        seed,
        ious,
        boundary_offsets,
        rotation_deg: rotation_error_deg(&est, &truth),
        translation_mm: translation_error_mm(&est, &truth),
    })
}

/// Passes segmentation through and keeps each frame's ground-truth side channel (the
/// simulator's truth: robot pixels a distractor hides are left out), by view index.
struct TruthRecorder {
    inner: Box<dyn crate::segment::Segmenter>,
    truth: std::sync::Arc<dyn crate::segment::TruthSource>,
    truths: std::sync::Arc<std::sync::Mutex<Vec<Option<Vec<u8>>>>>,
}

impl crate::segment::Segmenter for TruthRecorder {
    fn name(&self) -> &str {
        self.inner.name()
    }

    fn segment(&self, frame: &easyhec_drivers::Frame) -> Result<Mask> {
        self.inner.segment(frame)
    }

    fn segment_views(&self, views: &[crate::segment::ViewInput<'_>]) -> Result<Vec<Mask>> {
        if let Ok(mut t) = self.truths.lock() {
            *t = views
                .iter()
                .map(|v| self.truth.truth_mask(v.frame))
                .collect();
        }
        self.inner.segment_views(views)
    }

    fn uses_context(&self) -> bool {
        self.inner.uses_context()
    }
}

/// The builtin segmenter on a run directory whose masks are the reference.
#[derive(Clone, Debug)]
pub struct RunFigures {
    /// Views both calibrations kept.
    pub views: Vec<usize>,
    /// IoU of each of those views' builtin mask against the recorded one.
    pub ious: Vec<f64>,
    /// Boundary offset (mean, mean absolute; pixels, positive outward) of each of those
    /// views' builtin mask against the recorded one (see [`Mask::boundary_offsets`]).
    pub offsets: Vec<(f64, f64)>,
    /// Rotation between the image-only calibration and the recorded-mask one, degrees.
    pub rotation_deg: f64,
    /// Translation between them, mm.
    pub translation_mm: f64,
}

/// Solves `run` as `easyhec solve` does, once from its recorded masks and once from its
/// images alone (`--segmenter builtin --ignore-masks`), and compares the masks of the views
/// both kept and the two poses. Results and masks go to a temporary folder.
pub fn run_figures(run_dir: &Path, renderer: RendererChoice) -> Result<RunFigures> {
    let scratch = tempfile::tempdir().map_err(|e| Error::io(std::env::temp_dir(), e))?;
    let masks_dir = scratch.path().join("masks");
    let request = |out: &str, segmenter: Option<SegmenterConfig>| OfflineSolve {
        run: run_dir.to_path_buf(),
        views: None,
        selection: Selection::First,
        seed: 0,
        optimizer: Optimizer::Lm,
        out: Some(scratch.path().join(out)),
        initial_guess: None,
        overlays: None,
        renderer,
        keep_all_views: false,
        ignore_masks: segmenter.is_some(),
        masks_out: segmenter.is_some().then(|| masks_dir.clone()),
        segmenter,
        segmenter_file: None,
        allow_poor_fit: true,
        joint_noise_rad: SolveOptions::default().joint_noise_rad,
        model_floor: (0.0, 0.0),
        estimate_mask_offset: false,
        mount_contact: crate::solve::MountContact::Auto,
    };
    let quiet = &mut |_: &str| {};
    let reference = solve_run(&request("recorded.json", None), quiet)?;
    let builtin = SegmenterConfig::by_name("builtin").map_err(Error::Solve)?;
    let images = solve_run(&request("images.json", Some(builtin)), quiet)?;
    let (reference, images) = (reference.first(), images.first());
    let recorded = load_run(run_dir)?;
    let views: Vec<usize> = images
        .result
        .views_used
        .iter()
        .copied()
        .filter(|v| reference.result.views_used.contains(v))
        .collect();
    let (mut ious, mut offsets) = (Vec::new(), Vec::new());
    for &v in &views {
        let made = Mask::load(&masks_dir.join(crate::run::mask_file_name(v)))?;
        let made = recorded.camera.undistort_mask(&made);
        let truth = &recorded.views[v].observed;
        ious.push(made.iou(truth));
        offsets.push(offset_summary(
            &made.boundary_offsets(truth, OFFSET_REACH_PX),
        ));
    }
    let (a, b) = (
        &images.report.camera_from_base,
        &reference.report.camera_from_base,
    );
    Ok(RunFigures {
        views,
        ious,
        offsets,
        rotation_deg: rotation_error_deg(a, b),
        translation_mm: translation_error_mm(a, b),
    })
}

/// The builtin segmenter: mask IoU and RGB-only calibration error on seeded simulated
/// cells, and (with --run) its figures on a recorded run whose masks are the reference.
#[derive(clap::Args, Clone, Debug)]
pub struct SegmentBench {
    /// Base cell config (seeded variants move the camera, start pose and guess).
    #[arg(long, default_value = "config/sim-xarm6.toml")]
    pub config: PathBuf,
    /// Number of simulated cells (seeds 0..N-1; 0 skips them).
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u64).range(0..=1000))]
    pub scenes: u64,
    /// Views per calibration (no early stop).
    #[arg(long, default_value_t = 5, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=100))]
    pub views: usize,
    /// A run directory with images and masks (e.g. the imported Panda example), solved as
    /// `easyhec solve` does: its masks are withheld from the segmenter and used as the
    /// reference.
    #[arg(long)]
    pub run: Option<PathBuf>,
    /// Frame dressing of the simulated cells: hard (clutter, light robot on light walls,
    /// shadows, exposure changes, moving boxes) or easy.
    #[arg(long, value_enum, default_value_t = ScenePreset::Hard)]
    pub frames: ScenePreset,
    /// Renderer: cpu, wgpu or auto.
    #[arg(long, default_value = "auto")]
    pub renderer: RendererChoice,
    /// Calibrate the simulated cells with no initial guess: the loop first takes views near
    /// the start pose and starts from what changed between them. Cells that fail are counted
    /// and named, not fatal.
    #[arg(long)]
    pub no_guess: bool,
}

impl SegmentBench {
    /// Runs the benchmark: per-seed lines go to `log`, the summary into the report.
    pub fn run(&self, log: &mut dyn FnMut(&str)) -> Result<Report> {
        let mut report = Report::default();
        let SegmentBench {
            config,
            scenes,
            views,
            run,
            frames,
            renderer,
            no_guess,
        } = self.clone();
        let preset = frames;
        if scenes > 0 {
            let mut base = read_config(&config)?;
            base.calibration.renderer = renderer;
            let mut trials = Vec::new();
            let mut failed = Vec::new();
            for seed in 0..scenes {
                let mut cfg = seeded_sim_cell(&base, &config, seed)?;
                if no_guess {
                    cfg.calibration.initial_guess = None;
                }
                let t = match cell_trial(&cfg, &config, seed, views, preset) {
                    Ok(t) => t,
                    Err(e @ Error::Solve(_)) if no_guess => {
                        log(&format!("seed {seed}: failed: {e}"));
                        failed.push(seed);
                        continue;
                    }
                    Err(e) => return Err(e),
                };
                log(&format!(
                    "seed {seed}: IoU {:?}; {:.4} deg {:.3} mm",
                    t.ious
                        .iter()
                        .map(|x| (x * 1000.0).round() / 1000.0)
                        .collect::<Vec<_>>(),
                    t.rotation_deg,
                    t.translation_mm
                ));
                trials.push(t);
            }
            if no_guess {
                report.line(format!(
                    "no initial guess: {} of {scenes} cells calibrated (failed: seeds {failed:?})",
                    trials.len()
                ));
            }
            if !trials.is_empty() {
                report.line(summary(&trials, views));
            }
        }
        if let Some(run) = run {
            let f = run_figures(&run, renderer)?;
            let round = |x: f64| (x * 1000.0).round() / 1000.0;
            report.line(format!(
                "builtin on {} (masks withheld), views {:?} both calibrations kept: IoU {:?}; outline offset (mean, mean |offset|) {:?} px; images-only vs recorded-mask calibration {:.4} deg / {:.3} mm",
                run.display(),
                f.views,
                f.ious.iter().map(|&x| round(x)).collect::<Vec<_>>(),
                f.offsets
                    .iter()
                    .map(|&(m, a)| (round(m), round(a)))
                    .collect::<Vec<_>>(),
                f.rotation_deg,
                f.translation_mm,
            ));
        }
        Ok(report)
    }
}

/// The summary line of the simulated cells that calibrated.
fn summary(trials: &[CellTrial], views: usize) -> String {
    let calibrated = trials.len();
    let ious: Vec<f64> = trials.iter().flat_map(|t| t.ious.clone()).collect();
    let rot: Vec<f64> = trials.iter().map(|t| t.rotation_deg).collect();
    let trans: Vec<f64> = trials.iter().map(|t| t.translation_mm).collect();
    let offsets: Vec<f64> = trials
        .iter()
        .flat_map(|t| t.boundary_offsets.iter().copied())
        .collect();
    let (bias, spread) = offset_summary(&offsets);
    format!(
        "builtin on {calibrated} simulated cells, {views} views: mask IoU median {:.4} mean {:.4} (min {:.4}); outline offset against the truth mean {bias:+.3} px, mean |offset| {spread:.3} px ({crossings} crossings); RGB-only calibration median {:.4} deg / {:.3} mm (worst {:.4} deg / {:.3} mm)",
        median(&ious),
        ious.iter().sum::<f64>() / ious.len().max(1) as f64,
        ious.iter().copied().fold(f64::INFINITY, f64::min),
        median(&rot),
        median(&trans),
        rot.iter().copied().fold(0.0, f64::max),
        trans.iter().copied().fold(0.0, f64::max),
        crossings = offsets.len(),
    )
}

//! `easyhec bench segment`: the builtin segmenter's mask IoU against the simulator's truth and
//! the RGB-only closed-loop calibration error on seeded cells, and its figures on the Panda
//! photographs (masks withheld) against the provided masks. Nothing here asserts.

use std::path::{Path, PathBuf};

use super::{median, seeded_sim_cell, Report};
use crate::backend::open_renderer;
use crate::backend::Backend;
use crate::calibrate::{calibrate, RunOptions};
use crate::camera::LensWarp;
use crate::cell::Cell;
use crate::config::SegmenterConfig;
use crate::config::{read_config, RendererChoice, ScenePreset};
use crate::config::{CellConfig, SelectionSetting};
use crate::error::{Error, Result};
use crate::geometry::{rotation_error_deg, translation_error_mm};
use crate::mask::Mask;
use crate::render::PosedRobot;
use crate::run::{load_run, load_run_with, MaskSource};
use crate::solve::{solve, SolveOptions, View};

/// One seeded cell calibrated from colour frames alone.
#[derive(Clone, Debug)]
pub struct CellTrial {
    /// Cell seed.
    pub seed: u64,
    /// IoU of each final mask against the true silhouette.
    pub ious: Vec<f64>,
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
    if let crate::config::CameraConfig::Sim { scene, .. } = &mut cfg.camera {
        scene.preset = preset;
    }
    cfg.segmenter = SegmenterConfig::by_name("builtin").map_err(Error::Solve)?;
    cfg.calibration.selection = SelectionSetting::Explore;
    cfg.calibration.max_views = views;
    cfg.calibration.min_views = views;
    let mut cell = Cell::build(cfg, config_path)?;
    let truths = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    let inner = std::mem::replace(
        &mut cell.segmenter,
        crate::segment::build(
            &SegmenterConfig::by_name("builtin").map_err(Error::Solve)?,
            config_path,
        )?,
    );
    let camera = cell.sim.camera.clone().ok_or_else(|| {
        Error::Solve("the segmentation benchmark needs a simulated camera".into())
    })?;
    cell.segmenter = Box::new(TruthRecorder {
        inner,
        truth: camera,
        truths: truths.clone(),
    });
    let truth = cell
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
    }
    let est = outcome.report.camera_from_base;
    Ok(CellTrial {
        seed,
        ious,
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
    /// IoU of each builtin mask against the recorded one.
    pub ious: Vec<f64>,
    /// Rotation between the image-only calibration and the recorded-mask one, degrees.
    pub rotation_deg: f64,
    /// Translation between them, mm.
    pub translation_mm: f64,
    /// Segment-and-solve rounds.
    pub rounds: usize,
}

/// Solves `run` from its recorded masks, then from its images alone (masks withheld) with the
/// builtin segmenter, and compares masks and poses. The run needs an `initial_guess`.
pub fn run_figures(run_dir: &Path, renderer: &dyn Backend) -> Result<RunFigures> {
    let reference = load_run(run_dir)?;
    let guess = reference.initial_guess.ok_or_else(|| {
        Error::input(
            run_dir.join("run.json"),
            "initial_guess",
            "the segment benchmark needs one",
        )
    })?;
    let opts = SolveOptions::default();
    let views: Vec<View> = reference
        .views
        .iter()
        .map(|v| View {
            robot: PosedRobot::new(&reference.robot, &v.joints),
            observed: v.observed.clone(),
        })
        .collect();
    let ref_report = solve(renderer, &reference.camera, &views, &guess, &opts)?;
    let images = load_run_with(run_dir, MaskSource::Image)?;
    let mut frames = Vec::new();
    for v in &images.views {
        let path = v.image.as_ref().expect("checked by load_run_with");
        frames.push(crate::segment::read_frame(
            path,
            images.camera.width,
            images.camera.height,
        )?);
    }
    let refs: Vec<&easyhec_drivers::Frame> = frames.iter().collect();
    let robots: Vec<PosedRobot> = images
        .views
        .iter()
        .map(|v| PosedRobot::new(&images.robot, &v.joints))
        .collect();
    let config = SegmenterConfig::by_name("builtin").map_err(Error::Solve)?;
    let segmenter = crate::segment::build(&config, &run_dir.join("run.json"))?;
    let settled = crate::pipeline::segment_solve::segment_and_solve(
        renderer,
        &images.camera,
        segmenter.as_ref(),
        &refs,
        &robots,
        &|_| Ok(guess),
        Some((&guess, 80.0)),
        config.min_band_px(),
        config.final_band_px(),
        &opts,
        4,
    )?;
    let ious = settled
        .masks
        .iter()
        .zip(&reference.views)
        .map(|(m, v): (&Mask, _)| images.camera.undistort_mask(m).iou(&v.observed))
        .collect();
    Ok(RunFigures {
        ious,
        rotation_deg: rotation_error_deg(
            &settled.report.camera_from_base,
            &ref_report.camera_from_base,
        ),
        translation_mm: translation_error_mm(
            &settled.report.camera_from_base,
            &ref_report.camera_from_base,
        ),
        rounds: settled.rounds,
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
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u64).range(1..=1000))]
    pub scenes: u64,
    /// Views per calibration (no early stop).
    #[arg(long, default_value_t = 5, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=100))]
    pub views: usize,
    /// A run directory with images, masks and an initial guess (e.g. the imported Panda
    /// example): its masks are withheld from the segmenter and used as the reference.
    #[arg(long)]
    pub run: Option<PathBuf>,
    /// Frame dressing of the simulated cells: hard (clutter, light robot on light walls,
    /// shadows, exposure changes, moving boxes) or easy.
    #[arg(long, default_value = "hard")]
    pub frames: String,
    /// Renderer: cpu, wgpu or auto.
    #[arg(long, default_value = "auto")]
    pub renderer: RendererChoice,
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
        } = self.clone();
        let preset: ScenePreset = frames
            .parse()
            .map_err(|e: String| Error::Usage(format!("--frames: {e}")))?;
        if scenes > 0 {
            let mut base = read_config(&config)?;
            base.calibration.renderer = renderer;
            let mut trials = Vec::new();
            for seed in 0..scenes {
                let cfg = seeded_sim_cell(&base, &config, seed)?;
                let t = cell_trial(&cfg, &config, seed, views, preset)?;
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
            let ious: Vec<f64> = trials.iter().flat_map(|t| t.ious.clone()).collect();
            let rot: Vec<f64> = trials.iter().map(|t| t.rotation_deg).collect();
            let trans: Vec<f64> = trials.iter().map(|t| t.translation_mm).collect();
            report.line(format!(
                "builtin on {scenes} simulated cells, {views} views: mask IoU median {:.4} mean {:.4} (min {:.4}); RGB-only calibration median {:.4} deg / {:.3} mm (worst {:.4} deg / {:.3} mm)",
                median(&ious),
                ious.iter().sum::<f64>() / ious.len().max(1) as f64,
                ious.iter().copied().fold(f64::INFINITY, f64::min),
                median(&rot),
                median(&trans),
                rot.iter().copied().fold(0.0, f64::max),
                trans.iter().copied().fold(0.0, f64::max),
            ));
        }
        if let Some(run) = run {
            let r = open_renderer(renderer, false)
                .map_err(|e| Error::Usage(format!("--renderer: {e}")))?;
            let f = run_figures(&run, r.as_ref())?;
            report.line(format!(
                "builtin on {} ({} views, masks withheld): mean IoU {:.4} (per view {:?}); images-only vs recorded-mask calibration {:.4} deg / {:.3} mm after {} rounds",
                run.display(),
                f.ious.len(),
                f.ious.iter().sum::<f64>() / f.ious.len().max(1) as f64,
                f.ious.iter().map(|x| (x * 1000.0).round() / 1000.0).collect::<Vec<_>>(),
                f.rotation_deg,
                f.translation_mm,
                f.rounds
            ));
        }
        Ok(report)
    }
}

//! The offline solve of a recorded run directory (`easyhec solve`): load, segment the views
//! that need masks, initialise when there is no guess, select views, leave out the views no
//! pose agrees with, write the result and the overlays. The CLI prints what it returns; any
//! other caller (a service, a test) gets the same typed outcome without spawning the binary.

use std::path::{Path, PathBuf};
use std::time::Instant;

use nalgebra::Isometry3;

use crate::backend::{open_renderer, Backend};
use crate::config::{RendererChoice, SegmenterConfig};
use crate::consensus::{find_consensus, ConsensusOptions};
use crate::error::{Error, Result};
use crate::explore::{solve_selected, ExploreOptions, Selection, StopRule};
use crate::geometry::{from_rows, rotation_error_deg, translation_error_mm};
use crate::init::{initialise, InitOptions};
use crate::overlay::write_overlay;
use crate::pipeline::segment_solve::POOR_FIT_IOU;
use crate::render::PosedRobot;
use crate::run::rig::{write_result, JointCorrections, RigGroundTruth, RunLayout, RunSummary};
use crate::run::{
    load_run_with, GroundTruth, LoadedRun, MaskSource, PerView, ResultFile, UncertaintyEntry,
};
use crate::solve::{
    mount_contact_disagrees, solve_with_shared_joints, with_view_disagreement, CameraSolve,
    MountContact, Optimizer, SolveOptions, SolveReport, View,
};

mod segment;

use segment::{segment_run, SegmentedViews};

/// What to solve and how (`easyhec solve`'s flags).
#[derive(Clone, Debug)]
pub struct OfflineSolve {
    /// Run directory (or its `run.json`).
    pub run: PathBuf,
    /// Views to use (default: all).
    pub views: Option<usize>,
    /// How views are chosen.
    pub selection: Selection,
    /// Seed of the selection's candidates.
    pub seed: u64,
    /// The optimiser.
    pub optimizer: Optimizer,
    /// Result path (default `RUN/result.json`).
    pub out: Option<PathBuf>,
    /// A pose file to start from instead of the run's `initial_guess` (one camera only).
    pub initial_guess: Option<PathBuf>,
    /// Folder for one agreement overlay per view.
    pub overlays: Option<PathBuf>,
    /// Renderer backend.
    pub renderer: RendererChoice,
    /// Keep views that fit no pose the others agree on.
    pub keep_all_views: bool,
    /// Segment views without masks with this segmenter.
    pub segmenter: Option<SegmenterConfig>,
    /// The file the segmenter's table came from, when it came from one: its model paths are
    /// relative to it and its errors name it (otherwise the run's `run.json`).
    pub segmenter_file: Option<PathBuf>,
    /// With a segmenter: segment every view's image, ignoring recorded masks.
    pub ignore_masks: bool,
    /// With a segmenter: where to write the masks it made.
    pub masks_out: Option<PathBuf>,
    /// Write the result even when the fit is poor ([`judge_fit`]).
    pub allow_poor_fit: bool,
    /// 1-sigma error of each recorded joint, radians, for the reported covariance.
    pub joint_noise_rad: f64,
    /// Model-error floor (rotation degrees, translation millimetres, 1 sigma per camera
    /// axis) added to the reported covariance.
    pub model_floor: (f64, f64),
    /// Estimate the masks' outline offset with the pose ([`SolveOptions::estimate_mask_offset`]).
    pub estimate_mask_offset: bool,
    /// How every fit treats the robot's mount contact ([`SolveOptions::mount_contact`]).
    pub mount_contact: MountContact,
}

/// What an offline solve produced: every camera's solve, in the run's order (one for an
/// `easyhec-run/1` run).
#[derive(Clone, Debug)]
pub struct OfflineOutcome {
    /// How the run recorded its cameras, and so which result format was written.
    pub layout: RunLayout,
    /// Where the result was written.
    pub out: PathBuf,
    /// Every camera's solve.
    pub cameras: Vec<CameraSolved>,
}

impl OfflineOutcome {
    /// The solve of a run of one camera (the first of a list).
    pub fn first(&self) -> &CameraSolved {
        &self.cameras[0]
    }
}

/// One camera's solve.
#[derive(Clone, Debug)]
pub struct CameraSolved {
    /// The camera's name (`camera` for an `easyhec-run/1` run).
    pub name: String,
    /// The transform solved: `camera_from_base`, or `camera_from_<link>`.
    pub transform: String,
    /// Its `easyhec-result/1` record (an `easyhec-result/2` file holds one per camera).
    pub result: ResultFile,
    /// On a simulated run, the error against its `ground_truth.json`: (file, degrees, mm).
    pub truth_error: Option<(PathBuf, f64, f64)>,
    /// Its final solve.
    pub report: SolveReport,
    /// Views its result rests on.
    pub views: usize,
    /// Seconds of solving.
    pub solve_s: f64,
    /// Views that fit poorly (IoU < 0.8): the uncertainty does not cover a wrong model.
    pub poor_views: Vec<usize>,
}

/// Solves every camera of a recorded run (`easyhec-run/1` or `/2`): each as one camera's
/// run is solved; with several, each view's joints corrected from all cameras together and
/// every camera re-solved, as the calibration loop does. `note` receives the one-line remarks
/// a user should see as they happen (segmentation rounds, automatic initialisation, views
/// left out). Masks and overlays of a list go to a folder per camera (`DIR/<name>/`); the
/// result is written only when every camera's solve passes.
pub fn solve_run(req: &OfflineSolve, note: &mut dyn FnMut(&str)) -> Result<OfflineOutcome> {
    let started = Instant::now();
    let layout = RunLayout::of(&req.run)?;
    let named = layout == RunLayout::NamedCameras;
    let cameras = load_cameras(req, named)?;
    let mut reads: Vec<PathBuf> = cameras.iter().flat_map(|c| c.run.files_read()).collect();
    reads.extend(req.initial_guess.clone());
    check_outputs(req, &reads)?;
    let renderer =
        open_renderer(req.renderer, false).map_err(|e| Error::Usage(format!("--renderer: {e}")))?;
    let per_camera = |dir: &Option<PathBuf>, name: &str| {
        dir.as_ref()
            .map(|d| if named { d.join(name) } else { d.clone() })
    };
    let mut fitted = Vec::with_capacity(cameras.len());
    for LoadedCamera {
        name,
        run,
        views: k,
    } in cameras
    {
        let masks_out = per_camera(&req.masks_out, &name);
        let mut camera_note = |line: &str| {
            if named {
                note(&format!("{name}: {line}"))
            } else {
                note(line)
            }
        };
        let fit = fit_loaded(
            req,
            run,
            k,
            renderer.as_ref(),
            masks_out.as_deref(),
            &mut camera_note,
        )
        .map_err(|e| if named { in_camera(&name, e) } else { e })?;
        fitted.push((name, fit));
    }
    let joint_corrections = correct_shared_joints(req, renderer.as_ref(), &mut fitted, note);
    let mut solved_cameras = Vec::with_capacity(fitted.len());
    for (name, fit) in fitted {
        let overlays = per_camera(&req.overlays, &name);
        let solved = finish_fit(req, fit, renderer.as_ref(), overlays.as_deref(), started)?;
        solved_cameras.push(CameraSolved {
            truth_error: truth_error(layout, &solved.run_dir, &name, &solved),
            transform: solved.transform,
            name,
            views: solved.order.len(),
            poor_views: poor_views(&solved.order, &solved.report),
            solve_s: solved.solve_s,
            report: solved.report,
            result: solved.result,
        });
    }
    let run_dir = crate::run::run_paths(&req.run).1;
    let out = req
        .out
        .clone()
        .unwrap_or_else(|| run_dir.join("result.json"));
    let results: Vec<(&str, &ResultFile)> = solved_cameras
        .iter()
        .map(|c| (c.name.as_str(), &c.result))
        .collect();
    let mut timings_s = std::collections::BTreeMap::new();
    timings_s.insert("total".to_string(), started.elapsed().as_secs_f64());
    let summary = RunSummary {
        stop_reason: "solved every camera".into(),
        timings_s,
        joint_corrections,
    };
    write_result(layout, &out, &results, summary)?;
    Ok(OfflineOutcome {
        layout,
        out,
        cameras: solved_cameras,
    })
}

/// Every camera's loaded run and `--views` count, as the request reads them (recorded masks,
/// or images for a segmenter; a run of one camera from `--initial-guess` when given), before
/// any renderer is opened.
fn load_cameras(req: &OfflineSolve, named: bool) -> Result<Vec<LoadedCamera>> {
    if !named {
        let (run, views) = load_requested(req)?;
        let name = crate::config::cameras::SINGLE_CAMERA_NAME.to_string();
        return Ok(vec![LoadedCamera { name, run, views }]);
    }
    if req.initial_guess.is_some() {
        return Err(Error::Usage(
            "--initial-guess: a run of several cameras starts each camera from its own initial_guess in run.json; the flag is for a run of one camera".into(),
        ));
    }
    crate::run::load_cameras_with(&req.run, mask_source(req))?
        .into_iter()
        .map(|(name, run)| {
            let views = requested_views(req, run.views.len())?;
            Ok(LoadedCamera { name, run, views })
        })
        .collect()
}

/// One camera's loaded run and how many of its views the request uses.
struct LoadedCamera {
    name: String,
    run: LoadedRun,
    views: usize,
}

/// A solve error names the camera of a list it happened in.
fn in_camera(name: &str, e: Error) -> Error {
    match e {
        Error::Solve(m) => Error::Solve(format!("camera '{name}': {m}")),
        other => other,
    }
}

/// Every camera of a list saw the same views from the same arm, so each view's joint
/// correction is estimated from all of them together and every camera re-solved with it, as
/// the calibration loop does (docs/cameras.md, "Shared joint correction"); returns the
/// corrections. Skipped, with a note, when the cameras' solves rest on different views.
fn correct_shared_joints(
    req: &OfflineSolve,
    renderer: &dyn Backend,
    fitted: &mut [(String, Fitted)],
    note: &mut dyn FnMut(&str),
) -> Option<JointCorrections> {
    if fitted.len() < 2 || req.joint_noise_rad <= 0.0 {
        return None;
    }
    let order = fitted[0].1.order.clone();
    if fitted.iter().any(|(_, f)| f.order != order) {
        note("the cameras' solves rest on different views; each camera keeps its own solve, without the shared joint correction");
        return None;
    }
    let t = Instant::now();
    let used: Vec<Vec<View>> = fitted
        .iter()
        .map(|(_, f)| order.iter().map(|&i| f.pool[i].clone()).collect())
        .collect();
    let joints: Vec<Vec<f64>> = order
        .iter()
        .map(|&i| fitted[0].1.run.views[i].joints.clone())
        .collect();
    let cameras = fitted
        .iter()
        .zip(&used)
        .map(|((name, f), views)| CameraSolve {
            name,
            seen: &f.run.robot,
            camera: &f.run.camera,
            views,
            report: f.report.clone(),
        })
        .collect();
    let shared = solve_with_shared_joints(renderer, cameras, &joints, &solve_options(req));
    // Each camera's timings carry its share of the joint solve.
    let seconds = t.elapsed().as_secs_f64() / fitted.len() as f64;
    let mut below_poor_fit = Vec::new();
    for ((name, f), report) in fitted.iter_mut().zip(&shared.reports) {
        // The loop's keep rule allows a small drop in fit; never below the poor-fit line.
        if report.mean_iou() >= POOR_FIT_IOU || req.allow_poor_fit {
            f.report = report.clone();
        } else {
            below_poor_fit.push(name.clone());
        }
        f.timings.solve_s += seconds;
    }
    note(&shared.summary(&below_poor_fit));
    let corrections = JointCorrections {
        views: order,
        per_view_rad: shared.corrections,
    };
    corrections.is_finite().then_some(corrections)
}

/// One camera's judged solve, before its overlays and result.
struct Fitted {
    run: LoadedRun,
    /// Views whose masks a segmenter drew (indices into `run.views`).
    segmented: Vec<usize>,
    pool: Vec<View>,
    order: Vec<usize>,
    report: SolveReport,
    stop_reason: String,
    timings: Timings,
}

/// The options of every solve of the request.
fn solve_options(req: &OfflineSolve) -> SolveOptions {
    SolveOptions {
        optimizer: req.optimizer,
        joint_noise_rad: req.joint_noise_rad,
        floor_rotation_deg: req.model_floor.0,
        floor_translation_mm: req.model_floor.1,
        estimate_mask_offset: req.estimate_mask_offset,
        ..starting_options(req)
    }
}

/// The options of the solves that find a starting pose or draw masks: the defaults, with
/// what the request leaves out of every fit.
fn starting_options(req: &OfflineSolve) -> SolveOptions {
    SolveOptions {
        mount_contact: req.mount_contact,
        ..SolveOptions::default()
    }
}

/// What `easyhec solve` says when given masks disagree with the render at the mount contact.
pub const MOUNT_CONTACT_DISAGREES: &str = "the masks' outline where the robot stands on its mount lies more than 2 px from the rendered robot's, beyond the rest of the outline, in most views: a flange or plate that the masks and the mesh disagree on; --mount-contact leave-out (or [calibration] mount_contact = \"leave-out\") leaves it out of the fit (docs/method.md §6)";

/// One camera's judged solve, not yet written.
struct Solved {
    result: ResultFile,
    report: SolveReport,
    order: Vec<usize>,
    run_dir: PathBuf,
    transform: String,
    solve_s: f64,
}

/// Segments, initialises, selects and judges one camera's loaded run; `masks_out` is where
/// the masks a segmenter made go.
fn fit_loaded(
    req: &OfflineSolve,
    mut run: LoadedRun,
    k: usize,
    renderer: &dyn Backend,
    masks_out: Option<&Path>,
    note: &mut dyn FnMut(&str),
) -> Result<Fitted> {
    let mut timings = Timings::default();
    let mut settled = None;
    let segmented: Vec<usize> = match &req.segmenter {
        Some(_) => (0..run.views.len())
            .filter(|&i| run.views[i].needs_mask)
            .collect(),
        None => Vec::new(),
    };
    // Masks the run gives are the user's: `auto` fits their mount contact and says when it
    // disagrees with the render, rather than deciding for them.
    let asked = req.mount_contact;
    let given = &OfflineSolve {
        mount_contact: asked.for_given_masks(),
        ..req.clone()
    };
    let req = if segmented.is_empty() { given } else { req };
    if let Some(config) = &req.segmenter {
        let t = Instant::now();
        let opts = starting_options(req);
        let config_path = req
            .segmenter_file
            .clone()
            .unwrap_or_else(|| run.dir.join("run.json"));
        let segmenter = crate::segment::build(config, &config_path)?;
        settled = segment_run(
            &mut run,
            config,
            segmenter.as_ref(),
            &opts,
            renderer,
            masks_out,
            note,
        )?;
        timings.segment_s = Some(t.elapsed().as_secs_f64());
    }
    // The rounds' decision on the mount contact stands for the solve of their masks.
    let kept = &OfflineSolve {
        mount_contact: MountContact::LeaveOut,
        ..req.clone()
    };
    let req = match &settled {
        Some(s) if s.mount_contact_left_out && asked == MountContact::Auto => kept,
        _ => req,
    };
    let settled = settled.map(|s| s.camera_from_base);
    // The pool: every recorded view (views beyond K are only candidates for explore/random).
    let pool_size = if req.selection == Selection::First {
        k
    } else {
        run.views.len()
    };
    let pool: Vec<View> = run.views[..pool_size]
        .iter()
        .map(|v| View {
            robot: PosedRobot::new(&run.robot, &v.joints),
            observed: v.observed.clone(),
        })
        .collect();
    let initial = match settled.or(run.initial_guess) {
        Some(start) => start,
        None => auto_initial(renderer, &run, &pool, &starting_options(req), note)?,
    };
    let solve_opts = solve_options(req);
    let explore_opts = ExploreOptions {
        seed: req.seed,
        ..ExploreOptions::default()
    };
    let selected = solve_selected(
        renderer,
        &run.camera,
        &pool,
        &initial,
        k,
        req.selection,
        &solve_opts,
        &explore_opts,
        &StopRule::default(),
    )?;
    (timings.solve_s, timings.explore_s) = (selected.solve_s, selected.explore_s);
    let (order, report, stop_reason) = if req.keep_all_views {
        (selected.order, selected.report, selected.stop_reason)
    } else {
        consistent_views(renderer, &run, &pool, selected, &solve_opts, note)?
    };
    check_finite(&report)?;
    if !req.allow_poor_fit {
        judge_fit(&order, &report, k)?;
    }
    if segmented.is_empty() && asked == MountContact::Auto {
        let used: Vec<View> = order.iter().map(|&i| pool[i].clone()).collect();
        let camera = run.camera.undistorted();
        let pose = &report.camera_from_base;
        if mount_contact_disagrees(renderer, &camera, &used, pose, &solve_opts) {
            note(MOUNT_CONTACT_DISAGREES);
        }
    }

    Ok(Fitted {
        run,
        segmented,
        pool,
        order,
        report,
        stop_reason,
        timings,
    })
}

/// Writes one judged solve's overlays (into `overlays`) and describes it as a result.
fn finish_fit(
    req: &OfflineSolve,
    fitted: Fitted,
    renderer: &dyn Backend,
    overlays: Option<&Path>,
    started: Instant,
) -> Result<Solved> {
    let Fitted {
        run,
        segmented,
        pool,
        order,
        report,
        stop_reason,
        mut timings,
    } = fitted;
    // The reported covariance also holds what the views' disagreement shows.
    let t = Instant::now();
    let used: Vec<View> = order.iter().map(|&i| pool[i].clone()).collect();
    let report = with_view_disagreement(renderer, &run.camera, &used, report, &solve_options(req));
    // And, for masks a segmenter drew, what its undecided pixels could move the pose by.
    let report = match &req.segmenter {
        Some(config) => {
            let drawn = SegmentedViews {
                run: &run,
                order: &order,
                segmented: &segmented,
            };
            drawn.with_segmentation_term(config, renderer, &used, report, &solve_options(req))
        }
        None => report,
    };
    timings.solve_s += t.elapsed().as_secs_f64();
    if let Some(dir) = overlays {
        write_overlays(renderer, &run, &pool, &order, &report, dir)?;
    }
    timings.total_s = started.elapsed().as_secs_f64();
    let result = result_file(req, &run, &order, &report, stop_reason, &timings);
    Ok(Solved {
        transform: run.file.camera.mount.transform_name(),
        solve_s: timings.solve_s,
        run_dir: run.dir,
        result,
        report,
        order,
    })
}

/// Where the request takes masks from.
fn mask_source(req: &OfflineSolve) -> MaskSource {
    match (&req.segmenter, req.ignore_masks) {
        (None, _) => MaskSource::Recorded,
        (Some(_), true) => MaskSource::Image,
        (Some(_), false) => MaskSource::RecordedElseImage,
    }
}

/// `--views` against a run of `total` views.
fn requested_views(req: &OfflineSolve, total: usize) -> Result<usize> {
    let k = req.views.unwrap_or(total);
    if k == 0 || k > total {
        return Err(Error::Usage(format!(
            "--views {k}: the run has {total} views"
        )));
    }
    Ok(k)
}

/// The solve's outputs against the output policy ([`crate::io::output_file_problem`]),
/// before anything is computed: the result file and the masks and overlays folders must be
/// none of the files the solve reads, nor hold them.
fn check_outputs(req: &OfflineSolve, reads: &[PathBuf]) -> Result<()> {
    if let Some(out) = &req.out {
        if let Some(problem) = crate::io::output_file_problem(out, reads) {
            return Err(Error::input(out, "--out", problem));
        }
    }
    let folders = [
        ("--masks-out", &req.masks_out),
        ("--overlays", &req.overlays),
    ];
    for (flag, dir) in folders {
        let Some(dir) = dir else { continue };
        if let Some(problem) = crate::io::output_dir_problem(dir, reads) {
            return Err(Error::input(dir, flag, problem));
        }
    }
    Ok(())
}

/// Loads the run the way the request reads it (recorded masks, or images for a segmenter;
/// from `--initial-guess` when given) and checks `--views` against it, before any renderer is
/// opened.
fn load_requested(req: &OfflineSolve) -> Result<(LoadedRun, usize)> {
    let run = match &req.initial_guess {
        Some(guess) => crate::run::load_run_with_guess(&req.run, mask_source(req), guess)?,
        None => load_run_with(&req.run, mask_source(req))?,
    };
    let k = requested_views(req, run.views.len())?;
    Ok((run, k))
}

/// Seconds spent in each phase, as `result.json` records them.
#[derive(Default)]
struct Timings {
    segment_s: Option<f64>,
    solve_s: f64,
    explore_s: f64,
    total_s: f64,
}

/// A diverged solve is an error, never a result.
fn check_finite(report: &SolveReport) -> Result<()> {
    let matrix = report.camera_from_base.to_homogeneous();
    if matrix.iter().all(|v| v.is_finite()) {
        return Ok(());
    }
    Err(Error::Solve(
        "the solve diverged (non-finite pose): check the initial guess and the masks".into(),
    ))
}

/// The `easyhec-result/1` record of a judged solve.
fn result_file(
    req: &OfflineSolve,
    run: &LoadedRun,
    order: &[usize],
    report: &SolveReport,
    stop_reason: String,
    timings: &Timings,
) -> ResultFile {
    let mut result = ResultFile::new(&report.camera_from_base, &run.robot.links[run.robot.base]);
    result.views_used = order.to_vec();
    result.per_view = order
        .iter()
        .zip(&report.per_view_iou)
        .map(|(&v, &iou)| PerView { view: v, iou })
        .collect();
    result.uncertainty = UncertaintyEntry::of_report(report, &solve_options(req));
    result.mount_contact_left_out = report.mount_contact_left_out;
    result.stop_reason = match req.optimizer {
        Optimizer::Lm => stop_reason,
        Optimizer::Adam => format!(
            "{}; adam: {} steps, best iterate",
            stop_reason, report.iterations
        ),
    };
    let t = &mut result.timings_s;
    t.insert("solve".into(), timings.solve_s);
    if let Some(s) = timings.segment_s {
        t.insert("segment".into(), s);
    }
    if req.selection == Selection::Explore {
        t.insert("explore".into(), timings.explore_s);
    }
    t.insert("total".into(), timings.total_s);
    result
}

/// Views whose IoU is under the poor-fit line, for the warning an allowed poor fit prints.
fn poor_views(order: &[usize], report: &SolveReport) -> Vec<usize> {
    order
        .iter()
        .zip(&report.per_view_iou)
        .filter(|(_, &iou)| iou < POOR_FIT_IOU)
        .map(|(&v, _)| v)
        .collect()
}

/// Refuses a fit that no one should use, before anything is written: a mean IoU under
/// [`POOR_FIT_IOU`] means the rendered robot does not match the masks (wrong joints, intrinsics
/// or URDF), and a consensus that leaves fewer than two of several views means the views
/// contradict each other. In both cases the covariance describes a wrong model and would
/// still look tight, so the solve fails unless `--allow-poor-fit` is given.
pub fn judge_fit(order: &[usize], report: &SolveReport, solved: usize) -> Result<()> {
    let mean = report.mean_iou();
    if mean.is_nan() || mean < POOR_FIT_IOU {
        return Err(Error::Solve(format!(
            "poor fit: mean IoU {mean:.3} over views {order:?} is below {POOR_FIT_IOU}; no result written (check joints, intrinsics and URDF against the masks, or pass --allow-poor-fit)"
        )));
    }
    if solved >= 2 && order.len() < 2 {
        return Err(Error::Solve(format!(
            "poor fit: the views contradict each other and only view {order:?} of {solved} is left; no result written (check joint-read timing, or pass --allow-poor-fit)"
        )));
    }
    Ok(())
}

/// No guess: search for one (docs/method.md §6) over the first views.
fn auto_initial(
    renderer: &dyn Backend,
    run: &LoadedRun,
    pool: &[View],
    opts: &SolveOptions,
    note: &mut dyn FnMut(&str),
) -> Result<Isometry3<f64>> {
    let first = &pool[..pool.len().min(3)];
    let found =
        initialise(renderer, &run.camera, first, opts, &InitOptions::default()).map_err(|e| {
            Error::Solve(format!(
                "{}: initial_guess is absent: {e}",
                run.dir.join("run.json").display()
            ))
        })?;
    note(&format!(
        "no initial_guess: automatic initialisation found a pose with mean IoU {:.3} over {} views",
        found.mean_iou(),
        first.len()
    ));
    Ok(found.camera_from_base)
}

/// Leaves out the selected views that fit no pose the others agree on (their joints do not
/// describe their images), re-solving from the rest.
fn consistent_views(
    renderer: &dyn Backend,
    run: &LoadedRun,
    pool: &[View],
    selected: crate::explore::Selected,
    solve_opts: &SolveOptions,
    note: &mut dyn FnMut(&str),
) -> Result<(Vec<usize>, SolveReport, String)> {
    let order = selected.order;
    let used: Vec<View> = order.iter().map(|&i| pool[i].clone()).collect();
    let Some(c) = find_consensus(
        renderer,
        &run.camera,
        &used,
        &selected.report,
        solve_opts,
        &ConsensusOptions::default(),
    )?
    else {
        return Ok((order, selected.report, selected.stop_reason));
    };
    let rejected: Vec<String> = c
        .rejected
        .iter()
        .map(|&(i, iou)| format!("{} (IoU {iou:.2})", order[i]))
        .collect();
    let kept: Vec<usize> = c.kept.iter().map(|&i| order[i]).collect();
    note(&format!(
        "warning: views {} fit no pose the other views agree on and are left out (their joints do not describe their images: check joint-read timing); the result uses views {kept:?} (--keep-all-views keeps them)",
        rejected.join(", ")
    ));
    let stop_reason = format!(
        "{}; left out {} inconsistent views",
        selected.stop_reason,
        c.rejected.len()
    );
    Ok((kept, c.report, stop_reason))
}

/// One agreement overlay PNG per used view (the colour image underneath when undistorted).
fn write_overlays(
    renderer: &dyn Backend,
    run: &LoadedRun,
    pool: &[View],
    order: &[usize],
    report: &SolveReport,
    dir: &Path,
) -> Result<()> {
    let pinhole = run.camera.undistorted();
    for &i in order {
        let view = &pool[i];
        let rendered = renderer
            .render(&view.robot, &pinhole, &report.camera_from_base, None)
            .mask;
        let image = run.views[i]
            .image
            .as_deref()
            .filter(|_| !run.camera.is_distorted());
        write_overlay(
            &dir.join(format!("{i:03}.overlay.png")),
            &rendered,
            &view.observed,
            image,
        )?;
    }
    Ok(())
}

/// Synthetic runs carry their truth beside run.json, in the run's layout (`easyhec-truth/1`
/// for one camera, `/2` by camera name): the error of camera `name`'s solve against it.
fn truth_error(
    layout: RunLayout,
    dir: &Path,
    name: &str,
    solved: &Solved,
) -> Option<(PathBuf, f64, f64)> {
    let path = dir.join("ground_truth.json");
    let estimate = &solved.report.camera_from_base;
    let truth = match layout {
        RunLayout::NamedCameras => {
            RigGroundTruth::read(&path)?.camera_from_mount(name, &solved.transform)?
        }
        RunLayout::OneCamera => {
            let text = crate::io::read_text_input(&path).ok()?;
            let truth: GroundTruth = serde_json::from_str(&text).ok()?;
            from_rows(&truth.camera_from_base).ok()?
        }
    };
    Some((
        path,
        rotation_error_deg(estimate, &truth),
        translation_error_mm(estimate, &truth),
    ))
}

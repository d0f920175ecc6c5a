//! The `easyhec` command line.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{anyhow, bail, Context};
use clap::{Args, Parser, Subcommand};

use easyhec::backend::open_renderer;
use easyhec::bench;
use easyhec::config::NoiseModel;
use easyhec::config::RendererChoice;
use easyhec::config::{ScenePreset, SceneSettings};
use easyhec::consensus::{find_consensus, ConsensusOptions};
use easyhec::explore::{solve_selected, ExploreOptions, Selection, StopRule};
use easyhec::init::{initialise, InitOptions};
use easyhec::interop::{export, import_easyhec, EasyHecImport, ExportFormat};
use easyhec::overlay::write_overlay;
use easyhec::render::{CpuRenderer, PosedRobot};
use easyhec::robot::{RobotModel, RobotSource};
use easyhec::run::{
    load_run, load_run_with, MaskSource, PerView, ResultFile, RobotEntry, UncertaintyEntry,
};
use easyhec::solve::{solve, Optimizer, SolveOptions, View};
use easyhec::synth::{
    generate, generate_frames, write_imaged_scene, write_scene, SynthOptions, Truncation,
};

#[derive(Parser)]
#[command(
    name = "easyhec",
    version,
    about = "Markerless eye-to-hand camera calibration by silhouette alignment"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the whole calibration loop on a configured cell (move, capture, solve, explore).
    Calibrate(CalibrateArgs),
    /// Solve camera_from_base from a recorded run directory (easyhec-run/1).
    Solve(SolveArgs),
    /// Write a synthetic run directory with a separate ground-truth file.
    Synth(SynthArgs),
    /// Convert another tool's recordings into a run directory.
    #[command(subcommand)]
    Import(ImportCommand),
    /// Write a result in the form another tool reads.
    Export(ExportArgs),
    /// Benchmarks (figures for the README).
    #[command(subcommand)]
    Bench(BenchCommand),
    /// Serve calibrations of a cell over HTTP (API, web page, bump checks) until stopped.
    Daemon(DaemonArgs),
}

#[derive(Args)]
struct DaemonArgs {
    /// Cell config (TOML) with an optional [daemon] table.
    #[arg(long)]
    config: PathBuf,
    /// HOST:PORT to listen on (default: [daemon] listen, else 127.0.0.1:8787; port 0 picks
    /// a free one).
    #[arg(long)]
    listen: Option<String>,
    /// Data folder (default: [daemon] data_dir relative to the config).
    #[arg(long)]
    data: Option<PathBuf>,
}

#[derive(Args)]
struct SolveArgs {
    /// Run directory (or its run.json).
    run: PathBuf,
    /// Number of views to use (default: all).
    #[arg(long)]
    views: Option<usize>,
    /// How views are chosen: first (0..K-1); explore (view 0, then the view where the
    /// camera hypotheses disagree most, re-solving each round); random (like explore, random).
    #[arg(long, default_value = "first")]
    select: String,
    /// Seed for --select random.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Result path (default RUN/result.json).
    #[arg(long)]
    out: Option<PathBuf>,
    /// lm (default) or adam (the paper's baseline).
    #[arg(long, default_value = "lm")]
    optimizer: String,
    /// Write one agreement overlay PNG per view into this folder.
    #[arg(long)]
    overlays: Option<PathBuf>,
    /// Renderer: cpu, wgpu (any adapter) or auto (wgpu on a hardware GPU, else cpu).
    #[arg(long, default_value = "auto")]
    renderer: RendererChoice,
    /// Keep every view even when some do not fit any pose the others agree on (by default
    /// such views are left out of the result and named on stderr).
    #[arg(long)]
    keep_all_views: bool,
    /// Segment views that have an image but no mask with this segmenter (builtin), in
    /// segment → solve → re-segment rounds.
    #[arg(long)]
    segmenter: Option<String>,
    /// With --segmenter: segment every view's image, ignoring recorded masks.
    #[arg(long, requires = "segmenter")]
    ignore_masks: bool,
    /// With --segmenter: write the masks it made into this folder (NNN.mask.png).
    #[arg(long, requires = "segmenter")]
    masks_out: Option<PathBuf>,
}

#[derive(Args)]
struct CalibrateArgs {
    /// Cell config (TOML), e.g. config/sim-xarm6.toml.
    #[arg(long)]
    config: PathBuf,
    /// Run directory to record into (default: runs/<UTC time>).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Plan and print the poses with their checks; never move.
    #[arg(long)]
    dry_run: bool,
    /// Ask before each move.
    #[arg(long)]
    confirm: bool,
    /// No progress bars.
    #[arg(long)]
    quiet: bool,
    /// Renderer: cpu, wgpu or auto (overrides `[calibration] renderer`).
    #[arg(long)]
    renderer: Option<RendererChoice>,
}

#[derive(Args)]
struct SynthArgs {
    /// Robot URDF.
    #[arg(long)]
    robot: PathBuf,
    /// Output run directory.
    #[arg(long)]
    out: PathBuf,
    /// Number of views.
    #[arg(long, default_value_t = 5)]
    views: usize,
    /// RNG seed.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Image width.
    #[arg(long, default_value_t = 640)]
    width: u32,
    /// Image height.
    #[arg(long, default_value_t = 480)]
    height: u32,
    /// Focal length, pixels.
    #[arg(long, default_value_t = 600.0)]
    focal: f64,
    /// Noise-free masks and joints.
    #[arg(long)]
    no_noise: bool,
    /// plumb_bob coefficients k1,k2,p1,p2,k3.
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    distortion: Option<Vec<f64>>,
    /// Links not rendered (and not in the masks).
    #[arg(long, value_delimiter = ',')]
    ignore_links: Vec<String>,
    /// Write no initial guess.
    #[arg(long)]
    no_initial_guess: bool,
    /// Also write colour frames (views/NNN.png): `easy` (the plain simulated scene) or `hard`
    /// (clutter, a light robot on light walls, shadows, exposure changes, moving boxes).
    #[arg(long)]
    images: Option<ScenePreset>,
    /// Aim the camera so part of the robot leaves the image in every view (55–93% inside).
    #[arg(long)]
    truncate: bool,
}

#[derive(Subcommand)]
enum ImportCommand {
    /// EasyHeC's offline folder: color/ mask/ qpos/ K.txt [initial_guess.txt].
    Easyhec {
        /// Source folder.
        dir: PathBuf,
        /// Output run directory.
        #[arg(long)]
        out: PathBuf,
        /// Robot URDF.
        #[arg(long)]
        urdf: PathBuf,
        /// Actuated joints in qpos order (default: the URDF's movable, non-mimic joints).
        #[arg(long, value_delimiter = ',')]
        joints: Option<Vec<String>>,
        /// Links the masks leave out (e.g. fingers).
        #[arg(long, value_delimiter = ',')]
        ignore_links: Vec<String>,
    },
}

#[derive(Args)]
struct ExportArgs {
    /// easyhec-result/1 file.
    result: PathBuf,
    /// opencv | ros | easy-handeye | urdf
    #[arg(long)]
    format: String,
    /// Name of the camera optical frame in ROS/URDF forms.
    #[arg(long, default_value = "camera_color_optical_frame")]
    camera_frame: String,
    /// Output file (default: standard output).
    #[arg(long)]
    out: Option<PathBuf>,
}

#[derive(Subcommand)]
enum BenchCommand {
    /// Median pose error over seeded synthetic scenes, views 1..K, LM and/or Adam.
    Accuracy {
        /// Robot URDF.
        #[arg(long, default_value = "../shared/robots/xarm6/robot.urdf")]
        robot: PathBuf,
        /// Number of scenes (seeds 0..N-1).
        #[arg(long, default_value_t = 20)]
        scenes: u64,
        /// View counts to evaluate.
        #[arg(long, value_delimiter = ',', default_value = "1,2,3,4,5")]
        views: Vec<usize>,
        /// Optimisers to run.
        #[arg(long, value_delimiter = ',', default_value = "lm")]
        optimizers: Vec<String>,
    },
    /// Automatic initialisation (no guess): success rate, errors and time over seeded cells
    /// with the camera anywhere on a hemisphere around the robot.
    Init {
        /// Robot URDF.
        #[arg(long, default_value = "../shared/robots/xarm6/robot.urdf")]
        robot: PathBuf,
        /// Number of cells (seeds 0..N-1).
        #[arg(long, default_value_t = 40)]
        scenes: u64,
        /// Views per cell.
        #[arg(long, default_value_t = 3)]
        views: usize,
        /// Camera distance range, metres.
        #[arg(long, value_delimiter = ',', default_value = "0.6,2.5")]
        distance: Vec<f64>,
    },
    /// Closed loop on seeded simulated cells: exploration vs random pose selection (median
    /// error after each view), planning time per round and compute per calibration.
    Loop {
        /// Base cell config (seeded variants move the camera, start pose and guess).
        #[arg(long, default_value = "config/sim-xarm6.toml")]
        config: PathBuf,
        /// Number of cells (seeds FIRST..FIRST+N-1).
        #[arg(long, default_value_t = 20)]
        cells: u64,
        /// First cell seed (a seed set the settings were not chosen on).
        #[arg(long, default_value_t = 0)]
        first_seed: u64,
        /// Views per calibration (no early stop).
        #[arg(long, default_value_t = 5)]
        views: usize,
        /// Hill-climbing steps per start (`[calibration] climb_steps`; default: the config's).
        #[arg(long)]
        climb_steps: Option<usize>,
        /// Selections to run.
        #[arg(long, value_delimiter = ',', default_value = "explore,random")]
        selections: Vec<String>,
        /// Renderer: cpu, wgpu or auto.
        #[arg(long, default_value = "auto")]
        renderer: RendererChoice,
        /// Exploration score: information (default) or variance (the paper's).
        #[arg(long)]
        score: Option<String>,
    },
    /// How far 3-view selection can go: per seeded cell, the loop's explored pair and random
    /// pairs, each solved many times with fresh noise, against the selection score's
    /// prediction (README: closed loop).
    ViewSets {
        /// Base cell config (seeded variants move the camera, start pose and guess).
        #[arg(long, default_value = "config/sim-xarm6.toml")]
        config: PathBuf,
        /// Number of cells (seeds FIRST..FIRST+N-1).
        #[arg(long, default_value_t = 12)]
        cells: u64,
        /// First cell seed.
        #[arg(long, default_value_t = 0)]
        first_seed: u64,
        /// Random pairs per cell.
        #[arg(long, default_value_t = 12)]
        random_pairs: usize,
        /// Noisy solves per set.
        #[arg(long, default_value_t = 10)]
        trials: usize,
    },
    /// The builtin segmenter: mask IoU and RGB-only calibration error on seeded simulated
    /// cells, and (with --run) its figures on a recorded run whose masks are the reference.
    Segment {
        /// Base cell config (seeded variants move the camera, start pose and guess).
        #[arg(long, default_value = "config/sim-xarm6.toml")]
        config: PathBuf,
        /// Number of simulated cells (seeds 0..N-1; 0 skips them).
        #[arg(long, default_value_t = 20)]
        scenes: u64,
        /// Views per calibration (no early stop).
        #[arg(long, default_value_t = 5)]
        views: usize,
        /// A run directory with images, masks and an initial guess (e.g. the imported Panda
        /// example): its masks are withheld from the segmenter and used as the reference.
        #[arg(long)]
        run: Option<PathBuf>,
        /// Frame dressing of the simulated cells: hard (clutter, light robot on light walls,
        /// shadows, exposure changes, moving boxes) or easy.
        #[arg(long, default_value = "hard")]
        frames: String,
        /// Renderer: cpu, wgpu or auto.
        #[arg(long, default_value = "auto")]
        renderer: RendererChoice,
    },
    /// One exploration round on the renderer: N joint samples x K camera candidates scored by
    /// silhouette variance (method.md §5), with its posing/decimation time separate.
    Explore {
        /// Robot URDF.
        #[arg(long, default_value = "../shared/robots/xarm6/robot.urdf")]
        robot: PathBuf,
        /// Joint samples.
        #[arg(long, default_value_t = 2000)]
        samples: usize,
        /// Camera candidates.
        #[arg(long, default_value_t = 50)]
        candidates: usize,
        /// Image width (scored at 1/4).
        #[arg(long, default_value_t = 640)]
        width: u32,
        /// Image height.
        #[arg(long, default_value_t = 480)]
        height: u32,
        /// Rounds timed.
        #[arg(long, default_value_t = 5)]
        rounds: usize,
        /// Renderer: cpu, wgpu or auto.
        #[arg(long, default_value = "auto")]
        renderer: RendererChoice,
    },
    /// Wall time of K-view solves, and peak memory.
    Speed {
        /// Robot URDF.
        #[arg(long, default_value = "../shared/robots/xarm6/robot.urdf")]
        robot: PathBuf,
        /// Views per solve.
        #[arg(long, default_value_t = 5)]
        views: usize,
        /// Image width.
        #[arg(long, default_value_t = 640)]
        width: u32,
        /// Image height.
        #[arg(long, default_value_t = 480)]
        height: u32,
        /// Number of scenes (seeds) timed.
        #[arg(long, default_value_t = 5)]
        scenes: u64,
        /// Renderer: cpu, wgpu or auto.
        #[arg(long, default_value = "auto")]
        renderer: RendererChoice,
    },
}

fn main() -> ExitCode {
    // With `--features ur`, this executable is also the UR driver's `ur_rtde` child process.
    easyhec_drivers::ur::serve_worker_if_asked();
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e)
            if matches!(
                e.kind(),
                clap::error::ErrorKind::DisplayHelp
                    | clap::error::ErrorKind::DisplayVersion
                    | clap::error::ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand
            ) =>
        {
            e.exit()
        }
        Err(e) => {
            // One line, as for every other bad input; `--help` has the details.
            let text = e.render().to_string();
            let first = text
                .lines()
                .next()
                .unwrap_or("invalid arguments")
                .trim_start_matches("error: ");
            eprintln!("error: {first} (see easyhec --help)");
            return ExitCode::FAILURE;
        }
    };
    let outcome = match cli.command {
        Command::Calibrate(a) => cmd_calibrate(a),
        Command::Solve(a) => cmd_solve(a),
        Command::Synth(a) => cmd_synth(a),
        Command::Import(ImportCommand::Easyhec {
            dir,
            out,
            urdf,
            joints,
            ignore_links,
        }) => cmd_import(dir, out, urdf, joints, ignore_links),
        Command::Export(a) => cmd_export(a),
        Command::Bench(b) => cmd_bench(b),
        Command::Daemon(a) => cmd_daemon(a),
    };
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            let chain: Vec<String> = e.chain().map(|c| c.to_string()).collect();
            eprintln!("error: {}", chain.join(": "));
            ExitCode::FAILURE
        }
    }
}

fn cmd_calibrate(a: CalibrateArgs) -> anyhow::Result<()> {
    use easyhec::calibrate::{calibrate, PlannedPose, RunOptions};
    use easyhec::time::rfc3339;
    use std::io::Write;
    use std::sync::Arc;
    let mut config = easyhec::config::read_config(&a.config)?;
    if let Some(r) = a.renderer {
        config.calibration.renderer = r;
    }
    let cell = easyhec::cell::Cell::build(config, &a.config)?;
    let out = a.out.unwrap_or_else(|| {
        PathBuf::from("runs").join(rfc3339(std::time::SystemTime::now()).replace(':', "-"))
    });
    let confirm: Option<easyhec::calibrate::ConfirmMove> = if a.confirm {
        Some(Arc::new(|p: &PlannedPose| {
            eprint!(
                "move to {} (score {:.1}, {:.0}% in image, clearance {:.1} mm self / {:.1} mm environment)? [y/N] ",
                fmt_joints(&p.joints),
                p.score,
                p.in_image * 100.0,
                p.clearance.self_m * 1e3,
                p.clearance.environment_m * 1e3
            );
            let _ = std::io::stderr().flush();
            let mut line = String::new();
            std::io::stdin().read_line(&mut line).is_ok() && line.trim().eq_ignore_ascii_case("y")
        }))
    } else {
        None
    };
    let opts = RunOptions {
        dry_run: a.dry_run,
        confirm,
        progress: !a.quiet,
        ..RunOptions::default()
    };
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    let outcome = runtime.block_on(calibrate(&cell, &out, &opts))?;
    let r = &outcome.result;
    if a.dry_run {
        println!(
            "dry run: {} poses planned from the first view's estimate (nothing moved); speed {:.2} rad/s",
            outcome.planned.len(),
            cell.config.calibration.speed_rad_s
        );
        for (i, p) in outcome.planned.iter().enumerate() {
            println!(
                "  {}: {}  score {:.1}  in image {:.0}%  path {} poses checked, clearance {:.1} mm self / {:.1} mm environment",
                i + 1,
                fmt_joints(&p.joints),
                p.score,
                p.in_image * 100.0,
                p.path_samples,
                p.clearance.self_m * 1e3,
                p.clearance.environment_m * 1e3
            );
        }
        for (a, b, why) in &cell.checker.skipped_pairs {
            if *why == "always in contact"
                || *why == "allowed in config"
                || *why == "disabled in SRDF"
            {
                println!("  not checked: {a} / {b} ({why})");
            }
        }
        return Ok(());
    }
    let iou = outcome.report.mean_iou();
    let t = |k: &str| r.timings_s.get(k).copied().unwrap_or(0.0);
    eprintln!(
        "calibrated from {} views in {:.1} s (solve {:.1} s, explore {:.1} s, motion {:.1} s): {}; mean IoU {:.4} -> {}",
        r.views_used.len(),
        t("total"),
        t("solve"),
        t("explore"),
        t("motion"),
        r.stop_reason,
        iou,
        outcome.run_dir.join("result.json").display()
    );
    if let Some(u) = &r.uncertainty {
        eprintln!(
            "1-sigma: rotation [{:.4}, {:.4}, {:.4}] deg, translation [{:.3}, {:.3}, {:.3}] mm",
            u.rotation_deg[0],
            u.rotation_deg[1],
            u.rotation_deg[2],
            u.translation_mm[0],
            u.translation_mm[1],
            u.translation_mm[2]
        );
    }
    if let Some(truth) = cell.sim.camera_from_base {
        let noise = match &cell.config.arm {
            easyhec::config::ArmConfig::Sim {
                encoder_noise_rad, ..
            } => *encoder_noise_rad,
            // The controller's own readings (a mock's are exact).
            // Every driver-backed arm (xArm, UR, servo buses, Piper).
            _ => 0.0,
        };
        let gt = easyhec::run::GroundTruth {
            format: "easyhec-truth/1".into(),
            camera_from_base: easyhec::geometry::to_rows(&truth),
            true_joints: Vec::new(),
            noise: NoiseModel {
                boundary_jitter_px: 0.0,
                blob_probability: 0.0,
                joint_noise_rad: noise,
            },
            seed: cell.config.calibration.seed,
            scene: match &cell.config.camera {
                easyhec::config::CameraConfig::Sim { scene, .. } => Some(scene.clone()),
                _ => None,
            },
        };
        easyhec::io::write_json_atomic(&outcome.run_dir.join("ground_truth.json"), &gt)?;
        let est = r.camera_from_base();
        println!(
            "error against the simulated truth: rotation {:.4} deg, translation {:.3} mm",
            easyhec::geometry::rotation_error_deg(&est, &truth),
            easyhec::geometry::translation_error_mm(&est, &truth)
        );
    }
    Ok(())
}

fn cmd_daemon(a: DaemonArgs) -> anyhow::Result<()> {
    use easyhec::daemon::{data_dir, resolve_token, serve, Daemon};
    let cell = easyhec::cell::Cell::open(&a.config)?;
    let token = resolve_token(&cell)?;
    let listen = a
        .listen
        .clone()
        .unwrap_or_else(|| cell.config.daemon.listen.clone());
    let data = data_dir(&cell, a.data.as_deref());
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("easyhec-http")
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    runtime.block_on(async move {
        let daemon = Daemon::open(cell, &data, token)?;
        for id in daemon.recovered() {
            eprintln!("easyhec daemon: {id} was running when the daemon stopped: marked interrupted (its views are on disk)");
        }
        let listener = tokio::net::TcpListener::bind(&listen)
            .await
            .with_context(|| format!("--listen {listen}: cannot listen there (use HOST:PORT)"))?;
        let addr = listener.local_addr().context("reading the bound address")?;
        // Tests and supervisors read this line for the port.
        eprintln!(
            "easyhec daemon listening on http://{addr} (data {})",
            data.display()
        );
        serve(daemon, listener, stop_signal()).await?;
        eprintln!("easyhec daemon: stopped");
        anyhow::Ok(())
    })
}

/// Resolves on ctrl-c or SIGTERM.
async fn stop_signal() {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        match signal(SignalKind::terminate()) {
            Ok(mut term) => {
                tokio::select! {
                    _ = tokio::signal::ctrl_c() => {}
                    _ = term.recv() => {}
                }
            }
            Err(_) => {
                let _ = tokio::signal::ctrl_c().await;
            }
        }
    }
    #[cfg(not(unix))]
    {
        let _ = tokio::signal::ctrl_c().await;
    }
}

fn fmt_joints(q: &[f64]) -> String {
    let parts: Vec<String> = q.iter().map(|v| format!("{v:+.3}")).collect();
    format!("[{}]", parts.join(", "))
}

/// Fills the masks of views that need one (`--segmenter`): segment → solve → re-segment over
/// those views until the masks settle. Returns the settled pose when it fits (mean IoU ≥
/// 0.8): the solve that follows starts there, since masks drawn near that pose's render are
/// what it must fit, and a start back at the guess can stop in another basin (hard synthetic
/// seed 3: 5.9° off from the guess, 0.006° from the settled pose).
fn segment_run(
    run: &mut easyhec::run::LoadedRun,
    name: &str,
    renderer: RendererChoice,
    masks_out: Option<&Path>,
) -> anyhow::Result<Option<nalgebra::Isometry3<f64>>> {
    use easyhec::config::SegmenterConfig;
    use easyhec::pipeline::segment_solve as refine;
    let config = SegmenterConfig::by_name(name).map_err(|e| anyhow!(e))?;
    let segmenter = easyhec::segment::build(&config, &run.dir.join("run.json"))?;
    let need: Vec<usize> = (0..run.views.len())
        .filter(|&i| run.views[i].needs_mask)
        .collect();
    if need.is_empty() {
        return Ok(None);
    }
    let mut frames = Vec::with_capacity(need.len());
    for &i in &need {
        let path = run.views[i]
            .image
            .clone()
            .expect("checked by load_run_with");
        frames.push(easyhec::segment::read_frame(
            &path,
            run.camera.width,
            run.camera.height,
        )?);
    }
    let robots: Vec<PosedRobot> = need
        .iter()
        .map(|&i| PosedRobot::new(&run.robot, &run.views[i].joints))
        .collect();
    let renderer = open_renderer(renderer, false).map_err(|e| anyhow!("--renderer: {e}"))?;
    let renderer = renderer.as_ref();
    let guess = run.initial_guess;
    let camera = run.camera.clone();
    let start = |views: &[View]| -> easyhec::Result<nalgebra::Isometry3<f64>> {
        match guess {
            Some(g) => Ok(g),
            None => Ok(initialise(
                renderer,
                &camera,
                &views[..views.len().min(3)],
                &SolveOptions::default(),
                &InitOptions::default(),
            )?
            .camera_from_base),
        }
    };
    let frame_refs: Vec<&easyhec_drivers::Frame> = frames.iter().collect();
    let min_band = config.min_band_px();
    let settled = refine::segment_and_solve(
        renderer,
        &run.camera,
        segmenter.as_ref(),
        &frame_refs,
        &robots,
        &start,
        guess.as_ref().map(|g| (g, 80.0)),
        min_band,
        config.final_band_px(),
        &SolveOptions::default(),
        4,
    )?;
    eprintln!(
        "segmenter {name}: {} views segmented in {} segment-and-solve rounds (mean IoU {:.3} at the last solve)",
        need.len(),
        settled.rounds,
        settled.report.mean_iou()
    );
    // No pose fits the masks: some views' joints may not describe their images. Find the two
    // views that agree on a pose, from the images alone.
    let settled = if settled.report.mean_iou() < refine::POOR_FIT_IOU && segmenter.uses_context() {
        let joints: Vec<Vec<f64>> = need.iter().map(|&i| run.views[i].joints.clone()).collect();
        let t = Instant::now();
        match refine::search_view_pairs(
            renderer,
            &run.camera,
            segmenter.as_ref(),
            &frame_refs,
            &run.robot,
            &joints,
            &settled.report.camera_from_base,
            &SolveOptions::default(),
            &refine::PairSearchOptions::default(),
        )? {
            Some(found) => {
                let (i, j) = found.pair;
                let runner_up = found.runner_up.map_or(String::new(), |((a, b), s)| {
                    format!(", next views {} and {} at {s:.3}", need[a], need[b])
                });
                eprintln!(
                    "segmenter {name}: the masks fit no pose, so every pair of views was tried: views {} and {} agree best (IoU {:.3} on masks under their own pose{runner_up}; {:.1} s); masks redrawn around joints refitted to each image, the pair fits them at IoU {:.3}",
                    need[i],
                    need[j],
                    found.score,
                    t.elapsed().as_secs_f64(),
                    found.settled.report.mean_iou()
                );
                found.settled
            }
            None => {
                eprintln!(
                    "segmenter {name}: the masks fit no pose and no pair of views agrees on one ({:.1} s)",
                    t.elapsed().as_secs_f64()
                );
                settled
            }
        }
    } else {
        settled
    };
    for (&i, mask) in need.iter().zip(&settled.masks) {
        if let Some(dir) = masks_out {
            easyhec::io::write_atomic(&dir.join(format!("{i:03}.mask.png")), &mask.to_png_bytes())?;
        }
        run.views[i].observed = run.camera.undistort_mask(mask);
        run.views[i].needs_mask = false;
    }
    Ok((settled.report.mean_iou() >= refine::POOR_FIT_IOU)
        .then_some(settled.report.camera_from_base))
}

fn cmd_solve(a: SolveArgs) -> anyhow::Result<()> {
    let started = Instant::now();
    let optimizer: Optimizer = a.optimizer.parse().map_err(|e: String| anyhow!(e))?;
    let mut run = match &a.segmenter {
        None => load_run(&a.run)?,
        Some(_) if a.ignore_masks => load_run_with(&a.run, MaskSource::Image)?,
        Some(_) => load_run_with(&a.run, MaskSource::RecordedElseImage)?,
    };
    let mut segment_s = None;
    let mut settled = None;
    if let Some(name) = &a.segmenter {
        let t = Instant::now();
        settled = segment_run(&mut run, name, a.renderer, a.masks_out.as_deref())?;
        segment_s = Some(t.elapsed().as_secs_f64());
    }
    let total = run.views.len();
    let k = a.views.unwrap_or(total);
    if k == 0 || k > total {
        bail!("--views {k}: the run has {total} views");
    }
    let selection = match a.select.as_str() {
        "first" => Selection::First,
        "random" => Selection::Random(a.seed),
        "explore" => Selection::Explore,
        other => bail!("--select {other}: use first, random or explore"),
    };
    // The pool: every recorded view (views beyond K are only candidates for explore/random).
    let pool_size = if selection == Selection::First {
        k
    } else {
        total
    };
    let pool: Vec<View> = run.views[..pool_size]
        .iter()
        .map(|v| View {
            robot: PosedRobot::new(&run.robot, &v.joints),
            observed: v.observed.clone(),
        })
        .collect();
    let renderer = open_renderer(a.renderer, false).map_err(|e| anyhow!("--renderer: {e}"))?;
    let renderer = renderer.as_ref();
    let initial = match settled.or(run.initial_guess) {
        Some(start) => start,
        None => {
            // No guess: search for one (method.md §6) over the first views.
            let first = &pool[..pool.len().min(3)];
            let found = initialise(
                renderer,
                &run.camera,
                first,
                &SolveOptions::default(),
                &InitOptions::default(),
            )
            .with_context(|| {
                format!(
                    "{}: initial_guess is absent",
                    run.dir.join("run.json").display()
                )
            })?;
            eprintln!(
                "no initial_guess: automatic initialisation found a pose with mean IoU {:.3} over {} views",
                found.mean_iou(),
                first.len()
            );
            found.camera_from_base
        }
    };
    let selected = solve_selected(
        renderer,
        &run.camera,
        &pool,
        &initial,
        k,
        selection,
        &SolveOptions {
            optimizer,
            ..SolveOptions::default()
        },
        &ExploreOptions {
            seed: a.seed,
            ..ExploreOptions::default()
        },
        &StopRule::default(),
    )?;
    let mut report = selected.report;
    let mut order = selected.order;
    let mut stop_reason = selected.stop_reason;
    if !a.keep_all_views {
        let used: Vec<View> = order.iter().map(|&i| pool[i].clone()).collect();
        if let Some(c) = find_consensus(
            renderer,
            &run.camera,
            &used,
            &report,
            &SolveOptions {
                optimizer,
                ..SolveOptions::default()
            },
            &ConsensusOptions::default(),
        )? {
            let rejected: Vec<String> = c
                .rejected
                .iter()
                .map(|&(i, iou)| format!("{} (IoU {iou:.2})", order[i]))
                .collect();
            let kept: Vec<usize> = c.kept.iter().map(|&i| order[i]).collect();
            eprintln!(
                "warning: views {} fit no pose the other views agree on and are left out (their joints do not describe their images: check joint-read timing); the result uses views {kept:?} (--keep-all-views keeps them)",
                rejected.join(", ")
            );
            stop_reason = format!(
                "{stop_reason}; left out {} inconsistent views",
                c.rejected.len()
            );
            order = kept;
            report = c.report;
        }
    }
    let views: Vec<&View> = order.iter().map(|&i| &pool[i]).collect();
    let solve_s = selected.solve_s;
    let mut result = ResultFile::new(&report.camera_from_base, &run.robot.links[run.robot.base]);
    result.views_used = order.clone();
    result.per_view = order
        .iter()
        .zip(&report.per_view_iou)
        .map(|(&v, &iou)| PerView { view: v, iou })
        .collect();
    result.uncertainty = UncertaintyEntry::of(&report.uncertainty);
    if !report
        .camera_from_base
        .to_homogeneous()
        .iter()
        .all(|v| v.is_finite())
    {
        bail!("the solve diverged (non-finite pose): check the initial guess and the masks");
    }
    result.stop_reason = match optimizer {
        Optimizer::Lm => stop_reason,
        Optimizer::Adam => format!(
            "{}; adam: {} steps, best iterate",
            stop_reason, report.iterations
        ),
    };
    if let Some(dir) = &a.overlays {
        let pinhole = run.camera.undistorted();
        for (&i, view) in order.iter().zip(&views) {
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
    }
    result.timings_s.insert("solve".into(), solve_s);
    if let Some(t) = segment_s {
        result.timings_s.insert("segment".into(), t);
    }
    if selection == Selection::Explore {
        result
            .timings_s
            .insert("explore".into(), selected.explore_s);
    }
    result
        .timings_s
        .insert("total".into(), started.elapsed().as_secs_f64());
    let out = a.out.unwrap_or_else(|| run.dir.join("result.json"));
    easyhec::io::write_json_atomic(&out, &result)?;
    let mean_iou = report.mean_iou();
    let poor: Vec<usize> = order
        .iter()
        .zip(&report.per_view_iou)
        .filter(|(_, &iou)| iou < 0.8)
        .map(|(&v, _)| v)
        .collect();
    if !poor.is_empty() {
        eprintln!(
            "warning: views {poor:?} fit poorly (IoU < 0.8): the reported uncertainty does not cover a wrong model; check each view's joints against its mask, ignore_links, and the URDF"
        );
    }
    println!(
        "camera_from_base solved from {} views in {:.2} s: mean IoU {:.4}, 1-sigma rot {:.4?} deg, trans {:.3?} mm -> {}",
        views.len(),
        solve_s,
        mean_iou,
        report.uncertainty.rotation_deg,
        report.uncertainty.translation_mm,
        out.display()
    );
    // Synthetic runs carry their truth beside run.json: report the error against it.
    let truth_path = run.dir.join("ground_truth.json");
    if let Ok(text) = std::fs::read_to_string(&truth_path) {
        if let Some(truth) = serde_json::from_str::<easyhec::run::GroundTruth>(&text)
            .ok()
            .and_then(|t| easyhec::geometry::from_rows(&t.camera_from_base).ok())
        {
            println!(
                "error vs {}: rotation {:.4} deg, translation {:.3} mm",
                truth_path.display(),
                easyhec::geometry::rotation_error_deg(&report.camera_from_base, &truth),
                easyhec::geometry::translation_error_mm(&report.camera_from_base, &truth)
            );
        }
    }
    Ok(())
}

fn urdf_for_run(urdf: &Path) -> String {
    // Absolute paths keep the run directory valid wherever it is solved from.
    let abs = std::fs::canonicalize(urdf).unwrap_or_else(|_| urdf.to_path_buf());
    abs.display().to_string()
}

fn cmd_synth(a: SynthArgs) -> anyhow::Result<()> {
    let robot = RobotModel::load(&RobotSource {
        urdf: a.robot.clone(),
        ignore_links: a.ignore_links.clone(),
        ..Default::default()
    })?;
    let noise = if a.no_noise {
        NoiseModel::none()
    } else {
        NoiseModel::standard()
    };
    let distortion = match a.distortion.as_deref() {
        None => None,
        Some([k1, k2, p1, p2, k3]) => Some([*k1, *k2, *p1, *p2, *k3]),
        Some(other) => bail!(
            "--distortion: plumb_bob needs 5 coefficients k1,k2,p1,p2,k3, got {}",
            other.len()
        ),
    };
    let opts = SynthOptions {
        views: a.views,
        seed: a.seed,
        width: a.width,
        height: a.height,
        focal_px: a.focal,
        distortion,
        noise: noise.clone(),
        initial_error: if a.no_initial_guess {
            None
        } else {
            Some(((2.0, 6.0), (0.02, 0.08)))
        },
        truncation: a.truncate.then(Truncation::standard),
        ..SynthOptions::default()
    };
    let robot = std::sync::Arc::new(robot);
    let imaged = match a.images {
        Some(preset) => Some(generate_frames(
            &robot,
            &opts,
            &SceneSettings {
                preset,
                ..SceneSettings::default()
            },
        )?),
        None => None,
    };
    let entry = RobotEntry {
        urdf: urdf_for_run(&a.robot),
        package_dirs: Default::default(),
        base_link: None,
        ignore_links: a.ignore_links,
        joints: robot.joint_names().iter().map(|s| s.to_string()).collect(),
    };
    match &imaged {
        Some(imaged) => write_imaged_scene(imaged, entry, &a.out, a.seed, &noise)?,
        None => write_scene(&generate(&robot, &opts)?, entry, &a.out, a.seed, &noise)?,
    }
    println!(
        "wrote {} views to {} (ground truth in ground_truth.json)",
        a.views,
        a.out.display()
    );
    Ok(())
}

fn cmd_import(
    dir: PathBuf,
    out: PathBuf,
    urdf: PathBuf,
    joints: Option<Vec<String>>,
    ignore_links: Vec<String>,
) -> anyhow::Result<()> {
    let joints = match joints {
        Some(j) => j,
        None => {
            let robot = RobotModel::from_urdf(urdf.clone())?;
            robot.joint_names().iter().map(|s| s.to_string()).collect()
        }
    };
    let run = import_easyhec(&EasyHecImport {
        source: dir,
        out: out.clone(),
        urdf: urdf_for_run(&urdf),
        joints,
        ignore_links,
        initial_guess: None,
    })?;
    println!("imported {} views into {}", run.views.len(), out.display());
    Ok(())
}

fn cmd_export(a: ExportArgs) -> anyhow::Result<()> {
    let format: ExportFormat = a.format.parse().map_err(|e: String| anyhow!(e))?;
    let result = ResultFile::read(&a.result)?;
    let text = export(&result, format, &a.camera_frame);
    match a.out {
        Some(p) => easyhec::io::write_atomic(&p, text.as_bytes())
            .with_context(|| format!("writing {}", p.display()))?,
        None => print!("{text}"),
    }
    Ok(())
}

fn cmd_bench(b: BenchCommand) -> anyhow::Result<()> {
    match b {
        BenchCommand::Segment {
            config,
            scenes,
            views,
            run,
            frames,
            renderer,
        } => {
            use easyhec::segment::bench as sb;
            let preset: ScenePreset = frames
                .parse()
                .map_err(|e: String| anyhow!("--frames: {e}"))?;
            if scenes > 0 {
                let mut base = easyhec::config::read_config(&config)?;
                base.calibration.renderer = renderer;
                let mut trials = Vec::new();
                for seed in 0..scenes {
                    let cfg = bench::seeded_sim_cell(&base, &config, seed)?;
                    let t = sb::cell_trial(&cfg, &config, seed, views, preset)?;
                    eprintln!(
                        "seed {seed}: IoU {:?}; {:.4} deg {:.3} mm",
                        t.ious
                            .iter()
                            .map(|x| (x * 1000.0).round() / 1000.0)
                            .collect::<Vec<_>>(),
                        t.rotation_deg,
                        t.translation_mm
                    );
                    trials.push(t);
                }
                let ious: Vec<f64> = trials.iter().flat_map(|t| t.ious.clone()).collect();
                let rot: Vec<f64> = trials.iter().map(|t| t.rotation_deg).collect();
                let trans: Vec<f64> = trials.iter().map(|t| t.translation_mm).collect();
                println!(
                    "builtin on {scenes} simulated cells, {views} views: mask IoU median {:.4} mean {:.4} (min {:.4}); RGB-only calibration median {:.4} deg / {:.3} mm (worst {:.4} deg / {:.3} mm)",
                    bench::median(&ious),
                    ious.iter().sum::<f64>() / ious.len().max(1) as f64,
                    ious.iter().copied().fold(f64::INFINITY, f64::min),
                    bench::median(&rot),
                    bench::median(&trans),
                    rot.iter().copied().fold(0.0, f64::max),
                    trans.iter().copied().fold(0.0, f64::max),
                );
            }
            if let Some(run) = run {
                let r = open_renderer(renderer, false).map_err(|e| anyhow!("--renderer: {e}"))?;
                let f = sb::run_figures(&run, r.as_ref())?;
                println!(
                    "builtin on {} ({} views, masks withheld): mean IoU {:.4} (per view {:?}); images-only vs recorded-mask calibration {:.4} deg / {:.3} mm after {} rounds",
                    run.display(),
                    f.ious.len(),
                    f.ious.iter().sum::<f64>() / f.ious.len().max(1) as f64,
                    f.ious.iter().map(|x| (x * 1000.0).round() / 1000.0).collect::<Vec<_>>(),
                    f.rotation_deg,
                    f.translation_mm,
                    f.rounds
                );
            }
        }
        BenchCommand::ViewSets {
            config,
            cells,
            first_seed,
            random_pairs,
            trials,
        } => {
            if random_pairs < 3 || trials < 2 {
                bail!("--random-pairs must be at least 3 and --trials at least 2");
            }
            let base = easyhec::config::read_config(&config)?;
            let mut results = Vec::new();
            for seed in first_seed..first_seed + cells {
                let cfg = bench::seeded_sim_cell(&base, &config, seed)?;
                let c = bench::view_set_cell(&cfg, &config, seed, random_pairs, trials)?;
                let n = c.sets[0].errors.len();
                let median_of = |f: &dyn Fn(&bench::ViewSet) -> f64| {
                    bench::median(&c.sets[1..].iter().map(f).collect::<Vec<_>>())
                };
                let e = &c.sets[0];
                eprintln!(
                    "seed {seed}: explore predicted {:.4} deg {:.3} mm, measured RMS {:.4} deg {:.3} mm; random pairs' median predicted {:.4} deg {:.3} mm, measured {:.4} deg {:.3} mm",
                    e.predicted_deg,
                    e.predicted_mm,
                    e.rms(0, 0..n),
                    e.rms(1, 0..n),
                    median_of(&|v| v.predicted_deg),
                    median_of(&|v| v.predicted_mm),
                    median_of(&|v| v.rms(0, 0..n)),
                    median_of(&|v| v.rms(1, 0..n)),
                );
                results.push(c);
            }
            let s =
                bench::view_set_summary(&results).ok_or_else(|| anyhow!("no cell to summarise"))?;
            println!("| over {cells} cells, {random_pairs} random pairs, {trials} solves each | rotation | translation |");
            println!("|---|---|---|");
            let row =
                |name: &str, v: [f64; 2]| println!("| {name} | {:.2}x | {:.2}x |", v[0], v[1]);
            row(
                "explore / random, predicted by the score's model",
                s.predicted_ratio,
            );
            row("explore / random, measured", s.measured_ratio);
            row(
                "best random pair / random (picked on its own trials)",
                s.best_random_ratio,
            );
            println!(
                "| spread of the random pairs' error (sd of log) | {:.2} ({:.2} from the finite trials) | {:.2} ({:.2}) |",
                s.random_log_sd[0], s.trial_log_sd[0], s.random_log_sd[1], s.trial_log_sd[1]
            );
            let corr = |c: (f64, Option<f64>)| match c.1 {
                Some(r) => format!("{:.2} ({r:.2})", c.0),
                None => format!("{:.2} (-)", c.0),
            };
            println!(
                "| correlation of predicted and measured log error within a cell (trial noise removed) | {} | {} |",
                corr(s.correlation[0]),
                corr(s.correlation[1])
            );
        }
        BenchCommand::Loop {
            config,
            cells,
            first_seed,
            views,
            climb_steps,
            selections,
            renderer,
            score,
        } => {
            use easyhec::config::{ScoreSetting, SelectionSetting};
            let mut base = easyhec::config::read_config(&config)?;
            base.calibration.renderer = renderer;
            if let Some(n) = climb_steps {
                base.calibration.climb_steps = n;
            }
            match score.as_deref() {
                None => {}
                Some("information") => base.calibration.score = ScoreSetting::Information,
                Some("variance") => base.calibration.score = ScoreSetting::Variance,
                Some(other) => bail!("--score {other}: use information or variance"),
            }
            let mut all: Vec<(String, Vec<bench::LoopTrial>)> = Vec::new();
            for name in &selections {
                let selection = match name.as_str() {
                    "explore" => SelectionSetting::Explore,
                    "random" => SelectionSetting::Random,
                    other => bail!("--selections {other}: use explore or random"),
                };
                let mut trials = Vec::new();
                for seed in first_seed..first_seed + cells {
                    let cfg = bench::seeded_sim_cell(&base, &config, seed)?;
                    let t = bench::run_loop_trial(&cfg, &config, seed, selection, views)?;
                    let last = t.errors.last().copied().unwrap_or((0, f64::NAN, f64::NAN));
                    // Every view count's error, so medians over any subset of seeds can be
                    // taken from one run.
                    let per_view: Vec<String> = t
                        .errors
                        .iter()
                        .map(|e| format!("{}:{:.5}:{:.4}", e.0, e.1, e.2))
                        .collect();
                    eprintln!(
                        "{name} seed {seed}: {} views {:.4} deg {:.3} mm; planning {:.2} s/round; compute {:.1} s; per view (views:deg:mm) {}; {}",
                        last.0,
                        last.1,
                        last.2,
                        t.explore_round_s[0],
                        t.compute_s,
                        per_view.join(" "),
                        t.stop_reason
                    );
                    trials.push(t);
                }
                all.push((name.clone(), trials));
            }
            println!(
                "| selection | {} |",
                (1..=views)
                    .map(|k| format!("{k} views"))
                    .collect::<Vec<_>>()
                    .join(" | ")
            );
            println!("|---|{}", "---|".repeat(views));
            for (name, trials) in &all {
                let cells: Vec<String> = (1..=views)
                    .map(|k| match bench::loop_medians(trials, k) {
                        Some((r, t)) => format!("{r:.3}° / {t:.2} mm"),
                        None => "-".into(),
                    })
                    .collect();
                println!("| {name} | {} |", cells.join(" | "));
            }
            for (name, trials) in &all {
                let plan: Vec<f64> = trials
                    .iter()
                    .flat_map(|t| t.explore_round_s.clone())
                    .collect();
                let compute: Vec<f64> = trials.iter().map(|t| t.compute_s).collect();
                println!(
                    "{name}: planning per round median {:.2} s (max {:.2}); compute per {views}-view calibration median {:.1} s (max {:.1})",
                    bench::median(&plan),
                    plan.iter().cloned().fold(0.0, f64::max),
                    bench::median(&compute),
                    compute.iter().cloned().fold(0.0, f64::max)
                );
            }
            if all.len() == 2 {
                if let (Some(e), Some(r)) = (
                    bench::loop_medians(&all[0].1, 3),
                    bench::loop_medians(&all[1].1, 3),
                ) {
                    println!(
                        "3 views, {} / {}: rotation {:.2}x, translation {:.2}x",
                        all[0].0,
                        all[1].0,
                        e.0 / r.0,
                        e.1 / r.1
                    );
                }
            }
        }
        BenchCommand::Accuracy {
            robot,
            scenes,
            views,
            optimizers,
        } => {
            let model = RobotModel::from_urdf(robot)?;
            let seeds: Vec<u64> = (0..scenes).collect();
            for name in optimizers {
                let optimizer: Optimizer = name.parse().map_err(|e: String| anyhow!(e))?;
                let trials = bench::accuracy(
                    &model,
                    &seeds,
                    &views,
                    optimizer,
                    &SynthOptions::default(),
                    |t| {
                        eprintln!(
                        "{name} seed {} views {}: {:.4} deg {:.3} mm (1-sigma {:.4} deg {:.3} mm) {:.2} s",
                        t.seed, t.views, t.rotation_deg, t.translation_mm, t.sigma_rotation_deg, t.sigma_translation_mm, t.seconds
                    )
                    },
                )?;
                println!("{}", bench::summarize(&name, &trials, &views));
            }
        }
        BenchCommand::Init {
            robot,
            scenes,
            views,
            distance,
        } => {
            let model = RobotModel::from_urdf(robot)?;
            let (lo, hi) = match distance.as_slice() {
                [lo, hi] => (*lo, *hi),
                _ => bail!("--distance takes MIN,MAX in metres"),
            };
            let (mut ok, mut rot, mut trans, mut secs) =
                (0usize, Vec::new(), Vec::new(), Vec::new());
            for seed in 0..scenes {
                let synth = SynthOptions {
                    seed,
                    views,
                    initial_error: None,
                    camera_distance_m: (lo, hi),
                    camera_elevation_deg: (0.0, 90.0),
                    ..SynthOptions::default()
                };
                let scene = generate(&model, &synth)?;
                let v = bench::scene_views(&model, &scene);
                let t = Instant::now();
                let outcome = initialise(
                    &CpuRenderer,
                    &scene.camera,
                    &v,
                    &SolveOptions::default(),
                    &InitOptions::default(),
                );
                let dt = t.elapsed().as_secs_f64();
                secs.push(dt);
                match outcome {
                    Ok(r) => {
                        let (re, te) = (
                            easyhec::geometry::rotation_error_deg(
                                &r.camera_from_base,
                                &scene.camera_from_base,
                            ),
                            easyhec::geometry::translation_error_mm(
                                &r.camera_from_base,
                                &scene.camera_from_base,
                            ),
                        );
                        let good = re <= 0.1 && te <= 2.0;
                        ok += usize::from(good);
                        rot.push(re);
                        trans.push(te);
                        eprintln!(
                            "seed {seed}: {re:.4} deg {te:.3} mm in {dt:.2} s{}",
                            if good {
                                ""
                            } else {
                                "  (outside 0.1 deg / 2 mm)"
                            }
                        );
                    }
                    Err(e) => eprintln!("seed {seed}: reported failure in {dt:.2} s: {e}"),
                }
            }
            println!(
                "auto init, {views} views, camera {lo}-{hi} m on a hemisphere: {ok}/{scenes} within 0.1 deg / 2 mm; median error {:.4} deg {:.3} mm; time median {:.2} s, max {:.2} s",
                bench::median(&rot),
                bench::median(&trans),
                bench::median(&secs),
                secs.iter().copied().fold(0.0, f64::max)
            );
        }
        BenchCommand::Speed {
            robot,
            views,
            width,
            height,
            scenes,
            renderer,
        } => {
            let renderer =
                open_renderer(renderer, false).map_err(|e| anyhow!("--renderer: {e}"))?;
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
                let v = bench::scene_views(&model, &scene);
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
            println!(
                "{views}-view {width}x{height} solve on {} threads: median {:.3} s, min {:.3} s, max {:.3} s over {scenes} scenes; peak RSS {:.0} MB",
                rayon::current_num_threads(),
                bench::median(&times),
                times.iter().copied().fold(f64::INFINITY, f64::min),
                times.iter().copied().fold(0.0, f64::max),
                bench::peak_rss_bytes().unwrap_or(0) as f64 / 1e6
            );
        }
        BenchCommand::Explore {
            robot,
            samples,
            candidates,
            width,
            height,
            rounds,
            renderer,
        } => {
            let renderer =
                open_renderer(renderer, false).map_err(|e| anyhow!("--renderer: {e}"))?;
            let model = RobotModel::from_urdf(robot)?;
            let r = bench::explore_round(
                renderer.as_ref(),
                &model,
                samples,
                candidates,
                width,
                height,
                rounds,
            )?;
            println!(
                "exploration round, {samples} joint samples x {candidates} candidates at {}x{} on {}: median {:.3} s scoring (min {:.3} s) + {:.3} s posing and decimation on {} threads; best score {:.1}",
                width / 4,
                height / 4,
                renderer.name(),
                bench::median(&r.scoring_s),
                r.scoring_s.iter().copied().fold(f64::INFINITY, f64::min),
                bench::median(&r.posing_s),
                rayon::current_num_threads(),
                r.best_score
            );
        }
    }
    Ok(())
}

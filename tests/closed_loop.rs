//! The closed loop on simulated cells: calibrations reach the simulated truth, record
//! everything, and no command that reaches the simulated arm is unsafe — including in an
//! obstacle-heavy cell and with an arm that refuses, faults and stalls.

mod common;

use std::path::{Path, PathBuf};

use easyhec::calibrate::{calibrate, Outcome, RunOptions};
use easyhec::cell::Cell;
use easyhec::config::ObstacleConfig;
use easyhec::config::SimArmSettings;
use easyhec::config::{read_config, ArmConfig, CellConfig, FaultConfig};
use easyhec::geometry::{rotation_error_deg, translation_error_mm};
use easyhec::run::load_run;

fn run(cell: &Cell, out: &Path, opts: &RunOptions) -> easyhec::Result<Outcome> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
        .block_on(calibrate(cell, out, opts))
}

/// Rotation (degrees) and translation (mm) of the loop's result against the simulated truth.
fn truth_error(cell: &Cell, outcome: &Outcome) -> (f64, f64) {
    let truth = cell.units[0].sim.camera_from_base.unwrap();
    let est = outcome.result.camera_from_base();
    (
        rotation_error_deg(&est, &truth),
        translation_error_mm(&est, &truth),
    )
}

fn quick(mut cfg: CellConfig, views: usize) -> CellConfig {
    cfg.calibration.max_views = views;
    cfg.calibration.joint_samples = 600;
    cfg.calibration.candidates = 24;
    cfg
}

#[test]
fn every_shipped_config_parses_and_builds() {
    let mut n = 0;
    for entry in
        std::fs::read_dir(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config")).unwrap()
    {
        let path = entry.unwrap().path();
        if path.extension().and_then(|e| e.to_str()) == Some("toml") {
            match Cell::open(&path) {
                Ok(_) => {}
                // Built without the driver a config needs: the documented one-line refusal.
                Err(e)
                    if !cfg!(feature = "ur")
                        && e.to_string().contains("rebuild with --features ur") => {}
                Err(e) => panic!("{}: {e}", path.display()),
            }
            n += 1;
        }
    }
    assert!(n >= 3, "expected the sim configs, found {n}");
}

/// The uncertainty rule stops the loop as soon as the reported 95% centre bound meets the
/// target, and no sooner than `min_views`; a target no solve reaches leaves the other rules.
/// The cell's model-error floor reaches the loop's reported uncertainty.
#[test]
fn the_loop_stops_once_the_centre_bound_meets_its_target() {
    let path = common::config_path("sim-xarm6.toml");
    let stop_with_floor = |target: Option<f64>, floor_mm: f64| {
        let mut cfg = quick(read_config(&path).unwrap(), 4);
        cfg.calibration.min_views = 2;
        cfg.calibration.stop_centre_95_mm = target;
        cfg.calibration.model_floor_translation_mm = floor_mm;
        let cell = Cell::build(cfg, &path).unwrap();
        let dir = tempfile::tempdir().unwrap();
        run(&cell, &dir.path().join("run"), &RunOptions::default()).unwrap()
    };
    let stop_with = |target: Option<f64>| stop_with_floor(target, 0.0);
    let loose = stop_with(Some(50.0));
    let bound = loose
        .result
        .uncertainty
        .as_ref()
        .unwrap()
        .camera_centre_95_mm
        .unwrap();
    assert_eq!(
        loose.result.views_used.len(),
        2,
        "{}",
        loose.result.stop_reason
    );
    assert!(
        loose.result.stop_reason.contains("camera centre within") && bound <= 50.0,
        "{} (bound {bound} mm)",
        loose.result.stop_reason
    );
    let unreachable = stop_with(Some(1e-3));
    assert!(
        !unreachable
            .result
            .stop_reason
            .contains("camera centre within"),
        "{}",
        unreachable.result.stop_reason
    );
    // A 5 mm floor on the centre: every translation sigma at least 5 mm, and the centre
    // bound at least 2.8 times it (the 95% radius of a 3-D Gaussian).
    let floored = stop_with_floor(Some(50.0), 5.0);
    let u = floored.result.uncertainty.as_ref().unwrap();
    assert!(
        u.translation_mm.iter().all(|&s| s >= 5.0) && u.camera_centre_95_mm.unwrap() >= 13.9,
        "{u:?}"
    );
}

#[test]
fn simulated_xarm6_calibration_reaches_the_truth_and_records_a_solvable_run() {
    let path = common::config_path("sim-xarm6.toml");
    let cell = Cell::build(quick(read_config(&path).unwrap(), 4), &path).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let outcome = run(&cell, &out, &RunOptions::default()).unwrap();
    let (r, t) = truth_error(&cell, &outcome);
    assert!(r < 0.15 && t < 1.5, "error {r:.4} deg {t:.3} mm");
    let views = outcome.result.views_used.len();
    assert!(
        (3..=4).contains(&views),
        "{views} views: {}",
        outcome.result.stop_reason
    );
    // The run directory is complete and re-solvable offline.
    let loaded = load_run(&out).unwrap();
    assert_eq!(loaded.views.len(), views);
    assert!(out.join("result.json").is_file() && out.join("rounds.json").is_file());
    for v in &loaded.file.views {
        assert!(out.join(v.image.as_ref().unwrap()).is_file());
    }
    assert_eq!(outcome.rounds.len(), views);
    let moves = common::assert_every_command_safe(&cell);
    assert_eq!(moves, views - 1, "one move per added view");
}

#[test]
fn ur5e_and_panda_cells_calibrate() {
    for name in ["sim-ur5e.toml", "sim-panda.toml"] {
        let path = common::config_path(name);
        let cell = Cell::build(quick(read_config(&path).unwrap(), 3), &path).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let outcome = run(&cell, &dir.path().join("run"), &RunOptions::default()).unwrap();
        let (r, t) = truth_error(&cell, &outcome);
        assert!(r < 0.2 && t < 2.0, "{name}: error {r:.4} deg {t:.3} mm");
        common::assert_every_command_safe(&cell);
    }
}

#[test]
fn obstacle_heavy_cell_never_commands_an_unsafe_move() {
    let path = common::config_path("sim-xarm6.toml");
    let mut cfg = quick(read_config(&path).unwrap(), 4);
    let obstacles = [
        r#"kind = "box"
name = "fixture"
centre = [0.45, 0.0, 0.1]
size = [0.2, 0.5, 0.2]"#,
        r#"kind = "box"
name = "thin glass panel"
centre = [0.0, -0.45, 0.4]
size = [1.2, 0.002, 0.8]"#,
        r#"kind = "sphere"
name = "lamp"
centre = [0.0, 0.4, 0.75]
radius_m = 0.12"#,
        r#"kind = "keep-out"
name = "operator side"
min = [-1.0, 0.45, 0.0]
max = [1.0, 1.5, 2.0]"#,
        r#"kind = "box"
name = "ceiling"
centre = [0.0, 0.0, 1.05]
size = [2.0, 2.0, 0.02]"#,
    ];
    for o in obstacles {
        cfg.safety
            .obstacles
            .push(toml::from_str::<ObstacleConfig>(o).unwrap());
    }
    let cell = Cell::build(cfg, &path).unwrap();
    // The start pose itself is clear (otherwise the test would prove nothing).
    let ArmConfig::Sim(SimArmSettings { start, .. }) = &cell.config.arm else {
        panic!("a simulated arm")
    };
    let start = start.clone();
    cell.checker.check_pose(&start).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let outcome = run(&cell, &dir.path().join("run"), &RunOptions::default()).unwrap();
    let moves = common::assert_every_command_safe(&cell);
    assert!(
        moves >= 2,
        "the cell still leaves room to calibrate: {}",
        outcome.result.stop_reason
    );
    // Many joint samples were rejected by the environment.
    let first = &outcome.rounds[0].events[0];
    assert!(first.contains("safe"), "{first}");
}

#[test]
fn fault_injecting_arm_is_handled_and_stays_safe() {
    let path = common::config_path("sim-xarm6.toml");
    let mut cfg = quick(read_config(&path).unwrap(), 4);
    let ArmConfig::Sim(SimArmSettings { faults, .. }) = &mut cfg.arm else {
        panic!("a simulated arm")
    };
    *faults = vec![
        FaultConfig::Refuse { on_move: 0 },
        FaultConfig::Error {
            on_move: 1,
            at_fraction: 0.4,
        },
        FaultConfig::Stall {
            on_move: 3,
            at_fraction: 0.7,
        },
    ];
    cfg.calibration.clear_faults = true;
    let cell = Cell::build(cfg.clone(), &path).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let outcome = run(&cell, &dir.path().join("run"), &RunOptions::default()).unwrap();
    let events: Vec<&String> = outcome.rounds.iter().flat_map(|r| &r.events).collect();
    assert!(
        events.iter().filter(|e| e.contains("move failed")).count() >= 3,
        "{events:?}"
    );
    let sim = cell.sim_arm().unwrap();
    let commands = sim.commands();
    // The refused command is logged as refused; every accepted one was safe, including the
    // moves re-planned from where a fault left the arm mid-path.
    assert!(!commands[0].accepted);
    let accepted: Vec<_> = commands.iter().filter(|c| c.accepted).cloned().collect();
    for c in &accepted {
        cell.checker
            .check_move(&c.from, &c.target, c.speed_rad_s)
            .unwrap();
    }
    assert!(accepted.len() >= 4, "{commands:?}");
    let truth = cell.units[0].sim.camera_from_base.unwrap();
    let est = outcome.result.camera_from_base();
    assert!(rotation_error_deg(&est, &truth) < 0.2);

    // Without clearing faults, the loop stops at the first fault but keeps what it recorded.
    cfg.calibration.clear_faults = false;
    let ArmConfig::Sim(SimArmSettings { faults, .. }) = &mut cfg.arm else {
        panic!("a simulated arm")
    };
    *faults = vec![FaultConfig::Error {
        on_move: 1,
        at_fraction: 0.5,
    }];
    let cell = Cell::build(cfg, &path).unwrap();
    let out = dir.path().join("run2");
    let outcome = run(&cell, &out, &RunOptions::default()).unwrap();
    assert!(
        outcome.result.stop_reason.contains("fault"),
        "{}",
        outcome.result.stop_reason
    );
    assert_eq!(outcome.result.views_used.len(), 2);
    assert_eq!(load_run(&out).unwrap().views.len(), 2);
    assert!(out.join("result.json").is_file());
    assert_every_command_safe_accepted_only(&cell);
}

fn assert_every_command_safe_accepted_only(cell: &Cell) {
    for c in cell
        .sim_arm()
        .unwrap()
        .commands()
        .iter()
        .filter(|c| c.accepted)
    {
        cell.checker
            .check_move(&c.from, &c.target, c.speed_rad_s)
            .unwrap();
    }
}

#[test]
fn dry_run_plans_checked_poses_and_never_moves() {
    let path = common::config_path("sim-xarm6.toml");
    let cell = Cell::build(quick(read_config(&path).unwrap(), 4), &path).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let outcome = run(
        &cell,
        &dir.path().join("run"),
        &RunOptions {
            dry_run: true,
            ..RunOptions::default()
        },
    )
    .unwrap();
    assert!(cell.sim_arm().unwrap().commands().is_empty());
    assert_eq!(outcome.planned.len(), 3);
    let ArmConfig::Sim(SimArmSettings { start, .. }) = &cell.config.arm else {
        panic!("a simulated arm")
    };
    let mut at = start.clone();
    for p in &outcome.planned {
        cell.checker.check_move(&at, &p.joints, 0.5).unwrap();
        at = p.joints.clone();
    }
    assert!(!dir.path().join("run/result.json").exists());
}

#[test]
fn bad_cell_configs_get_one_line_errors_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let base = common::shipped_config_text("sim-xarm6.toml");
    let cases = [
        (
            base.replace("kind = \"sim-truth\"", "kind = \"magic\""),
            "line",
        ),
        (
            base.replace("max_views = 5", "max_views = 5\nmax_veiws = 3"),
            "max_veiws",
        ),
        (
            base.replace("margin_m = 0.01", "margin_m = -1.0"),
            "safety.margin_m",
        ),
        (
            base.replace("joint1 = [-2.0, 2.0]", "joint9 = [-2.0, 2.0]"),
            "joint9",
        ),
        (
            base.replace(
                "start = [0.0, -0.35, -0.6, 0.0, 0.95, 0.0]",
                "start = [0.0]",
            ),
            "arm.start",
        ),
        (
            base.replace(
                "kind = \"sim-truth\"\nnoise = { boundary_jitter_px = 0.5, blob_probability = 0.3, joint_noise_rad = 0.0 }",
                "kind = \"builtin\"\nfinal_band_px = -4.0",
            ),
            "segmenter.final_band_px",
        ),
    ];
    common::assert_configs_refused(dir.path(), &base, &cases);
}

#[test]
fn simulated_camera_frames_are_textured_noisy_and_match_their_masks() {
    let path = common::config_path("sim-panda.toml");
    let cell = Cell::open(&path).unwrap();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let (a, b) = rt.block_on(async {
        (
            cell.units[0].device.grab().await.unwrap(),
            cell.units[0].device.grab().await.unwrap(),
        )
    });
    // The truth stays with the simulator, looked up by the frame's sequence number.
    let sim_camera = cell.units[0].sim.camera.as_ref().unwrap();
    let mask = &sim_camera.truth_mask(a.sequence).unwrap();
    let n = mask.len();
    let robot = mask.iter().filter(|&&m| m >= 128).count();
    assert!(
        robot > n / 100 && robot < n / 2,
        "{robot} robot pixels of {n}"
    );
    // Sensor noise: two frames of the same pose differ a little everywhere.
    let diff = a
        .rgb
        .iter()
        .zip(&b.rgb)
        .map(|(x, y)| (f64::from(*x) - f64::from(*y)).abs())
        .sum::<f64>()
        / a.rgb.len() as f64;
    assert!(
        diff > 0.5 && diff < 8.0,
        "mean frame-to-frame difference {diff}"
    );
    // Texture: the background is not flat.
    let grey: Vec<f64> = a
        .rgb
        .chunks(3)
        .map(|p| p.iter().map(|&c| f64::from(c)).sum::<f64>() / 3.0)
        .collect();
    let bg: Vec<f64> = grey
        .iter()
        .zip(mask)
        .filter(|(_, &m)| m < 128)
        .map(|(g, _)| *g)
        .collect();
    let mean = bg.iter().sum::<f64>() / bg.len() as f64;
    let sd = (bg.iter().map(|g| (g - mean).powi(2)).sum::<f64>() / bg.len() as f64).sqrt();
    assert!(
        sd > 8.0,
        "background standard deviation {sd} (flat with sensor noise: about 2.5)"
    );
    // The lens is distorted: the mask is the pinhole silhouette warped, not the pinhole one.
    let cam = easyhec::camera::Intrinsics {
        width: a.width,
        height: a.height,
        fx: 610.0,
        fy: 609.0,
        cx: 324.0,
        cy: 236.0,
        distortion: None,
    };
    let sim = cell.sim_arm().unwrap();
    let posed = easyhec::render::PosedRobot::new(&cell.robot, &sim.true_joints());
    use easyhec::render::SilhouetteRenderer;
    let pinhole = easyhec::render::CpuRenderer
        .render(
            &posed,
            &cam,
            &cell.units[0].sim.camera_from_base.unwrap(),
            None,
        )
        .mask;
    let observed = easyhec::mask::Mask {
        width: a.width,
        height: a.height,
        data: mask.iter().map(|&m| u8::from(m >= 128)).collect(),
    };
    let iou = pinhole.iou(&observed);
    assert!(iou > 0.8 && iou < 0.995, "distorted vs pinhole IoU {iou}");
}

/// The loop on the hard cell (clutter, a light robot on light walls, shadows, exposure
/// changes, moving distractors) with `[segmenter] kind = "builtin"`: no side-channel mask is
/// used, each view's mask is written beside its frame (and rewritten as later rounds
/// re-segment it), and the pose still lands within the issue's RGB-only bound.
#[test]
fn hard_cell_calibrates_from_colour_frames_alone() {
    use easyhec::config::SegmenterConfig;
    use easyhec::mask::Mask;
    use easyhec::render::{CpuRenderer, PosedRobot, SilhouetteRenderer};
    let path = common::config_path("sim-xarm6-hard.toml");
    let mut cfg = quick(read_config(&path).unwrap(), 5);
    cfg.calibration.min_views = 5;
    cfg.segmenter = SegmenterConfig::by_name("builtin").unwrap();
    let cell = Cell::build(cfg, &path).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let outcome = run(&cell, &out, &RunOptions::default()).unwrap();
    let (r, t) = truth_error(&cell, &outcome);
    eprintln!("builtin loop on the hard cell: {r:.4} deg {t:.3} mm");
    assert!(r <= 0.08 && t <= 1.5, "error {r:.4} deg {t:.3} mm");
    assert_eq!(outcome.result.views_used.len(), 5);
    // Every recorded mask is the segmenter's, beside its frame: it matches the robot
    // rendered at the true pose, not an empty or full image.
    let loaded = load_run(&out).unwrap();
    let camera = loaded.camera.undistorted();
    let truth = cell.units[0].sim.camera_from_base.unwrap();
    let mut ious = Vec::new();
    for v in &loaded.file.views {
        assert!(out.join(v.image.as_ref().unwrap()).is_file());
        let mask = Mask::load(&out.join(v.mask.as_ref().unwrap())).unwrap();
        let posed = PosedRobot::new(&loaded.robot, &v.joints);
        let rendered = CpuRenderer.render(&posed, &camera, &truth, None).mask;
        ious.push(mask.iou(&rendered));
    }
    ious.sort_by(f64::total_cmp);
    eprintln!("mask IoU at the truth, worst to best: {ious:.3?}");
    // Measured 0.867 / 0.918 (worst / median; 0.85 / 0.90 before the final 4 px band), against
    // the robot rendered at the recorded joints with nothing occluding it; the bench's median
    // over 200 masks is 0.966.
    assert!(
        ious[0] >= 0.8 && ious[2] >= 0.87,
        "mask IoU at the truth {ious:?}"
    );
    common::assert_every_command_safe(&cell);
}

/// The demo cell (5 views, quick planning) with the builtin segmenter and no initial guess.
fn builtin_cell_without_guess() -> Cell {
    let path = common::config_path("sim-xarm6.toml");
    let mut cfg = quick(read_config(&path).unwrap(), 5);
    cfg.segmenter = easyhec::config::SegmenterConfig::by_name("builtin").unwrap();
    cfg.calibration.initial_guess = None;
    Cell::build(cfg, &path).unwrap()
}

/// The demo cell from colour frames alone with no starting pose at all: the loop first takes
/// views near the start pose, every command through the checker, starts from what changed
/// between them, and reaches the truth as a run with a guess does.
#[test]
fn with_no_guess_colour_frames_alone_start_from_seeding_views() {
    let cell = builtin_cell_without_guess();
    let dir = tempfile::tempdir().unwrap();
    let outcome = run(&cell, &dir.path().join("run"), &RunOptions::default()).unwrap();
    let (r, t) = truth_error(&cell, &outcome);
    eprintln!("builtin loop with no guess: {r:.4} deg {t:.3} mm");
    // Measured 0.041° / 0.35 mm.
    assert!(r <= 0.1 && t <= 1.0, "error {r:.4} deg {t:.3} mm");
    // The builtin masks' result carries the segmentation term, and its bound holds the truth.
    let u = outcome.result.uncertainty.as_ref().unwrap();
    let terms = u.terms.as_ref().unwrap();
    assert!(terms.segmentation_centre_95_mm.is_some(), "{terms:?}");
    let truth = cell.units[0].sim.camera_from_base.unwrap();
    let centre_mm =
        easyhec::geometry::camera_centre_error_mm(&outcome.result.camera_from_base(), &truth);
    assert!(
        centre_mm <= u.camera_centre_95_mm.unwrap(),
        "{centre_mm} mm: {u:?}"
    );
    let round0 = &outcome.rounds[0];
    assert_eq!(round0.views, 3, "{:?}", round0.events);
    assert!(
        round0.events[0].contains("started from the camera pose"),
        "{:?}",
        round0.events
    );
    common::assert_every_command_safe(&cell);
    let commands = cell.sim_arm().unwrap().commands();
    // The two seeding moves turn only the first three joints, by at most 0.4 rad from the
    // start (as read, with the encoder's noise), and each goes somewhere new.
    let ArmConfig::Sim(SimArmSettings { start, .. }) = &cell.config.arm else {
        panic!("a simulated arm")
    };
    for c in &commands[..2] {
        let turned: Vec<f64> = start.iter().zip(&c.target).map(|(a, b)| b - a).collect();
        assert!(
            turned[..3].iter().all(|d| d.abs() <= 0.405)
                && turned[3..].iter().all(|d| d.abs() < 0.005)
                && turned.iter().any(|d| d.abs() > 0.05),
            "seeding move {c:?}"
        );
    }
}

/// A seeding move the operator declines, or a cancel before it, ends the run before the arm
/// moves, with no result.
#[test]
fn a_declined_or_cancelled_seeding_move_ends_the_run_unmoved() {
    let declined = RunOptions {
        confirm: Some(std::sync::Arc::new(
            |_: &easyhec::calibrate::PlannedPose| false,
        )),
        ..RunOptions::default()
    };
    let cancelled = RunOptions {
        cancel: Some(std::sync::Arc::new(std::sync::atomic::AtomicBool::new(
            true,
        ))),
        ..RunOptions::default()
    };
    for (opts, why) in [
        (declined, "declined seeding move 1"),
        (cancelled, "cancelled before seeding move 1"),
    ] {
        let cell = builtin_cell_without_guess();
        let dir = tempfile::tempdir().unwrap();
        let err = run(&cell, &dir.path().join("run"), &opts)
            .unwrap_err()
            .to_string();
        assert!(err.contains(why), "{err}");
        assert!(cell.sim_arm().unwrap().commands().is_empty());
        assert!(!dir.path().join("run/result.json").exists());
    }
}

/// A planned move the operator declines, or a cancel that comes before it, stops the loop
/// there: the move never reaches the arm, and the result holds the views taken so far.
#[test]
fn a_declined_or_cancelled_planned_move_stops_the_loop_where_it_is() {
    use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
    use std::sync::Arc;
    let asked = Arc::new(AtomicUsize::new(0));
    let counter = asked.clone();
    // The first move is approved, the second declined.
    let declined = RunOptions {
        confirm: Some(Arc::new(move |_: &easyhec::calibrate::PlannedPose| {
            counter.fetch_add(1, Ordering::SeqCst) == 0
        })),
        ..RunOptions::default()
    };
    let cancel = Arc::new(AtomicBool::new(false));
    let flag = cancel.clone();
    let seen = AtomicUsize::new(0);
    // Both moves are approved, but the run is cancelled while the operator looks at the
    // second.
    let cancelled = RunOptions {
        confirm: Some(Arc::new(move |_: &easyhec::calibrate::PlannedPose| {
            if seen.fetch_add(1, Ordering::SeqCst) == 1 {
                flag.store(true, Ordering::SeqCst);
            }
            true
        })),
        cancel: Some(cancel),
        ..RunOptions::default()
    };
    for (opts, why) in [
        (declined, "operator declined a move after 2 views"),
        (cancelled, "cancelled"),
    ] {
        let path = common::config_path("sim-xarm6.toml");
        let cell = Cell::build(quick(read_config(&path).unwrap(), 6), &path).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let outcome = run(&cell, &dir.path().join("run"), &opts).unwrap();
        assert!(
            outcome.result.stop_reason.contains(why),
            "{}",
            outcome.result.stop_reason
        );
        assert_eq!(outcome.result.views_used.len(), 2, "{why}");
        assert_eq!(common::assert_every_command_safe(&cell), 1, "{why}");
        assert!(dir.path().join("run/result.json").is_file());
    }
}

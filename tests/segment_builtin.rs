//! The `builtin` segmenter on hard simulated frames: mask IoU against the
//! simulator's truth, and a calibration from the colour frames alone (no side-channel masks)
//! through segment → solve → re-segment.

mod common;

use std::sync::Arc;

use easyhec::config::SceneSettings;
use easyhec::config::SegmenterConfig;
use easyhec::geometry::{rotation_error_deg, translation_error_mm};
use easyhec::mask::Mask;
use easyhec::pipeline::segment_solve::segment_and_solve;
use easyhec::render::{CpuRenderer, PosedRobot};
use easyhec::segment::ViewInput;
use easyhec::solve::SolveOptions;
use easyhec::synth::{generate_frames, SynthOptions};
use easyhec_drivers::Frame;

fn frame_of(width: u32, height: u32, rgb: &[u8]) -> Frame {
    Frame {
        width,
        height,
        rgb: rgb.to_vec(),
        captured_at: std::time::SystemTime::now(),
        sequence: 0,
    }
}

/// Two seeded hard cells, 5 views each: every mask's IoU and the 5-view pose error.
#[test]
fn builtin_segments_hard_frames_and_calibrates_from_rgb_alone() {
    let robot = Arc::new(common::load_robot("xarm6"));
    let segmenter = easyhec::segment::build(
        &SegmenterConfig::by_name("builtin").unwrap(),
        std::path::Path::new("run.json"),
    )
    .unwrap();
    let mut ious = Vec::new();
    for seed in [1u64, 2] {
        let cell = generate_frames(
            &robot,
            &SynthOptions {
                seed,
                views: 5,
                ..SynthOptions::default()
            },
            &SceneSettings::hard(),
        )
        .unwrap();
        let scene = &cell.scene;
        let (w, h) = (scene.camera.width, scene.camera.height);
        let frames: Vec<Frame> = cell.frames.iter().map(|f| frame_of(w, h, &f.rgb)).collect();
        let refs: Vec<&Frame> = frames.iter().collect();
        let robots: Vec<PosedRobot> = scene
            .recorded_joints
            .iter()
            .map(|q| PosedRobot::new(&robot, q))
            .collect();
        let guess = scene.initial_guess.unwrap();
        let settled = segment_and_solve(
            &CpuRenderer,
            &scene.camera,
            segmenter.as_ref(),
            &refs,
            &robots,
            &|_| Ok(guess),
            Some((&guess, 80.0)),
            8.0,
            4.0,
            &SolveOptions::default(),
            4,
        )
        .unwrap();
        for (m, f) in settled.masks.iter().zip(&cell.frames) {
            ious.push(m.iou(&f.truth_mask));
        }
        let rot = rotation_error_deg(&settled.report.camera_from_base, &scene.camera_from_base);
        let trans = translation_error_mm(&settled.report.camera_from_base, &scene.camera_from_base);
        eprintln!(
            "seed {seed}: {rot:.4} deg {trans:.3} mm, {} rounds",
            settled.rounds
        );
        assert!(
            rot <= 0.08 && trans <= 1.5,
            "seed {seed}: RGB-only calibration off by {rot:.4} deg / {trans:.3} mm (bound 0.08 deg / 1.5 mm)"
        );
    }
    ious.sort_by(f64::total_cmp);
    let median = ious[ious.len() / 2];
    eprintln!("IoU {ious:?}");
    // The issue asks for a median of 0.95 over 20 cells; with the full hard preset (person-like
    // arms reaching in included) the 20-cell median is 0.946 and these two cells give 0.94.
    // This guards the present level, it does not claim the target.
    assert!(median >= 0.93, "median IoU {median:.4} < 0.93: {ious:?}");
}

/// A seeded default-dressing cell of 5 views and its frames without the truth side channel.
fn plate_cell(seed: u64) -> (easyhec::synth::ImagedScene, Vec<Frame>) {
    let robot = Arc::new(common::load_robot("xarm6"));
    let cell = generate_frames(
        &robot,
        &SynthOptions {
            seed,
            views: 5,
            ..SynthOptions::default()
        },
        &SceneSettings::default(),
    )
    .unwrap();
    let (w, h) = (cell.scene.camera.width, cell.scene.camera.height);
    let frames = cell.frames.iter().map(|f| frame_of(w, h, &f.rgb)).collect();
    (cell, frames)
}

/// Every frame without a prior.
fn without_prior(frames: &[Frame]) -> Vec<ViewInput<'_>> {
    frames
        .iter()
        .map(|frame| ViewInput {
            frame,
            prior: None,
            band_px: 8.0,
        })
        .collect()
}

/// Without any prior, a robot that moves between views is found from the background plate
/// alone, and a single frame without a prior is refused with a reason, never guessed.
#[test]
fn builtin_needs_context_and_uses_the_plate() {
    let (cell, frames) = plate_cell(3);
    let segmenter = easyhec::segment::build(
        &SegmenterConfig::by_name("builtin").unwrap(),
        std::path::Path::new("run.json"),
    )
    .unwrap();
    let err = segmenter.segment(&frames[0]).unwrap_err().to_string();
    assert!(err.contains("initial_guess"), "{err}");
    let inputs = without_prior(&frames);
    let masks: Vec<Mask> = segmenter.segment_views(&inputs).unwrap();
    // The moving links are found; only the links that never move (the base) can be missed.
    for (m, f) in masks.iter().zip(&cell.frames) {
        let inside = m
            .data
            .iter()
            .zip(&f.truth_mask.data)
            .filter(|(&a, &t)| a != 0 && t != 0)
            .count();
        let precision = inside as f64 / m.count().max(1) as f64;
        assert!(precision > 0.85, "plate-only precision {precision:.3}");
        assert!(
            m.iou(&f.truth_mask) > 0.4,
            "plate-only IoU {:.3}",
            m.iou(&f.truth_mask)
        );
    }
}

/// The evidence the builtin segmenter exposes (change and colour log-odds, no prior) scores
/// the true silhouette above the same silhouette moved 25 px: the region score that chooses a
/// view's joints when its recorded ones do not describe its image (docs/benchmarks.md, the Panda example).
/// Default frames: on the hard preset (seed 4) one of the twenty moved silhouettes outscores
/// the truth, so evidence without a prior is a selector among candidates, not a segmentation.
#[test]
fn builtin_evidence_scores_the_true_silhouette_highest() {
    let (cell, frames) = plate_cell(4);
    let (w, h) = (cell.scene.camera.width, cell.scene.camera.height);
    let inputs = without_prior(&frames);
    let params = easyhec::segment::BuiltinParams::default();
    let easyhec::segment::Evidence {
        masks,
        log_odds: evidence,
    } = easyhec::segment::builtin::segment_views_with_evidence(&inputs, &params).unwrap();
    assert_eq!(
        masks,
        easyhec::segment::builtin::segment_views(&inputs, &params).unwrap()
    );
    let score = easyhec::segment::builtin::evidence_over;
    for (k, (f, e)) in cell.frames.iter().zip(&evidence).enumerate() {
        assert_eq!(e.len(), (w * h) as usize);
        let truth = score(&f.truth_mask, e);
        for (dx, dy) in [(25i64, 0i64), (-25, 0), (0, 25), (0, -25)] {
            let mut moved = Mask::new(w, h);
            for y in 0..h {
                for x in 0..w {
                    moved.set(x, y, f.truth_mask.get(i64::from(x) - dx, i64::from(y) - dy));
                }
            }
            let other = score(&moved, e);
            assert!(
                truth > other,
                "view {k}: evidence over the truth {truth:.0} <= moved ({dx}, {dy}) px {other:.0}"
            );
        }
        assert!(truth > 0.0, "view {k}: evidence over the truth {truth:.0}");
    }
}

/// `easyhec solve --segmenter builtin --ignore-masks` on a hard synthetic run, through the CLI:
/// the pose must land within the RGB-only loop's bound (0.08°) and 2 mm (the synthetic runs'
/// guesses are up to 7 cm off) of the run's `ground_truth.json`.
fn assert_images_alone_land_on_the_truth(seed: u64) {
    assert_images_alone_land_on_the_truth_of(seed, &["--images", "hard"]);
}

/// [`assert_images_alone_land_on_the_truth`] for a run synthesised with `synth_args` added;
/// returns the solve's standard error.
fn assert_images_alone_land_on_the_truth_of(seed: u64, synth_args: &[&str]) -> String {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let urdf = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots/xarm6/robot.urdf");
    let status = std::process::Command::new(common::easyhec_bin())
        .args([
            "synth",
            "--seed",
            &seed.to_string(),
            "--no-noise",
            "--robot",
        ])
        .arg(&urdf)
        .args(synth_args)
        .arg("--out")
        .arg(&run)
        .status()
        .unwrap();
    assert!(status.success());
    let out = common::solve_run(
        &run,
        &[
            "--segmenter",
            "builtin",
            "--ignore-masks",
            "--renderer",
            "cpu",
        ],
    );
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{stderr}");
    let result = easyhec::run::ResultFile::read(&run.join("result.json")).unwrap();
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("ground_truth.json")).unwrap())
            .unwrap();
    let rows: [[f64; 4]; 4] = serde_json::from_value(truth["camera_from_base"].clone()).unwrap();
    let truth = easyhec::geometry::from_rows(&rows).unwrap();
    let est = result.camera_from_base();
    let (rot, trans) = (
        rotation_error_deg(&est, &truth),
        translation_error_mm(&est, &truth),
    );
    eprintln!("seed {seed}: {rot:.4} deg {trans:.3} mm");
    assert!(
        rot <= 0.08 && trans <= 2.0,
        "seed {seed}: {rot:.4} deg {trans:.3} mm\n{stderr}"
    );
    // The builtin masks' result carries the segmentation term; its bound holds the truth.
    let u = result.uncertainty.as_ref().unwrap();
    assert!(
        u.terms
            .as_ref()
            .unwrap()
            .segmentation_centre_95_mm
            .is_some(),
        "{u:?}"
    );
    let centre_mm = easyhec::geometry::camera_centre_error_mm(&est, &truth);
    assert!(
        centre_mm <= u.camera_centre_95_mm.unwrap(),
        "{centre_mm} mm: {u:?}"
    );
    stderr
}

/// A run solved from the masks it records gets no segmentation term: there is no segmenter's
/// evidence to measure it from, and those masks' errors are the view jackknife's to find.
#[test]
fn recorded_masks_carry_no_segmentation_term() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    common::synth_run(&run, "xarm6", &["--seed", "2"]);
    let out = common::solve_run(&run, &["--renderer", "cpu"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let result = easyhec::run::ResultFile::read(&run.join("result.json")).unwrap();
    let terms = result.uncertainty.unwrap().terms.unwrap();
    assert!(terms.segmentation_centre_95_mm.is_none(), "{terms:?}");
    assert_ne!(terms.dominant, "segmentation");
}

/// Seed 5: moving distractors pull a plate-only first solve 15° off a guess 4° / 23 mm away
/// (the settled fit was IoU 0.42). The poor fit sends round 0 back under the guess's prior,
/// and the pose lands on the truth.
#[test]
fn a_poor_plate_only_start_is_redone_under_the_guess() {
    // Measured 0.027° / 0.93 mm (before: 14.8° / 222 mm).
    assert_images_alone_land_on_the_truth(5);
}

/// Seed 3: the masks of the final (4 px) band are drawn around the settled pose's render;
/// the solve after segmentation starts from that pose. Started back at the guess it stopped in
/// another basin, 5.9° / 29 mm off with view 3 at IoU 0.24.
#[test]
fn the_solve_after_segmentation_starts_from_the_settled_pose() {
    // Measured 0.004° / 0.02 mm.
    assert_images_alone_land_on_the_truth(3);
}

/// With no guess, the first, plate-only masks of the plain simulated scene fit no hypothesis
/// (the mask-fit initialisation gave up at IoU 0.64–0.73 on seeds 1–4); the solve starts from
/// the pose that explains what changed between the views instead, and lands on the truth.
#[test]
fn with_no_guess_images_alone_start_from_what_changed() {
    // Measured 0.009° / 0.07 mm.
    let stderr =
        assert_images_alone_land_on_the_truth_of(1, &["--images", "easy", "--no-initial-guess"]);
    assert!(stderr.contains("explains what changed"), "{stderr}");
}

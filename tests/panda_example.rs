//! The real Panda example (`../shared/datasets/easyhec_franka_offline_example`): most of its
//! recorded joint vectors do not describe the arm in their image (docs/benchmarks.md, "The Panda example").
//! The solve must find the views that agree, say which it left out, and land on the same pose
//! with and without the example's `initial_guess.txt`.

mod common;

use std::path::{Path, PathBuf};

use easyhec::geometry::{rotation_error_deg, translation_error_mm};
use easyhec::mask::Mask;
use easyhec::run::ResultFile;

fn example() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/datasets/easyhec_franka_offline_example")
}

fn import(out: &Path) {
    let status = std::process::Command::new(common::easyhec_bin())
        .args(["import", "easyhec"])
        .arg(example())
        .arg("--out")
        .arg(out)
        .arg("--urdf")
        .arg(common::robot_urdf("panda"))
        .args(["--ignore-links", "panda_leftfinger,panda_rightfinger"])
        .status()
        .expect("easyhec runs");
    assert!(status.success(), "import failed");
}

#[test]
fn panda_example_solves_to_the_same_pose_with_and_without_its_guess() {
    let dir = tempfile::tempdir().unwrap();
    let guessed = dir.path().join("guess");
    import(&guessed);
    let unguessed = dir.path().join("noguess");
    import(&unguessed);
    let path = unguessed.join("run.json");
    let mut doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    assert!(doc
        .as_object_mut()
        .unwrap()
        .remove("initial_guess")
        .is_some());
    std::fs::write(&path, serde_json::to_string_pretty(&doc).unwrap()).unwrap();

    let mut results = Vec::new();
    for run in [&guessed, &unguessed] {
        let out = common::solve_run(run, &["--renderer", "cpu"]);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{stderr}");
        assert!(stderr.contains("left out"), "{stderr}");
        let result = ResultFile::read(&run.join("result.json")).unwrap();
        assert!(
            result.views_used.len() >= 2 && result.per_view.iter().all(|v| v.iou >= 0.85),
            "{:?}",
            result.per_view
        );
        results.push(result.camera_from_base());
    }
    let (rot, trans) = (
        rotation_error_deg(&results[0], &results[1]),
        translation_error_mm(&results[0], &results[1]),
    );
    assert!(
        rot <= 0.5 && trans <= 5.0,
        "with vs without the guess: {rot:.3} deg, {trans:.2} mm apart"
    );
}

/// Images only, on real photographs: with the example's masks withheld, `--segmenter builtin`
/// must draw masks at mean IoU ≥ 0.85 against the hand-annotated ones, and the calibration
/// from the images alone must land within 0.5° / 5 mm of the calibration from those masks.
/// Only two of the ten views' joints describe their images, so this passes only if the
/// segmenter's view-pair search finds them from the pictures.
#[test]
fn panda_images_alone_match_the_provided_masks_calibration() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    import(&run);
    let out = common::solve_run(&run, &["--renderer", "cpu"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let provided = ResultFile::read(&run.join("result.json"))
        .unwrap()
        .camera_from_base();

    let masks = dir.path().join("masks");
    std::fs::create_dir_all(&masks).unwrap();
    let out = common::solve_run(
        &run,
        &[
            "--segmenter",
            "builtin",
            "--ignore-masks",
            "--renderer",
            "cpu",
            "--masks-out",
            masks.to_str().unwrap(),
        ],
    );
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{stderr}");
    let images_only = ResultFile::read(&run.join("result.json")).unwrap();

    let ious: Vec<f64> = (0..10)
        .map(|i| {
            let drawn = Mask::load(&masks.join(format!("{i:03}.mask.png"))).unwrap();
            let annotated = Mask::load(&example().join(format!("mask/{i:06}.png"))).unwrap();
            drawn.iou(&annotated)
        })
        .collect();
    let mean = ious.iter().sum::<f64>() / ious.len() as f64;
    assert!(
        mean >= 0.85,
        "builtin masks: mean IoU {mean:.3} ({ious:.3?})\n{stderr}"
    );

    let pose = images_only.camera_from_base();
    let (rot, trans) = (
        rotation_error_deg(&pose, &provided),
        translation_error_mm(&pose, &provided),
    );
    assert!(
        rot <= 0.5 && trans <= 5.0,
        "images alone vs provided masks: {rot:.3} deg, {trans:.2} mm apart (views {:?})\n{stderr}",
        images_only.views_used
    );
}

//! The real Panda example (`../shared/datasets/easyhec_franka_offline_example`): most of its
//! recorded joint vectors do not describe the arm in their image (README, "The Panda example").
//! The solve must find the views that agree, say which it left out, and land on the same pose
//! with and without the example's `initial_guess.txt`.

mod common;

use std::path::{Path, PathBuf};

use easyhec::geometry::{rotation_error_deg, translation_error_mm};
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

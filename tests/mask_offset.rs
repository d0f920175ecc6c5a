//! A segmenter that draws every mask a pixel fat pulls a plain solve towards the camera by
//! centimetres: the silhouette grows, and moving closer is how the pose makes it grow. With
//! `estimate_mask_offset` the solve fits the outline offset beside the pose, reports it with
//! its sigma, and lands where the true camera is (docs/uncertainty.md, "Mask bias").

mod common;

use easyhec::bench::seeded_scene;
use easyhec::config::NoiseModel;
use easyhec::geometry::{camera_centre_error_mm, translation_error_mm};
use easyhec::mask::Mask;
use easyhec::render::CpuRenderer;
use easyhec::solve::{solve, with_view_disagreement, SolveOptions};
use easyhec::synth::SynthOptions;

/// Translation error (mm) and the report of a 3-view solve of a `fat` scene.
fn solve_fat_scene(seed: u64, estimate: bool) -> (f64, easyhec::solve::SolveReport) {
    let robot = common::load_robot("xarm6");
    let synth = SynthOptions {
        noise: NoiseModel::fat(),
        ..Default::default()
    };
    let (scene, views, init) = seeded_scene(&robot, seed, 3, &synth).unwrap();
    let opts = SolveOptions {
        estimate_mask_offset: estimate,
        ..SolveOptions::default()
    };
    let report = solve(&CpuRenderer, &scene.camera, &views, &init, &opts).unwrap();
    let report = with_view_disagreement(&CpuRenderer, &scene.camera, &views, report, &opts);
    let error = translation_error_mm(&report.camera_from_base, &scene.camera_from_base);
    let centre = camera_centre_error_mm(&report.camera_from_base, &scene.camera_from_base);
    assert!(centre.is_finite());
    (error, report)
}

#[test]
fn a_fat_segmenter_is_fitted_as_an_offset_not_as_a_closer_camera() {
    for seed in [1u64, 2] {
        let (plain, plain_report) = solve_fat_scene(seed, false);
        let (fitted, report) = solve_fat_scene(seed, true);
        assert!(plain_report.mask_offset.is_none());
        let offset = report.mask_offset.expect("the offset was estimated");
        // The preset moves the whole outline 1 px outward (on top of 0.5 px of jitter).
        assert!(
            (offset.px - 1.0).abs() < 0.3 && offset.sigma_px > 0.0 && offset.sigma_px < 0.3,
            "seed {seed}: offset {offset:?}"
        );
        assert!(
            plain > 4.0 && fitted < 1.5,
            "seed {seed}: {plain:.2} mm without the offset, {fitted:.2} mm with it"
        );
        // What not knowing the offset costs is in the reported uncertainty.
        let bound = report.mask_bias_bound_mm().unwrap();
        assert!(bound > 0.0 && bound.is_finite(), "seed {seed}: {bound}");
    }
}

#[test]
fn an_offset_mask_moves_its_outline_by_whole_pixels() {
    let mut square = Mask::new(40, 40);
    for v in 10..30 {
        for u in 10..30 {
            square.set(u, v, true);
        }
    }
    let count = |m: &Mask| m.data.iter().filter(|&&p| p != 0).count();
    assert_eq!(count(&square.with_outline_offset(0.0)), 400);
    assert_eq!(count(&square.with_outline_offset(1.0)), 22 * 22);
    assert_eq!(count(&square.with_outline_offset(-1.0)), 18 * 18);
    assert_eq!(count(&square.with_outline_offset(0.3)), 400);
}

#[test]
fn the_adam_baseline_refuses_to_fit_an_offset() {
    let out = std::process::Command::new(common::easyhec_bin())
        .args([
            "solve",
            "no-such-run",
            "--optimizer",
            "adam",
            "--estimate-mask-offset",
        ])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(
        stderr.contains("--estimate-mask-offset") && stderr.trim().lines().count() == 1,
        "{stderr}"
    );
}

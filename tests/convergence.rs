//! The default solver converges from rough starts: 10° and 15 cm off (issue acceptance), on
//! noisy synthetic xArm6 scenes.

mod common;

use easyhec::bench::scene_views;
use easyhec::geometry::{rotation_error_deg, translation_error_mm};
use easyhec::render::CpuRenderer;
use easyhec::solve::{solve, SolveOptions};
use easyhec::synth::{generate, SynthOptions};

#[test]
fn converges_from_10_degrees_and_15_cm_off() {
    let robot = common::load_robot("xarm6");
    for seed in [21, 22, 23, 24] {
        let scene = generate(
            &robot,
            &SynthOptions {
                seed,
                views: 3,
                initial_error: Some(((10.0, 10.0), (0.15, 0.15))),
                ..Default::default()
            },
        )
        .unwrap();
        let init = scene.initial_guess.unwrap();
        assert!((rotation_error_deg(&init, &scene.camera_from_base) - 10.0).abs() < 1e-6);
        assert!((translation_error_mm(&init, &scene.camera_from_base) - 150.0).abs() < 1e-3);
        let views = scene_views(&robot, &scene);
        let report = solve(
            &CpuRenderer,
            &scene.camera,
            &views,
            &init,
            &SolveOptions::default(),
        )
        .unwrap();
        let (rot, trans) = (
            rotation_error_deg(&report.camera_from_base, &scene.camera_from_base),
            translation_error_mm(&report.camera_from_base, &scene.camera_from_base),
        );
        assert!(
            rot < 0.15 && trans < 1.5,
            "seed {seed}: {rot:.4} deg, {trans:.3} mm after starting 10 deg / 150 mm off"
        );
    }
}

//! The wgpu backend against the CPU reference: masks, gradients, a solve and an exploration
//! round on fixed seeds. Runs on whatever adapter wgpu finds (lavapipe in CI); under CI
//! (`CI=true`) a missing adapter fails the test, elsewhere it is reported and skipped.
#![cfg(feature = "wgpu")]

mod common;

use easyhec::camera::Intrinsics;
use easyhec::explore::{camera_candidates, ExploreOptions};
use easyhec::geometry::{
    exp_se3, look_at_camera_from_base, rotation_error_deg, translation_error_mm, Twist,
};
use easyhec::gpu::{AdapterPolicy, WgpuRenderer};
use easyhec::objective::loss_gradient;
use easyhec::render::{CpuRenderer, PosedRobot, SilhouetteRenderer};
use easyhec::robot::RobotModel;
use easyhec::scoring::BatchScoring;
use easyhec::solve::{solve, SolveOptions};
use easyhec::synth::{generate, SynthOptions};
use nalgebra::Vector3;
use rand::{Rng, SeedableRng};

fn gpu() -> Option<WgpuRenderer> {
    match WgpuRenderer::new(AdapterPolicy::Any) {
        Ok(mut r) => {
            // Everything on the GPU, however small.
            r.set_min_pixels(0);
            eprintln!("wgpu adapter: {}", r.adapter());
            Some(r)
        }
        Err(e) => {
            assert!(
                std::env::var("CI").is_err(),
                "no wgpu adapter under CI (./test installs mesa-vulkan-drivers): {e}"
            );
            eprintln!("SKIPPED: {e}");
            None
        }
    }
}

fn random_view(
    robot: &RobotModel,
    rng: &mut impl Rng,
) -> (Vec<f64>, PosedRobot, nalgebra::Isometry3<f64>) {
    let q: Vec<f64> = robot
        .joint_limits()
        .iter()
        .map(|&(lo, hi)| rng.random_range(lo.max(-3.0)..=hi.min(3.0)))
        .collect();
    let posed = PosedRobot::new(robot, &q);
    let az: f64 = rng.random_range(0.0..std::f64::consts::TAU);
    let d = rng.random_range(0.9..1.6);
    let eye = Vector3::new(d * az.cos(), d * az.sin(), rng.random_range(0.3..1.1));
    let pose = look_at_camera_from_base(&eye, &Vector3::new(0.0, 0.0, 0.35), &Vector3::z());
    (q, posed, pose)
}

#[test]
fn masks_agree_with_the_cpu_on_all_four_robots() {
    let Some(gpu) = gpu() else { return };
    let cam = Intrinsics::pinhole(640, 480, 560.0, 560.0, 319.5, 239.5);
    for name in ["xarm6", "xarm7", "ur5e", "panda"] {
        let robot = common::load_robot(name);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let views: Vec<_> = (0..8).map(|_| random_view(&robot, &mut rng)).collect();
        let mut worst_all: f64 = 1.0;
        let mut worst_robot: f64 = 1.0;
        for (_, posed, pose) in &views {
            let cpu = CpuRenderer.render(posed, &cam, pose, None).mask;
            let wgpu = gpu.render(posed, &cam, pose, None).mask;
            let differ = cpu
                .data
                .iter()
                .zip(&wgpu.data)
                .filter(|(a, b)| a != b)
                .count();
            assert!(cpu.count() > 1000, "{name}: robot barely visible");
            worst_all = worst_all.min(1.0 - differ as f64 / cpu.data.len() as f64);
            worst_robot = worst_robot.min(1.0 - differ as f64 / cpu.count() as f64);
        }
        eprintln!(
            "{name}: worst agreement {:.5} of all pixels, {:.5} of robot pixels",
            worst_all, worst_robot
        );
        assert!(worst_all >= 0.999, "{name}: {worst_all:.5} of pixels agree");
        assert!(
            worst_robot >= 0.995,
            "{name}: differing pixels are {:.3}% of the robot",
            (1.0 - worst_robot) * 100.0
        );
    }
}

#[test]
fn batched_views_match_single_views() {
    let Some(gpu) = gpu() else { return };
    let cam = Intrinsics::pinhole(320, 240, 280.0, 280.0, 159.5, 119.5);
    let robot = common::load_robot("ur5e");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let (_, a, pose) = random_view(&robot, &mut rng);
    let (_, b, _) = random_view(&robot, &mut rng);
    let many = gpu.render_many(&[&a, &b, &a], &cam, &pose, None);
    assert_eq!(many.len(), 3);
    assert_eq!(many[0].mask, gpu.render(&a, &cam, &pose, None).mask);
    assert_eq!(many[1].mask, gpu.render(&b, &cam, &pose, None).mask);
    assert_eq!(many[0].mask, many[2].mask);
    assert_ne!(many[0].mask, many[1].mask, "two poses, two silhouettes");
}

#[test]
fn gradients_agree_with_the_cpu_within_two_percent() {
    let Some(gpu) = gpu() else { return };
    let cam = Intrinsics::pinhole(640, 480, 560.0, 560.0, 319.5, 239.5);
    for name in ["xarm6", "xarm7", "ur5e", "panda"] {
        let robot = common::load_robot(name);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let mut worst: f64 = 0.0;
        for _ in 0..4 {
            let (_, posed, truth) = random_view(&robot, &mut rng);
            let observed = CpuRenderer.render(&posed, &cam, &truth, None).mask;
            let xi = Twist::from_fn(|i, _| {
                if i < 3 {
                    rng.random_range(-0.01..0.01)
                } else {
                    rng.random_range(-0.015..0.015)
                }
            });
            let pose = exp_se3(&xi) * truth;
            let g_cpu = loss_gradient(
                &CpuRenderer.render(&posed, &cam, &pose, Some(1.0)),
                &observed,
                &cam,
            );
            let g_gpu = loss_gradient(&gpu.render(&posed, &cam, &pose, Some(1.0)), &observed, &cam);
            let rel = (g_gpu - g_cpu).norm() / g_cpu.norm();
            worst = worst.max(rel);
        }
        eprintln!("{name}: worst relative gradient difference {:.4}", worst);
        assert!(worst <= 0.02, "{name}: gradient differs by {worst:.4}");
    }
}

#[test]
fn a_solve_lands_on_the_same_pose() {
    let Some(gpu) = gpu() else { return };
    let robot = common::load_robot("xarm6");
    let seed = 2;
    let scene = generate(
        &robot,
        &SynthOptions {
            seed,
            views: 5,
            ..SynthOptions::default()
        },
    )
    .expect("scene");
    let views = easyhec::bench::scene_views(&robot, &scene);
    let start = scene.initial_guess.expect("guess");
    let opts = SolveOptions::default();
    let cpu = solve(&CpuRenderer, &scene.camera, &views, &start, &opts).expect("cpu solve");
    let wgpu = solve(&gpu, &scene.camera, &views, &start, &opts).expect("wgpu solve");
    let (dr, dt) = (
        rotation_error_deg(&cpu.camera_from_base, &wgpu.camera_from_base),
        translation_error_mm(&cpu.camera_from_base, &wgpu.camera_from_base),
    );
    eprintln!(
        "seed {seed}: cpu vs wgpu {dr:.5} deg, {dt:.4} mm (cpu error {:.4} deg)",
        rotation_error_deg(&cpu.camera_from_base, &scene.camera_from_base)
    );
    assert!(
        dr <= 0.005 && dt <= 0.1,
        "seed {seed}: {dr:.5} deg, {dt:.4} mm apart"
    );
}

#[test]
fn an_exploration_round_scores_alike_and_picks_the_same_sample() {
    let Some(gpu) = gpu() else { return };
    let robot = common::load_robot("xarm6");
    let scene = generate(
        &robot,
        &SynthOptions {
            seed: 4,
            views: 2,
            ..SynthOptions::default()
        },
    )
    .expect("scene");
    let views = easyhec::bench::scene_views(&robot, &scene);
    let report = solve(
        &CpuRenderer,
        &scene.camera,
        &views,
        &scene.initial_guess.expect("guess"),
        &SolveOptions::default(),
    )
    .expect("solve");
    let mut widened = report.clone();
    widened.covariance *= 400.0;
    let candidates = camera_candidates(&widened, &ExploreOptions::default());
    let low = scene.camera.undistorted().downsampled(4);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
    // Both pool shapes exploration uses: one shared coarse mesh (the closed loop's
    // `CoarseRobot`) and a mesh decimated per pose (`choose_next`, `solve --select explore`).
    let coarse = easyhec::render::CoarseRobot::new(&robot, 0.004);
    let (mut shared, mut own) = (Vec::new(), Vec::new());
    for _ in 0..150 {
        let q: Vec<f64> = robot
            .joint_limits()
            .iter()
            .map(|&(lo, hi)| rng.random_range(lo.max(-3.0)..=hi.min(3.0)))
            .collect();
        shared.push(coarse.pose(&robot, &q));
        own.push(PosedRobot::new(&robot, &q).decimated(0.004));
    }
    for pool in [shared, own] {
        exploration_scores_agree(&gpu, &low, &pool, &candidates);
    }
}

fn exploration_scores_agree(
    gpu: &WgpuRenderer,
    low: &Intrinsics,
    pool: &[PosedRobot],
    candidates: &[nalgebra::Isometry3<f64>],
) {
    let refs: Vec<&PosedRobot> = pool.iter().collect();
    let cpu = CpuRenderer.disagreement_many(low, &refs, candidates);
    let wgpu = gpu.disagreement_many(low, &refs, candidates);
    assert_eq!(cpu.len(), wgpu.len());
    let argmax = |v: &[f64]| {
        v.iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .map(|(i, _)| i)
    };
    let worst = cpu
        .iter()
        .zip(&wgpu)
        .map(|(a, b)| (a - b).abs() / a.max(1.0))
        .fold(0.0, f64::max);
    eprintln!(
        "exploration: best cpu {:?} ({:.2}) wgpu {:?} ({:.2}); worst relative score difference {worst:.4}",
        argmax(&cpu),
        argmax(&cpu).map(|i| cpu[i]).unwrap_or(0.0),
        argmax(&wgpu),
        argmax(&wgpu).map(|i| wgpu[i]).unwrap_or(0.0),
    );
    assert!(cpu.iter().any(|&s| s > 1.0), "candidates must disagree");
    assert_eq!(argmax(&cpu), argmax(&wgpu), "same chosen joint sample");
    assert!(worst <= 0.02, "scores differ by {worst:.4}");
}

/// The refinement's batched scores: every (pose, view) count of band pixels whose coverage
/// differs from the observation, GPU against the CPU rasteriser, on views whose observation
/// is the silhouette at a nearby pose and whose band is half the image.
#[test]
fn band_mismatch_counts_agree_with_the_cpu() {
    let Some(gpu) = gpu() else { return };
    let cam = Intrinsics::pinhole(640, 480, 560.0, 560.0, 319.5, 239.5);
    let robot = common::load_robot("xarm6");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let views: Vec<_> = (0..3).map(|_| random_view(&robot, &mut rng)).collect();
    // One camera pose for all views, as in a solve: the first view's.
    let centre = views[0].2;
    let near = exp_se3(&Twist::new(0.004, -0.003, 0.01, 0.004, -0.003, 0.002)) * centre;
    let observed: Vec<Vec<u8>> = views
        .iter()
        .map(|(_, posed, _)| CpuRenderer.render(posed, &cam, &near, None).mask.data)
        .collect();
    // The band: the left half of every row.
    let band_mask: Vec<u8> = (0..cam.width * cam.height)
        .map(|i| u8::from(i % cam.width < cam.width / 2))
        .collect();
    let poses: Vec<_> = (0..16)
        .map(|k| {
            let s = f64::from(k) / 16.0;
            exp_se3(&Twist::new(
                0.01 * s,
                0.0,
                -0.02 * s,
                0.0,
                0.006 * s,
                -0.004 * s,
            )) * centre
        })
        .collect();
    let robots: Vec<&PosedRobot> = views.iter().map(|v| &v.1).collect();
    let bands: Vec<&[u8]> = views.iter().map(|_| band_mask.as_slice()).collect();
    let observed_refs: Vec<&[u8]> = observed.iter().map(|o| o.as_slice()).collect();
    let counts = gpu
        .band_mismatches_on_gpu(&cam, &robots, &bands, &observed_refs, &poses)
        .expect("the wgpu backend batches band scores");
    assert_eq!(counts.len(), poses.len() * views.len());
    // The trait method takes the same GPU path; the CPU reference counts in band windows.
    assert_eq!(
        gpu.band_mismatches(&cam, &robots, &bands, &observed_refs, &poses),
        counts
    );
    let cpu_counts = CpuRenderer.band_mismatches(&cam, &robots, &bands, &observed_refs, &poses);
    let mut distinct = std::collections::BTreeSet::new();
    for (s, pose) in poses.iter().enumerate() {
        for (v, posed) in robots.iter().enumerate() {
            let rendered = CpuRenderer.render(posed, &cam, pose, None).mask;
            let covered = rendered.count();
            let want = (0..rendered.data.len())
                .filter(|&i| band_mask[i] != 0 && (rendered.data[i] != 0) != (observed[v][i] != 0))
                .count();
            let got = counts[s * views.len() + v] as usize;
            assert_eq!(
                cpu_counts[s * views.len() + v] as usize,
                want,
                "pose {s} view {v}"
            );
            assert!(covered > 1000, "view {v}: robot barely visible");
            // The GPU applies the CPU's rule in f32: ties on pixel centres may differ.
            assert!(
                got.abs_diff(want) <= 2 + covered / 1000,
                "pose {s} view {v}: GPU {got} vs CPU {want} mismatching pixels"
            );
            distinct.insert(want);
        }
    }
    assert!(
        distinct.len() > 10,
        "the poses barely change the counts: {distinct:?}"
    );
}

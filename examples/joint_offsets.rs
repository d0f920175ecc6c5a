//! Experiment behind the README's Panda note: can one constant offset per joint, estimated together
//! with the camera pose, make the example's masks fit? `cargo run --release --example
//! joint_offsets -- RUN_DIR` (a run imported from the Panda example). Answer: 0.68 -> 0.71 IoU.

use easyhec::render::{CpuRenderer, PosedRobot, SilhouetteRenderer};
use easyhec::run::load_run;
use easyhec::solve::{solve, SolveOptions, View};
use std::path::Path;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let run = load_run(Path::new(&args[1])).unwrap();
    let r = CpuRenderer;
    let cam = run.camera.undistorted();
    let mut offs = vec![0.0f64; 7];
    let mut pose = run.initial_guess.unwrap();
    let views_with = |offs: &[f64]| -> Vec<View> {
        run.views
            .iter()
            .map(|v| {
                let mut q = v.joints.clone();
                for j in 0..7 {
                    q[j] += offs[j];
                }
                View {
                    robot: PosedRobot::new(&run.robot, &q),
                    observed: v.observed.clone(),
                }
            })
            .collect()
    };
    let score = |views: &[View], pose: &easyhec::nalgebra::Isometry3<f64>| -> (f64, Vec<f64>) {
        let ious: Vec<f64> = views
            .iter()
            .map(|v| r.render(&v.robot, &cam, pose, None).mask.iou(&v.observed))
            .collect();
        (ious.iter().sum::<f64>() / ious.len() as f64, ious)
    };
    for round in 0..6 {
        let views = views_with(&offs);
        let rep = solve(&r, &cam, &views, &pose, &SolveOptions::default()).unwrap();
        pose = rep.camera_from_base;
        let (s, _) = score(&views, &pose);
        println!(
            "round {round} after solve: mean IoU {s:.4} offs {:?}",
            offs.iter().map(|o| o.to_degrees()).collect::<Vec<_>>()
        );
        for j in 0..7 {
            let mut best = (score(&views_with(&offs), &pose).0, offs[j]);
            for k in -20..=20 {
                let mut o = offs.clone();
                o[j] = offs[j] + (k as f64) * 0.75f64.to_radians();
                let s = score(&views_with(&o), &pose).0;
                if s > best.0 {
                    best = (s, o[j]);
                }
            }
            offs[j] = best.1;
        }
        let (s, ious) = score(&views_with(&offs), &pose);
        println!(
            "round {round} after offsets: mean IoU {s:.4} {:?}",
            ious.iter()
                .map(|x| (x * 100.0).round() / 100.0)
                .collect::<Vec<_>>()
        );
    }
}

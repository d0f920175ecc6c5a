//! Experiment behind the README's Panda note: which recorded joint vector does each photograph
//! show? Renders every view's joints at one pose and scores each against every mask.
//! `cargo run --release --example iou_matrix -- RUN_DIR RESULT_OR_TRUTH.json` (any JSON with a
//! `camera_from_base` 4x4: a `result.json`, a `ground_truth.json`).

use easyhec::render::{CpuRenderer, PosedRobot, SilhouetteRenderer};
use easyhec::run::load_run;
use std::path::Path;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let run = load_run(Path::new(&args[1])).unwrap();
    let res: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&args[2]).unwrap()).unwrap();
    let m = &res["camera_from_base"];
    let mut mat = easyhec::nalgebra::Matrix4::<f64>::zeros();
    for i in 0..4 {
        for j in 0..4 {
            mat[(i, j)] = m[i][j].as_f64().unwrap();
        }
    }
    let rot = easyhec::nalgebra::Rotation3::from_matrix(&mat.fixed_view::<3, 3>(0, 0).into_owned());
    let pose = easyhec::nalgebra::Isometry3::from_parts(
        easyhec::nalgebra::Translation3::new(mat[(0, 3)], mat[(1, 3)], mat[(2, 3)]),
        easyhec::nalgebra::UnitQuaternion::from_rotation_matrix(&rot),
    );
    let cam = run.camera.undistorted();
    let r = CpuRenderer;
    print!("mask\\q");
    for p in 0..run.views.len() {
        print!("  q{p}  ");
    }
    println!();
    for k in 0..run.views.len() {
        print!("m{k}    ");
        for p in 0..run.views.len() {
            let rob = PosedRobot::new(&run.robot, &run.views[p].joints);
            let iou = r
                .render(&rob, &cam, &pose, None)
                .mask
                .iou(&run.views[k].observed);
            print!(" {iou:.3}");
        }
        println!();
    }
}

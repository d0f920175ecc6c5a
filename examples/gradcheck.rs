use easyhec::render::SilhouetteRenderer;
use easyhec::*;
use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
fn main() {
    let name = std::env::args().nth(1).unwrap_or("ur5e".into());
    let robot = robot::RobotModel::load(&robot::RobotSource {
        urdf: format!("../shared/robots/{name}/robot.urdf").into(),
        ..Default::default()
    })
    .unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let cam = camera::Camera::pinhole(640, 480, 600.0, 600.0, 319.5, 239.5);
    let q: Vec<f64> = robot
        .joint_limits()
        .iter()
        .map(|&(lo, hi)| rng.random_range(lo.max(-3.0)..=hi.min(3.0)))
        .collect();
    let posed = render::PosedRobot::new(&robot, &q);
    let eye = Vector3::new(1.4, 0.3, 0.7);
    let truth =
        geometry::look_at_camera_from_base(&eye, &Vector3::new(0.0, 0.0, 0.35), &Vector3::z());
    let observed = render::CpuRenderer.render(&posed, &cam, &truth, None).mask;
    let pose = geometry::exp_se3(&geometry::Twist::new(
        0.008, -0.006, 0.004, 0.007, -0.005, 0.003,
    )) * truth;
    let sil = render::CpuRenderer.render(&posed, &cam, &pose, Some(1.0));
    let g = objective::loss_gradient(&sil, &observed, &cam);
    println!("analytic {:?}", g.as_slice());
    for (h, ss) in [(2e-3, 8u32), (1e-3, 8), (5e-4, 16), (2e-4, 16)] {
        let mut fd = geometry::Twist::zeros();
        for k in 0..6 {
            let mut xi = geometry::Twist::zeros();
            xi[k] = h;
            let a = objective::supersampled_loss(
                &posed,
                &cam,
                &(geometry::exp_se3(&xi) * pose),
                &observed,
                ss,
            );
            let b = objective::supersampled_loss(
                &posed,
                &cam,
                &(geometry::exp_se3(&(-xi)) * pose),
                &observed,
                ss,
            );
            fd[k] = (a - b) / (2.0 * h);
        }
        println!(
            "h {h} ss {ss}: fd {:?} rel {:.4}",
            fd.as_slice(),
            (g - fd).norm() / fd.norm()
        );
    }
}

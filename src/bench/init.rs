//! `easyhec bench init`: automatic initialisation (no guess) over seeded cells with the camera
//! anywhere on a hemisphere around the robot.

use std::path::PathBuf;
use std::time::Instant;

use super::{median, scene_views, Report};
use crate::error::{Error, Result};
use crate::init::{initialise, InitOptions};
use crate::render::CpuRenderer;
use crate::robot::RobotModel;
use crate::solve::SolveOptions;
use crate::synth::{generate, SynthOptions};

/// Automatic initialisation (no guess): success rate, errors and time over seeded cells
/// with the camera anywhere on a hemisphere around the robot.
#[derive(clap::Args, Clone, Debug)]
pub struct InitBench {
    /// Robot URDF.
    #[arg(long, default_value = "../shared/robots/xarm6/robot.urdf")]
    pub robot: PathBuf,
    /// Number of cells (seeds 0..N-1).
    #[arg(long, default_value_t = 40, value_parser = clap::value_parser!(u64).range(1..=1000))]
    pub scenes: u64,
    /// Views per cell.
    #[arg(long, default_value_t = 3, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=100))]
    pub views: usize,
    /// Camera distance range, metres.
    #[arg(long, value_delimiter = ',', default_value = "0.6,2.5")]
    pub distance: Vec<f64>,
}

impl InitBench {
    /// Runs the benchmark: per-seed lines go to `log`, the summary into the report.
    pub fn run(&self, log: &mut dyn FnMut(&str)) -> Result<Report> {
        let mut report = Report::default();
        let InitBench {
            robot,
            scenes,
            views,
            distance,
        } = self.clone();
        let model = RobotModel::from_urdf(robot)?;
        let (lo, hi) = match distance.as_slice() {
            [lo, hi] => (*lo, *hi),
            _ => {
                return Err(Error::Usage(
                    "--distance takes MIN,MAX in metres".to_string(),
                ))
            }
        };
        let (mut ok, mut rot, mut trans, mut secs) = (0usize, Vec::new(), Vec::new(), Vec::new());
        for seed in 0..scenes {
            let synth = SynthOptions {
                seed,
                views,
                initial_error: None,
                camera_distance_m: (lo, hi),
                camera_elevation_deg: (0.0, 90.0),
                ..SynthOptions::default()
            };
            let scene = generate(&model, &synth)?;
            let v = scene_views(&model, &scene);
            let t = Instant::now();
            let outcome = initialise(
                &CpuRenderer,
                &scene.camera,
                &v,
                &SolveOptions::default(),
                &InitOptions::default(),
            );
            let dt = t.elapsed().as_secs_f64();
            secs.push(dt);
            match outcome {
                Ok(r) => {
                    let (re, te) = (
                        crate::geometry::rotation_error_deg(
                            &r.camera_from_base,
                            &scene.camera_from_base,
                        ),
                        crate::geometry::translation_error_mm(
                            &r.camera_from_base,
                            &scene.camera_from_base,
                        ),
                    );
                    let good = re <= 0.1 && te <= 2.0;
                    ok += usize::from(good);
                    rot.push(re);
                    trans.push(te);
                    log(&format!(
                        "seed {seed}: {re:.4} deg {te:.3} mm in {dt:.2} s{}",
                        if good {
                            ""
                        } else {
                            "  (outside 0.1 deg / 2 mm)"
                        }
                    ));
                }
                Err(e) => log(&format!("seed {seed}: reported failure in {dt:.2} s: {e}")),
            }
        }
        report.line(format!(
            "auto init, {views} views, camera {lo}-{hi} m on a hemisphere: {ok}/{scenes} within 0.1 deg / 2 mm; median error {:.4} deg {:.3} mm; time median {:.2} s, max {:.2} s",
            median(&rot),
            median(&trans),
            median(&secs),
            secs.iter().copied().fold(0.0, f64::max)
        ));
        Ok(report)
    }
}

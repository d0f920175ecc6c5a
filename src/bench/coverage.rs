//! `easyhec bench coverage`: does the reported uncertainty cover the true error as often as it
//! claims? Over seeded synthetic scenes it counts the camera axes whose true error lies within
//! the reported 2σ (a Gaussian promise of 95.4%) and the scenes whose true camera centre lies
//! within the reported 95% bound, by view count.

use std::path::PathBuf;

use nalgebra::Isometry3;

use super::{median, seeded_scene, Report};
use crate::config::NoiseModel;
use crate::error::{Error, Result};
use crate::geometry::{camera_centre_error_mm, log_se3, rotation_error_deg, translation_error_mm};
use crate::render::CpuRenderer;
use crate::robot::RobotModel;
use crate::solve::{solve, with_view_disagreement, SolveOptions, Uncertainty};
use crate::synth::SynthOptions;

/// One solve's errors against what it reported.
#[derive(Clone, Debug)]
pub struct CoverageTrial {
    /// Scene seed.
    pub seed: u64,
    /// Views used (the scene's first k).
    pub views: usize,
    /// True error per axis in units of the reported 1σ: rotation about camera x, y, z, then
    /// translation along them.
    pub z: [f64; 6],
    /// True camera-centre error, mm.
    pub centre_error_mm: f64,
    /// Reported 95% camera-centre bound, mm.
    pub centre_bound_mm: f64,
    /// Rotation error, degrees.
    pub rotation_deg: f64,
    /// Translation error of `camera_from_base`, mm.
    pub translation_mm: f64,
}

/// Reported uncertainty against the true error over seeded synthetic scenes.
#[derive(clap::Args, Clone, Debug)]
pub struct CoverageBench {
    /// Robot URDF.
    #[arg(long, default_value = "../shared/robots/xarm6/robot.urdf")]
    pub robot: PathBuf,
    /// Number of scenes (seeds 0..N-1).
    #[arg(long, default_value_t = 60, value_parser = clap::value_parser!(u64).range(1..=1000))]
    pub scenes: u64,
    /// View counts to evaluate.
    #[arg(long, value_delimiter = ',', default_value = "1,3,5")]
    pub views: Vec<usize>,
    /// Segmentation-noise preset of the scenes (docs/uncertainty.md).
    #[arg(long, default_value = "segmenter", value_parser = clap::builder::PossibleValuesParser::new(NoiseModel::PRESETS))]
    pub noise: String,
    /// Estimate the masks' outline offset with the pose, as `easyhec solve
    /// --estimate-mask-offset` does.
    #[arg(long)]
    pub mask_offset: bool,
    /// The joint error the solver is told, radians, as `easyhec solve --joint-noise-rad`
    /// (0 to 0.1). By default the scenes' own, as a cell states its arm's in `[calibration]
    /// joint_noise_rad`: it comes with `--noise` (0.5 mrad, but 0.3 for `blurred` and none for
    /// `none`). Set it to see what a wrong statement costs.
    #[arg(long)]
    pub joint_noise_rad: Option<f64>,
    /// Judge the statistical covariance alone, without the view jackknife's inter-view term:
    /// what a result reported before the term, and how much the term adds.
    #[arg(long)]
    pub statistical_only: bool,
    /// Report LM's pose without the posterior refinement: the covariance is the LM
    /// estimator's, so this shows how far it fits that estimator and how much the refinement
    /// gains beyond it.
    #[arg(long)]
    pub no_refine: bool,
}

impl CoverageBench {
    /// Runs the benchmark: per-solve lines go to `log`, the summary table into the report.
    pub fn run(&self, log: &mut dyn FnMut(&str)) -> Result<Report> {
        let noise = NoiseModel::preset(&self.noise).ok_or_else(|| {
            Error::Usage(format!(
                "--noise {}: allowed: {}",
                self.noise,
                NoiseModel::PRESETS.join(", ")
            ))
        })?;
        if self.views.iter().any(|&k| !(1..=20).contains(&k)) {
            return Err(Error::Usage("--views: each count must be 1..=20".into()));
        }
        let joint_noise_rad = self.stated_joint_noise_rad(&noise)?;
        let model = RobotModel::from_urdf(&self.robot)?;
        let synth = SynthOptions {
            noise,
            ..SynthOptions::default()
        };
        let mut trials = Vec::new();
        let opts = self.solve_options(joint_noise_rad);
        let with_inter_view = !self.statistical_only;
        for seed in 0..self.scenes {
            for t in coverage_of_scene(&model, seed, &self.views, &synth, &opts, with_inter_view)? {
                log(&format!(
                    "seed {} views {}: {:.4} deg {:.3} mm; |error|/sigma rot {:.2} {:.2} {:.2} trans {:.2} {:.2} {:.2}; centre {:.3} mm of bound {:.3} mm",
                    t.seed, t.views, t.rotation_deg, t.translation_mm,
                    t.z[0], t.z[1], t.z[2], t.z[3], t.z[4], t.z[5],
                    t.centre_error_mm, t.centre_bound_mm
                ));
                trials.push(t);
            }
        }
        let mut report = Report::default();
        report.line(summarize(&self.noise, &trials, &self.views));
        Ok(report)
    }

    /// The solver's options: a result's, with the mask offset, the joint noise and the
    /// refinement as the flags say.
    fn solve_options(&self, joint_noise_rad: f64) -> SolveOptions {
        let defaults = SolveOptions::default();
        SolveOptions {
            estimate_mask_offset: self.mask_offset,
            joint_noise_rad,
            refine_samples: if self.no_refine {
                0
            } else {
                defaults.refine_samples
            },
            ..defaults
        }
    }

    /// The joint noise the solver is told: `--joint-noise-rad` when given, else the scenes'
    /// own (`noise`'s), as a cell states its arm's.
    fn stated_joint_noise_rad(&self, noise: &NoiseModel) -> Result<f64> {
        let stated = self.joint_noise_rad.unwrap_or(noise.joint_noise_rad);
        let bound = crate::config::checks::bounds::JOINT_NOISE_RAD;
        if !(0.0..=bound).contains(&stated) {
            return Err(Error::Usage(format!(
                "--joint-noise-rad {stated}: allowed: 0 to {bound} rad"
            )));
        }
        Ok(stated)
    }
}

/// Solves one seeded scene from its first k views for each k in `view_counts`, as a result is
/// reported (`with_inter_view`) or with the statistical covariance alone.
fn coverage_of_scene(
    robot: &RobotModel,
    seed: u64,
    view_counts: &[usize],
    synth: &SynthOptions,
    opts: &SolveOptions,
    with_inter_view: bool,
) -> Result<Vec<CoverageTrial>> {
    let max_views = view_counts.iter().copied().max().unwrap_or(1);
    let (scene, views, init) = seeded_scene(robot, seed, max_views, synth)?;
    let truth = scene.camera_from_base;
    let mut trials = Vec::new();
    for &k in view_counts {
        let rep = solve(&CpuRenderer, &scene.camera, &views[..k], &init, opts)?;
        let rep = if with_inter_view {
            with_view_disagreement(&CpuRenderer, &scene.camera, &views[..k], rep, opts)
        } else {
            rep
        };
        let est = rep.camera_from_base;
        trials.push(CoverageTrial {
            seed,
            views: k,
            z: errors_in_sigmas(&est, &truth, &rep.uncertainty),
            centre_error_mm: camera_centre_error_mm(&est, &truth),
            centre_bound_mm: rep.uncertainty.camera_centre_95_mm,
            rotation_deg: rotation_error_deg(&est, &truth),
            translation_mm: translation_error_mm(&est, &truth),
        });
    }
    Ok(trials)
}

/// The true error per camera axis in units of the reported 1σ, as magnitudes: rotation about
/// x, y, z, then translation of `camera_from_base` along them.
pub fn errors_in_sigmas(
    estimate: &Isometry3<f64>,
    truth: &Isometry3<f64>,
    u: &Uncertainty,
) -> [f64; 6] {
    // truth = exp(delta) * estimate: delta is the error in the covariance's own terms.
    let delta = log_se3(&(truth * estimate.inverse()));
    let dt = (truth.translation.vector - estimate.translation.vector) * 1000.0;
    [
        delta[3].to_degrees() / u.rotation_deg[0],
        delta[4].to_degrees() / u.rotation_deg[1],
        delta[5].to_degrees() / u.rotation_deg[2],
        dt.x / u.translation_mm[0],
        dt.y / u.translation_mm[1],
        dt.z / u.translation_mm[2],
    ]
    .map(f64::abs)
}

/// Markdown table: per view count, the share of axes within 2σ (rotation, translation, all),
/// the share of scenes within the centre bound, and median errors and bound.
pub fn summarize(noise: &str, trials: &[CoverageTrial], view_counts: &[usize]) -> String {
    let mut s = String::from(
        "| noise | views | scenes | rotation axes within 2σ | translation axes within 2σ | all axes within 2σ | centres within 95% bound | median rotation error (deg) | median translation error (mm) | median 95% centre bound (mm) |\n|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for &k in view_counts {
        let t: Vec<&CoverageTrial> = trials.iter().filter(|t| t.views == k).collect();
        let share = |axes: std::ops::Range<usize>| {
            let n = t.len() * axes.len();
            let inside: usize = t
                .iter()
                .map(|x| x.z[axes.clone()].iter().filter(|z| **z <= 2.0).count())
                .sum();
            100.0 * inside as f64 / n.max(1) as f64
        };
        let centres = t
            .iter()
            .filter(|x| x.centre_error_mm <= x.centre_bound_mm)
            .count();
        let med =
            |g: fn(&CoverageTrial) -> f64| median(&t.iter().map(|x| g(x)).collect::<Vec<_>>());
        s.push_str(&format!(
            "| {noise} | {k} | {} | {:.1}% | {:.1}% | {:.1}% | {:.1}% | {:.4} | {:.3} | {:.3} |\n",
            t.len(),
            share(0..3),
            share(3..6),
            share(0..6),
            100.0 * centres as f64 / t.len().max(1) as f64,
            med(|x| x.rotation_deg),
            med(|x| x.translation_mm),
            med(|x| x.centre_bound_mm),
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bench(noise: &str, joint_noise_rad: Option<f64>) -> CoverageBench {
        CoverageBench {
            robot: PathBuf::from("robot.urdf"),
            scenes: 1,
            views: vec![1],
            noise: noise.into(),
            mask_offset: false,
            joint_noise_rad,
            statistical_only: false,
            no_refine: false,
        }
    }

    #[test]
    fn the_solver_is_told_the_scenes_joint_noise_unless_the_flag_says_otherwise() {
        let told = |noise: &str, flag: Option<f64>| {
            let model = NoiseModel::preset(noise).unwrap();
            bench(noise, flag).stated_joint_noise_rad(&model)
        };
        assert_eq!(told("blurred", None).unwrap(), 3e-4);
        assert_eq!(told("segmenter", None).unwrap(), 5e-4);
        assert_eq!(told("none", None).unwrap(), 0.0);
        assert_eq!(told("blurred", Some(5e-4)).unwrap(), 5e-4);
        let refused = told("blurred", Some(1.0)).unwrap_err().to_string();
        assert!(
            refused.contains("--joint-noise-rad 1: allowed: 0 to"),
            "{refused}"
        );
        assert!(told("blurred", Some(f64::NAN)).is_err());
    }

    #[test]
    fn no_refine_turns_the_refinement_off_and_nothing_else() {
        let plain = bench("segmenter", None).solve_options(5e-4);
        let mut flagged = bench("segmenter", None);
        flagged.no_refine = true;
        let unrefined = flagged.solve_options(5e-4);
        assert!(plain.refine_samples > 1, "{}", plain.refine_samples);
        // The solver skips the refinement below two samples.
        assert!(unrefined.refine_samples <= 1);
        // Every other option is the same (SolveOptions has no PartialEq; Debug shows all).
        let restored = SolveOptions {
            refine_samples: plain.refine_samples,
            ..unrefined
        };
        assert_eq!(format!("{restored:?}"), format!("{plain:?}"));
    }
}

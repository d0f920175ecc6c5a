//! `easyhec synth`: a synthetic run directory with a separate ground-truth file.

use super::exit::outln;
use std::path::PathBuf;

use anyhow::bail;
use clap::Args;
use easyhec::config::{NoiseModel, ScenePreset, SceneSettings};
use easyhec::robot::{RobotModel, RobotSource};
use easyhec::run::RobotEntry;
use easyhec::synth::{
    generate, generate_frames, write_imaged_scene, write_scene, SynthOptions, Truncation,
};

use super::urdf_for_run;

#[derive(Args)]
pub struct SynthArgs {
    /// Robot URDF.
    #[arg(long)]
    pub robot: PathBuf,
    /// Output run directory.
    #[arg(long)]
    pub out: PathBuf,
    /// Number of views.
    #[arg(long, default_value_t = 5)]
    pub views: usize,
    /// RNG seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Image width.
    #[arg(long, default_value_t = 640)]
    pub width: u32,
    /// Image height.
    #[arg(long, default_value_t = 480)]
    pub height: u32,
    /// Focal length, pixels.
    #[arg(long, default_value_t = 600.0)]
    pub focal: f64,
    /// Noise-free masks and joints.
    #[arg(long)]
    pub no_noise: bool,
    /// plumb_bob coefficients k1,k2,p1,p2,k3.
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    pub distortion: Option<Vec<f64>>,
    /// Links not rendered (and not in the masks).
    #[arg(long, value_delimiter = ',')]
    pub ignore_links: Vec<String>,
    /// Write no initial guess.
    #[arg(long)]
    pub no_initial_guess: bool,
    /// Also write colour frames (views/NNN.png): `easy` (the plain simulated scene) or `hard`
    /// (clutter, a light robot on light walls, shadows, exposure changes, moving boxes).
    #[arg(long)]
    pub images: Option<ScenePreset>,
    /// Aim the camera so part of the robot leaves the image in every view (55–93% inside).
    #[arg(long)]
    pub truncate: bool,
    /// Replace OUT when it exists and is not empty (refused otherwise: new masks beside an
    /// old run's would mix two runs).
    #[arg(long)]
    pub force: bool,
}

/// Most views `easyhec synth` makes: a calibration uses 3–10, benchmarks up to 20; this keeps
/// one call under a minute.
pub const MAX_SYNTH_VIEWS: usize = 100;

/// The flags' ranges, checked before anything is loaded or allocated.
fn check_args(a: &SynthArgs) -> Result<(), easyhec::error::Error> {
    use easyhec::error::Error;
    if !(1..=MAX_SYNTH_VIEWS).contains(&a.views) {
        return Err(Error::Usage(format!(
            "--views is {}; allowed: 1 to {MAX_SYNTH_VIEWS}",
            a.views
        )));
    }
    let (w, h) = (a.width, a.height);
    let camera = easyhec::camera::Intrinsics::pinhole(
        w,
        h,
        a.focal,
        a.focal,
        (f64::from(w) - 1.0) / 2.0,
        (f64::from(h) - 1.0) / 2.0,
    );
    if let Some((field, allowed)) = camera.range_problem() {
        let flag = match field {
            "width" => "--width",
            "height" => "--height",
            _ => "--focal",
        };
        return Err(Error::Usage(format!("{flag} {allowed}")));
    }
    if let Some(k) = a
        .distortion
        .iter()
        .flatten()
        .find(|k| !(k.is_finite() && k.abs() <= 1e3))
    {
        return Err(Error::Usage(format!(
            "--distortion has {k}; allowed: finite coefficients of at most 1000 in magnitude"
        )));
    }
    let need =
        u64::from(w) * u64::from(h) * a.views as u64 * easyhec::run::SOLVE_BYTES_PER_VIEW_PIXEL;
    match easyhec::run::available_memory_bytes() {
        Some(free) if need > free => Err(Error::Usage(format!(
            "--views {} at {w}x{h} needs about {:.1} GB; this machine has {:.1} GB available",
            a.views,
            need as f64 / 1e9,
            free as f64 / 1e9
        ))),
        _ => Ok(()),
    }
}

/// `--out` under the output policy: a folder that holds no input (the URDF), empty or new
/// unless `--force`. Returns whether an old run is to be replaced.
fn check_out(a: &SynthArgs) -> anyhow::Result<bool> {
    if let Some(problem) = easyhec::io::output_dir_problem(&a.out, std::slice::from_ref(&a.robot)) {
        bail!("{}: --out: {problem}", a.out.display());
    }
    let non_empty = std::fs::read_dir(&a.out).is_ok_and(|mut d| d.next().is_some());
    if non_empty && !a.force {
        bail!(
            "{}: --out: exists and is not empty; allowed: a new or empty folder (pass --force to replace it)",
            a.out.display()
        );
    }
    // --force replaces a run, never any other folder (a typo must not delete a home folder).
    if non_empty && !a.out.join("run.json").is_file() {
        bail!(
            "{}: --out: holds no run.json, so it is no run to replace; allowed: a new or empty folder, or a run folder with --force",
            a.out.display()
        );
    }
    Ok(non_empty)
}

/// Writes a synthetic run with its ground truth.
pub fn run(a: SynthArgs) -> anyhow::Result<()> {
    check_args(&a)?;
    let replace = check_out(&a)?;
    let urdf = urdf_for_run(&a.robot)?;
    let robot = RobotModel::load(&RobotSource {
        urdf: a.robot.clone(),
        ignore_links: a.ignore_links.clone(),
        ..Default::default()
    })?;
    let noise = if a.no_noise {
        NoiseModel::none()
    } else {
        NoiseModel::standard()
    };
    let distortion = match a.distortion.as_deref() {
        None => None,
        Some([k1, k2, p1, p2, k3]) => Some([*k1, *k2, *p1, *p2, *k3]),
        Some(other) => bail!(
            "--distortion: plumb_bob needs 5 coefficients k1,k2,p1,p2,k3, got {}",
            other.len()
        ),
    };
    let opts = SynthOptions {
        views: a.views,
        seed: a.seed,
        width: a.width,
        height: a.height,
        focal_px: a.focal,
        distortion,
        noise: noise.clone(),
        initial_error: if a.no_initial_guess {
            None
        } else {
            Some(((2.0, 6.0), (0.02, 0.08)))
        },
        truncation: a.truncate.then(Truncation::standard),
        ..SynthOptions::default()
    };
    let robot = std::sync::Arc::new(robot);
    let activity = super::progress::Activity::start("synth");
    if a.images.is_some() {
        activity.note(&format!("rendering {} views with scene images", a.views));
    }
    let imaged = match a.images {
        Some(preset) => Some(generate_frames(
            &robot,
            &opts,
            &SceneSettings {
                preset,
                ..SceneSettings::default()
            },
        )?),
        None => None,
    };
    let entry = RobotEntry {
        urdf,
        package_dirs: Default::default(),
        package_paths: Vec::new(),
        base_link: None,
        ignore_links: a.ignore_links,
        joints: robot.joint_names().iter().map(|s| s.to_string()).collect(),
        xacro_args: Default::default(),
    };
    if replace {
        std::fs::remove_dir_all(&a.out)
            .map_err(|e| anyhow::anyhow!("{}: --out: cannot replace it: {e}", a.out.display()))?;
    }
    match &imaged {
        Some(imaged) => write_imaged_scene(imaged, entry, &a.out, a.seed, &noise)?,
        None => write_scene(&generate(&robot, &opts)?, entry, &a.out, a.seed, &noise)?,
    }
    drop(activity);
    outln!(
        "wrote {} views to {} (ground truth in ground_truth.json)",
        a.views,
        a.out.display()
    );
    Ok(())
}

//! Synthetic runs with known ground truth.
//!
//! Scene: a camera 0.9–1.6 m from the robot's centre at a random azimuth, 10–50° elevation,
//! looking at the robot with a few centimetres of aim jitter and ±10° roll; joint vectors drawn
//! uniformly within 80% of each joint's range, kept when the robot stays above the base plane
//! and at least 97% of its outline is inside the image.
//!
//! Segmentation-noise model (all seeded):
//! - **boundary jitter**: the true silhouette boundary is displaced along its normal by a smooth
//!   random field (six random planar waves, wavelength 8–40 px) with RMS `boundary_jitter_px`;
//! - **blobs**: with probability `blob_probability` per view, 1–2 ellipses (3–12 px radii)
//!   centred near the boundary are painted as robot or cut out as background;
//! - **joint encoder noise**: recorded joints = true joints + N(0, `joint_noise_rad`).
//!
//! With [`SynthOptions::truncation`] the camera is aimed off the robot so that part of it
//! leaves the image in every view (masks are whatever is inside). [`generate_frames`] adds the
//! colour frames the simulated camera sees ([`crate::scene`], plain or hard dressing), so a
//! segmenter benchmark can make many seeded cells in memory; [`write_imaged_scene`] writes them
//! as a run directory with `image` and `mask` per view.

use std::path::Path;
use std::sync::Arc;

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;

use crate::camera::{Intrinsics, LensWarp};
use crate::config::{NoiseModel, SceneSettings};
use crate::error::{Error, Result};
use crate::geometry::{look_at_camera_from_base, to_rows};
use crate::io::{write_atomic, write_json_atomic};
use crate::mask::Mask;
use crate::mask_noise::{apply_mask_noise_to_coverage, coverage_of_finer};
use crate::render::{CpuRenderer, PosedRobot, SilhouetteRenderer};
use crate::robot::RobotModel;
use crate::run::{
    mask_file_name, CameraEntry, GroundTruth, PoseEntry, RobotEntry, RunFile, ViewEntry, RUN_FORMAT,
};
use crate::scene::{SimFrame, SimScene};

/// Scene generator settings.
#[derive(Clone, Debug)]
pub struct SynthOptions {
    /// Number of views.
    pub views: usize,
    /// RNG seed.
    pub seed: u64,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Focal length, pixels.
    pub focal_px: f64,
    /// Lens distortion of the simulated camera.
    pub distortion: Option<[f64; 5]>,
    /// Segmentation noise.
    pub noise: NoiseModel,
    /// Initial-guess error ranges: rotation (deg) and translation (m); `None` writes no guess.
    pub initial_error: Option<((f64, f64), (f64, f64))>,
    /// Camera distance from the robot's centre, metres (min, max).
    pub camera_distance_m: (f64, f64),
    /// Camera elevation above the base plane, degrees (min, max).
    pub camera_elevation_deg: (f64, f64),
    /// Aim the camera so part of the robot leaves the image; `None`: at least 97% of the
    /// robot's vertices inside in every view.
    pub truncation: Option<Truncation>,
}

/// A camera placement that cuts the robot at the image border: what a real camera mounted too
/// close, or aimed at the gripper's workspace rather than the whole arm, sees.
#[derive(Clone, Debug, PartialEq)]
pub struct Truncation {
    /// Accepted range of the fraction of the robot's visual vertices inside the image, per
    /// view.
    pub in_image_fraction: (f64, f64),
    /// How far the aim point moves off the robot's centre across the line of sight, metres
    /// (min, max).
    pub aim_offset_m: (f64, f64),
}

impl Truncation {
    /// 55–93% of the robot inside the image, aim 15–35 cm off centre.
    pub fn standard() -> Truncation {
        Truncation {
            in_image_fraction: (0.55, 0.93),
            aim_offset_m: (0.15, 0.35),
        }
    }
}

impl Default for SynthOptions {
    fn default() -> Self {
        SynthOptions {
            views: 5,
            seed: 0,
            width: 640,
            height: 480,
            focal_px: 600.0,
            distortion: None,
            noise: NoiseModel::standard(),
            initial_error: Some(((2.0, 6.0), (0.02, 0.08))),
            camera_distance_m: (0.9, 1.6),
            camera_elevation_deg: (10.0, 50.0),
            truncation: None,
        }
    }
}

/// An in-memory synthetic scene.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Camera (possibly distorted: masks are in its image).
    pub camera: Intrinsics,
    /// True pose.
    pub camera_from_base: Isometry3<f64>,
    /// Initial guess, when requested.
    pub initial_guess: Option<Isometry3<f64>>,
    /// Joint vectors the robot really had.
    pub true_joints: Vec<Vec<f64>>,
    /// Joint vectors as recorded (with encoder noise).
    pub recorded_joints: Vec<Vec<f64>>,
    /// Observed masks (with segmentation noise), in the camera's (distorted) image.
    pub masks: Vec<Mask>,
}

/// A random rigid perturbation with rotation angle and translation length drawn from ranges.
pub fn perturb(
    rng: &mut impl Rng,
    pose: &Isometry3<f64>,
    rot_deg: (f64, f64),
    trans_m: (f64, f64),
) -> Isometry3<f64> {
    let axis = random_unit(rng);
    let dir = random_unit(rng);
    let angle = rng.random_range(rot_deg.0..=rot_deg.1).to_radians();
    let dist = rng.random_range(trans_m.0..=trans_m.1);
    // Rotation and translation errors are independent: R' = dR R, t' = t + d.
    Isometry3::from_parts(
        nalgebra::Translation3::from(pose.translation.vector + dir * dist),
        UnitQuaternion::from_scaled_axis(axis * angle) * pose.rotation,
    )
}

/// Supersampling of [`sub_pixel_coverage`] per image axis.
const COVERAGE_SUPERSAMPLING: u32 = 4;

/// The robot's sub-pixel coverage of each pixel, from a render 4x finer per axis: what a
/// blurring segmenter sees before it thresholds.
fn sub_pixel_coverage(
    renderer: &CpuRenderer,
    posed: &PosedRobot,
    pinhole: &Intrinsics,
    camera_from_base: &Isometry3<f64>,
) -> Vec<f32> {
    let f = COVERAGE_SUPERSAMPLING;
    let finer = Intrinsics {
        width: pinhole.width * f,
        height: pinhole.height * f,
        fx: pinhole.fx * f64::from(f),
        fy: pinhole.fy * f64::from(f),
        cx: (pinhole.cx + 0.5) * f64::from(f) - 0.5,
        cy: (pinhole.cy + 0.5) * f64::from(f) - 0.5,
        distortion: pinhole.distortion,
    };
    let fine = renderer.render(posed, &finer, camera_from_base, None);
    coverage_of_finer(&fine.mask, f, pinhole.width, pinhole.height)
}

fn random_unit(rng: &mut impl Rng) -> Vector3<f64> {
    let n = Normal::new(0.0, 1.0).expect("valid");
    loop {
        let v = Vector3::new(n.sample(rng), n.sample(rng), n.sample(rng));
        if v.norm() > 1e-6 {
            return v.normalize();
        }
    }
}

/// Robot centre used for aiming: the middle of its visual bounds at the zero pose.
fn robot_centre(robot: &RobotModel) -> Vector3<f64> {
    let q = vec![0.0; robot.actuated.len()];
    let v = robot.posed_vertices(&q);
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for p in &v {
        lo = lo.inf(&p.coords);
        hi = hi.sup(&p.coords);
    }
    if v.is_empty() {
        Vector3::zeros()
    } else {
        (lo + hi) / 2.0
    }
}

fn random_joints(rng: &mut impl Rng, robot: &RobotModel) -> Vec<f64> {
    robot
        .joint_limits()
        .iter()
        .map(|&(lo, hi)| {
            let (lo, hi) = (lo.max(-std::f64::consts::PI), hi.min(std::f64::consts::PI));
            let mid = (lo + hi) / 2.0;
            let half = (hi - lo) / 2.0 * 0.8;
            rng.random_range(mid - half..=mid + half)
        })
        .collect()
}

/// Generates a scene in memory.
pub fn generate(robot: &RobotModel, opts: &SynthOptions) -> Result<Scene> {
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
    let camera = Intrinsics {
        width: opts.width,
        height: opts.height,
        fx: opts.focal_px,
        fy: opts.focal_px * rng.random_range(0.995..1.005),
        cx: f64::from(opts.width) / 2.0 + rng.random_range(-8.0..8.0),
        cy: f64::from(opts.height) / 2.0 + rng.random_range(-8.0..8.0),
        distortion: opts.distortion,
    };
    let pinhole = camera.undistorted();
    let centre = robot_centre(robot);
    let renderer = CpuRenderer;
    for _attempt in 0..50 {
        let distance = rng.random_range(opts.camera_distance_m.0..=opts.camera_distance_m.1);
        let azimuth = rng.random_range(0.0..std::f64::consts::TAU);
        let elevation = rng
            .random_range(opts.camera_elevation_deg.0..=opts.camera_elevation_deg.1)
            .to_radians();
        let eye = centre
            + Vector3::new(
                elevation.cos() * azimuth.cos(),
                elevation.cos() * azimuth.sin(),
                elevation.sin(),
            ) * distance;
        let mut aim = centre + random_unit(&mut rng) * rng.random_range(0.0..0.05);
        if let Some(t) = &opts.truncation {
            // Push the aim across the line of sight, so the robot sits off to one side.
            let sight = (aim - eye).normalize();
            let across = random_unit(&mut rng);
            let across = (across - sight * across.dot(&sight))
                .try_normalize(1e-9)
                .unwrap_or_else(|| sight.cross(&Vector3::z()).normalize());
            aim += across * rng.random_range(t.aim_offset_m.0..=t.aim_offset_m.1);
        }
        let roll = rng.random_range(-10f64..10.0).to_radians();
        let look = look_at_camera_from_base(&eye, &aim, &Vector3::z());
        let truth = Isometry3::from_parts(
            nalgebra::Translation3::identity(),
            UnitQuaternion::from_scaled_axis(Vector3::z() * roll),
        ) * look;
        let mut true_joints = Vec::new();
        let mut masks = Vec::new();
        let mut tries = 0;
        while true_joints.len() < opts.views && tries < 400 {
            tries += 1;
            let q = random_joints(&mut rng, robot);
            let posed = PosedRobot::new(robot, &q);
            if posed.vertices_base.iter().any(|p| p.z < -0.005) {
                continue;
            }
            let inside = posed
                .vertices_base
                .iter()
                .filter(|p| {
                    let c = truth * **p;
                    let x = pinhole.project(&c);
                    c.z > 0.05
                        && x[0] >= 2.0
                        && x[1] >= 2.0
                        && x[0] <= f64::from(opts.width) - 3.0
                        && x[1] <= f64::from(opts.height) - 3.0
                })
                .count();
            let (lo, hi) = opts
                .truncation
                .as_ref()
                .map_or((0.97, 1.0), |t| t.in_image_fraction);
            let all = posed.vertices_base.len() as f64;
            if (inside as f64) < lo * all || (inside as f64) > hi * all {
                continue;
            }
            let sil = renderer.render(&posed, &pinhole, &truth, None);
            if sil.mask.count() < (opts.width * opts.height / 100) as usize {
                continue;
            }
            let coverage = (opts.noise.blur_px > 0.0)
                .then(|| sub_pixel_coverage(&renderer, &posed, &pinhole, &truth));
            let noisy =
                apply_mask_noise_to_coverage(&mut rng, &sil.mask, coverage.as_deref(), &opts.noise);
            masks.push(camera.distort_mask(&noisy));
            true_joints.push(q);
        }
        if true_joints.len() < opts.views {
            continue;
        }
        let jn = Normal::new(0.0, opts.noise.joint_noise_rad.max(1e-300)).expect("valid");
        let recorded_joints = true_joints
            .iter()
            .map(|q| {
                q.iter()
                    .map(|v| {
                        if opts.noise.joint_noise_rad > 0.0 {
                            v + jn.sample(&mut rng)
                        } else {
                            *v
                        }
                    })
                    .collect()
            })
            .collect();
        let initial_guess = opts
            .initial_error
            .map(|(r, t)| perturb(&mut rng, &truth, r, t));
        return Ok(Scene {
            camera,
            camera_from_base: truth,
            initial_guess,
            true_joints,
            recorded_joints,
            masks,
        });
    }
    Err(Error::Solve(format!(
        "could not place a camera that sees robot '{}' in {} valid poses: the robot may be too large for a {}x{} image at {:.1}-{:.1} m",
        robot.name, opts.views, opts.width, opts.height, opts.camera_distance_m.0, opts.camera_distance_m.1
    )))
}

/// A synthetic scene with the colour frames the simulated camera saw.
#[derive(Clone, Debug)]
pub struct ImagedScene {
    /// Camera, true pose, joints and observed masks (segmentation noise on the visible robot:
    /// pixels a distractor hides are left out).
    pub scene: Scene,
    /// View `i`'s frame (frame index `i`), with exact truth, distractor and hidden-robot masks.
    pub frames: Vec<SimFrame>,
    /// The dressing the frames were rendered with, seed included.
    pub dressing: SceneSettings,
}

/// [`generate`] plus colour frames of every view rendered with `dressing`
/// ([`SceneSettings::default`] for plain frames, [`SceneSettings::hard`] for hard ones). The
/// frames' seed is `opts.seed + dressing.seed * 0x9E3779B97F4A7C15` (wrapping), so one seed
/// makes one cell and a dressing seed of 0 reuses it.
pub fn generate_frames(
    robot: &Arc<RobotModel>,
    opts: &SynthOptions,
    dressing: &SceneSettings,
) -> Result<ImagedScene> {
    let mut scene = generate(robot, opts)?;
    let seed = opts
        .seed
        .wrapping_add(dressing.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let dressing = dressing.clone().with_seed(seed);
    let sim = SimScene::new(
        robot.clone(),
        scene.camera.clone(),
        scene.camera_from_base,
        dressing.clone(),
    );
    let frames: Vec<SimFrame> = scene
        .true_joints
        .par_iter()
        .enumerate()
        .map(|(i, q)| sim.render_frame(q, i as u64))
        .collect();
    for (mask, frame) in scene.masks.iter_mut().zip(&frames) {
        for (m, &hidden) in mask.data.iter_mut().zip(&frame.occluded_mask.data) {
            if hidden != 0 {
                *m = 0;
            }
        }
    }
    Ok(ImagedScene {
        scene,
        frames,
        dressing,
    })
}

/// Encodes a row-major RGB8 buffer as PNG.
pub fn rgb_png_bytes(width: u32, height: u32, rgb: &[u8]) -> Vec<u8> {
    let img = image::RgbImage::from_raw(width, height, rgb.to_vec())
        .expect("an RGB8 buffer of width * height * 3 bytes");
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .expect("PNG encoding to memory cannot fail");
    out.into_inner()
}

/// Writes a scene as an `easyhec-run/1` directory plus `ground_truth.json`.
pub fn write_scene(
    scene: &Scene,
    robot_entry: RobotEntry,
    out: &Path,
    seed: u64,
    noise: &NoiseModel,
) -> Result<()> {
    write_run(scene, None, robot_entry, out, seed, noise)
}

/// Writes an imaged scene as an `easyhec-run/1` directory (each view with `image`
/// `views/NNN.png` and `mask` `views/NNN.mask.png`) plus `ground_truth.json` (which records the
/// dressing).
pub fn write_imaged_scene(
    imaged: &ImagedScene,
    robot_entry: RobotEntry,
    out: &Path,
    seed: u64,
    noise: &NoiseModel,
) -> Result<()> {
    write_run(
        &imaged.scene,
        Some((&imaged.frames, &imaged.dressing)),
        robot_entry,
        out,
        seed,
        noise,
    )
}

fn write_run(
    scene: &Scene,
    frames: Option<(&[SimFrame], &SceneSettings)>,
    robot_entry: RobotEntry,
    out: &Path,
    seed: u64,
    noise: &NoiseModel,
) -> Result<()> {
    std::fs::create_dir_all(out.join("views"))
        .map_err(|e| Error::io(out, format!("cannot create run folder: {e}")))?;
    let mut views = Vec::new();
    for (i, (mask, q)) in scene.masks.iter().zip(&scene.recorded_joints).enumerate() {
        let rel = format!("views/{}", mask_file_name(i));
        write_atomic(&out.join(&rel), &mask.to_png_bytes())?;
        let image = match frames.and_then(|(f, _)| f.get(i)) {
            Some(frame) => {
                let rel = format!("views/{i:03}.png");
                let c = &scene.camera;
                write_atomic(
                    &out.join(&rel),
                    &rgb_png_bytes(c.width, c.height, &frame.rgb),
                )?;
                Some(rel)
            }
            None => None,
        };
        views.push(ViewEntry {
            joints: q.clone(),
            mask: Some(rel),
            image,
            captured_at: None,
        });
    }
    let c = &scene.camera;
    let run = RunFile {
        format: RUN_FORMAT.into(),
        robot: robot_entry,
        camera: CameraEntry::of(c),
        initial_guess: scene.initial_guess.map(|g| PoseEntry {
            camera_from_base: to_rows(&g),
        }),
        views,
    };
    write_json_atomic(
        &out.join("ground_truth.json"),
        &GroundTruth {
            format: "easyhec-truth/1".into(),
            camera_from_base: to_rows(&scene.camera_from_base),
            true_joints: scene.true_joints.clone(),
            noise: noise.clone(),
            seed,
            scene: frames.map(|(_, d)| d.clone()),
        },
    )?;
    write_json_atomic(&out.join("run.json"), &run)
}

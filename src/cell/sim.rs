//! The simulated parts of a cell (`[arm] kind = "sim"`, `[camera] kind = "sim"`,
//! `[segmenter] kind = "sim-truth"`): built through the same driver traits as real hardware,
//! with the simulator's own handles (true pose, scene, command log, ground-truth masks) kept
//! beside the cell for tests and for `ground_truth.json`, never on the hardware types.

use std::path::Path;
use std::sync::Arc;

use easyhec_drivers::JointLimit;
use easyhec_mocks::ur::UrRtdeJoints;
use easyhec_mocks::xarm::XArmReportJoints;
use easyhec_mocks::{Fault, JointSource, SimArm, SimArmConfig, SimCamera};
use nalgebra::Isometry3;

use crate::config::{
    seconds, ArmConfig, CameraConfig, CellConfig, FaultConfig, JointsFrom, SegmenterConfig,
};
use crate::config::{SimArmSettings, SimCameraSettings};
use crate::error::{Error, Result};
use crate::io::write_json_atomic;
use crate::robot::RobotModel;
use crate::run::rig::{CameraTruth, RigGroundTruth, RunLayout, RIG_TRUTH_FORMAT};
use crate::run::GroundTruth;
use crate::scene::SimScene;
use crate::segment::Segmenter;

/// What a test may read of the simulated arm: its true joints and every command it received.
/// Read-only on purpose: the arm itself moves only through the cell's `SafeArm`.
#[derive(Clone)]
pub struct SimArmLog(SimArm);

impl SimArmLog {
    /// The joints as they truly are (the reported ones carry encoder noise).
    pub fn true_joints(&self) -> Vec<f64> {
        self.0.true_joints()
    }

    /// Every move command received, accepted or refused, in order.
    pub fn commands(&self) -> Vec<easyhec_mocks::CommandRecord> {
        self.0.commands()
    }
}

/// Handles into the simulated hardware, for tests and the truth report.
#[derive(Clone, Default)]
pub struct SimHandles {
    /// The simulated arm's log (read-only).
    pub arm: Option<SimArmLog>,
    /// The simulated camera's true pose when the cell was built.
    pub camera_from_base: Option<Isometry3<f64>>,
    /// The simulated camera's scene: its true pose now, and a way to bump the camera
    /// ([`SimScene::set_camera_from_base`]).
    pub scene: Option<Arc<SimScene>>,
    /// The simulated camera itself: the ground-truth mask of each recent frame
    /// ([`SimCamera::truth_mask`], by the frame's sequence number).
    pub camera: Option<Arc<SimCamera>>,
}

impl SimHandles {
    /// The simulated camera's true pose now (it moves when a test bumps the camera).
    pub fn camera_from_base_now(&self) -> Option<Isometry3<f64>> {
        self.scene.as_ref().map(|s| s.camera_from_base())
    }
}

/// What a simulated camera table builds.
pub(super) struct SimCameraParts {
    pub(super) camera: Arc<SimCamera>,
    pub(super) camera_from_base: Isometry3<f64>,
    pub(super) scene: Arc<SimScene>,
}

/// The simulated arm of an `[arm] kind = "sim"` table, with the URDF's limits.
pub(super) fn arm(arm: &SimArmSettings, robot: &RobotModel, path: &Path) -> Result<SimArm> {
    let SimArmSettings {
        start,
        encoder_noise_rad,
        speedup,
        faults,
        seed,
    } = arm;
    let n = robot.actuated.len();
    if start.len() != n {
        return Err(Error::input(
            path,
            "arm.start",
            format!("{} values for the {n} actuated joints", start.len()),
        ));
    }
    let urdf_limits = robot.joint_limits();
    check_start(start, &urdf_limits, robot, path)?;
    let joints: Vec<JointLimit> = robot
        .joint_names()
        .iter()
        .enumerate()
        .map(|(k, name)| {
            let v = robot.joints[robot.actuated[k]].velocity;
            JointLimit {
                name: name.to_string(),
                lower: urdf_limits[k].0,
                upper: urdf_limits[k].1,
                max_velocity: if v > 0.0 { v } else { 1.0 },
            }
        })
        .collect();
    Ok(SimArm::new(SimArmConfig {
        joints,
        start: start.clone(),
        encoder_noise_rad: *encoder_noise_rad,
        speedup: speedup.unwrap_or(f64::INFINITY),
        faults: faults.iter().map(fault).collect(),
        seed: *seed,
    }))
}

/// A simulated arm cannot stand outside its own joint limits: a start there is a typo (often
/// degrees for radians), and every later path check would start from an impossible pose.
fn check_start(
    start: &[f64],
    limits: &[(f64, f64)],
    robot: &RobotModel,
    path: &Path,
) -> Result<()> {
    let names = robot.joint_names();
    for (k, (&q, &(lo, hi))) in start.iter().zip(limits).enumerate() {
        if !(q.is_finite() && q >= lo && q <= hi) {
            return Err(Error::input(
                path,
                format!("arm.start[{k}]"),
                format!(
                    "is {q}; allowed: within joint '{}' limits [{lo}, {hi}] rad",
                    names[k]
                ),
            ));
        }
    }
    Ok(())
}

fn fault(f: &FaultConfig) -> Fault {
    match *f {
        FaultConfig::Refuse { on_move } => Fault::Refuse { on_move },
        FaultConfig::Error {
            on_move,
            at_fraction,
        } => Fault::ErrorMidMove {
            on_move,
            at_fraction,
        },
        FaultConfig::Stall {
            on_move,
            at_fraction,
        } => Fault::Stall {
            on_move,
            at_fraction,
        },
    }
}

/// The simulated camera of a `[camera] kind = "sim"` table: it films the simulated arm, or a
/// controller's report stream when `joints_from` says so.
pub(super) fn camera(
    camera: &SimCameraSettings,
    robot: &Arc<RobotModel>,
    sim_arm: Option<&SimArm>,
    feed: Option<&super::ros2::JointFeed>,
    path: &Path,
) -> Result<SimCameraParts> {
    let SimCameraSettings {
        truth,
        scene,
        joints_from,
        mount,
        ..
    } = camera;
    let source = joint_source(
        joints_from.as_ref(),
        sim_arm,
        feed,
        robot.actuated.len(),
        path,
    )?;
    let pose = truth
        .checked_camera_from_base()
        .map_err(|problem| Error::input(path, "camera.truth", problem))?;
    let model = camera.intrinsics();
    scene.validate(path, "camera.scene")?;
    let scene = Arc::new(match mount.link() {
        None => SimScene::new(robot.clone(), model, pose, scene.clone()),
        Some(link) => {
            if scene.effects().distractors.is_some() {
                return Err(Error::input(
                    path,
                    "camera.scene.distractors",
                    "distractors are placed for a fixed camera: leave them out for a camera on a link",
                ));
            }
            let l = robot.link_index(link).ok_or_else(|| {
                Error::input(path, "camera.mount.link", format!("no link named '{link}'"))
            })?;
            SimScene::new(
                Arc::new(robot.without_links_fixed_to(l)),
                model,
                pose,
                scene.clone(),
            )
            .mounted_on(l)
        }
    });
    Ok(SimCameraParts {
        camera: Arc::new(SimCamera::watching(source, scene.clone())),
        camera_from_base: pose,
        scene,
    })
}

/// Where a simulated camera reads the true joints of the arm it films.
fn joint_source(
    joints_from: Option<&JointsFrom>,
    sim_arm: Option<&SimArm>,
    feed: Option<&super::ros2::JointFeed>,
    axes: usize,
    path: &Path,
) -> Result<Arc<dyn JointSource>> {
    Ok(match (joints_from, sim_arm) {
        (Some(JointsFrom::Ros2 { .. }), _) => ros2_source(feed, path)?,
        (Some(JointsFrom::XarmReport { addr, timeout_s }), _) => Arc::new(XArmReportJoints {
            addr: addr.clone(),
            axes,
            timeout: seconds(path, "camera.joints_from.timeout_s", *timeout_s)?,
        }),
        (Some(JointsFrom::UrRtde { addr, timeout_s }), _) => Arc::new(UrRtdeJoints {
            addr: addr.clone(),
            timeout: seconds(path, "camera.joints_from.timeout_s", *timeout_s)?,
        }),
        (None, Some(sim_arm)) => Arc::new(sim_arm.clone()),
        (None, None) => {
            return Err(Error::input(
                path,
                "camera.joints_from",
                "a simulated camera needs the true joints of the arm it films: set [arm] kind = \"sim\", or joints_from = { kind = \"xarm-report\", addr = \"HOST:30003\" } or { kind = \"ur-rtde\", addr = \"HOST:30004\" }",
            ))
        }
    })
}

/// The `/joint_states` source of a camera filming a ROS 2 arm.
#[cfg(feature = "ros2")]
fn ros2_source(feed: Option<&super::ros2::JointFeed>, path: &Path) -> Result<Arc<dyn JointSource>> {
    let feed = feed.expect("built for joints_from = ros2");
    super::ros2::feed::source(feed)
        .map_err(|e| Error::input(path, "camera.joints_from", e.to_string()))
}

#[cfg(not(feature = "ros2"))]
fn ros2_source(_: Option<&super::ros2::JointFeed>, path: &Path) -> Result<Arc<dyn JointSource>> {
    Err(Error::input(
        path,
        "camera.joints_from.kind",
        "\"ros2\" needs ROS 2 support, which this build leaves out: rebuild with --features ros2",
    ))
}

/// Gathers the simulator's handles, and gives a `sim-truth` segmenter the simulated camera
/// whose ground truth it reads.
pub(super) fn attach(
    config: &CellConfig,
    path: &Path,
    segmenter: Box<dyn Segmenter>,
    arm: Option<SimArm>,
    camera: Option<SimCameraParts>,
) -> Result<(Box<dyn Segmenter>, SimHandles)> {
    let segmenter = match (&config.segmenter, &camera) {
        (SegmenterConfig::SimTruth { .. }, Some(parts)) => {
            crate::segment::build_with_truth(&config.segmenter, path, Some(parts.camera.clone()))?
        }
        _ => segmenter,
    };
    let handles = SimHandles {
        arm: arm.map(SimArmLog),
        camera_from_base: camera.as_ref().map(|c| c.camera_from_base),
        scene: camera.as_ref().map(|c| c.scene.clone()),
        camera: camera.map(|c| c.camera),
    };
    Ok((segmenter, handles))
}

/// Writes the simulator's truth beside a run recorded on `cell`, in the run's layout:
/// `easyhec-truth/1` for one camera, `/2` by camera name. Nothing when a camera is not
/// simulated.
pub fn write_ground_truth(cell: &crate::cell::Cell, run_dir: &Path) -> Result<()> {
    let path = run_dir.join("ground_truth.json");
    match cell.layout() {
        RunLayout::OneCamera => match cell.units[0].sim.camera_from_base {
            Some(truth) => write_json_atomic(&path, &ground_truth(&cell.config, &truth)),
            None => Ok(()),
        },
        RunLayout::NamedCameras => match rig_ground_truth(cell) {
            Some(truth) => write_json_atomic(&path, &truth),
            None => Ok(()),
        },
    }
}

/// The simulator's truth for a rig run recorded on `cell` (`ground_truth.json`,
/// `easyhec-truth/2`): each camera's true transform in its mount's frame. `None` unless every
/// camera is simulated.
pub fn rig_ground_truth(cell: &crate::cell::Cell) -> Option<RigGroundTruth> {
    let cameras = cell
        .cameras()
        .iter()
        .map(|c| {
            Some(CameraTruth {
                name: c.name.to_string(),
                transform: c.config.mount().transform_name(),
                camera_from_mount: crate::geometry::to_rows(&c.sim.camera_from_base?),
            })
        })
        .collect::<Option<Vec<_>>>()?;
    Some(RigGroundTruth {
        format: RIG_TRUTH_FORMAT.into(),
        cameras,
        encoder_noise_rad: encoder_noise_rad(&cell.config),
        seed: cell.config.calibration.seed,
    })
}

/// The simulator's truth for a run recorded on `config`'s cell (`ground_truth.json`): the true
/// camera pose, the encoder noise the arm adds (a driver-backed arm's readings count as exact)
/// and the scene's dressing.
pub fn ground_truth(config: &CellConfig, camera_from_base: &Isometry3<f64>) -> GroundTruth {
    let joint_noise_rad = encoder_noise_rad(config);
    GroundTruth {
        format: "easyhec-truth/1".into(),
        camera_from_base: crate::geometry::to_rows(camera_from_base),
        true_joints: Vec::new(),
        noise: crate::config::NoiseModel {
            joint_noise_rad,
            ..crate::config::NoiseModel::none()
        },
        seed: config.calibration.seed,
        scene: match config.camera.first() {
            CameraConfig::Sim(SimCameraSettings { scene, .. }) => Some(scene.clone()),
            _ => None,
        },
    }
}

/// The simulated arm's encoder noise, radians: 0 for a driver-backed arm, whose readings
/// count as exact.
fn encoder_noise_rad(config: &CellConfig) -> f64 {
    match &config.arm {
        ArmConfig::Sim(SimArmSettings {
            encoder_noise_rad, ..
        }) => *encoder_noise_rad,
        _ => 0.0,
    }
}

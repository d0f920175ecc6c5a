//! A built cell: the arm, camera and segmenter a config names, the robot model and the safety
//! checker, ready for the loop. Backends are picked by each table's `kind` (module
//! [`hardware`] for real devices, [`sim`] for the simulator), so the loop only ever sees a
//! [`SafeArm`] and an `Arc<dyn Camera>`.
//!
//! Relative paths in a config are relative to the config file.

mod hardware;
pub mod ros2;
#[cfg(feature = "sim")]
pub mod sim;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use easyhec_drivers::{Arm, Camera as CameraDevice};
#[cfg(not(feature = "sim"))]
use nalgebra::Isometry3;

use crate::config::{read_config, ArmConfig, CameraCalibration, CameraConfig, CellConfig};
#[cfg(not(feature = "sim"))]
use crate::error::Error;
use crate::error::Result;
use crate::robot::{RobotModel, RobotSource};
use crate::safety::{SafeArm, SafetyChecker};
use crate::segment::Segmenter;

#[cfg(feature = "sim")]
pub use sim::SimHandles;

/// Stands in for the simulator's handles in a build without the `sim` feature: there is never
/// a simulated part to reach.
#[cfg(not(feature = "sim"))]
#[derive(Clone, Default)]
pub struct SimHandles {
    /// Never set without the `sim` feature.
    pub camera_from_base: Option<Isometry3<f64>>,
}

#[cfg(not(feature = "sim"))]
impl SimHandles {
    /// Never a pose without the `sim` feature.
    pub fn camera_from_base_now(&self) -> Option<Isometry3<f64>> {
        None
    }
}

/// A built cell.
pub struct Cell {
    /// The parsed config.
    pub config: CellConfig,
    /// Where it was read from.
    pub config_path: PathBuf,
    /// Robot model in the cell's base frame (the arm, safety, FK).
    pub robot: Arc<RobotModel>,
    /// The robot as the camera sees it, for every render and solve: `robot` itself for a
    /// fixed camera; for a camera on a link, rooted at that link (so the solved pose is
    /// `camera_from_<link>`) and without the links that move with the camera.
    pub seen: Arc<RobotModel>,
    /// The arm, behind the safety gate: every move must be a [`crate::safety::CheckedMove`].
    pub arm: SafeArm,
    /// The camera.
    pub camera: Arc<dyn CameraDevice>,
    /// The segmenter.
    pub segmenter: Box<dyn Segmenter>,
    /// The safety checker.
    pub checker: SafetyChecker,
    /// Simulator handles (empty on real hardware).
    pub sim: SimHandles,
}

/// The arm a config builds, with the simulated arm's own handle when simulated.
struct BuiltArm {
    device: Arc<dyn Arm>,
    #[cfg(feature = "sim")]
    sim: Option<easyhec_mocks::SimArm>,
}

/// The camera a config builds, with the simulator's parts when simulated.
struct BuiltCamera {
    device: Arc<dyn CameraDevice>,
    #[cfg(feature = "sim")]
    sim: Option<sim::SimCameraParts>,
}

impl Cell {
    /// Builds every backend named in the config at `path`.
    pub fn open(path: &Path) -> Result<Cell> {
        let config = read_config(path)?;
        Cell::build(config, path)
    }

    /// Builds from an already parsed config (`path` resolves relative paths).
    pub fn build(config: CellConfig, path: &Path) -> Result<Cell> {
        // Every value that needs only the file, before anything is read or opened.
        config.validate(path)?;
        // A bad calibration file fails here, before any hardware is opened.
        let calibration = config.camera.calibration(path)?;
        // So does a bad segmentation model.
        let segmenter = crate::segment::build(&config.segmenter, path)?;
        let robot = Arc::new(RobotModel::load(&robot_source(&config, path))?);
        let seen = seen_robot(&config, &robot, path)?;
        let arm = build_arm(&config, &robot, path)?;
        let feed = ros2::joint_feed(&config, &robot, path)?;
        let camera = build_camera(&config, calibration, &robot, &arm, feed, path)?;
        let controller: Vec<(f64, f64, f64)> = arm
            .device
            .joints()
            .iter()
            .map(|j| (j.lower, j.upper, j.max_velocity))
            .collect();
        let checker = SafetyChecker::new(robot.clone(), &config.safety, &controller, path)?;
        config.daemon.validate(path, robot.actuated.len())?;
        #[cfg(feature = "sim")]
        let (segmenter, sim) = sim::attach(&config, path, segmenter, arm.sim, camera.sim)?;
        #[cfg(not(feature = "sim"))]
        let sim = SimHandles::default();
        Ok(Cell {
            segmenter,
            config,
            config_path: path.to_path_buf(),
            robot,
            seen,
            arm: SafeArm::new(arm.device),
            camera: camera.device,
            checker,
            sim,
        })
    }
}

/// The robot as the camera sees it (see [`Cell::seen`]). A camera on a link needs a starting
/// pose: the automatic initialisation searches around a fixed camera only.
fn seen_robot(
    config: &CellConfig,
    robot: &Arc<RobotModel>,
    path: &Path,
) -> Result<Arc<RobotModel>> {
    let Some(link) = config.camera.mount().link() else {
        return Ok(robot.clone());
    };
    let seen = robot.seen_from_link(link, path, "camera.mount.link")?;
    if config.calibration.initial_guess.is_none() {
        return Err(crate::error::Error::input(
            path,
            "calibration.initial_guess",
            format!("a camera on link '{link}' needs a starting camera_from_{link}, from the mount's drawing: {{ eye = […], look_at = […] }} in the link's frame, or a 4x4 matrix"),
        ));
    }
    Ok(Arc::new(seen))
}

/// The `[robot]` table as a model source, its paths resolved against the config's folder.
fn robot_source(config: &CellConfig, path: &Path) -> RobotSource {
    let dir = path.parent().unwrap_or(Path::new("."));
    let r = &config.robot;
    RobotSource {
        urdf: dir.join(&r.urdf),
        package_dirs: r
            .package_dirs
            .iter()
            .map(|(k, v)| (k.clone(), dir.join(v)))
            .collect(),
        base_link: r.base_link.clone(),
        ignore_links: r.ignore_links.clone(),
        joints: r.joints.clone(),
        xacro_args: r.xacro_args.clone(),
    }
}

/// The arm of the `[arm]` table.
fn build_arm(config: &CellConfig, robot: &RobotModel, path: &Path) -> Result<BuiltArm> {
    let arm = &config.arm;
    let device = match arm {
        ArmConfig::Sim { .. } => return sim_arm(arm, robot, path),
        ArmConfig::Xarm { .. } => hardware::xarm_arm(arm, robot, path)?,
        ArmConfig::Ur { .. } => hardware::ur_arm(arm, robot, path)?,
        ArmConfig::Dynamixel(t) => hardware::servo_arm(
            easyhec_drivers::dynamixel::Family::Dynamixel,
            t,
            robot,
            path,
        )?,
        ArmConfig::Feetech(t) => {
            hardware::servo_arm(easyhec_drivers::dynamixel::Family::Feetech, t, robot, path)?
        }
        ArmConfig::Piper { .. } => hardware::piper_arm(arm, robot, path)?,
        ArmConfig::Ros2 { .. } => ros2::ros2_arm(arm, config.ros2.as_ref(), robot, path)?,
    };
    Ok(BuiltArm {
        device,
        #[cfg(feature = "sim")]
        sim: None,
    })
}

/// The camera of the `[camera]` table.
fn build_camera(
    config: &CellConfig,
    calibration: Option<CameraCalibration>,
    robot: &Arc<RobotModel>,
    arm: &BuiltArm,
    feed: Option<ros2::JointFeed>,
    path: &Path,
) -> Result<BuiltCamera> {
    let (camera, ros2_settings) = (&config.camera, config.ros2.as_ref());
    let device = match camera {
        CameraConfig::Sim { .. } => return sim_camera(camera, robot, arm, feed, path),
        CameraConfig::V4l2 { .. } => hardware::v4l2_camera(camera, calibration, path)?,
        CameraConfig::Aravis { .. } => hardware::aravis_camera(camera, calibration, path)?,
        CameraConfig::Ros2 { .. } => ros2::ros2_camera(camera, ros2_settings, path)?,
    };
    Ok(BuiltCamera {
        device,
        #[cfg(feature = "sim")]
        sim: None,
    })
}

#[cfg(feature = "sim")]
fn sim_arm(arm: &ArmConfig, robot: &RobotModel, path: &Path) -> Result<BuiltArm> {
    let sim = sim::arm(arm, robot, path)?;
    Ok(BuiltArm {
        device: Arc::new(sim.clone()),
        sim: Some(sim),
    })
}

#[cfg(feature = "sim")]
fn sim_camera(
    camera: &CameraConfig,
    robot: &Arc<RobotModel>,
    arm: &BuiltArm,
    feed: Option<ros2::JointFeed>,
    path: &Path,
) -> Result<BuiltCamera> {
    let parts = sim::camera(camera, robot, arm.sim.as_ref(), feed.as_ref(), path)?;
    Ok(BuiltCamera {
        device: parts.camera.clone(),
        sim: Some(parts),
    })
}

/// Without the `sim` feature a simulated cell cannot be built: say how to get one.
#[cfg(not(feature = "sim"))]
fn sim_arm(_: &ArmConfig, _: &RobotModel, path: &Path) -> Result<BuiltArm> {
    Err(Error::input(path, "arm.kind", NO_SIM))
}

#[cfg(not(feature = "sim"))]
fn sim_camera(
    _: &CameraConfig,
    _: &Arc<RobotModel>,
    _: &BuiltArm,
    _: Option<ros2::JointFeed>,
    path: &Path,
) -> Result<BuiltCamera> {
    Err(Error::input(path, "camera.kind", NO_SIM))
}

#[cfg(not(feature = "sim"))]
const NO_SIM: &str =
    "\"sim\" needs the simulator, which this build lacks: rebuild with the default `sim` feature";

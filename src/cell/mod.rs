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

use crate::config::{
    read_config, ArmConfig, CameraCalibration, CameraConfig, CellConfig, SimArmSettings,
    SimCameraSettings,
};
#[cfg(not(feature = "sim"))]
use crate::error::Error;
use crate::error::Result;
use crate::robot::{RobotModel, RobotSource};
use crate::run::rig::RunLayout;
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
    /// The arm, behind the safety gate: every move must be a [`crate::safety::CheckedMove`].
    pub arm: SafeArm,
    /// Every camera, in the config's order: one for a `[camera]` table.
    pub units: Vec<CameraUnit>,
    /// The safety checker.
    pub checker: Arc<SafetyChecker>,
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

/// One camera of a cell, built.
pub struct CameraUnit {
    /// The camera's single-camera config (its table as `[camera]`, its segmenter as
    /// `[segmenter]`, everything else shared).
    pub config: CellConfig,
    /// The camera's name in the config.
    pub name: String,
    /// The device.
    pub device: Arc<dyn CameraDevice>,
    /// The robot as this camera sees it, for every render and solve: the cell's robot for a
    /// fixed camera; for a camera on a link, rooted at that link (so the solved pose is
    /// `camera_from_<link>`) and without the links that move with the camera.
    pub seen: Arc<RobotModel>,
    /// This camera's segmenter.
    pub segmenter: Box<dyn Segmenter>,
    /// Simulator handles for this camera (empty on real hardware).
    pub sim: SimHandles,
}

/// One camera of the cell, borrowed, with what its config table says.
#[derive(Clone, Copy)]
pub struct CameraRef<'a> {
    /// The camera's name in the config (`camera` for a single `[camera]` table).
    pub name: &'a str,
    /// The camera's table.
    pub config: &'a CameraConfig,
    /// The segmenter's settings this camera uses.
    pub segmenter_config: &'a crate::config::SegmenterConfig,
    /// The device.
    pub device: &'a Arc<dyn CameraDevice>,
    /// The robot as this camera sees it.
    pub seen: &'a Arc<RobotModel>,
    /// Its segmenter.
    pub segmenter: &'a dyn Segmenter,
    /// Its simulator handles.
    pub sim: &'a SimHandles,
    /// Its own starting pose (`[[camera]] initial_guess`).
    pub initial_guess: Option<&'a crate::config::InitialGuess>,
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
        // Every calibration file and segmentation model next: a bad one fails before any
        // hardware is opened.
        let n = config.camera.cameras().len();
        let mut prepared = Vec::with_capacity(n);
        for i in 0..n {
            let rekey = |e| crate::config::cameras::rekey(e, &config.camera, i);
            let one = config.for_camera(i);
            let calibration = one.camera.first().calibration(path).map_err(rekey)?;
            let segmenter = crate::segment::build(&one.segmenter, path).map_err(rekey)?;
            prepared.push((one, calibration, segmenter));
        }
        let robot = Arc::new(RobotModel::load(&robot_source(&config, path))?);
        // Each camera's mount against the model, before the arm opens too.
        let mut parts = Vec::with_capacity(n);
        for (i, (one, calibration, segmenter)) in prepared.into_iter().enumerate() {
            let seen = seen_robot(&config, i, &robot, path)
                .map_err(|e| crate::config::cameras::rekey(e, &config.camera, i))?;
            parts.push(UnitParts {
                one,
                calibration,
                segmenter,
                seen,
            });
        }
        let arm = build_arm(&config, &robot, path)?;
        let controller: Vec<(f64, f64, f64)> = arm
            .device
            .joints()
            .iter()
            .map(|j| (j.lower, j.upper, j.max_velocity))
            .collect();
        let checker = Arc::new(SafetyChecker::new(
            robot.clone(),
            &config.safety,
            &controller,
            path,
        )?);
        config.daemon.validate(path, robot.actuated.len())?;
        let units = parts
            .into_iter()
            .enumerate()
            .map(|(i, unit)| {
                build_unit(&config, i, unit, &robot, &arm, path)
                    .map_err(|e| crate::config::cameras::rekey(e, &config.camera, i))
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Cell {
            config,
            config_path: path.to_path_buf(),
            robot,
            arm: SafeArm::new(arm.device, checker.clone()),
            units,
            checker,
        })
    }

    /// How this cell's runs and results record its cameras: named for `[[camera]]` tables,
    /// so the daemon's API and files follow the same layout.
    pub fn layout(&self) -> RunLayout {
        RunLayout::of_cameras(&self.config.camera)
    }

    /// The simulated arm's log, when the arm is simulated.
    #[cfg(feature = "sim")]
    pub fn sim_arm(&self) -> Option<&sim::SimArmLog> {
        self.units.first().and_then(|u| u.sim.arm.as_ref())
    }

    /// The index in [`Cell::cameras`] of the camera named `name`.
    pub fn camera_index(&self, name: &str) -> Option<usize> {
        self.config
            .camera
            .cameras()
            .iter()
            .position(|c| c.name == name)
    }

    /// Every camera, with its table.
    pub fn cameras(&self) -> Vec<CameraRef<'_>> {
        self.units
            .iter()
            .zip(self.config.camera.cameras())
            .map(|(u, named)| CameraRef {
                name: &u.name,
                config: u.config.camera.first(),
                segmenter_config: &u.config.segmenter,
                device: &u.device,
                seen: &u.seen,
                segmenter: u.segmenter.as_ref(),
                sim: &u.sim,
                initial_guess: named.initial_guess.as_ref(),
            })
            .collect()
    }
}

/// What is read and checked for one camera before the arm opens: its single-camera config,
/// its calibration file, its segmenter and the robot as it sees it.
struct UnitParts {
    one: CellConfig,
    calibration: Option<CameraCalibration>,
    segmenter: Box<dyn Segmenter>,
    seen: Arc<RobotModel>,
}

/// Camera `index`: device, segmenter and simulator handles, built from its single-camera
/// config on the cell's one arm.
fn build_unit(
    config: &CellConfig,
    index: usize,
    parts: UnitParts,
    robot: &Arc<RobotModel>,
    arm: &BuiltArm,
    path: &Path,
) -> Result<CameraUnit> {
    let UnitParts {
        one,
        calibration,
        segmenter,
        seen,
    } = parts;
    let feed = ros2::joint_feed(&one, robot, path)?;
    let camera = build_camera(&one, calibration, robot, arm, feed, path)?;
    #[cfg(feature = "sim")]
    let (segmenter, sim) = sim::attach(&one, path, segmenter, arm.sim.clone(), camera.sim)?;
    #[cfg(not(feature = "sim"))]
    let sim = SimHandles::default();
    Ok(CameraUnit {
        name: config.camera.cameras()[index].name.clone(),
        config: one,
        device: camera.device,
        seen,
        segmenter,
        sim,
    })
}

/// The robot as camera `index` sees it (see [`CameraUnit::seen`]). A camera on a link needs a
/// starting pose: the automatic initialisation searches around a fixed camera only. In a
/// list, that is the camera's own `initial_guess` (one pose cannot serve several cameras).
fn seen_robot(
    config: &CellConfig,
    index: usize,
    robot: &Arc<RobotModel>,
    path: &Path,
) -> Result<Arc<RobotModel>> {
    let named = &config.camera.cameras()[index];
    let Some(link) = named.config.mount().link() else {
        return Ok(robot.clone());
    };
    let seen = robot.seen_from_link(link, path, "camera.mount.link")?;
    let one_table = RunLayout::of_cameras(&config.camera) == RunLayout::OneCamera;
    let shared_guess = config.calibration.initial_guess.is_some() && one_table;
    if named.initial_guess.is_none() && !shared_guess {
        let key = if !one_table {
            "camera.initial_guess"
        } else {
            "calibration.initial_guess"
        };
        return Err(crate::error::Error::input(
            path,
            key,
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
        package_paths: r.package_paths.iter().map(|p| dir.join(p)).collect(),
        base_link: r.base_link.clone(),
        ignore_links: r.ignore_links.clone(),
        joints: r.joints.clone(),
        xacro_args: r.xacro_args.clone(),
    }
}

/// The arm of the `[arm]` table.
fn build_arm(config: &CellConfig, robot: &RobotModel, path: &Path) -> Result<BuiltArm> {
    let device = match &config.arm {
        ArmConfig::Sim(t) => return sim_arm(t, robot, path),
        ArmConfig::Xarm(t) => hardware::xarm_arm(t, robot, path)?,
        ArmConfig::Ur(t) => hardware::ur_arm(t, robot, path)?,
        ArmConfig::Dynamixel(t) => hardware::servo_arm(
            easyhec_drivers::dynamixel::Family::Dynamixel,
            t,
            robot,
            path,
        )?,
        ArmConfig::Feetech(t) => {
            hardware::servo_arm(easyhec_drivers::dynamixel::Family::Feetech, t, robot, path)?
        }
        ArmConfig::Piper(t) => hardware::piper_arm(t, robot, path)?,
        ArmConfig::Ros2(t) => ros2::ros2_arm(t, config.ros2.as_ref(), robot, path)?,
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
    let (camera, ros2_settings) = (config.camera.first(), config.ros2.as_ref());
    let device = match camera {
        CameraConfig::Sim(t) => return sim_camera(t, robot, arm, feed, path),
        CameraConfig::V4l2(t) => hardware::v4l2_camera(t, calibration, path)?,
        CameraConfig::Aravis(t) => hardware::aravis_camera(t, calibration, path)?,
        CameraConfig::Ros2(t) => ros2::ros2_camera(t, ros2_settings, path)?,
    };
    Ok(BuiltCamera {
        device,
        #[cfg(feature = "sim")]
        sim: None,
    })
}

#[cfg(feature = "sim")]
fn sim_arm(arm: &SimArmSettings, robot: &RobotModel, path: &Path) -> Result<BuiltArm> {
    let sim = sim::arm(arm, robot, path)?;
    Ok(BuiltArm {
        device: Arc::new(sim.clone()),
        sim: Some(sim),
    })
}

#[cfg(feature = "sim")]
fn sim_camera(
    camera: &SimCameraSettings,
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
fn sim_arm(_: &SimArmSettings, _: &RobotModel, path: &Path) -> Result<BuiltArm> {
    Err(Error::input(path, "arm.kind", NO_SIM))
}

#[cfg(not(feature = "sim"))]
fn sim_camera(
    _: &SimCameraSettings,
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

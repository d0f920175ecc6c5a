//! Real devices behind each `kind`: the arm and camera drivers a config names, with their
//! settings checked and converted. Drivers that need a native library sit behind cargo
//! features; without one, a config that names it gets a one-line "rebuild with" error.

use std::path::Path;
use std::sync::Arc;

use easyhec_drivers::dynamixel::{Family, ServoArm, ServoArmConfig, ServoJoint};
use easyhec_drivers::xarm::{Model as XArmModel, XArm, XArmConfig};
use easyhec_drivers::{Arm, Camera as CameraDevice};

use crate::config::{
    seconds, AravisSettings, CameraCalibration, PiperSettings, ServoArmSettings, UrSettings,
    V4l2Settings, XarmSettings,
};
use crate::error::{Error, Result};
use crate::robot::RobotModel;

/// The arm of an `[arm] kind = "xarm"` table.
pub(super) fn xarm_arm(t: &XarmSettings, robot: &RobotModel, path: &Path) -> Result<Arc<dyn Arm>> {
    let n = robot.actuated.len();
    let model: XArmModel = t
        .model
        .parse()
        .map_err(|e: String| Error::input(path, "arm.model", e))?;
    if model.axes() != n {
        return Err(Error::input(
            path,
            "arm.model",
            format!(
                "an {model} has {} joints; the URDF has {n} actuated joints",
                model.axes()
            ),
        ));
    }
    let mut cfg = XArmConfig::new(t.addr.clone(), model);
    cfg.joint_names = Some(robot.joint_names().iter().map(|s| s.to_string()).collect());
    cfg.speed_cap_rad_s = t.speed_cap_rad_s;
    cfg.accel_rad_s2 = t.accel_rad_s2;
    cfg.connect_timeout = seconds(path, "arm.connect_timeout_s", t.connect_timeout_s)?;
    cfg.reply_timeout = seconds(path, "arm.reply_timeout_s", t.reply_timeout_s)?;
    cfg.motion_timeout_margin = seconds(
        path,
        "arm.motion_timeout_margin_s",
        t.motion_timeout_margin_s,
    )?;
    let arm = XArm::new(cfg).map_err(|e| Error::input(path, "arm", e.to_string()))?;
    Ok(Arc::new(arm))
}

/// The UR arm of an `[arm] kind = "ur"` table.
#[cfg(feature = "ur")]
pub(super) fn ur_arm(t: &UrSettings, robot: &RobotModel, path: &Path) -> Result<Arc<dyn Arm>> {
    use easyhec_drivers::ur::{UrArm, UrConfig};
    let host = &t.host;
    let n = robot.actuated.len();
    if n != 6 {
        return Err(Error::input(
            path,
            "robot.urdf",
            format!("a UR arm has 6 joints; the URDF has {n} actuated joints"),
        ));
    }
    if host.contains(':') {
        return Err(Error::input(
            path,
            "arm.host",
            format!(
                "{host:?}: give the address only; ur_rtde always uses ports 30004, 29999 and 30003"
            ),
        ));
    }
    let mut cfg = UrConfig::new(host.clone());
    cfg.joint_names = Some(robot.joint_names().iter().map(|s| s.to_string()).collect());
    cfg.speed_cap_rad_s = t.speed_cap_rad_s;
    cfg.accel_rad_s2 = t.accel_rad_s2;
    cfg.frequency_hz = t.frequency_hz;
    cfg.connect_timeout = seconds(path, "arm.connect_timeout_s", t.connect_timeout_s)?;
    cfg.call_timeout = seconds(path, "arm.call_timeout_s", t.call_timeout_s)?;
    cfg.motion_timeout_margin = seconds(
        path,
        "arm.motion_timeout_margin_s",
        t.motion_timeout_margin_s,
    )?;
    let arm = UrArm::new(cfg).map_err(|e| Error::input(path, "arm", e.to_string()))?;
    Ok(Arc::new(arm))
}

/// Without the `ur` feature a UR cell cannot be built: say how to get one.
#[cfg(not(feature = "ur"))]
pub(super) fn ur_arm(_: &UrSettings, _: &RobotModel, path: &Path) -> Result<Arc<dyn Arm>> {
    Err(Error::input(
        path,
        "arm.kind",
        "\"ur\" needs the UR driver, which this build lacks: rebuild with --features ur",
    ))
}

/// The arm of an `[arm] kind = "dynamixel" | "feetech"` table.
pub(super) fn servo_arm(
    family: Family,
    t: &ServoArmSettings,
    robot: &RobotModel,
    path: &Path,
) -> Result<Arc<dyn Arm>> {
    let urdf = robot.joint_names();
    let names: Vec<&str> = t.joints.iter().map(|j| j.name.as_str()).collect();
    if names != urdf {
        return Err(Error::input(
            path,
            "arm.joints",
            format!(
                "joints {names:?}: list one [[arm.joints]] per URDF actuated joint, in order: {urdf:?}"
            ),
        ));
    }
    let joints = t
        .joints
        .iter()
        .map(|j| ServoJoint {
            name: j.name.clone(),
            id: j.id,
            offset_rad: j.offset_rad,
            direction: j.direction,
            ticks_per_rev: j.ticks_per_rev,
            lower_rad: j.lower_rad,
            upper_rad: j.upper_rad,
        })
        .collect();
    let baud = t.baud_or_factory(family == Family::Feetech);
    let mut cfg = ServoArmConfig::new(family, t.port.clone(), baud, joints);
    cfg.speed_cap_rad_s = t.speed_cap_rad_s;
    cfg.accel_rad_s2 = t.accel_rad_s2;
    cfg.reply_timeout = seconds(path, "arm.reply_timeout_s", t.reply_timeout_s)?;
    cfg.motion_timeout_margin = seconds(
        path,
        "arm.motion_timeout_margin_s",
        t.motion_timeout_margin_s,
    )?;
    let arm = ServoArm::new(cfg).map_err(|e| Error::input(path, "arm", e.to_string()))?;
    Ok(Arc::new(arm))
}

/// The arm of an `[arm] kind = "piper"` table.
#[cfg(feature = "socketcan")]
pub(super) fn piper_arm(
    t: &PiperSettings,
    robot: &RobotModel,
    path: &Path,
) -> Result<Arc<dyn Arm>> {
    use easyhec_drivers::piper::{PiperArm, PiperConfig, SocketCan};
    let names = robot.joint_names();
    if names.len() != 6 {
        return Err(Error::input(
            path,
            "robot.urdf",
            format!(
                "a Piper has 6 joints; the URDF has {} actuated joints",
                names.len()
            ),
        ));
    }
    let mut cfg = PiperConfig {
        joint_names: names.iter().map(|s| s.to_string()).collect(),
        ..PiperConfig::default()
    };
    cfg.speed_cap_rad_s = t.speed_cap_rad_s;
    cfg.full_speed_rad_s = t.full_speed_rad_s;
    cfg.enable_timeout = seconds(path, "arm.enable_timeout_s", t.enable_timeout_s)?;
    cfg.motion_timeout_margin = seconds(
        path,
        "arm.motion_timeout_margin_s",
        t.motion_timeout_margin_s,
    )?;
    let arm = PiperArm::new(cfg, Arc::new(SocketCan::new(&t.interface)))
        .map_err(|e| Error::input(path, "arm", e.to_string()))?;
    Ok(Arc::new(arm))
}

/// Without the `socketcan` feature a Piper config is an error that says how to get one.
#[cfg(not(feature = "socketcan"))]
pub(super) fn piper_arm(_: &PiperSettings, _: &RobotModel, path: &Path) -> Result<Arc<dyn Arm>> {
    Err(Error::input(
        path,
        "arm.kind",
        "\"piper\" drives SocketCAN, which this build leaves out: rebuild with --features socketcan",
    ))
}

/// The calibration [`CameraConfig::calibration`] read for a hardware camera kind.
#[cfg(any(feature = "v4l2", feature = "aravis"))]
pub(super) fn calibration_of(
    calibration: Option<CameraCalibration>,
    path: &Path,
) -> Result<CameraCalibration> {
    calibration.ok_or_else(|| {
        Error::input(
            path,
            "camera.intrinsics",
            "a hardware camera needs its calibration file",
        )
    })
}

/// A driver error while opening a camera: a calibration-size mismatch names the calibration
/// file and field; anything else the config's `[camera]` table.
#[cfg(any(feature = "v4l2", feature = "aravis"))]
pub(super) fn camera_open_error(e: easyhec_drivers::DriverError, path: &Path) -> Error {
    if let easyhec_drivers::DriverError::Backend(inner) = &e {
        if let Some(ie) = inner.downcast_ref::<easyhec_drivers::intrinsics::IntrinsicsError>() {
            return crate::config::camera::intrinsics_error(ie.clone(), path);
        }
    }
    Error::input(path, "camera", e.to_string())
}

/// The webcam of a `[camera] kind = "v4l2"` table (opened and streaming).
#[cfg(feature = "v4l2")]
pub(super) fn v4l2_camera(
    t: &V4l2Settings,
    calibration: Option<CameraCalibration>,
    path: &Path,
) -> Result<Arc<dyn CameraDevice>> {
    use easyhec_drivers::v4l2::{V4l2Camera, V4l2Config};
    let calibration = calibration_of(calibration, path)?;
    let format = t
        .pixel_format
        .parse()
        .map_err(|e: String| Error::input(path, "camera.pixel_format", e))?;
    let mut cfg = V4l2Config::new(
        t.device.clone(),
        t.width,
        t.height,
        format,
        calibration.intrinsics,
        calibration.file,
    );
    cfg.exposure_us = t.exposure_us;
    cfg.frame_timeout = seconds(path, "camera.frame_timeout_s", t.frame_timeout_s)?;
    let camera = V4l2Camera::open(cfg).map_err(|e| camera_open_error(e, path))?;
    Ok(Arc::new(camera))
}

/// Without the `v4l2` feature a webcam config is an error that says how to get one.
#[cfg(not(feature = "v4l2"))]
pub(super) fn v4l2_camera(
    _: &V4l2Settings,
    _: Option<CameraCalibration>,
    path: &Path,
) -> Result<Arc<dyn CameraDevice>> {
    Err(Error::input(
        path,
        "camera.kind",
        "\"v4l2\" needs the V4L2 camera driver, which this build leaves out: rebuild with --features v4l2",
    ))
}

/// The camera of a `[camera] kind = "aravis"` table (opened and streaming).
#[cfg(feature = "aravis")]
pub(super) fn aravis_camera(
    t: &AravisSettings,
    calibration: Option<CameraCalibration>,
    path: &Path,
) -> Result<Arc<dyn CameraDevice>> {
    use easyhec_drivers::aravis::{AravisCamera, AravisConfig};
    let calibration = calibration_of(calibration, path)?;
    let format = t
        .pixel_format
        .parse()
        .map_err(|e: String| Error::input(path, "camera.pixel_format", e))?;
    let mut cfg = AravisConfig::new(
        t.device_id.clone(),
        format,
        calibration.intrinsics,
        calibration.file,
    );
    cfg.exposure_us = t.exposure_us;
    cfg.gain_db = t.gain_db;
    cfg.frame_timeout = seconds(path, "camera.frame_timeout_s", t.frame_timeout_s)?;
    let camera = AravisCamera::open(cfg).map_err(|e| camera_open_error(e, path))?;
    Ok(Arc::new(camera))
}

/// Without the `aravis` feature a GenICam camera config is an error that says how to get one.
#[cfg(not(feature = "aravis"))]
pub(super) fn aravis_camera(
    _: &AravisSettings,
    _: Option<CameraCalibration>,
    path: &Path,
) -> Result<Arc<dyn CameraDevice>> {
    Err(Error::input(
        path,
        "camera.kind",
        "\"aravis\" needs the Aravis (GigE Vision / USB3 Vision) driver, which this build leaves out: rebuild with --features aravis",
    ))
}

//! Real devices behind each `kind`: the arm and camera drivers a config names, with their
//! settings checked and converted. Drivers that need a native library sit behind cargo
//! features; without one, a config that names it gets a one-line "rebuild with" error.

use std::path::Path;
use std::sync::Arc;

use easyhec_drivers::dynamixel::{Family, ServoArm, ServoArmConfig, ServoJoint};
use easyhec_drivers::xarm::{Model as XArmModel, XArm, XArmConfig};
use easyhec_drivers::{Arm, Camera as CameraDevice};

use crate::config::{seconds, ArmConfig, CameraCalibration, CameraConfig, ServoArmToml};
use crate::error::{Error, Result};
use crate::robot::RobotModel;

/// The arm of an `[arm] kind = "xarm"` table.
pub(super) fn xarm_arm(arm: &ArmConfig, robot: &RobotModel, path: &Path) -> Result<Arc<dyn Arm>> {
    let ArmConfig::Xarm {
        addr,
        model,
        speed_cap_rad_s,
        accel_rad_s2,
        connect_timeout_s,
        reply_timeout_s,
        motion_timeout_margin_s,
    } = arm
    else {
        unreachable!("called for kind = \"xarm\" only")
    };
    let n = robot.actuated.len();
    let model: XArmModel = model
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
    let mut cfg = XArmConfig::new(addr.clone(), model);
    cfg.joint_names = Some(robot.joint_names().iter().map(|s| s.to_string()).collect());
    if let Some(v) = speed_cap_rad_s {
        cfg.speed_cap_rad_s = *v;
    }
    if let Some(v) = accel_rad_s2 {
        cfg.accel_rad_s2 = *v;
    }
    cfg.connect_timeout = seconds(path, "arm.connect_timeout_s", *connect_timeout_s, 3.0)?;
    cfg.reply_timeout = seconds(path, "arm.reply_timeout_s", *reply_timeout_s, 2.0)?;
    cfg.motion_timeout_margin = seconds(
        path,
        "arm.motion_timeout_margin_s",
        *motion_timeout_margin_s,
        10.0,
    )?;
    let arm = XArm::new(cfg).map_err(|e| Error::input(path, "arm", e.to_string()))?;
    Ok(Arc::new(arm))
}

/// The UR arm of an `[arm] kind = "ur"` table.
#[cfg(feature = "ur")]
pub(super) fn ur_arm(arm: &ArmConfig, robot: &RobotModel, path: &Path) -> Result<Arc<dyn Arm>> {
    use easyhec_drivers::ur::{UrArm, UrConfig};
    let ArmConfig::Ur {
        host,
        speed_cap_rad_s,
        accel_rad_s2,
        frequency_hz,
        connect_timeout_s,
        call_timeout_s,
        motion_timeout_margin_s,
    } = arm
    else {
        unreachable!("called for kind = \"ur\" only")
    };
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
    if let Some(v) = speed_cap_rad_s {
        cfg.speed_cap_rad_s = *v;
    }
    if let Some(v) = accel_rad_s2 {
        cfg.accel_rad_s2 = *v;
    }
    if let Some(v) = frequency_hz {
        cfg.frequency_hz = *v;
    }
    cfg.connect_timeout = seconds(path, "arm.connect_timeout_s", *connect_timeout_s, 10.0)?;
    cfg.call_timeout = seconds(path, "arm.call_timeout_s", *call_timeout_s, 2.0)?;
    cfg.motion_timeout_margin = seconds(
        path,
        "arm.motion_timeout_margin_s",
        *motion_timeout_margin_s,
        10.0,
    )?;
    let arm = UrArm::new(cfg).map_err(|e| Error::input(path, "arm", e.to_string()))?;
    Ok(Arc::new(arm))
}

/// Without the `ur` feature a UR cell cannot be built: say how to get one.
#[cfg(not(feature = "ur"))]
pub(super) fn ur_arm(_arm: &ArmConfig, _robot: &RobotModel, path: &Path) -> Result<Arc<dyn Arm>> {
    Err(Error::input(
        path,
        "arm.kind",
        "\"ur\" needs the UR driver, which this build lacks: rebuild with --features ur",
    ))
}

/// The arm of an `[arm] kind = "dynamixel" | "feetech"` table.
pub(super) fn servo_arm(
    family: Family,
    t: &ServoArmToml,
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
            ticks_per_rev: j.ticks_per_rev.unwrap_or(4096),
            lower_rad: j.lower_rad,
            upper_rad: j.upper_rad,
        })
        .collect();
    let default_baud = match family {
        Family::Dynamixel => 57_600,
        Family::Feetech => 1_000_000,
    };
    let mut cfg = ServoArmConfig::new(
        family,
        t.port.clone(),
        t.baud.unwrap_or(default_baud),
        joints,
    );
    if let Some(v) = t.speed_cap_rad_s {
        cfg.speed_cap_rad_s = v;
    }
    if let Some(v) = t.accel_rad_s2 {
        cfg.accel_rad_s2 = v;
    }
    cfg.reply_timeout = seconds(path, "arm.reply_timeout_s", t.reply_timeout_s, 0.1)?;
    cfg.motion_timeout_margin = seconds(
        path,
        "arm.motion_timeout_margin_s",
        t.motion_timeout_margin_s,
        5.0,
    )?;
    let arm = ServoArm::new(cfg).map_err(|e| Error::input(path, "arm", e.to_string()))?;
    Ok(Arc::new(arm))
}

/// The arm of an `[arm] kind = "piper"` table.
#[cfg(feature = "socketcan")]
pub(super) fn piper_arm(arm: &ArmConfig, robot: &RobotModel, path: &Path) -> Result<Arc<dyn Arm>> {
    use easyhec_drivers::piper::{PiperArm, PiperConfig, SocketCan};
    let ArmConfig::Piper {
        interface,
        speed_cap_rad_s,
        full_speed_rad_s,
        enable_timeout_s,
        motion_timeout_margin_s,
    } = arm
    else {
        unreachable!("called for kind = \"piper\" only")
    };
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
    if let Some(v) = speed_cap_rad_s {
        cfg.speed_cap_rad_s = *v;
    }
    if let Some(v) = full_speed_rad_s {
        cfg.full_speed_rad_s = *v;
    }
    cfg.enable_timeout = seconds(path, "arm.enable_timeout_s", *enable_timeout_s, 5.0)?;
    cfg.motion_timeout_margin = seconds(
        path,
        "arm.motion_timeout_margin_s",
        *motion_timeout_margin_s,
        10.0,
    )?;
    let arm = PiperArm::new(cfg, Arc::new(SocketCan::new(interface)))
        .map_err(|e| Error::input(path, "arm", e.to_string()))?;
    Ok(Arc::new(arm))
}

/// Without the `socketcan` feature a Piper config is an error that says how to get one.
#[cfg(not(feature = "socketcan"))]
pub(super) fn piper_arm(_: &ArmConfig, _: &RobotModel, path: &Path) -> Result<Arc<dyn Arm>> {
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
    camera: &CameraConfig,
    calibration: Option<CameraCalibration>,
    path: &Path,
) -> Result<Arc<dyn CameraDevice>> {
    use easyhec_drivers::v4l2::{V4l2Camera, V4l2Config};
    let CameraConfig::V4l2 {
        device,
        width,
        height,
        pixel_format,
        exposure_us,
        frame_timeout_s,
        ..
    } = camera
    else {
        unreachable!("called for kind = \"v4l2\" only")
    };
    let calibration = calibration_of(calibration, path)?;
    let format = pixel_format
        .parse()
        .map_err(|e: String| Error::input(path, "camera.pixel_format", e))?;
    let mut cfg = V4l2Config::new(
        device.clone(),
        *width,
        *height,
        format,
        calibration.intrinsics,
        calibration.file,
    );
    cfg.exposure_us = *exposure_us;
    cfg.frame_timeout = seconds(path, "camera.frame_timeout_s", *frame_timeout_s, 2.0)?;
    let camera = V4l2Camera::open(cfg).map_err(|e| camera_open_error(e, path))?;
    Ok(Arc::new(camera))
}

/// Without the `v4l2` feature a webcam config is an error that says how to get one.
#[cfg(not(feature = "v4l2"))]
pub(super) fn v4l2_camera(
    _: &CameraConfig,
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
    camera: &CameraConfig,
    calibration: Option<CameraCalibration>,
    path: &Path,
) -> Result<Arc<dyn CameraDevice>> {
    use easyhec_drivers::aravis::{AravisCamera, AravisConfig};
    let CameraConfig::Aravis {
        device_id,
        pixel_format,
        exposure_us,
        gain_db,
        frame_timeout_s,
        ..
    } = camera
    else {
        unreachable!("called for kind = \"aravis\" only")
    };
    let calibration = calibration_of(calibration, path)?;
    let format = pixel_format
        .parse()
        .map_err(|e: String| Error::input(path, "camera.pixel_format", e))?;
    let mut cfg = AravisConfig::new(
        device_id.clone(),
        format,
        calibration.intrinsics,
        calibration.file,
    );
    cfg.exposure_us = *exposure_us;
    cfg.gain_db = *gain_db;
    cfg.frame_timeout = seconds(path, "camera.frame_timeout_s", *frame_timeout_s, 2.0)?;
    let camera = AravisCamera::open(cfg).map_err(|e| camera_open_error(e, path))?;
    Ok(Arc::new(camera))
}

/// Without the `aravis` feature a GenICam camera config is an error that says how to get one.
#[cfg(not(feature = "aravis"))]
pub(super) fn aravis_camera(
    _: &CameraConfig,
    _: Option<CameraCalibration>,
    path: &Path,
) -> Result<Arc<dyn CameraDevice>> {
    Err(Error::input(
        path,
        "camera.kind",
        "\"aravis\" needs the Aravis (GigE Vision / USB3 Vision) driver, which this build leaves out: rebuild with --features aravis",
    ))
}

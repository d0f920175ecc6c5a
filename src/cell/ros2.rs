//! The ROS 2 parts of a cell: the arm of an `[arm] kind = "ros2"` table, and the joint source
//! of a simulated camera filming an arm whose true joints are on `/joint_states`. The graph
//! place (domain, namespace) comes from the `[ros2]` table.

use std::path::Path;
use std::sync::Arc;

use easyhec_drivers::Arm;

use crate::config::ros2::Ros2Settings;
use crate::config::{seconds, ArmConfig};
use crate::error::{Error, Result};
use crate::robot::RobotModel;

/// Default `/joint_states` topic.
pub const JOINT_STATES_TOPIC: &str = "/joint_states";

/// Default command topic: ros2_control's joint_trajectory_controller under its usual name.
pub const COMMAND_TOPIC: &str = "/joint_trajectory_controller/joint_trajectory";

/// The arm of an `[arm] kind = "ros2"` table.
#[cfg(feature = "ros2")]
pub(super) fn ros2_arm(
    arm: &ArmConfig,
    ros2: Option<&Ros2Settings>,
    robot: &RobotModel,
    path: &Path,
) -> Result<Arc<dyn Arm>> {
    use easyhec_drivers::ros2::arm::{Ros2Arm, Ros2ArmOptions};
    let ArmConfig::Ros2 {
        joint_states_topic,
        command_topic,
        joint_names,
        stale_after_s,
        arrival_tolerance_rad,
        connect_timeout_s,
        motion_timeout_margin_s,
    } = arm
    else {
        unreachable!("called for kind = \"ros2\" only")
    };
    let names = controller_joint_names(joint_names.as_deref(), robot, path)?;
    let continuous = robot
        .actuated
        .iter()
        .map(|&i| robot.joints[i].kind == crate::robot::JointKind::Continuous)
        .collect();
    let joints = robot
        .actuated
        .iter()
        .zip(names)
        .map(|(&i, name)| {
            let j = &robot.joints[i];
            easyhec_drivers::JointLimit {
                name,
                lower: j.lower,
                upper: j.upper,
                max_velocity: j.velocity,
            }
        })
        .collect();
    let options = Ros2ArmOptions {
        place: easyhec_drivers::ros2::GraphPlace {
            domain_id: Ros2Settings::domain(ros2)?,
            namespace: Ros2Settings::namespace_of(ros2),
            node_name: "easyhec_arm".into(),
        },
        joint_states_topic: joint_states_topic
            .clone()
            .unwrap_or_else(|| JOINT_STATES_TOPIC.into()),
        command_topic: command_topic
            .clone()
            .unwrap_or_else(|| COMMAND_TOPIC.into()),
        joints,
        continuous,
        stale_after: seconds(path, "arm.stale_after_s", *stale_after_s, 0.5)?,
        arrival_tolerance_rad: arrival_tolerance_rad.unwrap_or(0.002),
        connect_timeout: seconds(path, "arm.connect_timeout_s", *connect_timeout_s, 10.0)?,
        arrival_margin: seconds(
            path,
            "arm.motion_timeout_margin_s",
            *motion_timeout_margin_s,
            10.0,
        )?,
    };
    let arm = Ros2Arm::new(options).map_err(|e| Error::input(path, "arm", e.to_string()))?;
    Ok(Arc::new(arm))
}

/// Without the `ros2` feature a ROS 2 arm cannot be built: say how to get one.
#[cfg(not(feature = "ros2"))]
pub(super) fn ros2_arm(
    _: &ArmConfig,
    _: Option<&Ros2Settings>,
    _: &RobotModel,
    path: &Path,
) -> Result<Arc<dyn Arm>> {
    Err(Error::input(
        path,
        "arm.kind",
        "\"ros2\" needs ROS 2 support, which this build leaves out: rebuild with --features ros2",
    ))
}

/// The controller's names for the URDF's actuated joints: `joint_names` when given (one per
/// actuated joint), else the URDF's own.
pub(super) fn controller_joint_names(
    given: Option<&[String]>,
    robot: &RobotModel,
    path: &Path,
) -> Result<Vec<String>> {
    let urdf: Vec<String> = robot.joint_names().iter().map(|s| s.to_string()).collect();
    match given {
        None => Ok(urdf),
        Some(names) if names.len() == urdf.len() => Ok(names.to_vec()),
        Some(names) => Err(Error::input(
            path,
            "arm.joint_names",
            format!(
                "has {} names; allowed: one per URDF actuated joint, in order ({} for {urdf:?})",
                names.len(),
                urdf.len()
            ),
        )),
    }
}

/// Where a simulated camera with `joints_from = { kind = "ros2" }` reads the true joints:
/// plain data, gathered from the `[ros2]`, `[arm]` and `[camera]` tables.
#[derive(Clone, Debug)]
pub struct JointFeed {
    /// Domain.
    pub domain_id: u16,
    /// Namespace.
    pub namespace: String,
    /// The `sensor_msgs/JointState` topic.
    pub topic: String,
    /// The joints' names on that topic, in the URDF's actuated order.
    pub names: Vec<String>,
    /// Limit for the first complete message.
    pub timeout: std::time::Duration,
}

/// The feed of a simulated camera filming a ROS 2 arm; `None` for every other camera.
pub(super) fn joint_feed(
    config: &crate::config::CellConfig,
    robot: &RobotModel,
    path: &Path,
) -> Result<Option<JointFeed>> {
    use crate::config::{CameraConfig, JointsFrom};
    let CameraConfig::Sim {
        joints_from: Some(JointsFrom::Ros2 { topic, timeout_s }),
        ..
    } = &*config.camera
    else {
        return Ok(None);
    };
    if let Some(t) = topic {
        crate::config::ros2::check_topic(t)
            .map_err(|m| Error::input(path, "camera.joints_from.topic", format!("is {m}")))?;
    }
    let given = match &config.arm {
        ArmConfig::Ros2 { joint_names, .. } => joint_names.as_deref(),
        _ => None,
    };
    let ros2 = config.ros2.as_ref();
    Ok(Some(JointFeed {
        domain_id: Ros2Settings::domain(ros2)?,
        namespace: Ros2Settings::namespace_of(ros2),
        topic: topic.clone().unwrap_or_else(|| JOINT_STATES_TOPIC.into()),
        names: controller_joint_names(given, robot, path)?,
        timeout: seconds(path, "camera.joints_from.timeout_s", *timeout_s, 10.0)?,
    }))
}

/// A simulated camera's true joints from `/joint_states`.
#[cfg(all(feature = "ros2", feature = "sim"))]
pub(super) mod feed {
    use std::sync::Arc;
    use std::time::{Duration, Instant};

    use async_trait::async_trait;
    use easyhec_drivers::ros2::joint_states::JointStateReader;
    use easyhec_drivers::{DriverError, Result};
    use easyhec_mocks::JointSource;

    use super::JointFeed;

    /// How old a reading may be and still count as the truth of the frame being rendered.
    const FRESH: Duration = Duration::from_millis(500);

    struct Ros2Joints {
        reader: JointStateReader,
        timeout: Duration,
        created: Instant,
        _graph: std::sync::Mutex<(ros2_client::Context, ros2_client::Node)>,
    }

    #[async_trait]
    impl JointSource for Ros2Joints {
        async fn true_joints(&self) -> Result<Vec<f64>> {
            loop {
                match self.reader.positions(FRESH) {
                    Ok(q) => return Ok(q),
                    Err(_) if self.created.elapsed() < self.timeout => {
                        tokio::time::sleep(Duration::from_millis(10)).await
                    }
                    Err(e) => return Err(e),
                }
            }
        }
    }

    /// Subscribes on a node of its own.
    pub fn source(feed: &JointFeed) -> Result<Arc<dyn JointSource>> {
        let place = easyhec_drivers::ros2::GraphPlace {
            domain_id: feed.domain_id,
            namespace: feed.namespace.clone(),
            node_name: "easyhec_sim_camera".into(),
        };
        let (context, mut node) = easyhec_drivers::ros2::join(&place)?;
        let reader =
            JointStateReader::start(&mut node, &feed.namespace, &feed.topic, feed.names.clone())
                .map_err(|e| DriverError::Connection(e.to_string()))?;
        Ok(Arc::new(Ros2Joints {
            reader,
            timeout: feed.timeout,
            created: Instant::now(),
            _graph: std::sync::Mutex::new((context, node)),
        }))
    }
}

/// Default image topic: a RealSense or most UVC drivers' colour stream.
pub const IMAGE_TOPIC: &str = "/camera/color/image_raw";

/// Default CameraInfo topic, beside [`IMAGE_TOPIC`].
pub const CAMERA_INFO_TOPIC: &str = "/camera/color/camera_info";

/// The camera of a `[camera] kind = "ros2"` table: opened, with its CameraInfo read.
#[cfg(feature = "ros2")]
pub(super) fn ros2_camera(
    camera: &crate::config::CameraConfig,
    ros2: Option<&Ros2Settings>,
    path: &Path,
) -> Result<Arc<dyn easyhec_drivers::Camera>> {
    use easyhec_drivers::ros2::camera::{Ros2Camera, Ros2CameraOptions};
    let crate::config::CameraConfig::Ros2 {
        image_topic,
        camera_info_topic,
        connect_timeout_s,
        frame_timeout_s,
        ..
    } = camera
    else {
        unreachable!("called for kind = \"ros2\" only")
    };
    let options = Ros2CameraOptions {
        place: easyhec_drivers::ros2::GraphPlace {
            domain_id: Ros2Settings::domain(ros2)?,
            namespace: Ros2Settings::namespace_of(ros2),
            node_name: "easyhec_camera".into(),
        },
        image_topic: image_topic.clone().unwrap_or_else(|| IMAGE_TOPIC.into()),
        camera_info_topic: camera_info_topic
            .clone()
            .unwrap_or_else(|| CAMERA_INFO_TOPIC.into()),
        connect_timeout: seconds(path, "camera.connect_timeout_s", *connect_timeout_s, 10.0)?,
        frame_timeout: seconds(path, "camera.frame_timeout_s", *frame_timeout_s, 2.0)?,
    };
    let camera =
        Ros2Camera::open(options).map_err(|e| Error::input(path, "camera", e.to_string()))?;
    Ok(Arc::new(camera))
}

/// Without the `ros2` feature a ROS 2 camera cannot be opened: say how to get one.
#[cfg(not(feature = "ros2"))]
pub(super) fn ros2_camera(
    _: &crate::config::CameraConfig,
    _: Option<&Ros2Settings>,
    path: &Path,
) -> Result<Arc<dyn easyhec_drivers::Camera>> {
    Err(Error::input(
        path,
        "camera.kind",
        "\"ros2\" needs ROS 2 support, which this build leaves out: rebuild with --features ros2",
    ))
}

//! The ROS 2 parts of a cell: the arm of an `[arm] kind = "ros2"` table, and the joint source
//! of a simulated camera filming an arm whose true joints are on `/joint_states`. The graph
//! place (domain, namespace) comes from the `[ros2]` table.

use std::path::Path;
use std::sync::Arc;

use easyhec_drivers::Arm;

use crate::config::ros2::Ros2Settings;
use crate::config::{seconds, ArmConfig, Ros2ArmSettings, Ros2CameraSettings};
use crate::error::{Error, Result};
use crate::robot::RobotModel;

/// The arm of an `[arm] kind = "ros2"` table.
#[cfg(feature = "ros2")]
pub(super) fn ros2_arm(
    t: &Ros2ArmSettings,
    ros2: Option<&Ros2Settings>,
    robot: &RobotModel,
    path: &Path,
) -> Result<Arc<dyn Arm>> {
    use easyhec_drivers::ros2::arm::{Ros2Arm, Ros2ArmOptions};
    let names = controller_joint_names(t.joint_names.as_deref(), robot, path)?;
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
        joint_states_topic: t.joint_states_topic.clone(),
        command_topic: t.command_topic.clone(),
        joints,
        continuous,
        stale_after: seconds(path, "arm.stale_after_s", t.stale_after_s)?,
        arrival_tolerance_rad: t.arrival_tolerance_rad,
        connect_timeout: seconds(path, "arm.connect_timeout_s", t.connect_timeout_s)?,
        arrival_margin: seconds(
            path,
            "arm.motion_timeout_margin_s",
            t.motion_timeout_margin_s,
        )?,
    };
    let arm = Ros2Arm::new(options).map_err(|e| Error::input(path, "arm", e.to_string()))?;
    Ok(Arc::new(arm))
}

/// Without the `ros2` feature a ROS 2 arm cannot be built: say how to get one.
#[cfg(not(feature = "ros2"))]
pub(super) fn ros2_arm(
    _: &Ros2ArmSettings,
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
    use crate::config::{CameraConfig, JointsFrom, SimCameraSettings};
    let CameraConfig::Sim(SimCameraSettings {
        joints_from: Some(JointsFrom::Ros2 { topic, timeout_s }),
        ..
    }) = config.camera.first()
    else {
        return Ok(None);
    };
    crate::config::ros2::check_topic(topic)
        .map_err(|m| Error::input(path, "camera.joints_from.topic", format!("is {m}")))?;
    let given = match &config.arm {
        ArmConfig::Ros2(t) => t.joint_names.as_deref(),
        _ => None,
    };
    let ros2 = config.ros2.as_ref();
    Ok(Some(JointFeed {
        domain_id: Ros2Settings::domain(ros2)?,
        namespace: Ros2Settings::namespace_of(ros2),
        topic: topic.clone(),
        names: controller_joint_names(given, robot, path)?,
        timeout: seconds(path, "camera.joints_from.timeout_s", *timeout_s)?,
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

/// The camera of a `[camera] kind = "ros2"` table: opened, with its CameraInfo read.
#[cfg(feature = "ros2")]
pub(super) fn ros2_camera(
    t: &Ros2CameraSettings,
    ros2: Option<&Ros2Settings>,
    path: &Path,
) -> Result<Arc<dyn easyhec_drivers::Camera>> {
    use easyhec_drivers::ros2::camera::{Ros2Camera, Ros2CameraOptions};
    let options = Ros2CameraOptions {
        place: easyhec_drivers::ros2::GraphPlace {
            domain_id: Ros2Settings::domain(ros2)?,
            namespace: Ros2Settings::namespace_of(ros2),
            node_name: "easyhec_camera".into(),
        },
        image_topic: t.image_topic.clone(),
        camera_info_topic: t.camera_info_topic.clone(),
        connect_timeout: seconds(path, "camera.connect_timeout_s", t.connect_timeout_s)?,
        frame_timeout: seconds(path, "camera.frame_timeout_s", t.frame_timeout_s)?,
    };
    let camera =
        Ros2Camera::open(options).map_err(|e| Error::input(path, "camera", e.to_string()))?;
    Ok(Arc::new(camera))
}

/// Without the `ros2` feature a ROS 2 camera cannot be opened: say how to get one.
#[cfg(not(feature = "ros2"))]
pub(super) fn ros2_camera(
    _: &Ros2CameraSettings,
    _: Option<&Ros2Settings>,
    path: &Path,
) -> Result<Arc<dyn easyhec_drivers::Camera>> {
    Err(Error::input(
        path,
        "camera.kind",
        "\"ros2\" needs ROS 2 support, which this build leaves out: rebuild with --features ros2",
    ))
}

//! `[arm] kind = "ros2"`: an arm driven through ros2_control. Positions come from
//! `/joint_states`; a move is one `trajectory_msgs/JointTrajectory` point sent to the
//! joint_trajectory_controller's topic. With positions only, that controller interpolates
//! linearly from where the arm is, so every joint starts and ends together: the straight
//! joint-space path the safety checker validated. Arrival is judged on `/joint_states`.
//!
//! The topic interface has no acknowledgement: a command the controller refuses (inactive,
//! unknown joint names) shows only as a move that never arrives, reported as stalled. A stop is
//! one point where the joints are now (heard within 0.1 s), 0.1 s ahead; an empty trajectory
//! would be refused by current controllers, and older positions would pull a moving arm back. A continuous joint moves at most π per command, since the controller
//! takes it the short way round.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use async_trait::async_trait;
use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{Context, MessageTypeName, Node, Publisher, QosProfile};

use super::joint_states::JointStateReader;
use super::msgs::{Header, JointTrajectory, JointTrajectoryPoint, Time};
use super::GraphPlace;
use crate::{Arm, ArmStatus, DriverError, JointLimit, Motion, Result};

/// How often a motion checks `/joint_states` for arrival.
const ARRIVAL_POLL: Duration = Duration::from_millis(10);

/// Shortest trajectory time sent, so a tiny move is not asked to happen instantly.
const MIN_MOVE_TIME: Duration = Duration::from_millis(200);

/// How long a stop takes: one point where the joints are, this far ahead.
const STOP_TIME: Duration = Duration::from_millis(100);

/// How old the joints a stop holds at may be. Older positions lag a moving arm, and holding
/// at them would move it back faster than any cap; with none this fresh, the stop is refused
/// (the arm must then be stopped at its controller).
const STOP_JOINTS_MAX_AGE: Duration = Duration::from_millis(100);

/// Widest single move of a continuous joint: the controller takes such joints the short way
/// round, so a longer move would not follow the straight line the checker validated.
const MAX_CONTINUOUS_MOVE_RAD: f64 = std::f64::consts::PI;

/// What the ROS 2 arm needs; the cell config's `[arm]` table fills it.
#[derive(Clone, Debug)]
pub struct Ros2ArmOptions {
    /// Domain, namespace and node name.
    pub place: GraphPlace,
    /// `sensor_msgs/JointState` topic (usually `/joint_states`).
    pub joint_states_topic: String,
    /// The controller's `trajectory_msgs/JointTrajectory` topic.
    pub command_topic: String,
    /// The actuated joints, named as the controller names them, with their limits.
    pub joints: Vec<JointLimit>,
    /// Per joint: true for a continuous (unlimited, wrapping) joint.
    pub continuous: Vec<bool>,
    /// `/joint_states` older than this stops the run.
    pub stale_after: Duration,
    /// The arm has arrived when every joint is within this of the target, rad.
    pub arrival_tolerance_rad: f64,
    /// Longest wait for the first complete `/joint_states`.
    pub connect_timeout: Duration,
    /// Extra time, beyond the trajectory's own, before a move counts as stalled.
    pub arrival_margin: Duration,
}

/// The ROS 2 arm.
pub struct Ros2Arm {
    options: Ros2ArmOptions,
    reader: Arc<JointStateReader>,
    command: Mutex<Publisher<JointTrajectory>>,
    moving: Arc<AtomicBool>,
    /// Until a complete `/joint_states` has been heard once, reads wait for one (discovery
    /// takes a moment); after that, a stale topic is an error at once.
    heard: AtomicBool,
    created: Instant,
    /// Kept alive for the reader and the publisher.
    _graph: Mutex<(Context, Node)>,
}

impl Ros2Arm {
    /// Joins the graph and subscribes. Nothing is awaited here: the first read waits up to
    /// `connect_timeout` for a complete `/joint_states`.
    pub fn new(options: Ros2ArmOptions) -> Result<Self> {
        let (context, mut node) = super::join(&options.place)?;
        let names: Vec<String> = options.joints.iter().map(|j| j.name.clone()).collect();
        let reader = JointStateReader::start(
            &mut node,
            &options.place.namespace,
            &options.joint_states_topic,
            names,
        )?;
        let command = command_publisher(&mut node, &options)?;
        Ok(Self {
            options,
            reader: Arc::new(reader),
            command: Mutex::new(command),
            moving: Arc::new(AtomicBool::new(false)),
            heard: AtomicBool::new(false),
            created: Instant::now(),
            _graph: Mutex::new((context, node)),
        })
    }

    /// Fresh joints; before the first complete message, waits for it until `connect_timeout`
    /// after creation.
    async fn fresh_joints(&self) -> Result<Vec<f64>> {
        loop {
            match self.reader.positions(self.options.stale_after) {
                Ok(q) => {
                    self.heard.store(true, Ordering::SeqCst);
                    return Ok(q);
                }
                Err(_)
                    if !self.heard.load(Ordering::SeqCst)
                        && self.created.elapsed() < self.options.connect_timeout =>
                {
                    tokio::time::sleep(ARRIVAL_POLL).await;
                }
                Err(e) if self.heard.load(Ordering::SeqCst) => return Err(e),
                Err(e) => {
                    return Err(DriverError::Connection(format!(
                        "no complete {} within {:.1} s of starting: {e}",
                        self.options.joint_states_topic,
                        self.options.connect_timeout.as_secs_f64()
                    )))
                }
            }
        }
    }

    fn send(&self, points: Vec<JointTrajectoryPoint>) -> Result<()> {
        let message = JointTrajectory {
            header: Header {
                stamp: Time { sec: 0, nanosec: 0 },
                frame_id: String::new(),
            },
            joint_names: self.options.joints.iter().map(|j| j.name.clone()).collect(),
            points,
        };
        let publisher = self.command.lock().unwrap_or_else(|p| p.into_inner());
        publisher.publish(message).map_err(|e| {
            DriverError::Connection(format!("publishing on {}: {e}", self.options.command_topic))
        })
    }
}

impl Ros2Arm {
    /// Refuses a move of more than [`MAX_CONTINUOUS_MOVE_RAD`] on a continuous joint.
    fn check_continuous(&self, from: &[f64], target: &[f64]) -> Result<()> {
        let joints = self.options.joints.iter().zip(&self.options.continuous);
        for ((j, continuous), (a, b)) in joints.zip(from.iter().zip(target)) {
            if *continuous && (b - a).abs() > MAX_CONTINUOUS_MOVE_RAD {
                return Err(DriverError::Refused(format!(
                    "continuous joint {:?} would turn {:.3} rad in one move; allowed: at most π (the controller would take the short way round)",
                    j.name,
                    b - a
                )));
            }
        }
        Ok(())
    }
}

fn command_publisher(node: &mut Node, o: &Ros2ArmOptions) -> Result<Publisher<JointTrajectory>> {
    let qos = QosProfile::publisher_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 1 });
    let topic = node
        .create_topic(
            &super::topic(&o.place.namespace, &o.command_topic)?,
            MessageTypeName::new("trajectory_msgs", "JointTrajectory"),
            &qos,
        )
        .map_err(|e| DriverError::Connection(format!("creating {}: {e}", o.command_topic)))?;
    node.create_publisher(&topic, None)
        .map_err(|e| DriverError::Connection(format!("publishing on {}: {e}", o.command_topic)))
}

/// Time for the fastest joint to cover its distance at `speed_rad_s`.
fn move_time(from: &[f64], to: &[f64], speed_rad_s: f64) -> Duration {
    let widest = from
        .iter()
        .zip(to)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    Duration::try_from_secs_f64(widest / speed_rad_s)
        .unwrap_or(Duration::MAX)
        .max(MIN_MOVE_TIME)
}

#[async_trait]
impl Arm for Ros2Arm {
    fn joints(&self) -> &[JointLimit] {
        &self.options.joints
    }

    async fn read_joints(&self) -> Result<Vec<f64>> {
        self.fresh_joints().await
    }

    async fn move_to(&self, target: &[f64], speed_rad_s: f64) -> Result<Motion> {
        let n = self.options.joints.len();
        if target.len() != n || target.iter().any(|v| !v.is_finite()) {
            return Err(DriverError::Refused(format!(
                "target has {} values; allowed: {n} finite positions",
                target.len()
            )));
        }
        if !(speed_rad_s.is_finite() && speed_rad_s > 0.0) {
            return Err(DriverError::Refused(format!(
                "speed {speed_rad_s} rad/s; allowed: a positive speed"
            )));
        }
        if self.moving.load(Ordering::SeqCst) {
            return Err(DriverError::Refused(
                "a move is still in progress: wait for it or stop the arm first".into(),
            ));
        }
        let from = self.read_joints().await?;
        self.check_continuous(&from, target)?;
        let time = move_time(&from, target, speed_rad_s);
        self.send(vec![JointTrajectoryPoint {
            positions: target.to_vec(),
            velocities: Vec::new(),
            accelerations: Vec::new(),
            effort: Vec::new(),
            time_from_start: time.into(),
        }])?;
        self.moving.store(true, Ordering::SeqCst);
        let (reader, moving, target) = (self.reader.clone(), self.moving.clone(), target.to_vec());
        let (stale, tol) = (self.options.stale_after, self.options.arrival_tolerance_rad);
        let limit = time.saturating_add(self.options.arrival_margin);
        let topic = self.options.command_topic.clone();
        Ok(Motion::new(async move {
            let start = Instant::now();
            let outcome = loop {
                tokio::time::sleep(ARRIVAL_POLL).await;
                let q = match reader.positions(stale) {
                    Ok(q) => q,
                    Err(e) => break Err(e),
                };
                if q.iter().zip(&target).all(|(a, b)| (a - b).abs() <= tol) {
                    break Ok(());
                }
                if start.elapsed() > limit {
                    break Err(DriverError::Stalled(format!(
                        "not at the target {:.1} s after a {:.1} s trajectory (is a controller listening on {topic}?)",
                        start.elapsed().as_secs_f64(),
                        time.as_secs_f64()
                    )));
                }
            };
            moving.store(false, Ordering::SeqCst);
            outcome
        }))
    }

    async fn stop(&self) -> Result<()> {
        let here = self.reader.positions(STOP_JOINTS_MAX_AGE).map_err(|e| {
            DriverError::Connection(format!(
                "cannot stop through {}: no position fresh enough to hold at ({e}); stop the arm at its controller",
                self.options.command_topic
            ))
        })?;
        self.send(vec![JointTrajectoryPoint {
            positions: here,
            velocities: Vec::new(),
            accelerations: Vec::new(),
            effort: Vec::new(),
            time_from_start: STOP_TIME.into(),
        }])?;
        self.moving.store(false, Ordering::SeqCst);
        Ok(())
    }

    async fn status(&self) -> Result<ArmStatus> {
        if let Err(e) = self.reader.positions(self.options.stale_after) {
            return Ok(ArmStatus::Fault(e.to_string()));
        }
        Ok(if self.moving.load(Ordering::SeqCst) {
            ArmStatus::Moving
        } else {
            ArmStatus::Idle
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fastest_joint_sets_the_move_time() {
        let t = move_time(&[0.0, 0.0], &[0.5, -1.0], 0.5);
        assert!((t.as_secs_f64() - 2.0).abs() < 1e-12);
        assert_eq!(move_time(&[0.0], &[0.001], 1.0), MIN_MOVE_TIME);
    }
}

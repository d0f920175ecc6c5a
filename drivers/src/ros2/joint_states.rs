//! `/joint_states` as the arm's encoders: a thread keeps, per joint name, the newest position
//! and when it arrived. Messages may carry any subset of the joints (an arm and its gripper
//! often publish separately), so positions are merged by name.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use ros2_client::qos::History;
use ros2_client::{MessageTypeName, Node, QosProfile, Subscription};

use super::msgs::JointState;
use crate::{DriverError, Result};

/// How often the thread drains the reader.
const POLL: Duration = Duration::from_millis(2);

type Positions = BTreeMap<String, (f64, Instant)>;

/// The newest position of each named joint, kept fresh by a background thread.
pub struct JointStateReader {
    names: Vec<String>,
    topic: String,
    latest: Arc<Mutex<Positions>>,
    stop: Arc<AtomicBool>,
}

impl JointStateReader {
    /// Subscribes to `topic` on `node` (best effort, which matches every writer) and starts
    /// the thread. `names` are the joints to report, in order.
    pub fn start(
        node: &mut Node,
        namespace: &str,
        topic: &str,
        names: Vec<String>,
    ) -> Result<Self> {
        let qos = QosProfile::subscription_default()
            .reliability_best_effort()
            .history(History::KeepLast { depth: 50 });
        let t = node
            .create_topic(
                &super::topic(namespace, topic)?,
                MessageTypeName::new("sensor_msgs", "JointState"),
                &qos,
            )
            .map_err(|e| DriverError::Connection(format!("creating {topic}: {e}")))?;
        let reader: Subscription<JointState> = node
            .create_subscription(&t, None)
            .map_err(|e| DriverError::Connection(format!("subscribing to {topic}: {e}")))?;
        let latest = Arc::new(Mutex::new(Positions::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let (l, s) = (latest.clone(), stop.clone());
        let wanted: BTreeSet<String> = names.iter().cloned().collect();
        std::thread::Builder::new()
            .name("easyhec-joint-states".into())
            .spawn(move || follow(reader, wanted, l, s))
            .map_err(|e| DriverError::Connection(format!("starting the {topic} thread: {e}")))?;
        Ok(Self {
            names,
            topic: topic.to_string(),
            latest,
            stop,
        })
    }

    /// The joints, in order, when every one was heard within `max_age`; otherwise an error
    /// naming the joint and how stale it is.
    pub fn positions(&self, max_age: Duration) -> Result<Vec<f64>> {
        let latest = self.latest.lock().unwrap_or_else(|p| p.into_inner());
        let now = Instant::now();
        self.names
            .iter()
            .map(|n| match latest.get(n) {
                None => Err(DriverError::Connection(format!(
                    "no position for joint {n:?} on {} yet",
                    self.topic
                ))),
                Some((_, at)) if now.duration_since(*at) > max_age => {
                    Err(DriverError::Connection(format!(
                        "{} went stale: joint {n:?} last heard {:.2} s ago (limit {:.2} s)",
                        self.topic,
                        now.duration_since(*at).as_secs_f64(),
                        max_age.as_secs_f64()
                    )))
                }
                Some((p, _)) => Ok(*p),
            })
            .collect()
    }
}

impl Drop for JointStateReader {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

/// Drains the reader until stopped, keeping only the wanted joints (so another node's joints
/// cannot grow the map).
fn follow(
    reader: Subscription<JointState>,
    wanted: BTreeSet<String>,
    latest: Arc<Mutex<Positions>>,
    stop: Arc<AtomicBool>,
) {
    while !stop.load(Ordering::Relaxed) {
        while let Ok(Some((m, _))) = reader.take() {
            let now = Instant::now();
            let mut l = latest.lock().unwrap_or_else(|p| p.into_inner());
            for (name, p) in m.name.iter().zip(&m.position) {
                if p.is_finite() && wanted.contains(name) {
                    l.insert(name.clone(), (*p, now));
                }
            }
        }
        std::thread::sleep(POLL);
    }
}

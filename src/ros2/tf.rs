//! tf over ROS 2: the static broadcaster (`/tf_static`, reliable, transient local, depth 1, as
//! tf2_ros's `StaticTransformBroadcaster` makes it, so a node that starts later still gets the
//! edge) and a listener that gathers what other nodes publish on `/tf` and `/tf_static`.

use std::time::{Duration, Instant};

use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{Gid, MessageTypeName, Name, Node, Publisher, QosProfile, Subscription};

use crate::error::{Error, Result};
use crate::interop::tf_tree::{TfSource, TfTree};
use crate::interop::TfEdge;

use super::msgs::{Header, Quaternion, TfMessage, Time, Transform, TransformStamped, Vector3};

/// How long the listener sleeps between polls of its readers.
const POLL: Duration = Duration::from_millis(20);

/// Samples the listener's `/tf_static` reader keeps: every static broadcaster's latched
/// message arrives as one sample of the same (keyless) instance.
const STATIC_READER_DEPTH: usize = 1000;

fn tf_type() -> MessageTypeName {
    MessageTypeName::new("tf2_msgs", "TFMessage")
}

fn static_qos() -> QosProfile {
    QosProfile::publisher_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .durability(Durability::TransientLocal)
        .history(History::KeepLast { depth: 1 })
}

fn topic_name(namespace: &str, base: &str) -> Result<Name> {
    Name::new(namespace, base)
        .map_err(|e| Error::Usage(format!("ROS 2 topic {namespace}/{base}: {e}")))
}

fn ros_error(what: &str) -> impl Fn(ros2_client::CreateError) -> Error + '_ {
    move |e| Error::Ros2(format!("{what}: {e}"))
}

/// The message form of an edge, stamped now.
pub fn stamped(edge: &TfEdge) -> TransformStamped {
    let t = edge.translation();
    let q = edge.quaternion_xyzw();
    TransformStamped {
        header: Header {
            stamp: Time::now(),
            frame_id: edge.parent.clone(),
        },
        child_frame_id: edge.child.clone(),
        transform: Transform {
            translation: Vector3 {
                x: t[0],
                y: t[1],
                z: t[2],
            },
            rotation: Quaternion {
                x: q[0],
                y: q[1],
                z: q[2],
                w: q[3],
            },
        },
    }
}

/// The edge a message carries, or `None` when its numbers are not a rigid transform (another
/// node's bad data is left out of the tree, not trusted).
pub fn edge_of(m: &TransformStamped) -> Option<TfEdge> {
    let (t, r) = (&m.transform.translation, &m.transform.rotation);
    let q = nalgebra::Quaternion::new(r.w, r.x, r.y, r.z);
    let finite = [t.x, t.y, t.z, r.x, r.y, r.z, r.w]
        .iter()
        .all(|v| v.is_finite());
    if !finite || (q.norm() - 1.0).abs() > 1e-2 {
        return None;
    }
    Some(TfEdge {
        parent: m.header.frame_id.trim_start_matches('/').to_string(),
        child: m.child_frame_id.trim_start_matches('/').to_string(),
        parent_from_child: Isometry3::from_parts(
            Translation3::new(t.x, t.y, t.z),
            UnitQuaternion::from_quaternion(q),
        ),
    })
}

/// Publishes a fixed set of edges on `/tf_static` (in the node's namespace).
pub struct StaticTfPublisher {
    publisher: Publisher<TfMessage>,
}

impl StaticTfPublisher {
    /// A latched `/tf_static` writer on `node`.
    pub fn new(node: &mut Node, namespace: &str) -> Result<Self> {
        let topic = node
            .create_topic(
                &topic_name(namespace, "tf_static")?,
                tf_type(),
                &static_qos(),
            )
            .map_err(ros_error("creating /tf_static"))?;
        let publisher = node
            .create_publisher(&topic, None)
            .map_err(ros_error("creating the /tf_static writer"))?;
        Ok(Self { publisher })
    }

    /// The writer's id, so that a listener on the same node can leave its own edges out.
    pub fn gid(&self) -> Gid {
        self.publisher.gid()
    }

    /// Replaces what this writer latches with `edges` (a late joiner gets only the last set,
    /// so every call sends all of them).
    pub fn send(&self, edges: &[TfEdge]) -> Result<()> {
        let message = TfMessage {
            transforms: edges.iter().map(stamped).collect(),
        };
        self.publisher
            .publish(message)
            .map_err(|e| Error::Ros2(format!("publishing on /tf_static: {e}")))
    }
}

/// Reads `/tf` (best effort, which matches any writer) and `/tf_static` (reliable, transient
/// local, so latched edges published before easyhec started arrive too).
pub struct TfListener {
    dynamic: Subscription<TfMessage>,
    fixed: Subscription<TfMessage>,
    /// Everything heard so far: a latched edge arrives once, when the readers match its
    /// writer, so a later window must still know it.
    seen: TfTree,
}

impl TfListener {
    /// Both readers, on `node`.
    pub fn new(node: &mut Node, namespace: &str) -> Result<Self> {
        let dynamic_qos = QosProfile::subscription_default()
            .reliability_best_effort()
            .history(History::KeepLast { depth: 100 });
        let dynamic_topic = node
            .create_topic(&topic_name(namespace, "tf")?, tf_type(), &dynamic_qos)
            .map_err(ros_error("creating /tf"))?;
        let dynamic = node
            .create_subscription(&dynamic_topic, None)
            .map_err(ros_error("creating the /tf reader"))?;
        let fixed_qos = static_qos().history(History::KeepLast {
            depth: STATIC_READER_DEPTH,
        });
        let fixed_topic = node
            .create_topic(&topic_name(namespace, "tf_static")?, tf_type(), &fixed_qos)
            .map_err(ros_error("creating /tf_static"))?;
        let fixed = node
            .create_subscription(&fixed_topic, Some(fixed_qos))
            .map_err(ros_error("creating the /tf_static reader"))?;
        Ok(Self {
            dynamic,
            fixed,
            seen: TfTree::default(),
        })
    }

    /// Listens for `window` more (discovery of the other nodes takes part of it) and returns
    /// every edge heard since the listener was made, leaving out those written by `own`
    /// (easyhec's own broadcaster).
    pub fn gather(&mut self, window: Duration, own: Option<Gid>) -> Result<TfTree> {
        let deadline = Instant::now() + window;
        loop {
            drain(&self.fixed, TfSource::Static, own, &mut self.seen)?;
            drain(&self.dynamic, TfSource::Dynamic, own, &mut self.seen)?;
            if Instant::now() >= deadline {
                return Ok(self.seen.clone());
            }
            std::thread::sleep(POLL);
        }
    }
}

fn drain(
    reader: &Subscription<TfMessage>,
    source: TfSource,
    own: Option<Gid>,
    tree: &mut TfTree,
) -> Result<()> {
    while let Some((message, info)) = reader
        .take()
        .map_err(|e| Error::Ros2(format!("reading {}: {e}", source.topic())))?
    {
        if Some(info.publisher_gid()) == own {
            continue;
        }
        for edge in message.transforms.iter().filter_map(edge_of) {
            tree.insert(edge, source);
        }
    }
    Ok(())
}

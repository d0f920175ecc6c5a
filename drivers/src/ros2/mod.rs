//! ROS 2 in pure Rust (ros2-client on RustDDS; no ROS installation): the message structs and
//! the ROS 2 arm, which reads `/joint_states` and moves through ros2_control's
//! joint_trajectory_controller.

pub mod arm;
pub mod camera;
pub mod joint_states;
pub mod msgs;

use ros2_client::{Context, ContextOptions, Node, NodeName, NodeOptions};

use crate::{DriverError, Result};

/// Where in a ROS 2 graph a node appears. The caller checks the values (domain 0 to 232, a
/// valid namespace); this module only reports what ros2-client refuses.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GraphPlace {
    /// `ROS_DOMAIN_ID`.
    pub domain_id: u16,
    /// Node namespace (`/` or `/name`); relative topic names resolve inside it.
    pub namespace: String,
    /// Node name.
    pub node_name: String,
}

/// Joins the graph: one DDS participant in the domain, one node.
pub fn join(place: &GraphPlace) -> Result<(Context, Node)> {
    let context = Context::with_options(ContextOptions::new().domain_id(place.domain_id))
        .map_err(|e| DriverError::Connection(format!("starting a DDS participant: {e}")))?;
    let name = NodeName::new(&place.namespace, &place.node_name)
        .map_err(|e| DriverError::Refused(format!("ROS 2 node name {:?}: {e}", place.node_name)))?;
    let node = context.new_node(name, NodeOptions::new()).map_err(|e| {
        DriverError::Connection(format!("creating node {:?}: {e}", place.node_name))
    })?;
    Ok((context, node))
}

/// A topic name (`/joint_states`, or relative to the node's namespace).
pub fn topic(namespace: &str, name: &str) -> Result<ros2_client::Name> {
    let (ns, base) = match name.rsplit_once('/') {
        Some(("", base)) => ("/".to_string(), base),
        Some((ns, base)) if name.starts_with('/') => (ns.to_string(), base),
        Some((rel, base)) => (format!("{}/{rel}", namespace.trim_end_matches('/')), base),
        None => (namespace.to_string(), name),
    };
    ros2_client::Name::new(&ns, base)
        .map_err(|e| DriverError::Refused(format!("ROS 2 topic {name:?}: {e}")))
}

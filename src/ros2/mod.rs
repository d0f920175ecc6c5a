//! ROS 2 in pure Rust (ros2-client on RustDDS; no ROS installation): easyhec joins a ROS 2
//! graph as one node, publishes its calibration on `/tf_static` and reads other nodes' tf.
//!
//! - [`msgs`]: the message structs, laid out as their `.msg` files;
//! - [`tf`]: the static broadcaster and the tf listener.

pub mod msgs;
pub mod tf;

use ros2_client::{Context, ContextOptions, Node, NodeName, NodeOptions};

use crate::error::{Error, Result};

pub use crate::config::ros2::{check_namespace, MAX_DOMAIN_ID};

/// Where in the ROS 2 graph easyhec appears.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GraphPlace {
    /// `ROS_DOMAIN_ID`.
    pub domain_id: u16,
    /// Node namespace (`/` or `/name`); relative topic names resolve inside it.
    pub namespace: String,
    /// Node name.
    pub node_name: String,
}

/// The domain id from `ROS_DOMAIN_ID`, as ROS 2 tools read it (unset or empty: 0).
pub fn domain_id_from_env() -> Result<u16> {
    match std::env::var("ROS_DOMAIN_ID") {
        Ok(v) if !v.trim().is_empty() => v
            .trim()
            .parse::<u16>()
            .ok()
            .filter(|d| *d <= MAX_DOMAIN_ID)
            .ok_or_else(|| {
                Error::Usage(format!(
                    "ROS_DOMAIN_ID is {v:?}; allowed: 0 to {MAX_DOMAIN_ID}"
                ))
            }),
        _ => Ok(0),
    }
}

/// Joins the graph: one DDS participant in the domain, one node.
pub fn join(place: &GraphPlace) -> Result<(Context, Node)> {
    if place.domain_id > MAX_DOMAIN_ID {
        return Err(Error::Usage(format!(
            "ROS 2 domain id is {}; allowed: 0 to {MAX_DOMAIN_ID}",
            place.domain_id
        )));
    }
    check_namespace(&place.namespace)
        .map_err(|m| Error::Usage(format!("ROS 2 namespace is {m}")))?;
    let context = Context::with_options(ContextOptions::new().domain_id(place.domain_id))
        .map_err(|e| Error::Ros2(format!("starting a DDS participant: {e}")))?;
    let name = NodeName::new(&place.namespace, &place.node_name)
        .map_err(|e| Error::Usage(format!("ROS 2 node name {:?}: {e}", place.node_name)))?;
    let node = context
        .new_node(name, NodeOptions::new())
        .map_err(|e| Error::Ros2(format!("creating node {:?}: {e}", place.node_name)))?;
    Ok((context, node))
}

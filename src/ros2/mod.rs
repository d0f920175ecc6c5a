//! ROS 2 in pure Rust (ros2-client on RustDDS; no ROS installation): easyhec joins a ROS 2
//! graph as one node, publishes its calibration on `/tf_static` and reads other nodes' tf.
//!
//! - [`msgs`]: the message structs, laid out as their `.msg` files (in the drivers crate,
//!   which the ROS 2 arm shares them with);
//! - [`tf`]: the static broadcaster and the tf listener;
//! - [`camera_out`]: frames published as a ROS 2 camera driver does (`easyhec sim-camera`).

pub mod camera_out;
pub mod tf;

pub use easyhec_drivers::ros2::{msgs, GraphPlace};
use ros2_client::{Context, Node};

use crate::error::{Error, Result};

pub use crate::config::ros2::{check_namespace, domain_id_from_env, MAX_DOMAIN_ID};

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
    easyhec_drivers::ros2::join(place).map_err(|e| Error::Ros2(e.to_string()))
}

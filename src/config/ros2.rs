//! `[ros2]` in a cell config: where easyhec joins a ROS 2 graph and which tf edge the daemon
//! publishes for the active calibration. Also the checks on ROS names (tf frames,
//! namespaces) that every ROS-facing form shares: names that need no quoting in YAML, XML,
//! Python or a shell, so nothing easyhec writes can be made to say something else.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// Longest frame name accepted.
pub const MAX_FRAME_NAME_LEN: usize = 256;

/// Highest DDS domain id ROS 2 uses on Linux (its port arithmetic allows 0 to 232).
pub const MAX_DOMAIN_ID: u16 = 232;

/// Longest wait, seconds, for other nodes' tf before publishing.
pub const MAX_LISTEN_S: f64 = 60.0;

/// Checks a tf frame name: ASCII letters, digits, `_` and inner single `/` (prefixes), not
/// starting with a digit, at most [`MAX_FRAME_NAME_LEN`] long. tf2 in ROS 2 refuses a leading
/// `/`, and a name that differs from another only by slashes would dodge the parent check.
pub fn check_frame_name(name: &str) -> std::result::Result<(), String> {
    let ok_char = |c: char| c.is_ascii_alphanumeric() || c == '_' || c == '/';
    let starts_ok = name
        .chars()
        .next()
        .is_some_and(|c| !c.is_ascii_digit() && c != '/');
    if !name.is_empty()
        && name.len() <= MAX_FRAME_NAME_LEN
        && starts_ok
        && !name.ends_with('/')
        && !name.contains("//")
        && name.chars().all(ok_char)
    {
        return Ok(());
    }
    Err(format!(
        "{name:?}; allowed: 1 to {MAX_FRAME_NAME_LEN} ASCII letters, digits, '_' or single inner '/', not starting with a digit"
    ))
}

/// Checks a ROS namespace: `/`, or `/` followed by `/`-separated names of ASCII letters,
/// digits and `_`, each starting with a letter or `_`.
pub fn check_namespace(ns: &str) -> std::result::Result<(), String> {
    let name_ok = |n: &str| {
        n.chars()
            .next()
            .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
            && n.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
            && !n.contains("__")
    };
    let ok =
        ns == "/" || (ns.len() <= 256 && ns.starts_with('/') && ns[1..].split('/').all(name_ok));
    if ok {
        return Ok(());
    }
    Err(format!(
        "{ns:?}; allowed: \"/\" or \"/a/b\" with names of ASCII letters, digits and '_' (no \"__\"), not starting with a digit"
    ))
}

/// Checks a topic name: a namespace-like path (`/joint_states`, `arm/joint_states`), absolute
/// or relative to the node's namespace.
pub fn check_topic(topic: &str) -> std::result::Result<(), String> {
    let absolute = if topic.starts_with('/') {
        topic.to_string()
    } else {
        format!("/{topic}")
    };
    if absolute != "/" && check_namespace(&absolute).is_ok() {
        return Ok(());
    }
    Err(format!(
        "{topic:?}; allowed: a ROS topic name such as \"/joint_states\" (names of ASCII letters, digits and '_' separated by '/', not starting with a digit)"
    ))
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

/// `[ros2]`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Ros2Settings {
    /// DDS domain; absent: `ROS_DOMAIN_ID`, else 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub domain_id: Option<u16>,
    /// Node namespace; tf topics resolve inside it (default `/`: `/tf_static`).
    #[serde(default = "root_namespace")]
    pub namespace: String,
    /// The daemon publishes the active calibration on `/tf_static` (default true).
    #[serde(default = "yes")]
    pub publish_tf: bool,
    /// Parent frame of the published edge; absent: the result's `base_link` (the robot's base
    /// link, or the mount link of a camera on a link).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame_id: Option<String>,
    /// Child frame: the optical frame, or the camera's root link with `optical_from_child`.
    #[serde(default = "default_child_frame")]
    pub child_frame_id: String,
    /// The camera driver's fixed `optical_from_child`, `[x, y, z, qx, qy, qz, qw]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub optical_from_child: Option<[f64; 7]>,
    /// Seconds to listen to `/tf` and `/tf_static` before each publication, to refuse a child
    /// frame that already has a parent (default 3).
    #[serde(default = "default_listen_s")]
    pub listen_s: f64,
}

fn root_namespace() -> String {
    "/".into()
}

fn yes() -> bool {
    true
}

fn default_child_frame() -> String {
    DEFAULT_CHILD_FRAME.into()
}

fn default_listen_s() -> f64 {
    3.0
}

/// The frame easyhec names the optical frame when the user names none: one no camera driver
/// publishes, so the tree stays a tree until the user attaches a real camera link.
pub const DEFAULT_CHILD_FRAME: &str = "easyhec_camera_optical_frame";

impl Ros2Settings {
    /// The domain: `domain_id`, else `ROS_DOMAIN_ID`, else 0.
    pub fn domain(settings: Option<&Self>) -> Result<u16> {
        match settings.and_then(|s| s.domain_id) {
            Some(d) => Ok(d),
            None => domain_id_from_env(),
        }
    }

    /// The namespace: `namespace`, else `/`.
    pub fn namespace_of(settings: Option<&Self>) -> String {
        settings.map_or_else(root_namespace, |s| s.namespace.clone())
    }

    /// Checks every key, naming it.
    pub fn validate(&self, path: &Path) -> Result<()> {
        let bad = |k: &str, m: String| Err(Error::input(path, format!("ros2.{k}"), m));
        if let Some(d) = self.domain_id {
            if d > MAX_DOMAIN_ID {
                return bad(
                    "domain_id",
                    format!("is {d}; allowed: 0 to {MAX_DOMAIN_ID}"),
                );
            }
        }
        if let Err(m) = check_namespace(&self.namespace) {
            return bad("namespace", format!("is {m}"));
        }
        if let Some(f) = &self.frame_id {
            if let Err(m) = check_frame_name(f) {
                return bad("frame_id", format!("is {m}"));
            }
        }
        if let Err(m) = check_frame_name(&self.child_frame_id) {
            return bad("child_frame_id", format!("is {m}"));
        }
        if self.frame_id.as_deref() == Some(self.child_frame_id.as_str()) {
            return bad(
                "child_frame_id",
                "is the same as frame_id; allowed: a different frame".into(),
            );
        }
        if let Some(v) = &self.optical_from_child {
            let norm = v[3..].iter().map(|x| x * x).sum::<f64>().sqrt();
            let far = crate::geometry::translation_problem(&[v[0], v[1], v[2]]).is_some();
            if v.iter().any(|x| !x.is_finite()) || far || (norm - 1.0).abs() > 1e-2 {
                return bad(
                    "optical_from_child",
                    format!("is {v:?}; allowed: 7 finite numbers [x, y, z, qx, qy, qz, qw], x, y and z within {} m, with a unit quaternion", crate::geometry::MAX_TRANSLATION_M),
                );
            }
        }
        if !(self.listen_s.is_finite() && (0.0..=MAX_LISTEN_S).contains(&self.listen_s)) {
            return bad(
                "listen_s",
                format!("is {}; allowed: 0 to {MAX_LISTEN_S} seconds", self.listen_s),
            );
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_names_are_checked() {
        for ok in ["camera_link", "robot1/camera_link", "_x"] {
            assert!(check_frame_name(ok).is_ok(), "{ok}");
        }
        for bad in [
            "",
            "/camera_link",
            "camera_link/",
            "a//b",
            "9cam",
            "cam:x",
            "a b",
        ] {
            assert!(check_frame_name(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn namespaces_are_checked() {
        for ok in ["/", "/cell_1", "/lab/cell_1"] {
            assert!(check_namespace(ok).is_ok(), "{ok}");
        }
        for bad in ["", "cell", "/cell/", "/1cell", "/a b", "//", "/a__b"] {
            assert!(check_namespace(bad).is_err(), "{bad}");
        }
        for ok in ["/joint_states", "arm/joint_states", "/a/b_2"] {
            assert!(check_topic(ok).is_ok(), "{ok}");
        }
        for bad in ["", "/", "/joint states", "/a//b", "/2x", "a/"] {
            assert!(check_topic(bad).is_err(), "{bad}");
        }
    }
}

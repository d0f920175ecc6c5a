//! `[robot]`: which robot description to load, as a run's `robot` entry does.

use std::collections::BTreeMap;
use std::path::PathBuf;

use serde::{Deserialize, Serialize};

/// `[robot]`, as in a run's `robot` entry.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RobotConfig {
    /// URDF file.
    pub urdf: PathBuf,
    /// `package://NAME` roots.
    #[serde(default)]
    pub package_dirs: BTreeMap<String, PathBuf>,
    /// Frame `camera_from_base` refers to.
    #[serde(default)]
    pub base_link: Option<String>,
    /// Links not rendered (and not expected in masks).
    #[serde(default)]
    pub ignore_links: Vec<String>,
    /// Actuated joints in the arm's order; default every movable joint in URDF order.
    #[serde(default)]
    pub joints: Option<Vec<String>>,
    /// Arguments of a `.xacro` description, passed to the xacro tool as `name:=value`.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub xacro_args: BTreeMap<String, String>,
}

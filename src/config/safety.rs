//! `[safety]`: the envelope every commanded pose must stay inside (speed cap, joint ranges,
//! clearances, obstacles).

use std::collections::BTreeMap;
use std::path::PathBuf;

use serde::{Deserialize, Serialize};

/// `[safety]` in a cell config.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SafetyConfig {
    /// Highest commanded speed of the fastest joint, rad/s.
    #[serde(default = "default_speed_cap")]
    pub speed_cap_rad_s: f64,
    /// Per-joint sub-ranges `[lower, upper]` (radians) the calibration may use.
    #[serde(default, deserialize_with = "exact_pairs")]
    pub joint_ranges: BTreeMap<String, [f64; 2]>,
    /// Clearance kept between links and to obstacles, metres.
    #[serde(default = "default_margin")]
    pub margin_m: f64,
    /// Link pairs never checked against each other (besides adjacent ones).
    #[serde(default)]
    pub allowed_collisions: Vec<[String; 2]>,
    /// MoveIt SRDF whose `disable_collisions` entries are honoured (relative to the config).
    #[serde(default)]
    pub srdf: Option<PathBuf>,
    /// Every collision piece's centre must stay within this ball.
    #[serde(default)]
    pub workspace: Option<WorkspaceConfig>,
    /// Environment obstacles and keep-out zones, in the base frame.
    #[serde(default)]
    pub obstacles: Vec<ObstacleConfig>,
    /// Bodies rigidly fixed to a link that the URDF lacks (a wrist camera, a gripper), each
    /// checked as part of its link.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub attached: Vec<AttachedConfig>,
    /// Least fraction of the robot that must project inside the image under the current
    /// estimate for a pose to be worth visiting.
    #[serde(default = "default_min_in_image")]
    pub min_in_image: f64,
}

/// `joint_ranges` with exactly two values per joint: a plain `[f64; 2]` would take the first two
/// of `[a, b, c]` and drop the rest without a word.
fn exact_pairs<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> Result<BTreeMap<String, [f64; 2]>, D::Error> {
    let raw = BTreeMap::<String, Vec<f64>>::deserialize(d)?;
    raw.into_iter()
        .map(|(name, v)| match v[..] {
            [lo, hi] => Ok((name, [lo, hi])),
            _ => Err(serde::de::Error::custom(format!(
                "joint_ranges.{name} has {} values; allowed: [lower, upper]",
                v.len()
            ))),
        })
        .collect()
}

fn default_speed_cap() -> f64 {
    0.5
}
fn default_margin() -> f64 {
    0.01
}
fn default_min_in_image() -> f64 {
    0.9
}

impl Default for SafetyConfig {
    fn default() -> Self {
        SafetyConfig {
            speed_cap_rad_s: default_speed_cap(),
            joint_ranges: BTreeMap::new(),
            margin_m: default_margin(),
            allowed_collisions: Vec::new(),
            srdf: None,
            workspace: None,
            obstacles: Vec::new(),
            attached: Vec::new(),
            min_in_image: default_min_in_image(),
        }
    }
}

/// `[safety.workspace]`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct WorkspaceConfig {
    /// Centre, base frame, metres.
    pub centre: [f64; 3],
    /// Radius, metres.
    pub radius_m: f64,
}

/// One `[[safety.obstacles]]` entry; all poses in the base frame, metres.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum ObstacleConfig {
    /// Everything on the side of the plane opposite `normal` (`n·p < offset_m`), e.g. a table
    /// top with `normal = [0, 0, 1]`.
    Plane {
        /// Label in messages.
        #[serde(default)]
        name: String,
        /// Normal pointing into free space.
        normal: [f64; 3],
        /// Plane offset along the normal.
        offset_m: f64,
    },
    /// A box.
    Box {
        /// Label in messages.
        #[serde(default)]
        name: String,
        /// Centre.
        centre: [f64; 3],
        /// Edge lengths.
        size: [f64; 3],
        /// Orientation (roll, pitch, yaw), degrees.
        #[serde(default)]
        rpy_deg: [f64; 3],
    },
    /// A sphere.
    Sphere {
        /// Label in messages.
        #[serde(default)]
        name: String,
        /// Centre.
        centre: [f64; 3],
        /// Radius.
        radius_m: f64,
    },
    /// A mesh (its convex hull), e.g. a fixture.
    Mesh {
        /// Label in messages.
        #[serde(default)]
        name: String,
        /// STL/DAE/OBJ file, relative to the config.
        file: PathBuf,
        /// Position.
        #[serde(default)]
        xyz: [f64; 3],
        /// Orientation (roll, pitch, yaw), degrees.
        #[serde(default)]
        rpy_deg: [f64; 3],
        /// Per-axis scale (e.g. 0.001 for millimetre meshes).
        #[serde(default = "unit_scale")]
        scale: [f64; 3],
    },
    /// An axis-aligned region no link may enter (a person's side of the cell, a conveyor).
    KeepOut {
        /// Label in messages.
        #[serde(default)]
        name: String,
        /// Lowest corner.
        min: [f64; 3],
        /// Highest corner.
        max: [f64; 3],
    },
}

/// One `[[safety.attached]]` entry: a body the URDF lacks, rigidly fixed to `link` (a wrist
/// camera's housing, a gripper, a cable loom), posed in that link's frame, metres.
///
/// Why: a wrist camera sticks out of the flange; when the arm turns to look back at itself
/// the housing is what comes closest to the table and the arm's own links, so a check that
/// knows only the URDF's links would let it hit them.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum AttachedConfig {
    /// A box.
    Box {
        /// Label in messages.
        name: String,
        /// The link it is fixed to.
        link: String,
        /// Edge lengths.
        size: [f64; 3],
        /// Centre, link frame.
        #[serde(default)]
        xyz: [f64; 3],
        /// Orientation (roll, pitch, yaw), degrees.
        #[serde(default)]
        rpy_deg: [f64; 3],
    },
    /// A sphere.
    Sphere {
        /// Label in messages.
        name: String,
        /// The link it is fixed to.
        link: String,
        /// Radius.
        radius_m: f64,
        /// Centre, link frame.
        #[serde(default)]
        xyz: [f64; 3],
    },
    /// A mesh (its convex hull), e.g. the camera maker's housing model.
    Mesh {
        /// Label in messages.
        name: String,
        /// The link it is fixed to.
        link: String,
        /// STL/DAE/OBJ file, relative to the config.
        file: PathBuf,
        /// Position, link frame.
        #[serde(default)]
        xyz: [f64; 3],
        /// Orientation (roll, pitch, yaw), degrees.
        #[serde(default)]
        rpy_deg: [f64; 3],
        /// Per-axis scale (e.g. 0.001 for millimetre meshes).
        #[serde(default = "unit_scale")]
        scale: [f64; 3],
    },
}

impl AttachedConfig {
    /// The body's label.
    pub fn name(&self) -> &str {
        match self {
            AttachedConfig::Box { name, .. }
            | AttachedConfig::Sphere { name, .. }
            | AttachedConfig::Mesh { name, .. } => name,
        }
    }

    /// The link it is fixed to.
    pub fn link(&self) -> &str {
        match self {
            AttachedConfig::Box { link, .. }
            | AttachedConfig::Sphere { link, .. }
            | AttachedConfig::Mesh { link, .. } => link,
        }
    }

    /// Where the body sits in its link's frame, metres.
    pub fn xyz(&self) -> [f64; 3] {
        match self {
            AttachedConfig::Box { xyz, .. }
            | AttachedConfig::Sphere { xyz, .. }
            | AttachedConfig::Mesh { xyz, .. } => *xyz,
        }
    }
}

fn unit_scale() -> [f64; 3] {
    [1.0; 3]
}

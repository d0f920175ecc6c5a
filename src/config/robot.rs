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
    /// Folders searched for ROS packages (`$(find NAME)`, `package://NAME`), relative to the
    /// config file: a description repository cloned anywhere, without a ROS installation.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub package_paths: Vec<PathBuf>,
    /// Frame `camera_from_base` refers to.
    #[serde(default)]
    pub base_link: Option<String>,
    /// Links not rendered (and not expected in masks).
    #[serde(default, deserialize_with = "link_names")]
    pub ignore_links: Vec<String>,
    /// Actuated joints in the arm's order; default every movable joint in URDF order.
    #[serde(default)]
    pub joints: Option<Vec<String>>,
    /// Arguments of a `.xacro` description, passed to the xacro tool as `name:=value`.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub xacro_args: BTreeMap<String, String>,
}

/// Most entries of `ignore_links`: more than any robot has links.
pub const MAX_IGNORE_LINKS: usize = 1024;

/// `ignore_links` read entry by entry: each name once, at most [`MAX_IGNORE_LINKS`], so a
/// list of millions of repeated names is refused as it is read instead of being held and
/// searched link by link.
pub fn link_names<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<String>, D::Error> {
    struct Names;
    impl<'de> serde::de::Visitor<'de> for Names {
        type Value = Vec<String>;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            write!(
                f,
                "a list of at most {MAX_IGNORE_LINKS} distinct link names"
            )
        }
        fn visit_seq<A: serde::de::SeqAccess<'de>>(
            self,
            mut seq: A,
        ) -> Result<Vec<String>, A::Error> {
            use serde::de::Error;
            let mut names: Vec<String> = Vec::new();
            while let Some(name) = seq.next_element::<String>()? {
                if names.len() == MAX_IGNORE_LINKS {
                    return Err(A::Error::custom(format!(
                        "has more than {MAX_IGNORE_LINKS} entries; allowed: each link at most once"
                    )));
                }
                if names.contains(&name) {
                    return Err(A::Error::custom(format!(
                        "names '{}' twice; allowed: each link once",
                        crate::error::cut(&name)
                    )));
                }
                names.push(name);
            }
            Ok(names)
        }
    }
    d.deserialize_seq(Names)
}

//! Where a camera is fixed: the key `mount` of a `[camera]` table and of a run's `camera`.
//!
//! `mount = "fixed"` (the default) is a camera on a tripod or the cell frame: the unknown is
//! `camera_from_base`. `mount = { link = "link6" }` is a camera on a moving link (eye-in-hand
//! on the flange): the unknown is `camera_from_link6`, and each view's camera pose follows
//! the forward kinematics.

use std::fmt;

use serde::de::{self, MapAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// A camera's mount.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum Mount {
    /// Fixed in the cell: `camera_from_base` is solved.
    #[default]
    Fixed,
    /// On a link of the robot: `camera_from_<link>` is solved.
    Link(String),
}

impl Mount {
    /// Whether this is the default fixed mount (left out when a run is written).
    pub fn is_fixed(&self) -> bool {
        *self == Mount::Fixed
    }

    /// The link a camera on the robot is fixed to.
    pub fn link(&self) -> Option<&str> {
        match self {
            Mount::Fixed => None,
            Mount::Link(l) => Some(l),
        }
    }

    /// The name of the solved transform: `camera_from_base`, or `camera_from_<link>`.
    pub fn transform_name(&self) -> String {
        match self {
            Mount::Fixed => "camera_from_base".into(),
            Mount::Link(l) => format!("camera_from_{l}"),
        }
    }
}

const EXPECTED: &str = "\"fixed\" or { link = \"<link name>\" }";

impl Serialize for Mount {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        match self {
            Mount::Fixed => s.serialize_str("fixed"),
            Mount::Link(l) => {
                let mut m = s.serialize_map(Some(1))?;
                m.serialize_entry("link", l)?;
                m.end()
            }
        }
    }
}

impl<'de> Deserialize<'de> for Mount {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(MountVisitor)
    }
}

struct MountVisitor;

impl<'de> Visitor<'de> for MountVisitor {
    type Value = Mount;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str(EXPECTED)
    }

    fn visit_str<E: de::Error>(self, v: &str) -> Result<Mount, E> {
        match v {
            "fixed" => Ok(Mount::Fixed),
            other => Err(E::custom(format!("mount '{other}': use {EXPECTED}"))),
        }
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Mount, A::Error> {
        let mut link: Option<String> = None;
        while let Some(key) = map.next_key::<String>()? {
            if key != "link" || link.is_some() {
                return Err(de::Error::custom(format!(
                    "mount key '{key}': use {EXPECTED}"
                )));
            }
            link = Some(map.next_value()?);
        }
        match link {
            Some(l) if !l.trim().is_empty() && l.len() <= 256 => Ok(Mount::Link(l)),
            _ => Err(de::Error::custom(format!(
                "mount needs a link name of 1 to 256 characters: use {EXPECTED}"
            ))),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Deserialize, Serialize)]
    struct T {
        #[serde(default)]
        mount: Mount,
    }

    #[test]
    fn both_spellings_parse_and_round_trip() {
        let fixed: T = toml::from_str("mount = \"fixed\"").unwrap();
        assert_eq!(fixed.mount, Mount::Fixed);
        let absent: T = toml::from_str("").unwrap();
        assert_eq!(absent.mount, Mount::Fixed);
        let link: T = toml::from_str("mount = { link = \"link6\" }").unwrap();
        assert_eq!(link.mount, Mount::Link("link6".into()));
        assert_eq!(link.mount.transform_name(), "camera_from_link6");
        let json = serde_json::to_string(&link).unwrap();
        assert_eq!(json, r#"{"mount":{"link":"link6"}}"#);
        let back: T = serde_json::from_str(&json).unwrap();
        assert_eq!(back.mount, link.mount);
    }

    #[test]
    fn other_spellings_name_the_allowed_ones() {
        for bad in [
            "mount = \"wrist\"",
            "mount = { lnk = \"a\" }",
            "mount = { link = \"\" }",
            "mount = 3",
        ] {
            let e = toml::from_str::<T>(bad).err().unwrap().to_string();
            assert!(e.contains("\"fixed\" or { link"), "{bad}: {e}");
        }
    }
}

//! The cell's cameras: one `[camera]` table, or several `[[camera]]` tables, each with a
//! `name` and, when it differs from the shared `[segmenter]`, its own `segmenter`.
//!
//! One table keeps the file format every existing cell uses, with its error lines. Several
//! tables make a rig: one arm motion serves them all (docs/cameras.md). Code iterates
//! [`CameraSet::cameras`]; code that cannot serve several refuses them
//! ([`CameraSet::require_one`]) before it reaches for [`CameraSet::first`].

use std::fmt;
use std::path::Path;

use serde::de::{self, MapAccess, SeqAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::{CameraConfig, InitialGuess, SegmenterConfig};
use crate::error::{Error, Result};

/// Most cameras one cell may list: each adds a frame, a mask and a solve to every view.
pub const MAX_CAMERAS: usize = 8;

/// Longest camera name: it becomes a folder, a frame name and a JSON key.
pub const MAX_CAMERA_NAME: usize = 32;

/// The name of the camera of a single `[camera]` table.
pub const SINGLE_CAMERA_NAME: &str = "camera";

/// One camera of the cell.
#[derive(Clone, Debug)]
pub struct NamedCamera {
    /// What runs, results and messages call it (`[a-z0-9_-]`, from the table's `name`).
    pub name: String,
    /// The backend, intrinsics and mount.
    pub config: CameraConfig,
    /// Its own segmenter; absent: the shared `[segmenter]`.
    pub segmenter: Option<SegmenterConfig>,
    /// Its own starting pose (a tape measure, a drawing); absent: the automatic
    /// initialisation. Only `[[camera]]` tables have one; a `[camera]` table's is
    /// `[calibration] initial_guess`.
    pub initial_guess: Option<InitialGuess>,
}

/// How a config file wrote its `camera` key: a fact of the TOML, which the error keys
/// (`camera.fx` or `camera[2].fx`) follow. Which run and result formats it records is
/// `run::rig::RunLayout`'s business.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraTables {
    /// A single `[camera]` table.
    One,
    /// `[[camera]]` tables, each named (even one).
    List,
}

/// The `camera` key: one table or a list of named tables.
#[derive(Clone, Debug)]
pub struct CameraSet {
    cameras: Vec<NamedCamera>,
    tables: CameraTables,
}

impl CameraSet {
    /// A single `[camera]` table.
    pub fn one(config: CameraConfig) -> CameraSet {
        CameraSet {
            cameras: vec![NamedCamera {
                name: SINGLE_CAMERA_NAME.into(),
                config,
                segmenter: None,
                initial_guess: None,
            }],
            tables: CameraTables::One,
        }
    }

    /// Every camera, in file order.
    pub fn cameras(&self) -> &[NamedCamera] {
        &self.cameras
    }

    /// The first camera's table: the only one of a `[camera]` table. Code that serves
    /// several cameras iterates [`CameraSet::cameras`] instead.
    pub fn first(&self) -> &CameraConfig {
        &self.cameras[0].config
    }

    /// As [`CameraSet::first`], to edit.
    pub fn first_mut(&mut self) -> &mut CameraConfig {
        &mut self.cameras[0].config
    }

    /// How the file wrote the `camera` key.
    pub fn tables(&self) -> CameraTables {
        self.tables
    }

    /// Refuses `[[camera]]` tables where `what` serves a single `[camera]` table, naming the
    /// key: even one listed camera records `easyhec-run/2`, which such code does not read.
    pub fn require_one(&self, path: &Path, what: &str) -> Result<()> {
        if self.tables == CameraTables::List {
            return Err(Error::input(
                path,
                "camera",
                format!(
                    "lists {} camera(s) as [[camera]] tables; {what} serves one camera: use a config with a single [camera] table for it",
                    self.cameras.len()
                ),
            ));
        }
        Ok(())
    }

    /// Checks what only a list of cameras can get wrong: how many, their names, their
    /// sources, and a starting pose for each camera on a link. Each camera's own values are checked as a `[camera]` table is.
    pub fn validate(&self, path: &Path) -> Result<()> {
        let n = self.cameras.len();
        if n == 0 || n > MAX_CAMERAS {
            return Err(Error::input(
                path,
                "camera",
                format!("lists {n} cameras; allowed: 1 to {MAX_CAMERAS}"),
            ));
        }
        for (i, cam) in self.cameras.iter().enumerate() {
            if let Some(problem) = name_problem(&cam.name) {
                return Err(Error::input(
                    path,
                    format!("camera[{i}].name"),
                    format!("is {:?}; allowed: {problem}", cam.name),
                ));
            }
            if let Some(first) = self.cameras[..i].iter().position(|c| c.name == cam.name) {
                return Err(Error::input(
                    path,
                    format!("camera[{i}].name"),
                    format!(
                        "is {:?}, already camera[{first}].name; allowed: each name once",
                        cam.name
                    ),
                ));
            }
            if let Some(Err(m)) = cam.initial_guess.as_ref().map(|g| g.camera_from_base()) {
                return Err(Error::input(path, format!("camera[{i}].initial_guess"), m));
            }
            if let Some((key, source)) = source_of(&cam.config) {
                let earlier = self.cameras[..i]
                    .iter()
                    .position(|c| source_of(&c.config).is_some_and(|(_, s)| s == source));
                if let Some(first) = earlier {
                    return Err(Error::input(
                        path,
                        format!("camera[{i}].{key}"),
                        format!("is {source:?}, as camera[{first}]'s; allowed: a different device or topic per camera (two tables would read one stream)"),
                    ));
                }
            }
            if let (true, Some(link), None) = (
                self.tables == CameraTables::List,
                cam.config.mount().link(),
                &cam.initial_guess,
            ) {
                return Err(Error::input(
                    path,
                    format!("camera[{i}].initial_guess"),
                    format!("is missing; a camera on link '{link}' needs its own starting camera_from_{link}, from the mount's drawing ({{ eye = […], look_at = […] }} in the link's frame)"),
                ));
            }
        }
        Ok(())
    }

    /// The key prefix errors about camera `index` use: `camera` for a single table,
    /// `camera[i]` for a list.
    pub fn key(&self, index: usize) -> String {
        if self.tables == CameraTables::List {
            format!("camera[{index}]")
        } else {
            "camera".into()
        }
    }

    /// Mutable access to every camera (benchmarks seed each one).
    pub fn cameras_mut(&mut self) -> &mut [NamedCamera] {
        &mut self.cameras
    }
}

/// Where a camera's frames come from, as `(key, value)`, for the kinds that name one: two
/// tables with the same source would calibrate one stream twice.
fn source_of(config: &CameraConfig) -> Option<(&'static str, String)> {
    match config {
        CameraConfig::V4l2(t) => Some(("device", t.device.clone())),
        CameraConfig::Aravis(t) => t.device_id.clone().map(|id| ("device_id", id)),
        CameraConfig::Ros2(t) => Some(("image_topic", t.image_topic.clone())),
        CameraConfig::Sim(_) => None,
    }
}

/// Why `asked` is no selection of the cameras `known` (1 to all of them, each a known name,
/// none twice), or `None`. The calibration loop and the daemon's start request both use it.
pub fn selection_problem(known: &[&str], asked: &[String]) -> Option<String> {
    if asked.is_empty() || asked.len() > known.len() {
        return Some(format!(
            "cameras: {} names; allowed: 1 to {} of {known:?}",
            asked.len(),
            known.len()
        ));
    }
    for (i, n) in asked.iter().enumerate() {
        if !known.contains(&n.as_str()) {
            return Some(format!(
                "cameras[{i}]: {n:?} is no camera of this cell; allowed: {known:?}"
            ));
        }
        if asked[..i].contains(n) {
            return Some(format!("cameras[{i}]: {n:?} is named twice"));
        }
    }
    None
}

/// Why `name` cannot name a camera, or `None`.
pub fn name_problem(name: &str) -> Option<String> {
    let ok_chars = name
        .chars()
        .all(|ch| ch.is_ascii_lowercase() || ch.is_ascii_digit() || ch == '_' || ch == '-');
    let ok = !name.is_empty()
        && name.len() <= MAX_CAMERA_NAME
        && ok_chars
        && name.starts_with(|ch: char| ch.is_ascii_lowercase());
    (!ok).then(|| {
        format!("1 to {MAX_CAMERA_NAME} characters of a-z, 0-9, _ and -, starting with a letter")
    })
}

/// Renames an error's field from a single camera's keys (`camera.fx`) to camera `index` of
/// the set (`camera[2].fx`), so a check written for one table names the right one.
pub fn rekey(err: Error, set: &CameraSet, index: usize) -> Error {
    match err {
        Error::Input {
            file,
            field,
            message,
        } if set.tables() == CameraTables::List => {
            let field = match field.strip_prefix("camera") {
                Some(rest) if rest.is_empty() || rest.starts_with('.') => {
                    format!("{}{rest}", set.key(index))
                }
                _ => field,
            };
            Error::Input {
                file,
                field,
                message,
            }
        }
        other => other,
    }
}

impl Serialize for CameraSet {
    fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        use serde::ser::Error as _;
        if self.tables == CameraTables::One {
            return self.cameras[0].config.serialize(s);
        }
        let mut tables = Vec::with_capacity(self.cameras.len());
        for cam in &self.cameras {
            let mut table = toml::Table::try_from(&cam.config).map_err(S::Error::custom)?;
            table.insert("name".into(), toml::Value::String(cam.name.clone()));
            if let Some(seg) = &cam.segmenter {
                let seg = toml::Value::try_from(seg).map_err(S::Error::custom)?;
                table.insert("segmenter".into(), seg);
            }
            if let Some(g) = &cam.initial_guess {
                let g = toml::Value::try_from(g).map_err(S::Error::custom)?;
                table.insert("initial_guess".into(), g);
            }
            tables.push(table);
        }
        tables.serialize(s)
    }
}

impl<'de> Deserialize<'de> for CameraSet {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<CameraSet, D::Error> {
        d.deserialize_any(CameraSetVisitor)
    }
}

struct CameraSetVisitor;

impl<'de> Visitor<'de> for CameraSetVisitor {
    type Value = CameraSet;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a [camera] table, or [[camera]] tables each with a name")
    }

    /// One `[camera]` table: parsed in place, so errors keep their line.
    fn visit_map<A: MapAccess<'de>>(self, map: A) -> std::result::Result<CameraSet, A::Error> {
        let config = CameraConfig::deserialize(de::value::MapAccessDeserializer::new(map))?;
        Ok(CameraSet::one(config))
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> std::result::Result<CameraSet, A::Error> {
        let mut cameras = Vec::new();
        while let Some(mut table) = seq.next_element::<toml::Table>()? {
            let i = cameras.len();
            if i >= MAX_CAMERAS {
                return Err(de::Error::custom(format!(
                    "camera: more than {MAX_CAMERAS} [[camera]] tables; allowed: 1 to {MAX_CAMERAS}"
                )));
            }
            let name = match table.remove("name") {
                Some(toml::Value::String(s)) => s,
                Some(other) => {
                    return Err(de::Error::custom(format!(
                        "camera[{i}].name: is {other}; allowed: a string"
                    )))
                }
                None => {
                    return Err(de::Error::custom(format!(
                        "camera[{i}].name: missing; every [[camera]] table needs a name"
                    )))
                }
            };
            let segmenter = match table.remove("segmenter") {
                Some(v) => Some(SegmenterConfig::deserialize(v).map_err(|e| {
                    de::Error::custom(format!("camera[{i}].segmenter: {}", e.message()))
                })?),
                None => None,
            };
            let initial_guess = match table.remove("initial_guess") {
                Some(v) => Some(InitialGuess::deserialize(v).map_err(|e| {
                    de::Error::custom(format!("camera[{i}].initial_guess: {}", e.message()))
                })?),
                None => None,
            };
            let config = CameraConfig::deserialize(toml::Value::Table(table))
                .map_err(|e| de::Error::custom(format!("camera[{i}]: {}", e.message())))?;
            cameras.push(NamedCamera {
                name,
                config,
                segmenter,
                initial_guess,
            });
        }
        if cameras.is_empty() {
            return Err(de::Error::custom(
                "camera: an empty list; add a [[camera]] table",
            ));
        }
        Ok(CameraSet {
            cameras,
            tables: CameraTables::List,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table(name: &str, fx: f64) -> String {
        format!("[[camera]]\nname = \"{name}\"\nkind = \"sim\"\nwidth = 64\nheight = 48\nfx = {fx}\nfy = 60.0\ncx = 31.5\ncy = 23.5\ntruth = {{ eye = [1.0, 0.0, 1.0], look_at = [0.0, 0.0, 0.3] }}\n")
    }

    #[derive(Deserialize, Serialize)]
    struct Holder {
        camera: CameraSet,
    }

    #[test]
    fn a_list_keeps_names_order_and_round_trips() {
        let text = format!("{}{}", table("left", 60.0), table("right", 61.0));
        let h: Holder = toml::from_str(&text).unwrap();
        let names: Vec<&str> = h.camera.cameras().iter().map(|c| c.name.as_str()).collect();
        assert_eq!(names, ["left", "right"]);
        assert!(h.camera.tables() == CameraTables::List && h.camera.cameras().len() > 1);
        assert_eq!(h.camera.first().camera().unwrap().fx, 60.0);
        let again: Holder = toml::from_str(&toml::to_string(&h).unwrap()).unwrap();
        assert_eq!(again.camera.cameras()[1].name, "right");
        assert_eq!(again.camera.cameras()[1].config.camera().unwrap().fx, 61.0);
    }

    #[test]
    fn names_are_checked_once_each_and_safe() {
        let path = Path::new("c.toml");
        for (text, key) in [
            (
                format!("{}{}", table("left", 60.0), table("left", 61.0)),
                "camera[1].name",
            ),
            (table("../x", 60.0), "camera[0].name"),
            (table("Left", 60.0), "camera[0].name"),
        ] {
            let h: Holder = toml::from_str(&text).unwrap();
            let e = h.camera.validate(path).unwrap_err().to_string();
            assert!(e.contains(key), "{e}");
        }
        let missing = table("x", 60.0).replace("name = \"x\"\n", "");
        let e = toml::from_str::<Holder>(&missing)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("camera[0].name"), "{e}");
    }

    #[test]
    fn errors_of_a_listed_camera_name_its_index() {
        let h: Holder =
            toml::from_str(&format!("{}{}", table("a", 60.0), table("b", 60.0))).unwrap();
        let e = rekey(Error::input("c.toml", "camera.fx", "bad"), &h.camera, 1).to_string();
        assert!(e.contains("camera[1].fx"), "{e}");
        let single = CameraSet::one(h.camera.cameras()[0].config.clone());
        let e = rekey(Error::input("c.toml", "camera.fx", "bad"), &single, 0).to_string();
        assert!(e.contains(": camera.fx:"), "{e}");
    }
}

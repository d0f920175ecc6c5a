//! Cell configuration (`config/*.toml`): one home for every table of a cell file.
//!
//! Each table is plain data plus the checks that need nothing but the file itself: which arm,
//! camera and segmenter to drive (`[arm]`, `[camera]`, `[segmenter]`), the robot description
//! (`[robot]`), the safety envelope (`[safety]`), the loop's settings (`[calibration]`) and the
//! service's (`[daemon]`). Building hardware from it is `crate::cell`'s job; this module sits
//! below everything that interprets it, so it imports nothing above the foundation (`error`,
//! `geometry`) and the driver crate's types and file readers.
//!
//! Relative paths in a config are relative to the config file. `docs/config.md` lists every key.

pub mod arm;
pub mod calibration;
pub mod camera;
pub mod cameras;
pub mod checks;
pub mod daemon;
pub mod mount;
pub mod robot;
pub mod ros2;
pub mod safety;
pub mod scene;
pub mod segmenter;

use std::path::Path;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

pub use arm::{
    ArmConfig, FaultConfig, PiperSettings, Ros2ArmSettings, ServoArmSettings, ServoJointToml,
    SimArmSettings, UrSettings, XarmSettings,
};
pub use calibration::{
    CalibrationSettings, InitialGuess, RendererChoice, ScoreSetting, SelectionSetting,
    SourceSetting,
};
pub use camera::{
    AravisSettings, CameraCalibration, CameraConfig, JointsFrom, LookAt, Ros2CameraSettings,
    SimCameraSettings, V4l2Settings,
};
pub use cameras::{CameraSet, CameraTables, NamedCamera};
pub use daemon::DaemonSettings;
pub use mount::Mount;
pub use robot::RobotConfig;
pub use safety::{AttachedConfig, ObstacleConfig, SafetyConfig, WorkspaceConfig};
pub use scene::{
    ClutterSettings, DistractorSettings, ExposureSettings, PaletteSettings, SceneEffects,
    ScenePreset, SceneSettings, ShadowSettings,
};
pub use segmenter::{NoiseModel, OnnxConfig, SegmenterConfig};

/// A whole cell config file.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CellConfig {
    /// The robot description.
    pub robot: RobotConfig,
    /// The arm backend.
    pub arm: ArmConfig,
    /// The cameras: one `[camera]` table, or `[[camera]]` tables with names (a rig).
    pub camera: CameraSet,
    /// How frames become masks.
    pub segmenter: SegmenterConfig,
    /// Loop settings.
    #[serde(default)]
    pub calibration: CalibrationSettings,
    /// Safety envelope.
    #[serde(default)]
    pub safety: SafetyConfig,
    /// `easyhec daemon` settings (ignored by the other commands).
    #[serde(default)]
    pub daemon: DaemonSettings,
    /// Where easyhec joins a ROS 2 graph (`--features ros2`); absent: it does not.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ros2: Option<ros2::Ros2Settings>,
}

impl CellConfig {
    /// The single-camera config of camera `index`: its table as `[camera]` and its own
    /// segmenter, if it has one, as `[segmenter]`. Everything else is shared.
    pub fn for_camera(&self, index: usize) -> CellConfig {
        let named = &self.camera.cameras()[index];
        CellConfig {
            camera: CameraSet::one(named.config.clone()),
            segmenter: named
                .segmenter
                .clone()
                .unwrap_or_else(|| self.segmenter.clone()),
            ..self.clone()
        }
    }
}

/// Longest duration a config may set, seconds (a day): every timeout and margin is far
/// shorter, and a bound keeps a typo from overflowing a deadline.
pub const MAX_SECONDS: f64 = 86_400.0;

/// A duration from a config value in seconds (positive, at most [`MAX_SECONDS`]).
pub(crate) fn seconds(path: &Path, key: &str, v: f64) -> Result<Duration> {
    if v.is_finite() && v > 0.0 && v <= MAX_SECONDS {
        Ok(Duration::from_secs_f64(v))
    } else {
        Err(Error::input(
            path,
            key,
            format!("{v} s: use a positive number of seconds, at most {MAX_SECONDS}"),
        ))
    }
}

/// Reads and parses a cell config, with one-line errors naming the key.
pub fn read_config(path: &Path) -> Result<CellConfig> {
    let text = crate::io::read_text_input(path)?;
    parse_config(&text, path)
}

/// Parses cell-config text; `path` is what errors name. Parsing only: [`CellConfig::validate`]
/// checks the values.
pub fn parse_config(text: &str, path: &Path) -> Result<CellConfig> {
    toml::from_str(text).map_err(|e| toml_error(text, path, &e))
}

/// A TOML parse error of `text` (read from `path`) as one line naming the line and, where the
/// parser stopped in a value, its dotted key.
pub(crate) fn toml_error(text: &str, path: &Path, e: &toml::de::Error) -> Error {
    let start = e.span().map(|s| s.start.min(text.len()));
    // Lines counted by the newlines before the span, so a span at a line's first column
    // names that line, not the one above.
    let line = start
        .and_then(|s| text.get(..s))
        .map_or(0, |t| t.matches('\n').count() + 1);
    let field = match start.and_then(|s| key_of_value_at(text, s)) {
        Some(key) => format!("line {line} ({key})"),
        None => format!("line {line}"),
    };
    Error::input(path, field, e.message().replace('\n', " "))
}

/// The dotted key (`table.key`, under the nearest table header above) whose value the byte
/// offset `at` lies in, on a `key = value` line: so a value the parser refuses (a misspelt
/// choice) names its field as well as its line. `None` when `at` is not past a line's `=`
/// (an unknown key, a missing one, a broken header), where the parser's message names it.
fn key_of_value_at(text: &str, at: usize) -> Option<String> {
    let line_start = text.get(..at)?.rfind('\n').map_or(0, |i| i + 1);
    let line = text[line_start..].split('\n').next().unwrap_or("");
    let eq = line.find('=')?;
    if at <= line_start + eq {
        return None;
    }
    let plain = |k: &str| {
        !k.is_empty()
            && k.chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-' || c == '.')
    };
    let key = line[..eq].trim();
    if !plain(key) {
        return None;
    }
    let table = text[..line_start].lines().rev().find_map(|l| {
        let l = l.split('#').next().unwrap_or("").trim();
        let name = l
            .strip_prefix("[[")
            .and_then(|t| t.strip_suffix("]]"))
            .or_else(|| l.strip_prefix('[').and_then(|t| t.strip_suffix(']')))?
            .trim();
        plain(name).then_some(name)
    });
    Some(match table {
        Some(t) => format!("{t}.{key}"),
        None => key.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::key_of_value_at;

    #[test]
    fn a_refused_value_names_its_key_under_its_table() {
        let text = "[robot]\nurdf = \"x\"\n\n[calibration] # the loop\nm = [[1, 0],\n  [0, 1]]\nmount_contact = \"sometimes\"\n";
        let value = text.find("\"sometimes").unwrap();
        assert_eq!(
            key_of_value_at(text, value).as_deref(),
            Some("calibration.mount_contact")
        );
        // An unknown or missing key is the parser's to name: the offset is not in a value.
        assert_eq!(
            key_of_value_at(text, text.find("mount_contact").unwrap()),
            None
        );
        assert_eq!(key_of_value_at(text, text.find("[robot]").unwrap()), None);
    }
}

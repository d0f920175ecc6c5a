//! `[camera.scene]`: how the simulated camera dresses its frames (table, clutter, palette,
//! shadows, exposure, distractors). Rendering them is `crate::scene`'s job.

use std::path::Path;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// A named bundle of scene effects; the effects' own tables override it.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum ScenePreset {
    /// The plain frames: none of the effects unless a table turns one on.
    #[default]
    Easy,
    /// Every effect on with its default settings: clutter, light robot on light walls, shadows,
    /// exposure changes, moving distractors.
    Hard,
}

impl FromStr for ScenePreset {
    type Err = String;

    /// `easy` or `hard` (command-line spelling).
    fn from_str(s: &str) -> std::result::Result<ScenePreset, String> {
        <ScenePreset as clap::ValueEnum>::from_str(s, false)
            .map_err(|_| format!("unknown scene preset '{s}': expected easy or hard"))
    }
}

/// Clutter on the wall and table (see the module docs).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct ClutterSettings {
    /// Off turns the effect off even under the hard preset.
    pub enabled: bool,
    /// Fraction of wall cells (about 0.3 x 0.22 rad each) holding a poster, shelf, clock or
    /// switch.
    pub wall_density: f64,
    /// Fraction of table cells (32 cm squares) holding an item.
    pub table_density: f64,
    /// Cables running along the wall.
    pub wall_cables: u32,
    /// Cables across the table.
    pub table_cables: u32,
}

impl Default for ClutterSettings {
    fn default() -> Self {
        ClutterSettings {
            enabled: true,
            wall_density: 0.8,
            table_density: 0.55,
            wall_cables: 3,
            table_cables: 3,
        }
    }
}

/// Robot and wall colours, linear RGB albedo in [0, 1].
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct PaletteSettings {
    /// Off turns the effect off even under the hard preset.
    pub enabled: bool,
    /// Link colours, used in turn along the links (link 0 takes the first).
    pub robot_colours: Vec<[f64; 3]>,
    /// Wall paint.
    pub wall_colour: [f64; 3],
}

impl Default for PaletteSettings {
    /// A white and light-grey robot in front of a near-white wall.
    fn default() -> Self {
        PaletteSettings {
            enabled: true,
            robot_colours: vec![[0.9, 0.9, 0.88], [0.74, 0.75, 0.77]],
            wall_colour: [1.0, 0.98, 0.95],
        }
    }
}

impl PaletteSettings {
    /// The plain frames' colours: white and dark-grey links, an off-white wall.
    pub fn easy() -> PaletteSettings {
        PaletteSettings {
            enabled: true,
            robot_colours: vec![[0.86, 0.86, 0.84], [0.22, 0.22, 0.24]],
            wall_colour: [0.92, 0.9, 0.85],
        }
    }
}

/// A directional light in the base frame casting shadows.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct ShadowSettings {
    /// Off turns the effect off even under the hard preset.
    pub enabled: bool,
    /// Direction from the scene towards the light, base frame (any length; z must be > 0).
    pub to_light_in_base: [f64; 3],
    /// Fraction of the light a shadow removes from the table and floor, in [0, 1].
    pub strength: f64,
}

impl Default for ShadowSettings {
    fn default() -> Self {
        ShadowSettings {
            enabled: true,
            to_light_in_base: [0.45, -0.35, 0.8],
            strength: 0.6,
        }
    }
}

/// Per-frame exposure and white-balance changes.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct ExposureSettings {
    /// Off turns the effect off even under the hard preset.
    pub enabled: bool,
    /// Overall gain drawn uniformly in `[1 - gain_spread, 1 + gain_spread]` (linear light).
    pub gain_spread: f64,
    /// Per-channel gain factor drawn in `[1 - spread, 1 + spread]` (white balance).
    pub white_balance_spread: f64,
    /// Offset drawn in `[-offset_spread, offset_spread]` grey levels (0–255), after gamma.
    pub offset_spread: f64,
}

impl Default for ExposureSettings {
    fn default() -> Self {
        ExposureSettings {
            enabled: true,
            gain_spread: 0.3,
            white_balance_spread: 0.08,
            offset_spread: 6.0,
        }
    }
}

/// Boxes on the table that move every frame and are not the robot.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct DistractorSettings {
    /// Off turns the effect off even under the hard preset.
    pub enabled: bool,
    /// Number of boxes.
    pub count: u32,
    /// Edge length range of a box, metres `[min, max]`.
    pub size_m: [f64; 2],
    /// Whether a box in front of the robot hides it (the truth mask then leaves out the hidden
    /// robot pixels). Off: boxes are drawn behind the robot, so the truth mask is the whole
    /// silhouette and calibrating from truth masks stays exact.
    pub occludes_robot: bool,
    /// Person-like arms reaching over the table from outside it (sleeve, wrist, hand), each
    /// frame from another side.
    pub arms: u32,
}

impl Default for DistractorSettings {
    fn default() -> Self {
        DistractorSettings {
            enabled: true,
            count: 2,
            size_m: [0.08, 0.24],
            occludes_robot: false,
            arms: 1,
        }
    }
}

/// Scene dressing.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SceneSettings {
    /// Table top height in the base frame, metres (the base stands on it).
    #[serde(default)]
    pub table_height_m: f64,
    /// Table extent `[x_min, x_max, y_min, y_max]` in the base frame, metres.
    #[serde(default = "default_table")]
    pub table_extent_m: [f64; 4],
    /// Floor height, metres.
    #[serde(default = "default_floor")]
    pub floor_height_m: f64,
    /// Sensor noise standard deviation, grey levels (0–255).
    #[serde(default = "default_noise")]
    pub noise_sigma: f64,
    /// Seed of the sensor noise and of every effect.
    #[serde(default)]
    pub seed: u64,
    /// Which effects are on when their tables are absent.
    #[serde(default)]
    pub preset: ScenePreset,
    /// Clutter on the wall and table.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clutter: Option<ClutterSettings>,
    /// Robot and wall colours.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub palette: Option<PaletteSettings>,
    /// Shadows from a light in the base frame.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shadows: Option<ShadowSettings>,
    /// Per-frame exposure changes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exposure: Option<ExposureSettings>,
    /// Moving boxes on the table.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distractors: Option<DistractorSettings>,
}

fn default_table() -> [f64; 4] {
    [-0.4, 1.0, -0.8, 0.8]
}
fn default_floor() -> f64 {
    -0.75
}
fn default_noise() -> f64 {
    2.5
}

/// Largest distance of a table edge or a floor from the robot's base, metres.
const MAX_SCENE_EXTENT_M: f64 = 10.0;

impl SceneSettings {
    /// The table's and floor's placement, if one is wrong: finite, within
    /// [`MAX_SCENE_EXTENT_M`] of the base, a table of positive size and a floor below it. The
    /// scene draws its clutter and boxes from these ranges.
    fn layout_problem(&self) -> Option<(&'static str, String)> {
        let near = |v: f64| v.is_finite() && v.abs() <= MAX_SCENE_EXTENT_M;
        let [x0, x1, y0, y1] = self.table_extent_m;
        if !(self.table_extent_m.iter().all(|&v| near(v)) && x0 < x1 && y0 < y1) {
            return Some((
                "table_extent_m",
                format!(
                    "is {:?}; allowed: [x_min, x_max, y_min, y_max] with min < max, each within {MAX_SCENE_EXTENT_M} m",
                    self.table_extent_m
                ),
            ));
        }
        if !near(self.table_height_m) {
            let h = self.table_height_m;
            return Some((
                "table_height_m",
                format!("is {h}; allowed: within {MAX_SCENE_EXTENT_M} m"),
            ));
        }
        if !(near(self.floor_height_m) && self.floor_height_m <= self.table_height_m) {
            return Some((
                "floor_height_m",
                format!(
                    "is {}; allowed: at most table_height_m ({}), within {MAX_SCENE_EXTENT_M} m",
                    self.floor_height_m, self.table_height_m
                ),
            ));
        }
        None
    }
}

impl Default for SceneSettings {
    fn default() -> Self {
        SceneSettings {
            table_height_m: 0.0,
            table_extent_m: default_table(),
            floor_height_m: default_floor(),
            noise_sigma: default_noise(),
            seed: 0,
            preset: ScenePreset::Easy,
            clutter: None,
            palette: None,
            shadows: None,
            exposure: None,
            distractors: None,
        }
    }
}

/// The effects a [`SceneSettings`] turns on, after the preset and the tables are combined
/// (`None`: off).
#[derive(Clone, Debug, PartialEq)]
pub struct SceneEffects {
    /// Clutter.
    pub clutter: Option<ClutterSettings>,
    /// Colours (always set: the plain frames have colours too).
    pub palette: PaletteSettings,
    /// Shadows.
    pub shadows: Option<ShadowSettings>,
    /// Exposure changes.
    pub exposure: Option<ExposureSettings>,
    /// Distractors.
    pub distractors: Option<DistractorSettings>,
}

impl SceneSettings {
    /// The hard preset with every effect at its default settings (seed 0).
    pub fn hard() -> SceneSettings {
        SceneSettings {
            preset: ScenePreset::Hard,
            ..SceneSettings::default()
        }
    }

    /// The same dressing with another seed.
    pub fn with_seed(self, seed: u64) -> SceneSettings {
        SceneSettings { seed, ..self }
    }

    /// The effects in force: an effect's table wins (on unless `enabled = false`); without a
    /// table the preset decides.
    pub fn effects(&self) -> SceneEffects {
        let hard = self.preset == ScenePreset::Hard;
        fn pick<T: Clone + Default>(
            t: &Option<T>,
            hard: bool,
            on: impl Fn(&T) -> bool,
        ) -> Option<T> {
            match t {
                Some(t) => on(t).then(|| t.clone()),
                None => hard.then(T::default),
            }
        }
        SceneEffects {
            clutter: pick(&self.clutter, hard, |t| t.enabled),
            palette: pick(&self.palette, hard, |t| t.enabled).unwrap_or_else(PaletteSettings::easy),
            shadows: pick(&self.shadows, hard, |t| t.enabled),
            exposure: pick(&self.exposure, hard, |t| t.enabled),
            distractors: pick(&self.distractors, hard, |t| t.enabled),
        }
    }

    /// Checks ranges; `field` is where these settings sit in `file` (e.g. `camera.scene`), so
    /// the error names the exact key.
    pub fn validate(&self, file: &Path, field: &str) -> Result<()> {
        let bad =
            |key: &str, message: String| Err(Error::input(file, format!("{field}.{key}"), message));
        let unit = |c: &[f64; 3]| c.iter().all(|v| v.is_finite() && (0.0..=1.0).contains(v));
        if let Some((key, message)) = self.layout_problem() {
            return bad(key, message);
        }
        if !(self.noise_sigma.is_finite() && (0.0..=255.0).contains(&self.noise_sigma)) {
            return bad(
                "noise_sigma",
                format!("must be in [0, 255] grey levels, got {}", self.noise_sigma),
            );
        }
        if let Some(c) = &self.clutter {
            for (key, v) in [
                ("wall_density", c.wall_density),
                ("table_density", c.table_density),
            ] {
                if !(0.0..=1.0).contains(&v) {
                    return bad(
                        &format!("clutter.{key}"),
                        format!("must be in [0, 1], got {v}"),
                    );
                }
            }
            if c.wall_cables > 64 || c.table_cables > 64 {
                return bad("clutter", "at most 64 cables per surface".into());
            }
        }
        if let Some(p) = &self.palette {
            if p.robot_colours.is_empty() || !p.robot_colours.iter().all(unit) {
                return bad(
                    "palette.robot_colours",
                    "needs at least one [r, g, b] colour, each channel in [0, 1]".into(),
                );
            }
            if !unit(&p.wall_colour) {
                return bad(
                    "palette.wall_colour",
                    "each channel must be in [0, 1]".into(),
                );
            }
        }
        if let Some(s) = &self.shadows {
            let d = s.to_light_in_base;
            if !(d.iter().all(|v| v.is_finite()) && d[2] > 0.0) {
                return bad(
                    "shadows.to_light_in_base",
                    format!("the light must be above the table (z > 0), got {d:?}"),
                );
            }
            if !(0.0..=1.0).contains(&s.strength) {
                return bad(
                    "shadows.strength",
                    format!("must be in [0, 1], got {}", s.strength),
                );
            }
        }
        if let Some(e) = &self.exposure {
            for (key, v) in [
                ("gain_spread", e.gain_spread),
                ("white_balance_spread", e.white_balance_spread),
            ] {
                if !(0.0..1.0).contains(&v) {
                    return bad(
                        &format!("exposure.{key}"),
                        format!("must be in [0, 1), got {v}"),
                    );
                }
            }
            if !(e.offset_spread.is_finite() && (0.0..=128.0).contains(&e.offset_spread)) {
                return bad(
                    "exposure.offset_spread",
                    format!("must be in [0, 128] grey levels, got {}", e.offset_spread),
                );
            }
        }
        if let Some(d) = &self.distractors {
            let [lo, hi] = d.size_m;
            if !(lo > 0.0 && lo <= hi && hi <= 1.0) {
                return bad(
                    "distractors.size_m",
                    format!("needs 0 < min <= max <= 1 m, got [{lo}, {hi}]"),
                );
            }
            if d.count > 16 {
                return bad("distractors.count", format!("at most 16, got {}", d.count));
            }
            if d.arms > 4 {
                return bad("distractors.arms", format!("at most 4, got {}", d.arms));
            }
        }
        Ok(())
    }
}

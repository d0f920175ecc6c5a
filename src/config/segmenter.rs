//! `[segmenter]`: how frames become robot masks, and the synthetic segmentation-noise model
//! the simulator's `sim-truth` segmenter and `easyhec synth` share.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// The segmentation-noise model (see [`crate::mask_noise`]). In a config it is a table of its
/// fields or the name of a preset: `"standard"`, `"segmenter"` or `"none"`.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct NoiseModel {
    /// RMS boundary displacement, pixels.
    pub boundary_jitter_px: f64,
    /// Correlation length of the boundary displacement, pixels: the displacement is smoothed
    /// white noise whose correlation falls to 0.61 at this distance. 0 keeps the older field of
    /// six planar waves (wavelengths 8–40 px).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub boundary_correlation_px: f64,
    /// Chance of blobs in a view.
    pub blob_probability: f64,
    /// Standard deviation of recorded joint noise, radians (or metres).
    pub joint_noise_rad: f64,
    /// Gaussian blur (standard deviation, pixels) of the robot's coverage before it is
    /// thresholded at one half: a segmenter that rounds corners and thins thin parts. 0: none.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub blur_px: f64,
    /// Signed offset of the whole outline, pixels (positive: outward, the masks fat): a
    /// segmenter's systematic bias, which more views do not average away. 0: none.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub outline_offset_px: f64,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

/// [`NoiseModel`]'s fields as a table states them.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct NoiseFields {
    boundary_jitter_px: f64,
    #[serde(default)]
    boundary_correlation_px: f64,
    blob_probability: f64,
    joint_noise_rad: f64,
    #[serde(default)]
    blur_px: f64,
    #[serde(default)]
    outline_offset_px: f64,
}

/// Reads a preset's name or a table, each with its own error message (an untagged enum would
/// only say that nothing matched).
struct NoiseVisitor;

impl<'de> serde::de::Visitor<'de> for NoiseVisitor {
    type Value = NoiseModel;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a noise preset (\"standard\", \"segmenter\", \"blurred\", \"fat\", \"none\") or a table of boundary_jitter_px, boundary_correlation_px, blob_probability, joint_noise_rad, blur_px, outline_offset_px")
    }

    fn visit_str<E: serde::de::Error>(self, name: &str) -> std::result::Result<NoiseModel, E> {
        NoiseModel::preset(name).ok_or_else(|| {
            E::custom(format!(
                "unknown noise preset '{name}'; allowed: {}, or a table",
                NoiseModel::PRESETS.join(", ")
            ))
        })
    }

    fn visit_map<A: serde::de::MapAccess<'de>>(
        self,
        map: A,
    ) -> std::result::Result<NoiseModel, A::Error> {
        let f = NoiseFields::deserialize(serde::de::value::MapAccessDeserializer::new(map))?;
        Ok(NoiseModel {
            boundary_jitter_px: f.boundary_jitter_px,
            boundary_correlation_px: f.boundary_correlation_px,
            blob_probability: f.blob_probability,
            joint_noise_rad: f.joint_noise_rad,
            blur_px: f.blur_px,
            outline_offset_px: f.outline_offset_px,
        })
    }
}

impl<'de> Deserialize<'de> for NoiseModel {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<NoiseModel, D::Error> {
        d.deserialize_any(NoiseVisitor)
    }
}

impl NoiseModel {
    /// The default benchmark noise: 0.5 px jitter, blobs in 30% of views, 0.5 mrad encoders.
    pub fn standard() -> NoiseModel {
        NoiseModel {
            boundary_jitter_px: 0.5,
            boundary_correlation_px: 0.0,
            blob_probability: 0.3,
            joint_noise_rad: 5e-4,
            blur_px: 0.0,
            outline_offset_px: 0.0,
        }
    }

    /// Noise like a segmentation network's: a soft boundary, thresholded, so the outline moves
    /// by a smooth 0.5 px RMS displacement correlated over about 6 px; blobs in a third of the
    /// views; 0.5 mrad encoders.
    pub fn segmenter() -> NoiseModel {
        NoiseModel {
            boundary_jitter_px: 0.5,
            boundary_correlation_px: 6.0,
            blob_probability: 1.0 / 3.0,
            joint_noise_rad: 5e-4,
            blur_px: 0.0,
            outline_offset_px: 0.0,
        }
    }

    /// A segmenter that rounds corners: the coverage blurred by 0.9 px before the threshold,
    /// so thin parts shrink and convex corners are cut (a bias more views do not average
    /// away), then [`NoiseModel::segmenter`]'s correlated threshold noise and blobs, and
    /// 0.3 mrad encoders.
    pub fn blurred() -> NoiseModel {
        NoiseModel {
            boundary_jitter_px: 0.5,
            boundary_correlation_px: 6.0,
            blob_probability: 1.0 / 3.0,
            joint_noise_rad: 3e-4,
            blur_px: 0.9,
            outline_offset_px: 0.0,
        }
    }

    /// A segmenter whose masks are fat: [`NoiseModel::segmenter`]'s noise with the whole
    /// outline 1 px outward, as a network trained on generously drawn labels (or a builtin
    /// colour model spilling onto a white wall) makes them.
    pub fn fat() -> NoiseModel {
        NoiseModel {
            outline_offset_px: 1.0,
            ..NoiseModel::segmenter()
        }
    }

    /// No noise at all.
    pub fn none() -> NoiseModel {
        NoiseModel {
            boundary_jitter_px: 0.0,
            boundary_correlation_px: 0.0,
            blob_probability: 0.0,
            joint_noise_rad: 0.0,
            blur_px: 0.0,
            outline_offset_px: 0.0,
        }
    }

    /// The presets' names, as configs and `--noise` spell them.
    pub const PRESETS: [&'static str; 5] = ["standard", "segmenter", "blurred", "fat", "none"];

    /// The preset called `name`, if there is one.
    pub fn preset(name: &str) -> Option<NoiseModel> {
        match name {
            "standard" => Some(NoiseModel::standard()),
            "segmenter" => Some(NoiseModel::segmenter()),
            "blurred" => Some(NoiseModel::blurred()),
            "fat" => Some(NoiseModel::fat()),
            "none" => Some(NoiseModel::none()),
            _ => None,
        }
    }
}

/// `[segmenter]` in a cell config.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum SegmenterConfig {
    /// The simulated camera's ground-truth mask, optionally with the synthetic segmentation
    /// noise of `easyhec synth` (boundary jitter and blobs), seeded per frame.
    SimTruth {
        /// Noise to add; absent: exact masks.
        #[serde(default)]
        noise: Option<NoiseModel>,
        /// Noise seed.
        #[serde(default)]
        seed: u64,
    },
    /// A segmentation network exported to ONNX, run on the CPU by tract. Needs the `onnx`
    /// cargo feature; the variant exists without it so such a config says how to rebuild.
    Onnx(OnnxConfig),
    /// A SAM-family promptable model the user exported to ONNX (an image encoder and a mask
    /// decoder), prompted with the box and interior points of the silhouette rendered under
    /// the current estimate, so no one clicks. Needs the `onnx` cargo feature.
    Sam(SamConfig),
    /// No training: background plate from the other views of the fixed camera, the silhouette
    /// rendered under the current estimate as a prior band, colour models and smoothing
    /// (module [`builtin`]).
    Builtin {
        /// Smallest prior band, pixels, while segmentation and solve alternate (the band also
        /// widens with the pose uncertainty and each view's misfit).
        #[serde(default = "default_min_band_px")]
        min_band_px: f32,
        /// Smallest band of the last re-segmentation, once the estimate has settled and fits
        /// (mean IoU at least 0.8): colours then decide only this close to the render.
        #[serde(default = "default_final_band_px")]
        final_band_px: f32,
    },
}

/// `[segmenter] kind = "onnx"`: which model, how to feed it a frame and how to read the robot
/// out of what it returns. The defaults fit a model that takes `1x3xHxW` RGB in 0–1 and ends
/// in one logit channel (`sigmoid`, threshold 0.5).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct OnnxConfig {
    /// The `.onnx` file, relative to the config file. Weights must be inside it (no external
    /// data files).
    pub model: PathBuf,
    /// Width the frame is resized to before inference; required when the model's input width
    /// is not fixed, and must equal it when it is.
    #[serde(default)]
    pub input_width: Option<u32>,
    /// Height the frame is resized to; same rules as `input_width`.
    #[serde(default)]
    pub input_height: Option<u32>,
    /// Tensor layout of the input and of 4-d outputs: `nchw` (PyTorch) or `nhwc`
    /// (TensorFlow/Keras exports).
    #[serde(default)]
    pub layout: TensorLayout,
    /// Channel order the model was trained on: `rgb` (torchvision, ultralytics) or `bgr`
    /// (OpenCV-based training code).
    #[serde(default)]
    pub channel_order: ChannelOrder,
    /// Scale of the pixel values before `mean`/`std`: `"0-1"` (pixel / 255) or `"0-255"`.
    #[serde(default)]
    pub pixel_range: PixelRange,
    /// Per-channel mean subtracted after scaling, in the channel order and range above
    /// (torchvision: `[0.485, 0.456, 0.406]`).
    #[serde(default = "OnnxConfig::zero_mean")]
    pub mean: [f32; 3],
    /// Per-channel divisor applied after the mean (torchvision: `[0.229, 0.224, 0.225]`).
    #[serde(default = "OnnxConfig::unit_std")]
    pub std: [f32; 3],
    /// Which model output holds the segmentation (torchvision's DeepLab exports `out` then
    /// `aux`: 0).
    #[serde(default)]
    pub output: usize,
    /// Which channel (class) of that output is the robot.
    #[serde(default)]
    pub channel: usize,
    /// What turns the output into a robot probability: `sigmoid` (one logit per class),
    /// `softmax` (across the channels, for multi-class logits) or `none` (the model already
    /// outputs a score; `threshold` applies to it as is).
    #[serde(default)]
    pub activation: Activation,
    /// A pixel is robot where the (activated) score exceeds this.
    #[serde(default = "OnnxConfig::half")]
    pub threshold: f32,
}

impl OnnxConfig {
    fn zero_mean() -> [f32; 3] {
        [0.0; 3]
    }
    fn unit_std() -> [f32; 3] {
        [1.0; 3]
    }
    fn half() -> f32 {
        0.5
    }
}

/// Most interior points a `sam` prompt carries per view, beside its box.
pub const MAX_SAM_POINTS: u32 = 16;

/// `[segmenter] kind = "sam"`: the two halves of a SAM-family model and how to prompt them.
/// No weights ship with easyhec and none are downloaded: export your own (docs/hardware/onnx.md).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SamConfig {
    /// The image encoder's `.onnx` file, relative to the config file: one input, `1x3xSxS`.
    pub encoder: PathBuf,
    /// The mask decoder's `.onnx` file, relative to the config file: it takes the encoder's
    /// outputs by name, `point_coords` and `point_labels`, and returns `low_res_masks`.
    pub decoder: PathBuf,
    /// How the frame becomes the encoder's square input: `longest-side` (SAM: scaled to fit,
    /// padded below and right) or `stretch` (SAM 2: stretched to the square).
    #[serde(default)]
    pub resize: SamResize,
    /// Interior points per view, besides the box: the deepest pixels of the rendered
    /// silhouette, spread apart (0 to [`MAX_SAM_POINTS`]).
    #[serde(default = "SamConfig::default_points")]
    pub points: u32,
    /// A pixel is robot where the decoder's mask logit exceeds this.
    #[serde(default)]
    pub threshold: f32,
}

impl SamConfig {
    fn default_points() -> u32 {
        3
    }
}

/// How a frame is fitted to a SAM-family encoder's square input.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum SamResize {
    /// Scaled so its longer side fills the square, keeping its aspect, the rest zero (SAM).
    #[default]
    LongestSide,
    /// Stretched to the square (SAM 2).
    Stretch,
}

/// Where the channel axis sits in the model's 4-d tensors.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum TensorLayout {
    /// `[1, C, H, W]`.
    #[default]
    Nchw,
    /// `[1, H, W, C]`.
    Nhwc,
}

/// Order of the colour channels in the model's input.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ChannelOrder {
    /// Red, green, blue.
    #[default]
    Rgb,
    /// Blue, green, red.
    Bgr,
}

/// Range of the pixel values fed to the model, before `mean` and `std`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
pub enum PixelRange {
    /// 8-bit values divided by 255.
    #[default]
    #[serde(rename = "0-1")]
    Unit,
    /// 8-bit values as they are.
    #[serde(rename = "0-255")]
    Byte,
}

/// How an output channel becomes a robot score.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Activation {
    /// Logistic function of the channel's logit.
    #[default]
    Sigmoid,
    /// Softmax across the output's channels, then the chosen channel.
    Softmax,
    /// The raw value.
    None,
}

fn default_min_band_px() -> f32 {
    8.0
}

/// Narrower than [`default_min_band_px`]: once the pose is known to a fraction of a pixel, the
/// render is better evidence near the outline than a light robot's colour against a light wall
/// (docs/benchmarks.md, segmentation: 0.948 -> 0.964 median mask IoU over 20 hard simulated cells). Not used
/// while the estimate can still move: a narrow band then shapes the masks to a wrong render
/// (offline synthetic seed 3 settled 5.9° off with 4 px from the start).
fn default_final_band_px() -> f32 {
    4.0
}

impl SegmenterConfig {
    /// The narrowest prior band a context-aware segmenter is given, pixels: `builtin`'s
    /// `min_band_px`, the default for any other kind.
    pub fn min_band_px(&self) -> f32 {
        match self {
            SegmenterConfig::Builtin { min_band_px, .. } => *min_band_px,
            _ => default_min_band_px(),
        }
    }

    /// Whether this segmenter reads a whole run of one camera (its other views, the prior
    /// silhouettes) rather than one frame at a time: the config-side twin of
    /// `Segmenter::uses_context`, for the rule in `CellConfig::check_whole_run_segmenters`.
    pub fn reads_whole_run(&self) -> bool {
        matches!(
            self,
            SegmenterConfig::Builtin { .. } | SegmenterConfig::Sam(_)
        )
    }

    /// Why a segmenter that [`SegmenterConfig::reads_whole_run`] does, for the error that
    /// refuses it in a list of cameras.
    pub fn whole_run_reason(&self) -> &'static str {
        match self {
            SegmenterConfig::Sam(_) => {
                "views with no estimate yet are drawn by builtin, from the background its other views show"
            }
            _ => "the background from its other views",
        }
    }

    /// The `kind` a config spells this segmenter with.
    pub fn kind(&self) -> &'static str {
        match self {
            SegmenterConfig::SimTruth { .. } => "sim-truth",
            SegmenterConfig::Onnx(_) => "onnx",
            SegmenterConfig::Sam(_) => "sam",
            SegmenterConfig::Builtin { .. } => "builtin",
        }
    }

    /// The narrowest band of the last re-segmentation once the estimate has settled and fits:
    /// `builtin`'s `final_band_px`, the default for any other kind.
    pub fn final_band_px(&self) -> f32 {
        match self {
            SegmenterConfig::Builtin { final_band_px, .. } => *final_band_px,
            _ => default_final_band_px(),
        }
    }

    /// Checks the values a segmenter would be built from; `config_path` is the cell config,
    /// which errors name.
    pub fn validate(&self, config_path: &Path) -> Result<()> {
        if let SegmenterConfig::Sam(sam) = self {
            return sam.validate(config_path);
        }
        if let SegmenterConfig::Builtin {
            min_band_px,
            final_band_px,
        } = self
        {
            for (key, v) in [
                ("segmenter.min_band_px", *min_band_px),
                ("segmenter.final_band_px", *final_band_px),
            ] {
                if !(v.is_finite() && v >= 0.0) {
                    return Err(Error::input(
                        config_path,
                        key,
                        format!("must be a width in pixels >= 0 (defaults: 8 and 4), got {v}"),
                    ));
                }
            }
        }
        Ok(())
    }

    /// A segmenter from a file holding a `[segmenter]` table (`easyhec solve --segmenter
    /// FILE`); its model paths stay relative to that file, which is the config path to build
    /// it with.
    pub fn from_file(path: &Path) -> Result<SegmenterConfig> {
        #[derive(Deserialize)]
        struct Table {
            segmenter: SegmenterConfig,
        }
        let text = crate::io::read_text_input(path)?;
        let table: Table = toml::from_str(&text).map_err(|e| super::toml_error(&text, path, &e))?;
        if let SegmenterConfig::SimTruth { .. } = table.segmenter {
            return Err(Error::input(
                path,
                "segmenter.kind",
                "\"sim-truth\" reads a simulated camera's truth, which recorded images do not carry; allowed: builtin, onnx, sam",
            ));
        }
        table.segmenter.validate(path)?;
        Ok(table.segmenter)
    }

    /// A segmenter by command-line name (`easyhec solve --segmenter NAME`).
    pub fn by_name(name: &str) -> std::result::Result<SegmenterConfig, String> {
        match name {
            "builtin" => Ok(SegmenterConfig::Builtin {
                min_band_px: default_min_band_px(),
                final_band_px: default_final_band_px(),
            }),
            "sim-truth" => Err(
                "--segmenter sim-truth: recorded images carry no ground truth; use builtin".into(),
            ),
            other => Err(format!(
                "--segmenter {other}: unknown segmenter and no such file; allowed: builtin, or a TOML file with a [segmenter] table"
            )),
        }
    }
}

impl SamConfig {
    /// Checks the prompt's size and the threshold; the model files are checked when the
    /// segmenter is built.
    fn validate(&self, config_path: &Path) -> Result<()> {
        if self.points > MAX_SAM_POINTS {
            return Err(Error::input(
                config_path,
                "segmenter.points",
                format!(
                    "is {}: allowed 0 to {MAX_SAM_POINTS} interior points per view",
                    self.points
                ),
            ));
        }
        if !self.threshold.is_finite() {
            return Err(Error::input(
                config_path,
                "segmenter.threshold",
                format!("{} is not a number: give a logit, e.g. 0.0", self.threshold),
            ));
        }
        Ok(())
    }
}

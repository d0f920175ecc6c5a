//! Segmenters: turn a colour frame into the robot mask the solver fits.
//!
//! `sim-truth` reads the simulator's ground-truth side channel; `builtin` (no training) uses
//! the static camera's other views and the silhouette rendered under the current estimate;
//! `onnx` (behind the `onnx` cargo feature) runs a user-supplied segmentation model.
//! Per-frame segmenters implement [`Segmenter::segment`] only; segmenters that gain from
//! context also override [`Segmenter::segment_views`] and [`Segmenter::uses_context`].

pub mod bench;
pub mod builtin;
pub mod refine;

pub use builtin::{BuiltinParams, ViewInput};

use std::path::{Path, PathBuf};

use easyhec_drivers::Frame;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::mask::Mask;

#[cfg(feature = "onnx")]
pub mod onnx;

/// Produces a robot mask from a frame.
pub trait Segmenter: Send + Sync {
    /// Name for logs and errors.
    fn name(&self) -> &str;
    /// The robot mask in the frame's (distorted) image.
    fn segment(&self, frame: &Frame) -> Result<Mask>;

    /// Masks for several views of the same fixed camera, each with an optional prior
    /// silhouette rendered under the current estimate. The default segments frame by frame;
    /// context-aware segmenters use the other views (background plate) and the priors.
    fn segment_views(&self, views: &[ViewInput<'_>]) -> Result<Vec<Mask>> {
        views.iter().map(|v| self.segment(v.frame)).collect()
    }

    /// Whether [`Segmenter::segment_views`] improves with more views and better priors, so
    /// callers re-segment earlier views as the calibration goes on (segment → solve →
    /// re-segment). False for per-frame segmenters: their masks never change.
    fn uses_context(&self) -> bool {
        false
    }

    /// Per-pixel log-odds for robot from the images alone (no prior), one per frame, when the
    /// segmenter has such evidence: it lets a caller fit each view's joints to its image where
    /// the recorded ones are wrong ([`refine::search_view_pairs`]). None by default.
    fn evidence(&self, _frames: &[&Frame]) -> Result<Option<Vec<Vec<f32>>>> {
        Ok(None)
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
        noise: Option<crate::synth::NoiseModel>,
        /// Noise seed.
        #[serde(default)]
        seed: u64,
    },
    /// A segmentation network exported to ONNX, run on the CPU by tract. Needs the `onnx`
    /// cargo feature; the variant exists without it so such a config says how to rebuild.
    Onnx(OnnxConfig),
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
/// (README, segmentation: 0.948 -> 0.964 median mask IoU over 20 hard simulated cells). Not used
/// while the estimate can still move: a narrow band then shapes the masks to a wrong render
/// (offline synthetic seed 3 settled 5.9° off with 4 px from the start).
fn default_final_band_px() -> f32 {
    4.0
}

/// A recorded view's colour image as a frame, for segmenting runs offline; it must have the
/// camera's size, since its mask is compared pixel for pixel with renders.
pub fn read_frame(path: &Path, width: u32, height: u32) -> Result<Frame> {
    let img = image::open(path)
        .map_err(|e| Error::input(path, "image", format!("cannot decode: {e}")))?
        .to_rgb8();
    if img.width() != width || img.height() != height {
        return Err(Error::input(
            path,
            "image",
            format!(
                "is {}x{} but the camera is {width}x{height}",
                img.width(),
                img.height()
            ),
        ));
    }
    Ok(Frame {
        width,
        height,
        rgb: img.into_raw(),
        captured_at: std::time::SystemTime::now(),
        truth_mask: None,
    })
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

    /// The narrowest band of the last re-segmentation once the estimate has settled and fits:
    /// `builtin`'s `final_band_px`, the default for any other kind.
    pub fn final_band_px(&self) -> f32 {
        match self {
            SegmenterConfig::Builtin { final_band_px, .. } => *final_band_px,
            _ => default_final_band_px(),
        }
    }

    /// Builds the segmenter; `config_path` is the cell config, which relative paths (the ONNX
    /// model) are resolved against and errors name.
    pub fn build(&self, config_path: &Path) -> Result<Box<dyn Segmenter>> {
        match self {
            SegmenterConfig::SimTruth { noise, seed } => Ok(Box::new(SimTruth {
                noise: noise.clone(),
                seed: *seed,
                frames: std::sync::atomic::AtomicU64::new(0),
            })),
            SegmenterConfig::Onnx(cfg) => onnx_segmenter(cfg, config_path),
            SegmenterConfig::Builtin {
                min_band_px,
                final_band_px,
            } => {
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
                Ok(Box::new(Builtin {
                    params: BuiltinParams::default(),
                    min_band_px: *min_band_px,
                }))
            }
        }
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
                "--segmenter {other}: unknown segmenter; use builtin"
            )),
        }
    }
}

/// The `builtin` segmenter (see [`builtin`]).
pub struct Builtin {
    params: BuiltinParams,
    /// Smallest prior band, pixels.
    pub min_band_px: f32,
}

impl Segmenter for Builtin {
    fn name(&self) -> &str {
        "builtin"
    }

    fn segment(&self, frame: &Frame) -> Result<Mask> {
        let views = [ViewInput {
            frame,
            prior: None,
            band_px: self.min_band_px,
        }];
        Ok(builtin::segment_views(&views, &self.params)?.remove(0))
    }

    fn segment_views(&self, views: &[ViewInput<'_>]) -> Result<Vec<Mask>> {
        builtin::segment_views(views, &self.params)
    }

    fn uses_context(&self) -> bool {
        true
    }

    /// Change and colour evidence with no prior (the plate from every view).
    fn evidence(&self, frames: &[&Frame]) -> Result<Option<Vec<Vec<f32>>>> {
        let views: Vec<ViewInput> = frames
            .iter()
            .map(|frame| ViewInput {
                frame,
                prior: None,
                band_px: self.min_band_px,
            })
            .collect();
        Ok(Some(
            builtin::segment_views_with_evidence(&views, &self.params)?.1,
        ))
    }
}

/// The model of a `[segmenter] kind = "onnx"` table, loaded and checked.
#[cfg(feature = "onnx")]
fn onnx_segmenter(cfg: &OnnxConfig, config_path: &Path) -> Result<Box<dyn Segmenter>> {
    Ok(Box::new(onnx::OnnxSegmenter::load(cfg, config_path)?))
}

/// Without the `onnx` feature an ONNX segmenter config is an error that says how to get one.
#[cfg(not(feature = "onnx"))]
fn onnx_segmenter(_cfg: &OnnxConfig, config_path: &Path) -> Result<Box<dyn Segmenter>> {
    Err(Error::input(
        config_path,
        "segmenter.kind",
        "\"onnx\" runs the model with tract, which this build leaves out: rebuild with --features onnx",
    ))
}

/// Where a model path in the config at `config_path` points.
pub fn resolve_model_path(config_path: &Path, model: &Path) -> PathBuf {
    config_path.parent().unwrap_or(Path::new(".")).join(model)
}

/// Uses [`Frame::truth_mask`].
pub struct SimTruth {
    noise: Option<crate::synth::NoiseModel>,
    seed: u64,
    frames: std::sync::atomic::AtomicU64,
}

impl Segmenter for SimTruth {
    fn name(&self) -> &str {
        "sim-truth"
    }

    fn segment(&self, frame: &Frame) -> Result<Mask> {
        let Some(truth) = &frame.truth_mask else {
            return Err(Error::Hardware(
                "segmenter 'sim-truth' needs a simulated camera (frames carry no ground-truth mask): set [segmenter] kind for this camera".into(),
            ));
        };
        if truth.len() != (frame.width * frame.height) as usize {
            return Err(Error::Hardware(format!(
                "ground-truth mask has {} pixels for a {}x{} frame",
                truth.len(),
                frame.width,
                frame.height
            )));
        }
        let mask = Mask {
            width: frame.width,
            height: frame.height,
            data: truth.iter().map(|&v| u8::from(v >= 128)).collect(),
        };
        Ok(match &self.noise {
            None => mask,
            Some(noise) => {
                use rand::SeedableRng;
                let n = self
                    .frames
                    .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let mut rng =
                    rand_chacha::ChaCha8Rng::seed_from_u64(self.seed.wrapping_mul(1_000_003) + n);
                crate::synth::apply_mask_noise(&mut rng, &mask, noise)
            }
        })
    }
}

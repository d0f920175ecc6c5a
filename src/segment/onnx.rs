//! `[segmenter] kind = "onnx"`: a segmentation network the user exported to ONNX, run on the
//! CPU by tract (pure Rust: nothing to install, nothing downloaded).
//!
//! The frame is stretched to the model's input size (bilinear), scaled and normalised as the
//! config says, and fed as one image. The chosen output channel becomes a robot score
//! (sigmoid, softmax across channels, or as is), which is stretched back to the frame size
//! (bilinear) and thresholded. Everything that can be checked without a frame (the file, the
//! input rank, channels and size, the output and channel index) is checked at load, so a bad
//! model fails when the cell is built, before any hardware moves.

use std::path::{Path, PathBuf};

use easyhec_drivers::{Frame, MAX_IMAGE_SIDE};
use tract_onnx::prelude::*;
use tract_onnx::tract_hir::infer::{DimFact, Factoid};

use super::Segmenter;
use crate::config::segmenter::{Activation, ChannelOrder, OnnxConfig, PixelRange, TensorLayout};
use crate::error::{Error, Result};
use crate::mask::Mask;

/// Largest model file read, bytes (2 GiB: the protobuf limit of an ONNX file with its weights
/// inside).
const MAX_MODEL_BYTES: u64 = 2 << 30;

/// The runnable model and how to feed and read it.
pub struct OnnxSegmenter {
    model_path: PathBuf,
    plan: TypedSimplePlan<TypedModel>,
    input_width: usize,
    input_height: usize,
    layout: TensorLayout,
    /// Frame channel (0 = red) feeding each model channel.
    source_channel: [usize; 3],
    /// Multiplier from an 8-bit value to the model's pixel range.
    scale: f32,
    mean: [f32; 3],
    std: [f32; 3],
    output: usize,
    channel: usize,
    activation: Activation,
    threshold: f32,
}

/// Shape of one output map: how many channels and how big, and where the channel axis is.
#[derive(Clone, Copy, Debug)]
struct OutputGeometry {
    channels: usize,
    height: usize,
    width: usize,
    channels_last: bool,
}

impl OutputGeometry {
    /// Reads `shape` (`[1,C,H,W]`/`[C,H,W]`/`[H,W]`, or channels last for `nhwc`).
    fn of(shape: &[usize], layout: TensorLayout) -> std::result::Result<Self, String> {
        let last = layout == TensorLayout::Nhwc;
        let dims = match shape {
            [1, a, b, c] | [a, b, c] => [*a, *b, *c],
            [h, w] => {
                return Ok(OutputGeometry {
                    channels: 1,
                    height: *h,
                    width: *w,
                    channels_last: false,
                })
            }
            _ => {
                return Err(format!(
                    "output shape {} is not one image's map ([1,C,H,W], [C,H,W] or [H,W]{})",
                    dims_text(shape),
                    if last { ", channels last" } else { "" }
                ))
            }
        };
        let (channels, height, width) = if last {
            (dims[2], dims[0], dims[1])
        } else {
            (dims[0], dims[1], dims[2])
        };
        Ok(OutputGeometry {
            channels,
            height,
            width,
            channels_last: last,
        })
    }

    /// Index of channel `c` at pixel (`x`, `y`) in the flat output.
    fn index(&self, c: usize, x: usize, y: usize) -> usize {
        if self.channels_last {
            (y * self.width + x) * self.channels + c
        } else {
            (c * self.height + y) * self.width + x
        }
    }
}

/// `1x3x640x480`-style text of a shape.
pub(super) fn dims_text(shape: &[usize]) -> String {
    shape
        .iter()
        .map(|d| d.to_string())
        .collect::<Vec<_>>()
        .join("x")
}

/// A fixed dimension of a declared input, `None` where the model leaves it symbolic.
pub(super) fn fixed(d: &DimFact) -> Option<usize> {
    d.concretize()?.to_i64().ok()?.try_into().ok()
}

/// A tract error as one line.
pub(super) fn one_line(e: &TractError) -> String {
    format!("{e:#}").replace('\n', " ")
}

/// Reads the ONNX file at `model_path` (checked first: a regular file of at most
/// [`MAX_MODEL_BYTES`]) as a model tract can type; errors name `config_path` and `field`.
pub(super) fn read_model(
    model_path: &Path,
    config_path: &Path,
    field: &str,
) -> Result<InferenceModel> {
    let bad = |message: String| Error::input(config_path, field, message);
    let shown = model_path.display();
    let unreadable = std::fs::metadata(model_path)
        .ok()
        .and_then(|meta| crate::io::input_file_problem(&meta, MAX_MODEL_BYTES));
    if let Some(problem) = unreadable {
        return Err(bad(format!("{shown} {problem}")));
    }
    let bytes = match std::fs::read(model_path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(bad(format!(
                "{shown}: no such file (the path is relative to this config)"
            )))
        }
        Err(e) => return Err(Error::io(model_path, e)),
    };
    tract_onnx::onnx()
        .model_for_read(&mut bytes.as_slice())
        .map_err(|e| {
            bad(format!(
                "{shown} is not an ONNX model tract can read ({}): export it with torch.onnx.export (weights inside the file)",
                one_line(&e)
            ))
        })
}

impl OnnxSegmenter {
    /// Loads and checks the model of `cfg`; `config_path` resolves the model path and is the
    /// file errors name.
    pub fn load(cfg: &OnnxConfig, config_path: &Path) -> Result<Self> {
        let bad = |field: &str, message: String| Error::input(config_path, field, message);
        let model_path = super::resolve_model_path(config_path, &cfg.model);
        let shown = model_path.display();
        for (c, (&m, &s)) in cfg.mean.iter().zip(&cfg.std).enumerate() {
            if !m.is_finite() {
                return Err(bad(
                    "segmenter.mean",
                    format!("entry {c} is {m}: give a finite number"),
                ));
            }
            if !s.is_finite() || s == 0.0 {
                return Err(bad(
                    "segmenter.std",
                    format!("entry {c} is {s}: give a finite, non-zero divisor"),
                ));
            }
        }
        if !cfg.threshold.is_finite() {
            return Err(bad(
                "segmenter.threshold",
                format!("{} is not a number: give e.g. 0.5", cfg.threshold),
            ));
        }
        for (field, v) in [
            ("segmenter.input_width", cfg.input_width),
            ("segmenter.input_height", cfg.input_height),
        ] {
            if let Some(v) = v.filter(|&v| v == 0 || v > MAX_IMAGE_SIDE) {
                return Err(bad(
                    field,
                    format!("is {v}: give the model's input size in pixels, 1 to {MAX_IMAGE_SIDE}"),
                ));
            }
        }
        let mut model = read_model(&model_path, config_path, "segmenter.model")?;
        let inputs = model.inputs.len();
        if inputs != 1 {
            return Err(bad(
                "segmenter.model",
                format!("{shown} has {inputs} inputs: the onnx segmenter feeds one image"),
            ));
        }
        let (input_height, input_width) = Self::input_size(&model, cfg, config_path)?;
        let side = MAX_IMAGE_SIDE as usize;
        if input_height > side || input_width > side {
            return Err(bad(
                "segmenter.model",
                format!("{shown} takes a {input_width}x{input_height} input; allowed: sides up to {side}"),
            ));
        }
        let shape = match cfg.layout {
            TensorLayout::Nchw => [1, 3, input_height, input_width],
            TensorLayout::Nhwc => [1, input_height, input_width, 3],
        };
        let cannot_run = |e: TractError| {
            bad(
                "segmenter.model",
                format!(
                    "tract cannot run {shown} on a {} input ({}): check layout and input_width/input_height",
                    dims_text(&shape),
                    one_line(&e)
                ),
            )
        };
        model
            .set_input_fact(0, InferenceFact::dt_shape(f32::datum_type(), shape))
            .map_err(cannot_run)?;
        let typed = model.into_optimized().map_err(cannot_run)?;
        let outputs = typed.outputs.len();
        if cfg.output >= outputs {
            return Err(bad(
                "segmenter.output",
                format!(
                    "output {} is out of range: {shown} has {outputs} output(s) (0..={})",
                    cfg.output,
                    outputs.saturating_sub(1)
                ),
            ));
        }
        if let Some(out) = typed
            .output_fact(cfg.output)
            .ok()
            .and_then(|f| f.shape.as_concrete())
        {
            if let Err((field, message)) = Self::check_output(cfg, out) {
                return Err(bad(field, format!("{shown}: {message}")));
            }
        }
        let plan = typed.into_runnable().map_err(cannot_run)?;
        Ok(OnnxSegmenter {
            model_path: model_path.clone(),
            plan,
            input_width,
            input_height,
            layout: cfg.layout,
            source_channel: match cfg.channel_order {
                ChannelOrder::Rgb => [0, 1, 2],
                ChannelOrder::Bgr => [2, 1, 0],
            },
            scale: match cfg.pixel_range {
                PixelRange::Unit => 1.0 / 255.0,
                PixelRange::Byte => 1.0,
            },
            mean: cfg.mean,
            std: cfg.std,
            output: cfg.output,
            channel: cfg.channel,
            activation: cfg.activation,
            threshold: cfg.threshold,
        })
    }

    /// The model's input (height, width), from its declared input and the config: the rank,
    /// batch and channel count must fit one colour image in `cfg.layout`.
    fn input_size(
        model: &InferenceModel,
        cfg: &OnnxConfig,
        config_path: &Path,
    ) -> Result<(usize, usize)> {
        let bad = |field: &str, message: String| Error::input(config_path, field, message);
        let shown = super::resolve_model_path(config_path, &cfg.model);
        let shown = shown.display();
        let fact = model
            .input_fact(0)
            .map_err(|e| bad("segmenter.model", format!("{shown}: {}", one_line(&e))))?;
        let dims: Vec<Option<usize>> = fact.shape.dims().map(fixed).collect();
        let declared = dims
            .iter()
            .map(|d| d.map_or("?".to_string(), |d| d.to_string()))
            .collect::<Vec<_>>()
            .join("x");
        let wanted = match cfg.layout {
            TensorLayout::Nchw => "1x3xHxW (layout = \"nchw\")",
            TensorLayout::Nhwc => "1xHxWx3 (layout = \"nhwc\")",
        };
        let (mut height, mut width) = (None, None);
        if fact.shape.rank().concretize().is_some() {
            if dims.len() != 4 {
                return Err(bad(
                    "segmenter.model",
                    format!(
                        "{shown} takes a rank-{} input ({declared}): the onnx segmenter feeds one colour image, {wanted}",
                        dims.len()
                    ),
                ));
            }
            let (c, h, w) = match cfg.layout {
                TensorLayout::Nchw => (1, 2, 3),
                TensorLayout::Nhwc => (3, 1, 2),
            };
            if let Some(channels) = dims[c] {
                if channels != 3 {
                    let other = match cfg.layout {
                        TensorLayout::Nchw if dims[3] == Some(3) => {
                            ": the channels look last, set layout = \"nhwc\""
                        }
                        TensorLayout::Nhwc if dims[1] == Some(3) => {
                            ": the channels look first, set layout = \"nchw\""
                        }
                        _ => "",
                    };
                    return Err(bad(
                        "segmenter.model",
                        format!(
                            "{shown} takes {channels} input channel(s) ({declared}), not 3 colour channels: the onnx segmenter feeds {wanted}{other}"
                        ),
                    ));
                }
            }
            if let Some(batch) = dims[0] {
                if batch != 1 {
                    return Err(bad(
                        "segmenter.model",
                        format!(
                            "{shown} takes a batch of {batch} ({declared}): export it with batch 1 or a dynamic batch"
                        ),
                    ));
                }
            }
            (height, width) = (dims[h], dims[w]);
        }
        let pick = |field: &str,
                    key: &str,
                    configured: Option<u32>,
                    declared_dim: Option<usize>| {
            match (configured.map(|v| v as usize), declared_dim) {
                (Some(c), Some(d)) if c != d => Err(bad(
                    field,
                    format!(
                        "is {c} but {shown} takes a fixed {key} of {d} ({declared}): set {d} or leave it out"
                    ),
                )),
                (Some(c), _) => Ok(c),
                (None, Some(d)) => Ok(d),
                (None, None) => Err(bad(
                    field,
                    format!(
                        "{shown} does not fix its input {key} ({declared}): set input_width and input_height to the size it was trained at"
                    ),
                )),
            }
        };
        let width = pick("segmenter.input_width", "width", cfg.input_width, width)?;
        let height = pick("segmenter.input_height", "height", cfg.input_height, height)?;
        Ok((height, width))
    }

    /// Checks a (concrete) output shape against `output`, `channel` and `activation`: the
    /// field at fault and what is wrong.
    fn check_output(
        cfg: &OnnxConfig,
        shape: &[usize],
    ) -> std::result::Result<(), (&'static str, String)> {
        match OutputGeometry::of(shape, cfg.layout) {
            Err(m) => Err(("segmenter.output", m)),
            Ok(g) if cfg.channel >= g.channels => Err((
                "segmenter.channel",
                format!(
                    "channel {} is out of range: output {} ({}) has {} channel(s) (0..={})",
                    cfg.channel,
                    cfg.output,
                    dims_text(shape),
                    g.channels,
                    g.channels - 1
                ),
            )),
            Ok(g) if cfg.activation == Activation::Softmax && g.channels < 2 => Err((
                "segmenter.activation",
                format!(
                    "softmax across 1 channel is always 1: output {} ({}) has one channel, use activation = \"sigmoid\" or \"none\"",
                    cfg.output,
                    dims_text(shape)
                ),
            )),
            Ok(_) => Ok(()),
        }
    }

    /// The frame stretched to the input size, scaled, normalised, in the model's layout.
    fn input_tensor(&self, frame: &Frame) -> Result<Tensor> {
        let (fw, fh) = (frame.width as usize, frame.height as usize);
        let (iw, ih) = (self.input_width, self.input_height);
        let mut data = vec![0f32; 3 * iw * ih];
        let sx = fw as f32 / iw as f32;
        let sy = fh as f32 / ih as f32;
        for y in 0..ih {
            let (y0, y1, ty) = taps((y as f32 + 0.5) * sy - 0.5, fh);
            for x in 0..iw {
                let (x0, x1, tx) = taps((x as f32 + 0.5) * sx - 0.5, fw);
                for (c, &src) in self.source_channel.iter().enumerate() {
                    let p = |xx: usize, yy: usize| f32::from(frame.rgb[(yy * fw + xx) * 3 + src]);
                    let top = p(x0, y0) + (p(x1, y0) - p(x0, y0)) * tx;
                    let bottom = p(x0, y1) + (p(x1, y1) - p(x0, y1)) * tx;
                    let v = (top + (bottom - top) * ty) * self.scale;
                    let i = match self.layout {
                        TensorLayout::Nchw => (c * ih + y) * iw + x,
                        TensorLayout::Nhwc => (y * iw + x) * 3 + c,
                    };
                    data[i] = (v - self.mean[c]) / self.std[c];
                }
            }
        }
        let shape: &[usize] = match self.layout {
            TensorLayout::Nchw => &[1, 3, ih, iw],
            TensorLayout::Nhwc => &[1, ih, iw, 3],
        };
        Tensor::from_shape(shape, &data).map_err(|e| self.failed(&e))
    }

    /// The robot score of the chosen channel at every output pixel.
    fn scores(&self, out: &Tensor) -> Result<(OutputGeometry, Vec<f32>)> {
        let g = OutputGeometry::of(out.shape(), self.layout)
            .map_err(|m| Error::Hardware(format!("segmenter 'onnx' ({}): {m}", self.shown())))?;
        if self.channel >= g.channels {
            return Err(Error::Hardware(format!(
                "segmenter 'onnx' ({}): channel {} is out of range: output {} ({}) has {} channel(s)",
                self.shown(),
                self.channel,
                self.output,
                dims_text(out.shape()),
                g.channels
            )));
        }
        let values = out.cast_to::<f32>().map_err(|e| self.failed(&e))?;
        let v = values.as_slice::<f32>().map_err(|e| self.failed(&e))?;
        let mut scores = Vec::with_capacity(g.width * g.height);
        for y in 0..g.height {
            for x in 0..g.width {
                let own = v[g.index(self.channel, x, y)];
                scores.push(match self.activation {
                    Activation::None => own,
                    Activation::Sigmoid => 1.0 / (1.0 + (-own).exp()),
                    Activation::Softmax => {
                        let all = (0..g.channels).map(|c| v[g.index(c, x, y)]);
                        let max = all.clone().fold(f32::NEG_INFINITY, f32::max);
                        let sum: f32 = all.map(|l| (l - max).exp()).sum();
                        (own - max).exp() / sum
                    }
                });
            }
        }
        Ok((g, scores))
    }

    fn shown(&self) -> String {
        self.model_path.display().to_string()
    }

    /// An inference-time tract failure as one error line.
    fn failed(&self, e: &TractError) -> Error {
        Error::Hardware(format!(
            "segmenter 'onnx' ({}): inference failed: {}",
            self.shown(),
            one_line(e)
        ))
    }
}

/// Bilinear taps along one axis of length `n` at sample position `s` (pixel centres at
/// integers), clamped to the edge.
pub(super) fn taps(s: f32, n: usize) -> (usize, usize, f32) {
    let s = s.clamp(0.0, (n - 1) as f32);
    let i0 = s.floor() as usize;
    let i1 = (i0 + 1).min(n - 1);
    (i0, i1, s - i0 as f32)
}

impl Segmenter for OnnxSegmenter {
    fn name(&self) -> &str {
        "onnx"
    }

    fn segment(&self, frame: &Frame) -> Result<Mask> {
        let (fw, fh) = super::frame_size(frame, "onnx")?;
        let input = self.input_tensor(frame)?;
        let outputs = self
            .plan
            .run(tvec!(input.into_tvalue()))
            .map_err(|e| self.failed(&e))?;
        let out = outputs.get(self.output).ok_or_else(|| {
            Error::Hardware(format!(
                "segmenter 'onnx' ({}): the model returned {} output(s), output {} asked for",
                self.shown(),
                outputs.len(),
                self.output
            ))
        })?;
        let (g, scores) = self.scores(out)?;
        let mut mask = Mask::new(frame.width, frame.height);
        let sx = g.width as f32 / fw as f32;
        let sy = g.height as f32 / fh as f32;
        for y in 0..fh {
            let (y0, y1, ty) = taps((y as f32 + 0.5) * sy - 0.5, g.height);
            for x in 0..fw {
                let (x0, x1, tx) = taps((x as f32 + 0.5) * sx - 0.5, g.width);
                let s = |xx: usize, yy: usize| scores[yy * g.width + xx];
                let top = s(x0, y0) + (s(x1, y0) - s(x0, y0)) * tx;
                let bottom = s(x0, y1) + (s(x1, y1) - s(x0, y1)) * tx;
                if top + (bottom - top) * ty > self.threshold {
                    mask.data[y * fw + x] = 1;
                }
            }
        }
        Ok(mask)
    }
}

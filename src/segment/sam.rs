//! `[segmenter] kind = "sam"`: a SAM-family promptable model the user exported to ONNX (an
//! image encoder and a mask decoder), run on the CPU by tract, and prompted by the cell itself.
//!
//! The good masks the method rests on come, in every published EasyHeC variant, from SAM or
//! SAM 2 prompted by hand. Here the prompt is the silhouette rendered under the current
//! estimate: its bounding box, grown by the band the estimate's uncertainty allows, and its
//! deepest interior pixels as foreground points (deep enough that a pose off by the band still
//! puts them on the robot). The decoder's low-resolution mask is read back into the frame, and
//! whatever lies beyond the band outside the render is background: a second robot or a person
//! inside the box cannot join the mask. A view with no estimate yet (the first round without a
//! guess) is drawn by the `builtin` segmenter, which needs no prompt.
//!
//! Model contract (both SAM's and SAM 2's common exports meet it): the encoder takes one
//! `1x3xSxS` image normalised with ImageNet's mean and deviation on 0–255 RGB; the decoder
//! takes the encoder's outputs by name, `point_coords` (`1xNx2`, pixels of the encoder's
//! square) and `point_labels` (`1xN`: 1 foreground, 2 and 3 a box's corners, -1 padding),
//! optionally `mask_input`, `has_mask_input` and `orig_im_size`, and returns `low_res_masks`
//! (`1xKxLxL` logits over the square; a decoder without `orig_im_size` may call them `masks`,
//! as SAM 2 exports do) and optionally `iou_predictions` (`1xK`). Of SAM's four masks the
//! first is taken (the one SAM itself uses for a box with points), of any other count the one
//! with the highest predicted IoU. Encoder outputs are kept per frame (a few recent frames), so
//! the rounds that draw the same frames again run only the decoder. Everything checkable
//! without a frame is checked when the cell is built.

use std::collections::VecDeque;
use std::hash::{Hash, Hasher};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use easyhec_drivers::Frame;
use tract_onnx::prelude::*;

use super::builtin::signed_distance;
use super::onnx::{dims_text, fixed, one_line, read_model, taps};
use super::{Builtin, Segmenter, ViewInput};
use crate::config::segmenter::{SamConfig, SamResize};
use crate::error::{Error, Result};
use crate::mask::Mask;

/// SAM's normalisation of 0–255 RGB (ImageNet's, scaled).
const PIXEL_MEAN: [f32; 3] = [123.675, 116.28, 103.53];
const PIXEL_STD: [f32; 3] = [58.395, 57.12, 57.375];

/// How far inside the render an interior point must lie beyond the band, pixels.
const POINT_MARGIN_PX: f32 = 2.0;

/// Frames whose encoder outputs are kept: a loop's views, drawn again each round (SAM 2's
/// outputs are about 16 MB a frame).
const CACHED_FRAMES: usize = 16;

/// SAM's mask count with its single-mask token first (`export_onnx_model.py` without
/// `--return-single-mask`).
const SAM_MASKS_WITH_SINGLE_TOKEN: usize = 4;

/// What the decoder is fed at one of its inputs.
#[derive(Clone, Copy, Debug, PartialEq)]
enum DecoderInput {
    /// The encoder's output of this index.
    Embedding(usize),
    PointCoords,
    PointLabels,
    MaskInput,
    HasMaskInput,
    OrigImSize,
}

/// The loaded encoder and decoder and how to prompt them.
pub struct SamSegmenter {
    encoder_path: PathBuf,
    decoder_path: PathBuf,
    encoder: TypedSimplePlan<TypedModel>,
    /// The encoder's square input side, pixels.
    side: usize,
    decoder: TypedSimplePlan<TypedModel>,
    /// What each decoder input is, in the decoder's order.
    decoder_inputs: Vec<DecoderInput>,
    /// `mask_input`'s declared shape (fed zeros), when the decoder takes it.
    mask_input_shape: Vec<usize>,
    /// Whether the decoder's second output is `iou_predictions`.
    has_iou: bool,
    resize: SamResize,
    /// Interior points per prompt (the box's two corners come besides).
    points: usize,
    threshold: f32,
    /// Draws views that have no estimate to prompt from.
    fallback: Builtin,
    /// Recent frames' encoder outputs, by the frame's content, newest last.
    embedded: Mutex<VecDeque<(u64, Vec<Arc<Tensor>>)>>,
}

/// Which of the two models a failure came from.
#[derive(Clone, Copy)]
enum Half {
    Encoder,
    Decoder,
}

/// A prompt in frame pixels: the box's corners, then interior points.
#[derive(Clone, Debug, PartialEq)]
pub struct Prompt {
    /// Top-left and bottom-right corners of the box, `[x, y]`.
    pub corners: [[f32; 2]; 2],
    /// Foreground points, `[x, y]`, deepest first.
    pub points: Vec<[f32; 2]>,
}

impl SamSegmenter {
    /// Loads and checks both models of `cfg`; `config_path` resolves their paths and is the
    /// file errors name. `fallback` draws views with no estimate.
    pub fn load(cfg: &SamConfig, config_path: &Path, fallback: Builtin) -> Result<Self> {
        let encoder_path = super::resolve_model_path(config_path, &cfg.encoder);
        let decoder_path = super::resolve_model_path(config_path, &cfg.decoder);
        let (encoder, side, embeddings) = load_encoder(&encoder_path, config_path)?;
        let decoder_model = read_model(&decoder_path, config_path, "segmenter.decoder")?;
        let points = cfg.points as usize;
        let wiring = Wiring::of(&decoder_model, &embeddings, &decoder_path, config_path)?;
        let (decoder, has_iou) = wiring.plan(
            decoder_model,
            &embeddings,
            2 + points,
            &decoder_path,
            config_path,
        )?;
        Ok(SamSegmenter {
            encoder_path,
            decoder_path,
            encoder,
            side,
            decoder,
            decoder_inputs: wiring.inputs,
            mask_input_shape: wiring.mask_input_shape,
            has_iou,
            resize: cfg.resize,
            points,
            threshold: cfg.threshold,
            fallback,
            embedded: Mutex::new(VecDeque::new()),
        })
    }

    /// The mask of one frame, prompted by `prior` (the render under the estimate, the frame's
    /// size) with a band of `band_px`.
    fn prompted(&self, frame: &Frame, prior: &Mask, band_px: f32) -> Result<Mask> {
        let (w, h) = super::frame_size(frame, "sam")?;
        if (prior.width, prior.height) != (frame.width, frame.height) {
            return Err(Error::Hardware(format!(
                "segmenter 'sam': the prior is {}x{}, the frame {w}x{h}",
                prior.width, prior.height
            )));
        }
        let depth = signed_distance(prior, w, h);
        let Some(prompt) = prompt_of(&depth, w, h, band_px, self.points) else {
            // The robot is not in view under the estimate: nothing to prompt for.
            return Ok(Mask::new(frame.width, frame.height));
        };
        let fit = Fit::of(w, h, self.side, self.resize);
        let embeddings = self.embeddings(frame, &fit)?;
        let inputs = self.decoder_feed(&embeddings, &prompt, &fit, w, h)?;
        let outputs = self
            .decoder
            .run(inputs)
            .map_err(|e| self.failed(Half::Decoder, &e))?;
        let logits = self.best_mask(&outputs)?;
        let mut mask = logits.sampled(&fit, w, h, self.threshold);
        for (m, &d) in mask.data.iter_mut().zip(&depth) {
            if d <= -band_px {
                *m = 0;
            }
        }
        Ok(mask)
    }

    /// The encoder's outputs for `frame`: kept from an earlier round when the same frame was
    /// drawn, else computed (and kept, the oldest dropped past [`CACHED_FRAMES`]).
    fn embeddings(&self, frame: &Frame, fit: &Fit) -> Result<Vec<Arc<Tensor>>> {
        let mut hasher = std::collections::hash_map::DefaultHasher::new();
        (frame.width, frame.height, &frame.rgb).hash(&mut hasher);
        let key = hasher.finish();
        let kept = |cache: &VecDeque<(u64, Vec<Arc<Tensor>>)>| {
            cache
                .iter()
                .find(|(k, _)| *k == key)
                .map(|(_, v)| v.clone())
        };
        if let Some(found) = self.embedded.lock().ok().and_then(|c| kept(&c)) {
            return Ok(found);
        }
        let outputs = self
            .encoder
            .run(tvec!(self.encoder_input(frame, fit)?.into_tvalue()))
            .map_err(|e| self.failed(Half::Encoder, &e))?
            .into_iter()
            .map(TValue::into_arc_tensor)
            .collect::<Vec<_>>();
        if let Ok(mut cache) = self.embedded.lock() {
            if cache.len() >= CACHED_FRAMES {
                cache.pop_front();
            }
            cache.push_back((key, outputs.clone()));
        }
        Ok(outputs)
    }

    /// The frame fitted to the encoder's square and normalised, `1x3xSxS`.
    fn encoder_input(&self, frame: &Frame, fit: &Fit) -> Result<Tensor> {
        let (w, h, s) = (frame.width as usize, frame.height as usize, self.side);
        let mut data = vec![0f32; 3 * s * s];
        for v in 0..fit.height {
            let (y0, y1, ty) = taps((v as f32 + 0.5) / fit.sy - 0.5, h);
            for u in 0..fit.width {
                let (x0, x1, tx) = taps((u as f32 + 0.5) / fit.sx - 0.5, w);
                for c in 0..3 {
                    let p = |xx: usize, yy: usize| f32::from(frame.rgb[(yy * w + xx) * 3 + c]);
                    let top = p(x0, y0) + (p(x1, y0) - p(x0, y0)) * tx;
                    let bottom = p(x0, y1) + (p(x1, y1) - p(x0, y1)) * tx;
                    let value = top + (bottom - top) * ty;
                    data[(c * s + v) * s + u] = (value - PIXEL_MEAN[c]) / PIXEL_STD[c];
                }
            }
        }
        Tensor::from_shape(&[1, 3, s, s], &data).map_err(|e| self.failed(Half::Encoder, &e))
    }

    /// The decoder's inputs, in its order: the encoder's outputs and the prompt.
    fn decoder_feed(
        &self,
        embeddings: &[Arc<Tensor>],
        prompt: &Prompt,
        fit: &Fit,
        w: usize,
        h: usize,
    ) -> Result<TVec<TValue>> {
        let n = 2 + self.points;
        let (coords, labels) = prompt_tensors(prompt, fit, n);
        let tensor = |shape: &[usize], data: &[f32]| {
            Tensor::from_shape(shape, data).map_err(|e| self.failed(Half::Decoder, &e))
        };
        let mut feed = TVec::new();
        for input in &self.decoder_inputs {
            let value = match *input {
                DecoderInput::Embedding(k) => embeddings
                    .get(k)
                    .cloned()
                    .map(TValue::from_const)
                    .ok_or_else(|| self.missing_embedding(k, embeddings.len()))?,
                DecoderInput::PointCoords => tensor(&[1, n, 2], &coords)?.into_tvalue(),
                DecoderInput::PointLabels => tensor(&[1, n], &labels)?.into_tvalue(),
                DecoderInput::MaskInput => {
                    let len = self.mask_input_shape.iter().product();
                    tensor(&self.mask_input_shape, &vec![0.0; len])?.into_tvalue()
                }
                DecoderInput::HasMaskInput => tensor(&[1], &[0.0])?.into_tvalue(),
                DecoderInput::OrigImSize => tensor(&[2], &[h as f32, w as f32])?.into_tvalue(),
            };
            feed.push(value);
        }
        Ok(feed)
    }

    /// The decoder's mask logits: SAM's single-mask token of four, else the one with the
    /// highest predicted IoU (the first without a score).
    fn best_mask(&self, outputs: &TVec<TValue>) -> Result<LowRes> {
        let bad = |what: String| {
            Error::Hardware(format!(
                "segmenter 'sam' ({}): {what}",
                self.decoder_path.display()
            ))
        };
        let masks = outputs
            .first()
            .ok_or_else(|| bad("the decoder returned no output".into()))?;
        let shape = masks.shape().to_vec();
        let [1, k, l_h, l_w] = shape[..] else {
            return Err(bad(format!(
                "the decoder's masks are {}, not 1xKxLxL",
                dims_text(&shape)
            )));
        };
        if k == 0 || l_h == 0 || l_w == 0 {
            return Err(bad(format!(
                "the decoder's masks are {}: empty",
                dims_text(&shape)
            )));
        }
        let values = self.floats(masks)?;
        let mut best = 0;
        if self.has_iou && k != SAM_MASKS_WITH_SINGLE_TOKEN {
            if let Some(scores) = outputs.get(1) {
                let scores = self.floats(scores)?;
                best = (0..k.min(scores.len()))
                    .max_by(|&a, &b| scores[a].total_cmp(&scores[b]))
                    .unwrap_or(0);
            }
        }
        let plane = l_h * l_w;
        Ok(LowRes {
            width: l_w,
            height: l_h,
            logits: values[best * plane..(best + 1) * plane].to_vec(),
            side: self.side,
        })
    }

    /// A decoder output's values as `f32`, in order.
    fn floats(&self, value: &TValue) -> Result<Vec<f32>> {
        let cast = value
            .cast_to::<f32>()
            .map_err(|e| self.failed(Half::Decoder, &e))?;
        cast.as_slice::<f32>()
            .map(<[f32]>::to_vec)
            .map_err(|e| self.failed(Half::Decoder, &e))
    }

    fn missing_embedding(&self, k: usize, returned: usize) -> Error {
        Error::Hardware(format!(
            "segmenter 'sam' ({}): the encoder returned {returned} output(s), the decoder needs output {k}",
            self.decoder_path.display()
        ))
    }

    /// An inference-time tract failure as one error line, naming the model's file.
    fn failed(&self, half: Half, e: &TractError) -> Error {
        let (name, path) = match half {
            Half::Encoder => ("encoder", &self.encoder_path),
            Half::Decoder => ("decoder", &self.decoder_path),
        };
        Error::Hardware(format!(
            "segmenter 'sam' ({}): {name} failed: {}",
            path.display(),
            one_line(e)
        ))
    }
}

impl Segmenter for SamSegmenter {
    fn name(&self) -> &str {
        "sam"
    }

    /// One frame with no estimate has nothing to prompt from.
    fn segment(&self, _frame: &Frame) -> Result<Mask> {
        Err(Error::Hardware(
            "segmenter 'sam' prompts from the robot rendered under an estimate: give the cell a [calibration] initial_guess (or the run an initial_guess)".into(),
        ))
    }

    fn segment_views(&self, views: &[ViewInput<'_>]) -> Result<Vec<Mask>> {
        let drawn = if views.iter().any(|v| v.prior.is_none()) {
            self.fallback.segment_views(views)?
        } else {
            Vec::new()
        };
        views
            .iter()
            .enumerate()
            .map(|(i, v)| match (v.prior, drawn.get(i)) {
                (Some(prior), _) => self.prompted(v.frame, prior, v.band_px),
                (None, Some(mask)) => Ok(mask.clone()),
                (None, None) => self.segment(v.frame),
            })
            .collect()
    }

    /// Better estimates make better prompts, and the first views are drawn without one.
    fn uses_context(&self) -> bool {
        true
    }
}

/// The encoder loaded for a `1x3xSxS` input: its plan, `S`, and its outputs' names and
/// shapes.
type Encoder = (
    TypedSimplePlan<TypedModel>,
    usize,
    Vec<(String, Vec<usize>)>,
);

fn load_encoder(path: &Path, config_path: &Path) -> Result<Encoder> {
    let bad = |message: String| Error::input(config_path, "segmenter.encoder", message);
    let shown = path.display();
    let mut model = read_model(path, config_path, "segmenter.encoder")?;
    if model.inputs.len() != 1 {
        return Err(bad(format!(
            "{shown} has {} inputs: a SAM encoder takes one image",
            model.inputs.len()
        )));
    }
    let fact = model
        .input_fact(0)
        .map_err(|e| bad(format!("{shown}: {}", one_line(&e))))?;
    let dims: Vec<Option<usize>> = fact.shape.dims().map(fixed).collect();
    let side = match dims[..] {
        [None | Some(1), Some(3), Some(a), Some(b)] if a == b && a > 0 && a <= 4096 => a,
        _ => {
            let declared: Vec<String> = dims
                .iter()
                .map(|d| d.map_or("?".into(), |d| d.to_string()))
                .collect();
            let declared = if declared.is_empty() {
                "an input of unknown rank".to_string()
            } else {
                format!("a {} input", declared.join("x"))
            };
            return Err(bad(format!(
                "{shown} takes {declared}: a SAM encoder takes a fixed square 1x3xSxS image (S up to 4096); export it with its input size fixed"
            )));
        }
    };
    let names: Vec<String> = model
        .outputs
        .iter()
        .map(|&o| {
            model
                .outlet_label(o)
                .map_or_else(|| model.node(o.node).name.clone(), str::to_string)
        })
        .collect();
    let cannot_run = |e: TractError| {
        bad(format!(
            "tract cannot run {shown} on a 1x3x{side}x{side} input ({})",
            one_line(&e)
        ))
    };
    model
        .set_input_fact(
            0,
            InferenceFact::dt_shape(f32::datum_type(), [1, 3, side, side]),
        )
        .map_err(cannot_run)?;
    let typed = model.into_optimized().map_err(cannot_run)?;
    let mut outputs = Vec::with_capacity(names.len());
    for (k, name) in names.into_iter().enumerate() {
        let shape = typed
            .output_fact(k)
            .ok()
            .and_then(|f| f.shape.as_concrete().map(<[usize]>::to_vec))
            .ok_or_else(|| {
                bad(format!(
                    "{shown}: the shape of output '{name}' is not fixed"
                ))
            })?;
        outputs.push((name, shape));
    }
    let plan = typed.into_runnable().map_err(cannot_run)?;
    Ok((plan, side, outputs))
}

/// How the decoder's inputs are fed, read from its declared inputs.
struct Wiring {
    inputs: Vec<DecoderInput>,
    mask_input_shape: Vec<usize>,
}

impl Wiring {
    /// Classifies every decoder input by name; `embeddings` are the encoder's outputs.
    fn of(
        model: &InferenceModel,
        embeddings: &[(String, Vec<usize>)],
        path: &Path,
        config_path: &Path,
    ) -> Result<Self> {
        let bad = |message: String| Error::input(config_path, "segmenter.decoder", message);
        let shown = path.display();
        let mut inputs = Vec::new();
        let mut mask_input_shape = Vec::new();
        for (ix, outlet) in model.inputs.iter().enumerate() {
            let name = model.node(outlet.node).name.as_str();
            let input = match name {
                "point_coords" => DecoderInput::PointCoords,
                "point_labels" => DecoderInput::PointLabels,
                "mask_input" => DecoderInput::MaskInput,
                "has_mask_input" => DecoderInput::HasMaskInput,
                "orig_im_size" => DecoderInput::OrigImSize,
                _ => match embeddings.iter().position(|(n, _)| n == name) {
                    Some(k) => DecoderInput::Embedding(k),
                    None => {
                        let names: Vec<&str> = embeddings.iter().map(|(n, _)| n.as_str()).collect();
                        return Err(bad(format!(
                            "{shown} takes an input '{name}' that is neither an encoder output ({}) nor a prompt (point_coords, point_labels, mask_input, has_mask_input, orig_im_size)",
                            names.join(", ")
                        )));
                    }
                },
            };
            if input == DecoderInput::MaskInput {
                let fact = model
                    .input_fact(ix)
                    .map_err(|e| bad(format!("{shown}: {}", one_line(&e))))?;
                // A leading dimension left symbolic (SAM 2 exports: the prompt count) is one.
                let dims: Option<Vec<usize>> = fact
                    .shape
                    .dims()
                    .enumerate()
                    .map(|(k, d)| fixed(d).or((k == 0).then_some(1)))
                    .collect();
                mask_input_shape = dims.filter(|d| !d.is_empty()).ok_or_else(|| {
                    bad(format!(
                        "{shown}: mask_input has no fixed shape: export it with one (SAM: 1x1x256x256)"
                    ))
                })?;
            }
            inputs.push(input);
        }
        for needed in [DecoderInput::PointCoords, DecoderInput::PointLabels] {
            if !inputs.contains(&needed) {
                let name = if needed == DecoderInput::PointCoords {
                    "point_coords"
                } else {
                    "point_labels"
                };
                return Err(bad(format!(
                    "{shown} has no input '{name}': a SAM decoder is prompted through point_coords and point_labels"
                )));
            }
        }
        Ok(Wiring {
            inputs,
            mask_input_shape,
        })
    }

    /// The decoder typed for `n` prompt points and pruned to `low_res_masks` (and
    /// `iou_predictions` when it has one); whether it has the scores.
    fn plan(
        &self,
        mut model: InferenceModel,
        embeddings: &[(String, Vec<usize>)],
        n: usize,
        path: &Path,
        config_path: &Path,
    ) -> Result<(TypedSimplePlan<TypedModel>, bool)> {
        let bad = |message: String| Error::input(config_path, "segmenter.decoder", message);
        let shown = path.display();
        let cannot_run = |e: TractError| {
            bad(format!(
                "tract cannot run {shown} with {n} prompt points ({})",
                one_line(&e)
            ))
        };
        for (ix, input) in self.inputs.iter().enumerate() {
            let shape: Vec<usize> = match *input {
                DecoderInput::Embedding(k) => embeddings[k].1.clone(),
                DecoderInput::PointCoords => vec![1, n, 2],
                DecoderInput::PointLabels => vec![1, n],
                DecoderInput::MaskInput => self.mask_input_shape.clone(),
                DecoderInput::HasMaskInput => vec![1],
                DecoderInput::OrigImSize => vec![2],
            };
            model
                .set_input_fact(ix, InferenceFact::dt_shape(f32::datum_type(), shape))
                .map_err(cannot_run)?;
        }
        // Without `orig_im_size` a decoder's `masks` can only cover the square (SAM 2).
        let names: &[&str] = if self.inputs.contains(&DecoderInput::OrigImSize) {
            &["low_res_masks"]
        } else {
            &["low_res_masks", "masks"]
        };
        let Some(masks) = names.iter().find(|n| model.set_output_names([**n]).is_ok()) else {
            return Err(bad(format!(
                "{shown} has no output 'low_res_masks'{}: a SAM decoder returns its masks' logits over the encoder's square under that name",
                if names.len() > 1 { " or 'masks'" } else { "" }
            )));
        };
        let has_iou = model.set_output_names([*masks, "iou_predictions"]).is_ok();
        if !has_iou {
            model.set_output_names([*masks]).map_err(cannot_run)?;
        }
        let typed = model.into_optimized().map_err(cannot_run)?;
        if let Some(shape) = typed
            .output_fact(0)
            .ok()
            .and_then(|f| f.shape.as_concrete())
        {
            if !matches!(shape, [1, k, h, w] if *k > 0 && *h > 0 && *w > 0) {
                return Err(bad(format!(
                    "{shown}: {masks} is {}, not 1xKxLxL",
                    dims_text(shape)
                )));
            }
        }
        Ok((typed.into_runnable().map_err(cannot_run)?, has_iou))
    }
}

/// Where a frame lies in the encoder's square: its scaled size there and the scales.
#[derive(Clone, Copy, Debug)]
pub struct Fit {
    width: usize,
    height: usize,
    sx: f32,
    sy: f32,
}

impl Fit {
    /// A `w`x`h` frame in a square of `side`, as `resize` says.
    pub fn of(w: usize, h: usize, side: usize, resize: SamResize) -> Fit {
        let (width, height) = match resize {
            SamResize::Stretch => (side, side),
            SamResize::LongestSide => {
                let scale = side as f64 / w.max(h) as f64;
                let fitted = |n: usize| ((n as f64 * scale).round() as usize).clamp(1, side);
                (fitted(w), fitted(h))
            }
        };
        Fit {
            width,
            height,
            sx: width as f32 / w as f32,
            sy: height as f32 / h as f32,
        }
    }

    /// A frame pixel position in the square's pixels (pixel centres at integers in both).
    pub fn in_square(&self, [x, y]: [f32; 2]) -> [f32; 2] {
        [(x + 0.5) * self.sx - 0.5, (y + 0.5) * self.sy - 0.5]
    }
}

/// One mask's logits over the encoder's square.
struct LowRes {
    width: usize,
    height: usize,
    logits: Vec<f32>,
    side: usize,
}

impl LowRes {
    /// The frame's mask: each pixel's logit, bilinear at its place in the square, over
    /// `threshold`.
    fn sampled(&self, fit: &Fit, w: usize, h: usize, threshold: f32) -> Mask {
        let mut mask = Mask::new(w as u32, h as u32);
        let (cx, cy) = (
            self.width as f32 / self.side as f32,
            self.height as f32 / self.side as f32,
        );
        for y in 0..h {
            let v = (y as f32 + 0.5) * fit.sy - 0.5;
            let (y0, y1, ty) = taps((v + 0.5) * cy - 0.5, self.height);
            for x in 0..w {
                let u = (x as f32 + 0.5) * fit.sx - 0.5;
                let (x0, x1, tx) = taps((u + 0.5) * cx - 0.5, self.width);
                let l = |xx: usize, yy: usize| self.logits[yy * self.width + xx];
                let top = l(x0, y0) + (l(x1, y0) - l(x0, y0)) * tx;
                let bottom = l(x0, y1) + (l(x1, y1) - l(x0, y1)) * tx;
                if top + (bottom - top) * ty > threshold {
                    mask.data[y * w + x] = 1;
                }
            }
        }
        mask
    }
}

/// `prompt`'s `point_coords` and `point_labels` for `n` points, in the encoder's square: the
/// box's corners (labels 2 and 3), the interior points (1), then padding (-1, which SAM's
/// prompt encoder ignores) up to `n`.
pub fn prompt_tensors(prompt: &Prompt, fit: &Fit, n: usize) -> (Vec<f32>, Vec<f32>) {
    let mut coords = Vec::with_capacity(2 * n);
    let mut labels = Vec::with_capacity(n);
    for (corner, label) in prompt.corners.iter().zip([2.0, 3.0]) {
        coords.extend(fit.in_square(*corner));
        labels.push(label);
    }
    for p in prompt.points.iter().take(n.saturating_sub(2)) {
        coords.extend(fit.in_square(*p));
        labels.push(1.0);
    }
    while labels.len() < n {
        coords.extend([0.0, 0.0]);
        labels.push(-1.0);
    }
    (coords, labels)
}

/// The prompt of a render whose signed distance (positive inside, pixels) is `depth`: its
/// bounding box grown by `band_px` and clamped to the frame, and up to `points` interior
/// points at least the band plus [`POINT_MARGIN_PX`] deep, each the deepest pixel farther
/// than twice its own depth from those already taken. `None` for an empty render.
pub fn prompt_of(depth: &[f32], w: usize, h: usize, band_px: f32, points: usize) -> Option<Prompt> {
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
    for (i, _) in depth.iter().enumerate().filter(|(_, &d)| d > 0.0) {
        let (x, y) = (i % w, i / w);
        (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
    }
    if x0 == usize::MAX {
        return None;
    }
    let grow = band_px.max(0.0);
    let corners = [
        [(x0 as f32 - grow).max(0.0), (y0 as f32 - grow).max(0.0)],
        [
            (x1 as f32 + grow).min((w - 1) as f32),
            (y1 as f32 + grow).min((h - 1) as f32),
        ],
    ];
    let deep_enough = grow + POINT_MARGIN_PX;
    let mut taken: Vec<([f32; 2], f32)> = Vec::with_capacity(points);
    while taken.len() < points {
        let best = depth
            .iter()
            .enumerate()
            .filter(|(_, &d)| d >= deep_enough)
            .map(|(i, &d)| ([(i % w) as f32, (i / w) as f32], d))
            .filter(|(p, _)| {
                taken
                    .iter()
                    .all(|(q, dq)| (p[0] - q[0]).hypot(p[1] - q[1]) > 2.0 * dq)
            })
            .max_by(|a, b| a.1.total_cmp(&b.1));
        match best {
            Some(point) => taken.push(point),
            None => break,
        }
    }
    Some(Prompt {
        corners,
        points: taken.into_iter().map(|(p, _)| p).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Signed distances of a `w`x`h` frame with a filled rectangle (a crude but exact-enough
    /// render for the prompt's geometry).
    fn rectangle_depth(w: usize, h: usize, x0: usize, y0: usize, x1: usize, y1: usize) -> Vec<f32> {
        let mut mask = Mask::new(w as u32, h as u32);
        for y in y0..=y1 {
            for x in x0..=x1 {
                mask.data[y * w + x] = 1;
            }
        }
        signed_distance(&mask, w, h)
    }

    #[test]
    fn the_box_is_the_render_grown_by_the_band_and_kept_in_the_frame() {
        let depth = rectangle_depth(100, 80, 10, 20, 59, 29);
        let p = prompt_of(&depth, 100, 80, 15.0, 0).unwrap();
        assert_eq!(p.corners, [[0.0, 5.0], [74.0, 44.0]]);
        assert!(p.points.is_empty());
        assert!(prompt_of(&vec![-1.0; 100 * 80], 100, 80, 4.0, 3).is_none());
    }

    #[test]
    fn interior_points_are_deep_and_spread_and_none_where_the_render_is_thin() {
        // A 60x20 bar: its deepest pixels run along the middle row, 10 px deep.
        let depth = rectangle_depth(100, 60, 20, 20, 79, 39);
        let p = prompt_of(&depth, 100, 60, 4.0, 3).unwrap();
        assert!(!p.points.is_empty(), "{p:?}");
        for (k, a) in p.points.iter().enumerate() {
            let d = depth[a[1] as usize * 100 + a[0] as usize];
            assert!(d >= 4.0 + POINT_MARGIN_PX, "point {a:?} only {d} px deep");
            for b in &p.points[k + 1..] {
                assert!((a[0] - b[0]).hypot(a[1] - b[1]) > 2.0 * d - 1e-3, "{p:?}");
            }
        }
        // With a band wider than the bar is deep, no point is sure to be on the robot.
        let thin = prompt_of(&depth, 100, 60, 9.0, 3).unwrap();
        assert!(thin.points.is_empty(), "{thin:?}");
    }

    #[test]
    fn the_prompt_goes_in_as_box_corners_then_points_then_padding() {
        let fit = Fit::of(200, 100, 64, SamResize::LongestSide);
        let prompt = Prompt {
            corners: [[10.0, 20.0], [59.0, 44.0]],
            points: vec![[30.0, 30.0]],
        };
        let (coords, labels) = prompt_tensors(&prompt, &fit, 4);
        assert_eq!(labels, vec![2.0, 3.0, 1.0, -1.0]);
        let square = |x: f32| (x + 0.5) * 0.32 - 0.5;
        let expected = [
            square(10.0),
            square(20.0),
            square(59.0),
            square(44.0),
            square(30.0),
            square(30.0),
            0.0,
            0.0,
        ];
        for (got, want) in coords.iter().zip(expected) {
            assert!((got - want).abs() < 1e-5, "{coords:?}");
        }
        // More points than the model takes are cut, never overflowing its shape.
        let (coords, labels) = prompt_tensors(&prompt, &fit, 2);
        assert_eq!((coords.len(), labels), (4, vec![2.0, 3.0]));
    }

    #[test]
    fn the_square_holds_the_frame_as_each_resize_says() {
        let fit = Fit::of(200, 100, 64, SamResize::LongestSide);
        assert_eq!((fit.width, fit.height), (64, 32));
        // Pixel centres map to pixel centres: the first pixel's centre lies a scale's half
        // pixel in, and the frame's outer edge on the content's edge.
        let [u, v] = fit.in_square([0.0, 0.0]);
        assert!((u - (0.5 * 0.32 - 0.5)).abs() < 1e-6, "{u}");
        assert!((v - (0.5 * 0.32 - 0.5)).abs() < 1e-6, "{v}");
        let [u, v] = fit.in_square([199.5, 99.5]);
        assert!(
            (u - 63.5).abs() < 1e-4 && (v - 31.5).abs() < 1e-4,
            "{u} {v}"
        );
        let fit = Fit::of(200, 100, 64, SamResize::Stretch);
        assert_eq!((fit.width, fit.height), (64, 64));
        let [u, v] = fit.in_square([199.5, 99.5]);
        assert!(
            (u - 63.5).abs() < 1e-4 && (v - 63.5).abs() < 1e-4,
            "{u} {v}"
        );
    }
}

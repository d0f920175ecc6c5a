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

mod cache;
mod models;
mod prompt;
mod resample;

pub use prompt::{prompt_of, prompt_tensors, Fit, Prompt};

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use easyhec_drivers::Frame;
use tract_onnx::prelude::*;

use super::builtin::signed_distance;
use super::onnx::{dims_text, one_line};
use super::{Builtin, Segmenter, ViewInput};
use crate::config::segmenter::{SamConfig, SamResize};
use crate::error::{Error, Result};
use crate::mask::Mask;
use cache::{frame_key, RecentlyUsed};
use models::{Decoder, DecoderInput, Encoder};
use prompt::LowRes;

/// SAM's normalisation of 0–255 RGB (ImageNet's, scaled).
const PIXEL_MEAN: [f32; 3] = [123.675, 116.28, 103.53];
const PIXEL_STD: [f32; 3] = [58.395, 57.12, 57.375];

/// Frames whose encoder outputs are kept: a loop's views, drawn again each round, or a bump
/// check's recorded views (SAM 2's outputs are about 16 MB a frame).
const CACHED_FRAMES: usize = 16;

/// SAM's mask count with its single-mask token first (`export_onnx_model.py` without
/// `--return-single-mask`).
const SAM_MASKS_WITH_SINGLE_TOKEN: usize = 4;

/// The loaded encoder and decoder and how to prompt them.
pub struct SamSegmenter {
    encoder_path: PathBuf,
    decoder_path: PathBuf,
    encoder: Encoder,
    decoder: Decoder,
    resize: SamResize,
    /// Interior points per prompt (the box's two corners come besides).
    points: usize,
    threshold: f32,
    /// Draws views that have no estimate to prompt from.
    fallback: Builtin,
    /// Recent frames' encoder outputs, by the frame's content.
    encoder_cache: Mutex<RecentlyUsed<Vec<Arc<Tensor>>>>,
}

/// Which of the two models a failure came from.
#[derive(Clone, Copy)]
enum Model {
    Encoder,
    Decoder,
}

impl SamSegmenter {
    /// Loads and checks both models of `cfg`; `config_path` resolves their paths and is the
    /// file errors name. `fallback` draws views with no estimate.
    pub fn load(cfg: &SamConfig, config_path: &Path, fallback: Builtin) -> Result<Self> {
        let encoder_path = super::resolve_model_path(config_path, &cfg.encoder);
        let decoder_path = super::resolve_model_path(config_path, &cfg.decoder);
        let encoder = Encoder::load(&encoder_path, config_path)?;
        let points = cfg.points as usize;
        let decoder = Decoder::load(&decoder_path, config_path, &encoder.outputs, 2 + points)?;
        Ok(SamSegmenter {
            encoder_path,
            decoder_path,
            encoder,
            decoder,
            resize: cfg.resize,
            points,
            threshold: cfg.threshold,
            fallback,
            encoder_cache: Mutex::new(RecentlyUsed::new(CACHED_FRAMES)),
        })
    }

    /// The mask of one frame, prompted by `prior` (the render under the estimate, the frame's
    /// size) with a band of `band_px`.
    fn prompted(&self, frame: &Frame, prior: &Mask, band_px: f32) -> Result<Mask> {
        let (w, h) = super::frame_size(frame, "sam")?;
        let band_px = band_px.max(0.0);
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
        let fit = Fit::of(w, h, self.encoder.side, self.resize);
        let embeddings = self.embeddings(frame, &fit)?;
        let inputs = self.decoder_feed(&embeddings, &prompt, &fit, w, h)?;
        let outputs = self
            .decoder
            .plan
            .run(inputs)
            .map_err(|e| self.failed(Model::Decoder, &e))?;
        let logits = self.best_mask(&outputs)?;
        let mut mask = logits.sampled(&fit, w, h, self.threshold);
        for (m, &d) in mask.data.iter_mut().zip(&depth) {
            if d <= -band_px {
                *m = 0;
            }
        }
        Ok(mask)
    }

    /// The encoder's outputs for `frame`: those kept from an earlier draw of the same frame,
    /// or computed and kept.
    fn embeddings(&self, frame: &Frame, fit: &Fit) -> Result<Vec<Arc<Tensor>>> {
        let key = frame_key(frame);
        if let Some(found) = self.encoder_cache.lock().ok().and_then(|mut c| c.get(key)) {
            return Ok(found);
        }
        let outputs: Vec<Arc<Tensor>> = self
            .encoder
            .plan
            .run(tvec!(self.encoder_input(frame, fit)?.into_tvalue()))
            .map_err(|e| self.failed(Model::Encoder, &e))?
            .into_iter()
            .map(TValue::into_arc_tensor)
            .collect();
        if let Ok(mut cache) = self.encoder_cache.lock() {
            cache.insert(key, outputs.clone());
        }
        Ok(outputs)
    }

    /// The frame fitted to the encoder's square and normalised, `1x3xSxS`.
    fn encoder_input(&self, frame: &Frame, fit: &Fit) -> Result<Tensor> {
        let (w, h, s) = (
            frame.width as usize,
            frame.height as usize,
            self.encoder.side,
        );
        let planes = resample::resized_planes(&frame.rgb, w, h, fit.width, fit.height);
        let mut data = vec![0f32; 3 * s * s];
        for (c, plane) in planes.iter().enumerate() {
            for v in 0..fit.height {
                for u in 0..fit.width {
                    let value = plane[v * fit.width + u];
                    data[(c * s + v) * s + u] = (value - PIXEL_MEAN[c]) / PIXEL_STD[c];
                }
            }
        }
        Tensor::from_shape(&[1, 3, s, s], &data).map_err(|e| self.failed(Model::Encoder, &e))
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
            Tensor::from_shape(shape, data).map_err(|e| self.failed(Model::Decoder, &e))
        };
        let mut feed = TVec::new();
        for input in &self.decoder.inputs {
            let value =
                match input {
                    DecoderInput::Embedding(k) => embeddings
                        .get(*k)
                        .cloned()
                        .map(TValue::from_const)
                        .ok_or_else(|| self.missing_embedding(*k, embeddings.len()))?,
                    DecoderInput::PointCoords => tensor(&[1, n, 2], &coords)?.into_tvalue(),
                    DecoderInput::PointLabels => tensor(&[1, n], &labels)?.into_tvalue(),
                    DecoderInput::MaskInput(zeros) => TValue::from_const(zeros.clone()),
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
        if self.decoder.has_iou && k != SAM_MASKS_WITH_SINGLE_TOKEN {
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
            side: self.encoder.side,
        })
    }

    /// A decoder output's values as `f32`, in order (a model may return another float type).
    fn floats(&self, value: &TValue) -> Result<Vec<f32>> {
        let cast = value
            .cast_to::<f32>()
            .map_err(|e| self.failed(Model::Decoder, &e))?;
        cast.as_slice::<f32>()
            .map(<[f32]>::to_vec)
            .map_err(|e| self.failed(Model::Decoder, &e))
    }

    /// The error of an encoder that returned fewer outputs than it declared when loaded.
    fn missing_embedding(&self, k: usize, returned: usize) -> Error {
        Error::Hardware(format!(
            "segmenter 'sam' ({}): the encoder returned {returned} output(s), the decoder needs output {k}",
            self.encoder_path.display()
        ))
    }

    /// An inference-time tract failure as one error line, naming the model's file.
    fn failed(&self, model: Model, e: &TractError) -> Error {
        let (name, path) = match model {
            Model::Encoder => ("encoder", &self.encoder_path),
            Model::Decoder => ("decoder", &self.decoder_path),
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

    /// One frame with no estimate has nothing to prompt from: the builtin segmenter draws it,
    /// as it draws such views in [`Segmenter::segment_views`].
    fn segment(&self, frame: &Frame) -> Result<Mask> {
        self.fallback.segment(frame)
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
                (None, None) => self.fallback.segment(v.frame),
            })
            .collect()
    }

    /// Better estimates make better prompts, and the first views are drawn without one.
    fn uses_context(&self) -> bool {
        true
    }

    /// A view with a prompt is drawn from its own frame: the other views lend it nothing.
    fn prompted_views_stand_alone(&self) -> bool {
        true
    }
}

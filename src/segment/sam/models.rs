//! Loading a SAM-family encoder and decoder, and checking them against the contract the
//! segmenter feeds (module notes of [`super`]) before any frame is read: a model that cannot be
//! prompted fails when the cell is built, before the arm moves.

use std::path::Path;

use tract_onnx::prelude::*;

use super::super::onnx::{dims_text, fixed, one_line, read_model};
use crate::error::{Error, Result};

/// Largest encoder input side, pixels (SAM and SAM 2 take 1024).
const MAX_SIDE: usize = 4096;

/// Most values of `mask_input`, which is fed zeros on every call (SAM: 256 x 256).
const MAX_MASK_INPUT_VALUES: usize = 1 << 22;

/// The prompt inputs a decoder may take besides the encoder's outputs.
const PROMPT_INPUTS: &str = "point_coords, point_labels, mask_input, has_mask_input, orig_im_size";

/// What the decoder is fed at one of its inputs.
#[derive(Clone, Debug)]
pub(super) enum DecoderInput {
    /// The encoder's output of this index.
    Embedding(usize),
    PointCoords,
    PointLabels,
    /// These zeros (no earlier mask), built in the input's own shape when the decoder is
    /// loaded, so a run never meets a shape it was not checked for.
    MaskInput(Arc<Tensor>),
    HasMaskInput,
    OrigImSize,
}

/// The encoder, typed for its square input.
pub(super) struct Encoder {
    pub(super) plan: TypedSimplePlan<TypedModel>,
    /// The square input's side, pixels.
    pub(super) side: usize,
    /// Each output's name and shape, in the encoder's order.
    pub(super) outputs: Vec<(String, Vec<usize>)>,
}

impl Encoder {
    /// Loads the encoder at `path`; errors name `config_path` and `segmenter.encoder`.
    pub(super) fn load(path: &Path, config_path: &Path) -> Result<Self> {
        let bad = |message: String| Error::input(config_path, "segmenter.encoder", message);
        let shown = path.display();
        let mut model = read_model(path, config_path, "segmenter.encoder")?;
        if model.inputs.len() != 1 {
            return Err(bad(format!(
                "{shown} has {} inputs: a SAM encoder takes one image",
                model.inputs.len()
            )));
        }
        let side = square_side(&model).map_err(|declared| {
            bad(format!(
                "{shown} takes {declared}: a SAM encoder takes a fixed square 1x3xSxS image (S up to {MAX_SIDE}); export it with its input size fixed"
            ))
        })?;
        let names = output_names(&model);
        let cannot_run = |e: TractError| {
            bad(format!(
                "tract cannot run {shown} on a 1x3x{side}x{side} input ({})",
                one_line(&e)
            ))
        };
        let fact = InferenceFact::dt_shape(f32::datum_type(), [1, 3, side, side]);
        model.set_input_fact(0, fact).map_err(cannot_run)?;
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
        Ok(Encoder {
            plan,
            side,
            outputs,
        })
    }
}

/// The side of a model's declared `1x3xSxS` input, or how the declared input reads.
fn square_side(model: &InferenceModel) -> std::result::Result<usize, String> {
    let fact = model.input_fact(0).map_err(|e| one_line(&e))?;
    let dims: Vec<Option<usize>> = fact.shape.dims().map(fixed).collect();
    match dims[..] {
        [None | Some(1), Some(3), Some(a), Some(b)] if a == b && a > 0 && a <= MAX_SIDE => Ok(a),
        _ if dims.is_empty() => Err("an input of unknown rank".into()),
        _ => {
            let declared: Vec<String> = dims
                .iter()
                .map(|d| d.map_or("?".into(), |d| d.to_string()))
                .collect();
            Err(format!("a {} input", declared.join("x")))
        }
    }
}

/// A model's output names as the ONNX file gives them.
fn output_names(model: &InferenceModel) -> Vec<String> {
    model
        .outputs
        .iter()
        .map(|&o| {
            model
                .outlet_label(o)
                .map_or_else(|| model.node(o.node).name.clone(), str::to_string)
        })
        .collect()
}

/// The decoder, typed for a prompt of a fixed number of points.
pub(super) struct Decoder {
    pub(super) plan: TypedSimplePlan<TypedModel>,
    /// What each input is fed, in the decoder's order.
    pub(super) inputs: Vec<DecoderInput>,
    /// Whether the second output is `iou_predictions`.
    pub(super) has_iou: bool,
}

impl Decoder {
    /// Loads the decoder at `path` for prompts of `n` points, fed by an encoder with
    /// `embeddings` (names and shapes); errors name `config_path` and `segmenter.decoder`.
    pub(super) fn load(
        path: &Path,
        config_path: &Path,
        embeddings: &[(String, Vec<usize>)],
        n: usize,
    ) -> Result<Self> {
        let bad = |message: String| Error::input(config_path, "segmenter.decoder", message);
        let shown = path.display();
        let mut model = read_model(path, config_path, "segmenter.decoder")?;
        let inputs =
            classify_inputs(&model, embeddings).map_err(|m| bad(format!("{shown} {m}")))?;
        let cannot_run = |e: TractError| {
            bad(format!(
                "tract cannot run {shown} with {n} prompt points ({})",
                one_line(&e)
            ))
        };
        for (ix, input) in inputs.iter().enumerate() {
            let shape: Vec<usize> = match input {
                DecoderInput::Embedding(k) => embeddings[*k].1.clone(),
                DecoderInput::PointCoords => vec![1, n, 2],
                DecoderInput::PointLabels => vec![1, n],
                DecoderInput::MaskInput(zeros) => zeros.shape().to_vec(),
                DecoderInput::HasMaskInput => vec![1],
                DecoderInput::OrigImSize => vec![2],
            };
            model
                .set_input_fact(ix, InferenceFact::dt_shape(f32::datum_type(), shape))
                .map_err(cannot_run)?;
        }
        let with_size = inputs.iter().any(|i| matches!(i, DecoderInput::OrigImSize));
        let (masks, has_iou) =
            keep_mask_outputs(&mut model, with_size).map_err(|m| bad(format!("{shown} {m}")))?;
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
        Ok(Decoder {
            plan: typed.into_runnable().map_err(cannot_run)?,
            inputs,
            has_iou,
        })
    }
}

/// What each of the decoder's inputs is fed, by name; or why one cannot be fed (a message to
/// follow the model's path).
fn classify_inputs(
    model: &InferenceModel,
    embeddings: &[(String, Vec<usize>)],
) -> std::result::Result<Vec<DecoderInput>, String> {
    let names: Vec<&str> = model
        .inputs
        .iter()
        .map(|outlet| model.node(outlet.node).name.as_str())
        .collect();
    let mut inputs = Vec::with_capacity(names.len());
    for (ix, &name) in names.iter().enumerate() {
        inputs.push(match name {
            "point_coords" => DecoderInput::PointCoords,
            "point_labels" => DecoderInput::PointLabels,
            "mask_input" => DecoderInput::MaskInput(zero_mask_input(model, ix)?),
            "has_mask_input" => DecoderInput::HasMaskInput,
            "orig_im_size" => DecoderInput::OrigImSize,
            _ => match embeddings.iter().position(|(n, _)| n == name) {
                Some(k) => DecoderInput::Embedding(k),
                None => {
                    let made: Vec<&str> = embeddings.iter().map(|(n, _)| n.as_str()).collect();
                    return Err(format!(
                        "takes an input '{name}' that is neither an encoder output ({}) nor a prompt ({PROMPT_INPUTS})",
                        made.join(", ")
                    ));
                }
            },
        });
    }
    for wanted in ["point_coords", "point_labels"] {
        if !names.contains(&wanted) {
            return Err(format!(
                "has no input '{wanted}': a SAM decoder is prompted through point_coords and point_labels"
            ));
        }
    }
    Ok(inputs)
}

/// Zeros in the shape of the decoder's input `ix` (`mask_input`): fixed but for a symbolic
/// leading dimension (SAM 2 exports: the prompt count), taken as one, and at most
/// [`MAX_MASK_INPUT_VALUES`] values.
fn zero_mask_input(model: &InferenceModel, ix: usize) -> std::result::Result<Arc<Tensor>, String> {
    let fact = model
        .input_fact(ix)
        .map_err(|e| format!("has a mask_input tract cannot read ({})", one_line(&e)))?;
    let dims: Option<Vec<usize>> = fact
        .shape
        .dims()
        .enumerate()
        .map(|(k, d)| fixed(d).or((k == 0).then_some(1)))
        .collect();
    let shape = dims
        .filter(|d| !d.is_empty())
        .ok_or("has a mask_input with no fixed shape: export it with one (SAM: 1x1x256x256)")?;
    let values = shape
        .iter()
        .try_fold(1usize, |n, &d| n.checked_mul(d))
        .filter(|&n| n <= MAX_MASK_INPUT_VALUES)
        .ok_or_else(|| {
            format!(
                "takes a mask_input of {}: allowed at most {MAX_MASK_INPUT_VALUES} values (SAM: 1x1x256x256)",
                dims_text(&shape)
            )
        })?;
    let zeros = Tensor::from_shape(&shape, &vec![0f32; values])
        .map_err(|e| format!("has a mask_input that cannot be filled ({})", one_line(&e)))?;
    Ok(Arc::new(zeros))
}

/// Prunes the decoder to its masks' logits and, when it has them, `iou_predictions`: its other
/// outputs (SAM's full-size `masks`, sized by `orig_im_size`'s values) are never typed. The
/// masks are `low_res_masks`, or `masks` in a decoder without `orig_im_size` (SAM 2), where
/// they can only cover the square. Returns their name and whether the scores are kept.
fn keep_mask_outputs(
    model: &mut InferenceModel,
    with_size: bool,
) -> std::result::Result<(&'static str, bool), String> {
    let names: &[&'static str] = if with_size {
        &["low_res_masks"]
    } else {
        &["low_res_masks", "masks"]
    };
    let Some(&masks) = names.iter().find(|n| model.set_output_names([**n]).is_ok()) else {
        return Err(format!(
            "has no output 'low_res_masks'{}: a SAM decoder returns its masks' logits over the encoder's square under that name",
            if with_size { "" } else { " or 'masks'" }
        ));
    };
    let has_iou = model.set_output_names([masks, "iou_predictions"]).is_ok();
    if !has_iou {
        model.set_output_names([masks]).map_err(|e| one_line(&e))?;
    }
    Ok((masks, has_iou))
}

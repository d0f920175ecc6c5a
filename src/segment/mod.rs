//! Segmenters: turn a colour frame into the robot mask the solver fits.
//!
//! `sim-truth` reads the simulator's ground-truth side channel; `builtin` (no training) uses
//! the static camera's other views and the silhouette rendered under the current estimate;
//! `onnx` (behind the `onnx` cargo feature) runs a user-supplied segmentation model.
//! Per-frame segmenters implement [`Segmenter::segment`] only; segmenters that gain from
//! context also override [`Segmenter::segment_views`] and [`Segmenter::uses_context`].

pub mod builtin;
pub mod change;
#[cfg(feature = "sim")]
mod sim_truth;

pub use builtin::{BuiltinParams, ViewInput};

use std::path::{Path, PathBuf};

use easyhec_drivers::Frame;

use crate::config::segmenter::SamConfig;
use crate::config::{NoiseModel, OnnxConfig, SegmenterConfig};
use crate::error::{Error, Result};
use crate::mask::Mask;

#[cfg(feature = "onnx")]
pub mod onnx;
#[cfg(feature = "onnx")]
pub mod sam;

/// A segmenter's masks with what the images alone said about each pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct Evidence {
    /// One mask per view, as [`Segmenter::segment_views`] draws them.
    pub masks: Vec<Mask>,
    /// Per view, each pixel's log-odds for robot before smoothing, the prior's own pull
    /// left out: near zero where the images did not decide the label.
    pub log_odds: Vec<Vec<f32>>,
}

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

    /// Whether a view given a prior is drawn from its own frame alone, the other views lending
    /// it nothing: then a caller that needs one view's mask (a bump check) need not draw the
    /// others. False by default, and for `builtin`, whose background plate is the others'.
    fn prompted_views_stand_alone(&self) -> bool {
        false
    }

    /// Per-pixel log-odds for robot from the images alone (no prior), one per frame, when the
    /// segmenter has such evidence: it lets a caller fit each view's joints to its image where
    /// the recorded ones are wrong ([`crate::pipeline::segment_solve::search_view_pairs`]). None by default.
    fn evidence(&self, _frames: &[&Frame]) -> Result<Option<Vec<Vec<f32>>>> {
        Ok(None)
    }

    /// [`Segmenter::segment_views`]'s masks with each pixel's log-odds for robot before the
    /// segmenter's smoothing, the prior's own pull left out, when the segmenter has such
    /// evidence: where it is near zero the images did not decide the label
    /// ([`crate::pipeline::undecided`]). None by default.
    fn segment_views_with_evidence(&self, _views: &[ViewInput<'_>]) -> Result<Option<Evidence>> {
        Ok(None)
    }
}

/// A recorded view's colour image as a frame, for segmenting runs offline; it must have the
/// camera's size, since its mask is compared pixel for pixel with renders.
pub fn read_frame(path: &Path, width: u32, height: u32) -> Result<Frame> {
    let stated = crate::mask::image_size(path, "image")?;
    if stated != (width, height) {
        return Err(Error::input(
            path,
            "image",
            format!(
                "is {}x{} but the camera is {width}x{height}",
                stated.0, stated.1
            ),
        ));
    }
    let img = image::open(path)
        .map_err(|e| Error::input(path, "image", format!("cannot decode: {e}")))?
        .to_rgb8();
    Ok(Frame {
        width,
        height,
        rgb: img.into_raw(),
        captured_at: std::time::SystemTime::now(),
        sequence: 0,
    })
}

/// Builds the segmenter a `[segmenter]` table names; `config_path` is the cell config, which
/// relative paths (the ONNX model) are resolved against and errors name.
pub fn build(config: &SegmenterConfig, config_path: &Path) -> Result<Box<dyn Segmenter>> {
    build_with_truth(config, config_path, None)
}

/// Where the `sim-truth` segmenter reads a simulated frame's true mask: the simulator's own
/// camera, which remembers what it rendered for each frame it handed out.
pub trait TruthSource: Send + Sync {
    /// The true robot mask (row-major, 0 or 255) of `frame`, when the source rendered it.
    fn truth_mask(&self, frame: &Frame) -> Option<Vec<u8>>;
}

/// [`build`], giving `sim-truth` the simulated camera it reads the truth from (without one,
/// it refuses every frame with a message saying it needs a simulated camera).
pub fn build_with_truth(
    config: &SegmenterConfig,
    config_path: &Path,
    truth: Option<std::sync::Arc<dyn TruthSource>>,
) -> Result<Box<dyn Segmenter>> {
    config.validate(config_path)?;
    match config {
        SegmenterConfig::SimTruth { noise, seed } => {
            sim_truth(truth, noise.clone(), *seed, config_path)
        }
        SegmenterConfig::Onnx(cfg) => onnx_segmenter(cfg, config_path),
        SegmenterConfig::Sam(cfg) => sam_segmenter(cfg, config.min_band_px(), config_path),
        SegmenterConfig::Builtin { min_band_px, .. } => Ok(Box::new(Builtin {
            params: BuiltinParams::default(),
            min_band_px: *min_band_px,
        })),
    }
}

#[cfg(feature = "sim")]
fn sim_truth(
    truth: Option<std::sync::Arc<dyn TruthSource>>,
    noise: Option<NoiseModel>,
    seed: u64,
    _config_path: &Path,
) -> Result<Box<dyn Segmenter>> {
    Ok(Box::new(sim_truth::SimTruth::new(truth, noise, seed)))
}

/// Without the `sim` feature there is no simulator to read the truth from.
#[cfg(not(feature = "sim"))]
fn sim_truth(
    _: Option<std::sync::Arc<dyn TruthSource>>,
    _: Option<NoiseModel>,
    _: u64,
    config_path: &Path,
) -> Result<Box<dyn Segmenter>> {
    Err(Error::input(
        config_path,
        "segmenter.kind",
        "\"sim-truth\" needs the simulator, which this build lacks: rebuild with the default `sim` feature",
    ))
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

    fn segment_views_with_evidence(&self, views: &[ViewInput<'_>]) -> Result<Option<Evidence>> {
        builtin::segment_views_with_evidence(views, &self.params).map(Some)
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
            builtin::segment_views_with_evidence(&views, &self.params)?.log_odds,
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

/// The two models of a `[segmenter] kind = "sam"` table, loaded and checked; views with no
/// estimate to prompt from are drawn by the builtin segmenter.
#[cfg(feature = "onnx")]
fn sam_segmenter(
    cfg: &SamConfig,
    min_band_px: f32,
    config_path: &Path,
) -> Result<Box<dyn Segmenter>> {
    let fallback = Builtin {
        params: BuiltinParams::default(),
        min_band_px,
    };
    Ok(Box::new(sam::SamSegmenter::load(
        cfg,
        config_path,
        fallback,
    )?))
}

/// Without the `onnx` feature a SAM segmenter config is an error that says how to get one.
#[cfg(not(feature = "onnx"))]
fn sam_segmenter(_: &SamConfig, _: f32, config_path: &Path) -> Result<Box<dyn Segmenter>> {
    Err(Error::input(
        config_path,
        "segmenter.kind",
        "\"sam\" runs the model with tract, which this build leaves out: rebuild with --features onnx",
    ))
}

/// A frame's width and height in pixels, once its RGB bytes are checked to fill them: a model
/// fed a short buffer would read past it. `segmenter` names the kind in the error.
#[cfg(feature = "onnx")]
fn frame_size(frame: &Frame, segmenter: &str) -> Result<(usize, usize)> {
    let (w, h) = (frame.width as usize, frame.height as usize);
    if w == 0 || h == 0 || frame.rgb.len() != w * h * 3 {
        return Err(Error::Hardware(format!(
            "segmenter '{segmenter}': a {}x{} frame with {} RGB bytes",
            frame.width,
            frame.height,
            frame.rgb.len()
        )));
    }
    Ok((w, h))
}

/// Where a model path in the config at `config_path` points.
pub fn resolve_model_path(config_path: &Path, model: &Path) -> PathBuf {
    config_path.parent().unwrap_or(Path::new(".")).join(model)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The config's rule (`reads_whole_run`, which refuses such segmenters for a list of
    /// cameras) and the segmenter's behaviour (`uses_context`) agree for every kind this
    /// build can make without a model file.
    #[test]
    fn reads_whole_run_is_uses_context() {
        let mut kinds = vec!["kind = \"builtin\""];
        if cfg!(feature = "sim") {
            kinds.push("kind = \"sim-truth\"");
        }
        for text in kinds {
            let config: SegmenterConfig = toml::from_str(text).unwrap();
            let segmenter = build(&config, Path::new("cell.toml")).unwrap();
            assert_eq!(segmenter.uses_context(), config.reads_whole_run(), "{text}");
        }
    }
}

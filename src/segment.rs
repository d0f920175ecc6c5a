//! Segmenters: turn a colour frame into the robot mask the solver fits.
//!
//! Only the simulator's ground-truth side channel exists so far; learned-free segmenters for
//! real frames arrive with their own issue and plug in behind the same trait.

use easyhec_drivers::Frame;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::mask::Mask;

/// Produces a robot mask from a frame.
pub trait Segmenter: Send + Sync {
    /// Name for logs and errors.
    fn name(&self) -> &str;
    /// The robot mask in the frame's (distorted) image.
    fn segment(&self, frame: &Frame) -> Result<Mask>;
}

/// `[segmenter]` in a cell config.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum SegmenterConfig {
    /// The simulated camera's ground-truth mask.
    SimTruth,
}

impl SegmenterConfig {
    /// Builds the segmenter.
    pub fn build(&self) -> Box<dyn Segmenter> {
        match self {
            SegmenterConfig::SimTruth => Box::new(SimTruth),
        }
    }
}

/// Uses [`Frame::truth_mask`].
pub struct SimTruth;

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
        Ok(Mask {
            width: frame.width,
            height: frame.height,
            data: truth.iter().map(|&v| u8::from(v >= 128)).collect(),
        })
    }
}

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
}

impl SegmenterConfig {
    /// Builds the segmenter.
    pub fn build(&self) -> Box<dyn Segmenter> {
        match self {
            SegmenterConfig::SimTruth { noise, seed } => Box::new(SimTruth {
                noise: noise.clone(),
                seed: *seed,
                frames: std::sync::atomic::AtomicU64::new(0),
            }),
        }
    }
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

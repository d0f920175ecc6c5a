//! `[segmenter] kind = "sim-truth"`: the simulated camera's ground-truth mask of each frame,
//! optionally with the synthetic segmentation noise of `easyhec synth`. It lets the whole loop
//! run before any real segmenter exists, and gives benchmarks exact masks to start from.

use std::sync::Arc;

use easyhec_drivers::Frame;

use super::{Segmenter, TruthSource};
use crate::config::NoiseModel;
use crate::error::{Error, Result};
use crate::mask::Mask;

impl TruthSource for easyhec_mocks::SimCamera {
    fn truth_mask(&self, frame: &Frame) -> Option<Vec<u8>> {
        easyhec_mocks::SimCamera::truth_mask(self, frame.sequence)
    }
}

/// The simulator's ground-truth mask of each frame ([`TruthSource`]), optionally with the
/// synthetic segmentation noise of `easyhec synth`.
pub struct SimTruth {
    truth: Option<Arc<dyn TruthSource>>,
    noise: Option<NoiseModel>,
    seed: u64,
    frames: std::sync::atomic::AtomicU64,
}

impl SimTruth {
    /// Reads the truth from `truth`; `noise` seeded by `seed` and the frame count.
    pub fn new(truth: Option<Arc<dyn TruthSource>>, noise: Option<NoiseModel>, seed: u64) -> Self {
        SimTruth {
            truth,
            noise,
            seed,
            frames: std::sync::atomic::AtomicU64::new(0),
        }
    }
}

impl Segmenter for SimTruth {
    fn name(&self) -> &str {
        "sim-truth"
    }

    fn segment(&self, frame: &Frame) -> Result<Mask> {
        let Some(truth) = self.truth.as_ref().and_then(|t| t.truth_mask(frame)) else {
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
                crate::mask_noise::apply_mask_noise(&mut rng, &mask, noise)
            }
        })
    }
}

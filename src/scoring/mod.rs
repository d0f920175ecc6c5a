//! Batched scoring: the two hot loops where a caller renders one robot at many camera poses
//! and keeps only a number per pose, never the silhouettes.
//!
//! - **Exploration** ([`BatchScoring::disagreement_many`]): per joint sample of a pool, the
//!   per-pixel variance of the candidate camera poses' silhouettes (docs/method.md §5).
//! - **Posterior refinement** ([`BatchScoring::band_mismatches`]): per sampled pose and view,
//!   the band pixels whose coverage differs from the observation.
//!
//! Why a capability of its own rather than methods of
//! [`SilhouetteRenderer`](crate::render::SilhouetteRenderer): these are the callers'
//! algorithms (exploration's score, the solver's refinement), which a backend only
//! accelerates. Keeping them here lets `render` depend on nothing but geometry, and lets a GPU
//! backend batch a whole pool in one submission while the CPU reference ([`cpu`]) stays the
//! definition every backend is checked against (`tests/gpu_parity.rs`). Code that needs both
//! capabilities takes a [`Backend`](crate::backend::Backend).

use nalgebra::Isometry3;

use crate::camera::Intrinsics;
use crate::render::PosedRobot;

pub mod cpu;

/// Scores many camera poses of many posed robots, returning only the scores. Implementations
/// must agree with [`cpu`] (exactly on the CPU; to the pixel-centre ties an f32 rasteriser
/// can flip on a GPU), and fall back to [`cpu`] themselves whenever they cannot take a batch,
/// so callers always get an answer.
pub trait BatchScoring: Send + Sync {
    /// Exploration's score of every pool entry: the candidates' total per-pixel silhouette
    /// variance ([`cpu::disagreement`]) at `camera`'s (scoring) resolution, in pool order.
    fn disagreement_many(
        &self,
        camera: &Intrinsics,
        pool: &[&PosedRobot],
        candidates: &[Isometry3<f64>],
    ) -> Vec<f64>;

    /// The solver's posterior refinement in one batch: for every pose in `poses` and every
    /// view `robots[v]`, how many pixels inside `band[v]` the silhouette at that pose covers
    /// differently from `observed[v]`, as `counts[pose * views + v]`. Masks are one byte per
    /// pixel over the whole image (`y * width + x`, nonzero = set), as in
    /// [`Mask`](crate::mask::Mask); `band` and `observed` hold one mask per robot.
    fn band_mismatches(
        &self,
        camera: &Intrinsics,
        robots: &[&PosedRobot],
        band: &[&[u8]],
        observed: &[&[u8]],
        poses: &[Isometry3<f64>],
    ) -> Vec<u32>;
}

//! Pipelines: the library's end-to-end jobs, with typed inputs and outcomes, that the CLI, the
//! daemon and the benchmarks call.
//! - [`offline`]: the offline solve of a recorded run directory (`easyhec solve`).
//! - [`segment_solve`]: segment → solve → re-segment, the one place that alternates a
//!   segmenter with the solver (offline runs, the closed loop's live frames, the bump check).
//! - [`undecided`]: the segmentation term of a result's covariance, from the pixels the
//!   segmenter could not decide.

pub mod offline;
pub mod segment_solve;
pub mod undecided;

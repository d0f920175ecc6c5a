//! easyhec: markerless eye-to-hand calibration by silhouette alignment.
//!
//! # Layout
//! - [`geometry`]: se(3), pose errors, matrix I/O.
//! - [`mesh`], [`robot`]: mesh loading and URDF kinematics (the model).
//! - [`camera`], [`mask`]: pinhole + distortion, binary masks and distance transforms.
//! - [`render`]: silhouettes and their outline samples, behind [`render::SilhouetteRenderer`].
//! - [`objective`]: the paper's loss and its exact boundary gradient.
//! - [`scoring`]: many poses scored in one batch (exploration's disagreement, the solver's
//!   refinement), behind [`scoring::BatchScoring`], with the CPU reference in [`scoring::cpu`].
//! - `gpu` (feature `wgpu`): the wgpu backend, implementing both of the above.
//! - [`backend`]: [`backend::Backend`] (render + score) and [`backend::open_renderer`].
//! - [`solve`]: Levenberg–Marquardt (default) and Adam (baseline) solvers, uncertainty.
//! - [`explore`]: consistency-based choice of the next view.
//! - [`run`]: the `easyhec-run/1` and `easyhec-result/1` formats.
//! - [`calibrate`], [`cell`], [`daemon`]: the closed loop on a configured cell, and the
//!   long-running service around it (`easyhec daemon`).
//! - [`synth`], [`interop`], [`overlay`], [`bench`](mod@bench): synthetic runs, import/export, overlays,
//!   benchmarks.

pub mod backend;
#[cfg(feature = "sim")]
pub mod bench;
pub mod calibrate;
pub mod camera;
pub mod cell;
pub mod collision;
pub mod config;
pub mod consensus;
pub mod daemon;
pub mod error;
pub mod explore;
pub mod geometry;
#[cfg(feature = "wgpu")]
pub mod gpu;
pub mod init;
pub mod interop;
pub mod io;
pub mod mask;
pub mod mask_noise;
pub mod mesh;
pub mod objective;
pub mod overlay;
pub mod pipeline;
pub mod render;
pub mod robot;
pub mod run;
pub mod safety;
#[cfg(feature = "sim")]
pub mod scene;
pub mod scoring;
pub mod segment;
pub mod solve;
#[cfg(feature = "sim")]
pub mod synth;
pub mod time;

pub use error::{Error, Result};
pub use nalgebra;

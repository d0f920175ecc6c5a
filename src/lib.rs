//! easyhec: markerless eye-to-hand calibration by silhouette alignment.
//!
//! # Layout
//! ARCHITECTURE.md has every module with its purpose and layer (a test keeps that table true).
//! In short, from the bottom up:
//! - foundation: [`error`], [`geometry`], [`time`], [`io`], [`mask`], [`mesh`], [`camera`]
//!   (lens warps for the one intrinsics type), [`robot`] (URDF kinematics);
//! - [`config`]: every table of a cell config;
//! - rendering and scoring: [`render`], [`objective`], [`scoring`], `gpu` (feature `wgpu`),
//!   [`backend`];
//! - estimation: [`solve`], [`init`], [`consensus`], [`explore`]; motion safety: [`safety`];
//! - the simulator (feature `sim`): `scene`, `synth`, with [`mask_noise`];
//! - [`segment`] (segmenters), [`run`] and [`interop`] (formats), [`overlay`];
//! - [`pipeline`] (the offline solve, segment-and-solve), [`cell`] (hardware or simulator
//!   behind the driver traits), [`calibrate`] (the closed loop), [`daemon`] (the service),
//!   `bench` (feature `sim`).

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
#[cfg(feature = "ros2")]
pub mod ros2;
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

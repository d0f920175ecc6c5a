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

/// The cargo features, each with whether this build has it: the one list of them in Rust. `easyhec --version` prints the ones built in, so a bug report says
/// which drivers and renderers were there; `./test` reads the same list from `Cargo.toml`, and
/// a unit test keeps the two equal.
pub const FEATURES: &[(&str, bool)] = &[
    ("sim", cfg!(feature = "sim")),
    ("wgpu", cfg!(feature = "wgpu")),
    ("ur", cfg!(feature = "ur")),
    ("socketcan", cfg!(feature = "socketcan")),
    ("v4l2", cfg!(feature = "v4l2")),
    ("aravis", cfg!(feature = "aravis")),
    ("onnx", cfg!(feature = "onnx")),
    ("ros2", cfg!(feature = "ros2")),
];

#[cfg(test)]
mod tests {
    /// Every feature `Cargo.toml` declares (but `default`) is in [`super::FEATURES`] and
    /// nothing else is: a new feature fails here until it is listed.
    #[test]
    fn features_are_cargo_tomls() {
        let manifest: toml::Table = toml::from_str(include_str!(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/Cargo.toml"
        )))
        .unwrap();
        let declared: Vec<&str> = manifest["features"]
            .as_table()
            .unwrap()
            .keys()
            .map(String::as_str)
            .filter(|k| *k != "default")
            .collect();
        let listed: Vec<&str> = super::FEATURES.iter().map(|(name, _)| *name).collect();
        let mut sorted = listed.clone();
        sorted.sort_unstable();
        let mut declared_sorted = declared.clone();
        declared_sorted.sort_unstable();
        assert_eq!(sorted, declared_sorted);
    }
}

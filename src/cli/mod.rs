//! The subcommands, one file each: each parses its flags into the library's typed inputs,
//! calls the library, and prints what came back. No computation lives here.

pub mod bench;
pub mod calibrate;
pub mod daemon;
pub mod exit;
pub mod export;
pub mod frames;
pub mod import;
pub mod logging;
pub mod progress;
pub mod publish;
#[cfg(feature = "sim")]
pub mod sim_camera;
pub mod solve;
#[cfg(feature = "sim")]
pub mod synth;
pub mod version;

use std::path::Path;

use anyhow::Context;

/// Joints as the operator reads them: signed, three decimals.
pub fn fmt_joints(q: &[f64]) -> String {
    let parts: Vec<String> = q.iter().map(|v| format!("{v:+.3}")).collect();
    format!("[{}]", parts.join(", "))
}

/// The URDF path a run directory records: absolute, so the run stays valid wherever it is
/// solved from. `run.json` is UTF-8 JSON, so a path that is not UTF-8 is refused rather
/// than written mangled (it would name another file).
pub fn urdf_for_run(urdf: &Path) -> anyhow::Result<String> {
    let abs = std::fs::canonicalize(urdf).unwrap_or_else(|_| urdf.to_path_buf());
    abs.to_str().map(str::to_string).ok_or_else(|| {
        anyhow::anyhow!(
            "{}: --urdf: the path is not UTF-8, and run.json records it as UTF-8 text; allowed: a UTF-8 path (rename or link the file)",
            abs.display()
        )
    })
}

/// The async runtime the arm and camera drivers run on (two workers: the loop's planning and
/// solving are CPU-bound and run on rayon).
pub fn runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the async runtime")
}

//! `easyhec export`: a result in the form another tool reads.

use super::exit::{out, outln};
use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use easyhec::error::Error;
use easyhec::interop::export::check_frame_name;
use easyhec::interop::{export, ExportFormat};
use easyhec::run::rig::{ResultCameras, RunLayout};

use super::frames::FrameArgs;

#[derive(Args)]
pub struct ExportArgs {
    /// easyhec-result/1 file, or easyhec-result/2: one file per camera into the --out folder.
    pub result: PathBuf,
    /// The form to write.
    #[arg(long, value_enum)]
    pub format: ExportFormat,
    #[command(flatten)]
    pub frames: FrameArgs,
    /// Output file (default: standard output).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Writes a result in another tool's form.
pub fn run(a: ExportArgs) -> anyhow::Result<()> {
    let results = ResultCameras::read(&a.result)?;
    if results.layout == RunLayout::NamedCameras {
        return export_rig(&a, &results);
    }
    let format = a.format;
    if let Some(p) = &a.out {
        if let Some(problem) = easyhec::io::output_file_problem(p, std::slice::from_ref(&a.result))
        {
            return Err(Error::input(p, "--out", problem).into());
        }
    }
    let result = &results.cameras[0].result;
    check_frame_name(&result.base_link)
        .map_err(|m| Error::input(&a.result, "base_link", format!("is {m}")))?;
    let edge = a.frames.edge(result)?;
    let text = export(result, format, &edge)?;
    match a.out {
        Some(p) => easyhec::io::write_atomic(&p, text.as_bytes())
            .with_context(|| format!("writing {}", p.display()))?,
        None => out!("{text}"),
    }
    Ok(())
}

/// Every camera of an `easyhec-result/2`, one file per camera in the `--out` folder
/// (`<name>.<ext>`), each camera under its own child frame (`FrameArgs::rig_edges`).
fn export_rig(a: &ExportArgs, results: &ResultCameras) -> anyhow::Result<()> {
    let Some(dir) = &a.out else {
        return Err(Error::Usage(format!(
            "--out: {} holds {} cameras, written as one file per camera: give a folder",
            a.result.display(),
            results.cameras.len()
        ))
        .into());
    };
    if let Some(problem) = easyhec::io::output_dir_problem(dir, std::slice::from_ref(&a.result)) {
        return Err(Error::input(dir, "--out", problem).into());
    }
    // Every camera's file is made before the folder or any file is written: a refused
    // camera leaves nothing half-exported.
    let edges = a.frames.rig_edges(results)?;
    let mut files = Vec::with_capacity(edges.len());
    for ((k, cam), edge) in results.cameras.iter().enumerate().zip(&edges) {
        let result = &cam.result;
        check_frame_name(&result.base_link)
            .map_err(|m| Error::input(&a.result, results.key(k, "base_link"), format!("is {m}")))?;
        let text = export(result, a.format, edge)?;
        let name = cam.name_or_empty();
        let path = dir.join(a.format.file_name(name));
        files.push((name, &edge.child, path, text));
    }
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    for (name, child, path, text) in files {
        easyhec::io::write_atomic(&path, text.as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
        outln!("{name}: {child} -> {}", path.display());
    }
    Ok(())
}

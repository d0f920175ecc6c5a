//! `easyhec export`: a result in the form another tool reads.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use easyhec::error::Error;
use easyhec::interop::export::check_frame_name;
use easyhec::interop::{export, ExportFormat};
use easyhec::run::ResultFile;

use super::frames::FrameArgs;

#[derive(Args)]
pub struct ExportArgs {
    /// easyhec-result/1 file.
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
    let format = a.format;
    let result = ResultFile::read(&a.result)?;
    check_frame_name(&result.base_link)
        .map_err(|m| Error::input(&a.result, "base_link", format!("is {m}")))?;
    let edge = a.frames.edge(&result)?;
    let text = export(&result, format, &edge)?;
    match a.out {
        Some(p) => easyhec::io::write_atomic(&p, text.as_bytes())
            .with_context(|| format!("writing {}", p.display()))?,
        None => print!("{text}"),
    }
    Ok(())
}

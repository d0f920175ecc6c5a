//! Other tools' formats: import from EasyHeC's offline folder ([`import`]) and export a result
//! in the forms OpenCV, ROS 2, easy_handeye2 and URDF read ([`export`]), through the one tf edge
//! a calibration adds ([`tf_edge`]).

pub mod export;
pub mod import;
pub mod tf_edge;
pub mod tf_tree;

use std::path::Path;

use crate::error::{Error, Result};

pub use export::{export, ExportFormat};
pub use import::{import_easyhec, EasyHecImport};
pub use tf_edge::TfEdge;

/// Reads a whitespace-separated numeric text file (comments after `#`).
pub fn read_numbers(path: &Path) -> Result<Vec<f64>> {
    let text = crate::io::read_text_input(path)?;
    let mut out = Vec::new();
    for (ln, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("");
        for tok in line
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|t| !t.is_empty())
        {
            let v: f64 = tok.parse().map_err(|_| {
                Error::input(
                    path,
                    format!("line {}", ln + 1),
                    format!("'{tok}' is not a number"),
                )
            })?;
            if !v.is_finite() {
                return Err(Error::input(
                    path,
                    format!("line {}", ln + 1),
                    "not a finite number",
                ));
            }
            out.push(v);
        }
    }
    Ok(out)
}

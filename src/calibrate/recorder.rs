//! The run directory, written as the loop goes (`easyhec-run/1` plus `rounds.json`): every
//! view is on disk before the next move, so a crash loses nothing and `easyhec solve` can
//! re-solve the run offline.

use std::path::{Path, PathBuf};

use easyhec_drivers::Frame;
use nalgebra::Isometry3;
use serde::Serialize;

use super::RoundRecord;
use crate::error::{Error, Result};
use crate::geometry::to_rows;
use crate::io::{write_atomic, write_json_atomic};
use crate::mask::Mask;
use crate::run::{
    mask_file_name, CameraEntry, PoseEntry, RobotEntry, RunFile, ViewEntry, RUN_FORMAT,
};
use crate::time::rfc3339;

/// Writes the run directory incrementally.
pub struct Recorder {
    dir: PathBuf,
    run: RunFile,
}

impl Recorder {
    /// Starts a run directory (refuses one that already holds a run).
    pub fn create(
        dir: &Path,
        robot: RobotEntry,
        camera: CameraEntry,
        guess: Option<Isometry3<f64>>,
    ) -> Result<Recorder> {
        if dir.join("run.json").exists() {
            return Err(Error::input(
                dir,
                "--out",
                "already holds a run.json: choose a new folder (nothing recorded is overwritten)",
            ));
        }
        std::fs::create_dir_all(dir.join("views"))
            .map_err(|e| Error::io(dir, format!("cannot create the run folder: {e}")))?;
        Ok(Recorder {
            dir: dir.to_path_buf(),
            run: RunFile {
                format: RUN_FORMAT.into(),
                robot,
                camera,
                initial_guess: guess.map(|g| PoseEntry {
                    camera_from_base: to_rows(&g),
                }),
                views: Vec::new(),
            },
        })
    }

    /// The run folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Writes a view's frame and mask, then `run.json`; returns its index.
    pub fn add_view(&mut self, joints: &[f64], frame: &Frame, mask: &Mask) -> Result<usize> {
        let i = self.run.views.len();
        let image_rel = format!("views/{i:03}.png");
        let mask_rel = format!("views/{}", mask_file_name(i));
        let img = image::RgbImage::from_raw(frame.width, frame.height, frame.rgb.clone())
            .ok_or_else(|| {
                Error::Hardware(format!(
                    "camera frame has {} bytes for {}x{} RGB",
                    frame.rgb.len(),
                    frame.width,
                    frame.height
                ))
            })?;
        let mut png = std::io::Cursor::new(Vec::new());
        img.write_to(&mut png, image::ImageFormat::Png)
            .map_err(|e| Error::io(self.dir.join(&image_rel), e))?;
        write_atomic(&self.dir.join(&image_rel), png.get_ref())?;
        write_atomic(&self.dir.join(&mask_rel), &mask.to_png_bytes())?;
        self.run.views.push(ViewEntry {
            joints: joints.to_vec(),
            mask: Some(mask_rel),
            image: Some(image_rel),
            captured_at: Some(rfc3339(frame.captured_at)),
        });
        write_json_atomic(&self.dir.join("run.json"), &self.run)?;
        Ok(i)
    }

    /// Replaces view `i`'s mask (a context-aware segmenter re-segmented it with more views
    /// or a better estimate): written atomically, the frame and `run.json` untouched.
    pub fn replace_mask(&self, i: usize, mask: &Mask) -> Result<()> {
        let Some(rel) = self.run.views.get(i).and_then(|v| v.mask.as_ref()) else {
            return Err(Error::Solve(format!(
                "re-segmented view {i}, which the run does not hold"
            )));
        };
        write_atomic(&self.dir.join(rel), &mask.to_png_bytes())
    }

    /// Writes `rounds.json`.
    pub fn write_rounds(&self, rounds: &[RoundRecord]) -> Result<()> {
        #[derive(Serialize)]
        struct Rounds<'a> {
            format: &'static str,
            rounds: &'a [RoundRecord],
        }
        write_json_atomic(
            &self.dir.join("rounds.json"),
            &Rounds {
                format: "easyhec-rounds/1",
                rounds,
            },
        )
    }
}

pub(super) fn absolute(p: &Path) -> String {
    std::fs::canonicalize(p)
        .unwrap_or_else(|_| p.to_path_buf())
        .display()
        .to_string()
}

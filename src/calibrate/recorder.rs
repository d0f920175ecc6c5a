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
use crate::run::rig::{
    FrameFiles, RigCameraEntry, RigRunFile, RigViewEntry, RunLayout, RIG_RUN_FORMAT,
};
use crate::run::{
    mask_file_name, CameraEntry, PoseEntry, RobotEntry, RunFile, ViewEntry, RUN_FORMAT,
};
use crate::time::rfc3339;

/// A camera as the recorder writes it: name, entry and starting pose.
pub struct RecordedCamera {
    /// The camera's name (a folder under `views/` in a rig).
    pub name: String,
    /// Intrinsics and mount.
    pub entry: CameraEntry,
    /// Starting pose, when the run has one.
    pub guess: Option<Isometry3<f64>>,
}

/// Writes the run directory incrementally: `easyhec-run/1` for a `[camera]` table,
/// `easyhec-run/2` for `[[camera]]` tables (each camera's files under `views/<name>/`).
pub struct Recorder {
    dir: PathBuf,
    run: RunFile,
    rig: Option<RigRunFile>,
}

impl Recorder {
    /// Starts a run directory (refuses one that already holds a run).
    pub fn create(
        dir: &Path,
        robot: RobotEntry,
        cameras: Vec<RecordedCamera>,
        layout: RunLayout,
    ) -> Result<Recorder> {
        if dir.join("run.json").exists() {
            return Err(Error::input(
                dir,
                "--out",
                "already holds a run.json: choose a new folder (nothing recorded is overwritten)",
            ));
        }
        let pose = |g: &Option<Isometry3<f64>>| {
            g.map(|g| PoseEntry {
                camera_from_base: to_rows(&g),
            })
        };
        let first = cameras
            .first()
            .ok_or_else(|| Error::Solve("a run needs at least one camera".into()))?;
        let run = RunFile {
            format: RUN_FORMAT.into(),
            robot: robot.clone(),
            camera: first.entry.clone(),
            initial_guess: pose(&first.guess),
            views: Vec::new(),
        };
        let rig = (layout == RunLayout::NamedCameras).then(|| RigRunFile {
            format: RIG_RUN_FORMAT.into(),
            robot,
            cameras: cameras
                .iter()
                .map(|c| RigCameraEntry {
                    name: c.name.clone(),
                    camera: c.entry.clone(),
                    initial_guess: pose(&c.guess),
                })
                .collect(),
            views: Vec::new(),
        });
        let folders: Vec<PathBuf> = match &rig {
            None => vec![dir.join("views")],
            Some(r) => r
                .cameras
                .iter()
                .map(|c| dir.join("views").join(&c.name))
                .collect(),
        };
        for f in folders {
            std::fs::create_dir_all(&f)
                .map_err(|e| Error::io(dir, format!("cannot create the run folder: {e}")))?;
        }
        Ok(Recorder {
            dir: dir.to_path_buf(),
            run,
            rig,
        })
    }

    /// The run folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Writes every camera's frame and mask of a view (one pair per camera, in order), then
    /// `run.json`; returns the view's index.
    pub fn add_view(&mut self, joints: &[f64], frames: &[(&Frame, &Mask)]) -> Result<usize> {
        let i = self.run.views.len();
        let folders: Vec<String> = match &self.rig {
            None => vec!["views".into()],
            Some(r) => r
                .cameras
                .iter()
                .map(|c| format!("views/{}", c.name))
                .collect(),
        };
        let mut files = Vec::with_capacity(frames.len());
        for (folder, (frame, mask)) in folders.iter().zip(frames) {
            let image_rel = format!("{folder}/{i:03}.png");
            let mask_rel = format!("{folder}/{}", mask_file_name(i));
            write_frame(&self.dir.join(&image_rel), frame)?;
            write_atomic(&self.dir.join(&mask_rel), &mask.to_png_bytes())?;
            files.push(FrameFiles {
                mask: Some(mask_rel),
                image: Some(image_rel),
            });
        }
        let captured_at = frames.first().map(|(f, _)| rfc3339(f.captured_at));
        let first = files.first().cloned().unwrap_or(FrameFiles {
            mask: None,
            image: None,
        });
        self.run.views.push(ViewEntry {
            joints: joints.to_vec(),
            mask: first.mask,
            image: first.image,
            captured_at: captured_at.clone(),
        });
        match &mut self.rig {
            None => write_json_atomic(&self.dir.join("run.json"), &self.run)?,
            Some(rig) => {
                rig.views.push(RigViewEntry {
                    joints: joints.to_vec(),
                    captured_at,
                    frames: rig
                        .cameras
                        .iter()
                        .map(|c| c.name.clone())
                        .zip(files)
                        .collect(),
                });
                write_json_atomic(&self.dir.join("run.json"), rig)?;
            }
        }
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

/// A frame as a PNG, written atomically.
fn write_frame(path: &Path, frame: &Frame) -> Result<()> {
    let img = image::RgbImage::from_raw(frame.width, frame.height, frame.rgb.clone()).ok_or_else(
        || {
            Error::Hardware(format!(
                "camera frame has {} bytes for {}x{} RGB",
                frame.rgb.len(),
                frame.width,
                frame.height
            ))
        },
    )?;
    let mut png = std::io::Cursor::new(Vec::new());
    img.write_to(&mut png, image::ImageFormat::Png)
        .map_err(|e| Error::io(path, e))?;
    write_atomic(path, png.get_ref())
}

pub(super) fn absolute(p: &Path) -> String {
    std::fs::canonicalize(p)
        .unwrap_or_else(|_| p.to_path_buf())
        .display()
        .to_string()
}

//! The `easyhec-run/1` run directory and the `easyhec-result/1` result (docs: docs/formats.md).
//!
//! Readers accept exactly the documented fields and ignore unknown ones; every validation
//! failure names the file and the field.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

use crate::camera::{Intrinsics, LensWarp};
use crate::config::Mount;
use crate::error::{Error, Result};
use crate::geometry::{from_rows, to_rows};
use crate::mask::Mask;
use crate::robot::{RobotModel, RobotSource};

mod checks;
pub mod rig;
mod uncertainty;

pub use checks::{
    available_memory_bytes, MAX_RUN_JOINTS, MAX_RUN_VIEWS, SOLVE_BYTES_PER_VIEW_PIXEL,
};
pub(crate) use checks::{check_mask_coverage, check_run_file, check_solve_memory, inside_run};
pub use uncertainty::{MaskOffsetEntry, UncertaintyEntry, UncertaintyTerms};

/// Run-directory format tag.
pub const RUN_FORMAT: &str = "easyhec-run/1";

/// A view's mask file name (`007.mask.png`): in a run folder's `views/`, and in a solve's
/// `--masks-out` folder, which readers pair with the run's views by it.
pub fn mask_file_name(view: usize) -> String {
    format!("{view:03}.mask.png")
}
/// Result format tag.
pub const RESULT_FORMAT: &str = "easyhec-result/1";

/// Reads a JSON file and checks its `format` tag; errors name the line or the field.
fn read_tagged_json(path: &Path, tag: &str) -> Result<serde_json::Value> {
    let text = crate::io::read_text_input(path)?;
    parse_tagged_json(&text, path, tag)
}

/// [`read_tagged_json`] on text already read.
fn parse_tagged_json(text: &str, path: &Path, tag: &str) -> Result<serde_json::Value> {
    let value = parse_json(text, path)?;
    match value.get("format").and_then(|f| f.as_str()) {
        Some(t) if t == tag => Ok(value),
        Some(other) => Err(Error::input(
            path,
            "format",
            format!("unknown format version '{other}': this easyhec reads {tag}"),
        )),
        None => Err(Error::input(
            path,
            "format",
            format!("missing: add \"format\": \"{tag}\""),
        )),
    }
}

/// Parses JSON text; a syntax error names the line and column.
fn parse_json(text: &str, path: &Path) -> Result<serde_json::Value> {
    serde_json::from_str(text).map_err(|e| {
        Error::input(
            path,
            format!("line {} column {}", e.line(), e.column()),
            format!("invalid JSON: {e} (NaN and Infinity are not JSON numbers)"),
        )
    })
}

/// Deserialises `value`, naming the field path of the first mismatch (`views[2].joints[1]`)
/// instead of serde's bare "invalid type: null, expected f64".
fn from_value_at<T: serde::de::DeserializeOwned>(
    path: &Path,
    value: serde_json::Value,
) -> Result<T> {
    serde_path_to_error::deserialize(value).map_err(|e| {
        let field = e.path().to_string();
        let field = if field == "." {
            "(top level)".to_string()
        } else {
            field
        };
        Error::input(path, field, e.into_inner().to_string())
    })
}

/// `run.json` → `robot`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RobotEntry {
    /// URDF path, relative to the run folder or absolute.
    pub urdf: String,
    /// `package://NAME` roots.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub package_dirs: BTreeMap<String, String>,
    /// Folders searched for ROS packages, relative to the run folder or absolute.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub package_paths: Vec<String>,
    /// Frame `camera_from_base` refers to.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub base_link: Option<String>,
    /// Links not rendered.
    #[serde(default, deserialize_with = "crate::config::robot::link_names")]
    pub ignore_links: Vec<String>,
    /// Actuated joints, in the order of each view's `joints`.
    pub joints: Vec<String>,
    /// Arguments of a `.xacro` description.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub xacro_args: BTreeMap<String, String>,
}

/// `run.json` → `camera`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct CameraEntry {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Focal length x, pixels.
    pub fx: f64,
    /// Focal length y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// `plumb_bob` or absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distortion_model: Option<String>,
    /// `k1 k2 p1 p2 k3`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distortion: Option<Vec<f64>>,
    /// Where the camera is fixed: absent or `"fixed"`, or `{"link": "<link>"}` for a camera
    /// on a link (the solve then finds `camera_from_<link>`, see docs/mounts.md).
    #[serde(default, skip_serializing_if = "Mount::is_fixed")]
    pub mount: Mount,
}

impl CameraEntry {
    /// The entry describing `camera` (distortion written as `plumb_bob` when present).
    pub fn of(camera: &Intrinsics) -> CameraEntry {
        CameraEntry {
            width: camera.width,
            height: camera.height,
            fx: camera.fx,
            fy: camera.fy,
            cx: camera.cx,
            cy: camera.cy,
            distortion_model: camera.distortion.map(|_| "plumb_bob".to_string()),
            distortion: camera.distortion.map(|d| d.to_vec()),
            mount: Mount::Fixed,
        }
    }
}

/// `ground_truth.json`, written beside (never inside) `run.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct GroundTruth {
    /// Always `easyhec-truth/1`.
    pub format: String,
    /// True `camera_from_base`.
    pub camera_from_base: [[f64; 4]; 4],
    /// True joint vectors per view.
    pub true_joints: Vec<Vec<f64>>,
    /// The noise model used.
    pub noise: crate::config::NoiseModel,
    /// The seed.
    pub seed: u64,
    /// The scene dressing of the colour frames, when the run has them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scene: Option<crate::config::SceneSettings>,
}

/// A 4x4 transform holder as the formats write it.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct PoseEntry {
    /// Row-major 4x4, base frame → OpenCV optical frame, metres.
    pub camera_from_base: [[f64; 4]; 4],
}

/// A pose file: any JSON object with a `camera_from_base` 4x4 (row-major), such as a
/// `result.json` or a reference pose; other fields are ignored.
pub fn read_pose_file(path: &Path) -> Result<Isometry3<f64>> {
    Ok(read_pose_file_framed(path)?.0)
}

/// [`read_pose_file`], with the file's `base_link` when it names one (a `result.json` does):
/// the frame its `camera_from_base` starts from.
fn read_pose_file_framed(path: &Path) -> Result<(Isometry3<f64>, Option<String>)> {
    #[derive(Deserialize)]
    struct Framed {
        camera_from_base: [[f64; 4]; 4],
        #[serde(default)]
        base_link: Option<String>,
    }
    let text = crate::io::read_text_input(path)?;
    let entry: Framed = serde_json::from_str(&text)
        .map_err(|e| Error::input(path, "camera_from_base", e.to_string()))?;
    let pose = from_rows(&entry.camera_from_base)
        .map_err(|m| Error::input(path, "camera_from_base", m))?;
    Ok((pose, entry.base_link))
}

/// [`load_run_with`], starting from the pose in `guess_file` ([`read_pose_file`]) instead of
/// `run.json`'s `initial_guess`, which stays as it is on disk. A run whose camera is on a
/// link needs a guess, and this one counts. A file that names its `base_link` must name the
/// frame the run solves from (the robot's base, or the camera's link): a wrist camera's
/// `camera_from_link6` is no guess for a fixed camera.
pub fn load_run_with_guess(
    path: &Path,
    mask_source: MaskSource,
    guess_file: &Path,
) -> Result<LoadedRun> {
    let (pose, frame) = read_pose_file_framed(guess_file)?;
    let (json, dir) = run_paths(path);
    let mut file = RunFile::read(&json)?;
    file.initial_guess = Some(PoseEntry {
        camera_from_base: to_rows(&pose),
    });
    let run = load_run_file(json, dir, file, mask_source)?;
    let solved_from = &run.robot.links[run.robot.base];
    match frame {
        Some(f) if &f != solved_from => Err(Error::input(
            guess_file,
            "base_link",
            format!("is '{f}', but this run solves the camera from '{solved_from}'; allowed: a pose from '{solved_from}' (or a file without base_link)"),
        )),
        _ => Ok(run),
    }
}

/// `run.json` → `views[i]`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct ViewEntry {
    /// Joint positions (rad / m) in `robot.joints` order.
    pub joints: Vec<f64>,
    /// 8-bit grey mask PNG, relative to the run folder.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mask: Option<String>,
    /// Colour frame, relative to the run folder.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub image: Option<String>,
    /// RFC 3339 capture time.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub captured_at: Option<String>,
}

/// `run.json`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RunFile {
    /// Always [`RUN_FORMAT`].
    pub format: String,
    /// The robot.
    pub robot: RobotEntry,
    /// The camera.
    pub camera: CameraEntry,
    /// Optional starting pose.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub initial_guess: Option<PoseEntry>,
    /// The recorded views.
    pub views: Vec<ViewEntry>,
}

impl RunFile {
    /// Reads and parses `run.json` (format version checked; content checked by [`load_run`]).
    pub fn read(path: &Path) -> Result<RunFile> {
        let text = crate::io::read_text_input(path)?;
        RunFile::parse(&text, path)
    }

    /// Parses `run.json` text; `path` is what errors name.
    pub fn parse(text: &str, path: &Path) -> Result<RunFile> {
        let value = parse_tagged_json(text, path, RUN_FORMAT)?;
        from_value_at(path, value)
    }

    /// Every check of the file's content that needs no robot model: intrinsics, joint names,
    /// view counts and values, repeated views, paths inside `dir` (the run folder) and the
    /// memory a solve would need. Returns the camera.
    pub fn check(&self, path: &Path, dir: &Path) -> Result<Intrinsics> {
        let camera = self.camera(path)?;
        checks::check_run_file(self, path, dir)?;
        Ok(camera)
    }

    /// Camera model described by this run.
    pub fn camera(&self, path: &Path) -> Result<Intrinsics> {
        let c = &self.camera;
        for (name, v) in [("fx", c.fx), ("fy", c.fy)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::input(
                    path,
                    format!("camera.{name}"),
                    format!("must be a positive number of pixels, got {v}"),
                ));
            }
        }
        for (name, v) in [("cx", c.cx), ("cy", c.cy)] {
            if !v.is_finite() {
                return Err(Error::input(
                    path,
                    format!("camera.{name}"),
                    "must be finite",
                ));
            }
        }
        if c.width == 0 || c.height == 0 {
            return Err(Error::input(
                path,
                "camera.width/height",
                "image size must be positive",
            ));
        }
        let distortion = match (&c.distortion_model, &c.distortion) {
            (None, None) => None,
            (Some(m), _) if m != "plumb_bob" => {
                return Err(Error::input(
                    path,
                    "camera.distortion_model",
                    format!("unsupported model '{m}': use plumb_bob"),
                ))
            }
            (_, Some(d)) => {
                if d.len() != 5 || d.iter().any(|k| !k.is_finite()) {
                    return Err(Error::input(
                        path,
                        "camera.distortion",
                        "plumb_bob needs 5 finite coefficients k1 k2 p1 p2 k3",
                    ));
                }
                Some([d[0], d[1], d[2], d[3], d[4]])
            }
            (Some(_), None) => None,
        };
        let intrinsics = Intrinsics {
            width: c.width,
            height: c.height,
            fx: c.fx,
            fy: c.fy,
            cx: c.cx,
            cy: c.cy,
            distortion,
        };
        if let Some((field, allowed)) = intrinsics.range_problem() {
            return Err(Error::input(path, format!("camera.{field}"), allowed));
        }
        Ok(intrinsics)
    }
}

/// One view of a loaded run.
#[derive(Clone, Debug)]
pub struct LoadedView {
    /// Index in `run.json`'s views.
    pub index: usize,
    /// Joint vector.
    pub joints: Vec<f64>,
    /// Observed mask resampled into the pinhole image (see [`Intrinsics::undistort_mask`]).
    pub observed: Mask,
    /// Colour frame path, when recorded.
    pub image: Option<PathBuf>,
    /// True when the view has no usable mask yet (image only, or masks ignored): `observed`
    /// is then empty and a segmenter must fill it.
    pub needs_mask: bool,
}

/// A validated run directory with its robot loaded.
#[derive(Debug)]
pub struct LoadedRun {
    /// Folder holding `run.json`.
    pub dir: PathBuf,
    /// The parsed file.
    pub file: RunFile,
    /// The robot model as the camera sees it: rooted at the mount link for a camera on a
    /// link (`RobotModel::seen_from_link`).
    pub robot: RobotModel,
    /// Camera (possibly distorted; masks in `views` are already undistorted).
    pub camera: Intrinsics,
    /// Initial `camera_from_base`, when given.
    pub initial_guess: Option<Isometry3<f64>>,
    /// Views.
    pub views: Vec<LoadedView>,
}

impl LoadedRun {
    /// Every file a solve of this run reads: `run.json`, each view's mask and colour frame,
    /// `ground_truth.json` and the URDF. The outputs of that solve must be none of them.
    pub fn files_read(&self) -> Vec<PathBuf> {
        let mut files = vec![
            self.dir.join("run.json"),
            self.dir.join("ground_truth.json"),
            resolve(&self.dir, &self.file.robot.urdf),
        ];
        for v in &self.file.views {
            files.extend(v.mask.iter().chain(&v.image).map(|f| resolve(&self.dir, f)));
        }
        files
    }
}

fn resolve(dir: &Path, p: &str) -> PathBuf {
    let p = Path::new(p);
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        dir.join(p)
    }
}

/// Loads and validates a run directory (or a path to its `run.json`); every view needs a mask.
pub fn load_run(path: &Path) -> Result<LoadedRun> {
    load_run_with(path, MaskSource::Recorded)
}

/// Where [`load_run_with`] takes each view's mask from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MaskSource {
    /// The recorded mask files; a view without one is an error.
    Recorded,
    /// The recorded mask where there is one; image-only views are left for a segmenter.
    RecordedElseImage,
    /// Every view's image (recorded masks withheld, e.g. to measure a segmenter).
    Image,
}

/// [`load_run`] with a choice of mask source; views left for a segmenter have
/// `needs_mask` set and must have an image.
pub fn load_run_with(path: &Path, mask_source: MaskSource) -> Result<LoadedRun> {
    let (json, dir) = run_paths(path);
    let file = RunFile::read(&json)?;
    load_run_file(json, dir, file, mask_source)
}

/// `run.json` of a run folder (or the file itself), and the folder its paths are relative to.
pub(crate) fn run_paths(path: &Path) -> (PathBuf, PathBuf) {
    let json = if path.is_dir() {
        path.join("run.json")
    } else {
        path.to_path_buf()
    };
    let dir = json
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from("."));
    (json, dir)
}

/// Loads either run version as named cameras: an `easyhec-run/1` run is the one camera
/// `camera`; an `easyhec-run/2` run gives each camera's part, checked as a run of its own,
/// with errors naming the rig's fields.
pub fn load_cameras_with(path: &Path, mask_source: MaskSource) -> Result<Vec<(String, LoadedRun)>> {
    let (json, dir) = run_paths(path);
    if rig::format_of(&json)?.as_deref() != Some(rig::RIG_RUN_FORMAT) {
        let name = crate::config::cameras::SINGLE_CAMERA_NAME.to_string();
        return Ok(vec![(name, load_run_with(path, mask_source)?)]);
    }
    let value = read_tagged_json(&json, rig::RIG_RUN_FORMAT)?;
    let file = rig::RigRunFile::from_value(&json, value)?;
    (0..file.cameras.len())
        .map(|k| {
            let name = file.cameras[k].name.clone();
            load_run_file(json.clone(), dir.clone(), file.camera_run(k), mask_source)
                .map(|run| (name.clone(), run))
                .map_err(|e| match e {
                    Error::Input {
                        file,
                        field,
                        message,
                    } => Error::input(file, rig::rig_field(&field, &name, k), message),
                    other => other,
                })
        })
        .collect()
}

/// The checks and loading of [`load_run_with`] on a parsed file.
fn load_run_file(
    json: PathBuf,
    dir: PathBuf,
    file: RunFile,
    mask_source: MaskSource,
) -> Result<LoadedRun> {
    let camera = file.check(&json, &dir)?;
    let source = RobotSource {
        urdf: resolve(&dir, &file.robot.urdf),
        package_dirs: file
            .robot
            .package_dirs
            .iter()
            .map(|(k, v)| (k.clone(), resolve(&dir, v)))
            .collect(),
        package_paths: file
            .robot
            .package_paths
            .iter()
            .map(|p| resolve(&dir, p))
            .collect(),
        base_link: file.robot.base_link.clone(),
        ignore_links: file.robot.ignore_links.clone(),
        joints: Some(file.robot.joints.clone()),
        xacro_args: file.robot.xacro_args.clone(),
    };
    let robot = match file.camera.mount.link() {
        None => RobotModel::load(&source)?,
        Some(link) => {
            if file.initial_guess.is_none() {
                return Err(Error::input(
                    &json,
                    "initial_guess",
                    format!("is absent: a camera on link '{link}' needs camera_from_{link} to start from (the automatic initialisation searches around a fixed camera only)"),
                ));
            }
            RobotModel::load(&source)?.seen_from_link(link, &json, "camera.mount.link")?
        }
    };
    // A continuous joint has no limit to hold it to: multi-turn encoders read past ±2π.
    let limits: Vec<Option<(f64, f64)>> = robot
        .actuated
        .iter()
        .map(|&i| &robot.joints[i])
        .map(|j| (j.kind != crate::robot::JointKind::Continuous).then_some((j.lower, j.upper)))
        .collect();
    checks::check_joints_within_limits(&file, &limits, &json)?;
    let initial_guess = match &file.initial_guess {
        Some(g) => Some(
            from_rows(&g.camera_from_base)
                .map_err(|m| Error::input(&json, "initial_guess.camera_from_base", m))?,
        ),
        None => None,
    };
    let mut views = Vec::with_capacity(file.views.len());
    for (i, v) in file.views.iter().enumerate() {
        let image = v.image.as_ref().map(|p| dir.join(p));
        let use_image = match mask_source {
            MaskSource::Recorded => false,
            MaskSource::RecordedElseImage => v.mask.is_none(),
            MaskSource::Image => true,
        };
        if use_image {
            match &image {
                Some(p) if p.exists() => {}
                Some(p) => {
                    return Err(Error::input(
                        &json,
                        format!("views[{i}].image"),
                        format!("file {} does not exist", p.display()),
                    ))
                }
                None => {
                    return Err(Error::input(
                        &json,
                        format!("views[{i}].image"),
                        "view has no image to segment: add the frame or a mask",
                    ))
                }
            }
            views.push(LoadedView {
                index: i,
                joints: v.joints.clone(),
                observed: Mask::new(camera.width, camera.height),
                image,
                needs_mask: true,
            });
            continue;
        }
        let Some(mask_rel) = &v.mask else {
            return Err(Error::input(
                &json,
                format!("views[{i}].mask"),
                "view has no mask: pass --segmenter builtin to segment its image",
            ));
        };
        let mask_path = dir.join(mask_rel);
        if !mask_path.exists() {
            return Err(Error::input(
                &json,
                format!("views[{i}].mask"),
                format!("file {} does not exist", mask_path.display()),
            ));
        }
        let mask = Mask::load(&mask_path)?;
        if mask.width != camera.width || mask.height != camera.height {
            return Err(Error::input(
                &mask_path,
                format!("views[{i}].mask"),
                format!(
                    "is {}x{} but camera is {}x{}: masks must have the camera's size",
                    mask.width, mask.height, camera.width, camera.height
                ),
            ));
        }
        checks::check_mask_coverage(&mask, &mask_path, &format!("views[{i}].mask"))?;
        views.push(LoadedView {
            index: i,
            joints: v.joints.clone(),
            observed: camera.undistort_mask(&mask),
            image,
            needs_mask: false,
        });
    }
    Ok(LoadedRun {
        dir,
        file,
        robot,
        camera,
        initial_guess,
        views,
    })
}

/// `easyhec-result/1`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, utoipa::ToSchema)]
pub struct ResultFile {
    /// Always [`RESULT_FORMAT`].
    pub format: String,
    /// Base frame → OpenCV optical frame.
    pub camera_from_base: [[f64; 4]; 4],
    /// Inverse of `camera_from_base`.
    pub base_from_camera: [[f64; 4]; 4],
    /// Frame `camera_from_base` refers to.
    pub base_link: String,
    /// Indices into the run's views, in the order they were added.
    pub views_used: Vec<usize>,
    /// Per-view agreement.
    pub per_view: Vec<PerView>,
    /// 1-sigma about the camera axes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uncertainty: Option<UncertaintyEntry>,
    /// Why the solve or calibration stopped.
    pub stop_reason: String,
    /// Wall-clock timings, seconds.
    pub timings_s: BTreeMap<String, f64>,
    /// The fit left out the robot's outline where its base meets the mount (decided by
    /// `[calibration] mount_contact`): recorded because it moves the pose, so two results are
    /// only comparable when they agree on it. Absent when it did not.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub mount_contact_left_out: bool,
}

/// `per_view[i]`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, utoipa::ToSchema)]
pub struct PerView {
    /// Index into the run's views.
    pub view: usize,
    /// Mask IoU at the estimate.
    pub iou: f64,
}

impl ResultFile {
    /// A result for `camera_from_base`.
    pub fn new(camera_from_base: &Isometry3<f64>, base_link: &str) -> ResultFile {
        ResultFile {
            format: RESULT_FORMAT.into(),
            camera_from_base: to_rows(camera_from_base),
            base_from_camera: to_rows(&camera_from_base.inverse()),
            base_link: base_link.into(),
            views_used: Vec::new(),
            per_view: Vec::new(),
            uncertainty: None,
            stop_reason: String::new(),
            timings_s: BTreeMap::new(),
            mount_contact_left_out: false,
        }
    }

    /// Reads a result file, checking the format tag and the transform.
    pub fn read(path: &Path) -> Result<ResultFile> {
        let value = read_tagged_json(path, RESULT_FORMAT)?;
        let r: ResultFile = from_value_at(path, value)?;
        from_rows(&r.camera_from_base).map_err(|m| Error::input(path, "camera_from_base", m))?;
        if let Some((field, problem)) = r.uncertainty.as_ref().and_then(UncertaintyEntry::problem) {
            return Err(Error::input(path, &field, problem));
        }
        Ok(r)
    }

    /// The transform as a rigid pose (checked by [`ResultFile::read`]; a result built from a
    /// solve holds the solver's own pose).
    pub fn camera_from_base(&self) -> Isometry3<f64> {
        crate::geometry::rigid_from_rows(&self.camera_from_base)
    }
}

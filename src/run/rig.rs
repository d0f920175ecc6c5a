//! `easyhec-run/2` and `easyhec-result/2`: a run and a result of several cameras that shared
//! one arm motion (docs/formats.md). Each camera's part reads as an `easyhec-run/1` run or an
//! `easyhec-result/1` result, so every single-camera check and tool applies to it.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::checks::{MAX_RUN_JOINTS, MAX_RUN_VIEWS};
use super::{
    from_rows, from_value_at, read_tagged_json, CameraEntry, PerView, PoseEntry, ResultFile,
    RobotEntry, RunFile, UncertaintyEntry, ViewEntry, RESULT_FORMAT, RUN_FORMAT,
};
use crate::error::{Error, Result};

/// Rig run format tag.
pub const RIG_RUN_FORMAT: &str = "easyhec-run/2";
/// Rig result format tag.
pub const RIG_RESULT_FORMAT: &str = "easyhec-result/2";

/// `run.json` → `cameras[k]`: a camera's name, its `easyhec-run/1` camera entry, and its
/// starting pose.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RigCameraEntry {
    /// The camera's name (`[[camera]] name`).
    pub name: String,
    /// Intrinsics and mount, as in `easyhec-run/1`.
    #[serde(flatten)]
    pub camera: CameraEntry,
    /// Optional starting pose.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub initial_guess: Option<PoseEntry>,
}

/// One camera's files of a view.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct FrameFiles {
    /// 8-bit grey mask PNG, relative to the run folder.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mask: Option<String>,
    /// Colour frame, relative to the run folder.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub image: Option<String>,
}

/// `run.json` → `views[i]`: the joints once, each camera's frame and mask by name.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RigViewEntry {
    /// Joint positions in `robot.joints` order.
    pub joints: Vec<f64>,
    /// RFC 3339 time of the first camera's frame.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub captured_at: Option<String>,
    /// Files per camera name.
    pub frames: BTreeMap<String, FrameFiles>,
}

/// `run.json` of a rig.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RigRunFile {
    /// Always [`RIG_RUN_FORMAT`].
    pub format: String,
    /// The robot.
    pub robot: RobotEntry,
    /// The cameras.
    pub cameras: Vec<RigCameraEntry>,
    /// The recorded views.
    pub views: Vec<RigViewEntry>,
}

impl RigRunFile {
    /// Reads and parses a rig's `run.json` (format version and camera list checked).
    pub fn read(path: &Path) -> Result<RigRunFile> {
        let text = crate::io::read_text_input(path)?;
        let value = super::parse_tagged_json(&text, path, RIG_RUN_FORMAT)?;
        RigRunFile::from_value(path, value)
    }

    /// Parses a rig `run.json` value (format already read), checking the camera list.
    pub fn from_value(path: &Path, value: serde_json::Value) -> Result<RigRunFile> {
        let rig: RigRunFile = from_value_at(path, value)?;
        rig.check_cameras(path)?;
        Ok(rig)
    }

    /// Names that are safe as folders and keys, each once, at most
    /// [`crate::config::cameras::MAX_CAMERAS`]; every view names exactly these cameras.
    fn check_cameras(&self, path: &Path) -> Result<()> {
        let max = crate::config::cameras::MAX_CAMERAS;
        if self.cameras.is_empty() || self.cameras.len() > max {
            return Err(Error::input(
                path,
                "cameras",
                format!("lists {} cameras; allowed: 1 to {max}", self.cameras.len()),
            ));
        }
        check_names(path, self.cameras.iter().map(|c| c.name.as_str()))?;
        self.check_memory(path)?;
        let mut listed: Vec<&String> = self.cameras.iter().map(|c| &c.name).collect();
        listed.sort();
        for (i, v) in self.views.iter().enumerate() {
            // `frames` is a sorted map: its keys compare with the sorted names.
            let named: Vec<&String> = v.frames.keys().collect();
            if named != listed {
                return Err(Error::input(
                    path,
                    format!("views[{i}].frames"),
                    format!("names {named:?}; allowed: exactly the cameras {listed:?}"),
                ));
            }
            check_distinct_files(path, i, v)?;
        }
        Ok(())
    }

    /// Every camera's masks are held at once when a rig is solved: the memory estimate of
    /// `easyhec-run/1` (`run::check_run_file`) summed over the cameras.
    fn check_memory(&self, path: &Path) -> Result<()> {
        let pixels: u64 = self
            .cameras
            .iter()
            .map(|c| u64::from(c.camera.width) * u64::from(c.camera.height))
            .fold(0, u64::saturating_add);
        let need = pixels
            .saturating_mul(self.views.len() as u64)
            .saturating_mul(super::SOLVE_BYTES_PER_VIEW_PIXEL);
        match super::available_memory_bytes() {
            Some(available) if need > available => Err(Error::input(
                path,
                "views",
                format!(
                    "{} views of {} cameras need about {:.1} GB to solve; this machine has {:.1} GB available: use fewer views or smaller images",
                    self.views.len(),
                    self.cameras.len(),
                    need as f64 / 1e9,
                    available as f64 / 1e9
                ),
            )),
            _ => Ok(()),
        }
    }

    /// Camera `k`'s part as an `easyhec-run/1` file: paths stay relative to the same folder.
    pub fn camera_run(&self, k: usize) -> RunFile {
        let cam = &self.cameras[k];
        RunFile {
            format: RUN_FORMAT.into(),
            robot: self.robot.clone(),
            camera: cam.camera.clone(),
            initial_guess: cam.initial_guess.clone(),
            views: self
                .views
                .iter()
                .map(|v| {
                    let files = v.frames.get(&cam.name);
                    ViewEntry {
                        joints: v.joints.clone(),
                        mask: files.and_then(|f| f.mask.clone()),
                        image: files.and_then(|f| f.image.clone()),
                        captured_at: v.captured_at.clone(),
                    }
                })
                .collect(),
        }
    }
}

/// A field of camera `name`'s part (`views[2].mask`, `camera.fx`) as the rig file spells it
/// (`views[2].frames.left.mask`, `cameras[1].fx`), so an error names the rig's own field.
pub fn rig_field(field: &str, name: &str, k: usize) -> String {
    if let Some(rest) = field.strip_prefix("camera.") {
        return format!("cameras[{k}].{rest}");
    }
    if field.starts_with("initial_guess") {
        return format!("cameras[{k}].{field}");
    }
    if let Some((view, tail)) = field.split_once("].") {
        if view.starts_with("views[") && (tail.starts_with("mask") || tail.starts_with("image")) {
            return format!("{view}].frames.{name}.{tail}");
        }
    }
    field.to_string()
}

/// `result.json` → `cameras[k]`: one camera's transform and its fit.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, utoipa::ToSchema)]
pub struct CameraResult {
    /// The camera's name.
    pub name: String,
    /// Base frame → the camera's OpenCV optical frame.
    pub camera_from_base: [[f64; 4]; 4],
    /// Inverse of `camera_from_base`.
    pub base_from_camera: [[f64; 4]; 4],
    /// Frame `camera_from_base` refers to.
    pub base_link: String,
    /// Indices into the run's views.
    pub views_used: Vec<usize>,
    /// Per-view agreement.
    pub per_view: Vec<PerView>,
    /// 1-sigma about the camera axes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uncertainty: Option<UncertaintyEntry>,
    /// Why this camera stopped asking for views.
    #[serde(default)]
    pub stop_reason: String,
    /// As `easyhec-result/1`'s: the fit left out the mount contact.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub mount_contact_left_out: bool,
}

/// `easyhec-result/2`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, utoipa::ToSchema)]
pub struct RigResultFile {
    /// Always [`RIG_RESULT_FORMAT`].
    pub format: String,
    /// One entry per camera, in the config's order.
    pub cameras: Vec<CameraResult>,
    /// Why the calibration stopped.
    pub stop_reason: String,
    /// Wall-clock timings, seconds.
    pub timings_s: BTreeMap<String, f64>,
    /// Each view's joint correction estimated from every camera together, when it ran.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub joint_corrections: Option<JointCorrections>,
}

/// Truth format tag of a simulated rig's run.
pub const RIG_TRUTH_FORMAT: &str = "easyhec-truth/2";

/// `ground_truth.json` beside a simulated rig's run (never inside `run.json`): each camera's
/// true transform, so `easyhec solve` of the run can say how far each camera landed.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RigGroundTruth {
    /// Always [`RIG_TRUTH_FORMAT`].
    pub format: String,
    /// Each camera's name and true transform.
    pub cameras: Vec<CameraTruth>,
    /// Standard deviation of the simulated encoder noise, radians (0 for a driver-backed arm,
    /// whose readings count as exact).
    pub encoder_noise_rad: f64,
    /// The calibration's seed.
    pub seed: u64,
}

/// `ground_truth.json` → `cameras[k]`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct CameraTruth {
    /// The camera's name.
    pub name: String,
    /// The transform `camera_from_mount` is: `camera_from_base`, or `camera_from_<link>` for
    /// a camera on a link.
    pub transform: String,
    /// The true transform from the mount's frame to the camera's optical frame, rows of a
    /// 4x4 matrix.
    pub camera_from_mount: [[f64; 4]; 4],
}

impl RigGroundTruth {
    /// The rig truth at `path`. Anything else (no file, another format, bad JSON) gives
    /// `None`: a truth file is a simulator's extra, never an input a solve depends on.
    pub fn read(path: &Path) -> Option<RigGroundTruth> {
        let text = crate::io::read_text_input(path).ok()?;
        let truth: RigGroundTruth = serde_json::from_str(&text).ok()?;
        (truth.format == RIG_TRUTH_FORMAT).then_some(truth)
    }

    /// Camera `name`'s true transform, when the file has one for that camera and the same
    /// `transform` (a truth about another mount says nothing about this solve).
    pub fn camera_from_mount(
        &self,
        name: &str,
        transform: &str,
    ) -> Option<nalgebra::Isometry3<f64>> {
        let camera = self
            .cameras
            .iter()
            .find(|c| c.name == name && c.transform == transform)?;
        from_rows(&camera.camera_from_mount).ok()
    }
}

/// `result.json` → `joint_corrections`: each view's joint error as the cameras together saw
/// it (docs/cameras.md, "Shared joint correction"), from the correction's last round: the
/// joints every re-solved camera rests on (a camera that kept its own solve, as the run's
/// notes say, rests on the recorded joints). It is not an encoder calibration: only what
/// moves the silhouettes shows, so the wrist joints' corrections stay near 0; the base
/// joint's error common to every view cannot show at all, and other joints' common errors
/// only weakly.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, utoipa::ToSchema)]
pub struct JointCorrections {
    /// Indices into the run's views, in the order of `per_view_rad`.
    pub views: Vec<usize>,
    /// Each view's correction, true minus recorded joints, radians (one entry per joint).
    pub per_view_rad: Vec<Vec<f64>>,
}

impl JointCorrections {
    /// Every correction finite (a result holding anything else could not be read back).
    pub fn is_finite(&self) -> bool {
        self.per_view_rad.iter().flatten().all(|v| v.is_finite())
    }

    /// The first entry no solve could have written, as `(field path, problem)`: one
    /// correction per listed view, each view listed once and within the run formats' bound,
    /// every correction as long as the others (1 to [`MAX_RUN_JOINTS`] joints) and finite.
    fn problem(&self) -> Option<(String, String)> {
        let n = self.views.len();
        if n > MAX_RUN_VIEWS || n != self.per_view_rad.len() {
            return Some((
                "joint_corrections.views".into(),
                format!(
                    "lists {n} views for {} corrections; allowed: at most {MAX_RUN_VIEWS}, one per entry of per_view_rad",
                    self.per_view_rad.len()
                ),
            ));
        }
        for (i, &v) in self.views.iter().enumerate() {
            let problem = if v >= MAX_RUN_VIEWS {
                format!("is {v}; allowed: a view index below {MAX_RUN_VIEWS}")
            } else if self.views[..i].contains(&v) {
                format!("is {v}, listed twice; allowed: each view once")
            } else {
                continue;
            };
            return Some((format!("joint_corrections.views[{i}]"), problem));
        }
        let nq = self.per_view_rad.first().map_or(1, Vec::len);
        for (i, row) in self.per_view_rad.iter().enumerate() {
            let field = format!("joint_corrections.per_view_rad[{i}]");
            if row.len() != nq || row.is_empty() || row.len() > MAX_RUN_JOINTS {
                let problem = format!(
                    "has {} joints; allowed: 1 to {MAX_RUN_JOINTS}, as many as the first entry",
                    row.len()
                );
                return Some((field, problem));
            }
            if let Some(v) = row.iter().find(|v| !v.is_finite()) {
                return Some((field, format!("holds {v}; allowed: finite radians")));
            }
        }
        None
    }
}

impl CameraResult {
    /// The entry of camera `name` from its single-camera result.
    pub fn of(name: &str, r: &ResultFile) -> CameraResult {
        CameraResult {
            name: name.into(),
            camera_from_base: r.camera_from_base,
            base_from_camera: r.base_from_camera,
            base_link: r.base_link.clone(),
            views_used: r.views_used.clone(),
            per_view: r.per_view.clone(),
            uncertainty: r.uncertainty.clone(),
            stop_reason: r.stop_reason.clone(),
            mount_contact_left_out: r.mount_contact_left_out,
        }
    }

    /// This camera as an `easyhec-result/1` (what export and the tf tools read).
    pub fn as_result(&self, timings_s: &BTreeMap<String, f64>) -> ResultFile {
        ResultFile {
            format: RESULT_FORMAT.into(),
            camera_from_base: self.camera_from_base,
            base_from_camera: self.base_from_camera,
            base_link: self.base_link.clone(),
            views_used: self.views_used.clone(),
            per_view: self.per_view.clone(),
            uncertainty: self.uncertainty.clone(),
            stop_reason: self.stop_reason.clone(),
            timings_s: timings_s.clone(),
            mount_contact_left_out: self.mount_contact_left_out,
        }
    }
}

impl RigResultFile {
    /// Reads a rig result, checking names, every transform and every uncertainty.
    pub fn read(path: &Path) -> Result<RigResultFile> {
        let value = read_tagged_json(path, RIG_RESULT_FORMAT)?;
        let r: RigResultFile = from_value_at(path, value)?;
        check_names(path, r.cameras.iter().map(|c| c.name.as_str()))?;
        for (k, c) in r.cameras.iter().enumerate() {
            from_rows(&c.camera_from_base)
                .map_err(|m| Error::input(path, format!("cameras[{k}].camera_from_base"), m))?;
            if let Some((field, problem)) =
                c.uncertainty.as_ref().and_then(UncertaintyEntry::problem)
            {
                return Err(Error::input(path, format!("cameras[{k}].{field}"), problem));
            }
        }
        if r.cameras.is_empty() {
            return Err(Error::input(
                path,
                "cameras",
                "is empty; allowed: 1 to 8 cameras",
            ));
        }
        if let Some((field, problem)) = r.joint_corrections.as_ref().and_then(|j| j.problem()) {
            return Err(Error::input(path, field, problem));
        }
        Ok(r)
    }
}

/// No two cameras of view `i` name the same file: each camera's frame is its own.
fn check_distinct_files(path: &Path, i: usize, view: &RigViewEntry) -> Result<()> {
    let mut seen: Vec<&String> = Vec::new();
    for (name, files) in &view.frames {
        for (kind, file) in [("mask", &files.mask), ("image", &files.image)] {
            let Some(file) = file else { continue };
            if seen.contains(&file) {
                return Err(Error::input(
                    path,
                    format!("views[{i}].frames.{name}.{kind}"),
                    format!("'{file}' is named twice in this view; allowed: one file per camera and kind"),
                ));
            }
            seen.push(file);
        }
    }
    Ok(())
}

/// Every `cameras[k].name` safe as a folder and a key, and listed once.
fn check_names<'n>(path: &Path, names: impl Iterator<Item = &'n str>) -> Result<()> {
    let mut seen: Vec<&str> = Vec::new();
    for (k, name) in names.enumerate() {
        let problem = crate::config::cameras::name_problem(name)
            .or_else(|| seen.contains(&name).then(|| "each name once".to_string()));
        if let Some(problem) = problem {
            return Err(Error::input(
                path,
                format!("cameras[{k}].name"),
                format!("is {name:?}; allowed: {problem}"),
            ));
        }
        seen.push(name);
    }
    Ok(())
}

/// How a run directory records its cameras: the one place that reads it from the format tag.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RunLayout {
    /// One camera, unnamed (`easyhec-run/1`).
    OneCamera,
    /// Named cameras (`easyhec-run/2`), even one.
    NamedCameras,
}

impl RunLayout {
    /// The `result.json` format tag this layout writes.
    pub fn result_format(self) -> &'static str {
        match self {
            RunLayout::OneCamera => super::RESULT_FORMAT,
            RunLayout::NamedCameras => RIG_RESULT_FORMAT,
        }
    }

    /// The layout a cell's cameras record: a `[camera]` table one camera, `[[camera]]`
    /// tables named cameras (even one).
    pub fn of_cameras(cameras: &crate::config::CameraSet) -> RunLayout {
        match cameras.tables() {
            crate::config::CameraTables::List => RunLayout::NamedCameras,
            crate::config::CameraTables::One => RunLayout::OneCamera,
        }
    }

    /// The layout of `run` (a folder or its `run.json`).
    pub fn of(run: &Path) -> Result<RunLayout> {
        let (json, _) = super::run_paths(run);
        Ok(match format_of(&json)?.as_deref() {
            Some(RIG_RUN_FORMAT) => RunLayout::NamedCameras,
            _ => RunLayout::OneCamera,
        })
    }
}

/// What a result says of the run as a whole, beside each camera's own record.
#[derive(Clone, Debug)]
pub struct RunSummary {
    /// Why the run stopped.
    pub stop_reason: String,
    /// Wall-clock timings, seconds.
    pub timings_s: BTreeMap<String, f64>,
    /// Each view's joint correction from every camera together, when it ran.
    pub joint_corrections: Option<JointCorrections>,
}

/// Writes `out` (atomically) in the result format of `layout`: a run of one camera gets its
/// camera's `easyhec-result/1` record as it is; named cameras get one `easyhec-result/2` with
/// each camera's entry and the run's `summary`.
pub fn write_result(
    layout: RunLayout,
    out: &Path,
    cameras: &[(&str, &ResultFile)],
    summary: RunSummary,
) -> Result<()> {
    match (layout, cameras) {
        (RunLayout::OneCamera, [(_, result)]) => crate::io::write_json_atomic(out, result),
        (RunLayout::OneCamera, _) => Err(Error::Solve(format!(
            "{} camera results for a run of one camera",
            cameras.len()
        ))),
        (RunLayout::NamedCameras, _) => {
            let rig = RigResultFile {
                format: RIG_RESULT_FORMAT.into(),
                cameras: cameras
                    .iter()
                    .map(|(name, r)| CameraResult::of(name, r))
                    .collect(),
                stop_reason: summary.stop_reason,
                timings_s: summary.timings_s,
                joint_corrections: summary.joint_corrections,
            };
            crate::io::write_json_atomic(out, &rig)
        }
    }
}

/// The format tag of a JSON file (`run.json` or `result.json`), so a reader can dispatch;
/// `None` when there is no string tag (the version's own reader then says what to add).
pub fn format_of(path: &Path) -> Result<Option<String>> {
    let text = crate::io::read_text_input(path)?;
    let value = super::parse_json(&text, path)?;
    Ok(value
        .get("format")
        .and_then(|f| f.as_str())
        .map(str::to_string))
}

/// Every camera of a `result.json`, whichever format holds it: what export, publish and the
/// daemon read, so none of them chooses between `easyhec-result/1` and `/2` itself.
#[derive(Clone, Debug)]
pub struct ResultCameras {
    /// The file's format.
    pub layout: RunLayout,
    /// Each camera, in the file's order: one unnamed for `easyhec-result/1`.
    pub cameras: Vec<ResultCamera>,
    /// Why the whole calibration stopped (a camera's own may differ in a list).
    pub stop_reason: String,
}

/// One camera of [`ResultCameras`].
#[derive(Clone, Debug)]
pub struct ResultCamera {
    /// Its name (`None` in a one-camera result).
    pub name: Option<String>,
    /// Its result as an `easyhec-result/1`: its own stop reason, the file's timings.
    pub result: ResultFile,
}

impl ResultCamera {
    /// Its name, empty for the one camera of an `easyhec-result/1`: file and frame names
    /// built from it then carry no camera part.
    pub fn name_or_empty(&self) -> &str {
        self.name.as_deref().unwrap_or_default()
    }
}

impl ResultCameras {
    /// Reads `path` in whichever format it is, with every check of that format's reader.
    pub fn read(path: &Path) -> Result<ResultCameras> {
        if format_of(path)?.as_deref() == Some(RIG_RESULT_FORMAT) {
            let rig = RigResultFile::read(path)?;
            return Ok(ResultCameras {
                layout: RunLayout::NamedCameras,
                cameras: rig
                    .cameras
                    .iter()
                    .map(|c| ResultCamera {
                        name: Some(c.name.clone()),
                        result: c.as_result(&rig.timings_s),
                    })
                    .collect(),
                stop_reason: rig.stop_reason,
            });
        }
        let result = ResultFile::read(path)?;
        Ok(ResultCameras {
            layout: RunLayout::OneCamera,
            stop_reason: result.stop_reason.clone(),
            cameras: vec![ResultCamera { name: None, result }],
        })
    }

    /// The key of `field` of camera `k` in the file: `cameras[k].field` in a list, `field`
    /// for one camera.
    pub fn key(&self, k: usize, field: &str) -> String {
        match self.layout {
            RunLayout::NamedCameras => format!("cameras[{k}].{field}"),
            RunLayout::OneCamera => field.to_string(),
        }
    }

    /// The cameras' names, in order (empty for one unnamed camera).
    pub fn names(&self) -> Vec<&str> {
        self.cameras
            .iter()
            .filter_map(|c| c.name.as_deref())
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rig_json(names: [&str; 2], view_names: [&str; 2]) -> serde_json::Value {
        let camera = |n: &str| serde_json::json!({"name": n, "width": 64, "height": 48, "fx": 60.0, "fy": 60.0, "cx": 31.5, "cy": 23.5});
        let files = |n: &str| serde_json::json!({"mask": format!("views/{n}/000.mask.png")});
        serde_json::json!({
            "format": RIG_RUN_FORMAT,
            "robot": {"urdf": "r.urdf", "joints": ["j1"]},
            "cameras": [camera(names[0]), camera(names[1])],
            "views": [{"joints": [0.0], "frames": {view_names[0]: files(view_names[0]), view_names[1]: files(view_names[1])}}]
        })
    }

    #[test]
    fn a_rig_run_names_its_cameras_once_and_every_view_names_them_all() {
        let path = Path::new("run.json");
        assert!(RigRunFile::from_value(path, rig_json(["a", "b"], ["b", "a"])).is_ok());
        for (value, field) in [
            (rig_json(["a", "a"], ["a", "b"]), "cameras[1].name"),
            (rig_json(["a", "B"], ["a", "B"]), "cameras[1].name"),
            (rig_json(["a", "b"], ["a", "c"]), "views[0].frames"),
            (
                {
                    let mut v = rig_json(["a", "b"], ["a", "b"]);
                    v["views"][0]["frames"]["b"]["mask"] = "views/a/000.mask.png".into();
                    v
                },
                "views[0].frames.b.mask",
            ),
        ] {
            let e = RigRunFile::from_value(path, value).unwrap_err().to_string();
            assert!(e.contains(field), "{e}");
        }
    }

    #[test]
    fn a_camera_parts_field_is_named_as_the_rig_spells_it() {
        assert_eq!(
            rig_field("views[2].mask", "left", 0),
            "views[2].frames.left.mask"
        );
        assert_eq!(rig_field("camera.fx", "left", 1), "cameras[1].fx");
        assert_eq!(
            rig_field("views[0].joints[1]", "left", 0),
            "views[0].joints[1]"
        );
    }
}

//! `easyhec import easyhec`: EasyHeC's offline folder (`color/ mask/ qpos/ K.txt
//! [initial_guess.txt]`) as an `easyhec-run/1` directory.
//!
//! Everything is read and checked before anything is written, the run is built in a temporary
//! folder beside the target and renamed into place at the end, so a bad file leaves nothing
//! behind and an existing run is never half overwritten.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::read_numbers;
use crate::camera::Intrinsics;
use crate::error::{Error, Result};
use crate::io::{write_atomic, write_json_atomic};
use crate::mask::Mask;
use crate::run::{
    CameraEntry, PoseEntry, RobotEntry, RunFile, ViewEntry, MAX_RUN_VIEWS, RUN_FORMAT,
};

/// Options for `easyhec import easyhec`.
#[derive(Clone, Debug)]
pub struct EasyHecImport {
    /// EasyHeC offline folder (`color/ mask/ qpos/ K.txt`).
    pub source: PathBuf,
    /// Output run directory.
    pub out: PathBuf,
    /// URDF path as written into `run.json` (absolute or relative to `out`).
    pub urdf: String,
    /// Actuated joint names in qpos order; extra qpos values (fingers) are dropped.
    pub joints: Vec<String>,
    /// Links not rendered.
    pub ignore_links: Vec<String>,
    /// Initial-guess file (4x4); defaults to `initial_guess.txt` in the source when present.
    pub initial_guess: Option<PathBuf>,
    /// Replace a non-empty `out` (refused otherwise).
    pub force: bool,
}

/// One source view, read and checked.
struct SourceView {
    mask: Mask,
    joints: Vec<f64>,
    color: Option<PathBuf>,
}

/// Converts EasyHeC's offline layout into an `easyhec-run/1` directory.
pub fn import_easyhec(opts: &EasyHecImport) -> Result<RunFile> {
    check_target(&opts.out, &opts.source, opts.force)?;
    check_joint_names(&opts.joints)?;
    let src = &opts.source;
    let k = read_camera_matrix(&src.join("K.txt"))?;
    let views = read_views(src, opts.joints.len())?;
    let (width, height) = (views[0].mask.width, views[0].mask.height);
    let camera = Intrinsics::pinhole(width, height, k[0], k[4], k[2], k[5]);
    if let Some((field, allowed)) = camera.range_problem() {
        return Err(Error::input(src.join("K.txt"), field, allowed));
    }
    let initial_guess = read_initial_guess(opts)?;
    let run = RunFile {
        format: RUN_FORMAT.into(),
        robot: RobotEntry {
            urdf: opts.urdf.clone(),
            package_dirs: BTreeMap::new(),
            package_paths: Vec::new(),
            base_link: None,
            ignore_links: opts.ignore_links.clone(),
            joints: opts.joints.clone(),
            xacro_args: BTreeMap::new(),
        },
        camera: CameraEntry::of(&camera),
        initial_guess,
        views: (0..views.len()).map(|i| view_entry(i, &views[i])).collect(),
    };
    // What `easyhec solve` will check (repeated views, counts), before anything is written.
    crate::run::check_run_file(&run, &opts.out.join("run.json"), &opts.out)?;
    write_run(opts, &run, &views)?;
    Ok(run)
}

/// An existing, non-empty target is refused unless `force`: importing over a run would mix
/// its old files with the new `run.json`.
fn check_target(out: &Path, source: &Path, force: bool) -> Result<()> {
    if let Some(problem) = crate::io::output_dir_problem(out, &[source.to_path_buf()]) {
        return Err(Error::input(out, "--out", problem));
    }
    let non_empty = std::fs::read_dir(out).is_ok_and(|mut d| d.next().is_some());
    if non_empty && !force {
        return Err(Error::input(
            out,
            "--out",
            "exists and is not empty; allowed: a new or empty folder (pass --force to replace it)",
        ));
    }
    if out.exists() && !out.is_dir() {
        return Err(Error::input(out, "--out", "is not a folder"));
    }
    // --force replaces a run, never any other folder (a typo must not delete a home folder).
    if non_empty && !out.join("run.json").is_file() {
        return Err(Error::input(
            out,
            "--out",
            "holds no run.json, so it is no run to replace; allowed: a new or empty folder, or a run folder with --force",
        ));
    }
    Ok(())
}

fn check_joint_names(joints: &[String]) -> Result<()> {
    if joints.is_empty() {
        return Err(Error::Usage("--joints: name at least one joint".into()));
    }
    for (k, n) in joints.iter().enumerate() {
        if joints[..k].contains(n) {
            return Err(Error::Usage(format!(
                "--joints: '{n}' is listed twice; allowed: each joint once"
            )));
        }
    }
    Ok(())
}

/// `K.txt` as the 9 numbers of `[fx 0 cx; 0 fy cy; 0 0 1]`, row-major. A transposed matrix
/// (cx, cy in the last row) or a projection matrix is refused here, not read as cx = cy = 0.
fn read_camera_matrix(path: &Path) -> Result<Vec<f64>> {
    let k = read_numbers(path)?;
    if k.len() != 9 {
        return Err(Error::input(
            path,
            "K",
            format!("has {} numbers; allowed: a 3x3 matrix (9 numbers)", k.len()),
        ));
    }
    let zeros_ok = [1, 3, 6, 7].iter().all(|&i| k[i] == 0.0);
    if !zeros_ok || (k[8] - 1.0).abs() > 1e-9 {
        return Err(Error::input(
            path,
            "K",
            format!(
                "{k:?} is not [fx 0 cx; 0 fy cy; 0 0 1] row by row (transposed, or with skew?)"
            ),
        ));
    }
    Ok(k)
}

/// Masks and qpos files paired by file stem (`mask/0007.png` with `qpos/0007.txt`); any file
/// without its partner is an error, never a pairing by sort order.
fn read_views(src: &Path, joint_count: usize) -> Result<Vec<SourceView>> {
    let masks = files_by_stem(&src.join("mask"), "png")?;
    let qpos = files_by_stem(&src.join("qpos"), "txt")?;
    if masks.is_empty() {
        return Err(Error::input(src.join("mask"), "mask", "no mask PNGs found"));
    }
    if masks.len() > MAX_RUN_VIEWS {
        return Err(Error::input(
            src.join("mask"),
            "mask",
            format!(
                "holds {} masks; allowed: at most {MAX_RUN_VIEWS}",
                masks.len()
            ),
        ));
    }
    for (stem, path) in &qpos {
        if !masks.contains_key(stem) {
            return Err(Error::input(
                path,
                "qpos",
                format!("has no mask/{stem}.png to pair with"),
            ));
        }
    }
    check_mask_headers(src, &masks)?;
    let mut views: Vec<SourceView> = Vec::with_capacity(masks.len());
    for (stem, mask_path) in &masks {
        let Some(qpos_path) = qpos.get(stem) else {
            return Err(Error::input(
                mask_path,
                "mask",
                format!("has no qpos/{stem}.txt to pair with"),
            ));
        };
        views.push(read_view(src, stem, mask_path, qpos_path, joint_count)?);
    }
    Ok(views)
}

fn read_view(
    src: &Path,
    stem: &str,
    mask_path: &Path,
    qpos_path: &Path,
    joint_count: usize,
) -> Result<SourceView> {
    let mask = Mask::load(mask_path)?;
    crate::run::check_mask_coverage(&mask, mask_path, "mask")?;
    let q = read_numbers(qpos_path)?;
    if q.len() < joint_count {
        return Err(Error::input(
            qpos_path,
            "qpos",
            format!(
                "has {} values; allowed: at least the {joint_count} joints named",
                q.len()
            ),
        ));
    }
    let color = src.join("color").join(format!("{stem}.png"));
    let color = match std::fs::symlink_metadata(&color) {
        Ok(_) => Some(check_color(src, &color, (mask.width, mask.height))?),
        Err(_) => None,
    };
    Ok(SourceView {
        mask,
        joints: q[..joint_count].to_vec(),
        color,
    })
}

/// A colour frame is copied only when it is a PNG image of the mask's size inside the
/// source folder: a link out of it (to /etc/passwd, say) or a file that is no image would
/// otherwise be copied into the run unread.
fn check_color(src: &Path, color: &Path, size: (u32, u32)) -> Result<PathBuf> {
    let real = std::fs::canonicalize(color)
        .map_err(|e| Error::input(color, "color", format!("cannot be resolved: {e}")))?;
    let root = std::fs::canonicalize(src).map_err(|e| Error::io(src, e))?;
    if !real.starts_with(&root) {
        return Err(Error::input(
            color,
            "color",
            format!(
                "resolves to {}, outside the source folder; allowed: a file inside it",
                real.display()
            ),
        ));
    }
    let found = crate::mask::image_size(&real, "color")?;
    if found != size {
        return Err(Error::input(
            color,
            "color",
            format!(
                "is {}x{}; allowed: the mask's {}x{}",
                found.0, found.1, size.0, size.1
            ),
        ));
    }
    Ok(real)
}

/// Every mask's header states the first one's size, and a solve of them all fits in memory:
/// checked before any mask is decoded, since each decoded mask is held until the write.
fn check_mask_headers(src: &Path, masks: &BTreeMap<String, PathBuf>) -> Result<()> {
    let mut first: Option<(u32, u32)> = None;
    for path in masks.values() {
        let size = Mask::dimensions(path)?;
        match first {
            None => first = Some(size),
            Some(f) if f != size => {
                return Err(Error::input(
                    path,
                    "mask",
                    format!(
                        "is {}x{}; allowed: the first mask's {}x{}",
                        size.0, size.1, f.0, f.1
                    ),
                ))
            }
            Some(_) => {}
        }
    }
    match first {
        Some(size) => crate::run::check_solve_memory(masks.len(), size, &src.join("mask"), "mask"),
        None => Ok(()),
    }
}

/// The files in `dir` ending in `.ext`, keyed (and so ordered) by stem.
fn files_by_stem(dir: &Path, ext: &str) -> Result<BTreeMap<String, PathBuf>> {
    let mut out = BTreeMap::new();
    let entries =
        std::fs::read_dir(dir).map_err(|e| Error::io(dir, format!("cannot list: {e}")))?;
    for entry in entries.filter_map(|e| e.ok()) {
        let path = entry.path();
        let matches = path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| e.eq_ignore_ascii_case(ext));
        let stem = path
            .file_stem()
            .and_then(|s| s.to_str())
            .map(str::to_string);
        if let (true, Some(stem)) = (matches, stem) {
            if let Some(other) = out.get(&stem) {
                return Err(Error::input(
                    &path,
                    dir.file_name().and_then(|n| n.to_str()).unwrap_or(ext),
                    format!(
                        "and {} name the same view '{stem}' (the extension differs only in case); allowed: one file per view",
                        Path::new(other).display()
                    ),
                ));
            }
            out.insert(stem, path);
        }
    }
    Ok(out)
}

fn read_initial_guess(opts: &EasyHecImport) -> Result<Option<PoseEntry>> {
    let default = opts.source.join("initial_guess.txt");
    let Some(p) = opts
        .initial_guess
        .clone()
        .or_else(|| default.exists().then_some(default))
    else {
        return Ok(None);
    };
    let n = read_numbers(&p)?;
    if n.len() != 16 {
        return Err(Error::input(
            &p,
            "camera_from_base",
            format!(
                "has {} numbers; allowed: a 4x4 matrix (16 numbers)",
                n.len()
            ),
        ));
    }
    let rows = [0, 1, 2, 3].map(|r| [0, 1, 2, 3].map(|c| n[r * 4 + c]));
    crate::geometry::from_rows(&rows).map_err(|m| Error::input(&p, "camera_from_base", m))?;
    Ok(Some(PoseEntry {
        camera_from_base: rows,
    }))
}

fn view_entry(i: usize, v: &SourceView) -> ViewEntry {
    ViewEntry {
        joints: v.joints.clone(),
        mask: Some(format!("views/{}", crate::run::mask_file_name(i))),
        image: v.color.as_ref().map(|_| format!("views/{i:03}.png")),
        captured_at: None,
    }
}

/// Writes the run into a temporary folder beside `opts.out`, then renames it into place (replacing an old run only with `force`).
fn write_run(opts: &EasyHecImport, run: &RunFile, views: &[SourceView]) -> Result<()> {
    let out = &opts.out;
    let parent = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    let staging = tempfile::Builder::new()
        .prefix(".easyhec-import-")
        .tempdir_in(parent)
        .map_err(|e| Error::io(parent, e))?;
    let _registered = Staging::register(staging.path());
    let dir = staging.path();
    {
        let _writing = Staging::writing();
        std::fs::create_dir_all(dir.join("views")).map_err(|e| Error::io(dir, e))?;
    }
    for (entry, v) in run.views.iter().zip(views) {
        let _writing = Staging::writing();
        let mask_rel = entry.mask.as_deref().unwrap_or_default();
        write_atomic(&dir.join(mask_rel), &v.mask.to_png_bytes())?;
        if let (Some(rel), Some(color)) = (&entry.image, &v.color) {
            std::fs::copy(color, dir.join(rel)).map_err(|e| Error::io(color, e))?;
        }
    }
    let _writing = Staging::writing();
    write_json_atomic(&dir.join("run.json"), run)?;
    replace_dir(staging.keep(), out)
}

/// The staging folder of the import under way. Each write into it holds the read side; a
/// signal handler takes the write side, so it never deletes the folder under a write that
/// would then create it again.
static STAGING: std::sync::RwLock<Option<PathBuf>> = std::sync::RwLock::new(None);

/// Names the staging folder while it exists; forgets it when dropped.
struct Staging;

impl Staging {
    fn register(dir: &Path) -> Staging {
        *STAGING.write().unwrap_or_else(|e| e.into_inner()) = Some(dir.to_path_buf());
        Staging
    }

    /// Held while one step writes into the staging folder.
    fn writing() -> std::sync::RwLockReadGuard<'static, Option<PathBuf>> {
        STAGING.read().unwrap_or_else(|e| e.into_inner())
    }
}

impl Drop for Staging {
    fn drop(&mut self) {
        *STAGING.write().unwrap_or_else(|e| e.into_inner()) = None;
    }
}

/// For a signal handler: waits for the write under way, deletes the import's half-written
/// staging folder (if any), and ends the process with `code` without letting the import
/// write again. A signal's default action would leave a hidden folder of copied frames
/// beside the target.
pub fn abandon_staging_and_exit(code: i32) -> ! {
    let held = STAGING.write().unwrap_or_else(|e| e.into_inner());
    if let Some(dir) = held.as_ref() {
        let _ = std::fs::remove_dir_all(dir);
    }
    std::process::exit(code)
}

/// Moves `staged` to `out`; an existing `out` is set aside first and removed only after the
/// new folder is in place, so a failure leaves one complete run, never a mix.
fn replace_dir(staged: PathBuf, out: &Path) -> Result<()> {
    let old = out
        .exists()
        .then(|| out.with_extension("easyhec-import-old"));
    if let Some(old) = &old {
        std::fs::rename(out, old).map_err(|e| Error::io(out, e))?;
    }
    if let Err(e) = std::fs::rename(&staged, out) {
        if let Some(old) = &old {
            let _ = std::fs::rename(old, out);
        }
        let _ = std::fs::remove_dir_all(&staged);
        return Err(Error::io(out, e));
    }
    if let Some(old) = old {
        let _ = std::fs::remove_dir_all(old);
    }
    Ok(())
}

//! Checks on a `run.json` that need only the file and its folder, run before any mask is read
//! or any pose is computed. Each failure is one line naming the file, the field path
//! (`views[3].joints[2]`) and what is allowed.

use std::collections::HashMap;
use std::path::{Component, Path, PathBuf};

use super::RunFile;
use crate::error::{Error, Result};

/// Most views a run may hold. A calibration needs 3–10; this bound keeps a solve's memory and
/// time predictable whatever the file says.
pub const MAX_RUN_VIEWS: usize = 500;
/// Most joints a run's robot may list.
pub const MAX_RUN_JOINTS: usize = 64;
/// Bytes a solve keeps per pixel of one view (mask, undistorted mask, distance field, render
/// and gradient buffers), for the up-front memory estimate.
pub const SOLVE_BYTES_PER_VIEW_PIXEL: u64 = 24;

/// Every content check of `file`, read from `json` in the folder `dir`.
pub(crate) fn check_run_file(file: &RunFile, json: &Path, dir: &Path) -> Result<()> {
    check_joint_names(file, json)?;
    check_view_count(file, json)?;
    for (i, v) in file.views.iter().enumerate() {
        check_view_joints(&v.joints, file.robot.joints.len(), i, json)?;
    }
    check_repeated_views(file, json)?;
    check_view_paths(file, json, dir)?;
    check_memory(file, json)
}

fn check_joint_names(file: &RunFile, json: &Path) -> Result<()> {
    let names = &file.robot.joints;
    if names.is_empty() || names.len() > MAX_RUN_JOINTS {
        return Err(Error::input(
            json,
            "robot.joints",
            format!(
                "lists {} joints; allowed: 1 to {MAX_RUN_JOINTS}, the actuated joints in the order of each view's joints",
                names.len()
            ),
        ));
    }
    for (k, n) in names.iter().enumerate() {
        if let Some(first) = names[..k].iter().position(|m| m == n) {
            return Err(Error::input(
                json,
                format!("robot.joints[{k}]"),
                format!(
                    "'{n}' is listed twice (also robot.joints[{first}]); allowed: each joint once"
                ),
            ));
        }
    }
    Ok(())
}

fn check_view_count(file: &RunFile, json: &Path) -> Result<()> {
    let n = file.views.len();
    if n == 0 || n > MAX_RUN_VIEWS {
        return Err(Error::input(
            json,
            "views",
            format!("has {n} views; allowed: 1 to {MAX_RUN_VIEWS}"),
        ));
    }
    Ok(())
}

fn check_view_joints(joints: &[f64], expected: usize, i: usize, json: &Path) -> Result<()> {
    if joints.len() != expected {
        return Err(Error::input(
            json,
            format!("views[{i}].joints"),
            format!(
                "has {} values but robot.joints names {expected}",
                joints.len()
            ),
        ));
    }
    if let Some(k) = joints.iter().position(|q| !q.is_finite()) {
        return Err(Error::input(
            json,
            format!("views[{i}].joints[{k}]"),
            format!("is {}; allowed: a finite number (rad or m)", joints[k]),
        ));
    }
    Ok(())
}

/// How far a recorded joint may lie past its URDF limit (rad or m): encoders read a little
/// past a limit the controller itself enforces, but a value far beyond it is a unit or
/// field mix-up, and at 1e300 rad the sine and cosine of forward kinematics mean nothing.
pub const JOINT_LIMIT_MARGIN: f64 = 0.2;

/// Every view's joints within the URDF's limits (`limits`, in `robot.joints` order; `None`
/// for a continuous joint, which only has to be finite) plus [`JOINT_LIMIT_MARGIN`].
pub(crate) fn check_joints_within_limits(
    file: &RunFile,
    limits: &[Option<(f64, f64)>],
    json: &Path,
) -> Result<()> {
    for (i, v) in file.views.iter().enumerate() {
        for (k, (q, limit)) in v.joints.iter().zip(limits).enumerate() {
            let Some((lo, hi)) = limit else { continue };
            let (lo, hi) = (lo - JOINT_LIMIT_MARGIN, hi + JOINT_LIMIT_MARGIN);
            if !(lo..=hi).contains(q) {
                return Err(Error::input(
                    json,
                    format!("views[{i}].joints[{k}]"),
                    format!(
                        "is {}; allowed: {lo:.3} to {hi:.3} ({}'s URDF limits plus {JOINT_LIMIT_MARGIN})",
                        crate::error::cut(&q.to_string()),
                        file.robot.joints.get(k).map_or("the joint", String::as_str)
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// A view recorded twice counts its evidence twice: the solve would report an uncertainty
/// √2 too small. Two views with bit-identical joints, or two views sharing one mask file, are
/// the same view.
fn check_repeated_views(file: &RunFile, json: &Path) -> Result<()> {
    let mut by_joints: HashMap<Vec<u64>, usize> = HashMap::new();
    let mut by_mask: HashMap<&str, usize> = HashMap::new();
    for (i, v) in file.views.iter().enumerate() {
        let key: Vec<u64> = v.joints.iter().map(|q| (q + 0.0).to_bits()).collect();
        if let Some(first) = by_joints.insert(key, i) {
            return Err(repeated(json, i, first, "joints"));
        }
        if let Some(mask) = v.mask.as_deref() {
            if let Some(first) = by_mask.insert(mask, i) {
                return Err(repeated(json, i, first, "mask"));
            }
        }
    }
    Ok(())
}

fn repeated(json: &Path, i: usize, first: usize, what: &str) -> Error {
    Error::input(
        json,
        format!("views[{i}].{what}"),
        format!("repeats views[{first}].{what}; allowed: each view once (a repeated view would shrink the reported uncertainty without adding evidence)"),
    )
}

fn check_view_paths(file: &RunFile, json: &Path, dir: &Path) -> Result<()> {
    for (i, v) in file.views.iter().enumerate() {
        if let Some(m) = &v.mask {
            inside_run(dir, m, json, &format!("views[{i}].mask"))?;
        }
        if let Some(im) = &v.image {
            inside_run(dir, im, json, &format!("views[{i}].image"))?;
        }
    }
    Ok(())
}

/// `rel` as a path inside the run folder `dir`: relative, without `..`, and (when it exists)
/// a regular file whose real path stays inside the folder. A run is data another tool or
/// person may have written; it must not make easyhec read `/etc/passwd` or block on a FIFO.
pub(crate) fn inside_run(dir: &Path, rel: &str, json: &Path, field: &str) -> Result<PathBuf> {
    let p = Path::new(rel);
    let escapes = p.is_absolute()
        || p.components().any(|c| {
            matches!(
                c,
                Component::ParentDir | Component::RootDir | Component::Prefix(_)
            )
        });
    if rel.is_empty() || escapes {
        return Err(Error::input(
            json,
            field,
            format!("is '{rel}'; allowed: a path relative to the run folder, without '..'"),
        ));
    }
    let full = dir.join(p);
    let Ok(meta) = std::fs::metadata(&full) else {
        return Ok(full); // Missing files are reported where they are needed.
    };
    let real_dir = dir.canonicalize().map_err(|e| Error::io(dir, e))?;
    let real = full.canonicalize().map_err(|e| Error::io(&full, e))?;
    if !real.starts_with(&real_dir) {
        return Err(Error::input(
            json,
            field,
            format!(
                "'{rel}' leads to {} outside the run folder; allowed: files inside it",
                real.display()
            ),
        ));
    }
    if !meta.is_file() {
        return Err(Error::input(
            json,
            field,
            format!("'{rel}' is not a regular file; allowed: a PNG file"),
        ));
    }
    Ok(full)
}

/// Refuses, before allocating, a run whose masks alone would not fit in the memory this
/// machine has available (an allocation failure aborts the process with no message).
fn check_memory(file: &RunFile, json: &Path) -> Result<()> {
    let size = (file.camera.width, file.camera.height);
    check_solve_memory(file.views.len(), size, json, "views")
}

/// `views` images of `size` (width, height) must fit in the memory a solve of them needs;
/// otherwise an error naming `field` of `path`.
pub(crate) fn check_solve_memory(
    views: usize,
    size: (u32, u32),
    path: &Path,
    field: &str,
) -> Result<()> {
    let pixels = u64::from(size.0) * u64::from(size.1);
    let need = pixels
        .saturating_mul(views as u64)
        .saturating_mul(SOLVE_BYTES_PER_VIEW_PIXEL);
    let Some(available) = available_memory_bytes() else {
        return Ok(());
    };
    if need > available {
        return Err(Error::input(
            path,
            field,
            format!(
                "{views} views of {}x{} need about {:.1} GB to solve; this machine has {:.1} GB available: use fewer views or smaller images",
                size.0,
                size.1,
                need as f64 / 1e9,
                available as f64 / 1e9
            ),
        ));
    }
    Ok(())
}

/// Largest share of the image a mask may mark as robot. A mask that is (almost) all robot is
/// inverted or thresholded wrong; solving against it fails with a misleading "robot not
/// visible" rather than naming the mask.
pub const MAX_ROBOT_FRACTION: f64 = 0.99;

/// A mask must mark some robot, and not (nearly) the whole image.
pub(crate) fn check_mask_coverage(
    mask: &crate::mask::Mask,
    path: &Path,
    field: &str,
) -> Result<()> {
    let total = (mask.width as usize * mask.height as usize).max(1);
    let share = mask.count() as f64 / total as f64;
    if mask.count() == 0 {
        return Err(Error::input(
            path,
            field,
            "mask has no robot pixels (>= 128): drop the view or fix the mask",
        ));
    }
    if share > MAX_ROBOT_FRACTION {
        return Err(Error::input(
            path,
            field,
            format!(
                "mask marks {:.1}% of the image as robot; allowed: at most {}% (is it inverted?)",
                share * 100.0,
                MAX_ROBOT_FRACTION * 100.0
            ),
        ));
    }
    Ok(())
}

/// `MemAvailable` from `/proc/meminfo`, when the system reports it.
pub fn available_memory_bytes() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

//! Which calibration may become the active one. The active pose is what bump checks test and
//! what robot controllers read from `GET /api/v1/calibration`, so a calibration is activated
//! only when its record says it ran to the end and its own `result.json` holds a rigid pose:
//!
//! - state `succeeded`, or `interrupted` with a `result.json` from `easyhec solve` (the loop's
//!   partial result of a shutdown, stop reason `cancelled after …`, is refused like a
//!   cancelled run's);
//! - not a dry run (it only planned);
//! - `run_dir` is the record's own `runs/ID`, and it and `result.json` resolve inside the data
//!   folder (a record edited to point at another run or outside the folder is refused);
//! - `camera_from_base` finite and rigid within 1e-6, `base_from_camera` its inverse;
//! - `base_link` fits the camera's mount: the mount link for a camera on a link, a frame no
//!   joint moves for a fixed camera. A result for another mount is refused.
//!
//! Each refusal is a 409 whose message names the calibration and the field.

use std::fmt::Display;
use std::path::PathBuf;

use super::reconcile::check_result;
use super::store::{ActiveFile, CalibrationRecord, State, Store};
use super::validate::{inside, resolved_inside};
use super::{now, Daemon, Refusal};
use crate::run::rig::{ResultCameras, RigRunFile, RunLayout};
use crate::run::{ResultFile, RunFile};

impl Daemon {
    /// Makes calibration `id` active, when [`activatable`] allows it: for a list of cameras,
    /// every camera it calibrated, each checked before any becomes active.
    pub fn activate(&self, id: &str) -> Result<Vec<ActiveFile>, Refusal> {
        let record = self
            .status(id)
            .ok_or_else(|| Refusal::NotFound(format!("no calibration {id}")))?;
        let names: Vec<&str> = self.cell.cameras().iter().map(|c| c.name).collect();
        let results = activatable(&self.store, &record, self.cell.layout(), &names)?;
        for (camera, result) in &results {
            if let Some(why) = self.frame_mismatch(camera.as_deref(), &result.base_link) {
                return Err(refuse(&record, "result.json base_link", why));
            }
        }
        // One write for every camera: a failure leaves the previous active set whole.
        let activated = self.store.activate_cameras(id, results, &now())?;
        self.announce_active();
        Ok(activated)
    }
}

/// Each camera's result calibration `r` may be activated with (one unnamed camera for a
/// `[camera]` cell), or a 409 naming it and the field: its file must be in the cell's
/// `layout`, and every camera one of `names`.
pub fn activatable(
    store: &Store,
    r: &CalibrationRecord,
    layout: RunLayout,
    names: &[&str],
) -> Result<Vec<(Option<String>, ResultFile)>, Refusal> {
    check_state(r)?;
    let path = result_path(store, r)?;
    let results = ResultCameras::read(&path).map_err(|e| refuse(r, "result.json", e))?;
    if results.layout != layout {
        return Err(refuse(
            r,
            "result.json format",
            format!(
                "is {}; allowed: {}, which this cell's cameras record",
                results.layout.result_format(),
                layout.result_format()
            ),
        ));
    }
    check_not_partial(store, r, &results.stop_reason)?;
    let mut out = Vec::with_capacity(results.cameras.len());
    for (k, cam) in results.cameras.iter().enumerate() {
        if let Some(name) = cam.name.as_deref().filter(|n| !names.contains(n)) {
            return Err(refuse(
                r,
                &format!("result.json {}", results.key(k, "name")),
                format!("{name:?} is no camera of this cell; allowed: {names:?}"),
            ));
        }
        check_result(&cam.result)
            .map_err(|(f, m)| refuse(r, &format!("result.json {}", results.key(k, &f)), m))?;
        check_views(store, r, &cam.result, cam.name.as_deref())?;
        out.push((cam.name.clone(), cam.result.clone()));
    }
    Ok(out)
}

/// The result's view indices name views of its own run (of `camera`, for a list), each used
/// once: a `result.json` copied in from another run, or edited, is refused before it can
/// become what bump checks and robot controllers read.
fn check_views(
    store: &Store,
    r: &CalibrationRecord,
    result: &ResultFile,
    camera: Option<&str>,
) -> Result<(), Refusal> {
    let json = store.run_dir(r).join("run.json");
    let count = match camera {
        None => RunFile::read(&json).map(|run| run.views.len()),
        Some(name) => RigRunFile::read(&json).map(|rig| {
            rig.cameras
                .iter()
                .position(|c| c.name == name)
                .map_or(0, |k| rig.camera_run(k).views.len())
        }),
    }
    .map_err(|e| refuse(r, "run.json", e))?;
    let mut seen = std::collections::BTreeSet::new();
    for (i, &v) in result.views_used.iter().enumerate() {
        if v >= count || !seen.insert(v) {
            return Err(refuse(
                r,
                &format!("result.json views_used[{i}]"),
                format!("{v} does not fit its run: allowed: each of the run's {count} views (0 to {}) at most once", count.saturating_sub(1)),
            ));
        }
    }
    for (i, p) in result.per_view.iter().enumerate() {
        if p.view >= count {
            return Err(refuse(
                r,
                &format!("result.json per_view[{i}].view"),
                format!(
                    "{} does not fit its run: allowed: 0 to {} (the run has {count} views)",
                    p.view,
                    count.saturating_sub(1)
                ),
            ));
        }
    }
    Ok(())
}

/// A 409 naming the calibration and the field.
fn refuse(r: &CalibrationRecord, field: &str, message: impl Display) -> Refusal {
    Refusal::Conflict(format!("calibration {}: {field}: {message}", r.id))
}

/// Only a run that reached its end (or was re-solved after an interruption) and moved the arm.
fn check_state(r: &CalibrationRecord) -> Result<(), Refusal> {
    let why = match r.state {
        State::Succeeded | State::Interrupted => None,
        State::Queued | State::Running => Some("wait for it to end"),
        State::Cancelled => Some("a cancelled run stopped early; its partial result is never activated: start a new calibration"),
        State::Failed => Some("a failed run has no trustworthy result: start a new calibration"),
    };
    if let Some(why) = why {
        return Err(refuse(r, "state", format!("{}: {why}", r.state.name())));
    }
    if r.dry_run {
        return Err(refuse(
            r,
            "dry_run",
            "true: a dry run only plans, so it has no calibration to activate",
        ));
    }
    Ok(())
}

/// The record's own `DATA/runs/ID/result.json`, resolved inside the data folder.
fn result_path(store: &Store, r: &CalibrationRecord) -> Result<PathBuf, Refusal> {
    let own = format!("runs/{}", r.id);
    if r.run_dir != own {
        return Err(refuse(
            r,
            "run_dir",
            format!("{:?} is not its own run directory {own:?}", r.run_dir),
        ));
    }
    let dir = inside(store.dir(), store.canonical_dir(), &r.run_dir)
        .map_err(|m| refuse(r, "run_dir", m))?;
    let path = dir.join("result.json");
    if !path.is_file() {
        return Err(refuse(
            r,
            "result.json",
            format!(
                "{} is missing (a failed run and a crashed one have none: re-solve an interrupted run with `easyhec solve {}`)",
                path.display(),
                dir.display()
            ),
        ));
    }
    resolved_inside(&path, store.canonical_dir()).map_err(|m| refuse(r, "result.json", m))?;
    Ok(path)
}

/// An interrupted run's `result.json` is the loop's partial result until `easyhec solve`
/// replaces it (the loop writes `cancelled after N views` as its stop reason).
fn check_not_partial(
    store: &Store,
    r: &CalibrationRecord,
    stop_reason: &str,
) -> Result<(), Refusal> {
    if r.state == State::Interrupted && stop_reason.starts_with("cancelled") {
        return Err(refuse(
            r,
            "state",
            format!(
                "interrupted, and result.json is the loop's partial result (stop_reason {:?}): re-solve it with `easyhec solve {}` first",
                stop_reason,
                store.run_dir(r).display()
            ),
        ));
    }
    Ok(())
}

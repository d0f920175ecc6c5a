//! Reading the data folder back at start, trusting nothing in it.
//!
//! The files may have been edited, restored from an old backup, half-copied or lost while
//! the daemon was down. So at start the daemon reconciles them with `runs/`:
//!
//! - a missing or unreadable `index.json` is rebuilt from the run directories (each run
//!   becomes an `interrupted` record whose error says so), and a run directory the index does
//!   not list gets a record the same way, so its id is never handed out again;
//! - every record is checked (a well-formed id that cannot wrap, once only; a `run_dir` that
//!   stays inside the data folder; a rigid estimate); one that fails is moved to
//!   `DATA/quarantine/` and logged, the others are served;
//! - `active.json` must name a well-formed id and hold a rigid pose; otherwise it goes to
//!   quarantine and nothing is active (a bump check or a robot controller must never get a
//!   bad matrix);
//! - broken JSON in `checks.json` is quarantined and the check history starts empty.
//!
//! A file of another format version (a newer easyhec's) still stops the daemon: rewriting it
//! in this version's format would lose what the newer one wrote.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use serde_json::Value;

use super::records::{
    ActiveFile, CalibrationRecord, CheckRecord, Recovery, RigActiveFile, State, ACTIVE_FORMAT,
    CHECKS_FORMAT, INDEX_FORMAT, RIG_ACTIVE_FORMAT,
};
use super::validate::{check_inverse, check_rigid, id_number, id_problem, inside};
use crate::error::{Error, Result};
use crate::run::{ResultFile, RunFile};

/// The quarantine folder, inside the data folder.
pub const QUARANTINE: &str = "quarantine";

/// What the data folder held, after reconciliation.
pub(super) struct Loaded {
    pub records: Vec<CalibrationRecord>,
    /// The one camera's entry, or each named camera's of a list.
    pub active: Vec<ActiveFile>,
    pub checks: Vec<CheckRecord>,
    pub recovery: Recovery,
    /// The records differ from `index.json` on disk (rewrite it).
    pub index_changed: bool,
}

/// What is wrong with something read back: the field and a one-line message.
struct Problem {
    field: String,
    message: String,
}

impl Problem {
    fn new(field: impl Into<String>, message: impl Into<String>) -> Problem {
        Problem {
            field: field.into(),
            message: message.into(),
        }
    }

    /// The same problem, its field inside `outer`.
    fn within(self, outer: &str) -> Problem {
        Problem {
            field: format!("{outer}.{}", self.field),
            message: self.message,
        }
    }
}

/// One of the data folder's JSON files.
enum Doc {
    Missing,
    Broken(Problem),
    Found(Value),
}

/// The data folder during reconciliation.
struct Folder<'a> {
    dir: &'a Path,
    canonical: &'a Path,
}

/// Reads and reconciles the data folder `dir` (resolved: `canonical`).
pub(super) fn load(dir: &Path, canonical: &Path, now: &str) -> Result<Loaded> {
    let f = Folder { dir, canonical };
    let (mut records, mut index_changed) = f.load_index()?;
    index_changed |= f.adopt_run_dirs(&mut records, now);
    let recovery = mark_interrupted(dir, &mut records, now);
    index_changed |= !recovery.interrupted.is_empty();
    Ok(Loaded {
        records,
        active: f.load_active()?,
        checks: f.load_checks()?,
        recovery,
        index_changed,
    })
}

/// Reads a JSON file of format `tag`. Broken JSON (or a body that is not an object) is a
/// [`Doc::Broken`] to quarantine; another format tag stops the daemon.
fn read_doc(path: &Path, tag: &str) -> Result<Doc> {
    read_doc_of(path, &[tag])
}

/// [`read_doc`] for a file that may hold any of `tags`.
fn read_doc_of(path: &Path, tags: &[&str]) -> Result<Doc> {
    let unreadable = std::fs::metadata(path)
        .ok()
        .and_then(|meta| crate::io::input_file_problem(&meta, crate::io::MAX_TEXT_INPUT_BYTES));
    if let Some(problem) = unreadable {
        return Ok(Doc::Broken(Problem::new("(file)", problem)));
    }
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Doc::Missing),
        Err(e) if e.kind() == std::io::ErrorKind::InvalidData => {
            return Ok(Doc::Broken(Problem::new("(file)", "is not UTF-8 text")))
        }
        Err(e) => return Err(Error::io(path, format!("cannot read: {e}"))),
    };
    let value: Value = match serde_json::from_str(&text) {
        Ok(v) => v,
        Err(e) => {
            let field = format!("line {} column {}", e.line(), e.column());
            return Ok(Doc::Broken(Problem::new(
                field,
                format!("invalid JSON ({e})"),
            )));
        }
    };
    if !value.is_object() {
        return Ok(Doc::Broken(Problem::new(
            "(top level)",
            "is not a JSON object",
        )));
    }
    check_format(path, &value, tags)?;
    Ok(Doc::Found(value))
}

/// Refuses another format version, printing the tag as written.
fn check_format(path: &Path, value: &Value, tags: &[&str]) -> Result<()> {
    let tag = tags.join(" or ");
    let message = match value.get("format") {
        Some(Value::String(t)) if tags.contains(&t.as_str()) => return Ok(()),
        Some(Value::String(t)) => format!("{t:?} is not {tag}, the format this easyhec reads"),
        Some(other) => format!("{other} is not a format tag (this easyhec reads {tag})"),
        None => format!("absent (this easyhec reads {tag})"),
    };
    Err(Error::input(
        path,
        "format",
        format!("{message}: move the file away to start afresh (the run directories stay intact)"),
    ))
}

impl Folder<'_> {
    /// `DATA/index.json`'s records, checked one by one; `true` when some were dropped.
    fn load_index(&self) -> Result<(Vec<CalibrationRecord>, bool)> {
        let path = self.dir.join("index.json");
        let value = match read_doc(&path, INDEX_FORMAT)? {
            Doc::Missing => return Ok((Vec::new(), false)),
            Doc::Broken(p) => {
                self.quarantine_file(&path, &p)?;
                return Ok((Vec::new(), true));
            }
            Doc::Found(v) => v,
        };
        let Some(list) = value.get("calibrations").and_then(Value::as_array) else {
            let p = Problem::new("calibrations", "missing or not an array");
            self.quarantine_file(&path, &p)?;
            return Ok((Vec::new(), true));
        };
        self.checked_records(&path, list)
    }

    /// The records of `list` that pass [`Folder::check_record`]; the others are quarantined.
    fn checked_records(
        &self,
        path: &Path,
        list: &[Value],
    ) -> Result<(Vec<CalibrationRecord>, bool)> {
        let mut seen = BTreeSet::new();
        let mut records = Vec::new();
        let mut dropped = false;
        for (i, item) in list.iter().enumerate() {
            match self.check_record(item, &seen) {
                Ok(r) => {
                    seen.insert(r.id.clone());
                    records.push(r);
                }
                Err(p) => {
                    let p =
                        Problem::new(format!("{}{}", record_label(i, item), p.field), p.message);
                    self.quarantine_value(path, &format!("index-record-{i}"), item, &p)?;
                    dropped = true;
                }
            }
        }
        Ok((records, dropped))
    }

    /// One record: it parses, its id is well formed and unique, its run directory stays
    /// inside the data folder, and its estimate (if any) is rigid. `field` is a suffix
    /// (`.run_dir`) of `calibrations[i]`.
    fn check_record(
        &self,
        item: &Value,
        seen: &BTreeSet<String>,
    ) -> std::result::Result<CalibrationRecord, Problem> {
        let r: CalibrationRecord =
            serde_json::from_value(item.clone()).map_err(|e| Problem::new("", e.to_string()))?;
        if id_number(&r.id).is_none() {
            return Err(Problem::new(".id", id_problem(&r.id)));
        }
        if seen.contains(&r.id) {
            return Err(Problem::new(
                ".id",
                format!("{} appears twice; the first record is kept", r.id),
            ));
        }
        inside(self.dir, self.canonical, &r.run_dir).map_err(|m| Problem::new(".run_dir", m))?;
        if let Some(rows) = &r.camera_from_base {
            check_rigid(rows).map_err(|m| Problem::new(".camera_from_base", m))?;
        }
        Ok(r)
    }

    /// Gives every run directory named by a well-formed id that no record lists a record of
    /// its own (`interrupted`, saying it was rebuilt), so the index covers `runs/` and no new
    /// id can collide with a folder. Returns whether any was added.
    fn adopt_run_dirs(&self, records: &mut Vec<CalibrationRecord>, now: &str) -> bool {
        let known: BTreeSet<String> = records.iter().map(|r| r.id.clone()).collect();
        let mut added = false;
        for name in run_dir_names(self.dir) {
            if known.contains(&name) {
                continue;
            }
            if id_number(&name).is_none() {
                if name.starts_with("cal-") {
                    tracing::warn!(
                        "easyhec daemon: {}: {}; the folder is left alone and no record is made for it",
                        self.dir.join("runs").join(&name).display(),
                        id_problem(&name)
                    );
                }
                continue;
            }
            let r = rebuilt_record(self.dir, &name, now);
            tracing::warn!(
                "easyhec daemon: {}: no record in index.json: rebuilt from the run directory ({} views, state interrupted)",
                self.dir.join(&r.run_dir).display(),
                r.views
            );
            records.push(r);
            added = true;
        }
        if added {
            records.sort_by_key(|r| id_number(&r.id));
        }
        added
    }

    /// `DATA/active.json`, or nothing (quarantined) when it does not hold a usable pose.
    fn load_active(&self) -> Result<Vec<ActiveFile>> {
        let path = self.dir.join("active.json");
        let problem = match read_doc_of(&path, &[ACTIVE_FORMAT, RIG_ACTIVE_FORMAT])? {
            Doc::Missing => return Ok(Vec::new()),
            Doc::Broken(p) => p,
            Doc::Found(v) if v["format"] == RIG_ACTIVE_FORMAT => match check_rig_active(v) {
                Ok(a) => return Ok(a),
                Err(p) => p,
            },
            Doc::Found(v) => match check_active(v) {
                Ok(a) if a.camera.is_none() => return Ok(vec![a]),
                Ok(_) => Problem::new(
                    "camera",
                    "is set in a file of one camera; allowed: only in easyhec-daemon-active/2",
                ),
                Err(p) => p,
            },
        };
        self.quarantine_file(&path, &problem)?;
        tracing::info!(
            "easyhec daemon: no calibration is active: activate one with POST /api/v1/calibrations/{{id}}/activate"
        );
        Ok(Vec::new())
    }

    /// `DATA/checks.json`; broken JSON is quarantined and the history starts empty.
    fn load_checks(&self) -> Result<Vec<CheckRecord>> {
        let path = self.dir.join("checks.json");
        let problem = match read_doc(&path, CHECKS_FORMAT)? {
            Doc::Missing => return Ok(Vec::new()),
            Doc::Broken(p) => p,
            Doc::Found(mut v) => match serde_json::from_value(v["checks"].take()) {
                Ok(checks) => return Ok(checks),
                Err(e) => Problem::new("checks", e.to_string()),
            },
        };
        self.quarantine_file(&path, &problem)?;
        Ok(Vec::new())
    }

    /// Moves a whole file to the quarantine folder and logs one line naming it and the field.
    fn quarantine_file(&self, path: &Path, p: &Problem) -> Result<()> {
        let name = path
            .file_name()
            .map_or("file".into(), |n| n.to_string_lossy().to_string());
        let dest = self.quarantine_dest(&name)?;
        std::fs::rename(path, &dest)
            .map_err(|e| Error::io(path, format!("cannot move it to {}: {e}", dest.display())))?;
        log_quarantined(path, p, &dest);
        Ok(())
    }

    /// Writes a part of a file (one record) to the quarantine folder and logs it.
    fn quarantine_value(&self, path: &Path, label: &str, value: &Value, p: &Problem) -> Result<()> {
        let dest = self.quarantine_dest(&format!("{label}.json"))?;
        crate::io::write_json_atomic(&dest, value)?;
        log_quarantined(path, p, &dest);
        Ok(())
    }

    /// A free path for `name` in the quarantine folder: `NAME.UNIXSECS[.k]`, never an existing
    /// file (an earlier start's quarantine is kept).
    fn quarantine_dest(&self, name: &str) -> Result<PathBuf> {
        let q = self.dir.join(QUARANTINE);
        std::fs::create_dir_all(&q)
            .map_err(|e| Error::io(&q, format!("cannot create the quarantine folder: {e}")))?;
        let secs = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs());
        let first = q.join(format!("{name}.{secs}"));
        let mut dest = first.clone();
        let mut k = 0;
        while dest.exists() {
            k += 1;
            dest = PathBuf::from(format!("{}.{k}", first.display()));
        }
        Ok(dest)
    }
}

/// `calibrations[I]`, with (the start of) the record's id when it has one, for the log line.
fn record_label(i: usize, item: &Value) -> String {
    match item.get("id").and_then(Value::as_str) {
        Some(id) => {
            let short: String = id.chars().take(40).collect();
            format!("calibrations[{i}] ({short:?})")
        }
        None => format!("calibrations[{i}]"),
    }
}

/// One log line for a quarantined file or record: the file, the field, why, and where it went.
fn log_quarantined(path: &Path, p: &Problem, dest: &Path) {
    tracing::warn!(
        "easyhec daemon: {}: {}: {}; quarantined, not served (moved to {})",
        path.display(),
        p.field,
        p.message,
        dest.display()
    );
}

/// `active.json`'s content: it parses and holds one entry [`check_active_entry`] accepts.
fn check_active(v: Value) -> std::result::Result<ActiveFile, Problem> {
    let a: ActiveFile =
        serde_json::from_value(v).map_err(|e| Problem::new("(content)", e.to_string()))?;
    check_active_entry(a)
}

/// One active entry: a well-formed id and a result [`check_result`] accepts.
fn check_active_entry(a: ActiveFile) -> std::result::Result<ActiveFile, Problem> {
    if id_number(&a.id).is_none() {
        return Err(Problem::new("id", id_problem(&a.id)));
    }
    check_result(&a.result).map_err(|(f, m)| Problem::new(format!("result.{f}"), m))?;
    Ok(a)
}

/// A list's `active.json`: 1 to `MAX_CAMERAS` entries, each a valid [`check_active`] entry
/// naming a distinct camera, sorted by name.
fn check_rig_active(v: Value) -> std::result::Result<Vec<ActiveFile>, Problem> {
    use crate::config::cameras::{name_problem, MAX_CAMERAS};
    let rig: RigActiveFile =
        serde_json::from_value(v).map_err(|e| Problem::new("(content)", e.to_string()))?;
    if !(1..=MAX_CAMERAS).contains(&rig.cameras.len()) {
        return Err(Problem::new(
            "cameras",
            format!(
                "holds {} entries; allowed: 1 to {MAX_CAMERAS}",
                rig.cameras.len()
            ),
        ));
    }
    let mut out: Vec<ActiveFile> = Vec::new();
    for (i, entry) in rig.cameras.into_iter().enumerate() {
        let a = check_active_entry(entry).map_err(|p| p.within(&format!("cameras[{i}]")))?;
        let Some(name) = a.camera.as_deref() else {
            return Err(Problem::new(
                format!("cameras[{i}].camera"),
                "is absent; allowed: the camera's name",
            ));
        };
        if let Some(m) = name_problem(name) {
            return Err(Problem::new(format!("cameras[{i}].camera"), m));
        }
        if out.iter().any(|o| o.camera == a.camera) {
            return Err(Problem::new(
                format!("cameras[{i}].camera"),
                format!("{name:?} is named twice"),
            ));
        }
        out.push(a);
    }
    out.sort_by(|a, b| a.camera.cmp(&b.camera));
    Ok(out)
}

/// A result the daemon can stand behind: `camera_from_base` rigid, `base_from_camera` its
/// inverse, and an uncertainty a solve could have written (a bump check reads its covariance).
pub(super) fn check_result(r: &ResultFile) -> std::result::Result<(), (String, String)> {
    check_rigid(&r.camera_from_base).map_err(|m| ("camera_from_base".to_string(), m))?;
    check_inverse(&r.camera_from_base, &r.base_from_camera)
        .map_err(|m| ("base_from_camera".to_string(), m))?;
    match r.uncertainty.as_ref().and_then(|u| u.problem()) {
        Some(problem) => Err(problem),
        None => Ok(()),
    }
}

/// Names of the folders under `DATA/runs/`, sorted.
fn run_dir_names(dir: &Path) -> Vec<String> {
    let Ok(entries) = std::fs::read_dir(dir.join("runs")) else {
        return Vec::new();
    };
    let mut names: Vec<String> = entries
        .filter_map(|e| e.ok())
        .filter(|e| e.file_type().is_ok_and(|t| t.is_dir()))
        .filter_map(|e| e.file_name().into_string().ok())
        .collect();
    names.sort();
    names
}

/// A record for run directory `runs/ID` that the index lost: `interrupted`, with the views
/// its `run.json` lists and the pose of its `result.json` when [`check_result`] accepts it.
fn rebuilt_record(dir: &Path, id: &str, now: &str) -> CalibrationRecord {
    let run_dir = format!("runs/{id}");
    let abs = dir.join(&run_dir);
    let views = RunFile::read(&abs.join("run.json")).map_or(0, |r| r.views.len());
    let result = ResultFile::read(&abs.join("result.json"))
        .ok()
        .filter(|r| check_result(r).is_ok());
    CalibrationRecord {
        id: id.to_string(),
        state: State::Interrupted,
        trigger: "unknown".into(),
        dry_run: false,
        max_views: views,
        created_at: now.to_string(),
        started_at: None,
        finished_at: Some(now.to_string()),
        run_dir,
        phase: None,
        round: None,
        views,
        loss: None,
        mean_iou: None,
        best_variance: None,
        camera_from_base: result.as_ref().map(|r| r.camera_from_base),
        uncertainty: result.as_ref().and_then(|r| r.uncertainty.clone()),
        stop_reason: result.map(|r| r.stop_reason),
        error: Some(format!(
            "index.json had no record of this run (lost or damaged): rebuilt from {} ({views} views); re-solve it with `easyhec solve {}` if it has no result",
            abs.display(),
            abs.display()
        )),
        warm_start_from: None,
        planned_poses: None,
        truth_error: None,
        cameras: None,
        camera_results: None,
    }
}

/// Records still `queued` or `running` belong to a daemon that died: they become
/// `interrupted`, with the view count read back from their `run.json`.
fn mark_interrupted(dir: &Path, records: &mut [CalibrationRecord], now: &str) -> Recovery {
    let mut recovery = Recovery::default();
    for r in records.iter_mut().filter(|r| !r.state.is_final()) {
        r.state = State::Interrupted;
        r.phase = None;
        r.finished_at = Some(now.to_string());
        if let Ok(run) = RunFile::read(&dir.join(&r.run_dir).join("run.json")) {
            r.views = run.views.len();
        }
        r.error = Some(format!(
            "the daemon stopped during this run ({} views recorded); re-solve it with `easyhec solve {}`",
            r.views,
            dir.join(&r.run_dir).display()
        ));
        recovery.interrupted.push(r.id.clone());
    }
    recovery
}

#[cfg(test)]
mod tests {
    use nalgebra::Isometry3;
    use serde_json::json;

    use super::*;
    use crate::run::UncertaintyEntry;

    /// The bump check reads the active result's covariance, so a broken one is refused when
    /// `active.json` is read, with the field named.
    #[test]
    fn an_active_result_with_a_broken_covariance_is_refused() {
        let active = |variance: f64| {
            let mut result = ResultFile::new(&Isometry3::identity(), "link_base");
            let mut covariance = [[0.0; 6]; 6];
            (0..6).for_each(|r| covariance[r][r] = variance);
            result.uncertainty = Some(UncertaintyEntry {
                rotation_deg: [0.1; 3],
                translation_mm: [0.5; 3],
                camera_centre_95_mm: Some(2.0),
                covariance: Some(Box::new(covariance)),
                terms: None,
                mask_offset: None,
            });
            json!({
                "format": ACTIVE_FORMAT,
                "id": "cal-0001",
                "activated_at": "2026-11-25T10:00:00Z",
                "stale": false,
                "result": result,
            })
        };
        assert!(check_active(active(1e-6)).is_ok());
        let problem = check_active(active(-1e-6)).unwrap_err();
        assert_eq!(problem.field, "result.uncertainty.covariance[0][0]");
    }
}

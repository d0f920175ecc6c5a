//! The daemon's data folder, written so that nothing is lost:
//!
//! ```text
//! DATA/index.json          history: one record per calibration (easyhec-daemon-index/1)
//! DATA/active.json         the active calibration with its easyhec-result/1 body; for a
//!                          list of cameras, each camera's (easyhec-daemon-active/2)
//! DATA/checks.json         the latest bump checks (easyhec-daemon-checks/1)
//! DATA/runs/<id>/          one easyhec-run/1 directory per calibration (run.json, views/,
//!                          rounds.json, result.json), written by the loop as it goes
//! ```
//!
//! Every file is replaced atomically (temp file, fsync, rename: [`crate::io`]). A record is
//! rewritten at each state change and each round, so after a crash the index says how far a
//! run got; [`Store::open`] marks runs that were queued or running as `interrupted`, with the
//! view count read back from their `run.json`. Nothing read back is trusted: see
//! [`super::reconcile`] for the checks and the `DATA/quarantine/` folder.

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use serde::{Deserialize, Serialize};

use super::reconcile;
use super::validate::{canonical_dir, id_for, id_number, MAX_ID};
use crate::error::{Error, Result};
use crate::io::write_json_atomic;
use crate::run::ResultFile;

pub use super::records::{
    ActiveFile, CalibrationRecord, CameraRecord, CheckRecord, Recovery, RigActiveFile, State,
    TruthError, ACTIVE_FORMAT, CHECKS_FORMAT, INDEX_FORMAT, RIG_ACTIVE_FORMAT,
};

/// Bump checks kept in `checks.json`.
const CHECKS_KEPT: usize = 200;

#[derive(Serialize, Deserialize)]
struct IndexFile {
    format: String,
    calibrations: Vec<CalibrationRecord>,
}

#[derive(Serialize, Deserialize)]
struct ChecksFile {
    format: String,
    checks: Vec<CheckRecord>,
}

struct Inner {
    records: Vec<CalibrationRecord>,
    /// One entry without a camera name, or one per named camera of a list.
    active: Vec<ActiveFile>,
    checks: Vec<CheckRecord>,
}

/// The data folder, with the index, active calibration and checks held in memory and
/// written through on every change.
pub struct Store {
    dir: PathBuf,
    canonical: PathBuf,
    inner: Mutex<Inner>,
}

/// Drops the oldest finished records that no active entry names until at most `keep` are
/// left (running ones and active ones always stay); returns the dropped ids.
fn prune_history(
    records: &mut Vec<CalibrationRecord>,
    active: &[ActiveFile],
    keep: usize,
) -> Vec<String> {
    let mut excess = records.len().saturating_sub(keep);
    let mut dropped = Vec::new();
    records.retain(|r| {
        let removable = excess > 0 && r.state.is_final() && !active.iter().any(|a| a.id == r.id);
        if removable {
            excess -= 1;
            dropped.push(r.id.clone());
        }
        !removable
    });
    dropped
}

fn lock(m: &Mutex<Inner>) -> std::sync::MutexGuard<'_, Inner> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

impl Store {
    /// Opens (or creates) the data folder and reconciles it with `runs/`
    /// ([`super::reconcile`]): a lost index is rebuilt, records and `active.json` that fail
    /// their checks are quarantined, and calibrations that were queued or running become
    /// `interrupted`, with their recorded view count.
    pub fn open(dir: &Path, now: &str) -> Result<(Store, Recovery)> {
        std::fs::create_dir_all(dir.join("runs"))
            .map_err(|e| Error::io(dir, format!("cannot create the data folder: {e}")))?;
        let canonical = canonical_dir(dir).map_err(|m| Error::io(dir, m))?;
        let loaded = reconcile::load(dir, &canonical, now)?;
        let store = Store {
            dir: dir.to_path_buf(),
            canonical,
            inner: Mutex::new(Inner {
                records: loaded.records,
                active: loaded.active,
                checks: loaded.checks,
            }),
        };
        if loaded.index_changed {
            store.write_index(&lock(&store.inner))?;
        }
        Ok((store, loaded.recovery))
    }

    /// The data folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The data folder as the file system resolves it (symbolic links followed): what paths
    /// read from records must stay under.
    pub fn canonical_dir(&self) -> &Path {
        &self.canonical
    }

    /// Absolute run directory of a record.
    pub fn run_dir(&self, record: &CalibrationRecord) -> PathBuf {
        self.dir.join(&record.run_dir)
    }

    fn write_index(&self, inner: &Inner) -> Result<()> {
        self.write_records(&inner.records)
    }

    fn write_records(&self, records: &[CalibrationRecord]) -> Result<()> {
        write_json_atomic(
            &self.dir.join("index.json"),
            &IndexFile {
                format: INDEX_FORMAT.into(),
                calibrations: records.to_vec(),
            },
        )
    }

    /// A fresh id: one past the highest in the history, skipping any id whose run directory
    /// already exists (a folder the index lost must not be written into). Numbers are checked:
    /// past [`MAX_ID`] the search starts again from 1, so an id never wraps to `cal-0000`.
    pub fn next_id(&self) -> Result<String> {
        let inner = lock(&self.inner);
        let taken = |n: u64| {
            let id = id_for(n);
            inner.records.iter().any(|r| r.id == id) || self.dir.join("runs").join(&id).exists()
        };
        let highest = inner
            .records
            .iter()
            .filter_map(|r| id_number(&r.id))
            .max()
            .unwrap_or(0);
        (highest + 1..=MAX_ID)
            .chain(1..=highest)
            .find(|&n| !taken(n))
            .map(id_for)
            .ok_or_else(|| {
                Error::io(
                    self.dir.join("runs"),
                    format!("every id up to cal-{MAX_ID} is taken"),
                )
            })
    }

    /// Adds a new record, written before it is kept: a write that fails (a full or
    /// read-only disk) leaves neither the index nor the daemon's memory holding it. Past
    /// `keep` records, the oldest finished ones that no camera has active leave the index and
    /// their run folders are deleted (after the index no longer names them).
    pub fn insert(&self, record: &CalibrationRecord, keep: usize) -> Result<()> {
        let mut inner = lock(&self.inner);
        let mut next = inner.records.clone();
        next.push(record.clone());
        let pruned = prune_history(&mut next, &inner.active, keep);
        self.write_records(&next)?;
        inner.records = next;
        drop(inner);
        for id in pruned {
            let dir = self.dir.join("runs").join(&id);
            if let Err(e) = std::fs::remove_dir_all(&dir) {
                if e.kind() != std::io::ErrorKind::NotFound {
                    tracing::warn!(
                        "easyhec daemon: {}: cannot delete a pruned run: {e}",
                        dir.display()
                    );
                }
            }
        }
        Ok(())
    }

    /// Inserts or replaces a record (by id) and rewrites `index.json`.
    pub fn save(&self, record: &CalibrationRecord) -> Result<()> {
        let mut inner = lock(&self.inner);
        match inner.records.iter_mut().find(|r| r.id == record.id) {
            Some(r) => *r = record.clone(),
            None => inner.records.push(record.clone()),
        }
        self.write_index(&inner)
    }

    /// Every record, oldest first.
    pub fn records(&self) -> Vec<CalibrationRecord> {
        lock(&self.inner).records.clone()
    }

    /// One record.
    pub fn record(&self, id: &str) -> Option<CalibrationRecord> {
        lock(&self.inner)
            .records
            .iter()
            .find(|r| r.id == id)
            .cloned()
    }

    /// The active calibration of a cell of one camera (none for a list of cameras).
    pub fn active(&self) -> Option<ActiveFile> {
        self.active_of(None)
    }

    /// The active calibration of `camera` (`None`: the cell's one camera).
    pub fn active_of(&self, camera: Option<&str>) -> Option<ActiveFile> {
        lock(&self.inner)
            .active
            .iter()
            .find(|a| a.camera.as_deref() == camera)
            .cloned()
    }

    /// Every active entry: the one camera's, or each named camera's of a list.
    pub fn active_all(&self) -> Vec<ActiveFile> {
        lock(&self.inner).active.clone()
    }

    /// Makes `result` of calibration `id` the active one.
    pub fn activate(&self, id: &str, result: ResultFile, now: &str) -> Result<ActiveFile> {
        self.activate_camera(None, id, result, now)
    }

    /// Makes `result` of calibration `id` the active one of `camera` (`None`: the cell's one
    /// camera), leaving every other camera's entry as it was.
    pub fn activate_camera(
        &self,
        camera: Option<&str>,
        id: &str,
        result: ResultFile,
        now: &str,
    ) -> Result<ActiveFile> {
        let mut done =
            self.activate_cameras(id, vec![(camera.map(str::to_string), result)], now)?;
        Ok(done.remove(0))
    }

    /// Makes each camera's result of calibration `id` its active one in one write of
    /// `active.json` (a failed write changes nothing), leaving the other cameras' entries.
    pub fn activate_cameras(
        &self,
        id: &str,
        results: Vec<(Option<String>, ResultFile)>,
        now: &str,
    ) -> Result<Vec<ActiveFile>> {
        let new: Vec<ActiveFile> = results
            .into_iter()
            .map(|(camera, result)| ActiveFile {
                format: ACTIVE_FORMAT.into(),
                id: id.to_string(),
                activated_at: now.to_string(),
                stale: false,
                stale_since: None,
                camera,
                result,
            })
            .collect();
        let mut inner = lock(&self.inner);
        let mut next: Vec<ActiveFile> = inner
            .active
            .iter()
            .filter(|a| a.camera.is_some() && !new.iter().any(|n| n.camera == a.camera))
            .cloned()
            .collect();
        if new.iter().any(|n| n.camera.is_none()) {
            next.clear();
        }
        next.extend(new.iter().cloned());
        next.sort_by(|a, b| a.camera.cmp(&b.camera));
        self.write_active(&next)?;
        inner.active = next;
        Ok(new)
    }

    /// Marks the active calibration stale (when it is still `id`).
    pub fn mark_stale(&self, id: &str, now: &str) -> Result<()> {
        self.mark_stale_camera(None, id, now)
    }

    /// Marks `camera`'s active calibration stale (when it is still `id`).
    pub fn mark_stale_camera(&self, camera: Option<&str>, id: &str, now: &str) -> Result<()> {
        let mut inner = lock(&self.inner);
        let mut next = inner.active.clone();
        let Some(active) = next
            .iter_mut()
            .find(|a| a.camera.as_deref() == camera && a.id == id)
        else {
            return Ok(());
        };
        if !active.stale {
            active.stale = true;
            active.stale_since = Some(now.to_string());
        }
        self.write_active(&next)?;
        inner.active = next;
        Ok(())
    }

    /// Writes `active.json`: an [`ActiveFile`] for one camera, a [`RigActiveFile`] for named
    /// cameras.
    fn write_active(&self, entries: &[ActiveFile]) -> Result<()> {
        let path = self.dir.join("active.json");
        match entries {
            [one] if one.camera.is_none() => write_json_atomic(&path, one),
            _ => write_json_atomic(
                &path,
                &RigActiveFile {
                    format: RIG_ACTIVE_FORMAT.into(),
                    cameras: entries.to_vec(),
                },
            ),
        }
    }

    /// Appends a bump check (the latest `CHECKS_KEPT` are kept).
    pub fn push_check(&self, check: &CheckRecord) -> Result<()> {
        self.push_checks(std::slice::from_ref(check))
    }

    /// Appends the checks of one bump check (one per camera) in one write.
    pub fn push_checks(&self, checks: &[CheckRecord]) -> Result<()> {
        let mut inner = lock(&self.inner);
        let mut next = inner.checks.clone();
        next.extend_from_slice(checks);
        let excess = next.len().saturating_sub(CHECKS_KEPT);
        next.drain(..excess);
        self.write_checks(&next)?;
        inner.checks = next;
        Ok(())
    }

    /// Updates the latest check (e.g. with the recalibration it started).
    pub fn update_last_check(&self, check: &CheckRecord) -> Result<()> {
        self.update_last_checks(std::slice::from_ref(check))
    }

    /// Replaces the latest `checks.len()` checks with `checks` (the same checks, now naming
    /// the recalibration they started).
    pub fn update_last_checks(&self, checks: &[CheckRecord]) -> Result<()> {
        let mut inner = lock(&self.inner);
        let mut next = inner.checks.clone();
        let from = next.len().saturating_sub(checks.len());
        next.truncate(from);
        next.extend_from_slice(checks);
        self.write_checks(&next)?;
        inner.checks = next;
        Ok(())
    }

    fn write_checks(&self, checks: &[CheckRecord]) -> Result<()> {
        write_json_atomic(
            &self.dir.join("checks.json"),
            &ChecksFile {
                format: CHECKS_FORMAT.into(),
                checks: checks.to_vec(),
            },
        )
    }

    /// Bump checks, oldest first.
    pub fn checks(&self) -> Vec<CheckRecord> {
        lock(&self.inner).checks.clone()
    }
}

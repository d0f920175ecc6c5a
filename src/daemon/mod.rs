//! `easyhec daemon`: a long-running service that owns one cell's arm and camera and runs
//! calibrations on request, with an HTTP API, a web page, bump checks and crash-safe storage.
//!
//! # Layout
//! - the `[daemon]` table of a cell config lives in [`crate::config::daemon`].
//! - [`store`]: the data folder (history index, active calibration, checks, run directories);
//!   [`reconcile`] reads it back at start without trusting it, with the checks of
//!   [`validate`].
//! - [`activation`]: which calibration may become the active one.
//! - [`bump`]: the bump check (silhouette under the active calibration vs a fresh mask).
//! - [`api`]: the axum router (JSON API, SSE progress, overlays, metrics, OpenAPI, web page);
//!   [`overlays`] renders and caches the overlay PNGs.
//! - [`http`]: the HTTP/1 server under the router (connection limit, timeouts).
//! - [`folder_lock`]: one daemon per data folder.
//!
//! One device lease: a calibration or a bump check holds the arm and camera; a second request
//! gets 409 naming the holder. The loop's planning and solving are CPU-bound and blocking, so
//! each calibration runs on its own named thread with a single-threaded tokio runtime; the
//! HTTP runtime only ever waits on channels and locks held for microseconds.

pub mod activation;
pub mod api;
pub mod bump;
pub mod exports;
pub mod folder_lock;
pub mod http;
pub mod openapi;
pub mod overlays;
pub mod plan;
pub mod reconcile;
pub mod store;
#[cfg(unix)]
pub mod systemd;
#[cfg(feature = "ros2")]
pub mod tf_broadcast;
pub mod validate;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime};

use nalgebra::Isometry3;
use serde::Serialize;
use tokio::sync::{broadcast, watch};

use crate::calibrate::{calibrate, Progress, RunOptions};
use crate::cell::Cell;
use crate::error::{Error, Result};
use crate::geometry::{from_rows, rotation_error_deg, translation_error_mm};
use crate::time::rfc3339;

use crate::config::DaemonSettings;
use store::{CalibrationRecord, Recovery, State, Store, TruthError};

/// The current time as RFC 3339.
fn now() -> String {
    rfc3339(SystemTime::now())
}

/// Locks a std mutex, recovering the data if a holder panicked (no holder does I/O that
/// could leave it half-updated).
fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// What holds the arm and camera.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Busy {
    /// A calibration, by id.
    Calibration(String),
    /// A bump check.
    Check,
    /// A camera preview for the page.
    Preview,
}

impl Busy {
    /// The id a 409 names (`check` for a bump check).
    pub fn name(&self) -> &str {
        match self {
            Busy::Calibration(id) => id,
            Busy::Check => "check",
            Busy::Preview => "preview",
        }
    }
}

/// The arm-and-camera lease: taken by [`Daemon::lease`], given back when dropped. One guard
/// type for calibrations, bump checks and previews, so no path can forget to give it back.
pub struct Lease {
    busy: Arc<Mutex<Option<Busy>>>,
    who: Busy,
}

impl Drop for Lease {
    fn drop(&mut self) {
        let mut busy = lock(&self.busy);
        if busy.as_ref() == Some(&self.who) {
            *busy = None;
        }
    }
}

/// How a calibration's loop ended, as [`final_state`] reads it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ending {
    /// The loop returned a result (it may have stopped early on the cancel flag).
    pub solved: bool,
    /// The loop itself saw the cancel flag and stopped early.
    pub loop_cancelled: bool,
    /// A cancel was accepted (answered 202) before the outcome was decided.
    pub cancel_accepted: bool,
    /// The daemon is shutting down.
    pub shutting_down: bool,
    /// The loop stopped on an arm fault (its result covers only the views before it).
    pub faulted: bool,
}

/// A job's final state. An accepted cancel always wins, even when the loop finished its
/// last round before it saw the flag: the client was promised a cancelled run, so it is
/// never `succeeded` and never activated. A loop that stopped on an arm fault failed, though
/// it wrote a result for the views before the fault.
pub fn final_state(e: Ending) -> State {
    let cancelled = e.loop_cancelled || e.cancel_accepted;
    let solved = e.solved && !e.faulted;
    match (e.shutting_down, cancelled, solved) {
        (true, true, _) | (true, _, false) => State::Interrupted,
        (false, true, _) => State::Cancelled,
        (_, false, true) => State::Succeeded,
        (false, false, false) => State::Failed,
    }
}

/// Why a request cannot be served now.
#[derive(Debug)]
pub enum Refusal {
    /// The arm is leased (409).
    Busy(Busy),
    /// The daemon is shutting down (503).
    ShuttingDown,
    /// Nothing to act on (404), with the reason.
    NotFound(String),
    /// The request does not fit the current state (409), with the reason.
    Conflict(String),
    /// The request itself is wrong (400).
    BadRequest(String),
    /// The request body is not JSON (415).
    UnsupportedMedia(String),
    /// The cell or the disk failed (500).
    Internal(String),
}

impl From<Error> for Refusal {
    fn from(e: Error) -> Self {
        Refusal::Internal(e.to_string())
    }
}

/// One SSE event: what happened and the calibration's status after it.
#[derive(Clone, Debug, Serialize, utoipa::ToSchema)]
pub struct Event {
    /// `state`, `view`, `round`, `planned` or `moving`.
    pub kind: String,
    /// For `view`: the view's index.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub view: Option<usize>,
    /// The status after the event.
    pub status: CalibrationRecord,
}

/// A calibration started by this process: its status, cancel flag and event channel.
pub struct Job {
    record: Mutex<CalibrationRecord>,
    cancel: Arc<AtomicBool>,
    events: broadcast::Sender<Event>,
    thread: Mutex<Option<std::thread::JoinHandle<()>>>,
    /// The arm lease this calibration holds, dropped when the job ends.
    lease: Mutex<Option<Lease>>,
    /// Set once the job's final state is decided: a cancel that finds it set is answered
    /// 409, so a 202 cancel always wins.
    decided: Mutex<bool>,
}

impl Job {
    /// The status now.
    pub fn record(&self) -> CalibrationRecord {
        lock(&self.record).clone()
    }

    /// Events from now on.
    pub fn subscribe(&self) -> broadcast::Receiver<Event> {
        self.events.subscribe()
    }
}

/// Counters for `/metrics`.
#[derive(Default)]
pub struct Metrics {
    /// Calibrations started.
    pub started: AtomicU64,
    /// Finished, by final state: succeeded, failed, cancelled, interrupted.
    pub finished: [AtomicU64; 4],
    /// Views captured by calibrations.
    pub views: AtomicU64,
    /// Bump checks run.
    pub checks: AtomicU64,
    /// Bump checks that found the camera moved.
    pub bumps: AtomicU64,
    /// Bump checks that failed (capture, motion).
    pub check_errors: AtomicU64,
    /// Last check's IoU, as f64 bits.
    pub last_iou: AtomicU64,
    /// Last check's boundary distance, as f64 bits.
    pub last_boundary_px: AtomicU64,
    /// Overlays rendered.
    pub overlay_renders: AtomicU64,
    /// Overlays served from the cache.
    pub overlay_hits: AtomicU64,
}

/// Final states in [`Metrics::finished`] order.
pub const FINISHED_STATES: [State; 4] = [
    State::Succeeded,
    State::Failed,
    State::Cancelled,
    State::Interrupted,
];

/// The daemon: the cell, the store and the live calibrations.
pub struct Daemon {
    cell: Arc<Cell>,
    settings: DaemonSettings,
    token: String,
    store: Store,
    jobs: Mutex<BTreeMap<String, Arc<Job>>>,
    busy: Arc<Mutex<Option<Busy>>>,
    shutting_down: AtomicBool,
    shutdown_tx: watch::Sender<bool>,
    /// Counters for `/metrics`.
    pub metrics: Metrics,
    /// The HTTP server's connection counters.
    pub http: Arc<http::HttpStats>,
    overlays: overlays::Cache,
    recovery: Recovery,
    /// `[ros2]`: the active calibration on `/tf_static`.
    #[cfg(feature = "ros2")]
    tf: Option<tf_broadcast::TfBroadcast>,
}

/// Options of `POST /api/v1/calibrations`.
#[derive(Clone, Debug, Default, serde::Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct StartOptions {
    /// Views at most (default: the config's `calibration.max_views`). Leaving the field out
    /// means the default; `null` is refused like any other non-integer, so a client's
    /// missing number never passes quietly as "use the config".
    #[serde(default, deserialize_with = "some_count")]
    pub max_views: Option<usize>,
    /// Plan only, never move.
    #[serde(default)]
    pub dry_run: bool,
    /// A cell with a list of cameras: calibrate only these, by name (default: every one).
    /// The others keep their active calibrations.
    #[serde(default, deserialize_with = "some_names")]
    pub cameras: Option<Vec<String>>,
}

/// A present `cameras`: a list of names, never `null`.
fn some_names<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> std::result::Result<Option<Vec<String>>, D::Error> {
    <Vec<String> as serde::Deserialize>::deserialize(d).map(Some)
}

/// Where a recalibration starts: the active calibration(s) it replaces and each camera's
/// pose in them (`None`: the cell's one camera).
#[derive(Clone, Debug)]
pub struct WarmStart {
    /// The calibration the first pose came from.
    pub from: String,
    /// Each camera's starting pose.
    pub poses: Vec<(Option<String>, Isometry3<f64>)>,
}

/// A camera's active calibration: the camera (`None`: the cell's one camera), its id and
/// its pose.
pub type ActivePose = (Option<String>, String, Isometry3<f64>);

/// A present `max_views`: an integer, never `null`.
fn some_count<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> std::result::Result<Option<usize>, D::Error> {
    <usize as serde::Deserialize>::deserialize(d).map(Some)
}

/// For a list of cameras, `[ros2]`'s frames give one edge per camera (published with
/// `publish_tf`, and in the export route's downloads), each to its own child frame: a
/// driver's fixed `optical_from_child` belongs to one camera, and one `frame_id` cannot parent
/// a camera on a link beside fixed ones, so those are refused.
fn check_tf_for_list(cell: &Cell) -> Result<()> {
    let Some(ros2) = cell.config.ros2.as_ref() else {
        return Ok(());
    };
    if !cell.config.camera.is_listed() {
        return Ok(());
    }
    if ros2.optical_from_child.is_some() {
        return Err(Error::input(
            &cell.config_path,
            "ros2.optical_from_child",
            "set with a list of cameras, and a driver's offset belongs to one camera; allowed: absent here (each camera's edge goes to its own child frame, NAME_ followed by child_frame_id)",
        ));
    }
    let mounts: std::collections::BTreeSet<Option<&str>> = cell
        .cameras()
        .iter()
        .map(|c| c.config.mount().link())
        .collect();
    if ros2.frame_id.is_some() && mounts.len() > 1 {
        return Err(Error::input(
            &cell.config_path,
            "ros2.frame_id",
            "set, and the listed cameras hang from different frames (a camera on a link beside fixed ones); allowed: absent here (each edge's parent is its camera's result base_link)",
        ));
    }
    Ok(())
}

impl Daemon {
    /// Opens the data folder at `data_dir` (repairing what a crash left) for `cell`, serving
    /// API calls that carry `token`.
    pub fn open(cell: Cell, data_dir: &Path, token: String) -> Result<Arc<Daemon>> {
        check_tf_for_list(&cell)?;
        if cell.config.camera.is_listed() {
            if let Some(c) = cell.cameras().iter().find(|c| c.segmenter.uses_context()) {
                return Err(Error::input(
                    &cell.config_path,
                    "segmenter.kind",
                    format!("camera '{}': a segmenter that reads the whole run (builtin) cannot check a camera of a [[camera]] list; allowed: a per-frame segmenter (onnx, sim-truth)", c.name),
                ));
            }
        }
        if token.trim().is_empty() {
            return Err(Error::input(
                &cell.config_path,
                "daemon.token",
                "no API token: set [daemon] token or the EASYHEC_TOKEN environment variable",
            ));
        }
        let (store, recovery) = Store::open(data_dir, &now())?;
        check_active_cameras(&cell, &store)?;
        let (shutdown_tx, _) = watch::channel(false);
        #[cfg(feature = "ros2")]
        let tf = match &cell.config.ros2 {
            Some(r) if r.publish_tf => Some(tf_broadcast::TfBroadcast::start(r.clone())?),
            _ => None,
        };
        #[cfg(not(feature = "ros2"))]
        if cell.config.ros2.is_some() {
            return Err(Error::input(
                &cell.config_path,
                "ros2",
                "needs ROS 2 support, which this build leaves out: rebuild with --features ros2",
            ));
        }
        let daemon = Arc::new(Daemon {
            settings: cell.config.daemon.clone(),
            cell: Arc::new(cell),
            token,
            store,
            jobs: Mutex::new(BTreeMap::new()),
            busy: Arc::default(),
            shutting_down: AtomicBool::new(false),
            shutdown_tx,
            metrics: Metrics::default(),
            http: Arc::default(),
            overlays: overlays::Cache::default(),
            recovery,
            #[cfg(feature = "ros2")]
            tf,
        });
        daemon.announce_active();
        Ok(daemon)
    }

    /// Hands every camera's active calibration to the ROS 2 broadcaster, when `[ros2]` asks
    /// for one (nothing while none is active). An entry whose frame no longer fits its
    /// camera's mount is left out, as [`Daemon::active_poses`] leaves it out.
    fn announce_active(&self) {
        #[cfg(feature = "ros2")]
        if let Some(tf) = &self.tf {
            tf.announce(|| {
                self.fitting_active()
                    .into_iter()
                    .map(|a| (a.id, a.camera, a.result))
                    .collect()
            });
        }
    }

    /// The cell.
    pub fn cell(&self) -> &Arc<Cell> {
        &self.cell
    }

    /// The `[daemon]` settings.
    pub fn settings(&self) -> &DaemonSettings {
        &self.settings
    }

    /// The store.
    pub fn store(&self) -> &Store {
        &self.store
    }

    /// Calibrations the last start found interrupted.
    pub fn recovered(&self) -> &[String] {
        &self.recovery.interrupted
    }

    /// Whether `given` is the API token (compared in constant time).
    pub fn token_matches(&self, given: &str) -> bool {
        let (a, b) = (self.token.as_bytes(), given.as_bytes());
        a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
    }

    /// What holds the arm now.
    pub fn busy(&self) -> Option<Busy> {
        lock(&self.busy).clone()
    }

    /// A live job of this process.
    pub fn job(&self, id: &str) -> Option<Arc<Job>> {
        lock(&self.jobs).get(id).cloned()
    }

    /// A calibration's status: live when this process runs it, else from the history.
    pub fn status(&self, id: &str) -> Option<CalibrationRecord> {
        self.job(id)
            .map(|j| j.record())
            .or_else(|| self.store.record(id))
    }

    /// Resolves when shutdown begins (SSE streams end on it).
    pub fn shutdown_signal(&self) -> watch::Receiver<bool> {
        self.shutdown_tx.subscribe()
    }

    /// Takes the arm lease for `who`, or says who holds it. The lease is given back when the
    /// returned guard drops, on every path: a finished job, an error, a panic or a request
    /// whose client hung up.
    fn lease(&self, who: Busy) -> std::result::Result<Lease, Refusal> {
        if self.shutting_down.load(Ordering::SeqCst) {
            return Err(Refusal::ShuttingDown);
        }
        let mut busy = lock(&self.busy);
        if let Some(b) = &*busy {
            return Err(Refusal::Busy(b.clone()));
        }
        *busy = Some(who.clone());
        Ok(Lease {
            busy: self.busy.clone(),
            who,
        })
    }

    /// Starts a calibration on its own thread; returns its id at once.
    pub fn start(
        self: &Arc<Self>,
        opts: StartOptions,
        trigger: &str,
        warm_start: Option<WarmStart>,
    ) -> std::result::Result<String, Refusal> {
        check_max_views(opts.max_views)?;
        let cameras = self.requested_cameras(opts.cameras.as_deref())?;
        // Hold the jobs lock while choosing the id so two starts cannot pick the same one.
        let jobs_guard = lock(&self.jobs);
        let id = self.store.next_id()?;
        let lease = self.lease(Busy::Calibration(id.clone()))?;
        let record = CalibrationRecord {
            id: id.clone(),
            state: State::Queued,
            trigger: trigger.to_string(),
            dry_run: opts.dry_run,
            max_views: opts
                .max_views
                .unwrap_or(self.cell.config.calibration.max_views),
            created_at: now(),
            started_at: None,
            finished_at: None,
            run_dir: format!("runs/{id}"),
            phase: None,
            round: None,
            views: 0,
            loss: None,
            mean_iou: None,
            best_variance: None,
            camera_from_base: None,
            uncertainty: None,
            stop_reason: None,
            error: None,
            warm_start_from: warm_start.as_ref().map(|w| w.from.clone()),
            planned_poses: None,
            truth_error: None,
            cameras,
            camera_results: None,
        };
        // Nothing is kept when the record cannot be written: no phantom `queued` entry.
        self.store
            .insert(&record, self.settings.keep_calibrations())?;
        let (events, _) = broadcast::channel(256);
        let job = Arc::new(Job {
            record: Mutex::new(record),
            cancel: Arc::new(AtomicBool::new(false)),
            events,
            thread: Mutex::new(None),
            lease: Mutex::new(Some(lease)),
            decided: Mutex::new(false),
        });
        let mut jobs_guard = jobs_guard;
        jobs_guard.insert(id.clone(), job.clone());
        drop(jobs_guard);
        self.metrics.started.fetch_add(1, Ordering::Relaxed);
        let daemon = self.clone();
        let warm = warm_start.map(|w| w.poses).unwrap_or_default();
        let thread_job = job.clone();
        let spawned = std::thread::Builder::new()
            .name(format!("easyhec-{id}"))
            .spawn(move || daemon.run_job(&thread_job, opts, warm));
        match spawned {
            Ok(handle) => {
                *lock(&job.thread) = Some(handle);
                Ok(id)
            }
            Err(e) => {
                let msg = format!("cannot start the calibration thread: {e}");
                self.finish(&job, State::Failed, |r| r.error = Some(msg.clone()));
                Err(Refusal::Internal(msg))
            }
        }
    }

    /// Updates a job's record, persists it (logging a failed write: the run directory still
    /// has everything) and broadcasts an event.
    fn update(
        &self,
        job: &Job,
        kind: &str,
        view: Option<usize>,
        f: impl FnOnce(&mut CalibrationRecord),
    ) {
        let record = {
            let mut r = lock(&job.record);
            f(&mut r);
            r.clone()
        };
        if let Err(e) = self.store.save(&record) {
            tracing::error!(
                "easyhec daemon: {}: cannot update the index: {e}",
                record.id
            );
        }
        let _ = job.events.send(Event {
            kind: kind.to_string(),
            view,
            status: record,
        });
    }

    /// Ends a job: frees the arm and counts it first, then publishes the final record, so a
    /// client that sees the final state can start the next calibration at once (no 409).
    fn finish(&self, job: &Job, state: State, f: impl FnOnce(&mut CalibrationRecord)) {
        if let Some(k) = FINISHED_STATES.iter().position(|s| *s == state) {
            self.metrics.finished[k].fetch_add(1, Ordering::Relaxed);
        }
        drop(lock(&job.lease).take());
        self.update(job, "state", None, |r| {
            f(r);
            r.state = state;
            r.phase = None;
            r.finished_at = Some(now());
        });
    }

    /// The calibration thread: runs the loop on a single-threaded runtime and records the end.
    fn run_job(
        self: &Arc<Self>,
        job: &Arc<Job>,
        opts: StartOptions,
        warm: Vec<(Option<String>, Isometry3<f64>)>,
    ) {
        let (id, run_dir) = {
            let r = job.record();
            (r.id.clone(), self.store.run_dir(&r))
        };
        self.update(job, "state", None, |r| {
            r.state = State::Running;
            r.started_at = Some(now());
            r.phase = Some("capturing".into());
        });
        let sink_daemon = Arc::downgrade(self);
        let sink_job = Arc::downgrade(job);
        let on_progress: crate::calibrate::ProgressSink = Arc::new(move |p: &Progress| {
            let (Some(d), Some(j)) = (sink_daemon.upgrade(), sink_job.upgrade()) else {
                return;
            };
            d.on_progress(&j, p);
        });
        let run_opts = RunOptions {
            dry_run: opts.dry_run,
            on_progress: Some(on_progress),
            cancel: Some(job.cancel.clone()),
            initial_guess: warm.iter().find(|(c, _)| c.is_none()).map(|(_, p)| *p),
            camera_guesses: warm
                .iter()
                .filter_map(|(c, p)| c.clone().map(|c| (c, *p)))
                .collect(),
            only_cameras: job.record().cameras,
            max_views: opts.max_views,
            ..RunOptions::default()
        };
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build();
        // A panic in the loop (a solver bug) must still end the job: lease given back, arm
        // stopped below, record final, never a daemon that answers 409 until restarted.
        let outcome = match runtime {
            Ok(rt) => std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                rt.block_on(calibrate(&self.cell, &run_dir, &run_opts))
            }))
            .unwrap_or_else(|_| {
                Err(Error::Hardware(
                    "the calibration loop panicked (a bug: please report it with the run folder)"
                        .into(),
                ))
            }),
            Err(e) => Err(Error::Hardware(format!(
                "cannot start the calibration runtime: {e}"
            ))),
        };
        // From here on a cancel is answered 409: the state below is final. The cancel flag is
        // read before the shutdown flag, so a shutdown that sets it is seen as a shutdown.
        let (cancel_accepted, shutting_down) = {
            let mut decided = lock(&job.decided);
            *decided = true;
            let cancelled = job.cancel.load(Ordering::SeqCst);
            (cancelled, self.shutting_down.load(Ordering::SeqCst))
        };
        let ending = |solved: bool, loop_cancelled: bool, faulted: bool| Ending {
            solved,
            loop_cancelled,
            cancel_accepted,
            shutting_down,
            faulted,
        };
        match outcome {
            Ok(o) => {
                let truth = self.truth_error(&o.result.camera_from_base());
                let state = final_state(ending(true, o.cancelled, o.faulted));
                // Activate before the record turns final: a client that sees "succeeded" may
                // check against the active calibration at once (it got 409 in between).
                if state == State::Succeeded && !opts.dry_run && self.settings.activate_on_success {
                    self.activate_outcome(&id, &o);
                }
                let camera_results = self.camera_records(&o);
                // A list's top-level figures are its first calibrated camera's.
                let truth = match &camera_results {
                    Some(c) => c.first().and_then(|c| c.truth_error.clone()),
                    None => truth,
                };
                if opts.dry_run {
                    if let Err(e) = plan::write(&o.run_dir, &o.planned) {
                        tracing::error!("easyhec daemon: {id}: cannot keep the plan: {e}");
                    }
                }
                self.finish(job, state, |r| {
                    r.stop_reason = Some(o.result.stop_reason.clone());
                    r.camera_from_base = Some(o.result.camera_from_base);
                    r.uncertainty = o.result.uncertainty.clone();
                    r.mean_iou = Some(o.report.mean_iou());
                    r.loss = Some(o.report.loss);
                    r.truth_error = truth;
                    r.camera_results = camera_results;
                    if r.dry_run {
                        r.planned_poses = Some(o.planned.len());
                    }
                    if state == State::Interrupted {
                        r.error = Some(
                            "the daemon shut down during this run; the arm was stopped".into(),
                        );
                    } else if state == State::Failed {
                        r.error = Some(format!(
                            "the loop stopped on an arm fault: {}",
                            o.result.stop_reason
                        ));
                    }
                });
                tracing::info!(
                    "easyhec daemon: {id} {}: {}",
                    state.name(),
                    o.result.stop_reason
                );
            }
            Err(e) => {
                // The loop stops the arm when a move fails; stop again in case it failed
                // elsewhere with the arm in motion.
                if let Ok(rt) = tokio::runtime::Builder::new_current_thread()
                    .enable_all()
                    .build()
                {
                    let _ = rt.block_on(self.cell.arm.stop());
                }
                let state = final_state(ending(false, false, false));
                tracing::warn!("easyhec daemon: {id} {}: {e}", state.name());
                self.finish(job, state, |r| r.error = Some(e.to_string()));
            }
        }
    }

    fn on_progress(&self, job: &Job, p: &Progress) {
        match p {
            Progress::ViewCaptured { index, .. } => {
                self.metrics.views.fetch_add(1, Ordering::Relaxed);
                self.update(job, "view", Some(*index), |r| {
                    r.views = index + 1;
                    r.phase = Some("solving".into());
                });
            }
            Progress::Round {
                round,
                views,
                loss,
                mean_iou,
                camera_from_base,
                uncertainty,
            } => self.update(job, "round", None, |r| {
                r.round = Some(*round);
                r.views = *views;
                r.loss = Some(*loss);
                r.mean_iou = Some(*mean_iou);
                r.camera_from_base = Some(*camera_from_base);
                r.uncertainty = uncertainty.as_deref().cloned();
                r.phase = Some("planning".into());
            }),
            Progress::Planned { best_variance, .. } => self.update(job, "planned", None, |r| {
                r.best_variance = *best_variance;
            }),
            Progress::Moving { .. } => self.update(job, "moving", None, |r| {
                r.phase = Some("moving".into());
            }),
        }
    }

    /// Error against the simulated camera's true pose now (simulated cells only).
    fn truth_error(&self, est: &Isometry3<f64>) -> Option<TruthError> {
        let truth = self.cell.sim.camera_from_base_now()?;
        Some(truth_error_of(est, &truth))
    }

    /// Cancels a running calibration: sets its flag and stops the arm at once.
    pub async fn cancel(&self, id: &str) -> std::result::Result<CalibrationRecord, Refusal> {
        let Some(job) = self.job(id) else {
            return match self.store.record(id) {
                Some(r) => Err(Refusal::Conflict(format!(
                    "calibration {id} is {}: only a queued or running one can be cancelled",
                    r.state.name()
                ))),
                None => Err(Refusal::NotFound(format!("no calibration {id}"))),
            };
        };
        {
            // Under the job's decision lock: either the flag is set before the outcome is
            // decided (and the run ends cancelled), or the run has already finished.
            let decided = lock(&job.decided);
            let record = job.record();
            if *decided || record.state.is_final() {
                return Err(Refusal::Conflict(format!(
                    "calibration {id} already finished (its outcome was decided before the cancel arrived): only a queued or running one can be cancelled"
                )));
            }
            job.cancel.store(true, Ordering::SeqCst);
        }
        // Stop first; the loop notices the flag and ends the run as cancelled.
        if let Err(e) = self.cell.arm.stop().await {
            tracing::error!("easyhec daemon: {id}: stop after cancel failed: {e}");
        }
        Ok(job.record())
    }

    /// Activates what a calibration that just succeeded solved: its one camera, or each
    /// camera of a list it calibrated (the others keep theirs).
    fn activate_outcome(&self, id: &str, o: &crate::calibrate::Outcome) {
        if !self.cell.config.camera.is_listed() {
            self.activate_new(id, None, &o.result);
            return;
        }
        let mut results = Vec::new();
        for c in &o.cameras {
            if let Err((field, m)) = reconcile::check_result_pose(&c.result) {
                tracing::warn!(
                    "easyhec daemon: {id}: camera '{}': result {field}: {m}; not activated",
                    c.name
                );
                return;
            }
            results.push((Some(c.name.clone()), c.result.clone()));
        }
        match self.store.activate_cameras(id, results, &now()) {
            Ok(_) => self.announce_active(),
            Err(e) => tracing::error!("easyhec daemon: {id}: cannot activate: {e}"),
        }
    }

    /// Activates one camera's result, unless its pose is not rigid (logged: a solver bug
    /// must not reach the robot controllers).
    fn activate_new(&self, id: &str, camera: Option<&str>, result: &crate::run::ResultFile) {
        if let Err((field, m)) = reconcile::check_result_pose(result) {
            tracing::warn!("easyhec daemon: {id}: result {field}: {m}; not activated");
            return;
        }
        match self
            .store
            .activate_camera(camera, id, result.clone(), &now())
        {
            Ok(_) => self.announce_active(),
            Err(e) => tracing::error!("easyhec daemon: {id}: cannot activate: {e}"),
        }
    }

    /// Each camera's final result, for a calibration of a list of cameras.
    fn camera_records(&self, o: &crate::calibrate::Outcome) -> Option<Vec<store::CameraRecord>> {
        if !self.cell.config.camera.is_listed() {
            return None;
        }
        let units = self.cell.cameras();
        let records = o
            .cameras
            .iter()
            .map(|c| {
                let truth = self
                    .cell
                    .camera_index(&c.name)
                    .and_then(|k| units[k].sim.camera_from_base_now())
                    .map(|t| truth_error_of(&c.result.camera_from_base(), &t));
                store::CameraRecord {
                    camera: c.name.clone(),
                    camera_from_base: c.result.camera_from_base,
                    uncertainty: c.result.uncertainty.clone(),
                    mean_iou: c.report.mean_iou(),
                    stop_reason: c.result.stop_reason.clone(),
                    truth_error: truth,
                }
            })
            .collect();
        Some(records)
    }

    /// The cameras a start request names, checked against the cell: `None` for a cell of
    /// one camera, else the names asked for (every camera by default), in config order.
    fn requested_cameras(
        &self,
        asked: Option<&[String]>,
    ) -> std::result::Result<Option<Vec<String>>, Refusal> {
        let names: Vec<String> = self
            .cell
            .cameras()
            .iter()
            .map(|c| c.name.to_string())
            .collect();
        if !self.cell.config.camera.is_listed() {
            return match asked {
                None => Ok(None),
                Some(_) => Err(Refusal::BadRequest(
                    "cameras: this cell has one [camera]; allowed: only for a cell with [[camera]] tables".into(),
                )),
            };
        }
        let Some(asked) = asked else {
            return Ok(Some(names));
        };
        let known: Vec<&str> = names.iter().map(String::as_str).collect();
        if let Some(m) = crate::config::cameras::selection_problem(&known, asked) {
            return Err(Refusal::BadRequest(m));
        }
        Ok(Some(
            names.into_iter().filter(|n| asked.contains(n)).collect(),
        ))
    }

    /// Begins shutdown: refuses new work, cancels a running calibration (stopping the arm
    /// first) and waits for its thread to end, so the run directory and index are final.
    pub async fn shutdown(self: &Arc<Self>) {
        self.shutting_down.store(true, Ordering::SeqCst);
        let _ = self.shutdown_tx.send(true);
        let running: Vec<Arc<Job>> = lock(&self.jobs).values().cloned().collect();
        let mut any = false;
        for job in &running {
            if !job.record().state.is_final() {
                job.cancel.store(true, Ordering::SeqCst);
                any = true;
            }
        }
        if any || matches!(self.busy(), Some(Busy::Check)) {
            if let Err(e) = self.cell.arm.stop().await {
                tracing::error!("easyhec daemon: stopping the arm at shutdown failed: {e}");
            }
        }
        for job in running {
            let handle = lock(&job.thread).take();
            if let Some(h) = handle {
                // Planning can take a few seconds before the loop sees the flag.
                let joined = tokio::time::timeout(
                    Duration::from_secs(60),
                    tokio::task::spawn_blocking(move || h.join()),
                )
                .await;
                if joined.is_err() {
                    tracing::warn!(
                        "easyhec daemon: a calibration did not end within 60 s of shutdown"
                    );
                }
            }
        }
    }

    /// The active calibration's pose, for bump checks and warm starts; none when it was
    /// solved for another frame than this cell's camera pose refers to (the mount changed).
    pub fn active_pose(&self) -> Option<(String, Isometry3<f64>)> {
        let a = self.store.active()?;
        if self.frame_mismatch(None, &a.result.base_link).is_some() {
            return None;
        }
        let pose = from_rows(&a.result.camera_from_base).ok()?;
        Some((a.id, pose))
    }

    /// Every active entry whose result's frame fits its camera's mount ([`Daemon::frame_mismatch`]).
    fn fitting_active(&self) -> Vec<store::ActiveFile> {
        self.store
            .active_all()
            .into_iter()
            .filter(|a| {
                self.frame_mismatch(a.camera.as_deref(), &a.result.base_link)
                    .is_none()
            })
            .collect()
    }

    /// Every camera's active calibration that fits its mount, for bump checks: the one
    /// camera's, or each camera's of a list.
    pub fn active_poses(&self) -> Vec<ActivePose> {
        self.fitting_active()
            .into_iter()
            .filter_map(|a| {
                let pose = from_rows(&a.result.camera_from_base).ok()?;
                Some((a.camera, a.id, pose))
            })
            .collect()
    }

    /// Why a result solved from frame `base_link` does not fit the mount of camera `camera`
    /// (the first, or only, camera when `None`), if it does not: a camera on a link needs a
    /// result for that link, and a fixed camera one for a frame that no joint moves (the base
    /// link or a frame fixed to it).
    pub fn frame_mismatch(&self, camera: Option<&str>, base_link: &str) -> Option<String> {
        let robot = &self.cell.robot;
        let cameras = self.cell.cameras();
        let index = match camera {
            None => 0,
            Some(name) => match self.cell.camera_index(name) {
                Some(i) => i,
                None => {
                    return Some(format!(
                        "belongs to camera '{name}', which this cell's config does not list"
                    ))
                }
            },
        };
        let unit = &cameras[index];
        let (table, key) = if self.cell.config.camera.is_listed() {
            (
                format!("camera '{}'", unit.name),
                format!("camera[{index}].mount"),
            )
        } else {
            (
                "this cell's camera".to_string(),
                "[camera] mount".to_string(),
            )
        };
        match unit.config.mount().link() {
            Some(link) if base_link != link => Some(format!(
                "is '{base_link}', but {table} is on link '{link}' ({key}): calibrate again for this mount"
            )),
            None if robot.link_index(base_link).is_some_and(|i| robot.link_moves(i)) => {
                Some(format!(
                    "is '{base_link}', a link the arm moves: that result is for a camera on the arm, and {table} is fixed ({key}): calibrate again for this mount"
                ))
            }
            _ => None,
        }
    }
}

/// Error of `est` against a simulated camera's true pose.
fn truth_error_of(est: &Isometry3<f64>, truth: &Isometry3<f64>) -> TruthError {
    TruthError {
        rotation_deg: rotation_error_deg(est, truth),
        translation_mm: translation_error_mm(est, truth),
    }
}

/// `active.json` fits the cell: entries named by camera for a list of cameras, each a camera
/// of the config; one unnamed entry for a cell of one camera. A data folder written for
/// another camera layout is refused before anything is checked against it.
fn check_active_cameras(cell: &Cell, store: &Store) -> Result<()> {
    let names: Vec<&str> = cell.cameras().iter().map(|c| c.name).collect();
    let listed = cell.config.camera.is_listed();
    for a in store.active_all() {
        let problem = match (&a.camera, listed) {
            (None, true) => Some(format!(
                "holds one camera's calibration ({}), and this cell lists cameras {names:?}; allowed: an easyhec-daemon-active/2 file naming them",
                a.id
            )),
            (Some(n), false) => Some(format!(
                "names camera {n:?}, and this cell has one [camera]; allowed: an easyhec-daemon-active/1 file"
            )),
            (Some(n), true) if !names.contains(&n.as_str()) => Some(format!(
                "names camera {n:?}, which the config does not list; allowed: {names:?}"
            )),
            _ => None,
        };
        if let Some(m) = problem {
            return Err(Error::input(
                store.dir().join("active.json"),
                "cameras",
                format!(
                    "{m}: move the file away to start afresh (the run directories stay intact)"
                ),
            ));
        }
    }
    Ok(())
}

/// `max_views` within the bounds a cell config has (1 to `bounds::MAX_VIEWS`): a start
/// request must not ask for a run (and a plan and solve) the config itself could not.
fn check_max_views(n: Option<usize>) -> std::result::Result<(), Refusal> {
    use crate::config::checks::bounds::MAX_VIEWS;
    match n {
        Some(0) => Err(Refusal::BadRequest(
            "max_views: a calibration needs at least 1 view".into(),
        )),
        Some(n) if n > MAX_VIEWS => Err(Refusal::BadRequest(format!(
            "max_views: {n} is more than {MAX_VIEWS}, the most a calibration takes (the bound of [calibration] max_views)"
        ))),
        _ => Ok(()),
    }
}

/// Resolves the daemon's data folder: `--data` as given, else `[daemon] data_dir` relative to
/// the config file, else the state folder [`default_data_dir`] names.
pub fn data_dir(
    config: &crate::config::CellConfig,
    config_path: &Path,
    arg: Option<&Path>,
) -> Result<PathBuf> {
    if let Some(p) = arg {
        return Ok(p.to_path_buf());
    }
    if let Some(d) = &config.daemon.data_dir {
        let base = config_path.parent().unwrap_or(Path::new("."));
        return Ok(base.join(d));
    }
    let var = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty());
    default_data_dir(var("STATE_DIRECTORY"), var("XDG_STATE_HOME"), var("HOME")).ok_or_else(|| {
        Error::input(
            config_path,
            "daemon.data_dir",
            "absent, and neither STATE_DIRECTORY, XDG_STATE_HOME nor HOME is set; allowed: a folder for the daemon's data, or --data",
        )
    })
}

/// The data folder a daemon uses when neither `--data` nor `data_dir` names one: systemd's
/// `StateDirectory=` (first entry of `$STATE_DIRECTORY`), else `$XDG_STATE_HOME/easyhec`,
/// else `$HOME/.local/state/easyhec`. Never a folder beside the config, which may sit in a
/// source checkout.
pub fn default_data_dir(
    state_directory: Option<std::ffi::OsString>,
    xdg_state_home: Option<std::ffi::OsString>,
    home: Option<std::ffi::OsString>,
) -> Option<PathBuf> {
    if let Some(s) = state_directory {
        // systemd joins several StateDirectory= entries with ':'.
        let first = s
            .to_string_lossy()
            .split(':')
            .next()
            .unwrap_or("")
            .to_string();
        if !first.is_empty() {
            return Some(PathBuf::from(first));
        }
    }
    if let Some(x) = xdg_state_home.filter(|x| Path::new(x).is_absolute()) {
        return Some(PathBuf::from(x).join("easyhec"));
    }
    home.map(|h| PathBuf::from(h).join(".local/state/easyhec"))
}

/// The API token: `EASYHEC_TOKEN` when set and non-empty, else `[daemon] token`.
pub fn resolve_token(cell: &Cell) -> Result<String> {
    if let Ok(t) = std::env::var("EASYHEC_TOKEN") {
        if !t.trim().is_empty() {
            return Ok(t.trim().to_string());
        }
    }
    cell.config.daemon.token.clone().ok_or_else(|| {
        Error::input(
            &cell.config_path,
            "daemon.token",
            "no API token: set [daemon] token in the config or the EASYHEC_TOKEN environment variable",
        )
    })
}

/// Runs the daemon on `listener` until `shutdown` resolves, then stops any calibration
/// (arm first) and drains the server. Scheduled bump checks run when configured. The soft
/// open-file limit is raised first, since every connection is a file descriptor.
pub async fn serve(
    daemon: Arc<Daemon>,
    listener: tokio::net::TcpListener,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) -> Result<()> {
    let limits = http::Limits::resolve(&daemon.settings, http::open_file_limit());
    let router = api::router(daemon.clone());
    let scheduler = daemon
        .settings
        .check_interval_s
        .map(|s| tokio::spawn(bump::schedule(daemon.clone(), Duration::from_secs_f64(s))));
    let d = daemon.clone();
    let stopping = async move {
        shutdown.await;
        tracing::info!("easyhec daemon: shutting down (stopping any motion first)");
        d.shutdown().await;
    };
    http::run(listener, router, limits, daemon.http.clone(), stopping).await;
    if let Some(s) = scheduler {
        s.abort();
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ending(
        solved: bool,
        loop_cancelled: bool,
        cancel_accepted: bool,
        shutting_down: bool,
    ) -> State {
        final_state(Ending {
            solved,
            loop_cancelled,
            cancel_accepted,
            shutting_down,
            faulted: false,
        })
    }

    #[test]
    fn an_accepted_cancel_always_ends_cancelled_even_after_the_last_round() {
        assert_eq!(ending(true, false, false, false), State::Succeeded);
        // The loop finished before it saw the flag: the 202 still wins.
        assert_eq!(ending(true, false, true, false), State::Cancelled);
        assert_eq!(ending(true, true, true, false), State::Cancelled);
        assert_eq!(ending(false, false, true, false), State::Cancelled);
        assert_eq!(ending(false, false, false, false), State::Failed);
        // Shutdown stops the run with the same flag: interrupted, never activated.
        assert_eq!(ending(true, true, true, true), State::Interrupted);
        assert_eq!(ending(false, false, false, true), State::Interrupted);
        assert_eq!(ending(true, false, false, true), State::Succeeded);
        // An arm fault ends the loop with a result, which is still a failed run.
        let faulted = Ending {
            solved: true,
            loop_cancelled: false,
            cancel_accepted: false,
            shutting_down: false,
            faulted: true,
        };
        assert_eq!(final_state(faulted), State::Failed);
    }

    #[test]
    fn the_default_data_folder_is_the_state_folder_never_the_config_folder() {
        let some = |s: &str| Some(std::ffi::OsString::from(s));
        assert_eq!(
            default_data_dir(
                some("/var/lib/easyhec:/var/lib/other"),
                some("/x"),
                some("/home/u")
            ),
            Some(PathBuf::from("/var/lib/easyhec"))
        );
        assert_eq!(
            default_data_dir(None, some("/home/u/.state"), some("/home/u")),
            Some(PathBuf::from("/home/u/.state/easyhec"))
        );
        // A relative XDG_STATE_HOME is invalid by the spec and ignored.
        assert_eq!(
            default_data_dir(None, some("rel"), some("/home/u")),
            Some(PathBuf::from("/home/u/.local/state/easyhec"))
        );
        assert_eq!(default_data_dir(None, None, None), None);
    }
}

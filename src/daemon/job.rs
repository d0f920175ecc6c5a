//! A calibration job's life: started under the arm lease, run on its own thread, followed
//! through events, cancelled, and ended in the state [`final_state`] decides (a pure
//! function of how the loop ended, unit-tested below), after which its result may become
//! active.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use nalgebra::Isometry3;
use serde::Serialize;
use tokio::sync::broadcast;

use crate::calibrate::{calibrate, Progress, RunOptions};
use crate::error::Error;
use crate::geometry::{rotation_error_deg, translation_error_mm};
use crate::run::rig::RunLayout;

use super::records::Phase;
use super::store::{CalibrationRecord, State, TruthError};
use super::{lock, now, plan, reconcile, store, Busy, Daemon, Lease, Refusal, FINISHED_STATES};

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

/// What an [`Event`] reports. Serialised lowercase, which is also the SSE event's name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum EventKind {
    /// The calibration's state changed (and the first event of every stream).
    State,
    /// A view was captured.
    View,
    /// A round was solved.
    Round,
    /// The next pose was planned.
    Planned,
    /// The arm is moving to it.
    Moving,
}

impl EventKind {
    /// The name in the JSON and the SSE `event:` line.
    pub fn name(self) -> &'static str {
        match self {
            EventKind::State => "state",
            EventKind::View => "view",
            EventKind::Round => "round",
            EventKind::Planned => "planned",
            EventKind::Moving => "moving",
        }
    }
}

/// One SSE event: what happened and the calibration's status after it.
#[derive(Clone, Debug, Serialize, utoipa::ToSchema)]
pub struct Event {
    /// What happened.
    pub kind: EventKind,
    /// For `view`: the view's index.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub view: Option<usize>,
    /// The status after the event.
    pub status: CalibrationRecord,
}

/// A calibration started by this process: its status, cancel flag and event channel.
pub struct Job {
    record: Mutex<CalibrationRecord>,
    pub(super) cancel: Arc<AtomicBool>,
    events: broadcast::Sender<Event>,
    pub(super) thread: Mutex<Option<std::thread::JoinHandle<()>>>,
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

/// A present `max_views`: an integer, never `null`.
fn some_count<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> std::result::Result<Option<usize>, D::Error> {
    <usize as serde::Deserialize>::deserialize(d).map(Some)
}

/// Error of `est` against a simulated camera's true pose.
fn truth_error_of(est: &Isometry3<f64>, truth: &Isometry3<f64>) -> TruthError {
    TruthError {
        rotation_deg: rotation_error_deg(est, truth),
        translation_mm: translation_error_mm(est, truth),
    }
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

impl Daemon {
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
    pub(super) fn update(
        &self,
        job: &Job,
        kind: EventKind,
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
            kind,
            view,
            status: record,
        });
    }

    /// Ends a job: frees the arm and counts it first, then publishes the final record, so a
    /// client that sees the final state can start the next calibration at once (no 409).
    pub(super) fn finish(&self, job: &Job, state: State, f: impl FnOnce(&mut CalibrationRecord)) {
        if let Some(k) = FINISHED_STATES.iter().position(|s| *s == state) {
            self.metrics.finished[k].fetch_add(1, Ordering::Relaxed);
        }
        drop(lock(&job.lease).take());
        self.update(job, EventKind::State, None, |r| {
            f(r);
            r.state = state;
            r.phase = None;
            r.finished_at = Some(now());
        });
    }

    /// The calibration thread: runs the loop on a single-threaded runtime and records the end.
    pub(super) fn run_job(
        self: &Arc<Self>,
        job: &Arc<Job>,
        opts: StartOptions,
        warm: Vec<(Option<String>, Isometry3<f64>)>,
    ) {
        let (id, run_dir) = {
            let r = job.record();
            (r.id.clone(), self.store.run_dir(&r))
        };
        self.update(job, EventKind::State, None, |r| {
            r.state = State::Running;
            r.started_at = Some(now());
            r.phase = Some(Phase::Capturing);
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

    pub(super) fn on_progress(&self, job: &Job, p: &Progress) {
        match p {
            Progress::ViewCaptured { index, .. } => {
                self.metrics.views.fetch_add(1, Ordering::Relaxed);
                self.update(job, EventKind::View, Some(*index), |r| {
                    r.views = index + 1;
                    r.phase = Some(Phase::Solving);
                });
            }
            Progress::Round {
                round,
                views,
                loss,
                mean_iou,
                camera_from_base,
                uncertainty,
            } => self.update(job, EventKind::Round, None, |r| {
                r.round = Some(*round);
                r.views = *views;
                r.loss = Some(*loss);
                r.mean_iou = Some(*mean_iou);
                r.camera_from_base = Some(*camera_from_base);
                r.uncertainty = uncertainty.as_deref().cloned();
                r.phase = Some(Phase::Planning);
            }),
            Progress::Planned { best_variance, .. } => {
                self.update(job, EventKind::Planned, None, |r| {
                    r.best_variance = *best_variance;
                })
            }
            Progress::Moving { .. } => self.update(job, EventKind::Moving, None, |r| {
                r.phase = Some(Phase::Moving);
            }),
        }
    }

    /// Error against the simulated camera's true pose now (simulated cells only).
    pub(super) fn truth_error(&self, est: &Isometry3<f64>) -> Option<TruthError> {
        let truth = self.cell.units[0].sim.camera_from_base_now()?;
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
    pub(super) fn activate_outcome(&self, id: &str, o: &crate::calibrate::Outcome) {
        if self.cell.layout() == RunLayout::OneCamera {
            self.activate_new(id, None, &o.result);
            return;
        }
        let mut results = Vec::new();
        for c in &o.cameras {
            if let Err((field, m)) = reconcile::check_result(&c.result) {
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

    /// Activates one camera's result, unless [`reconcile::check_result`] refuses it (logged:
    /// a solver bug must not reach the robot controllers or the bump checks).
    pub(super) fn activate_new(
        &self,
        id: &str,
        camera: Option<&str>,
        result: &crate::run::ResultFile,
    ) {
        if let Err((field, m)) = reconcile::check_result(result) {
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
    pub(super) fn camera_records(
        &self,
        o: &crate::calibrate::Outcome,
    ) -> Option<Vec<store::CameraRecord>> {
        if self.cell.layout() == RunLayout::OneCamera {
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
    pub(super) fn requested_cameras(
        &self,
        asked: Option<&[String]>,
    ) -> std::result::Result<Option<Vec<String>>, Refusal> {
        let names: Vec<String> = self
            .cell
            .cameras()
            .iter()
            .map(|c| c.name.to_string())
            .collect();
        if self.cell.layout() == RunLayout::OneCamera {
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
}

#[cfg(test)]
mod event_tests {
    use super::EventKind;

    /// The enum serialises to the names clients read (the JSON stays what it was).
    #[test]
    fn event_kinds_serialise_to_their_names() {
        for k in [
            EventKind::State,
            EventKind::View,
            EventKind::Round,
            EventKind::Planned,
            EventKind::Moving,
        ] {
            assert_eq!(serde_json::to_value(k).unwrap(), k.name());
        }
    }
}

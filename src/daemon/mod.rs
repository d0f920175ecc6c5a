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
pub mod job;
pub mod openapi;
pub mod overlays;
pub mod plan;
pub mod reconcile;
pub mod records;
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
use tokio::sync::watch;

use crate::cell::Cell;
use crate::error::{Error, Result};
use crate::geometry::from_rows;
use crate::run::rig::RunLayout;
use crate::time::rfc3339;

use crate::config::DaemonSettings;
use store::{CalibrationRecord, Recovery, State, Store};

pub use job::{final_state, Ending, Event, Job, StartOptions, WarmStart};

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

/// A camera's active calibration: the camera (`None`: the cell's one camera), its id and
/// its pose.
pub type ActivePose = (Option<String>, String, Isometry3<f64>);

/// For a list of cameras, `[ros2]`'s frames give one edge per camera (published with
/// `publish_tf`, and in the export route's downloads), each to its own child frame: a
/// driver's fixed `optical_from_child` belongs to one camera, and one `frame_id` cannot parent
/// a camera on a link beside fixed ones, so those are refused.
fn check_tf_for_list(cell: &Cell) -> Result<()> {
    let Some(ros2) = cell.config.ros2.as_ref() else {
        return Ok(());
    };
    if cell.layout() == RunLayout::OneCamera {
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
        cell.config.check_whole_run_segmenters(
            &cell.config_path,
            cell.layout() == RunLayout::NamedCameras,
        )?;
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
        let (table, key) = if self.cell.layout() == RunLayout::NamedCameras {
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

/// `active.json` fits the cell: entries named by camera for a list of cameras, each a camera
/// of the config; one unnamed entry for a cell of one camera. A data folder written for
/// another camera layout is refused before anything is checked against it.
fn check_active_cameras(cell: &Cell, store: &Store) -> Result<()> {
    let names: Vec<&str> = cell.cameras().iter().map(|c| c.name).collect();
    let named = cell.layout() == RunLayout::NamedCameras;
    for a in store.active_all() {
        let problem = match (&a.camera, named) {
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

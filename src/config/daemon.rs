//! `[daemon]` in a cell config: where the daemon listens, its token, its data folder and the
//! bump check, and the limits of its HTTP server. Every key has a default, so a cell config
//! without the table still runs a daemon (given a token in `EASYHEC_TOKEN`).

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// `[daemon]`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct DaemonSettings {
    /// `HOST:PORT` to listen on (default `127.0.0.1:8787`; `--listen` overrides).
    #[serde(default = "default_listen")]
    pub listen: String,
    /// Bearer token every call that acts (starts, cancels, activates, checks: anything that
    /// can move the arm or change the active calibration) must send. `EASYHEC_TOKEN`
    /// overrides it, so the secret can stay out of the file; the daemon refuses to start with
    /// neither.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub token: Option<String>,
    /// Require the token for read-only routes too (status, history, events, overlays, the
    /// active calibration, metrics). Default false: dashboards and cell controllers read
    /// without it.
    #[serde(default)]
    pub protect_reads: bool,
    /// Data folder (run directories, history, active calibration), relative to the config
    /// file. Absent: the service manager's state folder (`$STATE_DIRECTORY`, systemd's
    /// `StateDirectory=`), else `$XDG_STATE_HOME/easyhec`, else `~/.local/state/easyhec`:
    /// never beside the config, which may sit in a checkout. `--data` overrides.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub data_dir: Option<PathBuf>,
    /// Calibrations kept in the history. Past it, the oldest finished calibration that is
    /// no camera's active one leaves the index and its run folder is deleted, so the index
    /// stays far below the size the daemon reads back. Absent: [`KEEP_CALIBRATIONS`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub keep_calibrations: Option<usize>,
    /// Seconds between scheduled bump checks; absent: checks only on demand.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub check_interval_s: Option<f64>,
    /// A check whose silhouette IoU falls below this marks the calibration stale.
    #[serde(default = "default_min_iou")]
    pub bump_min_iou: f64,
    /// A check whose mean boundary distance (pixels, both ways) exceeds this marks the
    /// calibration stale.
    #[serde(default = "default_max_boundary_px")]
    pub bump_max_boundary_px: f64,
    /// Largest uniform outline offset (pixels) a check puts down to its segmenter rather than
    /// to the camera: a segmenter that draws masks fatter or thinner than the one the
    /// calibration used moves the whole outline outward or inward, which no bump does. The
    /// check removes the typical offset (the mean of the middle half), up to this, before it
    /// measures IoU and boundary distance (0: measure the masks as they are).
    #[serde(default = "default_max_mask_offset_px")]
    pub bump_max_mask_offset_px: f64,
    /// Recalibrate, warm-started from the stale pose, when a check finds a bump.
    #[serde(default)]
    pub recalibrate_on_bump: bool,
    /// Joints to move to before each check (through the safety checker, at
    /// `calibration.speed_rad_s`). Setting it is what allows checks to move the arm; absent:
    /// checks capture wherever the idle arm stands.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub check_pose: Option<Vec<f64>>,
    /// Make a successful calibration the active one at once (default true); otherwise only
    /// `POST /api/v1/calibrations/{id}/activate` does.
    #[serde(default = "yes")]
    pub activate_on_success: bool,
    /// Seconds a connection may take to send a complete request head, counted from when it
    /// opens or from its previous response (so it also bounds an idle keep-alive connection).
    /// Absent: [`HEADER_READ_TIMEOUT_S`]. An option, so that configs without it serialise as
    /// before.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub header_read_timeout_s: Option<f64>,
    /// Seconds a connection may move no byte either way (a stalled request body, a client
    /// that stops reading) before it is closed; a handler at work with the whole request does
    /// not count as idle. Absent: [`IDLE_TIMEOUT_S`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub idle_timeout_s: Option<f64>,
    /// Open connections at most; one more is answered 503 and closed. Absent:
    /// [`MAX_CONNECTIONS`]. The daemon lowers it to what its open-file limit allows.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_connections: Option<usize>,
}

/// Default `header_read_timeout_s`: long enough for any client on a LAN, short enough that a
/// client which connects and says nothing does not hold a connection for long.
pub const HEADER_READ_TIMEOUT_S: f64 = 10.0;
/// Largest `header_read_timeout_s`.
pub const HEADER_READ_TIMEOUT_MAX_S: f64 = 300.0;
/// Default `idle_timeout_s`.
pub const IDLE_TIMEOUT_S: f64 = 60.0;
/// Smallest `idle_timeout_s` (an idle event stream sends a keep-alive comment every third of
/// it, at most every 15 s, so it is never cut).
pub const IDLE_TIMEOUT_MIN_S: f64 = 2.0;
/// Largest `idle_timeout_s`.
pub const IDLE_TIMEOUT_MAX_S: f64 = 3600.0;
/// Default `max_connections`: room for a thousand idle clients and the ones that matter.
pub const MAX_CONNECTIONS: usize = 2048;
/// Longest time between scheduled bump checks, seconds (a year): far beyond any useful
/// schedule, and well inside what a timer can hold.
pub const MAX_CHECK_INTERVAL_S: f64 = 31_536_000.0;
/// Default `keep_calibrations`.
pub const KEEP_CALIBRATIONS: usize = 1000;
/// Largest `keep_calibrations`: a record is at most a few KiB, so the index stays well
/// inside the 64 MiB the daemon reads back.
pub const KEEP_CALIBRATIONS_MAX: usize = 10_000;
/// Largest `max_connections`.
pub const MAX_CONNECTIONS_MAX: usize = 65_536;

fn default_listen() -> String {
    "127.0.0.1:8787".into()
}
fn default_min_iou() -> f64 {
    0.9
}
fn default_max_boundary_px() -> f64 {
    1.5
}
fn default_max_mask_offset_px() -> f64 {
    2.0
}
/// Largest `bump_max_mask_offset_px`: past a few pixels a uniform offset is no segmenter's
/// habit.
pub const BUMP_MAX_MASK_OFFSET_MAX_PX: f64 = 8.0;
fn yes() -> bool {
    true
}

impl Default for DaemonSettings {
    fn default() -> Self {
        toml::from_str("").expect("every field has a default")
    }
}

impl DaemonSettings {
    /// `header_read_timeout_s`, or its default.
    pub fn header_read_timeout(&self) -> Duration {
        Duration::from_secs_f64(self.header_read_timeout_s.unwrap_or(HEADER_READ_TIMEOUT_S))
    }

    /// `idle_timeout_s`, or its default.
    pub fn idle_timeout(&self) -> Duration {
        Duration::from_secs_f64(self.idle_timeout_s.unwrap_or(IDLE_TIMEOUT_S))
    }

    /// `keep_calibrations`, or its default.
    pub fn keep_calibrations(&self) -> usize {
        self.keep_calibrations.unwrap_or(KEEP_CALIBRATIONS)
    }

    /// `max_connections`, or its default.
    pub fn max_connections(&self) -> usize {
        self.max_connections.unwrap_or(MAX_CONNECTIONS)
    }

    /// Checks the HTTP server's limits, naming the key at fault.
    fn validate_http(&self, path: &Path) -> Result<()> {
        let bad = |f: &str, m: String| Err(Error::input(path, format!("daemon.{f}"), m));
        if let Some(s) = self.header_read_timeout_s {
            if !(s.is_finite() && (1.0..=HEADER_READ_TIMEOUT_MAX_S).contains(&s)) {
                return bad(
                    "header_read_timeout_s",
                    format!("{s}: use 1 to {HEADER_READ_TIMEOUT_MAX_S} seconds (default {HEADER_READ_TIMEOUT_S})"),
                );
            }
        }
        if let Some(s) = self.idle_timeout_s {
            if !(s.is_finite() && (IDLE_TIMEOUT_MIN_S..=IDLE_TIMEOUT_MAX_S).contains(&s)) {
                return bad(
                    "idle_timeout_s",
                    format!("{s}: use {IDLE_TIMEOUT_MIN_S} to {IDLE_TIMEOUT_MAX_S} seconds (default {IDLE_TIMEOUT_S})"),
                );
            }
        }
        if let Some(n) = self.keep_calibrations {
            if !(1..=KEEP_CALIBRATIONS_MAX).contains(&n) {
                return bad(
                    "keep_calibrations",
                    format!("{n}: use 1 to {KEEP_CALIBRATIONS_MAX} (default {KEEP_CALIBRATIONS})"),
                );
            }
        }
        if let Some(n) = self.max_connections {
            if !(1..=MAX_CONNECTIONS_MAX).contains(&n) {
                return bad(
                    "max_connections",
                    format!("{n}: use 1 to {MAX_CONNECTIONS_MAX} (default {MAX_CONNECTIONS})"),
                );
            }
        }
        Ok(())
    }

    /// Checks ranges, naming the key at fault; `joints` is the arm's joint count.
    pub fn validate(&self, path: &Path, joints: usize) -> Result<()> {
        let bad = |f: &str, m: String| Err(Error::input(path, format!("daemon.{f}"), m));
        if self.listen.trim().is_empty() {
            return bad(
                "listen",
                "is empty: use HOST:PORT, e.g. \"127.0.0.1:8787\"".into(),
            );
        }
        if let Some(t) = &self.token {
            if t.trim().is_empty() || t.chars().any(|c| c.is_whitespace() || c.is_control()) {
                return bad(
                    "token",
                    "must be non-empty without spaces (it is sent as `Authorization: Bearer TOKEN`)"
                        .into(),
                );
            }
        }
        if let Some(s) = self.check_interval_s {
            if !(s.is_finite() && (1.0..=MAX_CHECK_INTERVAL_S).contains(&s)) {
                return bad(
                    "check_interval_s",
                    format!("{s}: use 1 to {MAX_CHECK_INTERVAL_S} seconds (a year), or leave it out for on-demand checks"),
                );
            }
        }
        if !(self.bump_min_iou > 0.0 && self.bump_min_iou <= 1.0) {
            return bad(
                "bump_min_iou",
                format!("{}: use an IoU in (0, 1], e.g. 0.9", self.bump_min_iou),
            );
        }
        if !(self.bump_max_boundary_px.is_finite() && self.bump_max_boundary_px > 0.0) {
            return bad(
                "bump_max_boundary_px",
                format!(
                    "{}: use a positive number of pixels, e.g. 1.5",
                    self.bump_max_boundary_px
                ),
            );
        }
        let offset = self.bump_max_mask_offset_px;
        if !(0.0..=BUMP_MAX_MASK_OFFSET_MAX_PX).contains(&offset) {
            return bad(
                "bump_max_mask_offset_px",
                format!("{offset}: use 0 to {BUMP_MAX_MASK_OFFSET_MAX_PX} pixels, e.g. 2"),
            );
        }
        if let Some(q) = &self.check_pose {
            if q.len() != joints {
                return bad(
                    "check_pose",
                    format!("{} values for the {joints} actuated joints", q.len()),
                );
            }
            if q.iter().any(|v| !v.is_finite()) {
                return bad("check_pose", "every joint must be a finite number".into());
            }
        }
        self.validate_http(path)
    }
}

//! [`PiperArm`]: the AgileX Piper as an [`Arm`] over any [`CanBus`].
//!
//! The arm pushes feedback continuously; a background task (started at first use, ended
//! when the driver is dropped) keeps the latest joints, status and driver-enable bits, each
//! with a sequence number so that every answer is built from frames received *after* the
//! question was asked.
//!
//! Defence in depth: targets outside the limits are refused before a frame is sent, and the
//! speed percentage of MOVE J is the largest whole percentage whose speed stays within the
//! cap (`full_speed_rad_s` is what 100 % means). Completion: status byte 4 = "reached" and
//! every joint within tolerance, both from frames newer than the command. The targets are
//! re-sent while the move runs (the SDK demo streams them; repeating an unchanged target is
//! harmless). `stop` commands the present position at the same speed cap: the arm holds
//! where it is, with no emergency stop to reset.

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use async_trait::async_trait;
use tokio::sync::Notify;
use tokio::task::JoinHandle;
use tokio::time::Instant;

use super::bus::CanBus;
use super::frame::{
    decode_driver_enabled, decode_joint_pair, enable_frame, id, joint_target_frames,
    millideg_to_rad, motion_control_frame, rad_to_millideg, ModeCommand, StatusFrame,
};
use crate::{Arm, ArmStatus, DriverError, JointLimit, Motion, Result};

/// The SDK's joint limits (docs/protocols.md §4.3), radians. J2's upper limit is the SDK's
/// 3.14, not π.
#[allow(clippy::approx_constant)]
pub const PIPER_LIMITS_RAD: [(f64, f64); 6] = [
    (-2.6179, 2.6179),
    (0.0, 3.14),
    (-2.967, 0.0),
    (-1.745, 1.745),
    (-1.22, 1.22),
    (-2.09439, 2.09439),
];

/// Settings of a [`PiperArm`].
#[derive(Clone, Debug)]
pub struct PiperConfig {
    /// Joint names in the arm's order (must match the URDF).
    pub joint_names: Vec<String>,
    /// Joint limits the driver enforces, radians (default: the SDK's).
    pub limits: [(f64, f64); 6],
    /// Speed cap of the fastest joint, rad/s.
    pub speed_cap_rad_s: f64,
    /// Joint speed at 100 % on the 0x151 speed byte, rad/s. Not documented by AgileX; the
    /// default (π rad/s) is an assumption to measure on the real arm.
    pub full_speed_rad_s: f64,
    /// Motor number of the enable frame: 7, as the SDK's `EnableArm` (docs/protocols.md §4.2).
    pub enable_motor: u8,
    /// Limit for all six drivers to report enabled.
    pub enable_timeout: Duration,
    /// Limit for fresh feedback (joints or status) to arrive.
    pub feedback_timeout: Duration,
    /// Interval of completion checks while a move runs.
    pub poll_interval: Duration,
    /// Interval at which a running move's targets are sent again.
    pub resend_interval: Duration,
    /// Slack on top of 1.5x the expected motion time before a move is stopped as timed out.
    pub motion_timeout_margin: Duration,
    /// Largest joint error at which the arm counts as arrived, radians.
    pub arrival_tolerance_rad: f64,
}

impl Default for PiperConfig {
    fn default() -> PiperConfig {
        PiperConfig {
            joint_names: (1..=6).map(|i| format!("joint{i}")).collect(),
            limits: PIPER_LIMITS_RAD,
            speed_cap_rad_s: 1.0,
            full_speed_rad_s: std::f64::consts::PI,
            enable_motor: 7,
            enable_timeout: Duration::from_secs(5),
            feedback_timeout: Duration::from_millis(500),
            poll_interval: Duration::from_millis(10),
            resend_interval: Duration::from_millis(100),
            motion_timeout_margin: Duration::from_secs(10),
            arrival_tolerance_rad: 0.002,
        }
    }
}

/// The latest feedback, with sequence numbers.
#[derive(Default)]
struct Feedback {
    joints: [i32; 6],
    pair_seq: [u64; 3],
    status: StatusFrame,
    status_seq: u64,
    enabled: [bool; 6],
    enabled_seq: [u64; 6],
    link_error: Option<String>,
}

#[derive(Default)]
struct Shared {
    fb: Mutex<Feedback>,
    changed: Notify,
}

impl Shared {
    fn fb(&self) -> MutexGuard<'_, Feedback> {
        self.fb.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn apply(&self, f: &super::frame::CanFrame) {
        let mut fb = self.fb();
        if let Some((k, a, b)) = decode_joint_pair(id::JOINT_FEEDBACK_12, f) {
            fb.joints[k] = a;
            fb.joints[k + 1] = b;
            fb.pair_seq[k / 2] += 1;
        } else if let Some(s) = StatusFrame::decode(f) {
            fb.status = s;
            fb.status_seq += 1;
        } else if let Some((k, on)) = decode_driver_enabled(f) {
            fb.enabled[k] = on;
            fb.enabled_seq[k] += 1;
        } else {
            return;
        }
        drop(fb);
        self.changed.notify_waiters();
    }
}

struct Command {
    enabled: bool,
    stopped: bool,
    /// Bumped by `stop` and every new move: a watched move ends when it changes.
    epoch: u64,
}

struct Inner {
    cfg: PiperConfig,
    joints: Vec<JointLimit>,
    bus: Arc<dyn CanBus>,
    shared: Arc<Shared>,
    reader: Mutex<Option<JoinHandle<()>>>,
    cmd: tokio::sync::Mutex<Command>,
}

impl Drop for Inner {
    fn drop(&mut self) {
        if let Some(h) = self.reader.lock().unwrap_or_else(|p| p.into_inner()).take() {
            h.abort();
        }
    }
}

/// An AgileX Piper on a CAN bus. Cloning shares the bus and the feedback.
#[derive(Clone)]
pub struct PiperArm {
    inner: Arc<Inner>,
}

impl std::fmt::Debug for PiperArm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("PiperArm")
    }
}

fn config_error(msg: String) -> DriverError {
    DriverError::Backend(Box::new(super::PiperError::Config(msg)))
}

impl PiperArm {
    /// A driver on `bus`; nothing is sent or received before the first call.
    pub fn new(cfg: PiperConfig, bus: Arc<dyn CanBus>) -> Result<PiperArm> {
        if cfg.joint_names.len() != 6 {
            return Err(config_error(format!(
                "{} joint names for the Piper's 6 joints",
                cfg.joint_names.len()
            )));
        }
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !positive(cfg.speed_cap_rad_s) || !positive(cfg.full_speed_rad_s) {
            return Err(config_error(format!(
                "speed_cap_rad_s {} and full_speed_rad_s {} must be positive numbers",
                cfg.speed_cap_rad_s, cfg.full_speed_rad_s
            )));
        }
        if cfg.speed_cap_rad_s < cfg.full_speed_rad_s / 100.0 {
            return Err(config_error(format!(
                "speed_cap_rad_s {} is below 1 % of full_speed_rad_s {}: the controller cannot go that slowly",
                cfg.speed_cap_rad_s, cfg.full_speed_rad_s
            )));
        }
        for (k, &(lo, hi)) in cfg.limits.iter().enumerate() {
            if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                return Err(config_error(format!(
                    "joint {} limits [{lo}, {hi}]: lower must be below upper",
                    k + 1
                )));
            }
        }
        let cap = cfg.speed_cap_rad_s.min(cfg.full_speed_rad_s);
        let joints = cfg
            .joint_names
            .iter()
            .zip(&cfg.limits)
            .map(|(name, &(lower, upper))| JointLimit {
                name: name.clone(),
                lower,
                upper,
                max_velocity: cap,
            })
            .collect();
        Ok(PiperArm {
            inner: Arc::new(Inner {
                cfg,
                joints,
                bus,
                shared: Arc::default(),
                reader: Mutex::new(None),
                cmd: tokio::sync::Mutex::new(Command {
                    enabled: false,
                    stopped: false,
                    epoch: 0,
                }),
            }),
        })
    }

    /// The speed byte a move at `speed_rad_s` sends: the largest whole percentage whose
    /// speed stays within both the request and the cap (at least 1).
    pub fn speed_percent(&self, speed_rad_s: f64) -> u8 {
        let c = &self.inner.cfg;
        let v = speed_rad_s.min(c.speed_cap_rad_s);
        ((100.0 * v / c.full_speed_rad_s).floor()).clamp(1.0, 100.0) as u8
    }

    /// Enables the six drivers (repeating the enable frame until all report enabled).
    pub async fn enable(&self) -> Result<()> {
        let mut cmd = self.inner.cmd.lock().await;
        self.inner.enable(&mut cmd).await
    }
}

impl Inner {
    fn ensure_reader(&self) {
        let mut r = self.reader.lock().unwrap_or_else(|p| p.into_inner());
        if r.as_ref().is_some_and(|h| !h.is_finished()) {
            return;
        }
        let (bus, shared) = (self.bus.clone(), self.shared.clone());
        shared.fb().link_error = None;
        *r = Some(tokio::spawn(async move {
            loop {
                match bus.recv().await {
                    Ok(f) => shared.apply(&f),
                    Err(e) => {
                        shared.fb().link_error = Some(e.to_string());
                        shared.changed.notify_waiters();
                        return;
                    }
                }
            }
        }));
    }

    /// Waits until `f` returns something, or the feedback timeout passes.
    async fn wait_for<T>(
        &self,
        timeout: Duration,
        mut f: impl FnMut(&Feedback) -> Option<T>,
    ) -> Result<T> {
        self.ensure_reader();
        let deadline = Instant::now() + timeout;
        loop {
            let notified = self.shared.changed.notified();
            {
                let fb = self.shared.fb();
                if let Some(v) = f(&fb) {
                    return Ok(v);
                }
                if let Some(e) = &fb.link_error {
                    return Err(DriverError::Connection(e.clone()));
                }
            }
            if tokio::time::timeout_at(deadline, notified).await.is_err() {
                return Err(DriverError::Timeout(timeout));
            }
        }
    }

    /// Joints from three feedback frames all received after this call.
    async fn fresh_joints(&self) -> Result<[i32; 6]> {
        self.ensure_reader();
        let since = self.shared.fb().pair_seq;
        self.wait_for(self.cfg.feedback_timeout, |fb| {
            (0..3)
                .all(|k| fb.pair_seq[k] > since[k])
                .then_some(fb.joints)
        })
        .await
    }

    /// A status frame received after this call.
    async fn fresh_status(&self) -> Result<StatusFrame> {
        self.ensure_reader();
        let since = self.shared.fb().status_seq;
        self.wait_for(self.cfg.feedback_timeout, |fb| {
            (fb.status_seq > since).then_some(fb.status)
        })
        .await
    }

    async fn send_move(&self, millideg: &[i32; 6], pct: u8) -> Result<()> {
        self.bus.send(&ModeCommand::move_j(pct).encode()).await?;
        for f in joint_target_frames(millideg) {
            self.bus.send(&f).await?;
        }
        Ok(())
    }

    async fn enable(&self, cmd: &mut Command) -> Result<()> {
        self.ensure_reader();
        let deadline = Instant::now() + self.cfg.enable_timeout;
        let since = self.shared.fb().enabled_seq;
        loop {
            self.bus
                .send(&enable_frame(self.cfg.enable_motor, true))
                .await?;
            let wait = Duration::from_millis(100).min(self.cfg.enable_timeout);
            let all = self
                .wait_for(wait, |fb| {
                    (0..6)
                        .all(|k| fb.enabled_seq[k] > since[k] && fb.enabled[k])
                        .then_some(())
                })
                .await;
            match all {
                Ok(()) => break,
                Err(DriverError::Timeout(_)) if Instant::now() < deadline => continue,
                Err(DriverError::Timeout(_)) => {
                    let fb = self.shared.fb();
                    let off: Vec<String> = (0..6)
                        .filter(|&k| !(fb.enabled_seq[k] > since[k] && fb.enabled[k]))
                        .map(|k| format!("J{}", k + 1))
                        .collect();
                    return Err(DriverError::Refused(format!(
                        "drivers {} did not report enabled within {:?} of enabling",
                        off.join(", "),
                        self.cfg.enable_timeout
                    )));
                }
                Err(e) => return Err(e),
            }
        }
        cmd.enabled = true;
        Ok(())
    }

    async fn wait_arrival(
        self: Arc<Self>,
        target: [i32; 6],
        pct: u8,
        expected: Duration,
        epoch: u64,
        seq: (u64, [u64; 3]),
    ) -> Result<()> {
        let started = Instant::now();
        let deadline = started + expected.mul_f64(1.5) + self.cfg.motion_timeout_margin;
        let tolerance = rad_to_millideg(self.cfg.arrival_tolerance_rad)
            .unwrap_or(0)
            .max(1);
        let mut last_send = started;
        let mut last_feedback = (started, seq.0);
        loop {
            tokio::time::sleep(self.cfg.poll_interval).await;
            if self.cmd.lock().await.epoch != epoch {
                return Err(DriverError::MotionFailed(
                    "stopped (or superseded) before arriving".into(),
                ));
            }
            let (status, status_seq, joints, pairs, link) = {
                let fb = self.shared.fb();
                (
                    fb.status,
                    fb.status_seq,
                    fb.joints,
                    fb.pair_seq,
                    fb.link_error.clone(),
                )
            };
            if let Some(e) = link {
                return Err(DriverError::Connection(e));
            }
            let now = Instant::now();
            if status_seq != last_feedback.1 {
                last_feedback = (now, status_seq);
            } else if now - last_feedback.0 > self.cfg.feedback_timeout {
                return Err(DriverError::Timeout(self.cfg.feedback_timeout));
            }
            if status_seq > seq.0 {
                if let Some(fault) = status.fault() {
                    return Err(DriverError::MotionFailed(fault));
                }
                let fresh = (0..3).all(|k| pairs[k] > seq.1[k]);
                let near = joints
                    .iter()
                    .zip(&target)
                    .all(|(a, b)| (a - b).abs() <= tolerance);
                if status.motion_status == 0 && fresh && near {
                    return Ok(());
                }
            }
            if now >= deadline {
                let _ = self.hold(pct).await;
                return Err(DriverError::Timeout(started.elapsed()));
            }
            if now - last_send >= self.cfg.resend_interval {
                self.send_move(&target, pct).await?;
                last_send = now;
            }
        }
    }

    /// Commands the present position (the arm holds where it is).
    async fn hold(&self, pct: u8) -> Result<()> {
        let mut cmd = self.cmd.lock().await;
        cmd.epoch += 1;
        let here = self.fresh_joints().await?;
        self.send_move(&here, pct).await?;
        cmd.stopped = true;
        Ok(())
    }
}

#[async_trait]
impl Arm for PiperArm {
    fn joints(&self) -> &[JointLimit] {
        &self.inner.joints
    }

    async fn read_joints(&self) -> Result<Vec<f64>> {
        let q = self.inner.fresh_joints().await?;
        Ok(q.iter().map(|&v| millideg_to_rad(v)).collect())
    }

    async fn move_to(&self, target: &[f64], speed_rad_s: f64) -> Result<Motion> {
        let inner = &self.inner;
        if target.len() != 6 {
            return Err(DriverError::Refused(format!(
                "target has {} joints; the Piper has 6",
                target.len()
            )));
        }
        let mut millideg = [0i32; 6];
        for (k, (j, &v)) in inner.joints.iter().zip(target).enumerate() {
            match rad_to_millideg(v) {
                Some(m) if v >= j.lower && v <= j.upper => millideg[k] = m,
                _ => {
                    return Err(DriverError::Refused(format!(
                        "joint {} target {v} rad outside its limits [{}, {}]",
                        j.name, j.lower, j.upper
                    )))
                }
            }
        }
        if !(speed_rad_s.is_finite() && speed_rad_s > 0.0) {
            return Err(DriverError::Refused(format!(
                "speed {speed_rad_s} rad/s is not a positive number"
            )));
        }
        let pct = self.speed_percent(speed_rad_s);
        let sent = f64::from(pct) / 100.0 * inner.cfg.full_speed_rad_s;
        if sent > speed_rad_s * (1.0 + 1e-9) {
            // The least speed byte (1%) is faster than asked: the path was checked at the
            // slower speed, so refuse rather than move faster than checked.
            return Err(DriverError::Refused(format!(
                "speed {speed_rad_s} rad/s is below the controller's least step ({sent} rad/s, 1%)"
            )));
        }
        let mut cmd = inner.cmd.lock().await;
        let status = inner.fresh_status().await?;
        if let Some(fault) = status.fault() {
            return Err(DriverError::Refused(format!("{fault}; call clear_fault")));
        }
        if !cmd.enabled {
            inner.enable(&mut cmd).await?;
        }
        let from = inner.fresh_joints().await?;
        let seq = {
            let fb = inner.shared.fb();
            (fb.status_seq, fb.pair_seq)
        };
        inner.send_move(&millideg, pct).await?;
        cmd.epoch += 1;
        cmd.stopped = false;
        let epoch = cmd.epoch;
        drop(cmd);
        let dmax = from
            .iter()
            .zip(&millideg)
            .map(|(a, b)| millideg_to_rad(a - b).abs())
            .fold(0.0, f64::max);
        let speed = f64::from(pct) / 100.0 * inner.cfg.full_speed_rad_s;
        let expected = Duration::from_secs_f64(dmax / speed);
        Ok(Motion::new(
            inner
                .clone()
                .wait_arrival(millideg, pct, expected, epoch, seq),
        ))
    }

    async fn stop(&self) -> Result<()> {
        self.inner
            .hold(self.speed_percent(self.inner.cfg.speed_cap_rad_s))
            .await
    }

    async fn status(&self) -> Result<ArmStatus> {
        let s = self.inner.fresh_status().await?;
        if let Some(fault) = s.fault() {
            return Ok(ArmStatus::Fault(fault));
        }
        Ok(if s.motion_status != 0 {
            ArmStatus::Moving
        } else if self.inner.cmd.lock().await.stopped {
            ArmStatus::Stopped
        } else {
            ArmStatus::Idle
        })
    }

    /// Sends "resume/reset" (0x150 byte 0 = 2), waits for a status without fault, then
    /// enables the drivers again.
    async fn clear_fault(&self) -> Result<()> {
        let inner = &self.inner;
        let mut cmd = inner.cmd.lock().await;
        cmd.epoch += 1;
        inner.bus.send(&motion_control_frame(2)).await?;
        let since = inner.shared.fb().status_seq;
        let left = inner
            .wait_for(inner.cfg.enable_timeout, |fb| {
                (fb.status_seq > since && fb.status.fault().is_none()).then_some(())
            })
            .await;
        if let Err(DriverError::Timeout(_)) = left {
            let s = inner.shared.fb().status;
            return Err(DriverError::Refused(format!(
                "the arm still reports {} after resume",
                s.fault().unwrap_or_else(|| "no status".into())
            )));
        }
        left?;
        cmd.enabled = false;
        inner.enable(&mut cmd).await
    }
}

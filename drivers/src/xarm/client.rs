//! The xArm command client: one TCP connection to port 502, one request in flight at a time,
//! replies matched by transaction id.
//!
//! Defence in depth: the driver refuses targets outside the model's joint limits and clamps
//! speed and acceleration to its caps before a byte is sent, whatever the caller checked.
//! It connects lazily (building a cell never touches the network) and enables motion only
//! before the first move, so planning and `--dry-run` never arm the robot.
//!
//! Completion is detected by polling GET_STATE (docs/protocols.md §1.5, method A: it works on
//! every firmware), then confirmed by reading the joints back: a controller that goes idle
//! short of the target is a failed motion, not an arrival.

use std::sync::Arc;
use std::time::{Duration, Instant};

use async_trait::async_trait;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::sync::{Mutex, MutexGuard};

use super::codes::{describe_error, describe_state, describe_warning};
use super::frame::{
    encode_request, protocol, read_f32s_le, reg, FrameError, MoveJoint, RawFrame, Reply, Version,
};
use super::model::Model;
use crate::{Arm, ArmStatus, DriverError, JointLimit, Motion, Result};

/// The SDK's hard ceiling on joint speed, rad/s.
pub const MAX_SPEED_RAD_S: f64 = std::f64::consts::PI;
/// The SDK's hard ceiling on joint acceleration, rad/s².
pub const MAX_ACCEL_RAD_S2: f64 = 20.0;

/// Connection and motion settings of an [`XArm`].
#[derive(Clone, Debug)]
pub struct XArmConfig {
    /// `host:port` of the command channel (port 502 on a real controller).
    pub addr: String,
    /// The arm model: axis count and the joint limits the driver enforces.
    pub model: Model,
    /// Joint names in the arm's order (default `joint1`…); must match the URDF.
    pub joint_names: Option<Vec<String>>,
    /// Speed cap of the fastest joint, rad/s; faster requests are slowed to it (≤ π).
    pub speed_cap_rad_s: f64,
    /// Joint acceleration sent with every move, rad/s² (≤ 20).
    pub accel_rad_s2: f64,
    /// Limit for establishing the TCP connection.
    pub connect_timeout: Duration,
    /// Limit for one request/reply exchange (the SDK uses 2 s).
    pub reply_timeout: Duration,
    /// Limit for the motion-enable exchange, which the controller answers slowly.
    pub enable_timeout: Duration,
    /// Interval of GET_STATE polls while waiting for a motion.
    pub poll_interval: Duration,
    /// Slack on top of 1.5x the expected motion time before a motion times out (and is stopped).
    pub motion_timeout_margin: Duration,
    /// Largest joint error at which an idle arm counts as arrived, radians.
    pub arrival_tolerance_rad: f64,
}

impl XArmConfig {
    /// Settings with the defaults: 1 rad/s, 5 rad/s², the SDK's 2 s reply limit.
    pub fn new(addr: impl Into<String>, model: Model) -> XArmConfig {
        XArmConfig {
            addr: addr.into(),
            model,
            joint_names: None,
            speed_cap_rad_s: 1.0,
            accel_rad_s2: 5.0,
            connect_timeout: Duration::from_secs(3),
            reply_timeout: Duration::from_secs(2),
            enable_timeout: Duration::from_secs(8),
            poll_interval: Duration::from_millis(50),
            motion_timeout_margin: Duration::from_secs(10),
            arrival_tolerance_rad: 0.005,
        }
    }
}

/// Failures particular to the xArm backend (inside [`DriverError::Backend`]).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum XArmError {
    /// The controller reports an error code.
    #[error("{message}")]
    Controller {
        /// The controller's code (§1.8).
        code: u8,
        /// What it means.
        message: String,
    },
    /// A reply that does not follow the protocol.
    #[error("xArm protocol: {0}")]
    Protocol(String),
    /// The controller is a different arm than configured.
    #[error("{0}")]
    WrongModel(String),
    /// Unusable settings.
    #[error("xArm config: {0}")]
    Config(String),
}

fn backend(e: XArmError) -> DriverError {
    DriverError::Backend(Box::new(e))
}

/// The text of an error without its variant prefix, for wrapping in another message.
fn detail(e: &DriverError) -> String {
    match e {
        DriverError::Connection(s)
        | DriverError::Refused(s)
        | DriverError::MotionFailed(s)
        | DriverError::Stalled(s) => s.clone(),
        other => other.to_string(),
    }
}

struct Link {
    stream: Option<TcpStream>,
    buf: Vec<u8>,
    next_transaction: u16,
    /// Bumped at every new connection: a motion started on one connection fails when the
    /// connection it was watched on is gone.
    epoch: u64,
    /// Bring-up done once. Later connections do not repeat it: clearing errors is for the
    /// first move and for `clear_fault`, never a side effect of reconnecting.
    armed: bool,
    /// The arm is in state 4 because this driver stopped it (re-armed by the next move).
    stopped_by_us: bool,
    version: Option<Version>,
}

struct Inner {
    cfg: XArmConfig,
    joints: Vec<JointLimit>,
    limits: Vec<(f64, f64)>,
    speed_cap_rad_s: f64,
    accel_rad_s2: f64,
    link: Mutex<Link>,
}

/// A UFACTORY arm (xArm 5/6/7, Lite 6, UF850) on its private TCP protocol. Cloning shares
/// the connection.
#[derive(Clone)]
pub struct XArm {
    inner: Arc<Inner>,
}

impl std::fmt::Debug for XArm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "XArm({} at {})",
            self.inner.cfg.model, self.inner.cfg.addr
        )
    }
}

impl XArm {
    /// A driver for the controller at `cfg.addr`; connects on first use.
    pub fn new(cfg: XArmConfig) -> Result<XArm> {
        let n = cfg.model.axes();
        let names = match &cfg.joint_names {
            Some(names) if names.len() != n => {
                return Err(backend(XArmError::Config(format!(
                    "{} joint names for the {n} axes of an {}",
                    names.len(),
                    cfg.model
                ))))
            }
            Some(names) => names.clone(),
            None => (1..=n).map(|i| format!("joint{i}")).collect(),
        };
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !positive(cfg.speed_cap_rad_s) || !positive(cfg.accel_rad_s2) {
            return Err(backend(XArmError::Config(format!(
                "speed cap {} rad/s and acceleration {} rad/s² must be positive",
                cfg.speed_cap_rad_s, cfg.accel_rad_s2
            ))));
        }
        let speed_cap_rad_s = cfg.speed_cap_rad_s.min(MAX_SPEED_RAD_S);
        let accel_rad_s2 = cfg.accel_rad_s2.min(MAX_ACCEL_RAD_S2);
        let limits = cfg.model.joint_limits();
        let joints = names
            .into_iter()
            .zip(&limits)
            .map(|(name, &(lower, upper))| JointLimit {
                name,
                lower,
                upper,
                max_velocity: speed_cap_rad_s,
            })
            .collect();
        Ok(XArm {
            inner: Arc::new(Inner {
                cfg,
                joints,
                limits,
                speed_cap_rad_s,
                accel_rad_s2,
                link: Mutex::new(Link {
                    stream: None,
                    buf: Vec::new(),
                    next_transaction: 1,
                    epoch: 0,
                    armed: false,
                    stopped_by_us: false,
                    version: None,
                }),
            }),
        })
    }

    /// The configured model.
    pub fn model(&self) -> Model {
        self.inner.cfg.model
    }

    /// The effective speed cap (the configured one, at most π rad/s).
    pub fn speed_cap_rad_s(&self) -> f64 {
        self.inner.speed_cap_rad_s
    }

    /// Connects now (if not connected) and returns the controller's version.
    pub async fn connect(&self) -> Result<Version> {
        let mut link = self.inner.link.lock().await;
        self.inner.ensure_connected(&mut link).await?;
        link.version
            .clone()
            .ok_or_else(|| backend(XArmError::Protocol("no version after connecting".into())))
    }

    /// Clears errors and warnings, enables all servos, selects position mode and the ready
    /// state: what the first move does implicitly.
    pub async fn bring_up(&self) -> Result<()> {
        let mut link = self.inner.link.lock().await;
        self.inner.bring_up(&mut link).await
    }

    /// The controller's (error code, warning code).
    pub async fn error_codes(&self) -> Result<(u8, u8)> {
        let mut link = self.inner.link.lock().await;
        self.inner.error_codes(&mut link).await
    }

    /// The controller's state number (§1.4).
    pub async fn state(&self) -> Result<u8> {
        let mut link = self.inner.link.lock().await;
        self.inner.state(&mut link).await
    }
}

impl Inner {
    async fn lock(&self) -> MutexGuard<'_, Link> {
        self.link.lock().await
    }

    async fn ensure_connected(&self, link: &mut Link) -> Result<()> {
        if link.stream.is_some() {
            return Ok(());
        }
        let addr = &self.cfg.addr;
        let wait = self.cfg.connect_timeout;
        let stream = tokio::time::timeout(wait, TcpStream::connect(addr.as_str()))
            .await
            .map_err(|_| DriverError::Timeout(wait))?
            .map_err(|e| DriverError::Connection(format!("xArm at {addr}: {e}")))?;
        // Small frames, one in flight: do not let Nagle hold them back.
        let _ = stream.set_nodelay(true);
        link.stream = Some(stream);
        link.buf.clear();
        link.epoch += 1;
        let reply = self
            .exchange(link, reg::GET_VERSION, &[], self.cfg.reply_timeout)
            .await?;
        let version = match Version::parse(&reply.data) {
            Some(v) => v,
            None => {
                link.stream = None;
                return Err(backend(XArmError::Protocol(format!(
                    "unreadable version string {:?}",
                    String::from_utf8_lossy(&reply.data)
                ))));
            }
        };
        if usize::from(version.axes) != self.cfg.model.axes() {
            link.stream = None;
            return Err(backend(XArmError::WrongModel(format!(
                "the controller at {addr} drives a {}-axis arm ({}); the config says {}",
                version.axes, version.text, self.cfg.model
            ))));
        }
        link.version = Some(version);
        Ok(())
    }

    /// Sends one request on the current connection and waits for its reply. Any failure
    /// drops the connection (its byte stream can no longer be trusted).
    async fn exchange(
        &self,
        link: &mut Link,
        register: u8,
        params: &[u8],
        wait: Duration,
    ) -> Result<Reply> {
        let transaction = link.next_transaction;
        link.next_transaction = if transaction == u16::MAX {
            1
        } else {
            transaction + 1
        };
        let request = encode_request(transaction, protocol::PRIVATE, register, params);
        let addr = &self.cfg.addr;
        let Link { stream, buf, .. } = link;
        let Some(s) = stream.as_mut() else {
            return Err(DriverError::Connection(format!(
                "xArm at {addr}: not connected"
            )));
        };
        let result = tokio::time::timeout(wait, async {
            s.write_all(&request)
                .await
                .map_err(|e| DriverError::Connection(format!("xArm at {addr}: sending: {e}")))?;
            loop {
                match RawFrame::parse(buf) {
                    Ok((frame, used)) => {
                        buf.drain(..used);
                        // Motion feedback frames carry the move's transaction id: skip them,
                        // as every reply to an earlier, abandoned request.
                        if frame.transaction != transaction || frame.register() == reg::FEEDBACK {
                            continue;
                        }
                        if frame.register() != register {
                            return Err(backend(XArmError::Protocol(format!(
                                "reply for register {:#04x} to a request for {register:#04x}",
                                frame.register()
                            ))));
                        }
                        return Reply::from_frame(frame)
                            .map_err(|e| backend(XArmError::Protocol(e.to_string())));
                    }
                    Err(FrameError::Incomplete) => {
                        let mut chunk = [0u8; 1024];
                        let n = s
                            .read(&mut chunk)
                            .await
                            .map_err(|e| DriverError::Connection(format!("xArm at {addr}: {e}")))?;
                        if n == 0 {
                            return Err(DriverError::Connection(format!(
                                "xArm at {addr}: the controller closed the connection"
                            )));
                        }
                        buf.extend_from_slice(&chunk[..n]);
                    }
                    Err(FrameError::Invalid(why)) => {
                        return Err(backend(XArmError::Protocol(why)));
                    }
                }
            }
        })
        .await;
        let outcome = result.unwrap_or(Err(DriverError::Timeout(wait)));
        if outcome.is_err() {
            link.stream = None;
        }
        outcome
    }

    async fn call(&self, link: &mut Link, register: u8, params: &[u8]) -> Result<Reply> {
        self.ensure_connected(link).await?;
        self.exchange(link, register, params, self.cfg.reply_timeout)
            .await
    }

    async fn error_codes(&self, link: &mut Link) -> Result<(u8, u8)> {
        let r = self.call(link, reg::GET_ERROR, &[]).await?;
        match r.data.as_slice() {
            [e, w, ..] => Ok((*e, *w)),
            _ => Err(backend(XArmError::Protocol(
                "GET_ERROR reply without codes".into(),
            ))),
        }
    }

    async fn state(&self, link: &mut Link) -> Result<u8> {
        let r = self.call(link, reg::GET_STATE, &[]).await?;
        r.data.first().copied().ok_or_else(|| {
            backend(XArmError::Protocol(
                "GET_STATE reply without a state".into(),
            ))
        })
    }

    async fn controller_error(&self, link: &mut Link) -> Result<Option<(u8, String)>> {
        let (code, _) = self.error_codes(link).await?;
        Ok((code != 0).then(|| (code, describe_error(code))))
    }

    async fn bring_up(&self, link: &mut Link) -> Result<()> {
        self.call(link, reg::CLEAN_ERR, &[]).await?;
        self.call(link, reg::CLEAN_WAR, &[]).await?;
        self.ensure_connected(link).await?;
        self.exchange(link, reg::MOTION_EN, &[8, 1], self.cfg.enable_timeout)
            .await?;
        // The detection flag byte exists from firmware 1.10.0 on (0 = detection on).
        let new_mode_layout = link
            .version
            .as_ref()
            .is_some_and(|v| v.firmware >= (1, 10, 0));
        let mode: &[u8] = if new_mode_layout { &[0, 0] } else { &[0] };
        self.call(link, reg::SET_MODE, mode).await?;
        self.call(link, reg::SET_STATE, &[0]).await?;
        if let Some((code, message)) = self.controller_error(link).await? {
            return Err(backend(XArmError::Controller { code, message }));
        }
        let state = self.state(link).await?;
        if state == 4 || state == 5 {
            return Err(DriverError::Refused(format!(
                "the controller is still {} after enabling motion",
                describe_state(state)
            )));
        }
        link.armed = true;
        link.stopped_by_us = false;
        Ok(())
    }

    async fn read_joints(&self, link: &mut Link) -> Result<Vec<f64>> {
        let r = self.call(link, reg::GET_JOINT_POS, &[]).await?;
        let q = read_f32s_le(&r.data, 7).ok_or_else(|| {
            backend(XArmError::Protocol(format!(
                "joint reply of {} bytes; 28 expected",
                r.data.len()
            )))
        })?;
        Ok(q[..self.cfg.model.axes()]
            .iter()
            .map(|&v| f64::from(v))
            .collect())
    }

    /// Sends SET_STATE 4, reconnecting if needed.
    async fn send_stop(&self, link: &mut Link) -> Result<()> {
        self.call(link, reg::SET_STATE, &[4]).await?;
        link.stopped_by_us = true;
        Ok(())
    }

    /// After the link failed mid-move: try to stop the arm over a fresh connection and say
    /// whether that worked.
    async fn lost_mid_move(&self, link: &mut Link, cause: &DriverError) -> DriverError {
        link.stream = None;
        match self.send_stop(link).await {
            Ok(()) => DriverError::Connection(format!(
                "{}; link lost during the move, stop sent on a new connection",
                detail(cause)
            )),
            Err(e) => DriverError::Connection(format!(
                "{}; link lost during the move and the controller cannot be reached to stop the arm ({})",
                detail(cause),
                detail(&e)
            )),
        }
    }

    async fn wait_arrival(
        self: Arc<Self>,
        epoch: u64,
        target: Vec<f64>,
        expected: Duration,
        starts_at_target: bool,
    ) -> Result<()> {
        let started = Instant::now();
        let deadline = started + expected.mul_f64(1.5) + self.cfg.motion_timeout_margin;
        let (mut idle, mut resets, mut seen_moving) = (0u32, 0u32, false);
        loop {
            tokio::time::sleep(self.cfg.poll_interval).await;
            let mut link = self.lock().await;
            if link.epoch != epoch || link.stream.is_none() {
                let cause = DriverError::Connection(format!(
                    "xArm at {}: the connection the move was sent on is gone",
                    self.cfg.addr
                ));
                return Err(self.lost_mid_move(&mut link, &cause).await);
            }
            let reply = match self
                .exchange(&mut link, reg::GET_STATE, &[], self.cfg.reply_timeout)
                .await
            {
                Ok(r) => r,
                Err(e @ DriverError::Timeout(_)) => {
                    let _ = self.send_stop(&mut link).await;
                    return Err(e);
                }
                Err(e) => return Err(self.lost_mid_move(&mut link, &e).await),
            };
            if reply.has_error() {
                if let Some((_, message)) = self.controller_error(&mut link).await? {
                    return Err(DriverError::MotionFailed(message));
                }
            }
            let state = reply.data.first().copied().unwrap_or(0);
            match state {
                0 | 1 => {
                    seen_moving = true;
                    idle = 0;
                }
                2 => idle += 1,
                3 => {}
                5 if resets < 20 => resets += 1,
                other => {
                    return Err(DriverError::MotionFailed(format!(
                        "the controller reports state {other} ({}) before the arm arrived",
                        describe_state(other)
                    )))
                }
            }
            if (idle >= 2 && (seen_moving || starts_at_target)) || idle >= 10 {
                let q = self.read_joints(&mut link).await?;
                let (k, off) = q
                    .iter()
                    .zip(&target)
                    .map(|(a, b)| (a - b).abs())
                    .enumerate()
                    .fold(
                        (0, 0.0),
                        |best, (k, d)| if d > best.1 { (k, d) } else { best },
                    );
                if off <= self.cfg.arrival_tolerance_rad {
                    return Ok(());
                }
                return Err(DriverError::MotionFailed(format!(
                    "the controller went idle with joint {} {off:.4} rad from the target",
                    k + 1
                )));
            }
            if Instant::now() >= deadline {
                let _ = self.send_stop(&mut link).await;
                return Err(DriverError::Timeout(started.elapsed()));
            }
        }
    }
}

#[async_trait]
impl Arm for XArm {
    fn joints(&self) -> &[JointLimit] {
        &self.inner.joints
    }

    async fn read_joints(&self) -> Result<Vec<f64>> {
        let mut link = self.inner.lock().await;
        self.inner.read_joints(&mut link).await
    }

    async fn move_to(&self, target: &[f64], speed_rad_s: f64) -> Result<Motion> {
        let inner = &self.inner;
        let n = inner.limits.len();
        if target.len() != n {
            return Err(DriverError::Refused(format!(
                "target has {} joints; an {} has {n}",
                target.len(),
                inner.cfg.model
            )));
        }
        for (k, (v, (lo, hi))) in target.iter().zip(&inner.limits).enumerate() {
            if !v.is_finite() || v < lo || v > hi {
                return Err(DriverError::Refused(format!(
                    "joint {} target {v} rad outside the {}'s limits [{lo}, {hi}]",
                    k + 1,
                    inner.cfg.model
                )));
            }
        }
        if !(speed_rad_s.is_finite() && speed_rad_s > 0.0) {
            return Err(DriverError::Refused(format!(
                "speed {speed_rad_s} rad/s is not a positive number"
            )));
        }
        let speed = speed_rad_s.min(inner.speed_cap_rad_s);
        let mut link = inner.lock().await;
        inner.ensure_connected(&mut link).await?;
        if !link.armed {
            // Bringing the arm up clears errors; a fault already there is the caller's to
            // clear (`clear_fault`, which a cell allows only with clear_faults), not a move's.
            if let Some((_, message)) = inner.controller_error(&mut link).await? {
                return Err(DriverError::Refused(format!(
                    "{message} (reported before the first move: clear it at the pendant, or let easyhec clear faults)"
                )));
            }
            inner.bring_up(&mut link).await?;
        } else {
            if let Some((_, message)) = inner.controller_error(&mut link).await? {
                return Err(DriverError::Refused(message));
            }
            if link.stopped_by_us {
                // Our own stop left the arm in state 4: re-arm it (nothing else is wrong).
                inner.call(&mut link, reg::SET_STATE, &[0]).await?;
                link.stopped_by_us = false;
            }
        }
        let from = inner.read_joints(&mut link).await?;
        let request = MoveJoint::new(target, speed, inner.accel_rad_s2);
        let reply = inner
            .call(&mut link, reg::MOVE_JOINT, &request.encode())
            .await?;
        if reply.has_error() {
            if let Some((_, message)) = inner.controller_error(&mut link).await? {
                return Err(DriverError::Refused(message));
            }
        }
        if reply.not_ready() {
            let state = inner.state(&mut link).await?;
            return Err(DriverError::Refused(format!(
                "the controller is not ready to move (state {state}: {})",
                describe_state(state)
            )));
        }
        if reply.has_warning() {
            let (_, warning) = inner.error_codes(&mut link).await?;
            if (11..=14).contains(&warning) {
                return Err(DriverError::Refused(describe_warning(warning)));
            }
        }
        let epoch = link.epoch;
        drop(link);
        let distance = from
            .iter()
            .zip(target)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        let expected = Duration::from_secs_f64(distance / speed + speed / inner.accel_rad_s2);
        let starts_at_target = distance <= inner.cfg.arrival_tolerance_rad;
        let waiter = inner
            .clone()
            .wait_arrival(epoch, target.to_vec(), expected, starts_at_target);
        Ok(Motion::new(waiter))
    }

    async fn stop(&self) -> Result<()> {
        let mut link = self.inner.lock().await;
        self.inner.send_stop(&mut link).await
    }

    async fn status(&self) -> Result<ArmStatus> {
        let mut link = self.inner.lock().await;
        if let Some((_, message)) = self.inner.controller_error(&mut link).await? {
            return Ok(ArmStatus::Fault(message));
        }
        Ok(match self.inner.state(&mut link).await? {
            0 | 1 | 6 => ArmStatus::Moving,
            2 => ArmStatus::Idle,
            3..=5 => ArmStatus::Stopped,
            other => ArmStatus::Fault(format!("unknown controller state {other}")),
        })
    }

    async fn clear_fault(&self) -> Result<()> {
        let mut link = self.inner.lock().await;
        self.inner.bring_up(&mut link).await
    }
}

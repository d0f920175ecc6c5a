//! [`UrArm`]: the [`Arm`] role over ur_rtde's receive, control and dashboard interfaces.
//!
//! Defence in depth: targets outside the joint limits are refused and speed and acceleration
//! are clamped to the driver's caps before ur_rtde sees them, whatever the caller checked.
//! Before the first move the driver checks, through the dashboard, that the pendant is in
//! remote control and, through RTDE, that the arm is powered with brakes released and in a
//! normal (or reduced) safety mode; each failure is one sentence saying what to do. It
//! connects lazily and creates the control interface (which uploads and starts ur_rtde's
//! control script on the controller) only before the first move, so planning, `--dry-run`
//! and reading joints never start a program on the robot.
//!
//! Moves are ur_rtde's asynchronous moveJ, watched by polling the receive interface (joints,
//! speeds, modes) and the control script's progress register: a synchronous moveJ would block
//! the worker for the whole motion and leave no way to stop it. Every ur_rtde constructor is
//! preceded by a native probe of the controller's ports with a time limit, because ur_rtde
//! blocks forever on a peer that accepts and never answers. Every SDK call runs in a child
//! process (`worker`), so that ur_rtde crashing after a lost link kills only that process: the
//! driver reports it and stops the arm from a fresh one.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use async_trait::async_trait;
use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::TcpStream;

use super::model::{
    self, robot_mode_name, safety_mode_advice, DASHBOARD_PORT, ROBOT_MODE_RUNNING, RTDE_PORT,
    SAFETY_MODE_NORMAL, SAFETY_MODE_REDUCED, SCRIPT_PORT, UR5E_JOINT_NAMES, UR5E_LIMITS,
};
use super::proto::{Request, State};
use super::worker::Worker;
use crate::{Arm, ArmStatus, DriverError, JointLimit, Motion, Result};

/// The receive interface's recipe: what the driver reads.
const VARIABLES: [&str; 6] = [
    "actual_q",
    "actual_qd",
    "robot_mode",
    "safety_mode",
    "runtime_state",
    "timestamp",
];

/// Connection and motion settings of a [`UrArm`].
#[derive(Clone, Debug)]
pub struct UrConfig {
    /// The controller's address (ur_rtde always uses ports 30004, 29999 and 30003).
    pub host: String,
    /// Joint names in the arm's order (default the UR5e's); must match the URDF.
    pub joint_names: Option<Vec<String>>,
    /// Joint limits the driver enforces, rad (default the UR5e's).
    pub limits: Vec<(f64, f64)>,
    /// Speed cap of the fastest joint, rad/s; faster requests are slowed to it (≤ π).
    pub speed_cap_rad_s: f64,
    /// Joint acceleration of every move, rad/s² (≤ 40).
    pub accel_rad_s2: f64,
    /// Deceleration of `stop`, rad/s².
    pub stop_decel_rad_s2: f64,
    /// RTDE frequency of both interfaces, Hz.
    pub frequency_hz: f64,
    /// Limit for connecting (the control interface uploads a script and waits for it).
    pub connect_timeout: Duration,
    /// Limit for one ordinary SDK call.
    pub call_timeout: Duration,
    /// Interval of state polls while a move runs.
    pub poll_interval: Duration,
    /// Slack on top of 1.5x a move's expected time before it is stopped as stalled.
    pub motion_timeout_margin: Duration,
    /// Largest joint error at which a finished move counts as arrived, rad.
    pub arrival_tolerance_rad: f64,
}

impl UrConfig {
    /// Settings for a UR5e at `host` with the defaults: 1 rad/s, 1.4 rad/s² (ur_rtde's
    /// default), 125 Hz, 10 s to connect, 2 s per call.
    pub fn new(host: impl Into<String>) -> UrConfig {
        UrConfig {
            host: host.into(),
            joint_names: None,
            limits: UR5E_LIMITS.to_vec(),
            speed_cap_rad_s: 1.0,
            accel_rad_s2: 1.4,
            stop_decel_rad_s2: 4.0,
            frequency_hz: 125.0,
            connect_timeout: Duration::from_secs(10),
            call_timeout: Duration::from_secs(2),
            poll_interval: Duration::from_millis(20),
            motion_timeout_margin: Duration::from_secs(10),
            arrival_tolerance_rad: 1e-3,
        }
    }
}

/// Failures particular to the UR backend (inside [`DriverError::Backend`]).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum UrError {
    /// The `ur_rtde` Python package cannot be used.
    #[error("{0}")]
    Sdk(String),
    /// Unusable settings.
    #[error("UR config: {0}")]
    Config(String),
}

fn config_error(msg: String) -> DriverError {
    DriverError::Backend(Box::new(UrError::Config(msg)))
}

struct Inner {
    cfg: UrConfig,
    joints: Vec<JointLimit>,
    speed_cap_rad_s: f64,
    accel_rad_s2: f64,
    worker: Worker,
    /// Why the arm stands where it does, when a move of ours was cut short.
    interrupted: Mutex<Option<String>>,
    /// Serialises moves, stops and reconnects (the worker serialises SDK calls anyway).
    op: tokio::sync::Mutex<()>,
}

/// A Universal Robots arm through `ur_rtde`. Cloning shares the connection.
#[derive(Clone)]
pub struct UrArm {
    inner: Arc<Inner>,
}

impl std::fmt::Debug for UrArm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "UrArm({})", self.inner.cfg.host)
    }
}

/// Probes the controller's ports natively, within `limit`: ur_rtde's constructors block
/// forever on a peer that accepts and never answers, and would take the GIL with them.
async fn probe(host: &str, limit: Duration) -> Result<()> {
    let connect =
        |port: u16| async move {
            let addr = format!("{host}:{port}");
            match tokio::time::timeout(limit, TcpStream::connect(&addr)).await {
                Err(_) => Err(DriverError::Timeout(limit)),
                Ok(Err(e)) => {
                    Err(DriverError::Connection(format!(
                "UR controller at {addr}: {e} (is it on, on this network, and is {} enabled?)",
                if port == RTDE_PORT { "RTDE" } else { "this interface" }
            )))
                }
                Ok(Ok(s)) => Ok(s),
            }
        };
    // RTDE answers a protocol-version request.
    let mut rtde = connect(RTDE_PORT).await?;
    let exchange = async {
        rtde.write_all(&[0x00, 0x05, b'V', 0x00, 0x02]).await?;
        let mut reply = [0u8; 3];
        rtde.read_exact(&mut reply).await?;
        Ok::<_, std::io::Error>(reply)
    };
    match tokio::time::timeout(limit, exchange).await {
        Err(_) => return Err(DriverError::Timeout(limit)),
        Ok(Err(e)) => {
            return Err(DriverError::Connection(format!(
                "UR controller at {host}:{RTDE_PORT}: RTDE handshake: {e}"
            )))
        }
        Ok(Ok(r)) if r[2] != b'V' => {
            return Err(DriverError::Connection(format!(
                "{host}:{RTDE_PORT} does not speak RTDE (answered type {:#04x})",
                r[2]
            )))
        }
        Ok(Ok(_)) => {}
    }
    // The dashboard greets.
    let dash = connect(DASHBOARD_PORT).await?;
    let mut line = String::new();
    match tokio::time::timeout(limit, BufReader::new(dash).read_line(&mut line)).await {
        Err(_) => return Err(DriverError::Timeout(limit)),
        Ok(Err(e)) => {
            return Err(DriverError::Connection(format!(
                "UR dashboard at {host}:{DASHBOARD_PORT}: {e}"
            )))
        }
        Ok(Ok(_)) => {}
    }
    connect(SCRIPT_PORT).await?;
    Ok(())
}

impl UrArm {
    /// A driver for the controller at `cfg.host`; connects on first use.
    pub fn new(cfg: UrConfig) -> Result<UrArm> {
        let n = cfg.limits.len();
        if n != 6 {
            return Err(config_error(format!(
                "{n} joint limits: a UR arm has 6 joints"
            )));
        }
        let names = match &cfg.joint_names {
            Some(names) if names.len() != n => {
                return Err(config_error(format!(
                    "{} joint names for the 6 joints of a UR arm",
                    names.len()
                )))
            }
            Some(names) => names.clone(),
            None => UR5E_JOINT_NAMES.iter().map(|s| s.to_string()).collect(),
        };
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !positive(cfg.speed_cap_rad_s)
            || !positive(cfg.accel_rad_s2)
            || !positive(cfg.stop_decel_rad_s2)
        {
            return Err(config_error(format!(
                "speed cap {} rad/s, acceleration {} rad/s² and stop deceleration {} rad/s² must be positive",
                cfg.speed_cap_rad_s, cfg.accel_rad_s2, cfg.stop_decel_rad_s2
            )));
        }
        if !positive(cfg.frequency_hz) || cfg.frequency_hz > 500.0 {
            return Err(config_error(format!(
                "RTDE frequency {} Hz: use 1..=500",
                cfg.frequency_hz
            )));
        }
        if cfg.host.trim().is_empty() {
            return Err(config_error(
                "empty host: give the controller's address".into(),
            ));
        }
        let speed_cap_rad_s = cfg.speed_cap_rad_s.min(model::UR5E_MAX_SPEED_RAD_S);
        let accel_rad_s2 = cfg.accel_rad_s2.min(model::MAX_ACCEL_RAD_S2);
        let joints = names
            .into_iter()
            .zip(&cfg.limits)
            .map(|(name, &(lower, upper))| JointLimit {
                name,
                lower,
                upper,
                max_velocity: speed_cap_rad_s,
            })
            .collect();
        let worker = Worker::spawn(format!("ur_rtde {}", cfg.host))?;
        Ok(UrArm {
            inner: Arc::new(Inner {
                cfg,
                joints,
                speed_cap_rad_s,
                accel_rad_s2,
                worker,
                interrupted: Mutex::new(None),
                op: tokio::sync::Mutex::new(()),
            }),
        })
    }

    /// The speed cap actually applied, rad/s.
    pub fn speed_cap_rad_s(&self) -> f64 {
        self.inner.speed_cap_rad_s
    }

    /// The acceleration sent with every move, rad/s².
    pub fn accel_rad_s2(&self) -> f64 {
        self.inner.accel_rad_s2
    }
}

impl Inner {
    fn set_interrupted(&self, why: Option<String>) {
        *self.interrupted.lock().unwrap_or_else(|e| e.into_inner()) = why;
    }

    fn interrupted(&self) -> Option<String> {
        self.interrupted
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// Connects the receive interface if needed. A process whose receive link broke while it
    /// holds a control interface is replaced first: that interface is reconnecting on its own
    /// threads, and ur_rtde can crash when a new interface is created next to it.
    async fn ensure_receive(&self) -> Result<()> {
        let connected: bool = self
            .worker
            .call(
                "isConnected",
                self.cfg.call_timeout,
                Request::ReceiveConnected,
            )
            .await?;
        if connected {
            return Ok(());
        }
        if self.control_connected().await?.is_some() {
            self.fresh_worker().await?;
        }
        probe(&self.cfg.host, self.cfg.call_timeout).await?;
        self.worker
            .call(
                "RTDEReceiveInterface",
                self.cfg.connect_timeout,
                Request::ConnectReceive {
                    host: self.cfg.host.clone(),
                    frequency_hz: self.cfg.frequency_hz,
                    variables: VARIABLES.iter().map(|v| v.to_string()).collect(),
                },
            )
            .await
    }

    /// Whether the control interface is connected (`None`: there is none).
    async fn control_connected(&self) -> Result<Option<bool>> {
        self.worker
            .call(
                "isConnected",
                self.cfg.call_timeout,
                Request::ControlConnected,
            )
            .await
    }

    /// Replaces the worker process: whatever ur_rtde interfaces it held (a broken control
    /// interface whose background threads may still be reconnecting, or crash) die with it.
    /// The next call starts a fresh process, and every interface is reconnected when needed.
    async fn fresh_worker(&self) -> Result<()> {
        self.worker.restart(self.cfg.call_timeout).await
    }

    /// Reconnects whichever RTDE interface lost its link, probing first so a silent
    /// controller cannot hang ur_rtde. A control interface that lost its link is never
    /// reconnected in place (ur_rtde's own reconnection races with it): its process is
    /// replaced, and the next move creates a new one.
    async fn ensure_links(&self) -> Result<()> {
        self.ensure_receive().await?;
        if self.control_connected().await? == Some(false) {
            self.fresh_worker().await?;
            self.ensure_receive().await?;
        }
        Ok(())
    }

    /// Asks the dashboard whether the pendant is in remote control.
    async fn remote_control(&self) -> Result<bool> {
        probe(&self.cfg.host, self.cfg.call_timeout).await?;
        self.worker
            .call(
                "DashboardClient",
                self.cfg.call_timeout,
                Request::IsInRemoteControl {
                    host: self.cfg.host.clone(),
                },
            )
            .await
    }

    async fn state(&self) -> Result<State> {
        self.worker
            .call("read state", self.cfg.call_timeout, Request::ReadState)
            .await
    }

    async fn program_running(&self) -> Result<bool> {
        self.worker
            .call(
                "isProgramRunning",
                self.cfg.call_timeout,
                Request::IsProgramRunning,
            )
            .await
    }

    /// Everything a move needs: receive and control interfaces, remote control, power,
    /// brakes, safety mode, and ur_rtde's script running.
    async fn ensure_ready(&self) -> Result<()> {
        if self.control_connected().await? == Some(false) {
            // Lost earlier: its process goes, with its background reconnection threads, so
            // that a new interface does not fight it over the controller's input registers.
            self.fresh_worker().await?;
        }
        self.ensure_receive().await?;
        let st = self.state().await?;
        if st.safety_mode != SAFETY_MODE_NORMAL && st.safety_mode != SAFETY_MODE_REDUCED {
            return Err(DriverError::Refused(safety_mode_advice(st.safety_mode)));
        }
        if st.robot_mode != ROBOT_MODE_RUNNING {
            return Err(DriverError::Refused(format!(
                "robot mode {}: power the arm on and release the brakes (pendant, or dashboard `power on` / `brake release`)",
                robot_mode_name(st.robot_mode)
            )));
        }
        if !self.remote_control().await? {
            return Err(DriverError::Refused(
                "the controller is in local control: switch the pendant to Remote Control".into(),
            ));
        }
        if self.control_connected().await? != Some(true) {
            probe(&self.cfg.host, self.cfg.call_timeout).await?;
            self.worker
                .call::<()>(
                    "RTDEControlInterface",
                    self.cfg.connect_timeout,
                    Request::ConnectControl {
                        host: self.cfg.host.clone(),
                        frequency_hz: self.cfg.frequency_hz,
                    },
                )
                .await?;
        } else if !self.program_running().await? {
            // A protective stop or a dashboard `stop` ended ur_rtde's script.
            self.worker
                .call::<()>(
                    "reuploadScript",
                    self.cfg.connect_timeout,
                    Request::ReuploadScript,
                )
                .await?;
            // ur_rtde returns before its own state shows the script running, and its
            // next command would be turned down until it does.
            let deadline = Instant::now() + self.cfg.connect_timeout;
            loop {
                if self.program_running().await? {
                    break;
                }
                if Instant::now() > deadline {
                    return Err(DriverError::Refused(
                        "ur_rtde's control script did not start after a re-upload: check the pendant for a popup or a stopped program".into(),
                    ));
                }
                tokio::time::sleep(self.cfg.poll_interval).await;
            }
        }
        Ok(())
    }

    /// stopJ through the control interface; if its link is gone (or its process died), the
    /// dashboard's `stop` (which ends the program, halting the arm) from a fresh worker
    /// process over a new connection.
    async fn send_stop(&self) -> Result<()> {
        let stopped = self
            .worker
            .call::<bool>(
                "stopJ",
                self.cfg.call_timeout,
                Request::StopJ {
                    decel: self.cfg.stop_decel_rad_s2,
                },
            )
            .await;
        if matches!(stopped, Ok(true)) {
            return Ok(());
        }
        self.dashboard_stop().await
    }

    /// The dashboard's `stop` from a fresh worker process over new connections: the process
    /// holding a broken control interface (whose background reconnection can crash it, or
    /// reconnect to a controller that no longer runs its script) is replaced first.
    async fn dashboard_stop(&self) -> Result<()> {
        self.fresh_worker().await?;
        probe(&self.cfg.host, self.cfg.call_timeout).await?;
        self.worker
            .call(
                "dashboard stop",
                self.cfg.call_timeout,
                Request::DashboardStop {
                    host: self.cfg.host.clone(),
                },
            )
            .await
    }

    /// Waits for a started move to end at `target`.
    async fn wait_arrival(&self, target: Vec<f64>, expected: Duration) -> Result<()> {
        let deadline = Instant::now() + expected.mul_f64(1.5) + self.cfg.motion_timeout_margin;
        let tol = self.cfg.arrival_tolerance_rad;
        // ur_rtde's state can trail the command by a package or two: a move counts as
        // finished only once the script has said so twice in a row with the arm at rest.
        let mut finished_polls = 0;
        loop {
            tokio::time::sleep(self.cfg.poll_interval).await;
            let st = match self.state().await {
                Ok(st) if st.connected => st,
                Ok(_) => return Err(self.lost_mid_move("RTDE connection closed").await),
                Err(e) => return Err(self.lost_mid_move(&e.to_string()).await),
            };
            if st.safety_mode != SAFETY_MODE_NORMAL && st.safety_mode != SAFETY_MODE_REDUCED {
                self.set_interrupted(Some(safety_mode_advice(st.safety_mode)));
                return Err(DriverError::MotionFailed(safety_mode_advice(
                    st.safety_mode,
                )));
            }
            if st.runtime_state != model::RUNTIME_PLAYING {
                let why = "the controller ended ur_rtde's control script mid-move (program stopped or paused)".to_string();
                self.set_interrupted(Some(why.clone()));
                return Err(DriverError::MotionFailed(why));
            }
            let err =
                st.q.iter()
                    .zip(&target)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max);
            let at_rest = st.qd.iter().all(|v| v.abs() < 1e-6);
            if !st.async_running && at_rest {
                finished_polls += 1;
                if err <= tol && finished_polls >= 2 {
                    return Ok(());
                }
                if finished_polls >= 3 {
                    let why =
                        format!("the controller ended the move {err:.4} rad short of the target");
                    self.set_interrupted(Some(why.clone()));
                    return Err(DriverError::MotionFailed(why));
                }
            } else {
                finished_polls = 0;
            }
            if Instant::now() > deadline {
                let _ = self.send_stop().await;
                let why = format!(
                    "no arrival within {:.1} s; stopped {err:.4} rad from the target",
                    (expected.mul_f64(1.5) + self.cfg.motion_timeout_margin).as_secs_f64()
                );
                self.set_interrupted(Some(why.clone()));
                return Err(DriverError::Stalled(why));
            }
        }
    }

    /// The link dropped during a move: stop the arm through the dashboard, from a fresh
    /// worker process, and say so.
    async fn lost_mid_move(&self, cause: &str) -> DriverError {
        let stop = self.dashboard_stop().await;
        let outcome = match &stop {
            Ok(()) => "arm stopped through the dashboard".to_string(),
            Err(e) => format!("could not stop the arm: {e}"),
        };
        let why = format!("link lost mid-move ({cause}); {outcome}");
        self.set_interrupted(Some(why.clone()));
        DriverError::Connection(why)
    }
}

#[async_trait]
impl Arm for UrArm {
    fn joints(&self) -> &[JointLimit] {
        &self.inner.joints
    }

    async fn read_joints(&self) -> Result<Vec<f64>> {
        self.inner.ensure_links().await?;
        let st = self.inner.state().await?;
        if !st.connected {
            return Err(DriverError::Connection(format!(
                "RTDE link to {} lost",
                self.inner.cfg.host
            )));
        }
        Ok(st.q)
    }

    async fn move_to(&self, target: &[f64], speed_rad_s: f64) -> Result<Motion> {
        let inner = &self.inner;
        if target.len() != 6 {
            return Err(DriverError::Refused(format!(
                "{} target joints for the 6 joints of a UR arm",
                target.len()
            )));
        }
        for (k, (v, (lo, hi))) in target.iter().zip(&inner.cfg.limits).enumerate() {
            if !v.is_finite() || v < lo || v > hi {
                return Err(DriverError::Refused(format!(
                    "joint {} ({}) target {v} rad outside its limits [{lo}, {hi}]",
                    k + 1,
                    inner.joints[k].name
                )));
            }
        }
        if !(speed_rad_s.is_finite() && speed_rad_s > 0.0) {
            return Err(DriverError::Refused(format!(
                "speed {speed_rad_s} rad/s: must be positive"
            )));
        }
        let speed = speed_rad_s.min(inner.speed_cap_rad_s);
        let accel = inner.accel_rad_s2;
        let _op = inner.op.lock().await;
        inner.ensure_ready().await?;
        let from = inner.state().await?.q;
        let q = target.to_vec();
        let accepted: bool = inner
            .worker
            .call(
                "moveJ",
                inner.cfg.call_timeout,
                Request::MoveJ {
                    q: q.clone(),
                    speed,
                    accel,
                    asynchronous: true,
                },
            )
            .await?;
        if !accepted {
            let st = inner.state().await?;
            let why =
                if st.safety_mode != SAFETY_MODE_NORMAL && st.safety_mode != SAFETY_MODE_REDUCED {
                    safety_mode_advice(st.safety_mode)
                } else {
                    format!(
                        "the controller did not accept the moveJ (robot mode {}, runtime state {})",
                        robot_mode_name(st.robot_mode),
                        st.runtime_state
                    )
                };
            return Err(DriverError::Refused(why));
        }
        inner.set_interrupted(None);
        let distance = from
            .iter()
            .zip(&q)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        let expected = Duration::from_secs_f64(distance / speed + 2.0 * speed / accel);
        let me = self.clone();
        Ok(Motion::new(async move {
            let _op = me.inner.op.lock().await;
            me.inner.wait_arrival(q, expected).await
        }))
    }

    async fn stop(&self) -> Result<()> {
        // Not behind `op`: a stop must not wait for a move's watcher.
        self.inner.send_stop().await?;
        if self.inner.interrupted().is_none() {
            let st = self.inner.state().await.ok();
            if st.is_some_and(|st| st.async_running) {
                self.inner
                    .set_interrupted(Some("stopped by request".into()));
            }
        }
        Ok(())
    }

    async fn status(&self) -> Result<ArmStatus> {
        self.inner.ensure_links().await?;
        let st = self.inner.state().await?;
        if !st.connected {
            return Err(DriverError::Connection(format!(
                "RTDE link to {} lost",
                self.inner.cfg.host
            )));
        }
        if st.safety_mode != SAFETY_MODE_NORMAL && st.safety_mode != SAFETY_MODE_REDUCED {
            return Ok(ArmStatus::Fault(safety_mode_advice(st.safety_mode)));
        }
        if st.robot_mode != ROBOT_MODE_RUNNING {
            return Ok(ArmStatus::Fault(format!(
                "robot mode {}",
                robot_mode_name(st.robot_mode)
            )));
        }
        if st.async_running || st.qd.iter().any(|v| v.abs() > 1e-6) {
            return Ok(ArmStatus::Moving);
        }
        if self.inner.interrupted().is_some() {
            return Ok(ArmStatus::Stopped);
        }
        Ok(ArmStatus::Idle)
    }

    async fn clear_fault(&self) -> Result<()> {
        let inner = &self.inner;
        probe(&inner.cfg.host, inner.cfg.call_timeout).await?;
        inner
            .worker
            .call::<()>(
                "dashboard",
                inner.cfg.call_timeout,
                Request::ClearFault {
                    host: inner.cfg.host.clone(),
                },
            )
            .await?;
        inner.ensure_links().await?;
        // The RTDE stream shows the new mode a package or two later.
        let deadline = Instant::now() + inner.cfg.call_timeout;
        loop {
            let st = inner.state().await?;
            if st.safety_mode == SAFETY_MODE_NORMAL || st.safety_mode == SAFETY_MODE_REDUCED {
                break;
            }
            if Instant::now() > deadline {
                return Err(DriverError::Refused(safety_mode_advice(st.safety_mode)));
            }
            tokio::time::sleep(inner.cfg.poll_interval).await;
        }
        inner.set_interrupted(None);
        Ok(())
    }
}

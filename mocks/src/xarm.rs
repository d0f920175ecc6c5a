//! A mock UFACTORY controller on loopback, speaking the private protocol byte for byte
//! (docs/protocols.md §1.10), so the real driver and the vendor's own SDK can be tested without
//! an arm.
//!
//! It listens on a command port (502 on a real controller) and on report ports (30001
//! "normal" at 5 Hz, 30002 "rich" at 5 Hz, 30003 "real" at 100 Hz); port 0 picks a free one.
//! The rich port matters because it is the vendor SDK's default (`XArmAPI(ip)` reads 30002):
//! the SDK starts no move before a report has shown it a ready arm, so without the port its
//! client reads, `set_servo_angle(wait=True)` blocks for ever. The SDK cannot be given ports;
//! [`MockXArmConfig::standard_ports_on_private_loopback`] serves the real ones on a loopback
//! address of the mock's own, where they collide with nothing.
//!
//! It answers protocol ids 2 and 3 (echoing the id), ignores heartbeats (id 1) and answers
//! Modbus (id 0) with "illegal function". Joint moves run linearly in joint space at the
//! commanded speed (the fastest joint at that speed, no acceleration ramps), `speedup` times
//! faster than the wall clock. Every move is recorded with what was on the wire and whether it
//! was accepted; targets outside the model's limits are refused with error C23, speeds or
//! accelerations above the caps with C24, so tests can prove no unsafe command reached "the
//! arm".
//!
//! It announces firmware 1.12.10 by default: below 2.0.102 the SDK waits for motions by
//! polling the state rather than asking for 0xFF feedback frames, which this mock does not
//! send. Behaviour no document pins down is this mock's choice: a new move replaces a running
//! one (no command queue); a lost client does not stop the arm unless `halt_on_disconnect`.

mod controller;
mod rich;

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use async_trait::async_trait;
use easyhec_drivers::xarm::frame::{protocol, RawFrame, Reply};
use easyhec_drivers::xarm::{read_report_from, Model};
use easyhec_drivers::Result as DriverResult;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

use crate::links::{closed, tick_until_shutdown, Links};
use crate::JointSource;
use controller::{Controller, ReportKind};

/// Where and how the mock controller runs.
#[derive(Clone, Debug)]
pub struct MockXArmConfig {
    /// Address to listen on (loopback by default).
    pub host: IpAddr,
    /// Replace `host` at spawn with a fresh 127.x.y.z, retrying while the ports are taken
    /// there: for the standard ports, which clients like the vendor SDK cannot change.
    pub private_loopback: bool,
    /// Command port (502 on a real controller; 0: a free port).
    pub command_port: u16,
    /// The 5 Hz "normal" report port (30001; 0: free; `None`: not served).
    pub normal_report_port: Option<u16>,
    /// The 5 Hz "rich" report port (30002; 0: free; `None`: not served), the one the vendor
    /// SDK reads unless told otherwise.
    pub rich_report_port: Option<u16>,
    /// The 100 Hz "real" report port (30003; 0: free; `None`: not served).
    pub real_report_port: Option<u16>,
    /// The arm model: axes, device type, joint limits.
    pub model: Model,
    /// Joints at start (default all 0).
    pub start: Option<Vec<f64>>,
    /// Firmware version announced, `major.minor.patch`.
    pub firmware: String,
    /// Moves faster than this (fastest joint, rad/s) are refused with C24.
    pub speed_cap_rad_s: f64,
    /// Moves with a larger acceleration (rad/s²) are refused with C24.
    pub accel_cap_rad_s2: f64,
    /// Simulated seconds per wall-clock second.
    pub speedup: f64,
    /// Injected faults.
    pub faults: Vec<MockFault>,
    /// Stop the arm when the link is dropped (see [`MockFault::DropMidMove`]).
    pub halt_on_disconnect: bool,
}

impl MockXArmConfig {
    /// On 127.0.0.1 with the ports of a real controller (502, 30001, 30002, 30003).
    pub fn standard_ports(model: Model) -> MockXArmConfig {
        MockXArmConfig {
            host: IpAddr::V4(Ipv4Addr::LOCALHOST),
            private_loopback: false,
            command_port: 502,
            normal_report_port: Some(30001),
            rich_report_port: Some(30002),
            real_report_port: Some(30003),
            model,
            start: None,
            firmware: "1.12.10".into(),
            speed_cap_rad_s: std::f64::consts::PI,
            accel_cap_rad_s2: 20.0,
            speedup: 1.0,
            faults: Vec::new(),
            halt_on_disconnect: false,
        }
    }

    /// On 127.0.0.1 with free ports for everything (for tests running in parallel).
    pub fn free_ports(model: Model) -> MockXArmConfig {
        MockXArmConfig {
            command_port: 0,
            normal_report_port: Some(0),
            rich_report_port: Some(0),
            real_report_port: Some(0),
            ..MockXArmConfig::standard_ports(model)
        }
    }

    /// The ports of a real controller on a loopback address no one else uses (127.x.y.z,
    /// picked at spawn; read it from [`MockXArm::command_addr`]): for the vendor SDK's default
    /// constructor, which cannot be given ports, in tests running beside others that hold
    /// them on 127.0.0.1. Port 502 still needs root (or a lowered
    /// `net.ipv4.ip_unprivileged_port_start`).
    pub fn standard_ports_on_private_loopback(model: Model) -> MockXArmConfig {
        MockXArmConfig {
            private_loopback: true,
            ..MockXArmConfig::standard_ports(model)
        }
    }
}

/// A fault to inject, on a given move (0-based count of joint-move commands received).
#[derive(Clone, Debug, PartialEq)]
pub enum MockFault {
    /// The controller raises error `code` after `at_fraction` of the path and stops there.
    ErrorMidMove {
        /// Which move.
        on_move: usize,
        /// Fraction of the path covered, 0..1.
        at_fraction: f64,
        /// Controller error code (e.g. 31, collision).
        code: u8,
    },
    /// Every connection is closed after `at_fraction` of the path; the arm keeps going
    /// unless `halt_on_disconnect`. With `refuse_reconnect` the listeners close too (a
    /// cut cable rather than a restarted client link).
    DropMidMove {
        /// Which move.
        on_move: usize,
        /// Fraction of the path covered, 0..1.
        at_fraction: f64,
        /// Stop accepting connections afterwards.
        refuse_reconnect: bool,
    },
    /// The arm stops progressing at `at_fraction` but keeps reporting "in motion".
    Stall {
        /// Which move.
        on_move: usize,
        /// Fraction of the path covered, 0..1.
        at_fraction: f64,
    },
    /// Requests for `register` are never answered.
    NoReply {
        /// The register ignored.
        register: u8,
    },
}

/// One joint-move command as the mock received it.
#[derive(Clone, Debug, PartialEq)]
pub struct MoveRecord {
    /// 0-based count of joint-move commands.
    pub index: usize,
    /// MOVE_JOINT (0x17) or MOVE_JOINTB (0x18).
    pub register: u8,
    /// True joints when it arrived.
    pub from: Vec<f64>,
    /// Target of the arm's axes, radians, as decoded from the wire (empty if malformed).
    pub target: Vec<f64>,
    /// The slots beyond the arm's axes (must be 0).
    pub unused_slots: Vec<f32>,
    /// Commanded speed, rad/s.
    pub speed_rad_s: f64,
    /// Commanded acceleration, rad/s².
    pub accel_rad_s2: f64,
    /// Whether the controller started it.
    pub accepted: bool,
    /// `None` while moving; "arrived", or how it was refused or ended.
    pub outcome: Option<String>,
}

/// One private-protocol request as received.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RequestRecord {
    /// Which command connection (1 = the first accepted).
    pub connection: u64,
    /// Transaction id.
    pub transaction: u16,
    /// Protocol id (2 or 3).
    pub protocol: u16,
    /// Register.
    pub register: u8,
    /// Parameter bytes.
    pub params: Vec<u8>,
}

struct Shared {
    ctl: Mutex<Controller>,
    links: Links,
    connections: Mutex<u64>,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Controller> {
        // The controller state stays consistent between statements; a panicked holder
        // (only possible in a test) leaves it usable.
        self.ctl.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Runs `f` on the controller brought up to now, then fires any drop a fault asked for.
    fn with<R>(&self, f: impl FnOnce(&mut Controller) -> R) -> R {
        let (out, drop_now) = {
            let mut c = self.lock();
            c.advance();
            let out = f(&mut c);
            c.advance();
            (out, c.drop_now.take())
        };
        if let Some(refuse) = drop_now {
            self.links.drop_all(refuse);
        }
        out
    }
}

/// A running mock controller. Dropping it shuts it down.
pub struct MockXArm {
    shared: Arc<Shared>,
    command_addr: SocketAddr,
    normal_report_addr: Option<SocketAddr>,
    rich_report_addr: Option<SocketAddr>,
    real_report_addr: Option<SocketAddr>,
}

#[derive(Clone, Copy)]
enum Port {
    Command,
    Report { period: Duration, kind: ReportKind },
}

/// The listeners of one mock: command port, then the normal, rich and real report ports.
type Listeners = (
    TcpListener,
    Option<TcpListener>,
    Option<TcpListener>,
    Option<TcpListener>,
);

/// Binds every port of `cfg` on `cfg.host`.
async fn bind_all(cfg: &MockXArmConfig) -> std::io::Result<Listeners> {
    let bind = |port: u16| TcpListener::bind(SocketAddr::new(cfg.host, port));
    let optional = |port: Option<u16>| async move {
        match port {
            Some(p) => bind(p).await.map(Some),
            None => Ok(None),
        }
    };
    Ok((
        bind(cfg.command_port).await?,
        optional(cfg.normal_report_port).await?,
        optional(cfg.rich_report_port).await?,
        optional(cfg.real_report_port).await?,
    ))
}

impl MockXArm {
    /// Binds the ports and starts serving on the current tokio runtime.
    pub async fn spawn(cfg: MockXArmConfig) -> std::io::Result<MockXArm> {
        let invalid = |msg: String| std::io::Error::new(std::io::ErrorKind::InvalidInput, msg);
        if let Some(start) = &cfg.start {
            if start.len() != cfg.model.axes() {
                return Err(invalid(format!(
                    "{} start joints for the {} axes of an {}",
                    start.len(),
                    cfg.model.axes(),
                    cfg.model
                )));
            }
        }
        if !(cfg.speedup.is_finite() && cfg.speedup > 0.0) {
            return Err(invalid(format!("speedup {} must be positive", cfg.speedup)));
        }
        let mut cfg = cfg;
        let mut attempt = 0;
        let (command, normal, rich, real) = loop {
            if cfg.private_loopback {
                cfg.host = crate::fresh_loopback();
            }
            match bind_all(&cfg).await {
                Ok(l) => break l,
                Err(e)
                    if cfg.private_loopback
                        && e.kind() == std::io::ErrorKind::AddrInUse
                        && attempt < 20 =>
                {
                    attempt += 1
                }
                Err(e) => return Err(e),
            }
        };
        let shared = Arc::new(Shared {
            ctl: Mutex::new(Controller::new(cfg)),
            links: Links::new(),
            connections: Mutex::new(0),
        });
        let mock = MockXArm {
            command_addr: command.local_addr()?,
            normal_report_addr: normal.as_ref().map(|l| l.local_addr()).transpose()?,
            rich_report_addr: rich.as_ref().map(|l| l.local_addr()).transpose()?,
            real_report_addr: real.as_ref().map(|l| l.local_addr()).transpose()?,
            shared: shared.clone(),
        };
        tokio::spawn(accept_loop(shared.clone(), command, Port::Command));
        let reports = [
            (normal, 200, ReportKind::Normal),
            (rich, 200, ReportKind::Rich),
            (real, 10, ReportKind::Real),
        ];
        for (listener, period_ms, kind) in reports {
            if let Some(l) = listener {
                let port = Port::Report {
                    period: Duration::from_millis(period_ms),
                    kind,
                };
                tokio::spawn(accept_loop(shared.clone(), l, port));
            }
        }
        // Faults fire on time even when nobody is asking.
        let links = shared.links.subscribe();
        tokio::spawn(tick_until_shutdown(
            links,
            Duration::from_millis(5),
            move || shared.with(|_| ()),
        ));
        Ok(mock)
    }

    /// The command port's address.
    pub fn command_addr(&self) -> SocketAddr {
        self.command_addr
    }

    /// The normal (30001-style) report port's address, if served.
    pub fn normal_report_addr(&self) -> Option<SocketAddr> {
        self.normal_report_addr
    }

    /// The rich (30002-style) report port's address, if served.
    pub fn rich_report_addr(&self) -> Option<SocketAddr> {
        self.rich_report_addr
    }

    /// The real (30003-style) report port's address, if served.
    pub fn real_report_addr(&self) -> Option<SocketAddr> {
        self.real_report_addr
    }

    /// Every joint-move command received, in order.
    pub fn commands(&self) -> Vec<MoveRecord> {
        self.shared.with(|c| c.log.clone())
    }

    /// Every private-protocol request received, in order.
    pub fn requests(&self) -> Vec<RequestRecord> {
        self.shared.with(|c| c.requests.clone())
    }

    /// Command connections accepted so far.
    pub fn connections(&self) -> u64 {
        *self
            .shared
            .connections
            .lock()
            .unwrap_or_else(|e| e.into_inner())
    }

    /// The arm's true joints (what a camera would see).
    pub fn true_joints(&self) -> Vec<f64> {
        self.shared.with(|c| c.true_joints())
    }

    /// The state the controller reports now.
    pub fn reported_state(&self) -> u8 {
        self.shared.with(|c| c.reported_state())
    }

    /// Raises controller error `code` now (the arm stops where it is).
    pub fn inject_error(&self, code: u8) {
        self.shared.with(|c| c.raise_error(code));
    }

    /// Closes every connection now; with `refuse_reconnect` the listeners close too.
    pub fn drop_connections(&self, refuse_reconnect: bool) {
        self.shared.links.drop_all(refuse_reconnect);
    }

    /// A one-line summary of where it listens.
    pub fn describe(&self) -> String {
        let (model, fw) = self
            .shared
            .with(|c| (c.model().to_string(), c.firmware().to_string()));
        let mut s = format!(
            "mock {model} controller (firmware v{fw}): commands on {}",
            self.command_addr
        );
        if let Some(a) = self.normal_report_addr {
            s += &format!(", normal report (5 Hz) on {a}");
        }
        if let Some(a) = self.rich_report_addr {
            s += &format!(", rich report (5 Hz) on {a}");
        }
        if let Some(a) = self.real_report_addr {
            s += &format!(", real report (100 Hz) on {a}");
        }
        s
    }
}

impl Drop for MockXArm {
    fn drop(&mut self) {
        self.shared.links.shut_down();
    }
}

async fn accept_loop(shared: Arc<Shared>, listener: TcpListener, port: Port) {
    let serving = shared.clone();
    let serve = move |stream: TcpStream, generation: u64| {
        let shared = serving.clone();
        match port {
            Port::Command => {
                let id = {
                    let mut n = shared.connections.lock().unwrap_or_else(|e| e.into_inner());
                    *n += 1;
                    *n
                };
                tokio::spawn(serve_commands(shared, stream, id, generation));
            }
            Port::Report { period, kind } => {
                tokio::spawn(serve_reports(shared, stream, period, kind, generation));
            }
        }
    };
    shared.links.accept(listener, serve).await;
}

async fn serve_commands(shared: Arc<Shared>, mut stream: TcpStream, id: u64, generation: u64) {
    let mut rx = shared.links.subscribe();
    let mut buf = Vec::new();
    let mut chunk = [0u8; 2048];
    loop {
        loop {
            match RawFrame::parse(&buf) {
                Ok((frame, used)) => {
                    buf.drain(..used);
                    if let Some(reply) = answer(&shared, id, frame) {
                        if stream.write_all(&reply).await.is_err() {
                            return;
                        }
                    }
                }
                Err(easyhec_drivers::xarm::frame::FrameError::Incomplete) => break,
                // A stream out of step cannot be resynchronised: close it like a controller.
                Err(_) => return,
            }
        }
        tokio::select! {
            r = stream.read(&mut chunk) => match r {
                Ok(0) | Err(_) => break,
                Ok(n) => buf.extend_from_slice(&chunk[..n]),
            },
            _ = closed(&mut rx, generation) => break,
        }
    }
    shared.with(|c| c.client_gone());
}

fn answer(shared: &Shared, connection: u64, frame: RawFrame) -> Option<Vec<u8>> {
    let register = frame.register();
    match frame.protocol {
        protocol::PRIVATE | protocol::PRIVATE_KEEPALIVE => {
            let params = frame.body[1..].to_vec();
            let (status, data) = shared.with(|c| {
                c.requests.push(RequestRecord {
                    connection,
                    transaction: frame.transaction,
                    protocol: frame.protocol,
                    register,
                    params: params.clone(),
                });
                c.handle(register, &params)
            })?;
            Some(
                Reply {
                    transaction: frame.transaction,
                    protocol: frame.protocol,
                    register,
                    status,
                    data,
                }
                .encode(),
            )
        }
        // Standard Modbus-TCP: "illegal function" for everything (read-only joints at
        // 0.1° are of no use to calibration).
        protocol::MODBUS => Some(
            RawFrame {
                transaction: frame.transaction,
                protocol: protocol::MODBUS,
                body: vec![
                    register,
                    frame.body.get(1).copied().unwrap_or(0) | 0x80,
                    0x01,
                ],
            }
            .encode(),
        ),
        // Heartbeats (id 1) and unknown ids: no answer.
        _ => None,
    }
}

async fn serve_reports(
    shared: Arc<Shared>,
    mut stream: TcpStream,
    period: Duration,
    kind: ReportKind,
    generation: u64,
) {
    let mut rx = shared.links.subscribe();
    // The first frame goes out at once: a client connecting gets a current reading.
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            _ = tick.tick() => {
                let frame = shared.with(|c| c.report_frame(kind));
                if stream.write_all(&frame).await.is_err() {
                    return;
                }
            }
            _ = closed(&mut rx, generation) => return,
        }
    }
}

/// The true joints of an arm as its controller's report port streams them: what a
/// simulated camera films when the arm is a (mock or real) xArm rather than a [`crate::SimArm`].
#[derive(Clone, Debug)]
pub struct XArmReportJoints {
    /// `host:port` of a report port (30001, 30002 or 30003: all three begin with the joints).
    pub addr: String,
    /// Joints to keep (the arm's axes; reports always carry 7).
    pub axes: usize,
    /// Limit for connecting and receiving one frame.
    pub timeout: Duration,
}

#[async_trait]
impl JointSource for XArmReportJoints {
    async fn true_joints(&self) -> DriverResult<Vec<f64>> {
        let report = read_report_from(&self.addr, self.timeout).await?;
        Ok(report.joints_rad[..self.axes.min(7)]
            .iter()
            .map(|&v| f64::from(v))
            .collect())
    }
}

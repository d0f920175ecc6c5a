//! A mock Universal Robots e-Series controller on loopback, speaking RTDE (30004), the
//! dashboard protocol (29999) and accepting URScript on the real-time port (30003), so the
//! vendor's own `ur_rtde` library (and our driver built on it) run unmodified.
//!
//! What it models (docs/protocols.md §2): RTDE protocol negotiation, the controller version
//! (5.11.1 by default), output recipes streamed at the requested frequency (≤ 500 Hz), input
//! recipes with ids handed out 1, 2, 3, … per connection (ur_rtde hard-codes them); the
//! dashboard commands clients use (modes, remote control, power, brakes, protective-stop
//! unlock, popups, play/stop); and the register handshake of ur_rtde's control script
//! (§2.5): moveJ (synchronous or not), stopJ/stopL, STOP_SCRIPT, with `output_int_register_0`
//! signalling ready/done and `output_int_register_2` the asynchronous progress.
//!
//! Motion is linear in joint space at the commanded speed (no acceleration ramps), `speedup`
//! times faster than the wall clock. Every moveJ is recorded with what the registers held
//! and whether it was accepted; targets outside the UR5e limits, speeds above the cap or
//! accelerations above their cap are refused (the script halts with a runtime error, as a
//! real one would), so tests can prove that no unsafe command reached "the arm". Faults:
//! protective stop mid-move, not in remote control, all connections dropped mid-move.
//!
//! ur_rtde has no port options for RTDE and the script port, so tests that drive it use
//! [`MockUrConfig::free_ports`]: the standard ports on a loopback address of their own
//! (127.x.y.z), which is how parallel tests avoid each other.

mod controller;
mod dashboard;
mod rtde;
pub mod wire;

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use async_trait::async_trait;
use easyhec_drivers::ur::model::{self, DASHBOARD_PORT, RTDE_PORT, SCRIPT_PORT};
use easyhec_drivers::{DriverError, Result as DriverResult};
use tokio::net::{TcpListener, TcpStream};

use crate::links::{closed, tick_until_shutdown, Links};
use crate::JointSource;
use controller::Controller;
pub use dashboard::GREETING as DASHBOARD_GREETING;

/// Where and how the mock controller runs.
#[derive(Clone, Debug)]
pub struct MockUrConfig {
    /// Address to listen on.
    pub host: IpAddr,
    /// RTDE port (30004; 0: a free one, which ur_rtde cannot use).
    pub rtde_port: u16,
    /// Dashboard port (29999; 0: free).
    pub dashboard_port: u16,
    /// Script port (30003; 0: free).
    pub script_port: u16,
    /// Pick a fresh 127.x.y.z for `host` at spawn, retrying while the ports are taken there.
    pub private_loopback: bool,
    /// Joints at start, rad.
    pub start: Vec<f64>,
    /// Joint limits enforced (default UR5e).
    pub limits: Vec<(f64, f64)>,
    /// Moves faster than this (fastest joint, rad/s) are refused.
    pub speed_cap_rad_s: f64,
    /// Moves with a larger acceleration (rad/s²) are refused.
    pub accel_cap_rad_s2: f64,
    /// Simulated seconds per wall-clock second.
    pub speedup: f64,
    /// Controller software version announced (major, minor, bugfix, build).
    pub version: [u32; 4],
    /// The dashboard's `get serial number`.
    pub serial_number: String,
    /// The pendant is in remote control (state-changing dashboard commands allowed).
    pub remote_control: bool,
    /// Injected faults.
    pub faults: Vec<MockUrFault>,
    /// Halt the arm when the connections are dropped by a fault.
    pub halt_on_disconnect: bool,
}

/// The start pose of `config/sim-ur5e.toml` (the demo camera sees the whole arm).
pub const DEMO_UR5E_START: [f64; 6] = [0.3, -1.9, 1.6, -1.3, -1.57, 0.0];

impl MockUrConfig {
    /// On 127.0.0.1 with the ports of a real controller (30004, 29999, 30003).
    pub fn standard_ports() -> MockUrConfig {
        MockUrConfig {
            host: IpAddr::V4(Ipv4Addr::LOCALHOST),
            rtde_port: RTDE_PORT,
            dashboard_port: DASHBOARD_PORT,
            script_port: SCRIPT_PORT,
            private_loopback: false,
            start: DEMO_UR5E_START.to_vec(),
            limits: model::UR5E_LIMITS.to_vec(),
            speed_cap_rad_s: model::UR5E_MAX_SPEED_RAD_S,
            accel_cap_rad_s2: model::MAX_ACCEL_RAD_S2,
            speedup: 1.0,
            version: [5, 11, 1, 108318],
            serial_number: "20185500001".into(),
            remote_control: true,
            faults: Vec::new(),
            halt_on_disconnect: false,
        }
    }

    /// The standard ports on a loopback address no one else uses (127.x.y.z, picked at
    /// spawn): ur_rtde cannot be told other ports, so the address is what varies between
    /// tests running in parallel.
    pub fn free_ports() -> MockUrConfig {
        MockUrConfig {
            private_loopback: true,
            ..MockUrConfig::standard_ports()
        }
    }

    /// Free ports on 127.0.0.1 (port 0 everywhere): for clients that take a port, not
    /// ur_rtde.
    pub fn any_ports() -> MockUrConfig {
        MockUrConfig {
            rtde_port: 0,
            dashboard_port: 0,
            script_port: 0,
            ..MockUrConfig::standard_ports()
        }
    }
}

/// A fault to inject on a given moveJ (0-based count of moveJ commands received).
#[derive(Clone, Debug, PartialEq)]
pub enum MockUrFault {
    /// The arm protective-stops after `at_fraction` of the path: safety mode 3, program
    /// paused, until the dashboard's `unlock protective stop`.
    ProtectiveStop {
        /// Which move.
        on_move: usize,
        /// Fraction of the path covered, 0..1.
        at_fraction: f64,
    },
    /// Every connection is closed after `at_fraction` of the path; the arm keeps going
    /// unless `halt_on_disconnect`. With `refuse_reconnect` the listeners close too.
    DropMidMove {
        /// Which move.
        on_move: usize,
        /// Fraction of the path covered, 0..1.
        at_fraction: f64,
        /// Stop accepting connections afterwards.
        refuse_reconnect: bool,
    },
}

/// One moveJ as the mock's control script received it.
#[derive(Clone, Debug, PartialEq)]
pub struct UrMoveRecord {
    /// 0-based count of moveJ commands.
    pub index: usize,
    /// True joints when it arrived.
    pub from: Vec<f64>,
    /// Target, rad (`input_double_register_0..5`).
    pub target: Vec<f64>,
    /// Commanded joint speed, rad/s (`input_double_register_6`).
    pub speed_rad_s: f64,
    /// Commanded joint acceleration, rad/s² (`input_double_register_7`).
    pub accel_rad_s2: f64,
    /// ur_rtde's `asynchronous` flag (`input_int_register_1`).
    pub asynchronous: bool,
    /// Whether the arm started it.
    pub accepted: bool,
    /// `None` while moving; "arrived", "stopped", "protective stop", or why it was refused.
    pub outcome: Option<String>,
}

/// A script received on the script port.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ScriptUpload {
    /// Its first line (`def rtde_control():` for ur_rtde's).
    pub first_line: String,
    /// Its length in bytes.
    pub bytes: usize,
}

/// One RTDE package a client sent.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RtdeRequest {
    /// Which RTDE connection (1 = the first accepted).
    pub connection: u64,
    /// Package type byte.
    pub kind: u8,
    /// Payload.
    pub payload: Vec<u8>,
}

struct Shared {
    ctl: Mutex<Controller>,
    links: Links,
    requests: Mutex<Vec<RtdeRequest>>,
    connections: Mutex<u64>,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Controller> {
        // The state stays consistent between statements; a panicked holder (only in a test)
        // leaves it usable.
        self.ctl.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Runs `f` on the controller brought up to now, then fires any drop a fault asked for.
    fn with<R>(&self, f: impl FnOnce(&mut Controller) -> R) -> R {
        let (out, drop_now) = {
            let mut c = self.lock();
            c.advance();
            let out = f(&mut c);
            c.advance();
            let drop_now = c.drop_now.take();
            if drop_now.is_some() && c.cfg.halt_on_disconnect {
                c.halt("link lost");
            }
            (out, drop_now)
        };
        if let Some(refuse) = drop_now {
            self.links.drop_all(refuse);
        }
        out
    }

    fn record(&self, r: RtdeRequest) {
        // Data packages are the bulk; keep the log bounded.
        let mut log = self.requests.lock().unwrap_or_else(|e| e.into_inner());
        if log.len() < 100_000 {
            log.push(r);
        }
    }
}

/// A running mock controller. Dropping it shuts it down.
pub struct MockUr {
    shared: Arc<Shared>,
    rtde_addr: SocketAddr,
    dashboard_addr: SocketAddr,
    script_addr: SocketAddr,
}

#[derive(Clone, Copy)]
enum Port {
    Rtde,
    Dashboard,
    Script,
}

impl MockUr {
    /// Binds the ports and starts serving on the current tokio runtime.
    pub async fn spawn(cfg: MockUrConfig) -> std::io::Result<MockUr> {
        let invalid = |msg: String| std::io::Error::new(std::io::ErrorKind::InvalidInput, msg);
        if cfg.start.len() != 6 || cfg.limits.len() != 6 {
            return Err(invalid(format!(
                "{} start joints and {} limits for the 6 joints of a UR arm",
                cfg.start.len(),
                cfg.limits.len()
            )));
        }
        if !model::within_limits(&cfg.start, &cfg.limits) {
            return Err(invalid(format!(
                "start joints {:?} outside the joint limits",
                cfg.start
            )));
        }
        if !(cfg.speedup.is_finite() && cfg.speedup > 0.0) {
            return Err(invalid(format!("speedup {} must be positive", cfg.speedup)));
        }
        let mut cfg = cfg;
        let mut attempt = 0;
        let (rtde, dashboard, script) = loop {
            if cfg.private_loopback {
                cfg.host = crate::fresh_loopback();
            }
            let bind = |port: u16| TcpListener::bind(SocketAddr::new(cfg.host, port));
            let bound = async {
                Ok::<_, std::io::Error>((
                    bind(cfg.rtde_port).await?,
                    bind(cfg.dashboard_port).await?,
                    bind(cfg.script_port).await?,
                ))
            }
            .await;
            match bound {
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
            requests: Mutex::new(Vec::new()),
            connections: Mutex::new(0),
        });
        let mock = MockUr {
            rtde_addr: rtde.local_addr()?,
            dashboard_addr: dashboard.local_addr()?,
            script_addr: script.local_addr()?,
            shared: shared.clone(),
        };
        tokio::spawn(accept_loop(shared.clone(), rtde, Port::Rtde));
        tokio::spawn(accept_loop(shared.clone(), dashboard, Port::Dashboard));
        tokio::spawn(accept_loop(shared.clone(), script, Port::Script));
        // Motion, faults and the script run on time even when nobody is asking.
        let links = shared.links.subscribe();
        tokio::spawn(tick_until_shutdown(
            links,
            Duration::from_millis(2),
            move || shared.with(|_| ()),
        ));
        Ok(mock)
    }

    /// The address every port listens on (the one to give ur_rtde as hostname).
    pub fn host(&self) -> IpAddr {
        self.rtde_addr.ip()
    }

    /// The RTDE port's address.
    pub fn rtde_addr(&self) -> SocketAddr {
        self.rtde_addr
    }

    /// The dashboard's address.
    pub fn dashboard_addr(&self) -> SocketAddr {
        self.dashboard_addr
    }

    /// The script port's address.
    pub fn script_addr(&self) -> SocketAddr {
        self.script_addr
    }

    /// Every moveJ received, in order.
    pub fn commands(&self) -> Vec<UrMoveRecord> {
        self.shared.with(|c| c.log.clone())
    }

    /// Every command id the control script processed (1 moveJ, 34 stopJ, 255 stop script…).
    pub fn script_commands(&self) -> Vec<i32> {
        self.shared.with(|c| c.script_commands.clone())
    }

    /// Every script received on the script port.
    pub fn script_uploads(&self) -> Vec<ScriptUpload> {
        self.shared.with(|c| c.uploads.clone())
    }

    /// Every dashboard command line received.
    pub fn dashboard_commands(&self) -> Vec<String> {
        self.shared.with(|c| c.dashboard.clone())
    }

    /// Every RTDE package clients sent (data packages included), in order.
    pub fn rtde_requests(&self) -> Vec<RtdeRequest> {
        self.shared
            .requests
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// RTDE connections accepted so far.
    pub fn rtde_connections(&self) -> u64 {
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

    /// Whether the arm is moving.
    pub fn moving(&self) -> bool {
        self.shared.with(|c| c.moving())
    }

    /// (`robot_mode`, `safety_mode`, `runtime_state`) now.
    pub fn modes(&self) -> (i32, i32, u32) {
        self.shared
            .with(|c| (c.robot_mode, c.safety_mode, c.runtime))
    }

    /// Protective-stops the arm now.
    pub fn protective_stop(&self) {
        self.shared.with(|c| c.protective_stop());
    }

    /// Switches the pendant between remote and local control.
    pub fn set_remote_control(&self, on: bool) {
        self.shared.with(|c| c.remote_control = on);
    }

    /// Closes every connection now; with `refuse_reconnect` the listeners close too.
    pub fn drop_connections(&self, refuse_reconnect: bool) {
        self.shared.links.drop_all(refuse_reconnect);
    }

    /// A one-line summary of where it listens.
    pub fn describe(&self) -> String {
        let v = self.shared.with(|c| c.cfg.version);
        format!(
            "mock UR5e controller (software {}.{}.{}.{}): RTDE on {}, dashboard on {}, script on {}",
            v[0], v[1], v[2], v[3], self.rtde_addr, self.dashboard_addr, self.script_addr
        )
    }
}

impl Drop for MockUr {
    fn drop(&mut self) {
        self.shared.links.shut_down();
    }
}

async fn accept_loop(shared: Arc<Shared>, listener: TcpListener, port: Port) {
    let serving = shared.clone();
    let serve = move |stream: TcpStream, generation: u64| {
        let shared = serving.clone();
        match port {
            Port::Rtde => {
                let id = {
                    let mut n = shared.connections.lock().unwrap_or_else(|e| e.into_inner());
                    *n += 1;
                    *n
                };
                tokio::spawn(rtde::serve_rtde(shared, stream, id, generation));
            }
            Port::Dashboard => {
                tokio::spawn(dashboard::serve_dashboard(shared, stream, generation));
            }
            Port::Script => {
                tokio::spawn(dashboard::serve_script(shared, stream, generation));
            }
        }
    };
    shared.links.accept(listener, serve).await;
}

/// Reads `actual_q` once from an RTDE port (a mock or a real controller): connect, negotiate
/// protocol 2, set up a one-variable output recipe, start, take the first data package.
pub async fn read_actual_q(addr: &str, timeout: Duration) -> DriverResult<Vec<f64>> {
    use wire::{kind, read_package, write_package};
    let io = |what: &str, e: std::io::Error| {
        DriverError::Connection(format!("RTDE {addr}: {what}: {e}"))
    };
    let exchange = async {
        let mut s = TcpStream::connect(addr)
            .await
            .map_err(|e| io("connect", e))?;
        let _ = s.set_nodelay(true);
        let mut o = 125.0f64.to_be_bytes().to_vec();
        o.extend_from_slice(b"actual_q");
        let steps: [(u8, Vec<u8>); 3] = [
            (kind::PROTOCOL_VERSION, 2u16.to_be_bytes().to_vec()),
            (kind::SETUP_OUTPUTS, o),
            (kind::START, Vec::new()),
        ];
        for (k, payload) in steps {
            write_package(&mut s, k, &payload)
                .await
                .map_err(|e| io("send", e))?;
            loop {
                let p = read_package(&mut s)
                    .await
                    .map_err(|e| io("receive", e))?
                    .ok_or_else(|| {
                        DriverError::Connection(format!("RTDE {addr}: closed during setup"))
                    })?;
                if p.kind == kind::TEXT_MESSAGE {
                    continue;
                }
                let ok = p.kind == k
                    && match k {
                        kind::SETUP_OUTPUTS => p.payload.first().is_some_and(|id| *id != 0),
                        _ => p.payload.first() == Some(&1),
                    };
                if !ok {
                    return Err(DriverError::Refused(format!(
                        "RTDE {addr}: request {:?} answered with {:?} {:?}",
                        k as char,
                        p.kind as char,
                        String::from_utf8_lossy(&p.payload)
                    )));
                }
                break;
            }
        }
        loop {
            let p = read_package(&mut s)
                .await
                .map_err(|e| io("receive", e))?
                .ok_or_else(|| {
                    DriverError::Connection(format!("RTDE {addr}: closed before data"))
                })?;
            if p.kind == kind::DATA && p.payload.len() == 1 + 48 {
                let v = wire::decode_values(&[wire::FieldType::Vector6d], &p.payload[1..]);
                if let Some(wire::Value::Doubles(q)) = v.and_then(|mut v| v.pop()) {
                    return Ok(q);
                }
            }
        }
    };
    tokio::time::timeout(timeout, exchange)
        .await
        .map_err(|_| DriverError::Timeout(timeout))?
}

/// The true joints of a UR arm as its controller's RTDE stream reports them: what a
/// simulated camera films when the arm is a (mock or real) UR controller.
#[derive(Clone, Debug)]
pub struct UrRtdeJoints {
    /// `host:port` of the RTDE port (30004).
    pub addr: String,
    /// Limit for connecting and receiving one data package.
    pub timeout: Duration,
}

#[async_trait]
impl JointSource for UrRtdeJoints {
    async fn true_joints(&self) -> DriverResult<Vec<f64>> {
        read_actual_q(&self.addr, self.timeout).await
    }
}

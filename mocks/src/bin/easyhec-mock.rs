//! `easyhec-mock`: mock robot controllers on loopback, for trying the real drivers (and the
//! vendors' SDKs) without hardware. One subcommand per controller family; each runs until
//! killed and prints one line saying where it listens.

use std::net::IpAddr;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use easyhec_drivers::xarm::Model;
use easyhec_mocks::ur::{MockUr, MockUrConfig};
use easyhec_mocks::xarm::{MockXArm, MockXArmConfig};

#[derive(Parser)]
#[command(
    name = "easyhec-mock",
    about = "Mock robot controllers speaking the real protocols"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// A UFACTORY controller: private protocol on 502, reports on 30001 (normal, 5 Hz), 30002
    /// (rich, 5 Hz, the vendor SDK's default) and 30003 (real, 100 Hz).
    Xarm(XarmArgs),
    /// A Universal Robots e-Series controller (UR5e): RTDE on 30004, dashboard on 29999,
    /// URScript on 30003, with ur_rtde's control-script handshake.
    Ur(UrArgs),
}

#[derive(clap::Args)]
struct UrArgs {
    /// Address to listen on (ur_rtde always uses 30004/29999/30003, so parallel mocks need
    /// different addresses, e.g. 127.0.0.2).
    #[arg(long, default_value = "127.0.0.1")]
    bind: IpAddr,
    /// Pick free ports instead of 30004/29999/30003 (printed on start; ur_rtde cannot use them).
    #[arg(long)]
    free_ports: bool,
    /// Start joints, radians, comma-separated [default: the demo pose of config/sim-ur5e.toml].
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    start: Option<Vec<f64>>,
    /// Simulated seconds per wall-clock second.
    #[arg(long, default_value_t = 1.0)]
    speedup: f64,
    /// Refuse moves faster than this, rad/s.
    #[arg(long, default_value_t = std::f64::consts::PI)]
    speed_cap: f64,
    /// Start in local control (the pendant's mode): state-changing dashboard commands are
    /// refused and ur_rtde's control interface will not connect.
    #[arg(long)]
    local_control: bool,
    /// Print every moveJ as it ends.
    #[arg(long)]
    verbose: bool,
}

#[derive(clap::Args)]
struct XarmArgs {
    /// Arm model: xarm5, xarm6, xarm6-sn1305, xarm7, lite6, uf850.
    #[arg(long, default_value = "xarm6")]
    model: String,
    /// Address to listen on.
    #[arg(long, default_value = "127.0.0.1")]
    bind: IpAddr,
    /// Pick free ports instead of 502/30001/30002/30003 (printed on start).
    #[arg(long)]
    free_ports: bool,
    /// Start joints, radians, comma-separated [default: the demo pose for xarm6, else zeros].
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    start: Option<Vec<f64>>,
    /// Simulated seconds per wall-clock second.
    #[arg(long, default_value_t = 1.0)]
    speedup: f64,
    /// Refuse (error C24) moves faster than this, rad/s.
    #[arg(long, default_value_t = std::f64::consts::PI)]
    speed_cap: f64,
    /// Firmware version to announce (≥ 2.0.102 makes the vendor SDK ask for feedback frames,
    /// which this mock does not send; it then falls back to polling).
    #[arg(long, default_value = "1.12.10")]
    firmware: String,
    /// Print every joint-move command as it is answered.
    #[arg(long)]
    verbose: bool,
}

/// The start pose of `config/sim-xarm6.toml`, which the demo camera sees whole.
const DEMO_XARM6_START: [f64; 6] = [0.0, -0.35, -0.6, 0.0, 0.95, 0.0];

fn main() -> ExitCode {
    // With `--features ur`, this executable can also host the UR driver's `ur_rtde` child
    // process (used by the UR driver tests of this package).
    easyhec_drivers::ur::serve_worker_if_asked();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Xarm(args) => run_xarm(args),
        Command::Ur(args) => run_ur(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run_xarm(a: XarmArgs) -> Result<(), String> {
    let model: Model = a.model.parse()?;
    let mut cfg = if a.free_ports {
        MockXArmConfig::free_ports(model)
    } else {
        MockXArmConfig::standard_ports(model)
    };
    cfg.host = a.bind;
    cfg.start = match a.start {
        Some(q) => Some(q),
        None if model == Model::Xarm6 => Some(DEMO_XARM6_START.to_vec()),
        None => None,
    };
    cfg.speedup = a.speedup;
    cfg.speed_cap_rad_s = a.speed_cap;
    cfg.firmware = a.firmware;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(|e| format!("tokio runtime: {e}"))?;
    runtime.block_on(async move {
        let mock = MockXArm::spawn(cfg).await.map_err(|e| match e.kind() {
            std::io::ErrorKind::PermissionDenied | std::io::ErrorKind::AddrInUse => {
                format!("cannot listen ({e}): ports below 1024 need root, or pass --free-ports")
            }
            _ => e.to_string(),
        })?;
        println!("{}", mock.describe());
        let mut seen = 0;
        loop {
            tokio::time::sleep(std::time::Duration::from_millis(100)).await;
            if a.verbose {
                let log = mock.commands();
                for c in log.iter().skip(seen).filter(|c| c.outcome.is_some()) {
                    let q: Vec<String> = c.target.iter().map(|v| format!("{v:+.3}")).collect();
                    println!(
                        "move {}: [{}] at {:.3} rad/s: {}",
                        c.index,
                        q.join(", "),
                        c.speed_rad_s,
                        c.outcome.as_deref().unwrap_or("")
                    );
                    seen = c.index + 1;
                }
            }
        }
    })
}

fn run_ur(a: UrArgs) -> Result<(), String> {
    let mut cfg = if a.free_ports {
        MockUrConfig::any_ports()
    } else {
        MockUrConfig::standard_ports()
    };
    cfg.host = a.bind;
    if let Some(q) = a.start {
        if q.len() != 6 {
            return Err(format!("{} start joints: a UR arm has 6", q.len()));
        }
        cfg.start = q;
    }
    if !(a.speed_cap.is_finite() && a.speed_cap > 0.0) {
        return Err(format!(
            "--speed-cap {}: use a positive number of rad/s",
            a.speed_cap
        ));
    }
    cfg.speedup = a.speedup;
    cfg.speed_cap_rad_s = a.speed_cap;
    cfg.remote_control = !a.local_control;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(|e| format!("tokio runtime: {e}"))?;
    runtime.block_on(async move {
        let mock = MockUr::spawn(cfg).await.map_err(|e| match e.kind() {
            std::io::ErrorKind::AddrInUse => format!(
                "cannot listen ({e}): another controller or mock holds the ports; use --bind 127.0.0.2 (ur_rtde) or --free-ports"
            ),
            _ => e.to_string(),
        })?;
        println!("{}", mock.describe());
        let mut seen = 0;
        loop {
            tokio::time::sleep(std::time::Duration::from_millis(100)).await;
            if a.verbose {
                let log = mock.commands();
                for c in log.iter().skip(seen).take_while(|c| c.outcome.is_some()) {
                    let q: Vec<String> = c.target.iter().map(|v| format!("{v:+.3}")).collect();
                    println!(
                        "moveJ {}: [{}] at {:.3} rad/s, {:.2} rad/s²: {}",
                        c.index,
                        q.join(", "),
                        c.speed_rad_s,
                        c.accel_rad_s2,
                        c.outcome.as_deref().unwrap_or("")
                    );
                    seen = c.index + 1;
                }
            }
        }
    })
}

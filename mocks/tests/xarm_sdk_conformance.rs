//! Vendor-SDK conformance: UFACTORY's own `xarm-python-sdk` (1.18.4) drives the mock
//! controller through connect, enable, mode, state, a radian joint move with `wait=True` and
//! a read-back (`conformance/xarm_sdk.py`). If the mock disagrees with the real protocol
//! anywhere the SDK looks, this fails. Two ways in:
//!
//! - on free ports with the normal report (30001-style): the script patches the SDK's
//!   hard-coded port numbers in its own process;
//! - through the SDK's default constructor, `XArmAPI(host)`, as a user's first script calls
//!   it: command port 502 and the rich report on 30002, patched nowhere. The SDK starts no
//!   move before a report has shown it a ready arm, so this is what proves the rich report
//!   right. It needs the real port numbers, so the mock serves them on a 127.x.y.z address of
//!   its own (`standard_ports_on_private_loopback`): neither test here, nor a mock started by
//!   hand or another test binary on 127.0.0.1, can take its ports, and no lock is needed.
//!
//! Without the SDK (or python3), or without the privilege to listen on port 502 (root, or a
//! lowered `net.ipv4.ip_unprivileged_port_start`), a test fails when `CI` is set and is
//! skipped with a message otherwise. The SDK can block forever on a peer that never answers,
//! so the script runs under a kill timeout: the only timed check here.

mod python_probe;

use std::collections::HashMap;
use std::io::Write;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

use easyhec_drivers::xarm::frame::reg;
use easyhec_drivers::xarm::Model;
use easyhec_mocks::xarm::{MockXArm, MockXArmConfig};

const SCRIPT_TIMEOUT: Duration = Duration::from_secs(60);

/// Fails `test` under `CI`, otherwise reports it skipped (the caller then returns).
fn skip(test: &str, why: &str) {
    if std::env::var_os("CI").is_some() {
        panic!("CI must be able to run {test}: {why}");
    }
    // Straight to the stream: libtest would swallow eprintln! output of a passing test.
    let _ = writeln!(std::io::stderr(), "SKIPPED {test}: {why}");
}

fn sdk_available() -> Result<(), String> {
    python_probe::sdk_importable(
        "import xarm.wrapper",
        "the xarm SDK is not installed (python3 -m pip install xarm-python-sdk==1.18.4)",
    )
}

/// Runs the script, killing it after `SCRIPT_TIMEOUT`; returns (success, stdout + stderr).
fn run_script(args: &[String]) -> (bool, String) {
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/conformance/xarm_sdk.py");
    let dir = tempfile_dir();
    let out_path = dir.join("out.txt");
    let out_file = std::fs::File::create(&out_path).unwrap();
    let mut child = Command::new("python3")
        .arg(&script)
        .args(args)
        .stdin(Stdio::null())
        .stdout(out_file.try_clone().unwrap())
        .stderr(out_file)
        .spawn()
        .expect("python3 starts");
    let started = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break Some(status);
        }
        if started.elapsed() > SCRIPT_TIMEOUT {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let text = std::fs::read_to_string(&out_path).unwrap_or_default();
    let _ = std::fs::remove_dir_all(&dir);
    match status {
        Some(s) => (s.success(), text),
        None => (false, format!("killed after {SCRIPT_TIMEOUT:?}:\n{text}")),
    }
}

/// A fresh directory per script run: the tests of this file run their scripts in parallel.
fn tempfile_dir() -> PathBuf {
    static RUNS: AtomicU32 = AtomicU32::new(0);
    let run = RUNS.fetch_add(1, Ordering::Relaxed);
    let dir = std::env::temp_dir().join(format!("easyhec-xarm-sdk-{}-{run}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap()
}

/// The values of the script's line `PREFIX v1,v2,...`.
fn floats_after(output: &str, prefix: &str) -> Vec<f64> {
    let line = output
        .lines()
        .find_map(|l| l.strip_prefix(prefix))
        .unwrap_or_else(|| panic!("no {prefix:?} line in:\n{output}"));
    line.split(',')
        .map(|v| v.trim().parse().unwrap_or_else(|e| panic!("{v:?}: {e}")))
        .collect()
}

/// Every register the SDK sent is one the mock models (an unmodelled one only raises a
/// warning, which a scenario could pass without noticing).
fn assert_modelled(regs: &[u8]) {
    let known = [
        reg::GET_VERSION,
        reg::GET_ROBOT_SN,
        reg::MOTION_EN,
        reg::SET_STATE,
        reg::GET_STATE,
        reg::GET_CMDNUM,
        reg::GET_ERROR,
        reg::CLEAN_ERR,
        reg::CLEAN_WAR,
        reg::SET_MODE,
        reg::MOVE_JOINT,
        reg::MOVE_JOINTB,
        reg::GET_TCP_POSE,
        reg::GET_JOINT_POS,
    ];
    let unknown: Vec<&u8> = regs.iter().filter(|r| !known.contains(r)).collect();
    assert!(
        unknown.is_empty(),
        "registers the mock does not model: {unknown:?}"
    );
}

fn assert_near(got: &[f64], want: &[f64], tol: f64, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: {got:?} vs {want:?}");
    for (g, w) in got.iter().zip(want) {
        assert!((g - w).abs() <= tol, "{what}: {got:?} vs {want:?}");
    }
}

#[test]
fn vendor_sdk_drives_the_mock_through_a_joint_move() {
    if let Err(why) = sdk_available() {
        skip("vendor_sdk_drives_the_mock_through_a_joint_move", &why);
        return;
    }
    let runtime = runtime();
    let mut cfg = MockXArmConfig::free_ports(Model::Xarm6);
    cfg.speedup = 4.0;
    let mock = runtime.block_on(MockXArm::spawn(cfg)).unwrap();
    let target = [0.3, -0.5, -0.8, 0.1, 1.0, 0.2];
    let joints: Vec<String> = target.iter().map(|v| v.to_string()).collect();
    let args = vec![
        mock.command_addr().ip().to_string(),
        mock.command_addr().port().to_string(),
        mock.normal_report_addr().unwrap().port().to_string(),
        joints.join(","),
        "0.8".into(),
    ];
    let (ok, output) = run_script(&args);
    assert!(ok, "SDK scenario failed:\n{output}");
    assert!(output.lines().any(|l| l.starts_with("OK ")), "{output}");

    // What the SDK put on the wire: the handshake on protocol 2, then protocol 3.
    let requests = mock.requests();
    assert_eq!(requests[0].register, reg::GET_VERSION);
    assert_eq!(requests[0].protocol, 2);
    assert!(
        requests.iter().skip(1).any(|r| r.protocol == 3),
        "the SDK switches to protocol 3 after the handshake"
    );
    let regs: Vec<u8> = requests.iter().map(|r| r.register).collect();
    for needed in [
        reg::MOTION_EN,
        reg::SET_MODE,
        reg::SET_STATE,
        reg::MOVE_JOINT,
    ] {
        assert!(
            regs.contains(&needed),
            "{needed:#04x} missing from {regs:?}"
        );
    }
    assert!(
        regs.contains(&reg::GET_STATE),
        "wait=True polls the state on firmware < 2.0.102: {regs:?}"
    );
    assert_modelled(&regs);
    // One move, accepted, exactly the radians and speed the script asked for.
    let moves = mock.commands();
    assert_eq!(moves.len(), 1, "{moves:?}");
    let m = &moves[0];
    assert!(
        m.accepted && m.outcome.as_deref() == Some("arrived"),
        "{m:?}"
    );
    for (got, want) in m.target.iter().zip(target) {
        assert!((got - want).abs() < 1e-6, "{:?}", m.target);
    }
    assert!((m.speed_rad_s - 0.8).abs() < 1e-6);
    assert!(m.unused_slots.iter().all(|v| *v == 0.0));
}

/// `XArmAPI(host)` with no other argument: report type "rich" on 30002, commands on 502. Before
/// the mock served 30002 the SDK connected and then blocked for ever in `set_servo_angle`.
#[test]
fn vendor_sdk_default_constructor_moves_the_arm_through_the_rich_report() {
    const TEST: &str = "vendor_sdk_default_constructor_moves_the_arm_through_the_rich_report";
    if let Err(why) = sdk_available() {
        skip(TEST, &why);
        return;
    }
    let runtime = runtime();
    let mut cfg = MockXArmConfig::standard_ports_on_private_loopback(Model::Xarm6);
    cfg.speedup = 4.0;
    let (speed_cap, accel_cap) = (cfg.speed_cap_rad_s, cfg.accel_cap_rad_s2);
    let mock = match runtime.block_on(MockXArm::spawn(cfg)) {
        Ok(mock) => mock,
        Err(e) if e.kind() == std::io::ErrorKind::PermissionDenied => {
            let why = format!(
                "cannot listen on port 502 ({e}): run as root or lower \
                 net.ipv4.ip_unprivileged_port_start"
            );
            skip(TEST, &why);
            return;
        }
        Err(e) => panic!("mock on the standard ports: {e}"),
    };
    let ports = [
        mock.command_addr().port(),
        mock.normal_report_addr().unwrap().port(),
        mock.rich_report_addr().unwrap().port(),
        mock.real_report_addr().unwrap().port(),
    ];
    assert_eq!(ports, [502, 30001, 30002, 30003]);
    let host = mock.command_addr().ip();
    assert!(
        host.is_loopback() && host.to_string() != "127.0.0.1",
        "{host}"
    );

    let target = [0.3, -0.5, -0.8, 0.1, 1.0, 0.2];
    let joints: Vec<String> = target.iter().map(|v| v.to_string()).collect();
    let args = vec![
        "--default-constructor".to_string(),
        host.to_string(),
        joints.join(","),
        "0.8".into(),
    ];
    let (ok, output) = run_script(&args);
    assert!(ok, "SDK scenario failed:\n{output}");
    assert!(output.lines().any(|l| l.starts_with("OK ")), "{output}");

    // The arm arrived: the mock's own joints and its record of the one move.
    let moves = mock.commands();
    assert_eq!(moves.len(), 1, "{moves:?}");
    assert!(
        moves[0].accepted && moves[0].outcome.as_deref() == Some("arrived"),
        "{moves:?}"
    );
    assert_near(&mock.true_joints(), &target, 1e-6, "mock joints");
    // ... and the SDK saw it arrive through the rich report, in a frame pushed afterwards.
    assert_near(
        &floats_after(&output, "REPORTED "),
        &target,
        1e-5,
        "reported joints",
    );

    // The rich tail, as the SDK parsed it, agrees with the mock's model, caps and state.
    let rich: HashMap<&str, &str> = output
        .lines()
        .find_map(|l| l.strip_prefix("RICH "))
        .unwrap_or_else(|| panic!("no RICH line in:\n{output}"))
        .split_whitespace()
        .filter_map(|kv| kv.split_once('='))
        .collect();
    let field = |k: &str| {
        *rich
            .get(k)
            .unwrap_or_else(|| panic!("{k} missing: {rich:?}"))
    };
    let number = |k: &str| field(k).parse::<f64>().unwrap();
    assert_eq!(field("report_type"), "rich");
    assert_eq!(field("axis"), "6");
    assert_eq!(field("device_type"), Model::Xarm6.device_type().to_string());
    assert_eq!((field("master_id"), field("slave_id")), ("170", "85"));
    assert!(
        (number("joint_speed_max") - speed_cap).abs() < 1e-4,
        "{rich:?}"
    );
    assert!(
        (number("joint_acc_max") - accel_cap).abs() < 1e-3,
        "{rich:?}"
    );
    assert_eq!(field("temperatures"), "30,30,30,30,30,30,0");
    assert_eq!(
        field("voltages"),
        "48.00,48.00,48.00,48.00,48.00,48.00,0.00"
    );
    let speeds: Vec<f64> = field("joint_speeds")
        .split(',')
        .map(|v| v.parse().unwrap())
        .collect();
    assert_near(&speeds, &[0.0; 7], 0.0, "joint speeds at rest");
    assert_eq!(field("mtable"), "1,1,1,1,1,1,0,0");
    assert_eq!((field("state"), field("error")), ("2", "0"));

    // What the SDK put on the wire: the move, and nothing the mock does not model.
    let regs: Vec<u8> = mock.requests().iter().map(|r| r.register).collect();
    assert!(regs.contains(&reg::MOVE_JOINT), "{regs:?}");
    assert_modelled(&regs);
    assert!((moves[0].speed_rad_s - 0.8).abs() < 1e-6);
    assert!(moves[0].unused_slots.iter().all(|v| *v == 0.0));
}

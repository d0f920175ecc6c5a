//! Vendor-SDK conformance: UFACTORY's own `xarm-python-sdk` (1.18.4) drives the mock
//! controller through connect, enable, mode, state, a radian joint move with `wait=True` and
//! a read-back (`conformance/xarm_sdk.py`). If the mock disagrees with the real protocol
//! anywhere the SDK looks, this fails.
//!
//! Without the SDK (or python3) the test fails when `CI` is set and is skipped with a
//! message otherwise. The SDK can block forever on a peer that never answers, so the script
//! runs under a kill timeout. Ports are free ones: the script patches the SDK's hard-coded
//! port numbers in its own process.

use std::io::Write;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use easyhec_drivers::xarm::frame::reg;
use easyhec_drivers::xarm::Model;
use easyhec_mocks::xarm::{MockXArm, MockXArmConfig};

const SCRIPT_TIMEOUT: Duration = Duration::from_secs(60);

fn sdk_available() -> Result<(), String> {
    let out = Command::new("python3")
        .args(["-c", "import xarm.wrapper"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .output()
        .map_err(|e| format!("python3 cannot run ({e})"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err("the xarm SDK is not installed (python3 -m pip install xarm-python-sdk==1.18.4)".into())
    }
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

fn tempfile_dir() -> PathBuf {
    let dir = std::env::temp_dir().join(format!("easyhec-xarm-sdk-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn vendor_sdk_drives_the_mock_through_a_joint_move() {
    if let Err(why) = sdk_available() {
        if std::env::var_os("CI").is_some() {
            panic!("CI must install the vendor SDK: {why}");
        }
        // Straight to the stream: libtest would swallow eprintln! output of a passing test.
        let _ = writeln!(
            std::io::stderr(),
            "SKIPPED vendor_sdk_drives_the_mock_through_a_joint_move: {why}"
        );
        return;
    }
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
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

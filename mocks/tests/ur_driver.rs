//! The UR driver (`UrArm`: pyo3 + the vendor's ur_rtde) against the mock controller: moves
//! with the driver's own limits and speed clamp, and every failure path: a protective stop
//! mid-move (and clearing it), a pendant in local control, a link lost mid-move (reachable
//! again or not), and a peer that accepts and never answers.
//!
//! Needs the `ur` feature and `ur-rtde==1.6.5` for python3:
//! `cargo test --release -p easyhec-mocks --features ur --test ur_driver`.
#![cfg(feature = "ur")]

use std::time::{Duration, Instant};

use easyhec_drivers::ur::{UrArm, UrConfig};
use easyhec_drivers::{Arm, ArmStatus, DriverError};
use easyhec_mocks::ur::{MockUr, MockUrConfig, MockUrFault, DEMO_UR5E_START as START};

/// One UR test at a time: ur_rtde's calls hold the GIL (some for seconds, e.g. while its
/// control interface retries a lost controller), and every driver in this process shares it,
/// so parallel tests would starve each other's time-limited calls.
static SERIAL: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

const TARGET: [f64; 6] = [0.6, -1.6, 1.3, -1.0, -1.3, 0.3];

async fn mock(speedup: f64, faults: Vec<MockUrFault>) -> MockUr {
    let mut cfg = MockUrConfig::free_ports();
    cfg.speedup = speedup;
    cfg.faults = faults;
    MockUr::spawn(cfg).await.unwrap()
}

fn driver(mock: &MockUr) -> UrArm {
    let mut cfg = UrConfig::new(mock.host().to_string());
    cfg.poll_interval = Duration::from_millis(10);
    UrArm::new(cfg).unwrap()
}

fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn moves_read_back_and_the_driver_enforces_its_limits() {
    let _serial = SERIAL.lock().await;
    let m = mock(3.0, vec![]).await;
    let arm = driver(&m);
    assert_eq!(arm.read_joints().await.unwrap(), START);
    assert_eq!(arm.status().await.unwrap(), ArmStatus::Idle);
    assert!(
        m.script_uploads().is_empty(),
        "reading never starts a program"
    );

    // 2 rad/s asked, 1 rad/s (the cap) sent; ur_rtde's asynchronous moveJ.
    arm.move_to(&TARGET, 2.0)
        .await
        .unwrap()
        .wait()
        .await
        .unwrap();
    let q = arm.read_joints().await.unwrap();
    assert!(max_diff(&q, &TARGET) < 1e-9, "{q:?}");
    assert_eq!(m.true_joints(), TARGET);
    assert_eq!(arm.status().await.unwrap(), ArmStatus::Idle);
    let c = &m.commands()[0];
    assert!(
        c.accepted && c.asynchronous && c.outcome.as_deref() == Some("arrived"),
        "{c:?}"
    );
    assert_eq!((c.speed_rad_s, c.accel_rad_s2), (1.0, 1.4));
    assert_eq!(c.target, TARGET);
    assert_eq!(m.script_uploads().len(), 1);
    assert!(m
        .dashboard_commands()
        .iter()
        .any(|d| d == "is in remote control"));

    // Refused before the wire: elbow beyond ±π, NaN, wrong length, non-positive speed.
    let mut bad = TARGET;
    bad[2] = 3.3;
    for (q, speed, needle) in [
        (bad.to_vec(), 0.5, "elbow_joint"),
        (vec![f64::NAN; 6], 0.5, "outside its limits"),
        (vec![0.0; 5], 0.5, "5 target joints"),
        (TARGET.to_vec(), 0.0, "speed"),
    ] {
        match arm.move_to(&q, speed).await {
            Err(DriverError::Refused(msg)) => assert!(msg.contains(needle), "{msg}"),
            other => panic!("{q:?} at {speed}: {other:?}"),
        }
    }
    assert_eq!(
        m.commands().len(),
        1,
        "nothing refused reached the controller"
    );

    // A stop while moving leaves the arm short of the target, reported Stopped.
    // 0.3 rad at 0.3 rad/s: 1 s simulated, 330 ms here.
    let motion = arm.move_to(&START, 0.3).await.unwrap();
    tokio::time::sleep(Duration::from_millis(60)).await;
    arm.stop().await.unwrap();
    assert!(motion.wait().await.is_err());
    let q = m.true_joints();
    assert!(
        max_diff(&q, &START) > 0.05 && max_diff(&q, &TARGET) > 0.05,
        "{q:?}"
    );
    assert_eq!(arm.status().await.unwrap(), ArmStatus::Stopped);
    assert_eq!(m.commands()[1].outcome.as_deref(), Some("stopped"));
    assert!(m.script_commands().contains(&34), "stopJ went out");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn protective_stop_fails_the_move_and_clear_fault_recovers() {
    let _serial = SERIAL.lock().await;
    let stop = MockUrFault::ProtectiveStop {
        on_move: 0,
        at_fraction: 0.5,
    };
    // Real time: 0.3 rad at 1 rad/s, the stop 150 ms in, well after moveJ returned.
    let m = mock(1.0, vec![stop]).await;
    let arm = driver(&m);
    let e = arm
        .move_to(&TARGET, 1.0)
        .await
        .unwrap()
        .wait()
        .await
        .unwrap_err();
    assert!(
        matches!(&e, DriverError::MotionFailed(s) if s.contains("PROTECTIVE_STOP")),
        "{e}"
    );
    let q = m.true_joints();
    assert!(max_diff(&q, &TARGET) > 0.1, "halted halfway: {q:?}");
    assert!(matches!(arm.status().await.unwrap(), ArmStatus::Fault(s) if s.contains("unlock")));
    match arm.move_to(&START, 1.0).await {
        Err(DriverError::Refused(s)) => assert!(s.contains("PROTECTIVE_STOP"), "{s}"),
        other => panic!("{other:?}"),
    }
    assert_eq!(m.commands().len(), 1);
    arm.clear_fault().await.unwrap();
    assert!(m
        .dashboard_commands()
        .iter()
        .any(|d| d == "unlock protective stop"));
    arm.move_to(&TARGET, 1.0)
        .await
        .unwrap()
        .wait()
        .await
        .unwrap();
    assert_eq!(m.true_joints(), TARGET);
    assert_eq!(
        m.script_uploads().len(),
        2,
        "the paused script was replaced"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn local_control_is_refused_before_anything_moves() {
    let _serial = SERIAL.lock().await;
    let m = mock(5.0, vec![]).await;
    m.set_remote_control(false);
    let arm = driver(&m);
    assert_eq!(
        arm.read_joints().await.unwrap(),
        START,
        "reading needs no remote control"
    );
    match arm.move_to(&TARGET, 1.0).await {
        Err(DriverError::Refused(s)) => assert!(s.contains("Remote Control"), "{s}"),
        other => panic!("{other:?}"),
    }
    assert!(m.commands().is_empty() && m.script_uploads().is_empty());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn link_lost_mid_move_stops_the_arm() {
    let _serial = SERIAL.lock().await;
    // Real-time motion; the controller keeps moving after the drop, so only the driver's
    // stop over a new connection halts it.
    let drop = MockUrFault::DropMidMove {
        on_move: 0,
        at_fraction: 0.1,
        refuse_reconnect: false,
    };
    let m = mock(1.0, vec![drop]).await;
    let arm = driver(&m);
    let t = Instant::now();
    let e = arm
        .move_to(&TARGET, 1.0)
        .await
        .unwrap()
        .wait()
        .await
        .unwrap_err();
    let noticed = t.elapsed();
    assert!(
        matches!(&e, DriverError::Connection(s) if s.contains("link lost") && s.contains("arm stopped")),
        "{e}"
    );
    let q = m.true_joints();
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(m.true_joints(), q, "the arm stands still");
    assert!(
        max_diff(&q, &TARGET) > 0.05,
        "stopped short: {q:?} after {noticed:?}"
    );
    assert_eq!(arm.status().await.unwrap(), ArmStatus::Stopped);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn link_lost_for_good_is_a_connection_error() {
    let _serial = SERIAL.lock().await;
    // A controller that cannot be reached again: every call fails with a connection error.
    let drop = MockUrFault::DropMidMove {
        on_move: 0,
        at_fraction: 0.1,
        refuse_reconnect: true,
    };
    let m = {
        let mut cfg = MockUrConfig::free_ports();
        cfg.faults = vec![drop];
        cfg.halt_on_disconnect = true;
        MockUr::spawn(cfg).await.unwrap()
    };
    let arm = driver(&m);
    let e = arm
        .move_to(&TARGET, 1.0)
        .await
        .unwrap()
        .wait()
        .await
        .unwrap_err();
    assert!(
        matches!(&e, DriverError::Connection(s) if s.contains("could not stop")),
        "{e}"
    );
    assert!(matches!(
        arm.status().await,
        Err(DriverError::Connection(_))
    ));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_controller_is_a_timeout_not_a_hang() {
    let _serial = SERIAL.lock().await;
    // Accepts on all three ports, never answers.
    let mut listeners = Vec::new();
    let mut host = String::new();
    for attempt in 0..20u8 {
        let ip = format!(
            "127.{}.{}.{}",
            90 + attempt,
            std::process::id() % 250 + 1,
            7
        );
        let bound: std::io::Result<Vec<_>> = futures_bind(&ip).await;
        if let Ok(l) = bound {
            listeners = l;
            host = ip;
            break;
        }
    }
    assert_eq!(listeners.len(), 3);
    let mut cfg = UrConfig::new(host);
    cfg.call_timeout = Duration::from_millis(300);
    let arm = UrArm::new(cfg).unwrap();
    let t = Instant::now();
    let e = arm.read_joints().await.unwrap_err();
    assert!(matches!(e, DriverError::Timeout(_)), "{e}");
    assert!(t.elapsed() < Duration::from_secs(2), "{:?}", t.elapsed());
    let e = arm.move_to(&TARGET, 1.0).await.unwrap_err();
    assert!(matches!(e, DriverError::Timeout(_)), "{e}");
    drop(listeners);
}

async fn futures_bind(ip: &str) -> std::io::Result<Vec<tokio::net::TcpListener>> {
    let mut out = Vec::new();
    for port in [30004, 29999, 30003] {
        out.push(tokio::net::TcpListener::bind(format!("{ip}:{port}")).await?);
    }
    Ok(out)
}

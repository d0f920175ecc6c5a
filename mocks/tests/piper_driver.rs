//! The Piper driver (`PiperArm`) against the mock Piper on the in-process CAN bus: enable,
//! mode and targets on the wire, moves read back to the 0.001°, the driver's own limits and
//! speed cap, a collision fault, a silent arm.

use std::sync::Arc;
use std::time::{Duration, Instant};

use easyhec_drivers::piper::frame::{id, rad_to_millideg};
use easyhec_drivers::piper::{InProcessBus, PiperArm, PiperConfig};
use easyhec_drivers::{Arm, ArmStatus, DriverError};
use easyhec_mocks::piper::{MockPiper, MockPiperConfig, PiperFault};

const MILLIDEG: f64 = 0.001 * std::f64::consts::PI / 180.0;

fn setup(speedup: f64, faults: Vec<PiperFault>, cap: f64) -> (MockPiper, PiperArm) {
    let bus = InProcessBus::new(4096);
    let mock = MockPiper::spawn(
        MockPiperConfig {
            speedup,
            faults,
            ..Default::default()
        },
        Arc::new(bus.endpoint()),
    );
    let cfg = PiperConfig {
        speed_cap_rad_s: cap,
        poll_interval: Duration::from_millis(5),
        motion_timeout_margin: Duration::from_secs(2),
        arrival_tolerance_rad: 0.0,
        ..Default::default()
    };
    let arm = PiperArm::new(cfg, Arc::new(bus.endpoint())).unwrap();
    (mock, arm)
}

fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn enables_moves_and_reads_back_to_the_millidegree() {
    let (mock, arm) = setup(10.0, vec![], 1.0);
    let q0 = arm.read_joints().await.unwrap();
    assert!(max_diff(&q0, &[0.0, 0.5, -0.5, 0.0, 0.0, 0.0]) <= MILLIDEG / 2.0);
    let target = [0.3, 1.0, -0.9, 0.2, -0.4, 1.1];
    let t = Instant::now();
    arm.move_to(&target, 0.8)
        .await
        .unwrap()
        .wait()
        .await
        .unwrap();
    assert!(t.elapsed() < Duration::from_secs(2), "{:?}", t.elapsed());
    let q = arm.read_joints().await.unwrap();
    assert!(max_diff(&q, &target) <= MILLIDEG / 2.0 + 1e-12, "{q:?}");
    assert!(max_diff(&mock.true_joints(), &target) <= MILLIDEG / 2.0 + 1e-12);

    // On the wire: enable (motor 7) before anything else, then mode (CAN, MOVE J, 25 % =
    // floor(100 * 0.8 / pi)), then the three target frames in 0.001 deg big-endian.
    let rx = mock.received();
    assert_eq!(
        (rx[0].id, rx[0].data),
        (id::ENABLE, [7, 2, 0, 0, 0, 0, 0, 0])
    );
    let mode = rx.iter().position(|f| f.id == id::MODE).unwrap();
    assert!(rx[..mode].iter().all(|f| f.id == id::ENABLE));
    assert_eq!(rx[mode].data, [1, 1, 25, 0, 0, 0, 0, 0]);
    let want: Vec<i32> = target
        .iter()
        .map(|&v| rad_to_millideg(v).unwrap())
        .collect();
    assert_eq!(rx[mode + 1].id, id::JOINT_TARGET_12);
    assert_eq!(rx[mode + 1].data[..4], want[0].to_be_bytes());
    assert_eq!(rx[mode + 1].data[4..], want[1].to_be_bytes());
    assert_eq!(
        (rx[mode + 2].id, rx[mode + 3].id),
        (id::JOINT_TARGET_34, id::JOINT_TARGET_56)
    );
    let targets = mock.targets();
    assert!(!targets.is_empty());
    assert!(targets
        .iter()
        .all(|t| t.accepted && t.speed_pct == 25 && t.millideg.to_vec() == want));
    assert_eq!(arm.status().await.unwrap(), ArmStatus::Idle);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_speed_percentage_never_exceeds_the_cap() {
    let (mock, arm) = setup(20.0, vec![], 0.5);
    assert_eq!(
        (
            arm.speed_percent(10.0),
            arm.speed_percent(0.2),
            arm.speed_percent(1e-6)
        ),
        (15, 6, 1)
    );
    arm.move_to(&[0.2, 0.6, -0.6, 0.0, 0.0, 0.0], 10.0)
        .await
        .unwrap()
        .wait()
        .await
        .unwrap();
    let targets = mock.targets();
    // 15 % of pi rad/s = 0.471 rad/s <= 0.5.
    assert!(targets.iter().all(|t| t.speed_pct == 15), "{targets:?}");
    assert!(f64::from(targets[0].speed_pct) / 100.0 * std::f64::consts::PI <= 0.5);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn targets_outside_the_limits_are_refused_with_nothing_sent() {
    let (mock, arm) = setup(10.0, vec![], 1.0);
    arm.read_joints().await.unwrap();
    let before = mock.received().len();
    for target in [
        [0.0, -0.1, -0.5, 0.0, 0.0, 0.0], // J2 is 0 … 3.14
        [0.0, 0.5, 0.2, 0.0, 0.0, 0.0],   // J3 is −2.967 … 0
        [0.0, 0.5, -0.5, 0.0, 1.3, 0.0],  // J5 is ±1.22
        [f64::NAN, 0.5, -0.5, 0.0, 0.0, 0.0],
    ] {
        match arm.move_to(&target, 0.5).await {
            Err(DriverError::Refused(m)) => assert!(m.contains("outside its limits"), "{m}"),
            other => panic!("{target:?}: {other:?}"),
        }
    }
    assert!(matches!(
        arm.move_to(&[0.0; 5], 0.5).await,
        Err(DriverError::Refused(_))
    ));
    // Slower than the least speed byte (1% of full speed): moving would exceed the speed
    // the path was checked at.
    match arm.move_to(&[0.0, 0.5, -0.5, 0.0, 0.0, 0.0], 0.001).await {
        Err(DriverError::Refused(m)) => assert!(m.contains("least step"), "{m}"),
        other => panic!("{other:?}"),
    }
    tokio::time::sleep(Duration::from_millis(20)).await;
    assert_eq!(
        mock.received().len(),
        before,
        "a refused move sends nothing"
    );
    assert!(mock.targets().is_empty());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_collision_fails_the_move_with_the_decoded_status() {
    let faults = vec![PiperFault::Collision {
        on_move: 0,
        at_fraction: 0.5,
    }];
    let (mock, arm) = setup(10.0, faults, 1.0);
    let from = mock.true_joints();
    let target = [0.6, 0.5, -0.5, 0.0, 0.0, 0.0];
    match arm.move_to(&target, 1.0).await.unwrap().wait().await {
        Err(DriverError::MotionFailed(m)) => assert_eq!(m, "arm status 0x07: collision detected"),
        other => panic!("{other:?}"),
    }
    // Halted halfway along the line.
    assert!((mock.true_joints()[0] - (from[0] + 0.3)).abs() < MILLIDEG);
    assert!(matches!(arm.status().await.unwrap(), ArmStatus::Fault(m) if m.contains("collision")));
    assert!(
        matches!(arm.move_to(&target, 1.0).await, Err(DriverError::Refused(m)) if m.contains("clear_fault"))
    );
    arm.clear_fault().await.unwrap();
    assert!(mock
        .received()
        .iter()
        .any(|f| f.id == id::MOTION_CONTROL && f.data[0] == 2));
    arm.move_to(&target, 1.0)
        .await
        .unwrap()
        .wait()
        .await
        .unwrap();
    assert!(max_diff(&arm.read_joints().await.unwrap(), &target) <= MILLIDEG / 2.0 + 1e-12);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_arm_is_a_timeout_and_stop_holds_position() {
    let (mock, arm) = setup(1.0, vec![], 1.0);
    let motion = arm
        .move_to(&[0.5, 0.5, -0.5, 0.0, 0.0, 0.0], 0.5)
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(50)).await;
    arm.stop().await.unwrap();
    assert!(matches!(
        motion.wait().await,
        Err(DriverError::MotionFailed(_))
    ));
    let held = mock.targets().last().unwrap().millideg[0];
    assert!(
        held > 0 && held < rad_to_millideg(0.5).unwrap(),
        "held at {held}"
    );
    tokio::time::sleep(Duration::from_millis(30)).await;
    assert_eq!(arm.status().await.unwrap(), ArmStatus::Stopped);
    mock.set_silent(true);
    assert!(matches!(
        arm.read_joints().await,
        Err(DriverError::Timeout(_))
    ));
    assert!(matches!(arm.status().await, Err(DriverError::Timeout(_))));
}

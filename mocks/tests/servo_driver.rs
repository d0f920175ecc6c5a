//! The serial servo driver (`ServoArm`) against the mock bus on a pseudo-terminal: bring-up,
//! moves read back to the tick, the driver's own limits and speed clamp as seen on the wire,
//! a servo that stops answering and hardware errors, for both Dynamixel and Feetech.

use std::f64::consts::PI;
use std::time::{Duration, Instant};

use easyhec_drivers::dynamixel::packet::instruction;
use easyhec_drivers::dynamixel::{Family, ServoArm, ServoArmConfig, ServoJoint};
use easyhec_drivers::{Arm, ArmStatus, DriverError};
use easyhec_mocks::servo_bus::{MockServo, MockServoBus};

const TICK: f64 = 2.0 * PI / 4096.0;

fn joints(names: &[&str]) -> Vec<ServoJoint> {
    names
        .iter()
        .enumerate()
        .map(|(k, n)| ServoJoint::new(*n, k as u8 + 1))
        .collect()
}

/// Long enough that a loaded 2-core CI machine never misses a reply from the mock, short
/// enough that the silent-servo test stays quick.
const REPLY_TIMEOUT: Duration = Duration::from_millis(200);

fn config(family: Family, joints: Vec<ServoJoint>) -> ServoArmConfig {
    let mut c = ServoArmConfig::new(family, "unused", 1_000_000, joints);
    c.reply_timeout = REPLY_TIMEOUT;
    c.poll_interval = Duration::from_millis(5);
    c.arrival_tolerance_rad = 0.0; // one tick
    c.motion_timeout_margin = Duration::from_secs(2);
    c
}

fn setup(
    family: Family,
    servos: &[MockServo],
    speedup: f64,
    cfg: ServoArmConfig,
) -> (MockServoBus, ServoArm) {
    let (mock, port) = MockServoBus::spawn(family, servos, speedup).unwrap();
    let arm = ServoArm::with_port(cfg, Box::new(port)).unwrap();
    (mock, arm)
}

fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn dynamixel_bring_up_move_and_read_back_to_the_tick() {
    let mut extended = MockServo::new(3, 1024);
    extended.operating_mode = Some(4);
    let servos = [MockServo::new(1, 2048), MockServo::new(2, 3000), extended];
    let mut js = joints(&["base", "shoulder", "elbow"]);
    js[1].direction = -1;
    js[2].offset_rad = 0.25;
    let (mock, arm) = setup(
        Family::Dynamixel,
        &servos,
        20.0,
        config(Family::Dynamixel, js),
    );

    // Joints read before bring-up, through the tick mapping.
    let q0 = arm.read_joints().await.unwrap();
    assert!(max_diff(&q0, &[0.0, -(3000.0 - 2048.0) * TICK, 0.25 - 1024.0 * TICK]) < 1e-12);

    let target = [0.6, -0.4, -1.0];
    let t = Instant::now();
    arm.move_to(&target, 1.0)
        .await
        .unwrap()
        .wait()
        .await
        .unwrap();
    assert!(t.elapsed() < Duration::from_secs(2), "{:?}", t.elapsed());
    // Arrival means within one tick; the servo then finishes its last tick on its own, and
    // only once its moving flag clears must the reading be the target to the half tick.
    let settle = Instant::now();
    while arm.status().await.unwrap() != ArmStatus::Idle {
        assert!(settle.elapsed() < Duration::from_secs(1), "never settled");
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    let q = arm.read_joints().await.unwrap();
    assert!(max_diff(&q, &target) <= TICK / 2.0 + 1e-12, "{q:?}");
    let want = [
        2048 + (0.6 / TICK).round() as i64,
        2048 + (0.4 / TICK).round() as i64,
        2048 + ((-1.25) / TICK).round() as i64,
    ];
    for (id, w) in [1u8, 2, 3].iter().zip(want) {
        assert!(
            (mock.present_ticks(*id) - w).abs() <= 1,
            "servo {id}: {} vs {w}",
            mock.present_ticks(*id)
        );
    }

    // Bring-up on the wire: pings first, the EEPROM mode write only on the servo that needed
    // it (torque off just there), then torque on everywhere.
    let packets = mock.packets();
    let pings: Vec<u8> = packets
        .iter()
        .filter(|p| p.packet.instruction == instruction::PING)
        .map(|p| p.packet.id)
        .collect();
    assert_eq!(pings, [1, 2, 3]);
    let writes: Vec<(u8, Vec<u8>)> = packets
        .iter()
        .filter(|p| p.packet.instruction == instruction::WRITE)
        .map(|p| (p.packet.id, p.packet.params.clone()))
        .collect();
    assert_eq!(
        writes,
        vec![
            (3, vec![64, 0, 0]),
            (3, vec![11, 0, 3]),
            (1, vec![64, 0, 1]),
            (2, vec![64, 0, 1]),
            (3, vec![64, 0, 1]),
        ]
    );
    for id in 1..=3 {
        assert_eq!((mock.table_byte(id, 64), mock.table_byte(id, 11)), (1, 3));
    }
    // Goals: first "hold where you are", then the move with velocities scaled per joint so
    // all arrive together; the joint travelling farthest gets the full 1 rad/s.
    let goals = mock.goals();
    assert_eq!(goals.len(), 6);
    assert_eq!(
        goals[..3].iter().map(|g| g.goal_ticks).collect::<Vec<_>>(),
        [2048, 3000, 1024]
    );
    let mv = &goals[3..];
    assert_eq!(mv.iter().map(|g| g.goal_ticks).collect::<Vec<_>>(), want);
    let unit = 0.229 * 2.0 * PI / 60.0;
    let d: Vec<f64> = q0.iter().zip(&target).map(|(a, b)| (a - b).abs()).collect();
    let dmax = d.iter().cloned().fold(0.0, f64::max);
    assert!(
        (dmax - (-0.4 + (3000.0 - 2048.0) * TICK)).abs() < 1e-12,
        "the shoulder: {d:?}"
    );
    assert_eq!(
        mv[1].velocity_units,
        (1.0 / unit).floor() as i64,
        "41 units = 0.983 rad/s"
    );
    for k in [0, 2] {
        assert_eq!(
            mv[k].velocity_units,
            (d[k] / dmax / unit).floor() as i64,
            "joint {k}"
        );
    }
    assert!(mv.iter().all(|g| g.torque_on && g.accel_units >= 1));
    assert_eq!(arm.status().await.unwrap(), ArmStatus::Idle);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn speed_above_the_cap_is_clamped_on_the_wire() {
    let servos = [MockServo::new(1, 2048), MockServo::new(2, 2048)];
    let mut cfg = config(Family::Dynamixel, joints(&["a", "b"]));
    cfg.speed_cap_rad_s = 0.5;
    cfg.accel_rad_s2 = 2.0;
    let (mock, arm) = setup(Family::Dynamixel, &servos, 50.0, cfg);
    arm.move_to(&[0.8, -0.4], 10.0)
        .await
        .unwrap()
        .wait()
        .await
        .unwrap();
    let goals = mock.goals();
    let mv = &goals[goals.len() - 2..];
    let unit = 0.229 * 2.0 * PI / 60.0;
    let accel_unit = 214.577 * 2.0 * PI / 3600.0;
    assert_eq!(
        mv[0].velocity_units,
        (0.5 / unit).floor() as i64,
        "20 units = 0.48 rad/s"
    );
    assert_eq!(mv[1].velocity_units, (0.25 / unit).floor() as i64);
    assert_eq!(mv[0].accel_units, (2.0 / accel_unit).floor() as i64);
    // Nothing the bus ever received exceeds the cap or asks for "unlimited" (0).
    let cap_units = (0.5 / unit).floor() as i64;
    assert!(
        goals.iter().all(|g| g.velocity_units <= cap_units),
        "{goals:?}"
    );
    assert!(goals[2..]
        .iter()
        .all(|g| g.velocity_units >= 1 && g.accel_units >= 1));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn targets_outside_the_limits_are_refused_with_nothing_written() {
    let servos = [MockServo::new(1, 2048), MockServo::new(2, 2048)];
    let mut js = joints(&["pan", "lift"]);
    js[1].lower_rad = Some(-1.0);
    js[1].upper_rad = Some(1.0);
    let (mock, arm) = setup(
        Family::Dynamixel,
        &servos,
        50.0,
        config(Family::Dynamixel, js),
    );
    arm.bring_up().await.unwrap();
    let before = mock.packets().len();
    for target in [[0.0, 1.2], [0.0, f64::NAN], [3.5, 0.0]] {
        match arm.move_to(&target, 0.5).await {
            Err(DriverError::Refused(m)) => assert!(m.contains("outside its limits"), "{m}"),
            other => panic!("{target:?}: {other:?}"),
        }
    }
    assert!(matches!(
        arm.move_to(&[0.0], 0.5).await,
        Err(DriverError::Refused(_))
    ));
    assert!(matches!(
        arm.move_to(&[0.0, 0.0], -1.0).await,
        Err(DriverError::Refused(_))
    ));
    assert_eq!(
        mock.packets().len(),
        before,
        "a refused move writes nothing"
    );
    assert!(mock
        .goals()
        .iter()
        .all(|g| (g.goal_ticks - 2048).abs() <= (1.0 / TICK) as i64));
    // Slower than one velocity unit: moving would exceed the speed the path was checked at.
    match arm.move_to(&[0.5, 0.0], 0.001).await {
        Err(DriverError::Refused(m)) => assert!(m.contains("least velocity step"), "{m}"),
        other => panic!("{other:?}"),
    }
    assert!(mock
        .goals()
        .iter()
        .all(|g| (g.goal_ticks - 2048).abs() <= (1.0 / TICK) as i64));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_servo_that_stops_answering_is_a_timeout() {
    let servos = [MockServo::new(1, 2048), MockServo::new(2, 2048)];
    let (mock, arm) = setup(
        Family::Dynamixel,
        &servos,
        1.0,
        config(Family::Dynamixel, joints(&["a", "b"])),
    );
    // Mid-move: 1 rad at 0.5 rad/s takes 2 s; the servo goes quiet after 50 ms.
    let motion = arm.move_to(&[1.0, 0.5], 0.5).await.unwrap();
    tokio::time::sleep(Duration::from_millis(50)).await;
    mock.set_silent(2, true);
    let t = Instant::now();
    match motion.wait().await {
        Err(DriverError::Timeout(d)) => assert_eq!(d, REPLY_TIMEOUT),
        other => panic!("{other:?}"),
    }
    assert!(
        t.elapsed() < Duration::from_millis(1500),
        "{:?}",
        t.elapsed()
    );
    assert!(matches!(
        arm.read_joints().await,
        Err(DriverError::Timeout(_))
    ));
    mock.set_silent(2, false);
    assert_eq!(arm.read_joints().await.unwrap().len(), 2, "answers again");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hardware_error_fails_the_move_with_its_decoded_cause() {
    let servos = [MockServo::new(1, 2048), MockServo::new(2, 2048)];
    let (mock, arm) = setup(
        Family::Dynamixel,
        &servos,
        1.0,
        config(Family::Dynamixel, joints(&["shoulder", "elbow"])),
    );
    let motion = arm.move_to(&[0.5, 1.0], 0.5).await.unwrap();
    tokio::time::sleep(Duration::from_millis(50)).await;
    mock.inject_hardware_error(2, 0x20 | 0x04);
    match motion.wait().await {
        Err(DriverError::MotionFailed(m)) => assert_eq!(
            m,
            "servo 2 (elbow): overheating, overload (persistent load above the maximum torque)"
        ),
        other => panic!("{other:?}"),
    }
    assert!(matches!(arm.status().await.unwrap(), ArmStatus::Fault(m) if m.contains("overload")));
    // A new move is refused until the fault is cleared; clearing reboots the servo.
    assert!(
        matches!(arm.move_to(&[0.0, 0.0], 0.5).await, Err(DriverError::Refused(m)) if m.contains("clear_fault"))
    );
    arm.clear_fault().await.unwrap();
    assert!(mock
        .packets()
        .iter()
        .any(|p| p.packet.instruction == instruction::REBOOT && p.packet.id == 2));
    assert_eq!(mock.table_byte(2, 64), 1, "torque back on");
    // The hold written when the fault stopped the move lands a few ticks behind servo 1 (it
    // kept moving between the read and the write), so servo 1 may still be settling back onto
    // it: no fault, and at rest within a second.
    let settle_by = Instant::now() + Duration::from_secs(1);
    let stopped = loop {
        let s = arm.status().await.unwrap();
        if !matches!(s, ArmStatus::Moving) || Instant::now() >= settle_by {
            break s;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    };
    assert!(
        matches!(stopped, ArmStatus::Idle | ArmStatus::Stopped),
        "{stopped:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn feetech_so101_moves_stops_and_reports_conditions() {
    let names = [
        "shoulder_pan",
        "shoulder_lift",
        "elbow_flex",
        "wrist_flex",
        "wrist_roll",
        "gripper",
    ];
    let servos: Vec<MockServo> = (1..=6).map(|id| MockServo::new(id, 2048)).collect();
    let mut cfg = config(Family::Feetech, joints(&names));
    cfg.speed_cap_rad_s = 1.0;
    let (mock, arm) = setup(Family::Feetech, &servos, 20.0, cfg);
    let target = [0.3, -0.5, 0.9, 0.0, -0.2, 0.1];
    arm.move_to(&target, 3.0)
        .await
        .unwrap()
        .wait()
        .await
        .unwrap();
    assert!(max_diff(&arm.read_joints().await.unwrap(), &target) <= TICK / 2.0 + 1e-12);
    // Feetech framing on the wire: FF FF, then id (no FD 00).
    assert!(mock
        .packets()
        .iter()
        .all(|p| p.raw[..2] == [0xFF, 0xFF] && p.raw[2] != 0xFD));
    // EEPROM lock closed again and torque on; speed in steps/s, clamped to 1 rad/s.
    assert!((1..=6).all(|id| mock.table_byte(id, 40) == 1 && mock.table_byte(id, 55) == 1));
    let goals = mock.goals();
    let mv = &goals[goals.len() - 6..];
    assert_eq!(
        mv[2].velocity_units,
        (1.0 / TICK).floor() as i64,
        "651 steps/s"
    );
    assert!(goals.iter().all(|g| g.velocity_units <= 651));

    // stop holds the present position: goal = where the servo is, torque stays on.
    let motion = arm.move_to(&[0.0; 6], 0.05).await.unwrap();
    tokio::time::sleep(Duration::from_millis(30)).await;
    arm.stop().await.unwrap();
    assert!(matches!(
        motion.wait().await,
        Err(DriverError::MotionFailed(_))
    ));
    // It ran on for the instant between reading and writing, and comes back to the goal.
    tokio::time::sleep(Duration::from_millis(20)).await;
    let held = mock.goals().last().unwrap().goal_ticks;
    let p = mock.present_ticks(6);
    assert!(
        (p - held).abs() <= 1 && (p - 2048).abs() > 10,
        "held at {p}, goal {held}"
    );
    assert_eq!(arm.status().await.unwrap(), ArmStatus::Stopped);

    // A Feetech condition travels in every status byte.
    let motion = arm.move_to(&[0.0; 6], 0.05).await.unwrap();
    tokio::time::sleep(Duration::from_millis(20)).await;
    mock.inject_hardware_error(3, 0x04);
    match motion.wait().await {
        Err(DriverError::MotionFailed(m)) => assert_eq!(m, "servo 3 (elbow_flex): overheating"),
        other => panic!("{other:?}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn opens_the_port_by_its_path() {
    let (mock, port) =
        MockServoBus::spawn(Family::Dynamixel, &[MockServo::new(7, 1000)], 50.0).unwrap();
    let path = mock.port_name().to_string();
    drop(port);
    let mut cfg = config(Family::Dynamixel, vec![ServoJoint::new("only", 7)]);
    cfg.port = path;
    let arm = ServoArm::new(cfg).unwrap();
    arm.bring_up().await.unwrap();
    assert_eq!(arm.read_ticks().await.unwrap(), [1000]);
    // A missing servo id fails bring-up with a sentence naming it.
    let mut cfg = config(Family::Dynamixel, vec![ServoJoint::new("ghost", 9)]);
    cfg.port = mock.port_name().to_string();
    drop(arm);
    let err = ServoArm::new(cfg)
        .unwrap()
        .bring_up()
        .await
        .unwrap_err()
        .to_string();
    assert!(err.contains("servo 9 (ghost) does not answer"), "{err}");
}

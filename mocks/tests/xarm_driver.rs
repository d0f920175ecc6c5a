//! The real xArm driver against the mock controller: the SDK's scenario (connect, enable,
//! move with a speed, read back), the driver's own limits and speed clamp, and every failure
//! path: controller errors mid-move, lost links, stalls, silent controllers, a wrong model.

use std::time::{Duration, Instant};

use easyhec_drivers::xarm::frame::reg;
use easyhec_drivers::xarm::{Model, XArm, XArmConfig};
use easyhec_drivers::{Arm, ArmStatus, DriverError};
use easyhec_mocks::xarm::{MockFault, MockXArm, MockXArmConfig};

async fn mock(model: Model, speedup: f64, faults: Vec<MockFault>) -> MockXArm {
    let mut cfg = MockXArmConfig::free_ports(model);
    cfg.speedup = speedup;
    cfg.faults = faults;
    MockXArm::spawn(cfg).await.unwrap()
}

fn driver(mock: &MockXArm, model: Model) -> XArm {
    let mut cfg = XArmConfig::new(mock.command_addr().to_string(), model);
    cfg.poll_interval = Duration::from_millis(10);
    cfg.speed_cap_rad_s = 1.0;
    XArm::new(cfg).unwrap()
}

fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sdk_scenario_moves_and_reads_back_the_target() {
    let m = mock(Model::Xarm6, 20.0, vec![]).await;
    let arm = driver(&m, Model::Xarm6);
    let v = arm.connect().await.unwrap();
    assert_eq!((v.axes, v.device_type, v.firmware), (6, 6, (1, 12, 10)));
    assert_eq!(
        arm.status().await.unwrap(),
        ArmStatus::Stopped,
        "not enabled yet"
    );
    let target = [0.3, -0.5, -0.8, 0.1, 1.0, 0.2];
    let t = Instant::now();
    arm.move_to(&target, 0.8)
        .await
        .unwrap()
        .wait()
        .await
        .unwrap();
    // 1.0 rad at 0.8 rad/s = 1.25 s simulated, about 63 ms at 20x.
    assert!(t.elapsed() < Duration::from_secs(1), "{:?}", t.elapsed());
    let q = arm.read_joints().await.unwrap();
    assert!(max_diff(&q, &target) < 1e-6, "{q:?}");
    assert!(max_diff(&m.true_joints(), &target) < 1e-6);
    assert_eq!(arm.status().await.unwrap(), ArmStatus::Idle);
    // The bring-up went out in the documented order, then the move.
    let regs: Vec<u8> = m.requests().iter().map(|r| r.register).collect();
    let order = [
        reg::CLEAN_ERR,
        reg::CLEAN_WAR,
        reg::MOTION_EN,
        reg::SET_MODE,
        reg::SET_STATE,
        reg::MOVE_JOINT,
    ];
    let mut at = 0;
    for r in &regs {
        if at < order.len() && *r == order[at] {
            at += 1;
        }
    }
    assert_eq!(at, order.len(), "{regs:?}");
    let mv = &m.commands()[0];
    assert!(mv.accepted && mv.unused_slots == vec![0.0]);
    assert!((mv.speed_rad_s - 0.8).abs() < 1e-6 && (mv.accel_rad_s2 - 5.0).abs() < 1e-6);
    // Transaction ids count up from 1 on protocol id 2.
    let reqs = m.requests();
    assert_eq!(reqs[0].transaction, 1);
    assert!(reqs
        .windows(2)
        .all(|w| w[1].transaction == w[0].transaction + 1));
    assert!(reqs.iter().all(|r| r.protocol == 2));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn driver_refuses_out_of_limit_targets_and_clamps_speed() {
    let m = mock(Model::Uf850, 50.0, vec![]).await;
    let arm = driver(&m, Model::Uf850);
    // J3 of a UF850 ends at 3.5°; NaN and wrong lengths never reach the wire either.
    for bad in [
        vec![0.0, 0.0, 0.5, 0.0, 0.0, 0.0],
        vec![0.0, 0.0, f64::NAN, 0.0, 0.0, 0.0],
        vec![0.0; 7],
    ] {
        let e = arm.move_to(&bad, 0.5).await.unwrap_err();
        assert!(matches!(e, DriverError::Refused(_)), "{e}");
    }
    assert!(matches!(
        arm.move_to(&[0.0; 6], -1.0).await,
        Err(DriverError::Refused(_))
    ));
    assert!(m.commands().is_empty());
    // 3 rad/s requested, 1 rad/s (the cap) sent.
    let target = [0.5, 0.2, -0.4, 0.0, 0.3, 0.0];
    arm.move_to(&target, 3.0)
        .await
        .unwrap()
        .wait()
        .await
        .unwrap();
    let c = &m.commands()[0];
    assert!((c.speed_rad_s - 1.0).abs() < 1e-6, "{}", c.speed_rad_s);
    assert!(max_diff(&m.true_joints(), &target) < 1e-6);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn controller_error_mid_move_fails_the_motion_with_its_meaning() {
    let m = mock(
        Model::Xarm6,
        20.0,
        vec![MockFault::ErrorMidMove {
            on_move: 0,
            at_fraction: 0.5,
            code: 31,
        }],
    )
    .await;
    let arm = driver(&m, Model::Xarm6);
    let e = arm
        .move_to(&[1.0, 0.0, -0.5, 0.0, 0.5, 0.0], 1.0)
        .await
        .unwrap()
        .wait()
        .await
        .unwrap_err();
    match &e {
        DriverError::MotionFailed(s) => {
            assert!(s.contains("C31") && s.contains("collision"), "{s}")
        }
        other => panic!("{other}"),
    }
    assert!((m.true_joints()[0] - 0.5).abs() < 1e-9);
    assert!(matches!(arm.status().await.unwrap(), ArmStatus::Fault(s) if s.contains("C31")));
    // The next move is refused by the controller until the fault is cleared.
    let e = arm.move_to(&[0.0; 6], 1.0).await.unwrap_err();
    assert!(
        matches!(&e, DriverError::Refused(s) if s.contains("C31")),
        "{e}"
    );
    arm.clear_fault().await.unwrap();
    arm.move_to(&[0.0; 6], 1.0)
        .await
        .unwrap()
        .wait()
        .await
        .unwrap();
    assert_eq!(m.true_joints(), vec![0.0; 6]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn lost_link_mid_move_stops_the_arm_over_a_new_connection() {
    // Real time: 2 rad at 1 rad/s, the drop after 0.6 s, well clear of the end under load.
    let m = mock(
        Model::Xarm6,
        1.0,
        vec![MockFault::DropMidMove {
            on_move: 0,
            at_fraction: 0.3,
            refuse_reconnect: false,
        }],
    )
    .await;
    let arm = driver(&m, Model::Xarm6);
    let target = [2.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    let e = arm
        .move_to(&target, 1.0)
        .await
        .unwrap()
        .wait()
        .await
        .unwrap_err();
    assert!(
        matches!(&e, DriverError::Connection(s) if s.contains("stop sent")),
        "{e}"
    );
    // The mock kept moving after the drop (like a controller executing its queue) until the
    // driver's stop arrived on connection 2: it stands short of the target.
    let q = m.true_joints();
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(m.true_joints(), q, "the arm is stopped");
    assert!(q[0] > 0.59 && q[0] < 1.5, "{q:?}");
    assert_eq!(m.connections(), 2);
    let stop = m
        .requests()
        .into_iter()
        .find(|r| r.register == reg::SET_STATE && r.params == [4])
        .unwrap();
    assert_eq!(stop.connection, 2);
    assert_eq!(m.reported_state(), 4);
    // The next move re-arms from the driver's own stop, without clearing errors: a new
    // connection is no licence to reset the controller.
    let back = [q[0] - 0.05, 0.0, 0.0, 0.0, 0.0, 0.0];
    arm.move_to(&back, 1.0).await.unwrap().wait().await.unwrap();
    assert!(max_diff(&m.true_joints(), &back) < 1e-6);
    assert!(!m
        .requests()
        .iter()
        .any(|r| r.connection == 2 && [reg::CLEAN_ERR, reg::MOTION_EN].contains(&r.register)));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unreachable_controller_is_a_connection_error() {
    let m = mock(
        Model::Xarm6,
        5.0,
        vec![MockFault::DropMidMove {
            on_move: 0,
            at_fraction: 0.2,
            refuse_reconnect: true,
        }],
    )
    .await;
    let arm = driver(&m, Model::Xarm6);
    let e = arm
        .move_to(&[1.0, 0.0, 0.0, 0.0, 0.0, 0.0], 1.0)
        .await
        .unwrap()
        .wait()
        .await
        .unwrap_err();
    assert!(
        matches!(&e, DriverError::Connection(s) if s.contains("cannot be reached")),
        "{e}"
    );
    assert!(matches!(
        arm.read_joints().await,
        Err(DriverError::Connection(_))
    ));
    assert!(matches!(arm.stop().await, Err(DriverError::Connection(_))));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stalled_motion_times_out_and_is_stopped() {
    let m = mock(
        Model::Xarm6,
        10.0,
        vec![MockFault::Stall {
            on_move: 0,
            at_fraction: 0.5,
        }],
    )
    .await;
    let mut cfg = XArmConfig::new(m.command_addr().to_string(), Model::Xarm6);
    cfg.poll_interval = Duration::from_millis(10);
    cfg.motion_timeout_margin = Duration::from_millis(300);
    let arm = XArm::new(cfg).unwrap();
    let t = Instant::now();
    let e = arm
        .move_to(&[0.2, 0.0, 0.0, 0.0, 0.0, 0.0], 1.0)
        .await
        .unwrap()
        .wait()
        .await
        .unwrap_err();
    assert!(matches!(e, DriverError::Timeout(_)), "{e}");
    assert!(t.elapsed() < Duration::from_secs(2));
    assert_eq!(m.reported_state(), 4, "stopped by the driver");
    assert!((m.true_joints()[0] - 0.1).abs() < 1e-6);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn silent_controller_times_out_and_wrong_model_is_refused() {
    let m = mock(
        Model::Xarm6,
        1.0,
        vec![MockFault::NoReply {
            register: reg::GET_JOINT_POS,
        }],
    )
    .await;
    let mut cfg = XArmConfig::new(m.command_addr().to_string(), Model::Xarm6);
    cfg.reply_timeout = Duration::from_millis(200);
    let arm = XArm::new(cfg).unwrap();
    let e = arm.read_joints().await.unwrap_err();
    assert!(
        matches!(e, DriverError::Timeout(d) if d == Duration::from_millis(200)),
        "{e}"
    );
    // The link is re-established for the next call.
    assert_eq!(arm.state().await.unwrap(), 4);
    assert_eq!(m.connections(), 2);

    let seven = mock(Model::Xarm7, 1.0, vec![]).await;
    let e = driver(&seven, Model::Xarm6).connect().await.unwrap_err();
    let text = e.to_string();
    assert!(text.contains("7-axis") && text.contains("xarm6"), "{text}");
    assert!(!text.contains('\n'));
}

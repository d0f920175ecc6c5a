//! The mock xArm controller on the wire: the documented request/reply vectors byte for byte,
//! protocol-id handling, well-formed report streams at their rates, and the rich report's
//! layout at the offsets xarm-python-sdk 1.18.4 reads.

use std::time::{Duration, Instant};

use easyhec_drivers::xarm::frame::{encode_request, protocol, reg, MoveJoint};
use easyhec_drivers::xarm::{read_report, Model, Report};
use easyhec_mocks::xarm::{MockFault, MockXArm, MockXArmConfig};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

async fn exchange(stream: &mut TcpStream, request: &[u8]) -> Vec<u8> {
    stream.write_all(request).await.unwrap();
    let mut header = [0u8; 6];
    stream.read_exact(&mut header).await.unwrap();
    let len = usize::from(u16::from_be_bytes([header[4], header[5]]));
    let mut rest = vec![0u8; len];
    stream.read_exact(&mut rest).await.unwrap();
    let mut out = header.to_vec();
    out.extend(rest);
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn replays_the_documented_vectors_byte_for_byte() {
    let mut cfg = MockXArmConfig::free_ports(Model::Xarm6);
    cfg.speedup = 100.0;
    let mock = MockXArm::spawn(cfg).await.unwrap();
    let mut s = TcpStream::connect(mock.command_addr()).await.unwrap();
    // docs/protocols.md §1.3, in an order a fresh controller answers exactly as printed.
    let vectors = [
        ("00 01 00 02 00 03 0B 08 01", "00 01 00 02 00 02 0B 10"),
        ("00 01 00 02 00 02 0C 00", "00 01 00 02 00 02 0C 00"),
        ("00 01 00 02 00 01 0D", "00 01 00 02 00 03 0D 00 02"),
        ("00 01 00 02 00 01 0F", "00 01 00 02 00 04 0F 00 00 00"),
        ("00 01 00 02 00 03 13 00 00", "00 01 00 02 00 02 13 00"),
        (
            "00 01 00 02 00 29 17 92 0A 86 3F 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 \
             00 00 00 00 00 00 00 00 C2 B8 B2 3E 58 A0 0B 41 00 00 00 00",
            "00 01 00 02 00 04 17 00 00 01",
        ),
    ];
    for (request, reply) in vectors {
        assert_eq!(
            exchange(&mut s, &hex(request)).await,
            hex(reply),
            "{request}"
        );
    }
    // π/3 at 20°/s takes 3 s simulated, 30 ms here.
    tokio::time::sleep(Duration::from_millis(150)).await;
    let mut joints = hex("00 01 00 02 00 1E 2A 00 92 0A 86 3F");
    joints.extend([0u8; 24]);
    assert_eq!(exchange(&mut s, &hex("00 01 00 02 00 01 2A")).await, joints);
    let log = mock.commands();
    assert_eq!(log.len(), 1);
    assert!(log[0].accepted);
    assert_eq!(log[0].outcome.as_deref(), Some("arrived"));
    assert_eq!(log[0].speed_rad_s, f64::from(20f32.to_radians()));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn echoes_protocol_3_ignores_heartbeats_and_refuses_unsafe_moves() {
    let mock = MockXArm::spawn(MockXArmConfig::free_ports(Model::Lite6))
        .await
        .unwrap();
    let mut s = TcpStream::connect(mock.command_addr()).await.unwrap();
    // A heartbeat gets no answer: the next reply on the stream is the GET_STATE one.
    s.write_all(&hex("00 00 00 01 00 02 00 00")).await.unwrap();
    assert_eq!(
        exchange(&mut s, &hex("01 02 00 03 00 01 0D")).await,
        hex("01 02 00 03 00 03 0D 10 04"),
        "disabled: state 4 with the not-ready bit"
    );
    let version = exchange(&mut s, &hex("00 05 00 03 00 01 01")).await;
    assert_eq!(&version[..8], &hex("00 05 00 03 00 2A 01 10")[..]);
    assert!(String::from_utf8_lossy(&version[8..]).starts_with("6,9,"));
    for request in ["00 06 00 03 00 03 0B 08 01", "00 07 00 03 00 02 0C 00"] {
        exchange(&mut s, &hex(request)).await;
    }
    // J3 of a Lite 6 stops at −3.5°: −0.5 rad is refused with C23 and the error bit.
    let mut params = Vec::new();
    for v in [0.0f32, 0.0, -0.5, 0.0, 0.0, 0.0, 0.0, 0.5, 5.0, 0.0] {
        params.extend(v.to_le_bytes());
    }
    let mut request = hex("00 08 00 03 00 29 17");
    request.extend(&params);
    let reply = exchange(&mut s, &request).await;
    assert_eq!(reply[7] & 0x40, 0x40, "error bit");
    assert_eq!(
        exchange(&mut s, &hex("00 09 00 03 00 01 0F")).await,
        hex("00 09 00 03 00 04 0F 50 17 00")
    );
    // A speed over the cap is refused with C24 (after clearing and re-arming).
    for request in [
        "00 0A 00 03 00 01 10",
        "00 0B 00 03 00 03 0B 08 01",
        "00 0C 00 03 00 02 0C 00",
    ] {
        exchange(&mut s, &hex(request)).await;
    }
    let mut fast = Vec::new();
    for v in [0.1f32, 0.0, 0.5, 0.0, 0.0, 0.0, 0.0, 4.0, 5.0, 0.0] {
        fast.extend(v.to_le_bytes());
    }
    let mut request = hex("00 0D 00 03 00 29 17");
    request.extend(&fast);
    exchange(&mut s, &request).await;
    let codes = exchange(&mut s, &hex("00 0E 00 03 00 01 0F")).await;
    assert_eq!(codes[8], 24);
    let log = mock.commands();
    assert_eq!(log.len(), 2);
    assert!(log.iter().all(|c| !c.accepted));
    assert!(log[0].outcome.as_deref().unwrap().contains("C23"));
    assert!(log[1].outcome.as_deref().unwrap().contains("C24"));
    assert_eq!(mock.true_joints(), vec![0.0; 6], "nothing moved");
    // Modbus-TCP gets "illegal function".
    assert_eq!(
        exchange(&mut s, &hex("00 10 00 00 00 06 01 04 00 59 00 06")).await,
        hex("00 10 00 00 00 03 01 84 01")
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn report_ports_stream_well_formed_frames_at_their_rates() {
    let mut cfg = MockXArmConfig::free_ports(Model::Xarm7);
    cfg.start = Some(vec![0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7]);
    let mock = MockXArm::spawn(cfg).await.unwrap();
    let mut real = TcpStream::connect(mock.real_report_addr().unwrap())
        .await
        .unwrap();
    let t = Instant::now();
    for _ in 0..20 {
        let r = read_report(&mut real).await.unwrap();
        assert!(r.normal.is_none());
        assert_eq!(r.joints_rad[6], 0.7);
        assert_eq!(r.state, 4);
    }
    let real_s = t.elapsed().as_secs_f64();
    assert!(
        (0.15..1.0).contains(&real_s),
        "20 real frames took {real_s:.3} s"
    );
    let mut normal = TcpStream::connect(mock.normal_report_addr().unwrap())
        .await
        .unwrap();
    let t = Instant::now();
    let mut raw = vec![0u8; 145];
    normal.read_exact(&mut raw).await.unwrap();
    assert_eq!(&raw[..4], &145u32.to_be_bytes());
    for _ in 0..2 {
        let r = read_report(&mut normal).await.unwrap();
        let n = r.normal.unwrap();
        assert_eq!((n.error_code, n.motors_enabled), (0, 0));
    }
    let normal_s = t.elapsed().as_secs_f64();
    assert!(
        (0.35..1.2).contains(&normal_s),
        "3 normal frames took {normal_s:.3} s"
    );
}

/// One whole frame from a report port, read by its length header, on a fresh connection (the
/// first frame goes out at once, so it shows the controller as it is now).
async fn first_frame(addr: std::net::SocketAddr) -> Vec<u8> {
    let mut stream = TcpStream::connect(addr).await.unwrap();
    let mut frame = vec![0u8; 4];
    stream.read_exact(&mut frame).await.unwrap();
    let len = u32::from_be_bytes([frame[0], frame[1], frame[2], frame[3]]) as usize;
    assert!((4..=2048).contains(&len), "frame length {len}");
    frame.resize(len, 0);
    stream.read_exact(&mut frame[4..]).await.unwrap();
    frame
}

fn f32_at(frame: &[u8], offset: usize) -> f32 {
    f32::from_le_bytes(frame[offset..offset + 4].try_into().unwrap())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rich_report_is_the_normal_frame_plus_the_sdk_tail() {
    let start = vec![0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7];
    let mut cfg = MockXArmConfig::free_ports(Model::Xarm7);
    cfg.start = Some(start.clone());
    // The move below stalls half-way and keeps reporting "moving": frames read after it
    // started show it in motion, however late they are read.
    cfg.faults = vec![MockFault::Stall {
        on_move: 0,
        at_fraction: 0.5,
    }];
    let (speed_cap, accel_cap) = (cfg.speed_cap_rad_s as f32, cfg.accel_cap_rad_s2 as f32);
    let mock = MockXArm::spawn(cfg).await.unwrap();
    let rich_addr = mock.rich_report_addr().unwrap();

    // At rest, motors off. Offsets below are xarm-python-sdk 1.18.4's (docs/protocols.md §1.6.3).
    let rest = first_frame(rich_addr).await;
    assert_eq!(rest.len(), 587);
    assert_eq!(&rest[..4], &587u32.to_be_bytes());
    // It opens with the normal frame, byte for byte apart from the length.
    let normal = first_frame(mock.normal_report_addr().unwrap()).await;
    assert_eq!(&rest[4..145], &normal[4..145]);
    let r = Report::parse(&rest).unwrap();
    assert_eq!(r.joints_rad[6], 0.7);
    assert_eq!((r.state, r.mode), (4, 0));
    let n = r.normal.unwrap();
    assert_eq!((n.error_code, n.motors_enabled, n.brakes), (0, 0, 0));
    // Identity: device type, axes, master and slave ids, firmware text.
    assert_eq!(
        &rest[145..149],
        &[Model::Xarm7.device_type(), 7, 0xAA, 0x55]
    );
    assert!(
        rest[151..181].starts_with(b"v1.12.10\0"),
        "{:?}",
        &rest[151..181]
    );
    // Joint acceleration and speed limits are the mock's caps.
    assert_eq!(
        (f32_at(&rest, 209), f32_at(&rest, 217)),
        (accel_cap, speed_cap)
    );
    // No servo faults; temperatures; nothing moving.
    assert!(rest[229..245].iter().all(|&b| b == 0));
    assert_eq!(&rest[245..252], &[30; 7]);
    for k in 0..8 {
        assert_eq!(f32_at(&rest, 252 + 4 * k), 0.0, "speed slot {k}");
    }
    // Joint voltages, u16 BE in hundredths of a volt.
    for k in 0..7 {
        assert_eq!(&rest[341 + 2 * k..343 + 2 * k], &4800u16.to_be_bytes());
    }
    // Reduced-mode joint ranges: the model's limits.
    for (k, (lo, hi)) in Model::Xarm7.joint_limits().into_iter().enumerate() {
        let at = 516 + 8 * k;
        assert_eq!(
            (f32_at(&rest, at), f32_at(&rest, at + 4)),
            (lo as f32, hi as f32)
        );
    }

    // Enable, ready, and a move: J1 +0.5 rad, J7 -0.25 rad at 0.5 rad/s.
    let mut s = TcpStream::connect(mock.command_addr()).await.unwrap();
    let target = [0.6, 0.2, 0.3, 0.4, 0.5, 0.6, 0.45];
    let requests = [
        (reg::MOTION_EN, vec![8, 1]),
        (reg::SET_MODE, vec![0]),
        (reg::SET_STATE, vec![0]),
        (reg::MOVE_JOINT, MoveJoint::new(&target, 0.5, 5.0).encode()),
    ];
    for (t, (register, params)) in requests.into_iter().enumerate() {
        let request = encode_request(t as u16 + 1, protocol::PRIVATE, register, &params);
        exchange(&mut s, &request).await;
    }
    assert!(mock.commands()[0].accepted, "{:?}", mock.commands());

    let moving = first_frame(rich_addr).await;
    assert_eq!(moving.len(), 587);
    let r = Report::parse(&moving).unwrap();
    assert_eq!(r.state, 1, "moving");
    assert_eq!(r.normal.unwrap().motors_enabled, 0x7F);
    // (The joints that stay put move by the f32 rounding of their targets: nearly 0.)
    let speeds: Vec<f32> = (0..7).map(|k| f32_at(&moving, 256 + 4 * k)).collect();
    let want = [0.5, 0.0, 0.0, 0.0, 0.0, 0.0, -0.25];
    assert!(
        speeds.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-6),
        "{speeds:?}"
    );

    // An error shows in the normal part of the rich frame too.
    mock.inject_error(31);
    let stopped = first_frame(rich_addr).await;
    let r = Report::parse(&stopped).unwrap();
    assert_eq!((r.state, r.normal.unwrap().error_code), (4, 31));
    assert!((0..7).all(|k| f32_at(&stopped, 256 + 4 * k) == 0.0));
}

//! The mock xArm controller on the wire: the documented request/reply vectors byte for byte,
//! protocol-id handling, and well-formed report streams at their rates.

use std::time::{Duration, Instant};

use easyhec_drivers::xarm::{read_report, Model};
use easyhec_mocks::xarm::{MockXArm, MockXArmConfig};
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

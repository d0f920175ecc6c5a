//! The mock UR controller on the wire, without ur_rtde: RTDE bytes against the protocol
//! brief's test vectors (§2.2), recipe ids and NOT_FOUND, the dashboard's greeting and
//! replies, the control script's register handshake driven by hand (a moveJ the arm executes,
//! one outside the UR5e limits that it refuses), and the `easyhec-mock ur` binary.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

use easyhec_mocks::ur::wire::{self, kind, FieldType, Value};
use easyhec_mocks::ur::{read_actual_q, MockUr, MockUrConfig, DEMO_UR5E_START};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader as AsyncBufReader};
use tokio::net::TcpStream;

async fn exchange(s: &mut TcpStream, raw: &[u8]) -> wire::Package {
    s.write_all(raw).await.unwrap();
    loop {
        let p = wire::read_package(s).await.unwrap().unwrap();
        if p.kind != kind::DATA {
            return p;
        }
    }
}

/// `output_int_register_0` of the next data package (recipe: actual_q, robot_mode, reg0).
async fn reg0(s: &mut TcpStream, types: &[FieldType]) -> i64 {
    let p = wire::read_package(s).await.unwrap().unwrap();
    match &wire::decode_values(types, &p.payload[1..]).unwrap()[2] {
        Value::Int(v) => *v,
        other => panic!("{other:?}"),
    }
}

fn package(k: u8, payload: &[u8]) -> Vec<u8> {
    wire::Package {
        kind: k,
        payload: payload.to_vec(),
    }
    .encode()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rtde_bytes_match_the_brief_and_the_script_handshake_moves_the_arm() {
    let mut cfg = MockUrConfig::any_ports();
    cfg.speedup = 50.0;
    let m = MockUr::spawn(cfg).await.unwrap();
    let mut s = TcpStream::connect(m.rtde_addr()).await.unwrap();
    // V request 00 05 56 00 02 → 00 04 56 01.
    s.write_all(&[0x00, 0x05, 0x56, 0x00, 0x02]).await.unwrap();
    let mut reply = [0u8; 4];
    tokio::io::AsyncReadExt::read_exact(&mut s, &mut reply)
        .await
        .unwrap();
    assert_eq!(reply, [0x00, 0x04, 0x56, 0x01]);
    // v → 00 13 76 5.11.1.108318.
    let v = exchange(&mut s, &[0x00, 0x03, 0x76]).await;
    assert_eq!(
        v.encode(),
        [
            &[0x00, 0x13, 0x76][..],
            &[0, 0, 0, 5, 0, 0, 0, 0x0B, 0, 0, 0, 1, 0, 1, 0xA7, 0x1E]
        ]
        .concat()
    );
    // An unknown name is NOT_FOUND and sets up nothing.
    let mut o = 125.0f64.to_be_bytes().to_vec();
    o.extend_from_slice(b"actual_q,no_such_thing");
    let r = exchange(&mut s, &package(kind::SETUP_OUTPUTS, &o)).await;
    assert_eq!(r.payload, [&[0u8][..], b"VECTOR6D,NOT_FOUND"].concat());
    // The brief's O request (with ur_rtde's trailing comma) → id, then the types.
    let mut o = 500.0f64.to_be_bytes().to_vec();
    o.extend_from_slice(b"actual_q,robot_mode,output_int_register_0,");
    let r = exchange(&mut s, &package(kind::SETUP_OUTPUTS, &o)).await;
    assert_eq!(r.payload[1..], *b"VECTOR6D,INT32,INT32");
    // Input recipes get ids 1, 2 in setup order.
    let names = ["input_int_register_0,input_double_register_0,input_double_register_1,input_double_register_2,input_double_register_3,input_double_register_4,input_double_register_5,input_double_register_6,input_double_register_7,input_int_register_1", "input_int_register_0"];
    for (i, n) in names.iter().enumerate() {
        let r = exchange(&mut s, &package(kind::SETUP_INPUTS, n.as_bytes())).await;
        assert_eq!(r.payload[0] as usize, i + 1);
    }
    assert_eq!(
        exchange(&mut s, &package(kind::START, &[])).await.payload,
        [1]
    );
    // The first data package: [id][6 f64 actual_q][i32 robot_mode][i32 reg0].
    let first = wire::read_package(&mut s).await.unwrap().unwrap();
    assert_eq!(first.kind, kind::DATA);
    assert_eq!(first.encode().len(), 3 + 1 + 48 + 4 + 4);
    let types = [FieldType::Vector6d, FieldType::Int32, FieldType::Int32];
    let vals = wire::decode_values(&types, &first.payload[1..]).unwrap();
    assert_eq!(vals[0], Value::Doubles(DEMO_UR5E_START.to_vec()));
    assert_eq!(vals[1], Value::Int(7), "RUNNING");
    assert_eq!(vals[2], Value::Int(0), "no program yet");

    // Upload a (stand-in) control script: the program starts, reg0 = 1 (ready).
    let mut script = TcpStream::connect(m.script_addr()).await.unwrap();
    script
        .write_all(b"def rtde_control():\n  textmsg(\"x\")\nend\n")
        .await
        .unwrap();
    let mut ready = 0;
    for _ in 0..200 {
        ready = reg0(&mut s, &types).await;
        if ready == 1 {
            break;
        }
    }
    assert_eq!(ready, 1);
    // moveJ on recipe 1: [1][q][speed 1.0][acc 1.4][async 1], then 0 on recipe 2.
    let movej = |q: [f64; 6]| {
        let mut p = vec![1u8];
        wire::encode_value(&mut p, FieldType::Int32, &Value::Int(1));
        for v in q.iter().chain(&[1.0, 1.4]) {
            wire::encode_value(&mut p, FieldType::Double, &Value::Double(*v));
        }
        wire::encode_value(&mut p, FieldType::Int32, &Value::Int(1));
        package(kind::DATA, &p)
    };
    let clear = package(kind::DATA, &[2, 0, 0, 0, 0]);
    let target = [0.5, -1.7, 1.4, -1.1, -1.4, 0.3];
    s.write_all(&movej(target)).await.unwrap();
    s.write_all(&clear).await.unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(m.true_joints(), target);
    let bad = [0.5, -1.7, 3.3, -1.1, -1.4, 0.3];
    s.write_all(&movej(bad)).await.unwrap();
    tokio::time::sleep(Duration::from_millis(50)).await;
    assert_eq!(m.true_joints(), target, "the elbow beyond ±π is refused");
    let log = m.commands();
    assert_eq!(log.len(), 2);
    assert!(log[0].accepted && log[0].outcome.as_deref() == Some("arrived"));
    assert!(!log[1].accepted && log[1].outcome.as_deref().unwrap().contains("joint limits"));
    assert_eq!(
        m.modes().2,
        1,
        "the refused move ended the program (runtime STOPPED)"
    );
    assert_eq!(
        read_actual_q(&m.rtde_addr().to_string(), Duration::from_secs(2))
            .await
            .unwrap(),
        target
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn dashboard_greets_and_answers_and_local_control_refuses() {
    let m = MockUr::spawn(MockUrConfig::any_ports()).await.unwrap();
    let s = TcpStream::connect(m.dashboard_addr()).await.unwrap();
    let (r, mut w) = s.into_split();
    let mut lines = AsyncBufReader::new(r).lines();
    assert_eq!(
        lines.next_line().await.unwrap().unwrap(),
        "Connected: Universal Robots Dashboard Server"
    );
    let mut ask = async |cmd: &str| {
        w.write_all(format!("{cmd}\n").as_bytes()).await.unwrap();
        lines.next_line().await.unwrap().unwrap()
    };
    assert_eq!(ask("robotmode").await, "Robotmode: RUNNING");
    assert_eq!(ask("safetystatus").await, "Safetystatus: NORMAL");
    assert_eq!(ask("is in remote control").await, "true");
    assert!(ask("PolyscopeVersion")
        .await
        .starts_with("URSoftware 5.11.1.108318 ("));
    m.protective_stop();
    assert_eq!(ask("safetymode").await, "Safetymode: PROTECTIVE_STOP");
    m.set_remote_control(false);
    assert!(ask("unlock protective stop")
        .await
        .contains("remote control"));
    m.set_remote_control(true);
    assert_eq!(
        ask("unlock protective stop").await,
        "Protective stop releasing"
    );
    assert_eq!(ask("power off").await, "Powering off");
    assert_eq!(ask("robotmode").await, "Robotmode: POWER_OFF");
    assert_eq!(ask("power on").await, "Powering on");
    assert_eq!(ask("brake release").await, "Brake releasing");
    assert_eq!(ask("robotmode").await, "Robotmode: RUNNING");
    assert!(ask("fly").await.starts_with("could not understand"));
}

#[test]
fn ur_subcommand_listens_where_it_says() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_easyhec-mock"))
        .args(["ur", "--free-ports", "--start=0.1,-1.5,1.2,-1,-1.5,0"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("easyhec-mock starts");
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let addr = line
        .split("RTDE on ")
        .nth(1)
        .and_then(|rest| rest.split(',').next())
        .unwrap_or_else(|| panic!("no RTDE address in {line:?}"))
        .trim()
        .to_string();
    assert!(
        line.contains("dashboard on") && line.contains("script on"),
        "{line}"
    );
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let q = rt.block_on(read_actual_q(&addr, Duration::from_secs(2)));
    let _ = child.kill();
    let _ = child.wait();
    assert_eq!(q.unwrap(), [0.1, -1.5, 1.2, -1.0, -1.5, 0.0]);
}

#[test]
fn ur_subcommand_bad_arguments_get_one_error_line() {
    for (args, needle) in [
        (vec!["ur", "--free-ports", "--start=1,2"], "2 start joints"),
        (vec!["ur", "--free-ports", "--speed-cap=-1"], "--speed-cap"),
        (
            vec!["ur", "--free-ports", "--start=0,0,4,0,0,0"],
            "outside the joint limits",
        ),
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_easyhec-mock"))
            .args(&args)
            .output()
            .unwrap();
        assert!(!out.status.success(), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
        assert!(err.starts_with("error: ") && err.contains(needle), "{err}");
    }
}

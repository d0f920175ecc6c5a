//! The `easyhec-mock` binary: `xarm --free-ports` prints where it listens and serves the
//! protocol there; bad arguments get one error line and a non-zero exit.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};

use easyhec_drivers::xarm::{Model, XArm, XArmConfig};
use easyhec_drivers::Arm;

#[test]
fn xarm_subcommand_listens_where_it_says() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_easyhec-mock"))
        .args([
            "xarm",
            "--free-ports",
            "--model",
            "lite6",
            "--start=0.1,0,0.2,0,0,-0.3",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("easyhec-mock starts");
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let addr = line
        .split("commands on ")
        .nth(1)
        .and_then(|rest| rest.split(',').next())
        .unwrap_or_else(|| panic!("no command address in {line:?}"))
        .trim()
        .to_string();
    assert!(
        line.contains("lite6") && line.contains("real report"),
        "{line}"
    );
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let q = rt.block_on(async {
        XArm::new(XArmConfig::new(addr, Model::Lite6))
            .unwrap()
            .read_joints()
            .await
    });
    let _ = child.kill();
    let _ = child.wait();
    let q = q.unwrap();
    let want = [0.1, 0.0, 0.2, 0.0, 0.0, -0.3];
    assert!(
        q.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-6),
        "{q:?}"
    );
}

#[test]
fn bad_arguments_get_one_error_line() {
    for (args, needle) in [
        (vec!["xarm", "--free-ports", "--model", "xarm9"], "xarm9"),
        (
            vec!["xarm", "--free-ports", "--start=1,2"],
            "2 start joints",
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

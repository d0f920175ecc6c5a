//! The daemon survives its clients and its disk: a client that hangs up mid-check, a cancel
//! that races the end of a run, a start that cannot be written, a history that keeps
//! growing, and requests that are almost right (an array body, a token with extra spaces,
//! a flood of plan overlays, a result that does not fit its run).

mod common;

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use common::daemon::{call, call_as, real_time_arm, start, wait_final, write_config, TOKEN};
use serde_json::{json, Value};

/// Sends a raw request head (and body) and returns the status code of the reply.
fn raw_status(base: &str, head: &str, body: &str) -> u16 {
    let addr = base.trim_start_matches("http://");
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    write!(
        s,
        "{head}Content-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    )
    .unwrap();
    let mut reply = String::new();
    let _ = s.read_to_string(&mut reply);
    reply
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0)
}

fn calibrate_once(base: &str) -> Value {
    let (code, body) = call("POST", &format!("{base}/api/v1/calibrations"), None);
    assert_eq!(code, 202, "{body}");
    wait_final(base, body["id"].as_str().unwrap())
}

#[test]
fn a_client_that_hangs_up_during_a_check_leaves_the_arm_free() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |c| {
        real_time_arm(c);
        c.daemon.check_pose = Some(vec![0.6, -0.3, -0.7, 0.0, 1.0, 0.4]);
    });
    let d = start(&config, &dir.path().join("data"));
    let base = d.base.clone();
    assert_eq!(calibrate_once(&base)["state"], "succeeded");
    let arm = d.daemon.cell().sim_arm().cloned().unwrap();
    let moves_before = arm.commands().len();

    // The check's move to its pose takes about a second in real time; hang up at 0.3 s.
    let addr = base.trim_start_matches("http://");
    let mut s = TcpStream::connect(addr).unwrap();
    write!(
        s,
        "POST /api/v1/checks HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {TOKEN}\r\nContent-Length: 0\r\n\r\n"
    )
    .unwrap();
    std::thread::sleep(Duration::from_millis(300));
    drop(s);

    let started = Instant::now();
    let check = loop {
        let (code, body) = call("POST", &format!("{base}/api/v1/checks"), None);
        if code == 200 {
            break body;
        }
        assert_eq!(code, 409, "{body}");
        assert!(
            started.elapsed() < Duration::from_secs(30),
            "checks still refused 30 s after the client left: {body}"
        );
        std::thread::sleep(Duration::from_millis(200));
    };
    assert_eq!(check["stale"], false, "{check}");
    // The abandoned check ran to its end and was recorded, beside the one just answered.
    let (_, checks) = call("GET", &format!("{base}/api/v1/checks"), None);
    assert!(checks["checks"].as_array().unwrap().len() >= 2, "{checks}");
    assert!(
        arm.commands().len() > moves_before,
        "the check moved the arm"
    );
    let (code, body) = call(
        "POST",
        &format!("{base}/api/v1/calibrations"),
        Some(&json!({"dry_run": true, "max_views": 2})),
    );
    assert_eq!(code, 202, "{body}");
    wait_final(&base, body["id"].as_str().unwrap());
}

/// How many cancel-versus-finish races to run: `EASYHEC_CANCEL_RACES`, else 24 (each is a
/// short calibration; 200 were run for docs/daemon.md).
fn races() -> usize {
    std::env::var("EASYHEC_CANCEL_RACES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(24)
}

#[test]
fn a_cancel_answered_202_always_wins_the_race_with_the_finish() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |c| {
        c.calibration.max_views = 2;
        c.calibration.min_views = 2;
    });
    let d = start(&config, &dir.path().join("data"));
    let base = d.base.clone();
    // One run sets the time scale; cancels then land from the middle to just past the end.
    let t = Instant::now();
    calibrate_once(&base);
    let span = t.elapsed();
    let (mut won, mut late) = (0, 0);
    for k in 0..races() {
        let (code, body) = call("POST", &format!("{base}/api/v1/calibrations"), None);
        assert_eq!(code, 202, "{body}");
        let id = body["id"].as_str().unwrap().to_string();
        let fraction = 0.5 + 0.7 * k as f64 / races() as f64;
        std::thread::sleep(span.mul_f64(fraction));
        let (code, reply) = call(
            "POST",
            &format!("{base}/api/v1/calibrations/{id}/cancel"),
            None,
        );
        let s = wait_final(&base, &id);
        let (_, active) = call("GET", &format!("{base}/api/v1/calibration"), None);
        match code {
            202 => {
                won += 1;
                assert_eq!(reply["cancelling"], true);
                assert_eq!(s["state"], "cancelled", "race {k}: answered 202, ended {s}");
                assert_ne!(
                    active["id"],
                    json!(id),
                    "race {k}: a cancelled run became active"
                );
            }
            409 => {
                late += 1;
                assert!(
                    reply["error"]
                        .as_str()
                        .unwrap()
                        .contains("already finished"),
                    "{reply}"
                );
                assert_ne!(
                    s["state"], "cancelled",
                    "race {k}: refused cancel, yet cancelled"
                );
            }
            other => panic!("race {k}: cancel answered {other}: {reply}"),
        }
    }
    println!("cancel races: {won} cancelled, {late} already finished");
}

#[test]
fn a_start_that_cannot_be_written_leaves_no_record() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let config = write_config(dir.path(), |_| {});
    let d = start(&config, &data);
    let base = d.base.clone();
    // A folder where index.json belongs: every write of the index fails, even as root.
    let index = data.join("index.json");
    let _ = std::fs::remove_file(&index);
    std::fs::create_dir_all(index.join("blocker")).unwrap();
    let (code, body) = call("POST", &format!("{base}/api/v1/calibrations"), None);
    assert_eq!(code, 500, "{body}");
    let (_, history) = call("GET", &format!("{base}/api/v1/calibrations"), None);
    assert_eq!(history["calibrations"], json!([]), "{history}");
    let (code, _) = call("GET", &format!("{base}/api/v1/calibrations/cal-0001"), None);
    assert_eq!(code, 404);
    let (_, health) = call("GET", &format!("{base}/healthz"), None);
    assert_eq!(health["busy"], Value::Null, "the lease was given back");

    std::fs::remove_dir_all(&index).unwrap();
    d.stop();
    let d = start(&config, &data);
    assert!(
        d.daemon.recovered().is_empty(),
        "{:?}",
        d.daemon.recovered()
    );
    assert_eq!(calibrate_once(&d.base)["state"], "succeeded");
}

#[test]
fn the_history_keeps_at_most_keep_calibrations() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let config = write_config(dir.path(), |c| c.daemon.keep_calibrations = Some(3));
    let d = start(&config, &data);
    let mut ids = Vec::new();
    for _ in 0..5 {
        let (code, body) = call(
            "POST",
            &format!("{}/api/v1/calibrations", d.base),
            Some(&json!({"dry_run": true, "max_views": 1})),
        );
        assert_eq!(code, 202, "{body}");
        let id = body["id"].as_str().unwrap().to_string();
        wait_final(&d.base, &id);
        ids.push(id);
    }
    let listed = |base: &str| -> Vec<String> {
        let (_, h) = call("GET", &format!("{base}/api/v1/calibrations"), None);
        let mut v: Vec<String> = h["calibrations"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| r["id"].as_str().unwrap().to_string())
            .collect();
        v.sort();
        v
    };
    assert_eq!(listed(&d.base), ids[2..].to_vec());
    let mut runs: Vec<String> = std::fs::read_dir(data.join("runs"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    runs.sort();
    assert_eq!(runs, ids[2..].to_vec(), "pruned runs are deleted");
    d.stop();
    let d = start(&config, &data);
    assert_eq!(
        listed(&d.base),
        ids[2..].to_vec(),
        "a restart keeps the bound"
    );
}

#[test]
fn requests_must_have_exactly_the_documented_shape() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |_| {});
    let d = start(&config, &dir.path().join("data"));
    let base = d.base.clone();
    // An array is not read field by field.
    let head = format!(
        "POST /api/v1/calibrations HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {TOKEN}\r\nContent-Type: application/json\r\n"
    );
    assert_eq!(raw_status(&base, &head, "[1, true]"), 400);
    assert_eq!(raw_status(&base, &head, "  [1]"), 400);
    let (_, history) = call("GET", &format!("{base}/api/v1/calibrations"), None);
    assert_eq!(history["calibrations"], json!([]), "nothing started");
    // `Bearer TOKEN`, one space, nothing else (the scheme in any case).
    let checks = format!("{base}/api/v1/checks");
    for bad in [format!(" {TOKEN}"), format!("{TOKEN} x")] {
        let (code, _) = call_as("POST", &checks, Some(&bad), None);
        assert_eq!(code, 401, "token {bad:?}");
    }
    let tab =
        format!("POST /api/v1/checks HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer\t{TOKEN}\r\n");
    assert_eq!(raw_status(&base, &tab, ""), 401);
    let lower =
        format!("POST /api/v1/checks HTTP/1.1\r\nHost: x\r\nAuthorization: bearer {TOKEN}\r\n");
    assert_eq!(
        raw_status(&base, &lower, ""),
        409,
        "the scheme is case-insensitive"
    );
}

#[test]
fn plan_overlays_are_rendered_once_however_often_they_are_read() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |_| {});
    let d = start(&config, &dir.path().join("data"));
    let base = d.base.clone();
    let (_, body) = call(
        "POST",
        &format!("{base}/api/v1/calibrations"),
        Some(&json!({"dry_run": true, "max_views": 3})),
    );
    let id = body["id"].as_str().unwrap().to_string();
    assert_eq!(wait_final(&base, &id)["state"], "succeeded");
    let renders = || {
        d.daemon
            .metrics
            .overlay_renders
            .load(std::sync::atomic::Ordering::Relaxed)
    };
    let before = renders();
    for _ in 0..20 {
        let (code, _, png) = common::daemon::get_bytes(&format!(
            "{base}/api/v1/calibrations/{id}/plan/0/overlay.png"
        ));
        assert_eq!(code, 200);
        assert!(png.starts_with(b"\x89PNG"));
    }
    assert_eq!(renders() - before, 1, "twenty reads, one render");
}

#[test]
fn activation_refuses_a_result_whose_views_are_not_its_runs() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let config = write_config(dir.path(), |c| c.daemon.activate_on_success = false);
    let d = start(&config, &data);
    let base = d.base.clone();
    let s = calibrate_once(&base);
    let id = s["id"].as_str().unwrap().to_string();
    let result = data.join("runs").join(&id).join("result.json");
    let mut v: Value = serde_json::from_str(&std::fs::read_to_string(&result).unwrap()).unwrap();
    v["views_used"].as_array_mut().unwrap().push(json!(99));
    std::fs::write(&result, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    let msg = common::daemon::refused_activation(&base, &id, "views_used");
    assert!(msg.contains("99"), "{msg}");
    let (code, _) = call("GET", &format!("{base}/api/v1/calibration"), None);
    assert_eq!(code, 404, "nothing became active");
}

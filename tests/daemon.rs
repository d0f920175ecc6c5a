//! `easyhec daemon` on simulated cells: the API contract (auth, 409, SSE, overlays, history,
//! metrics, OpenAPI), cancel stopping the arm, bump detection with a warm-started
//! recalibration, graceful shutdown, restarts that keep history and the active calibration,
//! and a SIGKILL mid-run that leaves a re-solvable interrupted run (the real binary).

mod common;
mod daemon_common;

use std::io::BufRead;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use daemon_common::{
    call, call_as, full_resolution, get_bytes, read_events, real_time_arm, start, wait_final,
    wait_for, write_config,
};
use easyhec::geometry::{from_rows, rotation_error_deg, translation_error_mm};
use easyhec::nalgebra::{Isometry3, Translation3, UnitQuaternion};
use serde_json::{json, Value};

/// Rotation bound for one seeded calibration. The 0.05° is a median over cells; over
/// 80 seeded 5-view cells (docs/benchmarks.md, closed loop; code of 2026-11-23) 8 lie above it, the 95th
/// percentile is 0.060° and the worst 0.083°. A single draw held to the median would fail
/// about one change in ten for no fault; a failed recalibration is off by the knock (~1°).
const SINGLE_DRAW_MAX_DEG: f64 = 0.08;

fn error_vs(status: &Value, truth: &Isometry3<f64>) -> (f64, f64) {
    let rows: [[f64; 4]; 4] =
        serde_json::from_value(status["camera_from_base"].clone()).expect("an estimate");
    let est = from_rows(&rows).unwrap();
    (
        rotation_error_deg(&est, truth),
        translation_error_mm(&est, truth),
    )
}

#[test]
fn api_contract_auth_conflict_progress_overlays_history_and_restart() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), full_resolution);
    let data = dir.path().join("data");
    let d = start(&config, &data);
    let base = d.base.clone();
    let truth = d
        .daemon
        .cell()
        .sim
        .scene
        .as_ref()
        .unwrap()
        .camera_from_base();

    // Open routes.
    let (code, h) = call_as("GET", &format!("{base}/healthz"), None, None);
    assert_eq!((code, h["status"].as_str()), (200, Some("ok")));
    let (code, api) = call_as("GET", &format!("{base}/openapi.json"), None, None);
    assert_eq!(code, 200);
    assert!(api["openapi"].as_str().unwrap().starts_with("3."));
    for route in [
        "/api/v1/calibrations",
        "/api/v1/calibrations/{id}",
        "/api/v1/calibrations/{id}/events",
        "/api/v1/calibrations/{id}/views/{n}/overlay.png",
        "/api/v1/calibrations/{id}/cancel",
        "/api/v1/calibrations/{id}/activate",
        "/api/v1/calibration",
        "/api/v1/checks",
        "/healthz",
        "/metrics",
    ] {
        assert!(
            api["paths"][route].is_object(),
            "{route} missing from OpenAPI"
        );
    }
    let (_, _, page) = get_bytes(&format!("{base}/"));
    assert!(String::from_utf8_lossy(&page).contains("easyhec"));

    // Token: every route that acts refuses a missing or wrong one (401, JSON error) before
    // anything moves; read-only routes answer without it.
    for token in [None, Some("wrong-token")] {
        for (method, route) in [
            ("POST", "/api/v1/calibrations"),
            ("POST", "/api/v1/checks"),
            ("POST", "/api/v1/calibrations/cal-0001/cancel"),
            ("POST", "/api/v1/calibrations/cal-0001/activate"),
        ] {
            let (code, body) = call_as(method, &format!("{base}{route}"), token, None);
            assert_eq!(code, 401, "{method} {route} with {token:?}");
            assert!(body["error"].as_str().unwrap().contains("Bearer"), "{body}");
        }
        let (code, body) = call_as("GET", &format!("{base}/api/v1/calibrations"), token, None);
        assert_eq!(code, 200, "history reads without the token: {body}");
        let (code, _) = call_as("GET", &format!("{base}/api/v1/calibration"), token, None);
        assert_eq!(code, 404, "nothing active yet, but no 401");
        let (code, _) = call_as("GET", &format!("{base}/metrics"), token, None);
        assert_eq!(code, 200, "metrics read without the token");
    }
    let (_, history) = call("GET", &format!("{base}/api/v1/calibrations"), None);
    assert_eq!(
        history["calibrations"],
        json!([]),
        "nothing was started by the refused calls"
    );
    let (code, body) = call("GET", &format!("{base}/api/v1/calibration"), None);
    assert_eq!(code, 404, "nothing active yet: {body}");
    let (code, body) = call(
        "POST",
        &format!("{base}/api/v1/calibrations"),
        Some(&json!({"max_views": 0})),
    );
    assert_eq!(code, 400, "{body}");
    let (code, body) = call(
        "POST",
        &format!("{base}/api/v1/calibrations"),
        Some(&json!({"max_vews": 3})),
    );
    assert_eq!(code, 400, "unknown option: {body}");
    assert!(body["error"].as_str().unwrap().contains("max_vews"));

    // Start; a second start while it runs is 409 naming it.
    let (code, body) = call("POST", &format!("{base}/api/v1/calibrations"), None);
    assert_eq!(code, 202, "{body}");
    let id = body["id"].as_str().unwrap().to_string();
    let (code, busy) = call(
        "POST",
        &format!("{base}/api/v1/calibrations"),
        Some(&json!({"dry_run": true})),
    );
    assert_eq!(code, 409, "{busy}");
    assert_eq!(busy["running"].as_str(), Some(id.as_str()));
    assert!(busy["error"].as_str().unwrap().contains(&id));
    let (code, busy) = call("POST", &format!("{base}/api/v1/checks"), None);
    assert_eq!(code, 409, "a check while calibrating: {busy}");

    // Live progress to the end over SSE.
    let events = read_events(&base, &id);
    let kinds: Vec<&str> = events.iter().map(|(k, _)| k.as_str()).collect();
    assert_eq!(kinds.first(), Some(&"state"));
    let views: Vec<u64> = events
        .iter()
        .filter(|(k, _)| k == "view")
        .map(|(_, e)| e["view"].as_u64().unwrap())
        .collect();
    assert_eq!(
        views,
        (0..views.len() as u64).collect::<Vec<_>>(),
        "{kinds:?}"
    );
    assert!(views.len() >= 3, "{kinds:?}");
    assert!(kinds.iter().filter(|k| **k == "round").count() >= 3);
    let (last_kind, last) = events.last().unwrap();
    assert_eq!(last_kind, "state");
    assert_eq!(last["status"]["state"], "succeeded", "{last}");

    let s = wait_final(&base, &id);
    assert_eq!(s["state"], "succeeded", "{s}");
    assert_eq!(s["views"].as_u64(), Some(views.len() as u64));
    assert!(s["stop_reason"].as_str().unwrap().len() > 3);
    assert!(s["best_variance"].as_f64().unwrap() > 0.0);
    assert!(s["loss"].as_f64().unwrap() >= 0.0);
    assert_eq!(
        s["uncertainty"]["rotation_deg"].as_array().unwrap().len(),
        3
    );
    let (r, t) = error_vs(&s, &truth);
    assert!(
        r <= SINGLE_DRAW_MAX_DEG && t <= 1.0,
        "error {r:.4} deg {t:.3} mm"
    );
    eprintln!("daemon calibration: {r:.4} deg, {t:.3} mm from the truth");

    // Overlays decode at the camera's size; a missing view is 404.
    for n in 0..views.len() {
        let (code, ctype, png) = get_bytes(&format!(
            "{base}/api/v1/calibrations/{id}/views/{n}/overlay.png"
        ));
        assert_eq!((code, ctype.as_str()), (200, "image/png"));
        let img = image::load_from_memory(&png).unwrap();
        assert_eq!((img.width(), img.height()), (640, 480));
    }
    let (code, ..) = get_bytes(&format!(
        "{base}/api/v1/calibrations/{id}/views/99/overlay.png"
    ));
    assert_eq!(code, 404);
    let (code, _) = call("GET", &format!("{base}/api/v1/calibrations/cal-9999"), None);
    assert_eq!(code, 404);

    // Active with its easyhec-result/1 body; result.json in the run directory too.
    let (code, active) = call("GET", &format!("{base}/api/v1/calibration"), None);
    assert_eq!(code, 200, "{active}");
    assert_eq!(active["id"].as_str(), Some(id.as_str()));
    assert_eq!(active["stale"], false);
    assert_eq!(active["result"]["format"], "easyhec-result/1");
    let run_dir = data.join("runs").join(&id);
    let on_disk: Value =
        serde_json::from_str(&std::fs::read_to_string(run_dir.join("result.json")).unwrap())
            .unwrap();
    assert_eq!(
        on_disk["camera_from_base"],
        active["result"]["camera_from_base"]
    );

    // A check with the camera where it was: not stale.
    let (code, check) = call("POST", &format!("{base}/api/v1/checks"), None);
    assert_eq!(code, 200, "{check}");
    assert_eq!(check["stale"], false, "{check}");

    // Metrics.
    let (code, ctype, text) = get_bytes(&format!("{base}/metrics"));
    assert_eq!(code, 200);
    assert!(ctype.starts_with("text/plain"));
    let text = String::from_utf8(text).unwrap();
    for line in [
        "easyhec_calibrations_started_total 1",
        "easyhec_calibrations_finished_total{state=\"succeeded\"} 1",
        "easyhec_calibration_running 0",
        "easyhec_bump_checks_total 1",
        "easyhec_calibration_stale 0",
    ] {
        assert!(text.lines().any(|l| l == line), "{line} not in\n{text}");
    }

    // A dry run plans and never moves; it is not activated.
    let moves_before = d.daemon.cell().sim.arm.as_ref().unwrap().commands().len();
    let (code, body) = call(
        "POST",
        &format!("{base}/api/v1/calibrations"),
        Some(&json!({"dry_run": true, "max_views": 3})),
    );
    assert_eq!(code, 202, "{body}");
    let dry = body["id"].as_str().unwrap().to_string();
    let s = wait_final(&base, &dry);
    assert_eq!(s["state"], "succeeded", "{s}");
    assert!(s["planned_poses"].as_u64().unwrap() >= 1, "{s}");
    assert_eq!(
        d.daemon.cell().sim.arm.as_ref().unwrap().commands().len(),
        moves_before
    );
    let (code, body) = call(
        "POST",
        &format!("{base}/api/v1/calibrations/{dry}/activate"),
        None,
    );
    assert_eq!(code, 409, "a dry run has no result: {body}");

    // History, newest first.
    let (code, h) = call("GET", &format!("{base}/api/v1/calibrations"), None);
    assert_eq!(code, 200);
    let ids: Vec<&str> = h["calibrations"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["id"].as_str().unwrap())
        .collect();
    assert_eq!(ids, [dry.as_str(), id.as_str()]);
    assert_eq!(h["active"].as_str(), Some(id.as_str()));

    // Every command the arm got was safe.
    let cell = d.daemon.cell();
    for (i, c) in cell.sim.arm.as_ref().unwrap().commands().iter().enumerate() {
        assert!(c.accepted, "command {i} refused: {:?}", c.outcome);
        common::assert_commanded_path_safe(&cell.checker, i, &c.from, &c.target, c.speed_rad_s);
    }

    // Restart on the same data folder: history and the active calibration survive.
    d.stop();
    let d = start(&config, &data);
    let base = d.base.clone();
    let (_, h2) = call("GET", &format!("{base}/api/v1/calibrations"), None);
    assert_eq!(h2["calibrations"], h["calibrations"]);
    let (code, active2) = call("GET", &format!("{base}/api/v1/calibration"), None);
    assert_eq!(code, 200);
    assert_eq!(active2["result"], active["result"]);
    let (code, _) = call("GET", &format!("{base}/api/v1/calibrations/{id}"), None);
    assert_eq!(code, 200);
    // The next id continues the sequence.
    let (code, body) = call(
        "POST",
        &format!("{base}/api/v1/calibrations"),
        Some(&json!({"dry_run": true, "max_views": 2})),
    );
    assert_eq!(code, 202);
    assert_eq!(body["id"], "cal-0003");
    wait_final(&base, "cal-0003");
}

#[test]
fn cancel_stops_the_arm_and_ends_cancelled() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |c| {
        real_time_arm(c);
        c.calibration.max_views = 6;
        c.calibration.min_views = 6;
    });
    let d = start(&config, &dir.path().join("data"));
    let base = d.base.clone();
    let (code, body) = call("POST", &format!("{base}/api/v1/calibrations"), None);
    assert_eq!(code, 202);
    let id = body["id"].as_str().unwrap().to_string();
    wait_for(&base, &id, Duration::from_secs(60), |s| {
        s["phase"] == "moving"
    });
    // Mid-move (moves take about a second in real time).
    std::thread::sleep(Duration::from_millis(200));
    let arm = d.daemon.cell().sim.arm.clone().unwrap();
    let t = Instant::now();
    let (code, body) = call(
        "POST",
        &format!("{base}/api/v1/calibrations/{id}/cancel"),
        None,
    );
    assert_eq!(code, 202, "{body}");
    assert_eq!(body["cancelling"], true);
    let stopped_at = arm.true_joints();
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(
        arm.true_joints(),
        stopped_at,
        "the arm kept moving after cancel"
    );
    let s = wait_final(&base, &id);
    assert_eq!(s["state"], "cancelled", "{s}");
    assert!(s["stop_reason"].as_str().unwrap().contains("cancelled"));
    assert!(t.elapsed() < Duration::from_secs(10));
    let status = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
        .block_on(d.daemon.cell().arm.status())
        .unwrap();
    assert_ne!(status, easyhec_drivers::ArmStatus::Moving);
    // Cancelling an ended calibration is 409; an unknown one 404.
    let (code, _) = call(
        "POST",
        &format!("{base}/api/v1/calibrations/{id}/cancel"),
        None,
    );
    assert_eq!(code, 409);
    let (code, _) = call(
        "POST",
        &format!("{base}/api/v1/calibrations/nope/cancel"),
        None,
    );
    assert_eq!(code, 404);
    // The arm is free again.
    let (code, body) = call(
        "POST",
        &format!("{base}/api/v1/calibrations"),
        Some(&json!({"dry_run": true, "max_views": 2})),
    );
    assert_eq!(code, 202, "{body}");
    wait_final(&base, body["id"].as_str().unwrap());
}

#[test]
fn bump_check_marks_stale_and_a_warm_started_recalibration_recovers_the_new_pose() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |c| {
        full_resolution(c);
        c.daemon.recalibrate_on_bump = true;
    });
    let d = start(&config, &dir.path().join("data"));
    let base = d.base.clone();
    let scene = d.daemon.cell().sim.scene.clone().unwrap();

    let (code, _) = call("POST", &format!("{base}/api/v1/checks"), None);
    assert_eq!(code, 409, "nothing active to check yet");
    let (_, body) = call("POST", &format!("{base}/api/v1/calibrations"), None);
    let first = body["id"].as_str().unwrap().to_string();
    let s = wait_final(&base, &first);
    assert_eq!(s["state"], "succeeded", "{s}");

    let (code, ok) = call("POST", &format!("{base}/api/v1/checks"), None);
    assert_eq!(code, 200, "{ok}");
    assert_eq!(ok["stale"], false, "{ok}");
    eprintln!(
        "check before the bump: IoU {:.4}, boundary {:.3} px",
        ok["iou"].as_f64().unwrap(),
        ok["boundary_px"].as_f64().unwrap()
    );

    // Knock the camera: about 1 degree and 15 mm, in the camera frame.
    let old = scene.camera_from_base();
    let knock = Isometry3::from_parts(
        Translation3::new(0.010, -0.008, 0.008),
        UnitQuaternion::from_euler_angles(0.010, -0.012, 0.006),
    );
    let bumped = knock * old;
    scene.set_camera_from_base(bumped);
    let (code, bad) = call("POST", &format!("{base}/api/v1/checks"), None);
    assert_eq!(code, 200, "{bad}");
    eprintln!(
        "check after the bump: IoU {:.4}, boundary {:.3} px",
        bad["iou"].as_f64().unwrap(),
        bad["boundary_px"].as_f64().unwrap()
    );
    assert_eq!(bad["stale"], true, "{bad}");
    assert_eq!(bad["calibration_id"].as_str(), Some(first.as_str()));
    let second = bad["recalibration"]
        .as_str()
        .expect("a recalibration started")
        .to_string();
    let (_, ctype, text) = get_bytes(&format!("{base}/metrics"));
    assert!(ctype.starts_with("text/plain"));
    let text = String::from_utf8(text).unwrap();
    assert!(
        text.lines().any(|l| l == "easyhec_bumps_detected_total 1"),
        "{text}"
    );
    assert!(
        text.lines().any(|l| l == "easyhec_calibration_stale 1"),
        "{text}"
    );

    let s = wait_final(&base, &second);
    assert_eq!(s["state"], "succeeded", "{s}");
    assert_eq!(s["trigger"], "bump");
    assert_eq!(s["warm_start_from"].as_str(), Some(first.as_str()));
    let (r, t) = error_vs(&s, &bumped);
    eprintln!("recalibration after the bump: {r:.4} deg, {t:.3} mm from the new truth");
    assert!(
        r <= SINGLE_DRAW_MAX_DEG && t <= 1.0,
        "error {r:.4} deg {t:.3} mm"
    );
    let (r_old, t_old) = (
        rotation_error_deg(&old, &bumped),
        translation_error_mm(&old, &bumped),
    );
    assert!(
        r_old > 0.8 && t_old > 10.0,
        "the bump was {r_old} deg {t_old} mm"
    );
    // The recalibration's run starts from the old pose.
    let run: Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("data/runs").join(&second).join("run.json"))
            .unwrap(),
    )
    .unwrap();
    let guess: [[f64; 4]; 4] =
        serde_json::from_value(run["initial_guess"]["camera_from_base"].clone()).unwrap();
    assert!(rotation_error_deg(&from_rows(&guess).unwrap(), &old) < 0.3);

    let (_, active) = call("GET", &format!("{base}/api/v1/calibration"), None);
    assert_eq!(active["id"].as_str(), Some(second.as_str()));
    assert_eq!(active["stale"], false);
    let (code, ok) = call("POST", &format!("{base}/api/v1/checks"), None);
    assert_eq!(code, 200);
    assert_eq!(ok["stale"], false, "after recalibrating: {ok}");
    let (_, checks) = call("GET", &format!("{base}/api/v1/checks"), None);
    assert_eq!(checks["checks"].as_array().unwrap().len(), 3);
}

#[test]
fn check_pose_moves_through_the_checker_before_checking() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |c| {
        c.daemon.check_pose = Some(vec![0.2, -0.3, -0.7, 0.0, 1.0, 0.1]);
    });
    let d = start(&config, &dir.path().join("data"));
    let base = d.base.clone();
    let (_, body) = call("POST", &format!("{base}/api/v1/calibrations"), None);
    let id = body["id"].as_str().unwrap().to_string();
    assert_eq!(wait_final(&base, &id)["state"], "succeeded");
    let arm = d.daemon.cell().sim.arm.clone().unwrap();
    let before = arm.commands().len();
    let (code, c) = call("POST", &format!("{base}/api/v1/checks"), None);
    assert_eq!(code, 200, "{c}");
    assert_eq!(c["moved_to_check_pose"], true);
    assert_eq!(c["stale"], false, "{c}");
    let commands = arm.commands();
    assert_eq!(commands.len(), before + 1);
    let last = commands.last().unwrap();
    assert_eq!(last.target, vec![0.2, -0.3, -0.7, 0.0, 1.0, 0.1]);
    common::assert_commanded_path_safe(
        &d.daemon.cell().checker,
        before,
        &last.from,
        &last.target,
        last.speed_rad_s,
    );
}

#[test]
fn bad_daemon_config_is_one_line_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let run = |config: &Path, token_env: bool| {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_easyhec"));
        cmd.args(["daemon", "--config"]).arg(config);
        if !token_env {
            cmd.env_remove("EASYHEC_TOKEN");
        }
        let out = cmd.output().unwrap();
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        err
    };
    // An unknown key.
    let config = write_config(dir.path(), |_| {});
    let text = std::fs::read_to_string(&config).unwrap();
    std::fs::write(
        &config,
        text.replace("[daemon]\n", "[daemon]\ntokn = \"x\"\n"),
    )
    .unwrap();
    let err = run(&config, true);
    assert!(err.contains("tokn") && err.contains("cell.toml"), "{err}");
    // Out-of-range values, each naming its key.
    type Tweak = fn(&mut easyhec::config::CellConfig);
    let cases: [(Tweak, &str); 4] = [
        (
            |c| c.daemon.check_pose = Some(vec![0.0, 1.0]),
            "daemon.check_pose",
        ),
        (|c| c.daemon.bump_min_iou = 1.5, "daemon.bump_min_iou"),
        (
            |c| c.daemon.check_interval_s = Some(0.0),
            "daemon.check_interval_s",
        ),
        (
            |c| c.daemon.token = Some("has space".into()),
            "daemon.token",
        ),
    ];
    for (tweak, key) in cases {
        let config = write_config(dir.path(), tweak);
        let err = run(&config, false);
        assert!(err.contains(key) && err.contains("cell.toml"), "{err}");
    }
    // No token anywhere: refused, saying how to give one.
    let config = write_config(dir.path(), |c| c.daemon.token = None);
    let err = run(&config, false);
    assert!(
        err.contains("EASYHEC_TOKEN") && err.contains("daemon.token"),
        "{err}"
    );
}

/// Starts the real binary; returns it and its base URL (read from its first stderr line).
fn spawn_daemon(config: &Path, data: &Path) -> (Child, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_easyhec"))
        .args(["daemon", "--listen", "127.0.0.1:0", "--config"])
        .arg(config)
        .arg("--data")
        .arg(data)
        .env_remove("EASYHEC_TOKEN")
        .stderr(Stdio::piped())
        .spawn()
        .expect("easyhec runs");
    let stderr = child.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut sent = false;
        for line in std::io::BufReader::new(stderr)
            .lines()
            .map_while(Result::ok)
        {
            eprintln!("[daemon] {line}");
            if !sent {
                if let Some(url) = line.split_whitespace().find(|w| w.starts_with("http://")) {
                    let _ = tx.send(url.to_string());
                    sent = true;
                }
            }
        }
    });
    let base = rx
        .recv_timeout(Duration::from_secs(30))
        .expect("the daemon prints its address");
    (child, base)
}

#[test]
fn sigkill_mid_run_leaves_an_interrupted_run_that_resolves_offline() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |c| {
        real_time_arm(c);
        c.calibration.max_views = 8;
        c.calibration.min_views = 8;
    });
    let data = dir.path().join("data");
    let (mut child, base) = spawn_daemon(&config, &data);
    let (code, body) = call("POST", &format!("{base}/api/v1/calibrations"), None);
    assert_eq!(code, 202, "{body}");
    let id = body["id"].as_str().unwrap().to_string();
    let s = wait_for(&base, &id, Duration::from_secs(120), |s| {
        s["views"].as_u64().unwrap_or(0) >= 2
    });
    assert_eq!(s["state"], "running");
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();

    let run_dir = data.join("runs").join(&id);
    let run: Value =
        serde_json::from_str(&std::fs::read_to_string(run_dir.join("run.json")).unwrap()).unwrap();
    let n = run["views"].as_array().unwrap().len();
    assert!(n >= 2, "{n} views on disk");
    for v in run["views"].as_array().unwrap() {
        for key in ["mask", "image"] {
            let p = run_dir.join(v[key].as_str().unwrap());
            image::open(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
        }
    }
    assert!(!run_dir.join("result.json").exists());

    // Restart: the run is interrupted, with its views.
    let (mut child, base) = spawn_daemon(&config, &data);
    let s = wait_for(&base, &id, Duration::from_secs(5), |_| true);
    assert_eq!(s["state"], "interrupted", "{s}");
    assert_eq!(s["views"].as_u64(), Some(n as u64));
    assert!(
        s["error"].as_str().unwrap().contains("easyhec solve"),
        "{s}"
    );
    let (_, h) = call("GET", &format!("{base}/api/v1/calibrations"), None);
    assert_eq!(h["calibrations"][0]["state"], "interrupted");
    let (code, _) = call(
        "POST",
        &format!("{base}/api/v1/calibrations/{id}/activate"),
        None,
    );
    assert_eq!(code, 409, "no result yet");
    let (_, _, metrics) = get_bytes(&format!("{base}/metrics"));
    assert!(String::from_utf8(metrics)
        .unwrap()
        .contains("easyhec_calibrations_interrupted_in_history 1"));

    // Re-solve offline, then it can be activated.
    let out = common::solve_run(&run_dir, &[]);
    assert!(
        out.status.success(),
        "easyhec solve: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(run_dir.join("result.json").is_file());
    let (code, a) = call(
        "POST",
        &format!("{base}/api/v1/calibrations/{id}/activate"),
        None,
    );
    assert_eq!(code, 200, "{a}");
    let (code, active) = call("GET", &format!("{base}/api/v1/calibration"), None);
    assert_eq!(code, 200);
    assert_eq!(active["id"].as_str(), Some(id.as_str()));

    // SIGTERM mid-run: the daemon stops the arm, marks the run interrupted and exits 0.
    let (code, body) = call("POST", &format!("{base}/api/v1/calibrations"), None);
    assert_eq!(code, 202);
    let id2 = body["id"].as_str().unwrap().to_string();
    wait_for(&base, &id2, Duration::from_secs(60), |s| {
        s["phase"] == "moving"
    });
    let status = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let t = Instant::now();
    let exit = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "no exit after SIGTERM"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(exit.success(), "{exit:?}");
    let index: Value =
        serde_json::from_str(&std::fs::read_to_string(data.join("index.json")).unwrap()).unwrap();
    let rec = index["calibrations"]
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["id"] == id2.as_str())
        .unwrap();
    assert_eq!(rec["state"], "interrupted", "{rec}");
}

#[test]
fn scheduled_checks_run_while_the_arm_is_idle() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |c| c.daemon.check_interval_s = Some(1.0));
    let d = start(&config, &dir.path().join("data"));
    let base = d.base.clone();
    let (_, body) = call("POST", &format!("{base}/api/v1/calibrations"), None);
    let id = body["id"].as_str().unwrap().to_string();
    assert_eq!(wait_final(&base, &id)["state"], "succeeded");
    let t = Instant::now();
    loop {
        let (_, checks) = call("GET", &format!("{base}/api/v1/checks"), None);
        let list = checks["checks"].as_array().unwrap();
        if let Some(c) = list.iter().find(|c| c["trigger"] == "schedule") {
            assert_eq!(c["calibration_id"].as_str(), Some(id.as_str()));
            assert_eq!(c["stale"], false, "{c}");
            break;
        }
        assert!(
            t.elapsed() < Duration::from_secs(20),
            "no scheduled check: {checks}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let (_, active) = call("GET", &format!("{base}/api/v1/calibration"), None);
    assert_eq!(active["last_check"]["trigger"], "schedule");
}

#[test]
fn protect_reads_puts_the_read_only_routes_behind_the_token_too() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |c| c.daemon.protect_reads = true);
    let d = start(&config, &dir.path().join("data"));
    for route in ["/api/v1/calibrations", "/api/v1/calibration", "/metrics"] {
        let (code, body) = call_as("GET", &format!("{}{route}", d.base), None, None);
        assert_eq!(code, 401, "{route}: {body}");
    }
    let (code, _) = call("GET", &format!("{}/api/v1/calibrations", d.base), None);
    assert_eq!(code, 200);
    let (code, _) = call_as("GET", &format!("{}/healthz", d.base), None, None);
    assert_eq!(code, 200, "health stays open");
}

/// With `[segmenter] kind = "builtin"` (colour frames only, on the hard scene) a bump check
/// has one new frame and no plate of its own: it segments it together with the active
/// calibration's recorded frames. An untouched camera passes, a knocked one is caught. One
/// builtin mask of the hard scene agrees with the render less well than the simulator's
/// truth does (measured: IoU 0.83, 3.1 px untouched; 0.73, 4.5 px knocked), so the cell sets
/// thresholds for its segmenter, as a real cell would (docs/daemon.md, bump checks).
#[test]
fn builtin_segmenter_bump_checks_segment_with_the_recorded_frames() {
    use easyhec::config::CameraConfig;
    use easyhec::config::ScenePreset;
    use easyhec::config::SegmenterConfig;
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |c| {
        full_resolution(c);
        c.calibration.max_views = 5;
        c.daemon.bump_min_iou = 0.78;
        c.daemon.bump_max_boundary_px = 3.8;
        c.segmenter = SegmenterConfig::by_name("builtin").unwrap();
        if let CameraConfig::Sim { scene, .. } = &mut c.camera {
            scene.preset = ScenePreset::Hard;
        }
    });
    let d = start(&config, &dir.path().join("data"));
    let base = d.base.clone();
    let scene = d.daemon.cell().sim.scene.clone().unwrap();
    let (_, body) = call("POST", &format!("{base}/api/v1/calibrations"), None);
    let id = body["id"].as_str().unwrap().to_string();
    let s = wait_final(&base, &id);
    assert_eq!(s["state"], "succeeded", "{s}");
    let (r, t) = error_vs(&s, &scene.camera_from_base());
    eprintln!("builtin calibration: {r:.4} deg {t:.3} mm");
    assert!(r <= 0.08 && t <= 1.5, "error {r:.4} deg {t:.3} mm");

    let (code, ok) = call("POST", &format!("{base}/api/v1/checks"), None);
    assert_eq!(code, 200, "{ok}");
    let (iou, px) = (
        ok["iou"].as_f64().unwrap(),
        ok["boundary_px"].as_f64().unwrap(),
    );
    eprintln!("check before the bump: IoU {iou:.4}, boundary {px:.3} px");
    assert_eq!(ok["stale"], false, "{ok}");

    let knock = Isometry3::from_parts(
        Translation3::new(0.010, -0.008, 0.008),
        UnitQuaternion::from_euler_angles(0.010, -0.012, 0.006),
    );
    scene.set_camera_from_base(knock * scene.camera_from_base());
    let (code, bad) = call("POST", &format!("{base}/api/v1/checks"), None);
    assert_eq!(code, 200, "{bad}");
    let (iou_b, px_b) = (
        bad["iou"].as_f64().unwrap(),
        bad["boundary_px"].as_f64().unwrap(),
    );
    eprintln!("check after the bump: IoU {iou_b:.4}, boundary {px_b:.3} px");
    assert_eq!(bad["stale"], true, "{bad}");
    assert!(
        iou_b < iou - 0.05 && px_b > px + 0.5,
        "the knock should cost agreement: IoU {iou} -> {iou_b}, {px} -> {px_b} px"
    );
}

//! `easyhec daemon` on simulated cells: the API contract (auth, 409, SSE, overlays, history,
//! metrics, OpenAPI), cancel stopping the arm, bump detection with a warm-started
//! recalibration, graceful shutdown, restarts that keep history and the active calibration,
//! a SIGKILL mid-run that leaves a re-solvable interrupted run (the real binary), activation
//! refusals, a data folder that is reconciled rather than trusted at start, and the HTTP
//! server's limits (1,000 idle connections, timeouts, the connection limit).

mod common;

use std::io::BufRead;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::daemon::{
    assert_refused, call, call_as, full_resolution, get_bytes, quarantined, raise_open_files,
    read_events, real_time_arm, record, refused_activation, result_json, start, wait_final,
    wait_for, write_config, write_index, write_result, POSE, TOKEN,
};
use easyhec::config::SimCameraSettings;
use easyhec::geometry::{from_rows, rotation_error_deg, translation_error_mm};
use easyhec::nalgebra::{Isometry3, Translation3, UnitQuaternion};
use serde_json::{json, Value};

/// Rotation bound for one seeded calibration. The issue's 0.05° is a median over cells; over
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
    let truth = d.daemon.cell().units[0]
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
    assert_refused(
        "POST",
        &format!("{base}/api/v1/calibrations"),
        Some(&json!({"max_vews": 3})),
        "max_vews",
    );

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
    // One [camera] table: naming a camera is refused, not ignored.
    let url = format!("{base}/api/v1/calibrations/{id}/views/0/overlay.png?camera=camera");
    let body = assert_refused("GET", &url, None, "this cell has one");
    assert!(
        body["error"].as_str().unwrap().starts_with("camera: "),
        "{body}"
    );
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
    let moves_before = d.daemon.cell().sim_arm().unwrap().commands().len();
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
        d.daemon.cell().sim_arm().unwrap().commands().len(),
        moves_before
    );
    let (code, body) = call(
        "POST",
        &format!("{base}/api/v1/calibrations/{dry}/activate"),
        None,
    );
    assert_eq!(code, 409, "a dry run is never activated: {body}");
    let msg = body["error"].as_str().unwrap();
    assert!(msg.contains(&dry) && msg.contains("dry_run"), "{msg}");

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
    common::assert_every_command_safe(d.daemon.cell());

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
    let arm = d.daemon.cell().sim_arm().cloned().unwrap();
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
    // A cancelled run is never activated, although the loop wrote a result for its views.
    assert!(dir
        .path()
        .join("data/runs")
        .join(&id)
        .join("result.json")
        .is_file());
    let (code, body) = call(
        "POST",
        &format!("{base}/api/v1/calibrations/{id}/activate"),
        None,
    );
    assert_eq!(code, 409, "{body}");
    let msg = body["error"].as_str().unwrap();
    assert!(
        msg.contains(&id) && msg.contains("state: cancelled"),
        "{msg}"
    );
    let (code, _) = call("GET", &format!("{base}/api/v1/calibration"), None);
    assert_eq!(code, 404, "nothing became active");
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
    let scene = d.daemon.cell().units[0].sim.scene.clone().unwrap();

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
    let arm = d.daemon.cell().sim_arm().cloned().unwrap();
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

/// A valid `[ros2]` table, `tweak`ed.
fn ros2_table(
    tweak: fn(&mut easyhec::config::ros2::Ros2Settings),
) -> easyhec::config::ros2::Ros2Settings {
    let mut r: easyhec::config::ros2::Ros2Settings = toml::from_str("domain_id = 3").unwrap();
    tweak(&mut r);
    r
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
    let cases: [(Tweak, &str); 12] = [
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
        (
            |c| c.daemon.max_connections = Some(0),
            "daemon.max_connections",
        ),
        (
            |c| c.daemon.header_read_timeout_s = Some(301.0),
            "daemon.header_read_timeout_s",
        ),
        (
            |c| c.daemon.idle_timeout_s = Some(f64::NAN),
            "daemon.idle_timeout_s",
        ),
        (
            |c| c.ros2 = Some(ros2_table(|r| r.domain_id = Some(233))),
            "ros2.domain_id",
        ),
        (
            |c| c.ros2 = Some(ros2_table(|r| r.namespace = "cell".into())),
            "ros2.namespace",
        ),
        (
            |c| c.ros2 = Some(ros2_table(|r| r.child_frame_id = "cam: x".into())),
            "ros2.child_frame_id",
        ),
        (
            |c| {
                c.ros2 = Some(ros2_table(|r| {
                    r.optical_from_child = Some([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0])
                }))
            },
            "ros2.optical_from_child",
        ),
        (
            |c| c.ros2 = Some(ros2_table(|r| r.listen_s = f64::INFINITY)),
            "ros2.listen_s",
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
    let (child, base, _) = spawn_daemon_logged(config, data);
    (child, base)
}

/// [`spawn_daemon`], also collecting every line the daemon writes to stderr.
fn spawn_daemon_logged(
    config: &Path,
    data: &Path,
) -> (Child, String, std::sync::Arc<std::sync::Mutex<Vec<String>>>) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_easyhec"))
        .args(["daemon", "--listen", "127.0.0.1:0", "--config"])
        .arg(config)
        .arg("--data")
        .arg(data)
        .env_remove("EASYHEC_TOKEN")
        .env_remove("RUST_LOG")
        .env_remove("EASYHEC_LOG_FORMAT")
        .stderr(Stdio::piped())
        .spawn()
        .expect("easyhec runs");
    let stderr = child.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    let log = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    let lines = log.clone();
    std::thread::spawn(move || {
        let mut sent = false;
        for line in std::io::BufReader::new(stderr)
            .lines()
            .map_while(Result::ok)
        {
            eprintln!("[daemon] {line}");
            lines.lock().unwrap().push(line.clone());
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
    (child, base, log)
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
        if let CameraConfig::Sim(SimCameraSettings { scene, .. }) = c.camera.first_mut() {
            scene.preset = ScenePreset::Hard;
        }
    });
    let d = start(&config, &dir.path().join("data"));
    let base = d.base.clone();
    let scene = d.daemon.cell().units[0].sim.scene.clone().unwrap();
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

/// Activation accepts only a succeeded, non-dry run whose own result.json, inside the data
/// folder, holds a rigid pose: records that lie are refused, each naming the record and field.
#[test]
fn activation_refuses_records_that_did_not_succeed_or_point_elsewhere() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |_| {});
    let data = dir.path().join("data");
    let runs = data.join("runs");
    let mut scaled = POSE;
    for row in scaled.iter_mut().take(3) {
        for v in row.iter_mut().take(3) {
            *v *= 1.0001;
        }
    }
    write_result(&runs.join("cal-0001"), &result_json(POSE, "converged"));
    write_result(
        &runs.join("cal-0002"),
        &result_json(POSE, "cancelled after 1 views"),
    );
    write_result(&runs.join("cal-0005"), &result_json(scaled, "converged"));
    write_result(
        &runs.join("cal-0007"),
        &result_json(POSE, "cancelled after 2 views"),
    );
    let outside = dir.path().join("elsewhere");
    write_result(&outside, &result_json(POSE, "converged"));
    write_index(
        &data,
        &[
            record("cal-0001", "succeeded", false, "runs/cal-0001"),
            record("cal-0002", "cancelled", false, "runs/cal-0002"),
            // The reported case: a failed dry run whose record points at another run's result.
            record("cal-0003", "failed", true, "runs/cal-0001"),
            record("cal-0004", "succeeded", false, "runs/cal-0004"),
            record("cal-0005", "succeeded", false, "runs/cal-0005"),
            record("cal-0006", "succeeded", false, "runs/cal-0001"),
            record("cal-0007", "interrupted", false, "runs/cal-0007"),
        ],
    );
    let d = start(&config, &data);
    let base = d.base.clone();
    // A run directory that now resolves outside the data folder (the daemon checked the
    // records when it started; activation checks again).
    #[cfg(unix)]
    std::os::unix::fs::symlink(&outside, runs.join("cal-0004")).unwrap();

    refused_activation(&base, "cal-0002", "state: cancelled");
    refused_activation(&base, "cal-0003", "state: failed");
    #[cfg(unix)]
    {
        let msg = refused_activation(&base, "cal-0004", "run_dir");
        assert!(msg.contains("outside the data folder"), "{msg}");
    }
    let msg = refused_activation(&base, "cal-0005", "camera_from_base");
    assert!(msg.contains("orthonormal"), "{msg}");
    let msg = refused_activation(&base, "cal-0006", "run_dir");
    assert!(msg.contains("runs/cal-0006"), "{msg}");
    let msg = refused_activation(&base, "cal-0007", "state: interrupted");
    assert!(msg.contains("easyhec solve"), "{msg}");
    let (code, _) = call("GET", &format!("{base}/api/v1/calibration"), None);
    assert_eq!(code, 404, "every refusal left nothing active");

    let (code, a) = call(
        "POST",
        &format!("{base}/api/v1/calibrations/cal-0001/activate"),
        None,
    );
    assert_eq!(code, 200, "{a}");
    let (code, active) = call("GET", &format!("{base}/api/v1/calibration"), None);
    assert_eq!(code, 200);
    assert_eq!(active["id"], "cal-0001");
    assert_eq!(active["result"]["camera_from_base"], json!(POSE));
}

/// The ids of the history, newest first.
fn history_ids(base: &str) -> Vec<String> {
    let (code, h) = call("GET", &format!("{base}/api/v1/calibrations"), None);
    assert_eq!(code, 200, "{h}");
    h["calibrations"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["id"].as_str().unwrap().to_string())
        .collect()
}

/// Starts a one-view dry run and waits for it; returns its id.
fn dry_run(base: &str) -> String {
    let (code, body) = call(
        "POST",
        &format!("{base}/api/v1/calibrations"),
        Some(&json!({"dry_run": true, "max_views": 1})),
    );
    assert_eq!(code, 202, "{body}");
    let id = body["id"].as_str().unwrap().to_string();
    wait_final(base, &id);
    id
}

/// A broken `index.json` is quarantined and rebuilt from `runs/`; a lost one too; run
/// directories no record lists get records, so new ids never collide with them.
#[test]
fn a_lost_or_broken_index_is_rebuilt_from_the_runs_and_ids_never_collide() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |_| {});
    let data = dir.path().join("data");
    let d = start(&config, &data);
    let (_, body) = call("POST", &format!("{}/api/v1/calibrations", d.base), None);
    let first = body["id"].as_str().unwrap().to_string();
    let s = wait_final(&d.base, &first);
    assert_eq!(s["state"], "succeeded", "{s}");
    let second = dry_run(&d.base);
    assert_eq!((first.as_str(), second.as_str()), ("cal-0001", "cal-0002"));
    d.stop();

    // Broken JSON: quarantined, and the history comes back from runs/.
    std::fs::write(
        data.join("index.json"),
        "{\"format\": \"easyhec-daemon-index/1\", [",
    )
    .unwrap();
    let d = start(&config, &data);
    assert_eq!(quarantined(&data, "index.json").len(), 1);
    assert_eq!(history_ids(&d.base), ["cal-0002", "cal-0001"]);
    let (_, r) = call(
        "GET",
        &format!("{}/api/v1/calibrations/cal-0001", d.base),
        None,
    );
    assert_eq!(r["state"], "interrupted", "{r}");
    assert_eq!(r["trigger"], "unknown", "{r}");
    assert_eq!(r["views"], s["views"], "views read back from run.json: {r}");
    assert!(r["error"].as_str().unwrap().contains("rebuilt"), "{r}");
    let (code, active) = call("GET", &format!("{}/api/v1/calibration", d.base), None);
    assert_eq!((code, active["id"].as_str()), (200, Some("cal-0001")));
    assert_eq!(dry_run(&d.base), "cal-0003");
    // The rebuilt dry run has no result; the rebuilt full run still activates.
    refused_activation(&d.base, "cal-0002", "result.json");
    let (code, a) = call(
        "POST",
        &format!("{}/api/v1/calibrations/cal-0001/activate", d.base),
        None,
    );
    assert_eq!(code, 200, "{a}");
    d.stop();

    // Lost, with a run directory no record ever listed.
    std::fs::remove_file(data.join("index.json")).unwrap();
    std::fs::create_dir(data.join("runs/cal-0007")).unwrap();
    let d = start(&config, &data);
    assert_eq!(
        history_ids(&d.base),
        ["cal-0007", "cal-0003", "cal-0002", "cal-0001"]
    );
    assert_eq!(dry_run(&d.base), "cal-0008");
    let index: Value =
        serde_json::from_str(&std::fs::read_to_string(data.join("index.json")).unwrap()).unwrap();
    assert_eq!(index["calibrations"].as_array().unwrap().len(), 5);
}

/// Records that fail their checks are quarantined, not served: an id past the id space (which
/// would wrap the next id to `cal-0000`), a duplicate, a `run_dir` outside the data folder, a
/// non-rigid estimate. The next id neither wraps nor lands on an existing folder.
#[test]
fn bad_records_are_quarantined_and_a_huge_id_does_not_wrap_the_next_one() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |_| {});
    let data = dir.path().join("data");
    let huge = format!("cal-{}", u64::MAX);
    let mut bent = record("cal-0004", "failed", false, "runs/cal-0004");
    bent["camera_from_base"] = json!([[2.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]);
    write_index(
        &data,
        &[
            record("cal-0001", "failed", false, "runs/cal-0001"),
            record(&huge, "succeeded", false, &format!("runs/{huge}")),
            record("cal-0001", "succeeded", false, "runs/cal-0001"),
            record("cal-0003", "succeeded", false, "../../elsewhere"),
            bent,
        ],
    );
    std::fs::create_dir_all(data.join("runs").join(&huge)).unwrap();
    std::fs::create_dir_all(data.join("runs/cal-0002")).unwrap();
    let d = start(&config, &data);
    // cal-0002 had a folder but no record: it gets one, and the next id skips it.
    assert_eq!(history_ids(&d.base), ["cal-0002", "cal-0001"]);
    let records = quarantined(&data, "index-record-");
    assert_eq!(records.len(), 4, "{records:?}");
    let texts: Vec<String> = records
        .iter()
        .map(|p| std::fs::read_to_string(p).unwrap())
        .collect();
    let max = u64::MAX.to_string();
    for needle in [max.as_str(), "elsewhere", "cal-0004"] {
        assert!(
            texts.iter().any(|t| t.contains(needle)),
            "{needle}: {texts:?}"
        );
    }
    for id in ["cal-0003", "cal-0004", huge.as_str()] {
        let (code, _) = call("GET", &format!("{}/api/v1/calibrations/{id}", d.base), None);
        assert_eq!(code, 404, "{id} is not served");
    }
    let (_, first) = call(
        "GET",
        &format!("{}/api/v1/calibrations/cal-0001", d.base),
        None,
    );
    assert_eq!(
        first["state"], "failed",
        "the first of the duplicates is kept"
    );
    assert_eq!(dry_run(&d.base), "cal-0003");
}

/// A bad `active.json` means no active calibration: it is quarantined with one log line naming
/// the file and field, and never served. Another format version stops the daemon with the tag.
#[test]
fn a_bad_active_json_is_quarantined_and_nothing_is_active() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |_| {});
    let data = dir.path().join("data");
    let mut scaled = POSE;
    scaled[0][1] = -2.0;
    let active = json!({
        "format": "easyhec-daemon-active/1",
        "id": "cal-0001",
        "activated_at": "2026-11-25T10:00:00Z",
        "stale": false,
        "result": result_json(scaled, "converged"),
    });
    write_index(&data, &[]);
    std::fs::write(data.join("active.json"), active.to_string()).unwrap();
    let (mut child, base, log) = spawn_daemon_logged(&config, &data);
    let (code, body) = call("GET", &format!("{base}/api/v1/calibration"), None);
    assert_eq!(code, 404, "a non-rigid pose is not served: {body}");
    let (_, _, metrics) = get_bytes(&format!("{base}/metrics"));
    let metrics = String::from_utf8(metrics).unwrap();
    assert!(
        metrics.lines().any(|l| l == "easyhec_active_calibration 0"),
        "{metrics}"
    );
    assert!(!data.join("active.json").exists());
    assert_eq!(quarantined(&data, "active.json").len(), 1);
    let lines = log.lock().unwrap().clone();
    let line = lines
        .iter()
        .find(|l| l.contains("active.json") && l.contains("quarantined"))
        .unwrap_or_else(|| panic!("no quarantine line in {lines:?}"));
    assert!(line.contains("result.camera_from_base"), "{line}");
    child.kill().unwrap();
    child.wait().unwrap();

    // Another format version stops the daemon, printing the tag as written.
    std::fs::write(
        data.join("index.json"),
        r#"{"format": "easyhec-daemon-index/9", "calibrations": []}"#,
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_easyhec"))
        .args(["daemon", "--listen", "127.0.0.1:0", "--config"])
        .arg(&config)
        .arg("--data")
        .arg(&data)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains("index.json: format: \"easyhec-daemon-index/9\"") && !err.contains("Some("),
        "{err}"
    );
}

/// The p-th percentile (0–100) of sorted durations, in milliseconds.
fn percentile_ms(sorted: &[Duration], p: usize) -> f64 {
    let i = (sorted.len() * p).div_ceil(100).saturating_sub(1);
    sorted[i].as_secs_f64() * 1e3
}

/// Waits until the daemon holds `n` connections open.
fn wait_open(d: &common::daemon::Running, n: u64) {
    let t = Instant::now();
    let open = || {
        d.daemon
            .http
            .open
            .load(std::sync::atomic::Ordering::Relaxed)
    };
    while open() < n {
        assert!(
            t.elapsed() < Duration::from_secs(20),
            "{} of {n} open",
            open()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The issue's load bound: with 1,000 idle connections held open, `/healthz` (each request
/// on a new connection) answers with p99 under 50 ms over 200 requests.
#[test]
fn healthz_stays_fast_with_a_thousand_idle_connections() {
    const IDLE: usize = 1000;
    // Both ends of every connection live in this process.
    raise_open_files(2 * IDLE + 512);
    let dir = tempfile::tempdir().unwrap();
    // Long enough that no idle connection times out during the measurement.
    let config = write_config(dir.path(), |c| c.daemon.header_read_timeout_s = Some(120.0));
    let d = start(&config, &dir.path().join("data"));
    let addr = d.base.trim_start_matches("http://").to_string();
    let idle: Vec<std::net::TcpStream> = (0..IDLE)
        .map(|i| {
            std::net::TcpStream::connect(&addr).unwrap_or_else(|e| panic!("connection {i}: {e}"))
        })
        .collect();
    wait_open(&d, IDLE as u64);
    let url = format!("{}/healthz", d.base);
    let mut times: Vec<Duration> = (0..200)
        .map(|_| {
            let t = Instant::now();
            let (code, body) = call_as("GET", &url, None, None);
            let took = t.elapsed();
            assert_eq!((code, body["status"].as_str()), (200, Some("ok")));
            took
        })
        .collect();
    times.sort();
    let (p50, p99) = (percentile_ms(&times, 50), percentile_ms(&times, 99));
    eprintln!(
        "healthz with {IDLE} idle connections, 200 requests: p50 {p50:.2} ms, p99 {p99:.2} ms, max {:.2} ms",
        percentile_ms(&times, 100)
    );
    let still = d
        .daemon
        .http
        .open
        .load(std::sync::atomic::Ordering::Relaxed);
    assert!(
        still >= IDLE as u64,
        "the idle connections were held throughout: {still}"
    );
    assert!(p99 < 50.0, "p99 {p99:.2} ms (p50 {p50:.2} ms)");
    drop(idle);
}

/// Reads a connection to its end (the server closed it) and says how long that took.
fn read_to_close(s: &mut std::net::TcpStream) -> (String, Duration) {
    use std::io::Read;
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    let t = Instant::now();
    let mut text = Vec::new();
    s.read_to_end(&mut text)
        .unwrap_or_else(|e| panic!("the server did not close the connection: {e}"));
    (String::from_utf8_lossy(&text).to_string(), t.elapsed())
}

/// One connection over `max_connections` gets a 503; a client that sends no request head is
/// closed after `header_read_timeout_s`, one that stalls its upload after `idle_timeout_s`.
#[test]
fn the_connection_limit_and_the_timeouts_close_clients_that_hold_the_daemon() {
    use std::io::Write;
    use std::sync::atomic::Ordering::Relaxed;
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |c| {
        c.daemon.max_connections = Some(4);
        c.daemon.header_read_timeout_s = Some(1.0);
        c.daemon.idle_timeout_s = Some(2.0);
    });
    let d = start(&config, &dir.path().join("data"));
    let addr = d.base.trim_start_matches("http://").to_string();
    let mut idle: Vec<std::net::TcpStream> = (0..4)
        .map(|_| std::net::TcpStream::connect(&addr).unwrap())
        .collect();
    wait_open(&d, 4);
    let mut fifth = std::net::TcpStream::connect(&addr).unwrap();
    fifth
        .write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
        .unwrap();
    let (answer, _) = read_to_close(&mut fifth);
    assert!(
        answer.starts_with("HTTP/1.1 503") && answer.contains("max_connections"),
        "{answer}"
    );
    assert_eq!(d.daemon.http.refused.load(Relaxed), 1);
    for s in &mut idle {
        let (text, took) = read_to_close(s);
        assert!(
            text.is_empty() || text.starts_with("HTTP/1.1 408"),
            "{text}"
        );
        assert!(took < Duration::from_secs(4), "closed after {took:?}");
    }
    assert_eq!(d.daemon.http.header_timeouts.load(Relaxed), 4);

    // A stalled upload: the head arrives, 10 of 100 body bytes, then nothing.
    let mut stalled = std::net::TcpStream::connect(&addr).unwrap();
    let head = format!(
        "POST /api/v1/calibrations HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {}\r\nContent-Type: application/json\r\nContent-Length: 100\r\n\r\n{{\"dry_run\"",
        common::daemon::TOKEN
    );
    stalled.write_all(head.as_bytes()).unwrap();
    let (_, took) = read_to_close(&mut stalled);
    assert!(
        took >= Duration::from_millis(1500) && took < Duration::from_secs(6),
        "closed after {took:?}"
    );
    assert_eq!(d.daemon.http.idle_timeouts.load(Relaxed), 1);
    assert!(
        history_ids(&d.base).is_empty(),
        "the stalled request started nothing"
    );
    let (code, _) = call_as("GET", &format!("{}/healthz", d.base), None, None);
    assert_eq!(code, 200);
}

/// An overlay is rendered once per view and estimate; asking again is served from the cache.
#[test]
fn overlays_are_rendered_once_and_then_cached() {
    use std::sync::atomic::Ordering::Relaxed;
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |_| {});
    let d = start(&config, &dir.path().join("data"));
    let (_, body) = call("POST", &format!("{}/api/v1/calibrations", d.base), None);
    let id = body["id"].as_str().unwrap().to_string();
    assert_eq!(wait_final(&d.base, &id)["state"], "succeeded");
    let url = format!("{}/api/v1/calibrations/{id}/views/0/overlay.png", d.base);
    let (code, ctype, first) = get_bytes(&url);
    assert_eq!((code, ctype.as_str()), (200, "image/png"));
    for _ in 0..5 {
        let (code, _, again) = get_bytes(&url);
        assert_eq!(code, 200);
        assert_eq!(again, first, "the cached PNG is the rendered one");
    }
    assert_eq!(d.daemon.metrics.overlay_renders.load(Relaxed), 1);
    assert_eq!(d.daemon.metrics.overlay_hits.load(Relaxed), 5);
    let (_, _, text) = get_bytes(&format!("{}/metrics", d.base));
    let text = String::from_utf8(text).unwrap();
    assert!(
        text.lines().any(|l| l == "easyhec_overlay_renders_total 1"),
        "{text}"
    );
}

/// Under systemd (`Type=notify`, `WatchdogSec`): the daemon reports READY=1 once it listens,
/// pings the watchdog at half the interval, and says STOPPING=1 on SIGTERM before it exits 0.
#[test]
fn daemon_speaks_the_systemd_notify_protocol() {
    use std::os::unix::net::UnixDatagram;
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |_| {});
    let socket = dir.path().join("notify");
    let manager = UnixDatagram::bind(&socket).unwrap();
    manager
        .set_read_timeout(Some(Duration::from_secs(60)))
        .unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_easyhec"))
        .args(["daemon", "--listen", "127.0.0.1:0", "--config"])
        .arg(&config)
        .arg("--data")
        .arg(dir.path().join("data"))
        .env_remove("EASYHEC_TOKEN")
        .env("NOTIFY_SOCKET", &socket)
        .env("WATCHDOG_USEC", "200000")
        .stderr(Stdio::null())
        .spawn()
        .expect("easyhec runs");
    let next = || {
        let mut buf = [0u8; 256];
        let n = manager.recv(&mut buf).expect("a notice within 60 s");
        String::from_utf8_lossy(&buf[..n]).into_owned()
    };
    let ready = next();
    assert!(
        ready.starts_with("READY=1\nSTATUS=listening on http://127.0.0.1:"),
        "{ready}"
    );
    let t = Instant::now();
    let pings = (0..3).filter(|_| next() == "WATCHDOG=1").count();
    assert_eq!(pings, 3);
    assert!(t.elapsed() < Duration::from_secs(5), "pings every 0.1 s");
    let status = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let stopping = (0..100).map(|_| next()).find(|m| m != "WATCHDOG=1");
    assert_eq!(stopping.as_deref(), Some("STOPPING=1"));
    assert!(child.wait().unwrap().success());
}

/// `contrib/easyhec.service` passes `systemd-analyze verify` (with ExecStart pointed at this
/// build, since verify checks that the program exists). Where systemd is not installed the
/// test says so and checks nothing else.
#[test]
fn service_unit_verifies() {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let unit = std::fs::read_to_string(root.join("contrib/easyhec.service")).unwrap();
    assert!(unit.contains("Type=notify") && unit.contains("WatchdogSec="));
    assert!(unit.contains("User=easyhec") && unit.contains("--data /var/lib/easyhec"));
    if Command::new("systemd-analyze")
        .arg("--version")
        .output()
        .is_err()
    {
        eprintln!("SKIPPED: systemd-analyze is not installed, so the unit is not verified");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let copy = dir.path().join("easyhec.service");
    std::fs::write(
        &copy,
        unit.replace("/usr/local/bin/easyhec", env!("CARGO_BIN_EXE_easyhec")),
    )
    .unwrap();
    let out = Command::new("systemd-analyze")
        .arg("verify")
        .arg(&copy)
        .output()
        .unwrap();
    assert!(
        out.status.success() && out.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The access log: exactly one line per request, with method, path and final status (a 404
/// and a 401 too), and never the query string (a `?token=` stays out of the log).
#[test]
fn every_request_gets_one_access_line() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |_| {});
    let data = dir.path().join("data");
    let (child, base, log) = spawn_daemon_logged(&config, &data);
    let _child = KillOnDrop(child);
    let requests = [
        ("GET", "/healthz", 200),
        ("GET", "/api/v1/calibrations", 200),
        ("GET", "/api/v1/no-such-route", 404),
        ("POST", "/api/v1/checks", 401),
        ("GET", "/?token=do-not-log-me", 200),
    ];
    for (method, path, code) in requests {
        let (got, body) = call_as(method, &format!("{base}{path}"), None, None);
        assert_eq!(got, code, "{method} {path}: {body}");
    }
    let deadline = Instant::now() + Duration::from_secs(10);
    let access = loop {
        let lines = log.lock().unwrap().clone();
        let access: Vec<String> = lines
            .into_iter()
            .filter(|l| l.contains(": access "))
            .collect();
        if access.len() >= requests.len() || Instant::now() > deadline {
            break access;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    assert_eq!(access.len(), requests.len(), "{access:?}");
    for (method, path, code) in requests {
        let path = path.split('?').next().unwrap();
        let want = format!("method={method} path={path}: access status={code} ");
        let n = access.iter().filter(|l| l.starts_with(&want)).count();
        assert_eq!(n, 1, "{want:?} in {access:?}");
    }
    assert!(
        !log.lock()
            .unwrap()
            .iter()
            .any(|l| l.contains("do-not-log-me")),
        "the query string was logged"
    );
}

/// Every documented operation, as (method, path with its parameters filled in, whether the
/// token is required, whether it is accepted, its documented statuses).
type Operation = (String, String, bool, bool, Vec<u16>);

fn documented_operations(doc: &Value) -> Vec<Operation> {
    let mut ops = Vec::new();
    for (path, item) in doc["paths"].as_object().expect("paths") {
        for (method, op) in item.as_object().unwrap() {
            let security = op["security"].as_array().cloned().unwrap_or_default();
            let bearer = security.iter().any(|s| s.get("bearer").is_some());
            let optional = security.is_empty() || security.iter().any(|s| s == &json!({}));
            let url = path
                .replace("{id}", "cal-0999")
                .replace("{n}", "0")
                .replace("{k}", "0")
                .replace("{format}", "opencv");
            let codes = op["responses"]
                .as_object()
                .unwrap()
                .keys()
                .map(|k| k.parse().unwrap())
                .collect();
            ops.push((
                method.to_uppercase(),
                url,
                bearer && !optional,
                bearer,
                codes,
            ));
        }
    }
    ops
}

/// The generated OpenAPI document and the router agree: the daemon serves the document the
/// library generates; every documented operation is routed (never the fallback 404 or a 405);
/// every other method on a documented path is 405; the token is required exactly where the
/// document says, with `protect_reads` off and on; and no route is registered outside the
/// annotated handlers.
#[test]
fn the_openapi_document_and_the_router_agree() {
    let dir = tempfile::tempdir().unwrap();
    let generated: Value = serde_json::from_str(easyhec::daemon::openapi::document()).unwrap();
    let ops = documented_operations(&generated);
    assert!(ops.len() >= 15, "{ops:?}");
    for protect_reads in [false, true] {
        let sub = dir.path().join(format!("protect-{protect_reads}"));
        std::fs::create_dir_all(&sub).unwrap();
        let config = write_config(&sub, |c| c.daemon.protect_reads = protect_reads);
        let d = start(&config, &sub.join("data"));
        let base = &d.base;
        let (code, served) = call_as("GET", &format!("{base}/openapi.json"), None, None);
        assert_eq!((code, &served), (200, &generated), "served != generated");
        for (method, path, required, accepted, codes) in &ops {
            let (code, body) = call_as(method, &format!("{base}{path}"), None, None);
            assert!(
                codes.contains(&code),
                "{method} {path} answered {code}, not among its documented {codes:?}: {body}"
            );
            let routed = !body["error"]
                .as_str()
                .unwrap_or("")
                .contains("no such route")
                && code != 405;
            assert!(
                routed,
                "{method} {path} is documented but not routed: {code} {body}"
            );
            let needs_token = *required || (protect_reads && *accepted);
            assert_eq!(
                code == 401,
                needs_token,
                "{method} {path} (protect_reads {protect_reads}): {code} {body}"
            );
        }
        let paths: std::collections::BTreeSet<&String> = ops.iter().map(|o| &o.1).collect();
        for path in paths {
            for method in ["GET", "POST", "PUT", "DELETE", "PATCH"] {
                if ops.iter().any(|o| &o.1 == path && o.0 == method) {
                    continue;
                }
                let (code, body) = call_as(method, &format!("{base}{path}"), Some(TOKEN), None);
                assert_eq!(
                    code, 405,
                    "{method} {path} is served but not documented: {body}"
                );
            }
        }
    }
    // Routes come only from annotated handlers (`routes!`): a plain axum registration in the
    // daemon would serve a route the document does not list.
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/daemon");
    for entry in std::fs::read_dir(&src).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "rs") {
            let text = std::fs::read_to_string(&path).unwrap();
            for bad in [".route(", ".route_service(", ".nest(", ".nest_service("] {
                assert!(
                    !text.contains(bad),
                    "{}: {bad} outside routes!",
                    path.display()
                );
            }
        }
    }
}

/// A spawned daemon, killed when the test ends or fails (a leaked one would hold the test's
/// output pipes open).
struct KillOnDrop(Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Every file under `dir` with its bytes, for "nothing on disk changed".
fn folder_bytes(dir: &Path) -> Vec<(std::path::PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push((p.clone(), std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

/// Runs the real binary as a second daemon; returns its exit status, how long it took and
/// its stderr.
fn second_daemon(
    config: &Path,
    data: &Path,
    listen: &str,
) -> (std::process::ExitStatus, Duration, String) {
    let t = Instant::now();
    let out = Command::new(env!("CARGO_BIN_EXE_easyhec"))
        .args(["daemon", "--listen", listen, "--config"])
        .arg(config)
        .arg("--data")
        .arg(data)
        .env_remove("EASYHEC_TOKEN")
        .output()
        .expect("easyhec runs");
    (
        out.status,
        t.elapsed(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn one_daemon_per_data_folder_and_a_failed_start_changes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |_| {});
    let data = dir.path().join("data");
    let (mut first, base) = spawn_daemon(&config, &data);
    let (code, body) = call(
        "POST",
        &format!("{base}/api/v1/calibrations"),
        Some(&json!({"dry_run": true, "max_views": 1})),
    );
    assert_eq!(code, 202, "{body}");
    wait_final(&base, body["id"].as_str().unwrap());
    let before = folder_bytes(&data);

    let (status, took, err) = second_daemon(&config, &data, "127.0.0.1:0");
    assert!(!status.success(), "a second daemon started: {err}");
    assert!(took < Duration::from_secs(1), "took {took:?}");
    let pid = first.id().to_string();
    assert!(
        err.contains(&pid) && err.contains("another easyhec daemon"),
        "{err}"
    );
    assert_eq!(
        folder_bytes(&data),
        before,
        "the second daemon changed the folder"
    );

    // A daemon whose port is taken leaves an unlocked folder as it found it: the run the
    // index still calls running is not marked interrupted by a start that cannot serve.
    first.kill().unwrap();
    first.wait().unwrap();
    let index = data.join("index.json");
    let mut v: Value = serde_json::from_str(&std::fs::read_to_string(&index).unwrap()).unwrap();
    v["calibrations"][0]["state"] = json!("running");
    std::fs::write(&index, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    let before = folder_bytes(&data);
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let listen = taken.local_addr().unwrap().to_string();
    let (status, _, err) = second_daemon(&config, &data, &listen);
    assert!(!status.success() && err.contains("--listen"), "{err}");
    assert_eq!(
        folder_bytes(&data),
        before,
        "a failed bind repaired the folder"
    );
}

#[test]
fn without_a_data_folder_the_daemon_keeps_its_state_outside_the_config_folder() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |c| c.daemon.data_dir = None);
    let state = dir.path().join("state");
    let mut child = Command::new(env!("CARGO_BIN_EXE_easyhec"))
        .args(["daemon", "--listen", "127.0.0.1:0", "--config"])
        .arg(&config)
        .env_remove("EASYHEC_TOKEN")
        .env_remove("STATE_DIRECTORY")
        .env("XDG_STATE_HOME", &state)
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    std::io::BufReader::new(child.stderr.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    child.kill().unwrap();
    child.wait().unwrap();
    let expected = state.join("easyhec");
    assert!(
        line.contains(&format!("(data {})", expected.display())),
        "{line}"
    );
    assert!(expected.join("daemon.lock").is_file());
    let beside: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .flatten()
        .map(|e| e.file_name())
        .collect();
    assert!(
        !beside.iter().any(|n| n == "easyhec-data"),
        "a data folder appeared beside the config: {beside:?}"
    );
}

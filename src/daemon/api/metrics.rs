//! `/metrics`: counters and gauges in the Prometheus text format.

use std::sync::atomic::{AtomicU64, Ordering};

use axum::extract::State;
use axum::http::header;
use axum::response::{IntoResponse, Response};

use super::Shared;
use crate::daemon::openapi::ErrorBody;
use crate::daemon::store::State as RunState;
use crate::daemon::{Busy, Daemon, FINISHED_STATES};

/// Appends one metric in the Prometheus text format.
pub(super) fn metric(s: &mut String, name: &str, kind: &str, help: &str, lines: &[(String, f64)]) {
    use std::fmt::Write;
    let _ = writeln!(s, "# HELP {name} {help}\n# TYPE {name} {kind}");
    for (labels, v) in lines {
        let _ = writeln!(s, "{name}{labels} {v}");
    }
}

/// One unlabelled value.
pub(super) fn one(v: f64) -> Vec<(String, f64)> {
    vec![(String::new(), v)]
}

/// A counter's value.
pub(super) fn count(a: &AtomicU64) -> f64 {
    a.load(Ordering::Relaxed) as f64
}

/// Counters and gauges in the Prometheus text format.
#[utoipa::path(get, path = "/metrics", tag = "service",
    responses(
        (status = 200, description = "Prometheus text format 0.0.4", content_type = "text/plain", body = String),
        (status = 401, description = "Missing or wrong token (only with protect_reads)", body = ErrorBody)),
    security((), ("bearer" = [])))]
pub(super) async fn metrics(State(d): State<Shared>) -> Response {
    let mut s = String::new();
    calibration_metrics(&d, &mut s);
    check_metrics(&d, &mut s);
    server_metrics(&d, &mut s);
    (
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        s,
    )
        .into_response()
}

/// Calibrations: started, finished by state, running, views, active, stale, interrupted.
pub(super) fn calibration_metrics(d: &Daemon, s: &mut String) {
    let m = &d.metrics;
    metric(
        s,
        "easyhec_calibrations_started_total",
        "counter",
        "Calibrations started since the daemon started.",
        &one(count(&m.started)),
    );
    let finished: Vec<(String, f64)> = FINISHED_STATES
        .iter()
        .zip(&m.finished)
        .map(|(st, c)| (format!("{{state=\"{}\"}}", st.name()), count(c)))
        .collect();
    metric(
        s,
        "easyhec_calibrations_finished_total",
        "counter",
        "Calibrations ended since the daemon started, by final state.",
        &finished,
    );
    let running = matches!(d.busy(), Some(Busy::Calibration(_)));
    metric(
        s,
        "easyhec_calibration_running",
        "gauge",
        "1 while a calibration runs.",
        &one(f64::from(u8::from(running))),
    );
    metric(
        s,
        "easyhec_views_captured_total",
        "counter",
        "Views captured by calibrations.",
        &one(count(&m.views)),
    );
    // A list of cameras counts as active when any camera is, and stale when any camera is.
    let active = d.store().active_all();
    metric(
        s,
        "easyhec_active_calibration",
        "gauge",
        "1 when a calibration is active.",
        &one(f64::from(u8::from(!active.is_empty()))),
    );
    metric(
        s,
        "easyhec_calibration_stale",
        "gauge",
        "1 when a bump check found the active calibration no longer fits.",
        &one(f64::from(u8::from(active.iter().any(|a| a.stale)))),
    );
    let interrupted = d
        .store()
        .records()
        .iter()
        .filter(|r| r.state == RunState::Interrupted)
        .count();
    metric(
        s,
        "easyhec_calibrations_interrupted_in_history",
        "gauge",
        "Calibrations in the history that a shutdown or crash interrupted.",
        &one(interrupted as f64),
    );
}

/// Bump checks: run, bumps, errors, and the last check's agreement.
pub(super) fn check_metrics(d: &Daemon, s: &mut String) {
    let m = &d.metrics;
    metric(
        s,
        "easyhec_bump_checks_total",
        "counter",
        "Bump checks run.",
        &one(count(&m.checks)),
    );
    metric(
        s,
        "easyhec_bumps_detected_total",
        "counter",
        "Bump checks that found the camera moved.",
        &one(count(&m.bumps)),
    );
    metric(
        s,
        "easyhec_bump_check_errors_total",
        "counter",
        "Bump checks that failed (capture, motion, segmentation).",
        &one(count(&m.check_errors)),
    );
    if m.checks.load(Ordering::Relaxed) > 0 {
        metric(
            s,
            "easyhec_last_check_iou",
            "gauge",
            "IoU of the last bump check.",
            &one(f64::from_bits(m.last_iou.load(Ordering::Relaxed))),
        );
        metric(
            s,
            "easyhec_last_check_boundary_px",
            "gauge",
            "Mean outline distance of the last bump check, pixels.",
            &one(f64::from_bits(m.last_boundary_px.load(Ordering::Relaxed))),
        );
    }
}

/// The HTTP server and the overlay cache.
pub(super) fn server_metrics(d: &Daemon, s: &mut String) {
    let (m, h) = (&d.metrics, &d.http);
    metric(
        s,
        "easyhec_overlay_renders_total",
        "counter",
        "Overlays rendered (a cached one is not rendered again).",
        &one(count(&m.overlay_renders)),
    );
    metric(
        s,
        "easyhec_overlay_cache_hits_total",
        "counter",
        "Overlays served from the cache.",
        &one(count(&m.overlay_hits)),
    );
    metric(
        s,
        "easyhec_http_connections_open",
        "gauge",
        "HTTP connections open now.",
        &one(count(&h.open)),
    );
    metric(
        s,
        "easyhec_http_connections_refused_total",
        "counter",
        "Connections refused with 503 at [daemon] max_connections.",
        &one(count(&h.refused)),
    );
    let timeouts = vec![
        ("{reason=\"header\"}".to_string(), count(&h.header_timeouts)),
        ("{reason=\"idle\"}".to_string(), count(&h.idle_timeouts)),
    ];
    metric(
        s,
        "easyhec_http_connections_timed_out_total",
        "counter",
        "Connections closed by the header-read or idle timeout.",
        &timeouts,
    );
}

//! The HTTP API (axum). Every route that acts (`POST`: start, cancel, activate, check) needs
//! `Authorization: Bearer TOKEN`; read-only routes (`GET`) are open unless `[daemon]
//! protect_reads = true`; `/`, `/app.js`, `/openapi.json` and `/healthz` are always open. Errors are JSON
//! `{"error": "…"}`; a start while the arm is leased is 409 with `"running": ID`.
//!
//! The routes are split by resource (calibrations, overlays, cameras, checks, metrics), with
//! the service routes and the request layers (access log, JSON errors, token) apart. Each
//! handler carries its `#[utoipa::path]` (method, path, bodies, security), and [`routes`]
//! registers it from that annotation, so `/openapi.json` ([`super::openapi`]) lists exactly
//! the routes served.

use std::sync::Arc;

use axum::body::Bytes;
use axum::extract::DefaultBodyLimit;
use axum::http::{header, HeaderMap, StatusCode};
use axum::middleware;
use axum::response::{IntoResponse, Response};
use axum::{Json, Router};

use utoipa::OpenApi;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::openapi::{self, ErrorBody};
use super::store::CalibrationRecord;
use super::validate::{id_number, id_problem, inside};
use super::{Busy, Daemon, Refusal};

mod calibrations;
mod cameras;
mod checks;
mod layers;
mod metrics;
mod overlay;
mod service;

use layers::{auth, auth_always, json_errors, with_access_log};

type Shared = Arc<Daemon>;

/// Largest request body (only a start request has one, of a few dozen bytes).
pub const BODY_LIMIT: usize = 64 * 1024;
/// Longest error message: a hostile id or field name is echoed only this far.
const MESSAGE_CHARS: usize = 300;

/// An error message as one short line: control characters (a `%0A` in an id, a `\n` in a
/// JSON field name) escaped, cut at [`MESSAGE_CHARS`], so a log or a page that shows it
/// cannot be forged a second line or flooded.
pub fn one_line(m: &str) -> String {
    let mut out: String = m
        .chars()
        .flat_map(|c| {
            let esc: Vec<char> = if c.is_control() {
                c.escape_default().collect()
            } else {
                vec![c]
            };
            esc
        })
        .take(MESSAGE_CHARS + 1)
        .collect();
    if out.chars().count() > MESSAGE_CHARS {
        out = out.chars().take(MESSAGE_CHARS).collect::<String>() + "…";
    }
    out
}

impl IntoResponse for Refusal {
    fn into_response(self) -> Response {
        let (status, body) = match self {
            Refusal::Busy(b) => {
                let what = match &b {
                    Busy::Calibration(id) => format!("calibration {id} is running"),
                    Busy::Check => "a bump check is running".to_string(),
                    Busy::Preview => "a camera preview is being taken".to_string(),
                };
                (
                    StatusCode::CONFLICT,
                    ErrorBody {
                        error: format!("{what}: the daemon runs one thing at a time on the arm; wait for it or cancel it"),
                        running: Some(b.name().to_string()),
                    },
                )
            }
            Refusal::ShuttingDown => (
                StatusCode::SERVICE_UNAVAILABLE,
                ErrorBody::new("the daemon is shutting down".into()),
            ),
            Refusal::NotFound(m) => (StatusCode::NOT_FOUND, ErrorBody::new(one_line(&m))),
            Refusal::Conflict(m) => (StatusCode::CONFLICT, ErrorBody::new(one_line(&m))),
            Refusal::UnsupportedMedia(m) => (
                StatusCode::UNSUPPORTED_MEDIA_TYPE,
                ErrorBody::new(one_line(&m)),
            ),
            Refusal::BadRequest(m) => (StatusCode::BAD_REQUEST, ErrorBody::new(one_line(&m))),
            Refusal::Internal(m) => (
                StatusCode::INTERNAL_SERVER_ERROR,
                ErrorBody::new(one_line(&m)),
            ),
        };
        (status, Json(body)).into_response()
    }
}

/// The routes that need the token (every one that acts; those that read when `[daemon]
/// protect_reads = true`), each registered from its `#[utoipa::path]`.
fn guarded_routes() -> OpenApiRouter<Shared> {
    OpenApiRouter::new()
        .routes(routes!(calibrations::start, calibrations::history))
        .routes(routes!(calibrations::status))
        .routes(routes!(calibrations::events))
        .routes(routes!(overlay::overlay))
        .routes(routes!(calibrations::export_file))
        .routes(routes!(overlay::plan_overlay))
        .routes(routes!(calibrations::cancel))
        .routes(routes!(calibrations::activate))
        .routes(routes!(calibrations::active))
        .routes(routes!(cameras::cameras))
        .routes(routes!(checks::run_check, checks::checks))
        .routes(routes!(metrics::metrics))
}

/// Routes that read but always need the token: the camera preview shows the cell and holds
/// the camera while it grabs.
fn strict_routes() -> OpenApiRouter<Shared> {
    OpenApiRouter::new().routes(routes!(cameras::camera_preview))
}

/// The routes that are always open.
fn open_routes() -> OpenApiRouter<Shared> {
    OpenApiRouter::new()
        .routes(routes!(service::index))
        .routes(routes!(service::app_js))
        .routes(routes!(service::openapi_json))
        .routes(routes!(service::healthz))
}

/// Every route with its description: what [`router`] serves and `/openapi.json` describes.
pub fn routes() -> OpenApiRouter<Shared> {
    OpenApiRouter::with_openapi(openapi::ApiRoot::openapi())
        .merge(open_routes())
        .merge(guarded_routes())
        .merge(strict_routes())
}

/// The whole router: [`routes`], the token check on the guarded ones, JSON errors, the body
/// limit and the access log.
pub fn router(daemon: Shared) -> Router {
    let (guarded, _) = guarded_routes().split_for_parts();
    let guarded = guarded.route_layer(middleware::from_fn_with_state(daemon.clone(), auth));
    let (strict, _) = strict_routes().split_for_parts();
    let strict = strict.route_layer(middleware::from_fn_with_state(daemon.clone(), auth_always));
    let (open, _) = open_routes().split_for_parts();
    let router = open
        .merge(guarded)
        .merge(strict)
        .fallback(|| async {
            (
                StatusCode::NOT_FOUND,
                Json(ErrorBody::new("no such route: see /openapi.json".into())),
            )
        })
        .with_state(daemon)
        .layer(DefaultBodyLimit::max(BODY_LIMIT))
        .layer(middleware::from_fn(json_errors));
    with_access_log(router)
}

/// Whether a content type is JSON (`application/json`, `…+json`, any parameters).
fn is_json(h: &HeaderMap) -> bool {
    h.get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .map(|v| {
            v.split(';')
                .next()
                .unwrap_or("")
                .trim()
                .to_ascii_lowercase()
        })
        .is_some_and(|t| t == "application/json" || t.ends_with("+json"))
}

/// An id from a path, refused (404) unless it is one this daemon makes: a hostile id
/// (`../../etc/passwd`, 10,000 digits) never reaches a lookup, and the message says why.
fn daemon_id(id: String) -> Result<String, Refusal> {
    match id_number(&id) {
        Some(_) => Ok(id),
        None => Err(Refusal::NotFound(format!(
            "calibration id: {}",
            id_problem(&id)
        ))),
    }
}

/// `name` in a calibration's run directory, checked to lie inside the data folder (the
/// records and the folder are read back from disk, so they are not trusted).
fn run_file(
    d: &Daemon,
    record: &CalibrationRecord,
    name: &str,
) -> Result<std::path::PathBuf, Refusal> {
    let store = d.store();
    inside(
        store.dir(),
        store.canonical_dir(),
        &format!("{}/{name}", record.run_dir),
    )
    .map_err(|m| Refusal::Conflict(format!("calibration {}: {name}: {m}", record.id)))
}

/// A calibration's record, or 404.
fn record_of(d: &Daemon, id: &str) -> Result<CalibrationRecord, Refusal> {
    d.status(id)
        .ok_or_else(|| Refusal::NotFound(format!("no calibration {id}")))
}

/// A view or pose index from a path, or 400 naming what it should be.
fn path_index(text: &str, what: &str) -> Result<usize, Refusal> {
    text.parse()
        .map_err(|_| Refusal::BadRequest(format!("{what} {text:?}: use a {what} index (0, 1, …)")))
}

/// A PNG answer that clients must not cache (the daemon's cache keys on what it shows).
fn png_response(png: Bytes) -> Response {
    (
        [
            (header::CONTENT_TYPE, "image/png"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        png,
    )
        .into_response()
}

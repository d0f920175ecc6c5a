//! The HTTP API (axum). Every route that acts (`POST`: start, cancel, activate, check) needs
//! `Authorization: Bearer TOKEN`; read-only routes (`GET`) are open unless `[daemon]
//! protect_reads = true`; `/`, `/app.js`, `/openapi.json` and `/healthz` are always open. Errors are JSON
//! `{"error": "…"}`; a start while the arm is leased is 409 with `"running": ID`.
//!
//! Each handler carries its `#[utoipa::path]` (method, path, bodies, security), and [`routes`]
//! registers it from that annotation, so `/openapi.json` ([`super::openapi`]) lists exactly
//! the routes served.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use axum::body::{Body, Bytes};
use axum::extract::{DefaultBodyLimit, Path, RawQuery, Request, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::middleware::{self, Next};
use axum::response::sse::{Event as SseEvent, KeepAlive, Sse};
use axum::response::{Html, IntoResponse, Response};
use axum::{Json, Router};
use tokio::sync::broadcast;

use utoipa::OpenApi;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::openapi::{
    self, ActiveCalibration, CameraState, Cameras, Cancelling, Checks, ErrorBody, Health, History,
    Png, Started,
};
use super::store::{
    ActiveFile, CalibrationRecord, CheckRecord, RigActiveFile, State as RunState, RIG_ACTIVE_FORMAT,
};
use super::validate::{id_number, id_problem, inside};
use super::{bump, overlays, Busy, Daemon, Event, Refusal, StartOptions, FINISHED_STATES};
use crate::geometry::from_rows;
use crate::run::ViewEntry;

/// The web page (embedded; no build step).
const INDEX_HTML: &str = include_str!("web/index.html");
/// The page's script.
const APP_JS: &str = include_str!("web/app.js");

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
        .routes(routes!(start, history))
        .routes(routes!(status))
        .routes(routes!(events))
        .routes(routes!(overlay))
        .routes(routes!(export_file))
        .routes(routes!(plan_overlay))
        .routes(routes!(cancel))
        .routes(routes!(activate))
        .routes(routes!(active))
        .routes(routes!(cameras))
        .routes(routes!(run_check, checks))
        .routes(routes!(metrics))
}

/// Routes that read but always need the token: the camera preview shows the cell and holds
/// the camera while it grabs.
fn strict_routes() -> OpenApiRouter<Shared> {
    OpenApiRouter::new().routes(routes!(camera_preview))
}

/// The routes that are always open.
fn open_routes() -> OpenApiRouter<Shared> {
    OpenApiRouter::new()
        .routes(routes!(index))
        .routes(routes!(app_js))
        .routes(routes!(openapi_json))
        .routes(routes!(healthz))
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

/// The web page (embedded; no build step).
#[utoipa::path(get, path = "/", tag = "service",
    responses((status = 200, description = "The web page", content_type = "text/html", body = String)))]
async fn index() -> Html<&'static str> {
    Html(INDEX_HTML)
}

/// The page's script.
#[utoipa::path(get, path = "/app.js", tag = "service",
    responses((status = 200, description = "The page's script", content_type = "text/javascript", body = String)))]
async fn app_js() -> Response {
    (
        [(header::CONTENT_TYPE, "text/javascript; charset=utf-8")],
        APP_JS,
    )
        .into_response()
}

/// This document, generated from the handlers and their types.
#[utoipa::path(get, path = "/openapi.json", tag = "service",
    responses((status = 200, description = "The OpenAPI 3.1 description of this API", content_type = "application/json", body = Object)))]
async fn openapi_json() -> Response {
    (
        [(header::CONTENT_TYPE, "application/json")],
        openapi::document(),
    )
        .into_response()
}

/// The access log: one `info` record per request, target `easyhec::access`, in a span that
/// carries the method and path (never the query or headers: a `?token=` stays out of logs),
/// with the final status (after [`json_errors`]) and the time to the response head. Events
/// logged while a handler runs carry the same span.
fn with_access_log(router: Router) -> Router {
    router.layer(
    tower_http::trace::TraceLayer::new_for_http()
        .make_span_with(|req: &Request| {
            tracing::info_span!("http", method = %req.method(), path = %req.uri().path())
        })
        .on_request(())
        .on_response(
            |resp: &Response, latency: std::time::Duration, _: &tracing::Span| {
                tracing::info!(
                    target: "easyhec::access",
                    status = resp.status().as_u16(),
                    ms = (latency.as_secs_f64() * 1e4).round() / 10.0,
                    "access"
                );
            },
        )
        .on_body_chunk(())
        .on_eos(())
        .on_failure(()),
    )
}

/// Every error as `{"error": …}` on one line, the framework's too (405, 413, a path that
/// does not decode come from axum as plain text or nothing), and a declared body over
/// [`BODY_LIMIT`] refused at once: waiting for 100 GB that never come would hold the
/// connection until the idle timeout.
async fn json_errors(req: Request, next: Next) -> Response {
    let declared = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok()?.parse::<u64>().ok());
    if let Some(n) = declared.filter(|n| *n > BODY_LIMIT as u64) {
        let m = format!("request body: Content-Length {n} is over the {BODY_LIMIT}-byte limit");
        return (StatusCode::PAYLOAD_TOO_LARGE, Json(ErrorBody::new(m))).into_response();
    }
    let (method, path) = (req.method().clone(), req.uri().path().to_string());
    let resp = next.run(req).await;
    let status = resp.status();
    if !(status.is_client_error() || status.is_server_error()) || is_json(resp.headers()) {
        return resp;
    }
    let (mut parts, body) = resp.into_parts();
    let text = axum::body::to_bytes(body, 4096).await.unwrap_or_default();
    let text = String::from_utf8_lossy(&text).trim().to_string();
    let m = match status {
        StatusCode::METHOD_NOT_ALLOWED => {
            format!("method {method} is not allowed on {path}: see /openapi.json")
        }
        StatusCode::PAYLOAD_TOO_LARGE => format!("request body: over the {BODY_LIMIT}-byte limit"),
        _ if text.is_empty() => status.to_string(),
        _ => text,
    };
    parts.headers.remove(header::CONTENT_LENGTH);
    parts.headers.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/json"),
    );
    let body = serde_json::to_string(&ErrorBody::new(one_line(&m))).unwrap_or_default();
    Response::from_parts(parts, Body::from(body))
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

/// Longest wait for a preview frame.
const PREVIEW_GRAB: std::time::Duration = std::time::Duration::from_secs(10);

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

/// The token check of the guarded routes: reads pass without it unless `protect_reads`.
async fn auth(State(d): State<Shared>, req: Request, next: Next) -> Response {
    let read_only = matches!(
        *req.method(),
        axum::http::Method::GET | axum::http::Method::HEAD
    );
    if read_only && !d.settings().protect_reads {
        return next.run(req).await;
    }
    auth_always(State(d), req, next).await
}

/// The token check, whatever the method.
async fn auth_always(State(d): State<Shared>, req: Request, next: Next) -> Response {
    let given = req
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(bearer_token);
    match given {
        Some(t) if d.token_matches(t) => next.run(req).await,
        _ => {
            let mut r = (
                StatusCode::UNAUTHORIZED,
                Json(ErrorBody::new(
                    "missing or wrong token: send `Authorization: Bearer TOKEN` with the daemon's token ([daemon] token or EASYHEC_TOKEN)".into(),
                )),
            )
                .into_response();
            r.headers_mut().insert(
                header::WWW_AUTHENTICATE,
                HeaderValue::from_static("Bearer realm=\"easyhec\""),
            );
            r
        }
    }
}

/// The token of an `Authorization` value of exactly the documented form: the scheme
/// `Bearer` (any case, RFC 7235), one space, and the token with nothing around it.
fn bearer_token(value: &str) -> Option<&str> {
    let (scheme, token) = value.split_at_checked(7)?;
    let plain = !token.is_empty() && !token.chars().any(|c| c.is_whitespace() || c.is_control());
    (scheme.eq_ignore_ascii_case("Bearer ") && plain).then_some(token)
}

/// Liveness, and what holds the arm.
#[utoipa::path(get, path = "/healthz", tag = "service",
    responses((status = 200, description = "The daemon answers", body = Health)))]
async fn healthz(State(d): State<Shared>) -> Json<Health> {
    Json(Health {
        status: "ok".into(),
        busy: d.busy().map(|b| b.name().to_string()),
    })
}

/// Starts a calibration (or, with `dry_run`, plans one without moving).
#[utoipa::path(post, path = "/api/v1/calibrations", tag = "calibrations",
    request_body(content = Option<StartOptions>, content_type = "application/json",
        description = "Optional; an empty body means the config's defaults"),
    responses(
        (status = 202, description = "Started; follow it at the Location", body = Started,
            headers(("Location" = String, description = "/api/v1/calibrations/{id}"))),
        (status = 400, description = "A field is wrong (the error names it)", body = ErrorBody),
        (status = 401, description = "Missing or wrong token", body = ErrorBody),
        (status = 409, description = "The arm is leased; `running` names the holder", body = ErrorBody),
        (status = 413, description = "Body over 64 KiB", body = ErrorBody),
        (status = 415, description = "Body is not JSON", body = ErrorBody),
        (status = 503, description = "The daemon is shutting down", body = ErrorBody)),
    security(("bearer" = [])))]
async fn start(
    State(d): State<Shared>,
    headers: HeaderMap,
    body: Bytes,
) -> Result<Response, Refusal> {
    let opts = start_options(&headers, &body)?;
    let id = d.start(opts, "api", None)?;
    Ok((
        StatusCode::ACCEPTED,
        [(header::LOCATION, format!("/api/v1/calibrations/{id}"))],
        Json(Started { id }),
    )
        .into_response())
}

/// A start request's options: empty means the defaults; otherwise a JSON body (a declared
/// non-JSON content type is refused, 415), each error naming the field it is about.
fn start_options(headers: &HeaderMap, body: &[u8]) -> Result<StartOptions, Refusal> {
    if body.iter().all(u8::is_ascii_whitespace) {
        return Ok(StartOptions::default());
    }
    if headers.contains_key(header::CONTENT_TYPE) && !is_json(headers) {
        let given = headers
            .get(header::CONTENT_TYPE)
            .map(|v| v.to_str().unwrap_or("?"));
        return Err(Refusal::UnsupportedMedia(format!(
            "Content-Type: {:?} is not JSON: send the request body as application/json",
            given.unwrap_or_default()
        )));
    }
    // An array would otherwise be read field by field in order (`[1, true]` as max_views 1,
    // dry_run true): only an object names its fields.
    let first = body.iter().find(|b| !b.is_ascii_whitespace());
    if first != Some(&b'{') {
        return Err(Refusal::BadRequest(
            "request body: not a JSON object (expected {\"max_views\": N, \"dry_run\": false, \"cameras\": [NAME]}, each optional)".into(),
        ));
    }
    let mut de = serde_json::Deserializer::from_slice(body);
    let opts = serde_path_to_error::deserialize(&mut de)
        .map_err(|e| bad_body(&e.path().to_string(), e.inner()))?;
    de.end().map_err(|e| bad_body(".", &e))?;
    Ok(opts)
}

/// A 400 for a start body, naming the field (`at`, `.` for the whole body).
fn bad_body(at: &str, e: &serde_json::Error) -> Refusal {
    let field = if at == "." {
        String::new()
    } else {
        format!("{at}: ")
    };
    Refusal::BadRequest(format!(
        "request body: {field}{e} (expected {{\"max_views\": N, \"dry_run\": false, \"cameras\": [NAME]}}, each optional; cameras only for [[camera]] tables)"
    ))
}

/// Every calibration on record, newest first, and the active one's id.
#[utoipa::path(get, path = "/api/v1/calibrations", tag = "calibrations",
    responses(
        (status = 200, description = "The history", body = History),
        (status = 401, description = "Missing or wrong token (only with protect_reads)", body = ErrorBody)),
    security((), ("bearer" = [])))]
async fn history(State(d): State<Shared>) -> Json<History> {
    let mut records = d.store().records();
    // Live records are fresher than the index for the running one.
    for r in &mut records {
        if let Some(j) = d.job(&r.id) {
            *r = j.record();
        }
    }
    records.reverse();
    let active = d.store().active().map(|a| a.id);
    Json(History {
        calibrations: records,
        active,
    })
}

/// One calibration's status.
#[utoipa::path(get, path = "/api/v1/calibrations/{id}", tag = "calibrations",
    params(("id" = String, Path, description = "A calibration id, `cal-NNNN`")),
    responses(
        (status = 200, description = "Its status", body = CalibrationRecord),
        (status = 401, description = "Missing or wrong token (only with protect_reads)", body = ErrorBody),
        (status = 404, description = "No such calibration", body = ErrorBody)),
    security((), ("bearer" = [])))]
async fn status(State(d): State<Shared>, Path(id): Path<String>) -> Result<Response, Refusal> {
    let id = daemon_id(id)?;
    record_of(&d, &id).map(|r| Json(r).into_response())
}

fn sse_event(e: &Event) -> SseEvent {
    SseEvent::default()
        .event(e.kind.clone())
        .json_data(e)
        .unwrap_or_else(|_| SseEvent::default().comment("unserialisable event"))
}

/// Server-sent events: the status now (`state`), then one event per change (`view`, `round`,
/// `planned`, `moving`, `state`) until the calibration ends.
#[utoipa::path(get, path = "/api/v1/calibrations/{id}/events", tag = "calibrations",
    params(("id" = String, Path, description = "A calibration id, `cal-NNNN`")),
    responses(
        (status = 200, description = "An event stream; each event's data is one Event", content_type = "text/event-stream", body = Event),
        (status = 401, description = "Missing or wrong token (only with protect_reads)", body = ErrorBody),
        (status = 404, description = "No such calibration", body = ErrorBody)),
    security((), ("bearer" = [])))]
async fn events(State(d): State<Shared>, Path(id): Path<String>) -> Result<Response, Refusal> {
    let id = daemon_id(id)?;
    // Subscribe before reading the snapshot so no event falls between them.
    let rx: Option<broadcast::Receiver<Event>> = d.job(&id).map(|j| j.subscribe());
    let snapshot = record_of(&d, &id)?;
    let first = Event {
        kind: "state".into(),
        view: None,
        status: snapshot,
    };
    let shutdown = d.shutdown_signal();
    struct St {
        first: Option<Event>,
        rx: Option<broadcast::Receiver<Event>>,
        shutdown: tokio::sync::watch::Receiver<bool>,
        done: bool,
    }
    let init = St {
        first: Some(first),
        rx,
        shutdown,
        done: false,
    };
    let stream = futures_util::stream::unfold(init, |mut st| async move {
        if st.done {
            return None;
        }
        if let Some(e) = st.first.take() {
            st.done = e.status.state.is_final() || st.rx.is_none();
            return Some((Ok::<_, std::convert::Infallible>(sse_event(&e)), st));
        }
        let rx = st.rx.as_mut()?;
        loop {
            tokio::select! {
                r = rx.recv() => match r {
                    Ok(e) => {
                        st.done = e.kind == "state" && e.status.state.is_final();
                        return Some((Ok(sse_event(&e)), st));
                    }
                    Err(broadcast::error::RecvError::Lagged(_)) => continue,
                    Err(broadcast::error::RecvError::Closed) => return None,
                },
                _ = st.shutdown.changed() => return None,
            }
        }
    });
    let every = super::http::keep_alive_interval(d.settings().idle_timeout());
    Ok(Sse::new(stream)
        .keep_alive(KeepAlive::new().interval(every))
        .into_response())
}

/// View `n` with the robot drawn at the calibration's current estimate (green: agreement,
/// red: robot the render misses, blue: render the mask lacks). In a cell of several cameras,
/// `?camera=NAME` picks the camera, drawn under its own estimate.
#[utoipa::path(get, path = "/api/v1/calibrations/{id}/views/{n}/overlay.png", tag = "calibrations",
    params(("id" = String, Path, description = "A calibration id, `cal-NNNN`"),
        ("n" = usize, Path, description = "A view index (0, 1, …)"),
        ("camera" = Option<String>, Query, description = "The camera's name: required in a cell of `[[camera]]` tables, refused in a cell of one `[camera]`")),
    responses(
        (status = 200, description = "The overlay", content_type = "image/png", body = Png),
        (status = 400, description = "`n` is not a view index, or `camera` is missing, unknown or not allowed", body = ErrorBody),
        (status = 401, description = "Missing or wrong token (only with protect_reads)", body = ErrorBody),
        (status = 404, description = "No such calibration or view", body = ErrorBody),
        (status = 409, description = "No estimate yet, or a file leaves the data folder", body = ErrorBody),
        (status = 500, description = "A recorded file does not read back", body = ErrorBody)),
    security((), ("bearer" = [])))]
async fn overlay(
    State(d): State<Shared>,
    Path((id, n)): Path<(String, String)>,
    RawQuery(query): RawQuery,
) -> Result<Response, Refusal> {
    let id = daemon_id(id)?;
    let n = path_index(&n, "view")?;
    let target = overlays::target(d.cell(), query.as_deref())?;
    let record = record_of(&d, &id)?;
    let (run_dir, view) = overlay_view(&d, &record, &target, n)?;
    let rows =
        overlays::estimate(&record, &target, &run_dir.join("rounds.json")).ok_or_else(|| {
            Refusal::Conflict(format!(
                "calibration {id} has no estimate yet: retry after its first round"
            ))
        })?;
    let key = overlays::Key::new(
        &id,
        target.name.as_deref(),
        n,
        &rows,
        overlays::mask_path(&run_dir, &view).as_deref(),
    );
    let png = match d.overlays.get(&key) {
        Some(png) => {
            d.metrics.overlay_hits.fetch_add(1, Ordering::Relaxed);
            png
        }
        None => render_overlay(&d, (target, run_dir), n, view, &rows, key).await?,
    };
    Ok(png_response(png))
}

/// The run directory and view `n` of a calibration (of camera `target`), with the view's
/// files checked to lie inside the data folder (`run.json` is read back from disk, so it is
/// not trusted).
fn overlay_view(
    d: &Daemon,
    record: &CalibrationRecord,
    target: &overlays::Target,
    n: usize,
) -> Result<(std::path::PathBuf, ViewEntry), Refusal> {
    let id = &record.id;
    let store = d.store();
    let run_dir = inside(store.dir(), store.canonical_dir(), &record.run_dir)
        .map_err(|m| Refusal::Conflict(format!("calibration {id}: run_dir: {m}")))?;
    let run = overlays::camera_run(&run_dir.join("run.json"), target)
        .ok()
        .flatten()
        .ok_or_else(|| Refusal::NotFound(format!("calibration {id} has no views yet")))?;
    let Some(view) = run.views.get(n).cloned() else {
        return Err(Refusal::NotFound(format!(
            "calibration {id} has {} views; view {n} does not exist",
            run.views.len()
        )));
    };
    for (field, file) in [("mask", &view.mask), ("image", &view.image)] {
        if let Some(f) = file {
            inside(
                store.dir(),
                store.canonical_dir(),
                &format!("{}/{f}", record.run_dir),
            )
            .map_err(|m| {
                Refusal::Conflict(format!(
                    "calibration {id}: run.json views[{n}].{field}: {m}"
                ))
            })?;
        }
    }
    Ok((run_dir, view))
}

/// Renders an overlay of a camera's view in its run folder on a blocking thread and keeps
/// it in the cache.
async fn render_overlay(
    d: &Shared,
    (target, run_dir): (overlays::Target, std::path::PathBuf),
    n: usize,
    view: ViewEntry,
    rows: &[[f64; 4]; 4],
    key: overlays::Key,
) -> Result<Bytes, Refusal> {
    let pose = from_rows(rows).map_err(Refusal::Internal)?;
    let cell = d.cell().clone();
    let png = tokio::task::spawn_blocking(move || {
        overlays::render(&cell, &target, &run_dir, n, &view, &pose)
    })
    .await
    .map_err(|e| Refusal::Internal(format!("overlay task: {e}")))??;
    d.metrics.overlay_renders.fetch_add(1, Ordering::Relaxed);
    let png = Bytes::from(png);
    d.overlays.put(key, png.clone());
    Ok(png)
}

/// Planned pose `k` of a dry run drawn over its first view: blue where the robot would be,
/// red where it stands now, green where both are (the estimate of the dry run's view).
#[utoipa::path(get, path = "/api/v1/calibrations/{id}/plan/{k}/overlay.png", tag = "calibrations",
    params(("id" = String, Path, description = "A dry run's id, `cal-NNNN`"),
        ("k" = usize, Path, description = "A planned pose's index (0, 1, …)"),
        ("camera" = Option<String>, Query, description = "The camera's name: required in a cell of `[[camera]]` tables, refused in a cell of one `[camera]`")),
    responses(
        (status = 200, description = "The planned pose over the camera's first view", content_type = "image/png", body = Png),
        (status = 400, description = "`k` is not an index, or `camera` is missing, unknown or not allowed", body = ErrorBody),
        (status = 401, description = "Missing or wrong token (only with protect_reads)", body = ErrorBody),
        (status = 404, description = "No such calibration, plan or pose", body = ErrorBody),
        (status = 409, description = "No estimate to draw with, or a file leaves the data folder", body = ErrorBody),
        (status = 500, description = "plan.json or a view's files do not read back", body = ErrorBody)),
    security((), ("bearer" = [])))]
async fn plan_overlay(
    State(d): State<Shared>,
    Path((id, k)): Path<(String, String)>,
    RawQuery(query): RawQuery,
) -> Result<Response, Refusal> {
    let id = daemon_id(id)?;
    let k = path_index(&k, "pose")?;
    let target = overlays::target(d.cell(), query.as_deref())?;
    let record = record_of(&d, &id)?;
    // A dry run's plan is drawn over the camera's first view, under its estimate.
    let (run_dir, mut view) = overlay_view(&d, &record, &target, 0)?;
    let rows =
        overlays::estimate(&record, &target, &run_dir.join("rounds.json")).ok_or_else(|| {
            Refusal::Conflict(format!(
                "calibration {id} has no estimate to draw its plan with"
            ))
        })?;
    let plan = run_file(&d, &record, "plan.json")?;
    let key = overlays::Key::new(
        &id,
        target.name.as_deref(),
        0,
        &rows,
        overlays::mask_path(&run_dir, &view).as_deref(),
    )
    .planned(k);
    if let Some(png) = d.overlays.get(&key) {
        d.metrics.overlay_hits.fetch_add(1, Ordering::Relaxed);
        return Ok(png_response(png));
    }
    let pose = from_rows(&rows).map_err(Refusal::Internal)?;
    let cell = d.cell().clone();
    let png = tokio::task::spawn_blocking(move || {
        view.joints = super::plan::pose(&plan, k, cell.robot.actuated.len())?;
        overlays::render(&cell, &target, &run_dir, 0, &view, &pose)
    })
    .await
    .map_err(|e| Refusal::Internal(format!("plan overlay task: {e}")))??;
    d.metrics.overlay_renders.fetch_add(1, Ordering::Relaxed);
    let png = Bytes::from(png);
    d.overlays.put(key, png.clone());
    Ok(png_response(png))
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

/// One live camera frame, to frame the camera before a run. It takes the arm-and-camera
/// lease for the grab, so it never competes with a run's or a check's capture (409 then). In
/// a cell of several cameras, `?camera=NAME` picks the camera.
#[utoipa::path(get, path = "/api/v1/camera/preview.png", tag = "service",
    params(("camera" = Option<String>, Query, description = "The camera's name: required in a cell of `[[camera]]` tables, refused in a cell of one `[camera]`")),
    responses(
        (status = 200, description = "The frame", content_type = "image/png", body = Png),
        (status = 400, description = "`camera` is missing, unknown or not allowed", body = ErrorBody),
        (status = 401, description = "Missing or wrong token (always needed: it shows the cell and holds the camera)", body = ErrorBody),
        (status = 409, description = "The camera is in use; `running` names the holder", body = ErrorBody),
        (status = 500, description = "The camera failed", body = ErrorBody),
        (status = 503, description = "The daemon is shutting down", body = ErrorBody)),
    security(("bearer" = [])))]
async fn camera_preview(
    State(d): State<Shared>,
    RawQuery(query): RawQuery,
) -> Result<Response, Refusal> {
    let target = overlays::target(d.cell(), query.as_deref())?;
    let device = d
        .cell()
        .cameras()
        .get(target.index)
        .map(|c| c.device.clone())
        .ok_or_else(|| Refusal::Internal(format!("no camera {}", target.index)))?;
    // On its own task, released by the guard: a client that hangs up, a grab that panics or
    // one that never returns must not leave the lease taken.
    let lease = d.lease(Busy::Preview)?;
    let frame = tokio::spawn(async move {
        let grabbed = tokio::time::timeout(PREVIEW_GRAB, device.grab()).await;
        drop(lease);
        grabbed
    })
    .await
    .map_err(|e| Refusal::Internal(format!("preview task: {e}")))?
    .map_err(|_| {
        Refusal::Internal(format!(
            "camera: no frame within {} s",
            PREVIEW_GRAB.as_secs()
        ))
    })?
    .map_err(|e| Refusal::Internal(format!("camera: {e}")))?;
    let png = tokio::task::spawn_blocking(move || {
        let img =
            image::RgbImage::from_raw(frame.width, frame.height, frame.rgb).ok_or_else(|| {
                Refusal::Internal("camera: frame size does not match its pixels".into())
            })?;
        let mut bytes = std::io::Cursor::new(Vec::new());
        img.write_to(&mut bytes, image::ImageFormat::Png)
            .map_err(|e| Refusal::Internal(format!("encoding the preview: {e}")))?;
        Ok::<_, Refusal>(bytes.into_inner())
    })
    .await
    .map_err(|e| Refusal::Internal(format!("preview task: {e}")))??;
    Ok((
        [
            (header::CONTENT_TYPE, "image/png"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        png,
    )
        .into_response())
}

/// The calibration's result in another tool's form, as a download (the same text as
/// `easyhec export`; the ROS forms use the config's `[ros2]` frames when it has them).
#[utoipa::path(get, path = "/api/v1/calibrations/{id}/export/{format}", tag = "calibrations",
    params(("id" = String, Path, description = "A calibration id, `cal-NNNN`"),
        ("format" = String, Path, description = "opencv, ros, easy-handeye, easy-handeye-ros1 or urdf"),
        ("camera" = Option<String>, Query, description = "The camera's name: required in a cell of `[[camera]]` tables, refused in a cell of one `[camera]`")),
    responses(
        (status = 200, description = "The file, with Content-Disposition naming it", content_type = "text/plain", body = String),
        (status = 400, description = "Unknown format; `camera` missing, unknown or not allowed", body = ErrorBody),
        (status = 401, description = "Missing or wrong token (only with protect_reads)", body = ErrorBody),
        (status = 404, description = "No such calibration, it has no result, or it did not calibrate the camera asked for", body = ErrorBody),
        (status = 409, description = "The run directory leaves the data folder, or a frame name cannot be written", body = ErrorBody),
        (status = 500, description = "result.json does not read back", body = ErrorBody)),
    security((), ("bearer" = [])))]
async fn export_file(
    State(d): State<Shared>,
    Path((id, format)): Path<(String, String)>,
    RawQuery(query): RawQuery,
) -> Result<Response, Refusal> {
    let id = daemon_id(id)?;
    let format = <crate::interop::ExportFormat as clap::ValueEnum>::from_str(&format, false)
        .map_err(|_| {
            Refusal::BadRequest(format!(
                "format {format:?}: allowed: opencv, ros, easy-handeye, easy-handeye-ros1, urdf"
            ))
        })?;
    let camera = overlays::target(d.cell(), query.as_deref())?.name;
    let record = record_of(&d, &id)?;
    let path = run_file(&d, &record, "result.json")?;
    let settings = d.cell().config.ros2.clone();
    let (name, text) = tokio::task::spawn_blocking(move || {
        if !path.is_file() {
            return Err(Refusal::NotFound(format!("calibration {id} has no result")));
        }
        let result = read_camera_result(&id, &path, camera.as_deref())?;
        super::exports::render(&id, settings.as_ref(), camera.as_deref(), &result, format)
            .map_err(|e| Refusal::Conflict(format!("calibration {id}: {e}")))
    })
    .await
    .map_err(|e| Refusal::Internal(format!("export task: {e}")))??;
    Ok((
        [
            (
                header::CONTENT_TYPE,
                "text/plain; charset=utf-8".to_string(),
            ),
            (
                header::CONTENT_DISPOSITION,
                format!("attachment; filename=\"{name}\""),
            ),
        ],
        text,
    )
        .into_response())
}

/// The result a download exports: the run's own for one camera, or camera `camera`'s of a
/// run of a list (404 when that run did not calibrate it).
fn read_camera_result(
    id: &str,
    path: &std::path::Path,
    camera: Option<&str>,
) -> Result<crate::run::ResultFile, Refusal> {
    let unreadable = |e: crate::error::Error| Refusal::Internal(format!("calibration {id}: {e}"));
    let Some(name) = camera else {
        return crate::run::ResultFile::read(path).map_err(unreadable);
    };
    let rig = crate::run::rig::RigResultFile::read(path).map_err(unreadable)?;
    rig.cameras
        .iter()
        .find(|c| c.name == name)
        .map(|c| c.as_result(&rig.timings_s))
        .ok_or_else(|| {
            Refusal::NotFound(format!(
                "calibration {id} did not calibrate camera {name:?}; it calibrated {:?}",
                rig.cameras
                    .iter()
                    .map(|c| c.name.as_str())
                    .collect::<Vec<_>>()
            ))
        })
}

/// Cancels a running calibration: the arm is stopped first.
#[utoipa::path(post, path = "/api/v1/calibrations/{id}/cancel", tag = "calibrations",
    params(("id" = String, Path, description = "A calibration id, `cal-NNNN`")),
    responses(
        (status = 202, description = "Cancelling", body = Cancelling),
        (status = 401, description = "Missing or wrong token", body = ErrorBody),
        (status = 404, description = "No such calibration", body = ErrorBody),
        (status = 409, description = "It has already ended", body = ErrorBody)),
    security(("bearer" = [])))]
async fn cancel(State(d): State<Shared>, Path(id): Path<String>) -> Result<Response, Refusal> {
    let id = daemon_id(id)?;
    let r = d.cancel(&id).await?;
    Ok((
        StatusCode::ACCEPTED,
        Json(Cancelling {
            id: r.id,
            state: r.state,
            cancelling: true,
        }),
    )
        .into_response())
}

/// Makes a succeeded (or re-solved interrupted) calibration the active one.
#[utoipa::path(post, path = "/api/v1/calibrations/{id}/activate", tag = "calibrations",
    params(("id" = String, Path, description = "A calibration id, `cal-NNNN`")),
    responses(
        (status = 200, description = "Now active (a cell with a list of cameras answers RigActiveFile: every camera this calibration solved)", body = ActiveFile),
        (status = 401, description = "Missing or wrong token", body = ErrorBody),
        (status = 404, description = "No such calibration", body = ErrorBody),
        (status = 409, description = "It cannot be activated (the error says why)", body = ErrorBody)),
    security(("bearer" = [])))]
async fn activate(State(d): State<Shared>, Path(id): Path<String>) -> Result<Response, Refusal> {
    let id = daemon_id(id)?;
    let mut a = d.activate(&id)?;
    if d.cell().config.camera.is_listed() {
        return Ok(Json(RigActiveFile {
            format: RIG_ACTIVE_FORMAT.into(),
            cameras: a,
        })
        .into_response());
    }
    Ok(Json(a.remove(0)).into_response())
}

/// The active calibration, whether it is stale, and its last bump check.
#[utoipa::path(get, path = "/api/v1/calibration", tag = "calibrations",
    responses(
        (status = 200, description = "The active calibration", body = ActiveCalibration),
        (status = 401, description = "Missing or wrong token (only with protect_reads)", body = ErrorBody),
        (status = 404, description = "None is active yet", body = ErrorBody)),
    security((), ("bearer" = [])))]
async fn active(State(d): State<Shared>) -> Result<Response, Refusal> {
    if d.cell().config.camera.is_listed() {
        return Err(Refusal::Conflict(
            "this cell lists cameras, each with its own active calibration: GET /api/v1/cameras"
                .into(),
        ));
    }
    let a = d.store().active().ok_or_else(|| {
        Refusal::NotFound(
            "no active calibration yet: start one with POST /api/v1/calibrations".into(),
        )
    })?;
    Ok(Json(active_calibration(&d, a)).into_response())
}

/// An active entry with its latest bump check.
fn active_calibration(d: &Daemon, a: ActiveFile) -> ActiveCalibration {
    let last_check = d
        .store()
        .checks()
        .into_iter()
        .rev()
        .find(|c| c.calibration_id == a.id && c.camera == a.camera);
    ActiveCalibration {
        id: a.id,
        activated_at: a.activated_at,
        stale: a.stale,
        stale_since: a.stale_since,
        last_check,
        result: a.result,
    }
}

/// Every camera of the cell with its active calibration (each camera of a list is
/// calibrated, checked and marked stale by itself).
#[utoipa::path(get, path = "/api/v1/cameras", tag = "calibrations",
    responses(
        (status = 200, description = "Each camera and its active calibration", body = Cameras),
        (status = 401, description = "Missing or wrong token (only with protect_reads)", body = ErrorBody)),
    security((), ("bearer" = [])))]
async fn cameras(State(d): State<Shared>) -> Json<Cameras> {
    let listed = d.cell().config.camera.is_listed();
    let cameras = d
        .cell()
        .cameras()
        .iter()
        .map(|c| {
            let key = listed.then_some(c.name);
            CameraState {
                camera: c.name.to_string(),
                active: d.store().active_of(key).map(|a| active_calibration(&d, a)),
            }
        })
        .collect();
    Json(Cameras { listed, cameras })
}

/// Runs a bump check now: moves to the check pose, captures, compares with the active
/// calibration's silhouette.
#[utoipa::path(post, path = "/api/v1/checks", tag = "checks",
    responses(
        (status = 200, description = "The check's outcome (a cell with a list of cameras answers Checks: one record per camera with an active calibration)", body = CheckRecord),
        (status = 401, description = "Missing or wrong token", body = ErrorBody),
        (status = 409, description = "No active calibration, or the arm is leased", body = ErrorBody),
        (status = 500, description = "Capture, motion or segmentation failed", body = ErrorBody),
        (status = 503, description = "The daemon is shutting down", body = ErrorBody)),
    security(("bearer" = [])))]
async fn run_check(State(d): State<Shared>) -> Result<Response, Refusal> {
    // The check runs as its own task: a client that hangs up drops this handler, never the
    // check, so the arm's move is still supervised, recorded and its lease given back.
    let task = d.clone();
    let mut c = tokio::spawn(async move { bump::check(&task, "api").await })
        .await
        .map_err(|e| Refusal::Internal(format!("bump check task: {e}")))??;
    if d.cell().config.camera.is_listed() {
        return Ok(Json(Checks { checks: c }).into_response());
    }
    Ok(Json(c.remove(0)).into_response())
}

/// The last 50 bump checks, newest first.
#[utoipa::path(get, path = "/api/v1/checks", tag = "checks",
    responses(
        (status = 200, description = "The checks", body = Checks),
        (status = 401, description = "Missing or wrong token (only with protect_reads)", body = ErrorBody)),
    security((), ("bearer" = [])))]
async fn checks(State(d): State<Shared>) -> Json<Checks> {
    let mut c = d.store().checks();
    c.reverse();
    c.truncate(50);
    Json(Checks { checks: c })
}

/// Appends one metric in the Prometheus text format.
fn metric(s: &mut String, name: &str, kind: &str, help: &str, lines: &[(String, f64)]) {
    use std::fmt::Write;
    let _ = writeln!(s, "# HELP {name} {help}\n# TYPE {name} {kind}");
    for (labels, v) in lines {
        let _ = writeln!(s, "{name}{labels} {v}");
    }
}

/// One unlabelled value.
fn one(v: f64) -> Vec<(String, f64)> {
    vec![(String::new(), v)]
}

/// A counter's value.
fn count(a: &AtomicU64) -> f64 {
    a.load(Ordering::Relaxed) as f64
}

/// Counters and gauges in the Prometheus text format.
#[utoipa::path(get, path = "/metrics", tag = "service",
    responses(
        (status = 200, description = "Prometheus text format 0.0.4", content_type = "text/plain", body = String),
        (status = 401, description = "Missing or wrong token (only with protect_reads)", body = ErrorBody)),
    security((), ("bearer" = [])))]
async fn metrics(State(d): State<Shared>) -> Response {
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
fn calibration_metrics(d: &Daemon, s: &mut String) {
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
fn check_metrics(d: &Daemon, s: &mut String) {
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
fn server_metrics(d: &Daemon, s: &mut String) {
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

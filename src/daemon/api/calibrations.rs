//! `/api/v1/calibrations` and `/api/v1/calibration`: start, follow, cancel, activate, export.

use axum::body::Bytes;
use axum::extract::{Path, RawQuery, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::sse::{Event as SseEvent, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::Json;
use tokio::sync::broadcast;

use super::{daemon_id, is_json, record_of, run_file, Shared};
use crate::daemon::job::EventKind;
use crate::daemon::openapi::{ActiveCalibration, Cancelling, ErrorBody, History, Started};
use crate::daemon::store::{ActiveFile, CalibrationRecord, RigActiveFile, RIG_ACTIVE_FORMAT};
use crate::daemon::{overlays, Daemon, Event, Refusal, StartOptions};
use crate::run::rig::RunLayout;

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
pub(super) async fn start(
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
pub(super) fn start_options(headers: &HeaderMap, body: &[u8]) -> Result<StartOptions, Refusal> {
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
pub(super) fn bad_body(at: &str, e: &serde_json::Error) -> Refusal {
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
pub(super) async fn history(State(d): State<Shared>) -> Json<History> {
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
pub(super) async fn status(
    State(d): State<Shared>,
    Path(id): Path<String>,
) -> Result<Response, Refusal> {
    let id = daemon_id(id)?;
    record_of(&d, &id).map(|r| Json(r).into_response())
}

pub(super) fn sse_event(e: &Event) -> SseEvent {
    SseEvent::default()
        .event(e.kind.name())
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
pub(super) async fn events(
    State(d): State<Shared>,
    Path(id): Path<String>,
) -> Result<Response, Refusal> {
    let id = daemon_id(id)?;
    // Subscribe before reading the snapshot so no event falls between them.
    let rx: Option<broadcast::Receiver<Event>> = d.job(&id).map(|j| j.subscribe());
    let snapshot = record_of(&d, &id)?;
    let first = Event {
        kind: EventKind::State,
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
                        st.done = e.kind == EventKind::State && e.status.state.is_final();
                        return Some((Ok(sse_event(&e)), st));
                    }
                    Err(broadcast::error::RecvError::Lagged(_)) => continue,
                    Err(broadcast::error::RecvError::Closed) => return None,
                },
                _ = st.shutdown.changed() => return None,
            }
        }
    });
    let every = crate::daemon::http::keep_alive_interval(d.settings().idle_timeout());
    Ok(Sse::new(stream)
        .keep_alive(KeepAlive::new().interval(every))
        .into_response())
}

/// The calibration's result in another tool's form, as a download (the same text as
/// `easyhec export`; the ROS forms use the config's `[ros2]` frames when it has them).
#[utoipa::path(get, path = "/api/v1/calibrations/{id}/export/{format}", tag = "calibrations",
    params(("id" = String, Path, description = "A calibration id, `cal-NNNN`"),
        ("format" = inline(crate::interop::ExportFormat), Path, description = "An export format (the page reads this list)"),
        ("camera" = Option<String>, Query, description = "The camera's name: required in a cell of `[[camera]]` tables, refused in a cell of one `[camera]`")),
    responses(
        (status = 200, description = "The file, with Content-Disposition naming it; its content type is the format's (each listed here from `ExportFormat`)"),
        (status = 400, description = "Unknown format; `camera` missing, unknown or not allowed", body = ErrorBody),
        (status = 401, description = "Missing or wrong token (only with protect_reads)", body = ErrorBody),
        (status = 404, description = "No such calibration, it has no result, or it did not calibrate the camera asked for", body = ErrorBody),
        (status = 409, description = "The run directory leaves the data folder, or a frame name cannot be written", body = ErrorBody),
        (status = 500, description = "result.json does not read back", body = ErrorBody)),
    security((), ("bearer" = [])))]
pub(super) async fn export_file(
    State(d): State<Shared>,
    Path((id, format)): Path<(String, String)>,
    RawQuery(query): RawQuery,
) -> Result<Response, Refusal> {
    let id = daemon_id(id)?;
    let format = <crate::interop::ExportFormat as clap::ValueEnum>::from_str(&format, false)
        .map_err(|_| {
            Refusal::BadRequest(format!(
                "format {format:?}: allowed: {}",
                crate::interop::ExportFormat::names()
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
        crate::daemon::exports::render(&id, settings.as_ref(), camera.as_deref(), &result, format)
            .map_err(|e| Refusal::Conflict(format!("calibration {id}: {e}")))
    })
    .await
    .map_err(|e| Refusal::Internal(format!("export task: {e}")))??;
    Ok((
        [
            (
                header::CONTENT_TYPE,
                format!("{}; charset=utf-8", format.content_type()),
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
pub(super) fn read_camera_result(
    id: &str,
    path: &std::path::Path,
    camera: Option<&str>,
) -> Result<crate::run::ResultFile, Refusal> {
    let unreadable = |e: crate::error::Error| Refusal::Internal(format!("calibration {id}: {e}"));
    let results = crate::run::rig::ResultCameras::read(path).map_err(unreadable)?;
    // The route checked `camera` against the cell; a file of the other layout is a store
    // that no longer matches its cell.
    let layout = if camera.is_some() {
        RunLayout::NamedCameras
    } else {
        RunLayout::OneCamera
    };
    if results.layout != layout {
        return Err(Refusal::Internal(format!(
            "calibration {id}: {} is {}, and this cell's cameras record {}",
            path.display(),
            results.layout.result_format(),
            layout.result_format()
        )));
    }
    let Some(name) = camera else {
        return Ok(results.cameras[0].result.clone());
    };
    results
        .cameras
        .iter()
        .find(|c| c.name.as_deref() == Some(name))
        .map(|c| c.result.clone())
        .ok_or_else(|| {
            Refusal::NotFound(format!(
                "calibration {id} did not calibrate camera {name:?}; it calibrated {:?}",
                results.names()
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
pub(super) async fn cancel(
    State(d): State<Shared>,
    Path(id): Path<String>,
) -> Result<Response, Refusal> {
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
pub(super) async fn activate(
    State(d): State<Shared>,
    Path(id): Path<String>,
) -> Result<Response, Refusal> {
    let id = daemon_id(id)?;
    let mut a = d.activate(&id)?;
    if d.cell().layout() == RunLayout::NamedCameras {
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
pub(super) async fn active(State(d): State<Shared>) -> Result<Response, Refusal> {
    if d.cell().layout() == RunLayout::NamedCameras {
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
pub(super) fn active_calibration(d: &Daemon, a: ActiveFile) -> ActiveCalibration {
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

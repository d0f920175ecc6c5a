//! Overlay PNGs: a view under the estimate, a dry run's planned pose.

use std::sync::atomic::Ordering;

use axum::body::Bytes;
use axum::extract::{Path, RawQuery, State};
use axum::response::Response;

use super::{daemon_id, path_index, png_response, record_of, run_file, Shared};
use crate::daemon::openapi::{ErrorBody, Png};
use crate::daemon::store::CalibrationRecord;
use crate::daemon::validate::inside;
use crate::daemon::{overlays, Daemon, Refusal};
use crate::geometry::from_rows;
use crate::run::ViewEntry;

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
pub(super) async fn overlay(
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
pub(super) fn overlay_view(
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
pub(super) async fn render_overlay(
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
pub(super) async fn plan_overlay(
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
        view.joints = crate::daemon::plan::pose(&plan, k, cell.robot.actuated.len())?;
        overlays::render(&cell, &target, &run_dir, 0, &view, &pose)
    })
    .await
    .map_err(|e| Refusal::Internal(format!("plan overlay task: {e}")))??;
    d.metrics.overlay_renders.fetch_add(1, Ordering::Relaxed);
    let png = Bytes::from(png);
    d.overlays.put(key, png.clone());
    Ok(png_response(png))
}

//! `/api/v1/checks`: run a bump check, list the last ones.

use axum::extract::State;
use axum::response::{IntoResponse, Response};
use axum::Json;

use super::Shared;
use crate::daemon::openapi::{Checks, ErrorBody};
use crate::daemon::store::CheckRecord;
use crate::daemon::{bump, Refusal};
use crate::run::rig::RunLayout;

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
pub(super) async fn run_check(State(d): State<Shared>) -> Result<Response, Refusal> {
    // The check runs as its own task: a client that hangs up drops this handler, never the
    // check, so the arm's move is still supervised, recorded and its lease given back.
    let task = d.clone();
    let mut c = tokio::spawn(async move { bump::check(&task, "api").await })
        .await
        .map_err(|e| Refusal::Internal(format!("bump check task: {e}")))??;
    if d.cell().layout() == RunLayout::NamedCameras {
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
pub(super) async fn checks(State(d): State<Shared>) -> Json<Checks> {
    let mut c = d.store().checks();
    c.reverse();
    c.truncate(50);
    Json(Checks { checks: c })
}

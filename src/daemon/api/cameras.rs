//! `/api/v1/cameras` and the live preview.

use axum::extract::{RawQuery, State};
use axum::http::header;
use axum::response::{IntoResponse, Response};
use axum::Json;

use super::calibrations::active_calibration;
use super::Shared;
use crate::daemon::openapi::{CameraState, Cameras, ErrorBody, Png};
use crate::daemon::{overlays, Busy, Refusal};
use crate::run::rig::RunLayout;

/// Longest wait for a preview frame.
pub(super) const PREVIEW_GRAB: std::time::Duration = std::time::Duration::from_secs(10);

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
pub(super) async fn camera_preview(
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

/// Every camera of the cell with its active calibration (each camera of a list is
/// calibrated, checked and marked stale by itself).
#[utoipa::path(get, path = "/api/v1/cameras", tag = "calibrations",
    responses(
        (status = 200, description = "Each camera and its active calibration", body = Cameras),
        (status = 401, description = "Missing or wrong token (only with protect_reads)", body = ErrorBody)),
    security((), ("bearer" = [])))]
pub(super) async fn cameras(State(d): State<Shared>) -> Json<Cameras> {
    let named = d.cell().layout() == RunLayout::NamedCameras;
    let cameras = d
        .cell()
        .cameras()
        .iter()
        .map(|c| {
            let key = named.then_some(c.name);
            CameraState {
                camera: c.name.to_string(),
                active: d.store().active_of(key).map(|a| active_calibration(&d, a)),
            }
        })
        .collect();
    Json(Cameras {
        listed: named,
        cameras,
    })
}

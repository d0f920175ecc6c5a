//! A calibration's result in the forms other tools read, as the page downloads them
//! (`GET /api/v1/calibrations/{id}/export/{format}`, `?camera=NAME` in a list of cameras). The ROS forms use the daemon's `[ros2]`
//! frames when the config has that table, so a download matches what the daemon publishes.

use crate::config::ros2::Ros2Settings;
use crate::error::{Error, Result};
use crate::interop::tf_edge::{camera_frame, transform_from_parts, TfEdge, DEFAULT_CHILD_FRAME};
use crate::interop::{export, ExportFormat};
use crate::run::ResultFile;

/// The tf edge for `result`: the `[ros2]` table's frames and fixed optical transform, or the
/// result's base link and [`DEFAULT_CHILD_FRAME`] without one.
pub fn edge(settings: Option<&Ros2Settings>, result: &ResultFile) -> Result<TfEdge> {
    edge_to_child(settings, configured_child(settings), result)
}

/// The tf edge for one active entry: [`edge`] for a cell of one camera; for a camera of a
/// list, the child frame is the camera's own (the configured one with the camera's name and `_`
/// in front, [`camera_frame`]), as `easyhec publish` names it for a result of several cameras.
pub fn camera_edge(
    settings: Option<&Ros2Settings>,
    camera: Option<&str>,
    result: &ResultFile,
) -> Result<TfEdge> {
    match camera {
        None => edge(settings, result),
        Some(name) => edge_to_child(
            settings,
            &camera_frame(configured_child(settings), name),
            result,
        ),
    }
}

/// `[ros2] child_frame_id`, or the default without a `[ros2]` table.
fn configured_child(settings: Option<&Ros2Settings>) -> &str {
    settings.map_or(DEFAULT_CHILD_FRAME, |s| s.child_frame_id.as_str())
}

/// The edge from `[ros2] frame_id` (or the result's own parent) to `child`, with the
/// configured `optical_from_child` when there is one.
fn edge_to_child(
    settings: Option<&Ros2Settings>,
    child: &str,
    result: &ResultFile,
) -> Result<TfEdge> {
    let optical_from_child = settings
        .and_then(|s| s.optical_from_child)
        .map(|v| transform_from_parts([v[0], v[1], v[2]], [v[3], v[4], v[5], v[6]]))
        .transpose()
        .map_err(|m| Error::Usage(format!("ros2.optical_from_child {m}")))?;
    TfEdge::from_result(
        result,
        settings.and_then(|s| s.frame_id.as_deref()),
        child,
        optical_from_child.as_ref(),
        ["ros2.frame_id", "ros2.child_frame_id"],
    )
}

/// `result` (of `camera`, in a list) rendered in `format`, with the file name a download
/// should get ([`ExportFormat::file_name`]: `cal-0003.opencv.yaml`, `cal-0003-front.urdf` for a
/// camera of a list).
pub fn render(
    id: &str,
    settings: Option<&Ros2Settings>,
    camera: Option<&str>,
    result: &ResultFile,
    format: ExportFormat,
) -> Result<(String, String)> {
    let text = export(result, format, &camera_edge(settings, camera, result)?)?;
    let stem = match camera {
        Some(name) => format!("{id}-{name}"),
        None => id.to_string(),
    };
    Ok((format.file_name(&stem), text))
}

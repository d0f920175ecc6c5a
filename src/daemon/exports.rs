//! A calibration's result in the forms other tools read, as the page downloads them
//! (`GET /api/v1/calibrations/{id}/export/{format}`). The ROS forms use the daemon's `[ros2]`
//! frames when the config has that table, so a download matches what the daemon publishes.

use crate::config::ros2::Ros2Settings;
use crate::error::{Error, Result};
use crate::interop::tf_edge::{transform_from_parts, TfEdge, DEFAULT_CHILD_FRAME};
use crate::interop::{export, ExportFormat};
use crate::run::ResultFile;

/// The tf edge for `result`: the `[ros2]` table's frames and fixed optical transform, or the
/// result's base link and [`DEFAULT_CHILD_FRAME`] without one.
pub fn edge(settings: Option<&Ros2Settings>, result: &ResultFile) -> Result<TfEdge> {
    let Some(settings) = settings else {
        return TfEdge::from_result(
            result,
            None,
            DEFAULT_CHILD_FRAME,
            None,
            ["ros2.frame_id", "ros2.child_frame_id"],
        );
    };
    let optical_from_child = settings
        .optical_from_child
        .map(|v| transform_from_parts([v[0], v[1], v[2]], [v[3], v[4], v[5], v[6]]))
        .transpose()
        .map_err(|m| Error::Usage(format!("ros2.optical_from_child {m}")))?;
    TfEdge::from_result(
        result,
        settings.frame_id.as_deref(),
        &settings.child_frame_id,
        optical_from_child.as_ref(),
        ["ros2.frame_id", "ros2.child_frame_id"],
    )
}

/// `result` rendered in `format`, with the file name a download should get.
pub fn render(
    id: &str,
    settings: Option<&Ros2Settings>,
    result: &ResultFile,
    format: ExportFormat,
) -> Result<(String, String)> {
    let text = export(result, format, &edge(settings, result)?)?;
    Ok((file_name(id, format), text))
}

/// `cal-0003.yaml`, `cal-0003.launch.py`, `cal-0003.calib`, `cal-0003.urdf`.
fn file_name(id: &str, format: ExportFormat) -> String {
    let extension = match format {
        ExportFormat::Opencv => "opencv.yaml",
        ExportFormat::Ros => "launch.py",
        ExportFormat::EasyHandeye => "calib",
        ExportFormat::EasyHandeyeRos1 => "easy_handeye.yaml",
        ExportFormat::Urdf => "urdf",
    };
    format!("{id}.{extension}")
}

//! The frame flags `easyhec export` and `easyhec publish` share: which tf edge a result
//! becomes.

use clap::Args;
use easyhec::interop::tf_edge::{camera_frame, parse_transform, DEFAULT_CHILD_FRAME};
use easyhec::interop::TfEdge;
use easyhec::run::rig::ResultCameras;
use easyhec::run::ResultFile;

/// How errors name the two frames.
pub const FLAGS: [&str; 2] = ["--frame-id", "--child-frame-id"];

#[derive(Args, Clone, Debug)]
pub struct FrameArgs {
    /// Parent frame of the edge (default: the result's base_link).
    #[arg(long)]
    pub frame_id: Option<String>,
    /// Child frame: the optical frame itself, or, with --optical-from-child, the camera's
    /// root link. Never a frame a camera driver already publishes with a parent. (The opencv
    /// form always holds the optical frame and ignores the frame flags.)
    #[arg(long, alias = "camera-frame", default_value = DEFAULT_CHILD_FRAME)]
    pub child_frame_id: String,
    /// The camera driver's fixed optical_from_child, "x y z qx qy qz qw" (metres, unit
    /// quaternion): the pose of --child-frame-id in the optical frame, i.e. the inverse of
    /// what `ros2 run tf2_ros tf2_echo CHILD OPTICAL` prints.
    #[arg(long, allow_hyphen_values = true)]
    pub optical_from_child: Option<String>,
}

impl FrameArgs {
    /// The edge these flags describe for `result`.
    pub fn edge(&self, result: &ResultFile) -> easyhec::error::Result<TfEdge> {
        let optical_from_child = self
            .optical_from_child
            .as_deref()
            .map(|t| parse_transform(t, "--optical-from-child"))
            .transpose()?;
        TfEdge::from_result(
            result,
            self.frame_id.as_deref(),
            &self.child_frame_id,
            optical_from_child.as_ref(),
            FLAGS,
        )
    }
}

impl FrameArgs {
    /// One edge per camera of a rig result, each to the camera's own child frame
    /// ([`camera_frame`]). A driver's `--optical-from-child` belongs to one camera, so it is
    /// refused here: publish or export that camera's frame chain by itself. So is
    /// `--frame-id` when the cameras hang from different frames (a wrist camera's link beside
    /// the fixed cameras' base).
    pub fn rig_edges(&self, results: &ResultCameras) -> easyhec::error::Result<Vec<TfEdge>> {
        if self.optical_from_child.is_some() {
            return Err(easyhec::error::Error::Usage(format!(
                "--optical-from-child: the result holds {} cameras, and a driver's offset belongs to one; allowed: only for a result of one camera",
                results.cameras.len()
            )));
        }
        let bases: std::collections::BTreeSet<&str> = results
            .cameras
            .iter()
            .map(|c| c.result.base_link.as_str())
            .collect();
        if self.frame_id.is_some() && bases.len() > 1 {
            return Err(easyhec::error::Error::Usage(format!(
                "--frame-id: the result's cameras hang from different frames ({bases:?}: a camera on a link beside fixed ones), and one parent cannot serve them; allowed: leave --frame-id out"
            )));
        }
        results
            .cameras
            .iter()
            .map(|cam| {
                let mut frames = self.clone();
                let name = cam.name_or_empty();
                frames.child_frame_id = camera_frame(&self.child_frame_id, name);
                frames.edge(&cam.result)
            })
            .collect()
    }
}

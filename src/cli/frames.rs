//! The frame flags `easyhec export` and `easyhec publish` share: which tf edge a result
//! becomes.

use clap::Args;
use easyhec::interop::tf_edge::{parse_transform, DEFAULT_CHILD_FRAME};
use easyhec::interop::TfEdge;
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

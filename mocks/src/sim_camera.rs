//! A simulated camera: frames of the simulated arm's true joints from a pose the solver never
//! sees (the scene renderer owns it).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::SystemTime;

use async_trait::async_trait;
use easyhec_drivers::{Camera, DriverError, Frame, Intrinsics, Result};

use crate::SimArm;

/// One rendered frame with its ground-truth mask.
#[derive(Clone, Debug)]
pub struct SceneFrame {
    /// Row-major RGB8, intrinsics' size.
    pub rgb: Vec<u8>,
    /// Row-major robot mask (0 or 255), same image as `rgb`.
    pub mask: Vec<u8>,
}

/// Renders the cell as the camera sees it with the robot at `true_joints`; `frame_index`
/// seeds per-frame sensor noise.
pub trait SceneRenderer: Send + Sync {
    /// Intrinsics of the frames produced.
    fn intrinsics(&self) -> &Intrinsics;

    /// Renders a frame.
    fn render(
        &self,
        true_joints: &[f64],
        frame_index: u64,
    ) -> std::result::Result<SceneFrame, String>;
}

/// Simulated camera watching a [`SimArm`].
pub struct SimCamera {
    arm: SimArm,
    scene: Arc<dyn SceneRenderer>,
    frames: AtomicU64,
}

impl SimCamera {
    /// A camera rendering `scene` at `arm`'s true joints.
    pub fn new(arm: SimArm, scene: Arc<dyn SceneRenderer>) -> SimCamera {
        SimCamera {
            arm,
            scene,
            frames: AtomicU64::new(0),
        }
    }
}

#[async_trait]
impl Camera for SimCamera {
    fn intrinsics(&self) -> &Intrinsics {
        self.scene.intrinsics()
    }

    async fn grab(&self) -> Result<Frame> {
        let q = self.arm.true_joints();
        let index = self.frames.fetch_add(1, Ordering::Relaxed);
        let scene = self.scene.clone();
        let captured_at = SystemTime::now();
        let frame = tokio::task::spawn_blocking(move || scene.render(&q, index))
            .await
            .map_err(|e| DriverError::Connection(format!("render task: {e}")))?
            .map_err(|e| DriverError::Backend(e.into()))?;
        let i = self.scene.intrinsics();
        Ok(Frame {
            width: i.width,
            height: i.height,
            rgb: frame.rgb,
            captured_at,
            truth_mask: Some(frame.mask),
        })
    }
}

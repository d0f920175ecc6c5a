//! A simulated camera: frames of an arm's true joints (a [`SimArm`] or a controller's report
//! stream) from a pose the solver never sees (the scene renderer owns it).

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
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

/// Where a simulated camera learns the arm's true joints: the simulated arm itself, or a
/// controller's report stream (a mock or real xArm), so one scene renderer films any arm.
#[async_trait]
pub trait JointSource: Send + Sync {
    /// The joints as they truly are now.
    async fn true_joints(&self) -> Result<Vec<f64>>;
}

#[async_trait]
impl JointSource for SimArm {
    async fn true_joints(&self) -> Result<Vec<f64>> {
        Ok(SimArm::true_joints(self))
    }
}

/// How many recent frames' ground-truth masks a simulated camera keeps (a calibration takes a
/// few tens of views; the bound keeps a long-running simulated daemon's memory flat).
pub const TRUTH_MASKS_KEPT: usize = 64;

/// Simulated camera watching an arm's true joints. It keeps the ground-truth mask of each
/// recent frame, looked up by the frame's sequence number ([`SimCamera::truth_mask`]): the
/// truth stays with the simulator instead of riding on [`Frame`].
pub struct SimCamera {
    arm: Arc<dyn JointSource>,
    scene: Arc<dyn SceneRenderer>,
    frames: AtomicU64,
    truths: Mutex<VecDeque<(u64, Vec<u8>)>>,
}

impl SimCamera {
    /// A camera rendering `scene` at `arm`'s true joints.
    pub fn new(arm: SimArm, scene: Arc<dyn SceneRenderer>) -> SimCamera {
        SimCamera::watching(Arc::new(arm), scene)
    }

    /// A camera rendering `scene` at the joints `source` reports.
    pub fn watching(source: Arc<dyn JointSource>, scene: Arc<dyn SceneRenderer>) -> SimCamera {
        SimCamera {
            arm: source,
            scene,
            frames: AtomicU64::new(0),
            truths: Mutex::new(VecDeque::new()),
        }
    }

    /// The ground-truth robot mask (row-major, 0 or 255) of the frame with this sequence
    /// number, while it is among the last [`TRUTH_MASKS_KEPT`] frames grabbed.
    pub fn truth_mask(&self, sequence: u64) -> Option<Vec<u8>> {
        let truths = self.truths.lock().ok()?;
        truths
            .iter()
            .find(|(s, _)| *s == sequence)
            .map(|(_, m)| m.clone())
    }
}

#[async_trait]
impl Camera for SimCamera {
    fn intrinsics(&self) -> &Intrinsics {
        self.scene.intrinsics()
    }

    async fn grab(&self) -> Result<Frame> {
        let q = self.arm.true_joints().await?;
        let index = self.frames.fetch_add(1, Ordering::Relaxed);
        let scene = self.scene.clone();
        let captured_at = SystemTime::now();
        let frame = tokio::task::spawn_blocking(move || scene.render(&q, index))
            .await
            .map_err(|e| DriverError::Connection(format!("render task: {e}")))?
            .map_err(|e| DriverError::Backend(e.into()))?;
        // Sequence numbers start at 1: a frame read back from disk carries 0, which then
        // never matches a simulated frame's truth.
        let sequence = index + 1;
        if let Ok(mut truths) = self.truths.lock() {
            if truths.len() == TRUTH_MASKS_KEPT {
                truths.pop_front();
            }
            truths.push_back((sequence, frame.mask));
        }
        let i = self.scene.intrinsics();
        Ok(Frame {
            width: i.width,
            height: i.height,
            rgb: frame.rgb,
            captured_at,
            sequence,
        })
    }
}

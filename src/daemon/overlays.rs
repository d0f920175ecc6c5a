//! Overlay PNGs of a calibration's views, rendered once and cached in memory. Rendering runs
//! the CPU silhouette renderer and encodes a camera-sized PNG (tens of milliseconds of a core
//! each), and the web page asks for every view again after each round; without a cache a few
//! open pages would keep the cores busy re-drawing the same images.
//!
//! An entry is keyed by what the image shows: the calibration, the view, the estimate it is
//! drawn under (bit for bit) and the mask file's size and modification time (the builtin
//! segmenter rewrites masks). A new round's estimate is therefore a new entry, never a stale
//! image. The cache holds at most [`CACHE_BYTES`] of PNGs and drops the oldest first.

use std::collections::{HashMap, VecDeque};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::SystemTime;

use axum::body::Bytes;
use nalgebra::Isometry3;

use super::Refusal;
use crate::camera::LensWarp;
use crate::cell::Cell;
use crate::mask::Mask;
use crate::overlay::overlay_image;
use crate::render::{CpuRenderer, PosedRobot, SilhouetteRenderer};
use crate::run::ViewEntry;

/// Bytes of PNG the cache keeps at most (about 200 overlays of a 640×480 camera).
pub const CACHE_BYTES: usize = 64 << 20;

/// What an overlay shows.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct Key {
    id: String,
    view: usize,
    pose: [[u64; 4]; 4],
    mask: Option<(SystemTime, u64)>,
}

impl Key {
    /// The key of view `view` of calibration `id` under `rows`, with mask file `mask`.
    pub fn new(id: &str, view: usize, rows: &[[f64; 4]; 4], mask: Option<&Path>) -> Key {
        let stamp = mask
            .and_then(|p| std::fs::metadata(p).ok())
            .and_then(|m| Some((m.modified().ok()?, m.len())));
        Key {
            id: id.to_string(),
            view,
            pose: rows.map(|r| r.map(f64::to_bits)),
            mask: stamp,
        }
    }
}

/// The cache: PNGs by key, and the keys oldest first.
#[derive(Default)]
pub struct Cache {
    inner: Mutex<Entries>,
}

#[derive(Default)]
struct Entries {
    pngs: HashMap<Key, Bytes>,
    order: VecDeque<Key>,
    bytes: usize,
}

impl Cache {
    /// The cached PNG for `key`.
    pub fn get(&self, key: &Key) -> Option<Bytes> {
        super::lock(&self.inner).pngs.get(key).cloned()
    }

    /// Keeps `png` for `key`, dropping the oldest entries beyond [`CACHE_BYTES`].
    pub fn put(&self, key: Key, png: Bytes) {
        if png.len() > CACHE_BYTES {
            return;
        }
        let mut e = super::lock(&self.inner);
        if e.pngs.contains_key(&key) {
            return;
        }
        e.bytes += png.len();
        e.order.push_back(key.clone());
        e.pngs.insert(key, png);
        while e.bytes > CACHE_BYTES {
            let Some(old) = e.order.pop_front() else {
                break;
            };
            if let Some(p) = e.pngs.remove(&old) {
                e.bytes -= p.len();
            }
        }
    }
}

/// Renders view `n` (recorded in `run_dir` as `view`) under `pose` and encodes it as PNG:
/// green where render and mask agree, red where only the mask shows robot, blue where only
/// the render does, over the dimmed colour frame (over the grey mask when the lens distorts,
/// since the frame is in the distorted image).
pub fn render(
    cell: &Cell,
    run_dir: &Path,
    n: usize,
    view: &ViewEntry,
    pose: &Isometry3<f64>,
) -> Result<Vec<u8>, Refusal> {
    let camera = cell.camera.intrinsics().clone();
    let mask_rel = view
        .mask
        .as_ref()
        .ok_or_else(|| Refusal::NotFound(format!("view {n} has no mask")))?;
    let observed = camera.undistort_mask(&Mask::load(&run_dir.join(mask_rel))?);
    if view.joints.len() != cell.robot.actuated.len() {
        return Err(Refusal::Internal(format!(
            "view {n} has {} joints; the cell's robot has {}",
            view.joints.len(),
            cell.robot.actuated.len()
        )));
    }
    let rendered = CpuRenderer
        .render(
            &PosedRobot::new(&cell.seen, &view.joints),
            &camera.undistorted(),
            pose,
            None,
        )
        .mask;
    let background = view
        .image
        .as_ref()
        .filter(|_| !camera.is_distorted())
        .and_then(|p| image::open(run_dir.join(p)).ok())
        .map(|i| i.to_rgb8());
    let img = overlay_image(&rendered, &observed, background.as_ref());
    let mut bytes = std::io::Cursor::new(Vec::new());
    img.write_to(&mut bytes, image::ImageFormat::Png)
        .map_err(|e| Refusal::Internal(format!("encoding the overlay: {e}")))?;
    Ok(bytes.into_inner())
}

/// The mask file of a view, for the cache key.
pub fn mask_path(run_dir: &Path, view: &ViewEntry) -> Option<PathBuf> {
    view.mask.as_ref().map(|m| run_dir.join(m))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cache_keeps_what_fits_and_drops_the_oldest() {
        let cache = Cache::default();
        let rows = [[0.0; 4]; 4];
        let key = |v| Key::new("cal-0001", v, &rows, None);
        let big = Bytes::from(vec![0u8; CACHE_BYTES / 2]);
        cache.put(key(0), big.clone());
        cache.put(key(1), big.clone());
        assert!(cache.get(&key(0)).is_some() && cache.get(&key(1)).is_some());
        cache.put(key(2), Bytes::from(vec![1u8; 10]));
        assert!(cache.get(&key(0)).is_none(), "the oldest goes first");
        assert!(cache.get(&key(1)).is_some() && cache.get(&key(2)).is_some());
        let mut moved = rows;
        moved[0][3] = 0.001;
        assert!(cache.get(&Key::new("cal-0001", 1, &moved, None)).is_none());
    }
}

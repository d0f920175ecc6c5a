//! Overlay PNGs of a calibration's views, rendered once and cached in memory. Rendering runs
//! the CPU silhouette renderer and encodes a camera-sized PNG (tens of milliseconds of a core
//! each), and the web page asks for every view again after each round; without a cache a few
//! open pages would keep the cores busy re-drawing the same images.
//!
//! An entry is keyed by what the image shows: the calibration, the view, the estimate it is
//! drawn under (bit for bit) and the mask file's size and modification time (the builtin
//! segmenter rewrites masks). A new round's estimate is therefore a new entry, never a stale
//! image. The cache holds at most [`CACHE_BYTES`] of PNGs and drops the oldest first.
//!
//! In a cell of several cameras, an overlay is one camera's frame (`?camera=NAME`), drawn with
//! that camera's lens and the robot as it sees it, under that camera's estimate.

use std::collections::{HashMap, VecDeque};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::SystemTime;

use axum::body::Bytes;
use nalgebra::Isometry3;

use super::store::CalibrationRecord;
use super::Refusal;
use crate::camera::LensWarp;
use crate::cell::Cell;
use crate::mask::Mask;
use crate::overlay::overlay_image;
use crate::render::{CpuRenderer, PosedRobot, SilhouetteRenderer};
use crate::run::rig::RigRunFile;
use crate::run::rig::RunLayout;
use crate::run::RunFile;
use crate::run::ViewEntry;

/// Bytes of PNG the cache keeps at most (about 200 overlays of a 640×480 camera).
pub const CACHE_BYTES: usize = 64 << 20;

/// What an overlay shows.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct Key {
    id: String,
    camera: Option<String>,
    view: usize,
    /// A dry run's planned pose drawn over the view, by index (`None`: the view itself).
    planned: Option<usize>,
    pose: [[u64; 4]; 4],
    mask: Option<(SystemTime, u64)>,
}

impl Key {
    /// The key of view `view` of calibration `id` (camera `camera` of a list) under `rows`,
    /// with mask file `mask`.
    pub fn new(
        id: &str,
        camera: Option<&str>,
        view: usize,
        rows: &[[f64; 4]; 4],
        mask: Option<&Path>,
    ) -> Key {
        let stamp = mask
            .and_then(|p| std::fs::metadata(p).ok())
            .and_then(|m| Some((m.modified().ok()?, m.len())));
        Key {
            id: id.to_string(),
            camera: camera.map(str::to_string),
            view,
            planned: None,
            pose: rows.map(|r| r.map(f64::to_bits)),
            mask: stamp,
        }
    }
}

impl Key {
    /// The same key for planned pose `k` drawn over the view: a dry run's plan never changes
    /// once written, so its overlays are cached like a view's, and a flood of unauthenticated
    /// reads renders each at most once.
    pub fn planned(mut self, k: usize) -> Key {
        self.planned = Some(k);
        self
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

/// Which camera an overlay draws: its index in [`Cell::cameras`], and its name in a list of
/// cameras (a cell of one `[camera]` table has none).
#[derive(Clone, Debug)]
pub struct Target {
    /// Index in [`Cell::cameras`].
    pub index: usize,
    /// The camera's name, for a list.
    pub name: Option<String>,
}

/// Longest query value read back into a message.
const MAX_QUERY_VALUE: usize = 64;

/// The camera a request's query picks: `camera=NAME` is required for a list of cameras and
/// refused for a cell of one, so no overlay silently shows another camera than asked.
pub fn target(cell: &Cell, query: Option<&str>) -> Result<Target, Refusal> {
    let cameras = cell.cameras();
    let names: Vec<&str> = cameras.iter().map(|c| c.name).collect();
    let asked = match query {
        Some(q) => camera_query(q)?,
        None => None,
    };
    match (cell.layout() == RunLayout::NamedCameras, asked) {
        (false, None) => Ok(Target {
            index: 0,
            name: None,
        }),
        (false, Some(_)) => Err(Refusal::BadRequest(
            "camera: this cell has one [camera] table; leave the query out".into(),
        )),
        (true, None) => Err(Refusal::BadRequest(format!(
            "camera: name the camera, ?camera=NAME; allowed: {names:?}"
        ))),
        (true, Some(name)) => match cell.camera_index(&name) {
            Some(index) => Ok(Target {
                index,
                name: Some(name),
            }),
            None => Err(Refusal::BadRequest(format!(
                "camera: {name:?} is no camera of this cell; allowed: {names:?}"
            ))),
        },
    }
}

/// `camera=NAME` from a query string: the only key allowed, at most once.
fn camera_query(query: &str) -> Result<Option<String>, Refusal> {
    let mut camera = None;
    for pair in query.split('&').filter(|p| !p.is_empty()) {
        match pair.split_once('=') {
            Some(("camera", _)) if camera.is_some() => {
                return Err(Refusal::BadRequest(
                    "camera: given twice; allowed: once".into(),
                ))
            }
            Some(("camera", v)) if v.len() <= MAX_QUERY_VALUE => camera = Some(v.to_string()),
            Some(("camera", _)) => {
                return Err(Refusal::BadRequest(format!(
                    "camera: longer than {MAX_QUERY_VALUE} characters; allowed: a camera's name"
                )))
            }
            _ => {
                return Err(Refusal::BadRequest(
                    "query: only camera=NAME is allowed".into(),
                ))
            }
        }
    }
    Ok(camera)
}

/// The views of `target` in the run at `json`: the run itself for one camera, that camera's
/// part of an `easyhec-run/2` for a list.
pub fn camera_run(json: &Path, target: &Target) -> crate::error::Result<Option<RunFile>> {
    let Some(name) = &target.name else {
        return RunFile::read(json).map(Some);
    };
    let rig = RigRunFile::read(json)?;
    Ok(rig
        .cameras
        .iter()
        .position(|c| &c.name == name)
        .map(|k| rig.camera_run(k)))
}

/// The estimate an overlay of `target` is drawn under: the record's own for one camera; for
/// a list, the camera's final result, or while the run goes on the record's live estimate
/// for the first camera it calibrates and the latest round of `rounds.json` for the others
/// (a run of one camera writes no per-camera rounds).
pub fn estimate(
    record: &CalibrationRecord,
    target: &Target,
    rounds: &Path,
) -> Option<[[f64; 4]; 4]> {
    let Some(name) = &target.name else {
        return record.camera_from_base;
    };
    if let Some(done) = &record.camera_results {
        return done
            .iter()
            .find(|c| &c.camera == name)
            .map(|c| c.camera_from_base);
    }
    let first = record.cameras.as_ref().and_then(|c| c.first());
    if first == Some(name) {
        return record.camera_from_base;
    }
    let text = crate::io::read_text_input(rounds).ok()?;
    let log: serde_json::Value = serde_json::from_str(&text).ok()?;
    let last = log["rounds"].as_array()?.last()?;
    let camera = last["cameras"]
        .as_array()?
        .iter()
        .find(|c| c["name"] == name.as_str())?;
    serde_json::from_value(camera["camera_from_base"].clone()).ok()
}

/// Renders view `n` (recorded in `run_dir` as `view`) under `pose` and encodes it as PNG:
/// green where render and mask agree, red where only the mask shows robot, blue where only
/// the render does, over the dimmed colour frame (over the grey mask when the lens distorts,
/// since the frame is in the distorted image).
pub fn render(
    cell: &Cell,
    target: &Target,
    run_dir: &Path,
    n: usize,
    view: &ViewEntry,
    pose: &Isometry3<f64>,
) -> Result<Vec<u8>, Refusal> {
    let cameras = cell.cameras();
    let unit = cameras
        .get(target.index)
        .ok_or_else(|| Refusal::Internal(format!("no camera {}", target.index)))?;
    let camera = unit.device.intrinsics().clone();
    let mask_rel = view
        .mask
        .as_ref()
        .ok_or_else(|| Refusal::NotFound(format!("view {n} has no mask")))?;
    // The run folder is data on disk: its paths stay inside it and its mask has the camera's
    // size, since the overlay indexes the render with the mask's pixels.
    let json = run_dir.join("run.json");
    let mask_path = crate::run::inside_run(run_dir, mask_rel, &json, &format!("views[{n}].mask"))?;
    let mask = Mask::load(&mask_path)?;
    if (mask.width, mask.height) != (camera.width, camera.height) {
        return Err(Refusal::Internal(format!(
            "{}: mask: is {}x{}; allowed: the camera's {}x{}",
            mask_path.display(),
            mask.width,
            mask.height,
            camera.width,
            camera.height
        )));
    }
    let observed = camera.undistort_mask(&mask);
    if view.joints.len() != cell.robot.actuated.len() {
        return Err(Refusal::Internal(format!(
            "view {n} has {} joints; the cell's robot has {}",
            view.joints.len(),
            cell.robot.actuated.len()
        )));
    }
    let rendered = CpuRenderer
        .render(
            &PosedRobot::new(unit.seen, &view.joints),
            &camera.undistorted(),
            pose,
            None,
        )
        .mask;
    let background = view
        .image
        .as_ref()
        .filter(|_| !camera.is_distorted())
        .and_then(|p| crate::run::inside_run(run_dir, p, &json, "image").ok())
        .and_then(|p| crate::segment::read_frame(&p, camera.width, camera.height).ok())
        .and_then(|f| image::RgbImage::from_raw(f.width, f.height, f.rgb));
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

    /// A 4x4 pose, translated by `x` metres.
    fn rows(x: f64) -> [[f64; 4]; 4] {
        [
            [1.0, 0.0, 0.0, x],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 1.0],
            [0.0, 0.0, 0.0, 1.0],
        ]
    }

    #[test]
    fn each_camera_of_a_list_is_drawn_under_its_own_latest_estimate() {
        let dir = tempfile::tempdir().unwrap();
        let rounds = dir.path().join("rounds.json");
        let write_rounds = |round: serde_json::Value| {
            let log = serde_json::json!({"format": "easyhec-rounds/1", "rounds": [round]});
            std::fs::write(&rounds, log.to_string()).unwrap();
        };
        let mut record: CalibrationRecord = serde_json::from_value(serde_json::json!({
            "id": "cal-0002", "state": "running", "trigger": "api", "dry_run": false,
            "max_views": 4, "created_at": "2026-11-27T00:00:00Z", "run_dir": "runs/cal-0002",
            "views": 2, "camera_from_base": rows(0.1), "cameras": ["side", "high"]
        }))
        .unwrap();
        let target = |n: &str| Target {
            index: 0,
            name: Some(n.into()),
        };
        // Running: the first camera's is the record's own, the others' the latest round's.
        write_rounds(serde_json::json!({"cameras": [
            {"name": "side", "camera_from_base": rows(0.3)},
            {"name": "high", "camera_from_base": rows(0.2)}
        ]}));
        assert_eq!(estimate(&record, &target("side"), &rounds), Some(rows(0.1)));
        assert_eq!(estimate(&record, &target("high"), &rounds), Some(rows(0.2)));
        assert_eq!(estimate(&record, &target("front"), &rounds), None);
        // A run of one camera writes no per-camera rounds: the record's estimate serves it.
        record.cameras = Some(vec!["high".into()]);
        write_rounds(serde_json::json!({"round": 1}));
        assert_eq!(estimate(&record, &target("high"), &rounds), Some(rows(0.1)));
        assert_eq!(estimate(&record, &target("side"), &rounds), None);
        // Finished: each camera's own result, whatever the record's top level says.
        record.camera_results = Some(vec![serde_json::from_value(serde_json::json!({
            "camera": "high", "camera_from_base": rows(0.4), "mean_iou": 0.98,
            "stop_reason": "converged"
        }))
        .unwrap()]);
        assert_eq!(estimate(&record, &target("high"), &rounds), Some(rows(0.4)));
        // One [camera]: the record's own.
        let single = Target {
            index: 0,
            name: None,
        };
        assert_eq!(estimate(&record, &single, &rounds), Some(rows(0.1)));
    }

    #[test]
    fn the_cache_keeps_what_fits_and_drops_the_oldest() {
        let cache = Cache::default();
        let rows = [[0.0; 4]; 4];
        let key = |v| Key::new("cal-0001", None, v, &rows, None);
        let big = Bytes::from(vec![0u8; CACHE_BYTES / 2]);
        cache.put(key(0), big.clone());
        cache.put(key(1), big.clone());
        assert!(cache.get(&key(0)).is_some() && cache.get(&key(1)).is_some());
        cache.put(key(2), Bytes::from(vec![1u8; 10]));
        assert!(cache.get(&key(0)).is_none(), "the oldest goes first");
        assert!(cache.get(&key(1)).is_some() && cache.get(&key(2)).is_some());
        let mut moved = rows;
        moved[0][3] = 0.001;
        assert!(cache
            .get(&Key::new("cal-0001", None, 1, &moved, None))
            .is_none());
        let other_camera = Key::new("cal-0001", Some("side"), 1, &rows, None);
        assert!(cache.get(&other_camera).is_none());
    }
}

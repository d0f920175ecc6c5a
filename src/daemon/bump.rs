//! Bump detection: is the active calibration still right? With the arm idle (or after a
//! checked move to `[daemon] check_pose`), capture one frame, segment it with the cell's
//! segmenter (the same path the loop uses; a context-aware one, `builtin`, also gets the
//! active calibration's recorded frames for its background plate), render the robot's
//! silhouette under the active `camera_from_base` at the reported joints, and compare: mask
//! IoU and the mean distance between the two outlines, both ways, in pixels, once the
//! segmenter's uniform outline offset (a fat or thin habit, up to
//! `bump_max_mask_offset_px`) is taken out. Below `bump_min_iou` or above
//! `bump_max_boundary_px` plus what the calibration's own uncertainty explains (twice the RMS
//! outline displacement its covariance predicts at the check view) the calibration is marked
//! stale, so an honestly uncertain calibration is not called bumped for its own uncertainty;
//! with `recalibrate_on_bump` a recalibration starts, warm-started from the stale pose (a
//! knocked camera moves by centimetres and degrees, well inside the solver's basin).

use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use easyhec_drivers::{ArmStatus, Frame};
use nalgebra::{Isometry3, Matrix6};

use super::store::CheckRecord;
use super::{now, ActivePose, Busy, Daemon, Refusal, StartOptions, WarmStart};
use crate::camera::{Intrinsics, LensWarp};
use crate::cell::{CameraRef, Cell};
use crate::error::{Error, Result};
use crate::mask::{Mask, SignedDistance};
use crate::render::{CpuRenderer, PosedRobot, SilhouetteRenderer};
use crate::run::rig::RunLayout;
use crate::run::RunFile;
use crate::solve::predicted_outline_motion_px;

/// Agreement of an observed mask with a rendered one, once the segmenter's own outline
/// offset is taken out.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Agreement {
    /// Intersection over union.
    pub iou: f64,
    /// Mean outline distance, both ways, pixels.
    pub boundary_px: f64,
    /// The outline offset taken out: how far the observed outline lies outward of the
    /// rendered one (the mean of the middle half of its distances, pixels, negative inward).
    pub mask_offset_px: f64,
}

/// Signed distances (pixels, negative inside `to`) of `from`'s outline crossings in `to`'s
/// field.
fn outline_distances(from: &Mask, to: &SignedDistance) -> Vec<f64> {
    from.outline_crossings()
        .iter()
        .filter_map(|c| to.sample(c[0], c[1]).map(|(v, _)| v))
        .collect()
}

/// The mean of the middle half of `values` (none of them NaN): as robust as the median to
/// the outline a knock or a blob moves, and not stuck to the few values that distances on a
/// pixel grid take.
fn middle_half_mean(values: impl Iterator<Item = f64>) -> f64 {
    let mut sorted: Vec<f64> = values.collect();
    sorted.sort_unstable_by(f64::total_cmp);
    let n = sorted.len();
    if n == 0 {
        return 0.0;
    }
    let middle = &sorted[n / 4..n - n / 4];
    middle.iter().sum::<f64>() / middle.len() as f64
}

/// IoU and symmetric mean outline distance of two masks of the same image, after moving the
/// observed outline back by its typical offset from the rendered one, up to `max_offset_px`.
///
/// Why: a segmenter that draws masks a pixel fat or thin (another network, another
/// threshold, another light than at the calibration) moves the whole outline one way, which
/// no camera motion does: a knock shifts or turns the silhouette, so its outline moves out
/// on one side and in on the other and the typical offset stays near zero. Only a move
/// along the optical axis scales the outline one way, and then not uniformly, so what is
/// left after the offset still shows it.
pub fn agreement(observed: &Mask, rendered: &Mask, max_offset_px: f64) -> Agreement {
    let (sd_obs, sd_ren) = (SignedDistance::of(observed), SignedDistance::of(rendered));
    // How far the observed outline lies outward of the rendered one, seen from either side.
    let from_rendered: Vec<f64> = outline_distances(rendered, &sd_obs)
        .into_iter()
        .map(|d| -d)
        .collect();
    let from_observed = outline_distances(observed, &sd_ren);
    if from_rendered.is_empty() || from_observed.is_empty() {
        // One of them shows no robot at all: as far off as it gets.
        return Agreement {
            iou: observed.iou(rendered),
            boundary_px: f64::from(observed.width.max(observed.height)),
            mask_offset_px: 0.0,
        };
    }
    let offset = if max_offset_px > 0.0 {
        middle_half_mean(from_rendered.iter().chain(&from_observed).copied())
            .clamp(-max_offset_px, max_offset_px)
    } else {
        0.0
    };
    let mean_apart = |d: &[f64]| d.iter().map(|v| (v - offset).abs()).sum::<f64>() / d.len() as f64;
    Agreement {
        iou: observed.with_outline_offset(-offset).iou(rendered),
        boundary_px: 0.5 * (mean_apart(&from_rendered) + mean_apart(&from_observed)),
        mask_offset_px: offset,
    }
}

/// Runs one bump check under the arm lease: every camera with an active calibration is
/// compared at one arm pose. `trigger` is `api` or `schedule`. Each stale camera is marked;
/// with `recalibrate_on_bump` one recalibration starts for the stale cameras only, each
/// warm-started from its stale pose, so the other cameras keep their results.
pub async fn check(
    daemon: &Arc<Daemon>,
    trigger: &str,
) -> std::result::Result<Vec<CheckRecord>, Refusal> {
    let actives = daemon.active_poses();
    if actives.is_empty() {
        return Err(Refusal::Conflict(
            "no active calibration to check: run one first (POST /api/v1/calibrations)".into(),
        ));
    }
    let lease = daemon.lease(Busy::Check)?;
    let measured = measure(daemon, &actives).await;
    drop(lease);
    let m = &daemon.metrics;
    m.checks.fetch_add(1, Ordering::Relaxed);
    let (joints, moved, agreements) = match measured {
        Ok(v) => v,
        Err(e) => {
            m.check_errors.fetch_add(1, Ordering::Relaxed);
            tracing::warn!("easyhec daemon: {trigger} bump check failed: {e}");
            return Err(Refusal::Internal(format!("bump check failed: {e}")));
        }
    };
    let s = daemon.settings();
    let at = now();
    let mut records: Vec<CheckRecord> = actives
        .iter()
        .zip(&agreements)
        .map(|((camera, id, _), (a, explained_px))| {
            let max_boundary_px = s.bump_max_boundary_px + explained_px;
            CheckRecord {
                at: at.clone(),
                trigger: trigger.to_string(),
                calibration_id: id.clone(),
                joints: joints.clone(),
                moved_to_check_pose: moved,
                iou: a.iou,
                boundary_px: a.boundary_px,
                mask_offset_px: a.mask_offset_px,
                min_iou: s.bump_min_iou,
                max_boundary_px,
                explained_px: *explained_px,
                stale: a.iou < s.bump_min_iou || a.boundary_px > max_boundary_px,
                recalibration: None,
                camera: camera.clone(),
            }
        })
        .collect();
    if let Some(last) = records.last() {
        m.last_iou.store(last.iou.to_bits(), Ordering::Relaxed);
        m.last_boundary_px
            .store(last.boundary_px.to_bits(), Ordering::Relaxed);
    }
    let stale: Vec<&ActivePose> = actives
        .iter()
        .zip(&records)
        .filter(|(_, r)| r.stale)
        .map(|(a, _)| a)
        .collect();
    // The measurements are kept first, whatever happens next.
    daemon.store().push_checks(&records)?;
    for (camera, id, _) in &stale {
        m.bumps.fetch_add(1, Ordering::Relaxed);
        let r = records
            .iter()
            .find(|r| &r.camera == camera)
            .expect("one record per active camera");
        tracing::warn!(
            "easyhec daemon: bump detected: {}calibration {id} is stale (IoU {:.4} < {} or boundary {:.2} px > {:.2} px)",
            camera.as_deref().map(|c| format!("camera '{c}': ")).unwrap_or_default(),
            r.iou, s.bump_min_iou, r.boundary_px, r.max_boundary_px
        );
        daemon
            .store()
            .mark_stale_camera(camera.as_deref(), id, &at)?;
    }
    if s.recalibrate_on_bump && !stale.is_empty() {
        if let Some(new_id) = recalibrate(daemon, &stale) {
            for r in records.iter_mut().filter(|r| r.stale) {
                r.recalibration = Some(new_id.clone());
            }
            if let Err(e) = daemon.store().update_last_checks(&records) {
                tracing::error!(
                    "easyhec daemon: cannot note recalibration {new_id} in checks.json: {e}"
                );
            }
        }
    }
    Ok(records)
}

/// Starts one recalibration of the stale cameras, each warm-started from its stale pose (a
/// knocked camera moves by centimetres and degrees, well inside the solver's basin).
fn recalibrate(daemon: &Arc<Daemon>, stale: &[&ActivePose]) -> Option<String> {
    let named = daemon.cell().layout() == RunLayout::NamedCameras;
    let opts = StartOptions {
        cameras: named.then(|| stale.iter().filter_map(|(c, _, _)| c.clone()).collect()),
        ..StartOptions::default()
    };
    let warm = WarmStart {
        from: stale[0].1.clone(),
        poses: stale.iter().map(|(c, _, p)| (c.clone(), *p)).collect(),
    };
    match daemon.start(opts, "bump", Some(warm)) {
        Ok(new_id) => {
            tracing::info!(
                "easyhec daemon: recalibrating as {new_id}, warm-started from {}",
                stale[0].1
            );
            Some(new_id)
        }
        Err(e) => {
            tracing::error!("easyhec daemon: cannot start the recalibration: {e:?}");
            None
        }
    }
}

/// Frames and joints of calibration `id`'s recorded views: a context-aware segmenter
/// (`builtin`) needs views where the robot stood elsewhere to see the background behind it.
fn recorded_views(
    daemon: &Daemon,
    id: &str,
    camera: &Intrinsics,
) -> Result<Vec<(Frame, Vec<f64>)>> {
    let store = daemon.store();
    let record = store.record(id).ok_or_else(|| {
        Error::Solve(format!(
            "calibration {id} is active but has no record in the data folder"
        ))
    })?;
    let dir = store.run_dir(&record);
    // The run folder is data on disk: check it (view count, paths inside the folder, regular
    // files, memory) as `easyhec solve` would, before reading any frame.
    let json = dir.join("run.json");
    let run = RunFile::read(&json)?;
    run.check(&json, &dir)?;
    run.views
        .iter()
        .filter_map(|v| v.image.as_ref().map(|img| (img, &v.joints)))
        .map(|(img, q)| {
            Ok((
                crate::segment::read_frame(&dir.join(img), camera.width, camera.height)?,
                q.clone(),
            ))
        })
        .collect()
}

/// A check compares silhouettes, so the camera must see the robot where the arm stands.
/// A fixed camera always does; a wrist camera only from some poses, and a check elsewhere
/// would read the robot's absence as a bump.
fn check_robot_in_view(
    cell: &Cell,
    unit: CameraRef<'_>,
    joints: &[f64],
    pose: &Isometry3<f64>,
) -> Result<()> {
    use crate::calibrate::VisibilityRule;
    // Only a camera on a link can lose sight of the robot.
    let rule = VisibilityRule::of(cell, unit.config.mount());
    if matches!(rule, VisibilityRule::InImage(_)) {
        return Ok(());
    }
    let camera = unit.device.intrinsics().undistorted();
    let low = camera.downsampled(cell.config.calibration.score_downsample);
    let posed = PosedRobot::new(unit.seen, joints).decimated(0.01);
    match rule.shows(&posed, &camera, &low, pose) {
        Some(_) => Ok(()),
        None => Err(Error::Hardware(format!(
            "camera '{}' on the arm does not see enough of the robot at the arm's pose to check it, so no camera was checked: set [daemon] check_pose to a pose that shows the robot (calibration.min_robot_image_fraction)",
            unit.name
        ))),
    }
}

/// Moves to `check_pose` if configured, then captures, segments and compares with each
/// active camera: the joints, whether the arm moved, and per camera the agreement and the
/// outline distance its uncertainty explains.
async fn measure(
    daemon: &Arc<Daemon>,
    actives: &[ActivePose],
) -> Result<(Vec<f64>, bool, Vec<(Agreement, f64)>)> {
    let cell = daemon.cell().clone();
    check_arm_idle(&cell).await?;
    let moved = move_to_check_pose(daemon, &cell).await?;
    let joints = cell.arm.read_joints().await?;
    let mut out = Vec::with_capacity(actives.len());
    for (camera, id, pose) in actives {
        let k = camera_index(&cell, camera.as_deref())?;
        let unit = cell.cameras()[k];
        check_robot_in_view(&cell, unit, &joints, pose)?;
        let frame = unit.device.grab().await?;
        let covariance = daemon
            .store()
            .active_of(camera.as_deref())
            .and_then(|a| a.result.uncertainty)
            .and_then(|u| u.moving_between_checks(&model_floor_of(&cell)));
        let job = CameraCheck {
            daemon: daemon.clone(),
            id: id.clone(),
            index: k,
            pose: *pose,
            joints: joints.clone(),
            covariance,
        };
        let measured = tokio::task::spawn_blocking(move || job.compare(frame))
            .await
            .map_err(|e| Error::Hardware(format!("check task: {e}")))??;
        out.push(measured);
    }
    Ok((joints, moved, out))
}

/// A fault or a moving arm ends the check before anything moves.
async fn check_arm_idle(cell: &Cell) -> Result<()> {
    match cell.arm.status().await? {
        ArmStatus::Fault(f) => Err(Error::Hardware(format!(
            "the arm reports a fault ({f}): clear it before checking"
        ))),
        ArmStatus::Moving => Err(Error::Hardware("the arm is moving".into())),
        _ => Ok(()),
    }
}

/// Moves to `[daemon] check_pose` through the safety checker, when it is set and the arm
/// stands elsewhere; `true` when it moved.
async fn move_to_check_pose(daemon: &Daemon, cell: &Cell) -> Result<bool> {
    let Some(target) = &daemon.settings().check_pose else {
        return Ok(false);
    };
    let from = cell.arm.read_joints().await?;
    let far = from
        .iter()
        .zip(target)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    if far <= 1e-3 {
        return Ok(false);
    }
    let speed = cell.config.calibration.speed_rad_s;
    let mv = cell
        .checker
        .check_move(&from, target, speed)
        .map_err(|v| Error::Hardware(format!("check_pose refused by the safety checker: {v}")))?;
    let arrived = cell.arm.execute(&mv).await?.wait().await;
    if let Err(e) = arrived {
        // A failed wait need not mean the arm stopped (a driver may lose track of a motion
        // the controller still runs): stop it before the arm's lease is released.
        if let Err(stop) = cell.arm.stop().await {
            tracing::warn!("stopping the arm after a failed move to check_pose: {stop}");
        }
        return Err(Error::driver("moving to check_pose", e));
    }
    Ok(true)
}

/// The index of `camera` in the cell (`None`: the cell's one camera).
fn camera_index(cell: &Cell, camera: Option<&str>) -> Result<usize> {
    match camera {
        None => Ok(0),
        Some(name) => cell.camera_index(name).ok_or_else(|| {
            Error::Solve(format!("camera '{name}' is active but not in the config"))
        }),
    }
}

/// One camera's comparison, run off the async runtime.
struct CameraCheck {
    daemon: Arc<Daemon>,
    id: String,
    index: usize,
    pose: Isometry3<f64>,
    joints: Vec<f64>,
    covariance: Option<Matrix6<f64>>,
}

impl CameraCheck {
    /// Segments `frame` with the camera's segmenter and compares it with the silhouette
    /// rendered under the active pose.
    fn compare(self, frame: Frame) -> Result<(Agreement, f64)> {
        let cell = self.daemon.cell().clone();
        let unit = cell.cameras()[self.index];
        let camera = unit.device.intrinsics().clone();
        if frame.width != camera.width || frame.height != camera.height {
            return Err(Error::Hardware(format!(
                "camera returned a {}x{} frame; its intrinsics say {}x{}",
                frame.width, frame.height, camera.width, camera.height
            )));
        }
        let mask = if unit.segmenter.uses_context() {
            let recorded = recorded_views(&self.daemon, &self.id, &camera)?;
            crate::pipeline::segment_solve::segment_among_recorded(
                &CpuRenderer,
                unit.segmenter,
                unit.seen,
                &camera,
                frame,
                &self.joints,
                recorded,
                &self.pose,
                unit.segmenter_config.min_band_px(),
            )?
            .ok_or_else(|| Error::Solve("the segmenter returned no mask".into()))?
        } else {
            unit.segmenter.segment(&frame)?
        };
        let observed = camera.undistort_mask(&mask);
        let pinhole = camera.undistorted();
        let posed = PosedRobot::new(unit.seen, &self.joints);
        let rendered = CpuRenderer.render(&posed, &pinhole, &self.pose, Some(1.0));
        let explained = self.covariance.map_or(0.0, |c| {
            predicted_outline_motion_px(&rendered, &pinhole, &c)
        });
        let max_offset_px = self.daemon.settings().bump_max_mask_offset_px;
        Ok((
            agreement(&observed, &rendered.mask, max_offset_px),
            explained,
        ))
    }
}

/// The cell's model-error floor as a covariance.
fn model_floor_of(cell: &Cell) -> Matrix6<f64> {
    let settings = &cell.config.calibration;
    crate::solve::model_floor(
        settings.model_floor_rotation_deg,
        settings.model_floor_translation_mm,
    )
}

/// Scheduled checks every `interval` while the daemon runs; skipped while the arm is leased
/// or nothing is active.
pub async fn schedule(daemon: Arc<Daemon>, interval: Duration) {
    let mut shutdown = daemon.shutdown_signal();
    let mut tick = tokio::time::interval(interval);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    tick.tick().await;
    loop {
        tokio::select! {
            _ = tick.tick() => {}
            _ = shutdown.changed() => return,
        }
        if daemon.busy().is_some() || daemon.active_poses().is_empty() {
            continue;
        }
        match check(&daemon, "schedule").await {
            Ok(c) if c.iter().all(|c| !c.stale) => {}
            // A failed measurement was logged by `check`.
            Ok(_) | Err(Refusal::Busy(_) | Refusal::Internal(_)) => {}
            Err(e) => tracing::warn!("easyhec daemon: scheduled check: {e:?}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector3;

    use super::*;
    use crate::geometry::look_at_camera_from_base;
    use crate::render::Silhouette;
    use crate::robot::RobotModel;

    /// The posed xArm6, the camera and the pose it is seen from, about 1.5 m away.
    fn scene() -> (PosedRobot, Intrinsics, Isometry3<f64>) {
        let urdf = concat!(env!("CARGO_MANIFEST_DIR"), "/robots/xarm6/robot.urdf");
        let robot = RobotModel::from_urdf(urdf).unwrap();
        let camera = Intrinsics::pinhole(640, 480, 600.0, 600.0, 319.5, 239.5);
        let pose = look_at_camera_from_base(
            &Vector3::new(1.3, 0.5, 0.8),
            &Vector3::new(0.1, 0.0, 0.3),
            &Vector3::z(),
        );
        let posed = PosedRobot::new(&robot, &[0.3, -0.4, -0.5, 0.2, 0.9, 0.1]);
        (posed, camera, pose)
    }

    /// The xArm6 seen from 1.5 m, rendered with outline samples.
    fn seen() -> (Silhouette, Intrinsics) {
        let (posed, camera, pose) = scene();
        (
            CpuRenderer.render(&posed, &camera, &pose, Some(1.0)),
            camera,
        )
    }

    #[test]
    fn a_segmenter_drawing_fat_or_thin_reads_as_its_offset_not_as_a_bump() {
        let (sil, _) = seen();
        let rendered = &sil.mask;
        for habit in [1.0, -1.0] {
            // Every outline pixel one pixel outward (or inward).
            let observed = rendered.with_outline_offset(habit);
            let raw = agreement(&observed, rendered, 0.0);
            let taken_out = agreement(&observed, rendered, 2.0);
            eprintln!("{habit:+} px: as drawn {raw:?}; offset taken out {taken_out:?}");
            assert_eq!(raw.mask_offset_px.to_bits(), 0.0f64.to_bits());
            assert!(raw.boundary_px > 0.8, "{habit}: {raw:?}");
            assert!(
                (taken_out.mask_offset_px - habit).abs() < 0.3,
                "{habit}: {taken_out:?}"
            );
            assert!(taken_out.boundary_px < 0.35, "{habit}: {taken_out:?}");
            assert!(
                taken_out.iou > 0.97 && taken_out.iou > raw.iou,
                "{habit}: {taken_out:?} {raw:?}"
            );
        }
        // The offset taken out never exceeds the bound.
        let far = agreement(&rendered.with_outline_offset(4.0), rendered, 2.0);
        assert_eq!(far.mask_offset_px, 2.0, "{far:?}");
        assert!(far.boundary_px > 1.5, "{far:?}");
    }

    #[test]
    fn a_knocked_camera_still_reads_as_a_bump_through_a_fat_segmenter() {
        let (sil, _) = seen();
        let (posed, camera, pose) = scene();
        // About 1 degree and 15 mm, as the daemon's bump test knocks its camera.
        let knock = Isometry3::from_parts(
            nalgebra::Translation3::new(0.010, -0.008, 0.008),
            nalgebra::UnitQuaternion::from_euler_angles(0.010, -0.012, 0.006),
        );
        let moved = CpuRenderer
            .render(&posed, &camera, &(knock * pose), None)
            .mask;
        let knocked = agreement(&moved, &sil.mask, 2.0);
        let knocked_fat = agreement(&moved.with_outline_offset(1.0), &sil.mask, 2.0);
        eprintln!("knocked {knocked:?}; knocked and fat {knocked_fat:?}");
        // The default threshold is 1.5 px; both stay well past it.
        assert!(knocked.boundary_px > 3.0, "{knocked:?}");
        assert!(knocked_fat.boundary_px > 3.0, "{knocked_fat:?}");
        assert!(knocked.mask_offset_px.abs() < 1.0, "{knocked:?}");
        assert!(knocked_fat.iou < 0.9, "{knocked_fat:?}");
    }

    #[test]
    fn the_floor_and_the_segmentation_term_explain_no_outline_motion() {
        let (sil, camera) = seen();
        let rows = |m: &Matrix6<f64>| -> Box<[[f64; 6]; 6]> {
            Box::new(std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)])))
        };
        // 1 mm sideways from the outlines' own scatter, 5 mm sideways from the pixels the
        // segmenter could not decide, 2 mm from the model floor.
        let mut own = Matrix6::zeros();
        own[(0, 0)] = 1e-6;
        let segmentation = own * 25.0;
        let floor = crate::solve::model_floor(0.0, 2.0);
        let mut u = crate::run::UncertaintyEntry {
            rotation_deg: [0.1; 3],
            translation_mm: [5.0; 3],
            camera_centre_95_mm: Some(15.0),
            covariance: Some(rows(&(own + segmentation + floor))),
            terms: None,
            mask_offset: None,
        };
        let explained = |u: &crate::run::UncertaintyEntry| {
            predicted_outline_motion_px(&sil, &camera, &u.moving_between_checks(&floor).unwrap())
        };
        let expected = predicted_outline_motion_px(&sil, &camera, &own);
        // A result that does not split the segmentation term out keeps it in.
        assert!(
            explained(&u) > 4.0 * expected,
            "{} vs {expected}",
            explained(&u)
        );
        u.terms = Some(Box::new(crate::run::UncertaintyTerms {
            dominant: "segmentation".into(),
            statistical_centre_95_mm: 2.0,
            inter_view_centre_95_mm: None,
            mask_bias_centre_95_mm: None,
            segmentation_centre_95_mm: Some(14.0),
            segmentation_not_measured: None,
            segmentation_covariance: Some(rows(&segmentation)),
        }));
        assert!(
            (explained(&u) - expected).abs() < 1e-9,
            "{} vs {expected}",
            explained(&u)
        );
        u.covariance = None;
        assert!(u.moving_between_checks(&floor).is_none());
    }

    #[test]
    fn explained_distance_is_twice_the_predicted_outline_sigma() {
        let (sil, camera) = seen();
        assert_eq!(
            predicted_outline_motion_px(&sil, &camera, &Matrix6::zeros()),
            0.0
        );
        // 1 mm of sideways translation at about 1.5 m moves an outline by at most 0.4 px, by
        // about half that on average over its directions.
        let mut sideways = Matrix6::zeros();
        sideways[(0, 0)] = 1e-6;
        let one_mm = predicted_outline_motion_px(&sil, &camera, &sideways);
        assert!((0.1..=0.8).contains(&one_mm), "{one_mm} px for 1 mm");
        // The same in depth moves the outline far less: only by scaling the image.
        let mut depth = Matrix6::zeros();
        depth[(2, 2)] = 1e-6;
        assert!(predicted_outline_motion_px(&sil, &camera, &depth) < 0.5 * one_mm);
        // Standard deviations scale with the square root of the covariance.
        let four = predicted_outline_motion_px(&sil, &camera, &(sideways * 4.0));
        assert!((four - 2.0 * one_mm).abs() < 1e-9 * one_mm.max(1.0));
    }
}

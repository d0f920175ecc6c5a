//! The covariance of the estimate, built to cover the true error:
//!
//! - **Correlated outline noise.** A segmenter's boundary errors are smooth along the outline,
//!   so neighbouring residuals are not independent evidence. The covariance is a sandwich
//!   `H^-1 M H^-1`: `H` the robust (Cauchy-weighted) normal matrix, `M` the scatter of the
//!   residual pulls summed over image tiles, so residuals within a tile count as one
//!   observation whatever their correlation, and blobs count as large as they pull.
//! - **Joint errors.** The solver takes each view's reported joints as true. A joint error
//!   moves every link after it rigidly, which the outline sees as a camera motion on those
//!   links only; its pull on the normal equations, `H_links * xi_joint * dq`, enters `M` with
//!   the stated joint noise.
//! - **A model-error floor** for what no residual shows: mesh and kinematic deviations of the
//!   real robot from its URDF and intrinsics error. It is added per axis of the increment.
//!
//! Disagreement between views shows only partly as residual pulls: on real frames most of a
//! view's systematic error sits past the tight Cauchy scale, where it barely pulls. The view
//! jackknife (module `disagreement`) measures it and adds what it shows beyond this covariance.

use std::collections::BTreeMap;

use nalgebra::{Isometry3, Matrix6, SMatrix, SVector};
use rayon::prelude::*;

use super::boundary::{view_residuals, LeftOut, Level};
use super::SolveOptions;
use crate::geometry::Twist;
use crate::render::{PosedRobot, Silhouette};

/// A pose increment and the mask offset: the parameters the sandwich is built over.
type Vec7 = SVector<f64, 7>;
type Mat7 = SMatrix<f64, 7, 7>;

/// One view's part of the sandwich, over the pose increment and the mask offset.
struct ViewPart {
    /// Robust normal matrix, from the slope of the Cauchy influence.
    h: Mat7,
    /// The same from the IRLS weight: the stand-in when the slope's is not positive definite.
    h_weight: Mat7,
    /// Scatter of the tile-summed residual pulls.
    tiles_meat: Mat7,
    /// Tiles the outline crossed.
    tiles: usize,
    /// Scatter of the pull the view's joint errors put on the normal equations, before it is
    /// clamped to positive semi-definite (per parameter set: a clamp over seven parameters
    /// is not the clamp of the pose's six).
    joints_meat: Mat7,
}

/// The statistical covariance of a fit.
pub(super) struct Statistical {
    /// Of the left increment of `camera_from_base`, with the mask offset estimated too when
    /// it was.
    pub(super) pose: Matrix6<f64>,
    /// Of the same with the offset taken as known: what the pose's covariance would be
    /// without the offset to estimate (equal to `pose` when it was not estimated).
    pub(super) pose_offset_known: Matrix6<f64>,
    /// Variance of the mask offset, px^2 (when estimated).
    pub(super) offset_px2: Option<f64>,
}

/// The covariance of the left increment of `camera_from_base` at `pose` (and of the mask
/// offset `offset_px` when `opts` estimates it), from the fine level's residuals of
/// `silhouettes` (rendered at `pose`); `None` when the outlines leave a direction unpinned.
pub(super) fn pose_covariance(
    level: &Level,
    silhouettes: &[Silhouette],
    robots: &[&PosedRobot],
    pose: &Isometry3<f64>,
    offset_px: f64,
    opts: &SolveOptions,
) -> Option<Statistical> {
    let parts: Vec<ViewPart> = silhouettes
        .par_iter()
        .zip(&level.views)
        .zip(robots)
        .map(|((sil, obs), robot)| view_part(level, sil, obs, robot, pose, offset_px, opts))
        .collect();
    let h: Mat7 = parts.iter().map(|p| p.h).sum();
    let h_weight: Mat7 = parts.iter().map(|p| p.h_weight).sum();
    // With the offset fitted, both covariances below take their bread from the same matrix,
    // so that their difference (the mask-bias term) means something: the weight's when the
    // slope's 7x7 is not positive definite (then neither 6x6 block is trusted either).
    let h = if opts.estimate_mask_offset && h.cholesky().is_none() {
        h_weight
    } else {
        h
    };
    let tiles: usize = parts.iter().map(|p| p.tiles).sum();
    let fitted = if opts.estimate_mask_offset { 7 } else { 6 };
    // Residuals at the estimate have the fitted directions taken out of them: scale their
    // scatter back up by tiles / (tiles - fitted).
    let dof = tiles.saturating_sub(fitted).max(1) as f64;
    let scale = tiles as f64 / dof;
    let pose_block = |m: &Mat7| -> Matrix6<f64> { m.fixed_view::<6, 6>(0, 0).into_owned() };
    // Past the Cauchy scale the influence's slope is negative, so a fit with many residuals
    // there (a poor one, flagged as such) can leave `h` indefinite; the IRLS weight's matrix
    // then stands in: tighter, but a finite answer where the slope has none.
    let known = {
        let inv = pose_block(&h)
            .cholesky()
            .or_else(|| pose_block(&h_weight).cholesky())?
            .inverse();
        let meat: Matrix6<f64> = parts
            .iter()
            .map(|p| pose_block(&p.tiles_meat) * scale + positive_part(&pose_block(&p.joints_meat)))
            .sum();
        inv * meat * inv
    };
    if !opts.estimate_mask_offset {
        return Some(Statistical {
            pose: known,
            pose_offset_known: known,
            offset_px2: None,
        });
    }
    let inv = h.cholesky().or_else(|| h_weight.cholesky())?.inverse();
    let meat: Mat7 = parts
        .iter()
        .map(|p| p.tiles_meat * scale + positive_part7(&p.joints_meat))
        .sum();
    let both = inv * meat * inv;
    Some(Statistical {
        pose: pose_block(&both),
        pose_offset_known: known,
        offset_px2: Some(both[(6, 6)]),
    })
}

/// The model-error floor's covariance of the left increment `(rho, phi)`: `translation_mm`
/// per camera axis on `rho`, `rotation_deg` on `phi` (1 sigma each).
pub fn model_floor(rotation_deg: f64, translation_mm: f64) -> Matrix6<f64> {
    let rotation = rotation_deg.to_radians().powi(2);
    let translation = (translation_mm / 1000.0).powi(2);
    Matrix6::from_diagonal(&Twist::new(
        translation,
        translation,
        translation,
        rotation,
        rotation,
        rotation,
    ))
}

/// One image tile's share of a view's residuals.
#[derive(Clone)]
struct Tile {
    /// Summed residual pull.
    pull: Vec7,
    /// Per joint: the pull a unit error of that joint would add here.
    joint_pulls: Vec<Vec7>,
}

/// One view's robust normal matrix and its meat: tile-summed residual pulls, plus the pull of
/// its joints' errors across tiles (their pull within a tile is in the residuals already).
fn view_part(
    level: &Level,
    sil: &Silhouette,
    obs: &super::boundary::ObservedLevel,
    robot: &PosedRobot,
    pose: &Isometry3<f64>,
    offset_px: f64,
    opts: &SolveOptions,
) -> ViewPart {
    let c = level.robust_scale_px;
    let tile = opts.covariance_tile_px.max(1.0);
    let per_level_px = 1.0 / f64::from(level.factor);
    let motions = robot.joint_motions.as_slice();
    let twists: Vec<Twist> = motions.iter().map(|m| m.twist_in_camera(pose)).collect();
    let empty = Tile {
        pull: Vec7::zeros(),
        joint_pulls: vec![Vec7::zeros(); motions.len()],
    };
    let mut h = Mat7::zeros();
    let mut h_weight = Mat7::zeros();
    let mut tiles: BTreeMap<(i64, i64), Tile> = BTreeMap::new();
    let left_out = LeftOut::of(robot, opts, pose);
    view_residuals(sil, obs, &level.camera, &left_out, |res| {
        let Some(r) = res.r else { return };
        let j_offset = res.offset_sign * per_level_px;
        let r = r + j_offset * offset_px;
        let mut j = Vec7::zeros();
        j.fixed_rows_mut::<6>(0).copy_from(&res.j);
        if opts.estimate_mask_offset {
            j[6] = j_offset;
        }
        let u = (r / c) * (r / c);
        let w = 1.0 / (1.0 + u);
        // The bread is the derivative of the Cauchy influence `r w(r)`, not the IRLS weight:
        // near the scale the weight overstates how firmly a residual holds the pose.
        let held = j * ((1.0 - u) * w * w * res.ds);
        h += held * j.transpose();
        h_weight += j * j.transpose() * (w * res.ds);
        let key = (
            (res.pixel[0] / tile).floor() as i64,
            (res.pixel[1] / tile).floor() as i64,
        );
        let t = tiles.entry(key).or_insert_with(|| empty.clone());
        t.pull += j * (w * r * res.ds);
        let link = sil
            .boundary
            .get(res.sample)
            .and_then(|s| robot.vertex_link.get(s.vertex as usize));
        if let Some(&l) = link {
            for ((m, xi), jp) in motions.iter().zip(&twists).zip(&mut t.joint_pulls) {
                if m.moves_link.get(l as usize) == Some(&true) {
                    *jp += held * res.j.dot(xi);
                }
            }
        }
    });
    let tiles_meat: Mat7 = tiles.values().map(|t| t.pull * t.pull.transpose()).sum();
    ViewPart {
        h,
        h_weight,
        tiles_meat,
        tiles: tiles.len(),
        joints_meat: joints_meat(&tiles, motions.len(), opts.joint_noise_rad),
    }
}

/// The scatter of the pull of a view's joint errors between tiles: `q^2 sum_k (b_k b_k^T -
/// sum_t b_tk b_tk^T)`, `b_tk` joint k's pull in tile t, `b_k` its sum. The within-tile part
/// is left out because the tile scatter of the residuals already holds it. Not yet clamped
/// to positive semi-definite.
fn joints_meat(tiles: &BTreeMap<(i64, i64), Tile>, joints: usize, noise_rad: f64) -> Mat7 {
    let q2 = noise_rad * noise_rad;
    if q2 <= 0.0 || joints == 0 {
        return Mat7::zeros();
    }
    let mut meat = Mat7::zeros();
    for k in 0..joints {
        let b: Vec7 = tiles.values().map(|t| t.joint_pulls[k]).sum();
        let within: Mat7 = tiles
            .values()
            .map(|t| t.joint_pulls[k] * t.joint_pulls[k].transpose())
            .sum();
        meat += (b * b.transpose() - within) * q2;
    }
    meat
}

/// `m` with its negative eigenvalues set to zero.
pub(super) fn positive_part(m: &Matrix6<f64>) -> Matrix6<f64> {
    let eig = m.symmetric_eigen();
    eig.eigenvectors
        * Matrix6::from_diagonal(&eig.eigenvalues.map(|l| l.max(0.0)))
        * eig.eigenvectors.transpose()
}

/// [`positive_part`] over the pose and the mask offset.
fn positive_part7(m: &Mat7) -> Mat7 {
    let eig = m.symmetric_eigen();
    eig.eigenvectors
        * Mat7::from_diagonal(&eig.eigenvalues.map(|l| l.max(0.0)))
        * eig.eigenvectors.transpose()
}

//! What the views' disagreement shows: a view-level jackknife of the estimate.
//!
//! Real frames carry errors no residual model holds: a mesh that is not quite the robot,
//! joints a little off, a segmenter that is fat on one link and thin on another. Each view's
//! outline then pulls the pose its own way, and the outline residuals, smooth along the
//! outline and mostly past the tight Cauchy scale, understate how far (on the real xArm7 set,
//! 20–50 times). Leaving views out and solving again measures it directly.
//!
//! The views are dealt into at most [`MAX_GROUPS`] groups (view `i` into group `i mod g`);
//! each group is left out in turn and the rest solved again, warm: one LM iteration at the
//! second-finest pyramid level, whose wider Cauchy scale lets the pose leave the all-view
//! basin as a cold solve would, then LM at full resolution. The observations of both levels
//! are built once and shared, and so is the first render: every left-out solve starts at the
//! same pose, where its normal equations are a sum of per-view ones. With `d_j` the left increment of group `j`'s solve,
//! `C = (g-1)/g sum (d_j - d)(d_j - d)^T` estimates the estimate's covariance.
//!
//! The jackknife does not replace the statistical covariance `S`; it adds what it shows
//! beyond it ([`with_excess`]). In the frame where `S` is the identity, each direction's
//! jackknife variance `l` counts only past `CHANCE_RATIO` (10): a jackknife over a few views is
//! noisy and biased upward (each left-out solve rests on fewer views), and on the simulator,
//! where `S` is right, its largest such `l` stays below 10 in 87% of scenes at 5 and 10 views
//! (70% at 3). A higher threshold at few views was measured and dropped: on four real views
//! it cut what their disagreement showed (docs/benchmarks.md). The excess
//! `l - 10` is scaled by `(t / z)^2`, Student's 97.5% quantile with `g - 1` degrees of freedom
//! over the normal one, because it was estimated from `g` solves. On the real xArm7 set `l`
//! is 400–2500, so there the reported covariance is the jackknife's.

use nalgebra::{Isometry3, Matrix6};

use super::boundary::{per_view_normals, sum_over, Level};
use super::lm::{robust_scale_at, Walk};
use super::{SolveOptions, View};
use crate::camera::Intrinsics;
use crate::geometry::{log_se3, Twist};
use crate::render::{PosedRobot, SilhouetteRenderer};

/// Fewest views the jackknife runs on: with two, each left-out solve rests on one view alone
/// and the spread has one degree of freedom.
pub const JACKKNIFE_MIN_VIEWS: usize = 3;

/// Most left-out solves: past this, views are left out in groups (the cost stays that of
/// about [`MAX_GROUPS`] solves however many views there are).
pub const MAX_GROUPS: usize = 10;

/// LM iterations of a left-out solve at the second-finest level, then at full resolution.
const ITERATIONS: [usize; 2] = [1, 6];

/// The view-level jackknife covariance of the left increment of `camera_from_base` at `pose`
/// and its degrees of freedom; `None` with fewer than [`JACKKNIFE_MIN_VIEWS`] views or when a
/// left-out solve fails. Each left-out solve starts from the all-view mask offset `offset_px`
/// and, when the options estimate it, fits it again.
pub(super) fn view_jackknife(
    renderer: &dyn SilhouetteRenderer,
    camera: &Intrinsics,
    views: &[View],
    pose: &Isometry3<f64>,
    offset_px: f64,
    opts: &SolveOptions,
) -> Option<(Matrix6<f64>, usize)> {
    let n = views.len();
    if n < JACKKNIFE_MIN_VIEWS {
        return None;
    }
    let groups = n.min(MAX_GROUPS);
    let levels: Vec<(u32, Level)> = finest_levels(&opts.pyramid)
        .into_iter()
        .map(|f| (f, Level::new(camera, views, f, robust_scale_at(f, opts))))
        .collect();
    let robots: Vec<&PosedRobot> = views.iter().map(|v| &v.robot).collect();
    // Every left-out solve starts at `pose` on the coarser level: its first normal equations
    // are a sum of the same per-view ones, rendered once here.
    let (first_factor, first_level) = levels.first()?;
    let first_normals = per_view_normals(renderer, &robots, first_level, pose, offset_px, opts);
    let mut deltas = Vec::with_capacity(groups);
    for group in 0..groups {
        let kept: Vec<usize> = (0..n).filter(|i| i % groups != group).collect();
        let kept_robots: Vec<&PosedRobot> = kept.iter().map(|&i| robots[i]).collect();
        let mut walk = Walk {
            pose: *pose,
            offset_px,
            iterations: 0,
            trajectory: Vec::new(),
        };
        let caps = &ITERATIONS[ITERATIONS.len() - levels.len()..];
        for ((factor, level), &cap) in levels.iter().zip(caps) {
            let start = (factor == first_factor).then(|| sum_over(&first_normals, &kept));
            let level = level.keeping(&kept);
            walk.level(renderer, &level, &kept_robots, *factor, cap, opts, start)
                .ok()?;
        }
        deltas.push(log_se3(&(walk.pose * pose.inverse())));
    }
    let mean: Twist = deltas.iter().sum::<Twist>() / groups as f64;
    let scatter: Matrix6<f64> = deltas
        .iter()
        .map(|d| (d - mean) * (d - mean).transpose())
        .sum();
    let g = groups as f64;
    Some((scatter * ((g - 1.0) / g), groups - 1))
}

/// How many times the statistical variance a direction's jackknife variance must exceed
/// before the excess counts as disagreement (module notes).
const CHANCE_RATIO: f64 = 10.0;

/// `statistical` widened by what `jackknife` (with `dof` degrees of freedom) shows beyond it:
/// in the frame where `statistical` is the identity, each eigenvalue `l` of the jackknife adds
/// `(t / z)^2 max(0, l - CHANCE_RATIO)`. When `statistical` is not positive definite (an
/// unpinned or degenerate fit) it is returned unchanged.
pub(super) fn with_excess(
    statistical: &Matrix6<f64>,
    jackknife: &Matrix6<f64>,
    dof: usize,
) -> Matrix6<f64> {
    // An unpinned fit is `diag(inf)`; whitening by it would turn the infinities into NaN.
    let finite = |m: &Matrix6<f64>| m.iter().all(|v| v.is_finite());
    if !finite(statistical) || !finite(jackknife) {
        return *statistical;
    }
    let Some(l) = statistical.cholesky().map(|c| c.l()) else {
        return *statistical;
    };
    let Some(l_inv) = l.try_inverse() else {
        return *statistical;
    };
    let whitened = l_inv * jackknife * l_inv.transpose();
    let eig = (whitened + whitened.transpose())
        .scale(0.5)
        .symmetric_eigen();
    let scale = student_scale(dof).powi(2);
    let widened = eig
        .eigenvalues
        .map(|v| 1.0 + scale * (v - CHANCE_RATIO).max(0.0));
    let w = eig.eigenvectors * Matrix6::from_diagonal(&widened) * eig.eigenvectors.transpose();
    let c = l * w * l.transpose();
    (c + c.transpose()).scale(0.5)
}

/// The two finest factors of `pyramid`, coarser first (one when it has one level).
fn finest_levels(pyramid: &[u32]) -> Vec<u32> {
    let mut factors = pyramid.to_vec();
    factors.sort_unstable_by(|a, b| b.cmp(a));
    factors.dedup();
    let keep = factors.len().min(2);
    factors.split_off(factors.len() - keep)
}

/// Student's t 97.5% quantile with `dof` degrees of freedom over the normal one (1.960).
fn student_scale(dof: usize) -> f64 {
    const T975: [f64; 12] = [
        12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179,
    ];
    let t = T975.get(dof.max(1) - 1).copied().unwrap_or(2.0);
    t / 1.960
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_two_finest_levels_come_coarser_first() {
        assert_eq!(finest_levels(&[8, 4, 2, 1]), vec![2, 1]);
        assert_eq!(finest_levels(&[4, 1, 4]), vec![4, 1]);
        assert_eq!(finest_levels(&[1]), vec![1]);
    }

    #[test]
    fn only_the_excess_past_chance_widens_and_only_in_its_own_direction() {
        let statistical = Matrix6::from_diagonal(&Twist::new(4.0, 1.0, 1.0, 1.0, 1.0, 1.0));
        // Direction 0: 5 times its statistical variance (chance); direction 1: 100 times.
        let jackknife = Matrix6::from_diagonal(&Twist::new(20.0, 100.0, 0.5, 0.0, 0.0, 0.0));
        let c = with_excess(&statistical, &jackknife, 9);
        let t2 = (2.262f64 / 1.96).powi(2);
        assert!((c[(0, 0)] - 4.0).abs() < 1e-9, "{c}");
        assert!((c[(1, 1)] - (1.0 + t2 * 90.0)).abs() < 1e-9, "{c}");
        for k in 2..6 {
            assert!((c[(k, k)] - 1.0).abs() < 1e-9, "{c}");
        }
        assert!((c - c.transpose()).norm() < 1e-12);
        // A degenerate or unpinned statistical covariance is left as it is.
        let singular = Matrix6::zeros();
        assert_eq!(with_excess(&singular, &jackknife, 9), singular);
        let unpinned = Matrix6::from_diagonal_element(f64::INFINITY);
        assert_eq!(with_excess(&unpinned, &jackknife, 9), unpinned);
    }

    #[test]
    fn the_student_scale_shrinks_towards_one_with_more_groups() {
        assert!((student_scale(2) - 4.303 / 1.96).abs() < 1e-12);
        assert!((student_scale(9) - 2.262 / 1.96).abs() < 1e-12);
        assert!(student_scale(50) > 1.0 && student_scale(50) < student_scale(9));
    }
}

//! Several cameras' poses refined together with a correction of each view's joints.
//!
//! Why: encoder noise puts the robot somewhere slightly different from where its recorded
//! joints say, differently in each view. One camera's fit cannot tell that from its own pose
//! error and carries it into the estimate; in the three-camera cell (0.5 mrad of encoder
//! noise) it is about half of a 5-view calibration's error. Cameras that watch the same view
//! see the same joint error from different sides, so solving each view's joint correction
//! together with every camera's pose, under the encoder-noise prior, takes much of it out.
//!
//! The residuals are the solver's own full-resolution outline residuals (both ways, Cauchy
//! weighted), each weighed by the camera's outline noise; a joint correction moves only the
//! outline samples of the links that joint moves ([`crate::robot::JointMotion`]). The
//! corrections then pose every view for an ordinary re-solve of each camera, so the final
//! poses come from the same solver (and its posterior refinement) as a single camera's: the
//! Gauss–Newton end-game on quantised outline residuals is rougher than that.

use nalgebra::{DMatrix, DVector, Isometry3, Matrix6};
use rayon::prelude::*;

use super::boundary::{view_residuals, LeftOut, ObservedLevel};
use super::{uncertainty_of, SolveOptions, SolveReport, View};
use crate::backend::Backend;
use crate::camera::Intrinsics;
use crate::geometry::{exp_se3, Twist};
use crate::mask::Mask;
use crate::render::{PosedRobot, SilhouetteRenderer};
use crate::robot::RobotModel;

/// One camera of the joint refinement: the robot as it sees it, its undistorted pinhole
/// camera, its mask of every view (in the order of the joint vectors) and its estimate.
pub struct SharedCamera<'a> {
    /// The robot as this camera sees it (rooted at its mount).
    pub seen: &'a RobotModel,
    /// Undistorted pinhole camera the masks are in.
    pub camera: &'a Intrinsics,
    /// Observed mask of each view.
    pub observed: Vec<&'a Mask>,
    /// The camera's estimate before the refinement.
    pub camera_from_base: Isometry3<f64>,
    /// Variance of one pixel of outline, px² (the solve report's `outline_noise_px2`).
    pub outline_noise_px2: f64,
    /// Whether the camera's own solve left the mount contact out (its report's
    /// `mount_contact_left_out`): the shared fit reads the same outline.
    pub mount_contact_left_out: bool,
}

/// What the refinement found: each camera's pose, each view's joint correction.
#[derive(Clone, Debug)]
pub struct SharedRefinement {
    /// Each camera's refined `camera_from_base`, in the order given.
    pub camera_from_base: Vec<Isometry3<f64>>,
    /// Each view's joint correction (true minus recorded), radians.
    pub joint_corrections: Vec<Vec<f64>>,
    /// Each camera's pose covariance (left increment) from the joint error the corrections
    /// leave, when the normal equations could be inverted.
    pub left_joint_covariance: Option<Vec<Matrix6<f64>>>,
}

/// Most Gauss–Newton iterations of the refinement (each renders every camera's every view).
const MAX_ITERATIONS: usize = 8;

/// Rounds of "estimate the joint corrections, re-solve every camera with them": the second
/// round starts from poses that no longer carry the joint errors, and estimates the
/// corrections better (in `bench rig`, one round left one camera's median translation 0.5%
/// short of its single-camera figure; two rounds cleared every camera).
const ROUNDS: usize = 2;

/// A re-solve whose mean IoU falls this far below the earlier solve's is not kept: the joint
/// corrections made the fit worse, which only a wrong correction does.
const KEEP_IOU_DROP: f64 = 0.01;

/// One camera's side of [`solve_with_shared_joints`]: the robot as it sees it, its camera,
/// its views (every view of the run, at the recorded joints) and its solve so far.
pub struct CameraSolve<'a> {
    /// The camera's name, for messages.
    pub name: &'a str,
    /// The robot as this camera sees it.
    pub seen: &'a RobotModel,
    /// The camera (its distortion, if any, is already taken out of the masks).
    pub camera: &'a Intrinsics,
    /// Every view of the run, posed at the recorded joints.
    pub views: &'a [View],
    /// The camera's solve from `views`.
    pub report: SolveReport,
}

/// What [`solve_with_shared_joints`] found.
pub struct SharedSolve {
    /// Each camera's report, in the order given.
    pub reports: Vec<SolveReport>,
    /// Each view's joint correction of the last round, radians.
    pub corrections: Vec<Vec<f64>>,
    /// The cameras whose re-solve fit worse in some round and kept their earlier solve then.
    pub kept: Vec<String>,
}

impl SharedSolve {
    /// The one line a run's log and notes carry about the correction: its largest joint
    /// correction and which cameras kept their own solve (those of `kept`, then
    /// `extra_kept`: cameras the caller's own rules dropped the re-solve of).
    pub fn summary(&self, extra_kept: &[String]) -> String {
        let largest = self
            .corrections
            .iter()
            .flatten()
            .fold(0.0, |m: f64, d| m.max(d.abs()));
        let mut kept = self.kept.clone();
        for name in extra_kept {
            if !kept.contains(name) {
                kept.push(name.clone());
            }
        }
        let kept = match kept.is_empty() {
            true => String::new(),
            false => format!(
                "; kept its own solve, the re-solve fitting worse: {}",
                kept.join(", ")
            ),
        };
        format!("re-solved every camera with each view's joint correction, estimated from all cameras together (largest {largest:.5} rad){kept}")
    }
}

/// Every camera re-solved from its views with each view's joints corrected by what all the
/// cameras saw together ([`refine_with_joint_corrections`]), in [`ROUNDS`] rounds. A camera
/// whose re-solve fails or fits worse keeps its earlier solve. Nothing changes without a
/// joint-noise prior (`opts.joint_noise_rad` of 0: the joints are taken as exact).
pub fn solve_with_shared_joints(
    renderer: &dyn Backend,
    cameras: Vec<CameraSolve<'_>>,
    joints: &[Vec<f64>],
    opts: &SolveOptions,
) -> SharedSolve {
    let mut cameras = cameras;
    let mut corrections = vec![vec![0.0; joints.first().map_or(0, Vec::len)]; joints.len()];
    let mut kept = Vec::new();
    if opts.joint_noise_rad <= 0.0 {
        return SharedSolve {
            reports: cameras.into_iter().map(|c| c.report).collect(),
            corrections,
            kept,
        };
    }
    let pinholes: Vec<Intrinsics> = cameras.iter().map(|c| c.camera.undistorted()).collect();
    for _ in 0..ROUNDS {
        let shared: Vec<SharedCamera> = cameras
            .iter()
            .zip(&pinholes)
            .map(|(c, pinhole)| SharedCamera {
                seen: c.seen,
                camera: pinhole,
                observed: c.views.iter().map(|v| &v.observed).collect(),
                camera_from_base: c.report.camera_from_base,
                outline_noise_px2: c.report.outline_noise_px2,
                mount_contact_left_out: c.report.mount_contact_left_out,
            })
            .collect();
        let refined =
            refine_with_joint_corrections(renderer, &shared, joints, opts, opts.joint_noise_rad);
        // The re-solve's covariance counts no encoder noise when the joint error the
        // corrections leave can be added instead; otherwise it counts all of it.
        let resolve_opts = SolveOptions {
            joint_noise_rad: match refined.left_joint_covariance {
                Some(_) => 0.0,
                None => opts.joint_noise_rad,
            },
            ..opts.clone()
        };
        let corrected: Vec<Vec<f64>> = joints
            .iter()
            .zip(&refined.joint_corrections)
            .map(|(q, d)| q.iter().zip(d).map(|(a, b)| a + b).collect())
            .collect();
        let resolved: Vec<Option<SolveReport>> = cameras
            .par_iter()
            .zip(&refined.camera_from_base)
            .enumerate()
            .map(|(k, (c, start))| {
                let views: Vec<View> = c
                    .views
                    .iter()
                    .zip(&corrected)
                    .map(|(v, q)| View {
                        robot: PosedRobot::new(c.seen, q),
                        observed: v.observed.clone(),
                    })
                    .collect();
                let opts = resolve_opts.as_fitted(&c.report);
                let mut report = super::solve(renderer, c.camera, &views, start, &opts).ok()?;
                if let Some(left) = &refined.left_joint_covariance {
                    // Statistical too: the inter-view term widens that one, and a joint offset
                    // common to every view shows in no view's disagreement.
                    report.statistical_covariance += left[k];
                    report.covariance += left[k];
                    report.uncertainty =
                        uncertainty_of(&report.covariance, &report.camera_from_base);
                }
                Some(report)
            })
            .collect();
        for (c, r) in cameras.iter_mut().zip(resolved) {
            match r {
                Some(r) if r.mean_iou() >= c.report.mean_iou() - KEEP_IOU_DROP => c.report = r,
                _ => {
                    tracing::warn!(
                        "camera '{}': the re-solve with the shared joint corrections fit worse; kept its own solve",
                        c.name
                    );
                    if !kept.iter().any(|k| k == c.name) {
                        kept.push(c.name.to_string());
                    }
                }
            }
        }
        corrections = refined.joint_corrections;
    }
    SharedSolve {
        reports: cameras.into_iter().map(|c| c.report).collect(),
        corrections,
        kept,
    }
}

/// The state the normal equations are built at.
struct State {
    poses: Vec<Isometry3<f64>>,
    corrections: Vec<Vec<f64>>,
}

/// Normal equations of the whole problem at one state, with its cost.
struct Normal {
    h: DMatrix<f64>,
    g: DVector<f64>,
    cost: f64,
}

/// Refines every camera's pose together with each view's joint correction; `joints` are the
/// recorded joint vectors of the views every camera saw. `joint_noise_rad` is the prior's
/// standard deviation.
pub fn refine_with_joint_corrections(
    renderer: &dyn SilhouetteRenderer,
    cameras: &[SharedCamera<'_>],
    joints: &[Vec<f64>],
    opts: &SolveOptions,
    joint_noise_rad: f64,
) -> SharedRefinement {
    let nq = joints.first().map_or(0, Vec::len);
    let levels: Vec<Vec<ObservedLevel>> = cameras
        .par_iter()
        .map(|c| {
            c.observed
                .iter()
                .map(|m| ObservedLevel::new(m, 1))
                .collect()
        })
        .collect();
    let mut state = State {
        poses: cameras.iter().map(|c| c.camera_from_base).collect(),
        corrections: vec![vec![0.0; nq]; joints.len()],
    };
    if joint_noise_rad <= 0.0 || nq == 0 || cameras.is_empty() {
        return state.into_refinement();
    }
    let problem = Problem {
        renderer,
        cameras,
        levels: &levels,
        joints,
        opts,
        prior: 1.0 / (joint_noise_rad * joint_noise_rad),
    };
    let mut current = problem.normal(&state);
    let mut lambda = 1e-4;
    for _ in 0..MAX_ITERATIONS {
        let Some(step) = damped_step(&current, lambda) else {
            lambda *= 10.0;
            continue;
        };
        let candidate = problem.stepped(&state, &step);
        let next = problem.normal(&candidate);
        if next.cost <= current.cost {
            state = candidate;
            current = next;
            lambda = (lambda / 3.0).max(1e-7);
            if step.amax() < 1e-7 {
                break;
            }
        } else {
            lambda *= 4.0;
            if lambda > 1e4 {
                break;
            }
        }
    }
    let left = problem.left_joint_covariance(&current.h);
    let mut out = state.into_refinement();
    out.left_joint_covariance = left;
    out
}

impl State {
    fn into_refinement(self) -> SharedRefinement {
        SharedRefinement {
            camera_from_base: self.poses,
            joint_corrections: self.corrections,
            left_joint_covariance: None,
        }
    }
}

/// `(H + lambda diag H) x = -g`, or `None` when that is not positive definite.
fn damped_step(n: &Normal, lambda: f64) -> Option<DVector<f64>> {
    let mut a = n.h.clone();
    for k in 0..a.nrows() {
        a[(k, k)] += lambda * n.h[(k, k)].max(1e-12);
    }
    a.cholesky().map(|c| -c.solve(&n.g))
}

/// The fixed parts of one refinement.
struct Problem<'a> {
    renderer: &'a dyn SilhouetteRenderer,
    cameras: &'a [SharedCamera<'a>],
    levels: &'a [Vec<ObservedLevel>],
    joints: &'a [Vec<f64>],
    opts: &'a SolveOptions,
    /// Information of the joint-correction prior, 1/rad².
    prior: f64,
}

impl Problem<'_> {
    /// Each camera's pose covariance from the joint error the corrections leave. A camera
    /// solved at the corrected joints moves by `-A⁻¹ B e` for a joint error `e` (`A` its pose
    /// block of `h`, `B` its pose–joint block), and `e` has the corrections' posterior
    /// covariance `P` (the joint block of `h⁻¹`, the prior included): `A⁻¹ B P Bᵀ A⁻¹`.
    /// A joint error no camera can see (one offset of the first joint in every view turns
    /// every camera alike) keeps its prior variance in `P`, and so in the term.
    fn left_joint_covariance(&self, h: &DMatrix<f64>) -> Option<Vec<Matrix6<f64>>> {
        let at = self.joint_index(0);
        let nj = h.nrows() - at;
        let p = h
            .clone()
            .cholesky()?
            .inverse()
            .view((at, at), (nj, nj))
            .into_owned();
        (0..self.cameras.len())
            .map(|c| {
                let a = h.view((6 * c, 6 * c), (6, 6)).into_owned().try_inverse()?;
                let s = a * h.view((6 * c, at), (6, nj));
                let term = &s * &p * s.transpose();
                Some(Matrix6::from_iterator(term.iter().copied()))
            })
            .collect()
    }

    fn nq(&self) -> usize {
        self.joints.first().map_or(0, Vec::len)
    }

    /// Index of view `v`'s first joint unknown (the cameras' poses come first).
    fn joint_index(&self, v: usize) -> usize {
        6 * self.cameras.len() + v * self.nq()
    }

    /// `state` moved by `step`: left increments of the poses, additions to the corrections.
    fn stepped(&self, state: &State, step: &DVector<f64>) -> State {
        let poses = state
            .poses
            .iter()
            .enumerate()
            .map(|(c, p)| exp_se3(&Twist::from_iterator(step.rows(6 * c, 6).iter().copied())) * p)
            .collect();
        let corrections = state
            .corrections
            .iter()
            .enumerate()
            .map(|(v, dq)| {
                let at = self.joint_index(v);
                dq.iter()
                    .zip(step.rows(at, self.nq()).iter())
                    .map(|(a, b)| a + b)
                    .collect()
            })
            .collect();
        State { poses, corrections }
    }

    /// The normal equations and cost of every camera's every view at `state`, plus the prior.
    fn normal(&self, state: &State) -> Normal {
        let n = self.joint_index(self.joints.len());
        let pairs: Vec<(usize, usize)> = (0..self.cameras.len())
            .flat_map(|c| (0..self.joints.len()).map(move |v| (c, v)))
            .collect();
        let mut total = pairs
            .par_iter()
            .map(|&(c, v)| self.view_normal(state, c, v, n))
            .reduce(
                || Normal {
                    h: DMatrix::zeros(n, n),
                    g: DVector::zeros(n),
                    cost: 0.0,
                },
                |mut a, b| {
                    a.h += b.h;
                    a.g += b.g;
                    a.cost += b.cost;
                    a
                },
            );
        for (v, dq) in state.corrections.iter().enumerate() {
            let at = self.joint_index(v);
            for (k, d) in dq.iter().enumerate() {
                total.h[(at + k, at + k)] += self.prior;
                total.g[at + k] += self.prior * d;
                total.cost += 0.5 * self.prior * d * d;
            }
        }
        total
    }

    /// Camera `c`'s view `v`: its outline residuals' normal equations in the whole problem's
    /// unknowns (`n` of them), each residual weighed by the camera's outline noise.
    fn view_normal(&self, state: &State, c: usize, v: usize, n: usize) -> Normal {
        let cam = &self.cameras[c];
        let pose = state.poses[c];
        let q: Vec<f64> = self.joints[v]
            .iter()
            .zip(&state.corrections[v])
            .map(|(a, b)| a + b)
            .collect();
        let robot = PosedRobot::new(cam.seen, &q);
        let sil = self
            .renderer
            .render(&robot, cam.camera, &pose, Some(self.opts.boundary_step_px));
        let twists: Vec<Twist> = robot
            .joint_motions
            .iter()
            .map(|m| m.twist_in_camera(&pose))
            .collect();
        let scale = 1.0 / cam.outline_noise_px2.max(1e-12);
        let robust = self.opts.fine_robust_scale_px;
        let (nq, at) = (self.nq(), self.joint_index(v));
        let mut out = Normal {
            h: DMatrix::zeros(n, n),
            g: DVector::zeros(n),
            cost: 0.0,
        };
        let mut jac = DVector::<f64>::zeros(6 + nq);
        let left_out = LeftOut::mount_if(&robot, cam.mount_contact_left_out, &pose);
        view_residuals(&sil, &self.levels[c][v], cam.camera, &left_out, |res| {
            let r = res.r.unwrap_or(res.cap);
            let u = (r / robust) * (r / robust);
            out.cost += scale * res.ds * 0.5 * robust * robust * (1.0 + u).ln();
            if res.r.is_none() {
                return;
            }
            let w = scale * res.ds / (1.0 + u);
            jac.rows_mut(0, 6).copy_from(&res.j);
            let link = sil
                .boundary
                .get(res.sample)
                .and_then(|s| robot.vertex_link.get(s.vertex as usize))
                .map(|&l| l as usize);
            for (k, (m, t)) in robot.joint_motions.iter().zip(&twists).enumerate().take(nq) {
                let moves = link.is_some_and(|l| m.moves_link.get(l).copied().unwrap_or(false));
                jac[6 + k] = if moves { res.j.dot(t) } else { 0.0 };
            }
            let index = |i: usize| if i < 6 { 6 * c + i } else { at + i - 6 };
            for i in 0..6 + nq {
                if jac[i] == 0.0 {
                    continue;
                }
                out.g[index(i)] += w * r * jac[i];
                for j in 0..6 + nq {
                    out.h[(index(i), index(j))] += w * jac[i] * jac[j];
                }
            }
        });
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::look_at_camera_from_base;
    use crate::render::CpuRenderer;
    use nalgebra::Vector3;

    /// Three cameras watch four views whose recorded joints are off the true ones by about a
    /// milliradian: the refinement moves each view's joints most of the way back and keeps the
    /// cameras, which start at their truth, near it; the joint error it leaves weighs on each
    /// camera's covariance, less under a tighter prior.
    #[test]
    fn joint_errors_seen_by_three_cameras_are_recovered() {
        let urdf = concat!(env!("CARGO_MANIFEST_DIR"), "/robots/xarm6/robot.urdf");
        let robot = RobotModel::from_urdf(urdf).unwrap();
        let camera = Intrinsics {
            width: 640,
            height: 480,
            fx: 600.0,
            fy: 600.0,
            cx: 319.5,
            cy: 239.5,
            distortion: None,
        };
        let target = Vector3::new(0.15, 0.0, 0.3);
        let truths: Vec<Isometry3<f64>> = [[1.3, 0.5, 0.8], [0.3, -1.3, 0.8], [-0.6, 0.8, 1.3]]
            .iter()
            .map(|e| look_at_camera_from_base(&Vector3::from(*e), &target, &Vector3::z()))
            .collect();
        let recorded = [
            [0.0, -0.35, -0.6, 0.0, 0.95, 0.0],
            [0.5, -0.2, -0.8, 0.4, 0.7, 0.3],
            [-0.5, -0.5, -0.4, -0.3, 1.1, -0.2],
            [0.2, -0.1, -1.0, 0.6, 0.5, 0.5],
        ];
        let errors = [
            [0.0010, -0.0008, 0.0006, 0.0, 0.0, 0.0],
            [-0.0007, 0.0009, -0.0010, 0.0, 0.0, 0.0],
            [0.0008, 0.0007, 0.0009, 0.0, 0.0, 0.0],
            [-0.0009, -0.0010, 0.0007, 0.0, 0.0, 0.0],
        ];
        let joints: Vec<Vec<f64>> = recorded.iter().map(|q| q.to_vec()).collect();
        let masks: Vec<Vec<Mask>> = truths
            .iter()
            .map(|pose| {
                recorded
                    .iter()
                    .zip(&errors)
                    .map(|(q, e)| {
                        let truth: Vec<f64> = q.iter().zip(e).map(|(a, b)| a + b).collect();
                        CpuRenderer
                            .render(&PosedRobot::new(&robot, &truth), &camera, pose, None)
                            .mask
                    })
                    .collect()
            })
            .collect();
        let cameras: Vec<SharedCamera> = truths
            .iter()
            .zip(&masks)
            .map(|(pose, m)| SharedCamera {
                seen: &robot,
                camera: &camera,
                observed: m.iter().collect(),
                camera_from_base: *pose,
                outline_noise_px2: 0.1,
                mount_contact_left_out: false,
            })
            .collect();
        let opts = SolveOptions::default();
        let out = refine_with_joint_corrections(&CpuRenderer, &cameras, &joints, &opts, 0.002);
        // The shoulder and elbow joints (the wrist ones are left at zero error here).
        let rms = |f: &dyn Fn(usize, usize) -> f64| {
            let s: f64 = (0..4)
                .flat_map(|v| (0..3).map(move |k| (v, k)))
                .map(|(v, k)| f(v, k).powi(2))
                .sum();
            (s / 12.0).sqrt()
        };
        let before = rms(&|v, k| errors[v][k]);
        let after = rms(&|v, k| errors[v][k] - out.joint_corrections[v][k]);
        assert!(
            after < 0.4 * before,
            "rms joint error {before:.5} -> {after:.5} rad"
        );
        for (est, truth) in out.camera_from_base.iter().zip(&truths) {
            let deg = crate::geometry::rotation_error_deg(est, truth);
            let mm = crate::geometry::translation_error_mm(est, truth);
            assert!(deg < 0.05 && mm < 0.5, "{deg:.4} deg / {mm:.3} mm");
        }
        // What the corrections leave weighs on every camera, less than the whole prior would.
        let left = out.left_joint_covariance.expect("normal equations invert");
        let whole = refine_with_joint_corrections(&CpuRenderer, &cameras, &joints, &opts, 0.02)
            .left_joint_covariance
            .expect("normal equations invert");
        for (l, w) in left.iter().zip(&whole) {
            let eig = l.symmetric_eigen().eigenvalues;
            assert!(eig.iter().all(|e| *e > -1e-18) && l.trace() > 0.0, "{l}");
            assert!(l.trace() < w.trace(), "{} vs {}", l.trace(), w.trace());
        }
    }
}

//! The first views when nothing says where the camera is and only colour frames show the
//! robot: a context-aware segmenter (`builtin`) cannot cut the robot out of one frame with no
//! pose to lean on, but the robot is what changes between frames. So the loop first takes a
//! few views near where the arm stands, every move through the safety checks, and starts
//! from the camera pose that explains what changed between them ([`starts_from_change`]).
//! The views are chosen as far apart as a small reach allows: in simulated cells with the
//! camera placed at random, single-joint steps of 0.3 rad left the change ambiguous far more
//! often than poses spread over a 0.4 rad reach.
//!
//! Unlike the loop's other views, the seeding views reach the run directory only once the
//! start is settled: before that no mask can be drawn for them, and a run that ends during
//! the seeding (a declined, cancelled or failed move) records none of them.

use std::time::Instant;

use easyhec_drivers::Frame;
use nalgebra::Isometry3;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::backend::Backend;
use crate::calibrate::PlannedPose;
use crate::camera::Intrinsics;
use crate::camera::LensWarp;
use crate::error::{Error, Result};
use crate::init::change::{starts_from_change, ChangeStart};
use crate::init::InitOptions;
use crate::pipeline::segment_solve::{segment_and_solve, Settled, GUESS_BAND_PX, POOR_FIT_IOU};
use crate::render::PosedRobot;
use crate::safety::{CheckedMove, SafetyChecker};
use crate::segment::Segmenter;
use crate::solve::{SolveOptions, View};

use super::motion::Approval;
use super::Session;

/// Views the seeding takes, the one where the arm stands included: three pairs of views, and
/// the rest of a small `max_views` left to the planner's more telling poses (on a simulated
/// Panda with 5 views, three seeding views ended nearer the truth than four).
const SEED_VIEWS: usize = 3;

/// How far each proximal joint may turn from the pose the operator left the arm in (which
/// shows the robot), radians: far enough for the views to differ, near enough for the robot
/// to stay in the picture.
const SEED_REACH_RAD: f64 = 0.4;

/// Random poses drawn within that reach; the safe ones are the candidates.
const SEED_SAMPLES: usize = 256;

/// Candidate moves checked at most for each seeding view, farthest first.
const SEED_TRIES: usize = 32;

/// Starts from the change tried at most, each settled in turn.
const MAX_STARTS: usize = 4;

/// Segment-and-solve rounds at most while the seeding views settle (as offline).
const SETTLE_ROUNDS: usize = 4;

/// The joints the seeding turns: the arm's proximal ones move the most of it.
const SEED_JOINTS: usize = 3;

impl Session<'_> {
    /// Whether the first view needs seeding: one camera whose segmenter needs context, no
    /// starting pose, and a run that may move and keep more than one view.
    pub(super) fn needs_seed_views(&self) -> bool {
        let t = &self.tracks[0];
        self.tracks.len() == 1
            && t.live.is_some()
            && t.guess.is_none()
            && !self.opts.dry_run
            && self.settings.max_views >= 2
    }

    /// Takes the seeding views (see the module docs) and settles the camera's first estimate
    /// from them ([`Session::settle_held`]). Returns the events for round 0's record.
    pub(super) async fn seed_views(&mut self) -> Result<Vec<String>> {
        let mut events = Vec::new();
        self.hold_frame().await?;
        let wanted = SEED_VIEWS.min(self.settings.max_views);
        let checker = &self.cell.checker;
        let candidates: Vec<_> = seed_candidates(checker, &self.taken[0], self.settings.seed)
            .into_iter()
            .map(|q| {
                let links = link_origins(checker, &q);
                (q, links)
            })
            .collect();
        let mut taken_links = vec![link_origins(checker, &self.taken[0])];
        while self.views() < wanted {
            let from = self.cell.arm.read_joints().await?;
            let speed = self.settings.speed_rad_s;
            let Some((to, mv)) =
                farthest_safe_move(checker, &candidates, &taken_links, &from, speed)
            else {
                events.push(format!(
                    "no initial guess: no safe move from {from:.3?} to another seeding view"
                ));
                break;
            };
            taken_links.push(link_origins(checker, &to));
            self.seed_move(to, &mv).await?;
            self.hold_frame().await?;
        }
        events.push(self.settle_held()?);
        Ok(events)
    }

    /// Reads the joints and grabs the camera's frame, keeping both unsegmented.
    async fn hold_frame(&mut self) -> Result<()> {
        let t = Instant::now();
        let (joints, mut frames) = self.grab_all().await?;
        let frame = frames.pop().expect("one camera");
        self.tracks[0]
            .live
            .as_mut()
            .expect("seeding needs a context-aware segmenter")
            .frames
            .push(frame);
        self.taken.push(joints);
        self.capture_s += t.elapsed().as_secs_f64();
        super::emit_view(self.opts, &self.taken);
        self.pb.set_position(self.views() as u64);
        Ok(())
    }

    /// One seeding move: the operator's confirmation, then the checked move. A refused,
    /// cancelled or failed move ends the run, the arm stopped: there is no estimate yet to
    /// report and nothing to re-plan from.
    async fn seed_move(&mut self, joints: Vec<f64>, mv: &CheckedMove) -> Result<()> {
        let view = self.views();
        let pose = PlannedPose {
            joints,
            score: 0.0,
            variance: None,
            in_image: f64::NAN,
            clearance: mv.clearance,
            path_samples: mv.samples,
        };
        match self.approve(&pose) {
            Approval::Declined => {
                return Err(Error::Hardware(format!(
                    "operator declined seeding move {view} (no initial guess: the first views are taken near the start pose); no result"
                )))
            }
            Approval::Cancelled => {
                return Err(Error::Hardware(format!(
                    "calibration cancelled before seeding move {view}; no result"
                )))
            }
            Approval::Approved => {}
        }
        let moved = self
            .send(&pose, mv, format!("seeding: moving to view {}", view + 1))
            .await;
        if let Err(e) = moved {
            let _ = self.cell.arm.stop().await;
            return Err(Error::Hardware(format!(
                "seeding move {view} failed: {e}; the arm was stopped and no result written"
            )));
        }
        Ok(())
    }

    /// Starts the camera from what changed between the held frames, settles the masks and
    /// the pose from there as an offline run does ([`segment_and_solve`]), and records the
    /// frames as the run's first views. When no pose explains the change, the frames are
    /// segmented without a prior and round 0 initialises from their masks. Returns the
    /// event for round 0's record.
    fn settle_held(&mut self) -> Result<String> {
        let started = Instant::now();
        let t = &mut self.tracks[0];
        let live = t.live.as_ref().expect("checked by needs_seed_views");
        let frames: Vec<&Frame> = live.frames.iter().collect();
        let robots: Vec<PosedRobot> = self
            .taken
            .iter()
            .map(|q| PosedRobot::new(t.unit.seen, q))
            .collect();
        let renderer = self.renderer.as_ref();
        let n = frames.len();
        let scene = HeldViews {
            renderer,
            camera: &t.camera,
            segmenter: t.unit.segmenter,
            frames: &frames,
            robots: &robots,
            band_px: live.min_band_px,
        };
        let settled = scene.settle(&self.solve_opts);
        let (event, masks) = match settled {
            Ok((found, settled, tried)) => {
                t.views = settled
                    .masks
                    .iter()
                    .zip(robots)
                    .map(|(m, robot)| View {
                        robot,
                        observed: t.camera.undistort_mask(m),
                    })
                    .collect();
                // The settled pose, not the raw start, is what a poor later round re-solves
                // from (`Session::solve_from`).
                t.guess = Some(settled.report.camera_from_base);
                t.report = Some(settled.report);
                let event = format!("no initial guess: took {n} views near the start and started from the camera pose that explains what changed between them (overlap {:.2}; start {tried} of those found), settled in {} segment-and-solve rounds", found.score, settled.rounds);
                (event, settled.masks)
            }
            Err(e) => {
                let masks = live.resegment(
                    renderer,
                    t.unit.segmenter,
                    t.unit.seen,
                    &t.camera,
                    live.min_band_px,
                    &self.taken,
                    None,
                    None,
                    &mut t.views,
                    |_, _| Ok(()),
                )?;
                let event = format!("no initial guess: took {n} views near the start, but {e}; initialising from their masks instead");
                (event, masks)
            }
        };
        self.solve_s += started.elapsed().as_secs_f64();
        for ((joints, frame), mask) in self.taken.iter().zip(&live.frames).zip(&masks) {
            self.rec.add_view(joints, &[(frame, mask)])?;
        }
        Ok(event)
    }
}

/// The held seeding views of one camera, for settling a start on them.
struct HeldViews<'a> {
    renderer: &'a dyn Backend,
    camera: &'a Intrinsics,
    segmenter: &'a dyn Segmenter,
    frames: &'a [&'a Frame],
    robots: &'a [PosedRobot],
    band_px: f32,
}

impl HeldViews<'_> {
    /// The change starts ([`starts_from_change`]), each settled by segment-and-solve rounds
    /// as an offline run's start is ([`first_that_fits`]).
    fn settle(&self, solve_opts: &SolveOptions) -> Result<(ChangeStart, Settled, usize)> {
        let starts = starts_from_change(
            self.renderer,
            self.camera,
            self.frames,
            self.robots,
            &InitOptions::default(),
        )?;
        first_that_fits(starts, |start| {
            segment_and_solve(
                self.renderer,
                self.camera,
                self.segmenter,
                self.frames,
                self.robots,
                &|_| Ok(*start),
                Some((start, GUESS_BAND_PX)),
                self.band_px,
                self.band_px,
                solve_opts,
                SETTLE_ROUNDS,
            )
        })
    }
}

/// The first of `starts` (best explained change first, at most [`MAX_STARTS`]) whose
/// settled fit reaches [`POOR_FIT_IOU`], else the best-fitting one, with its 1-based rank:
/// views close together can leave the change ambiguous, and a wrong start does not settle
/// into a fit.
fn first_that_fits(
    starts: Vec<ChangeStart>,
    settle: impl Fn(&Isometry3<f64>) -> Result<Settled>,
) -> Result<(ChangeStart, Settled, usize)> {
    let mut best: Option<(ChangeStart, Settled, usize)> = None;
    let mut failure = None;
    for (k, start) in starts.into_iter().take(MAX_STARTS).enumerate() {
        // A start that cannot be settled (it shows no robot, say) leaves the others to try.
        let settled = match settle(&start.camera_from_base) {
            Ok(s) => s,
            Err(e) => {
                failure = Some(e);
                continue;
            }
        };
        let iou = settled.report.mean_iou();
        if best.as_ref().is_none_or(|b| iou > b.1.report.mean_iou()) {
            best = Some((start, settled, k + 1));
        }
        if iou >= POOR_FIT_IOU {
            break;
        }
    }
    best.ok_or_else(|| {
        failure.unwrap_or_else(|| Error::Solve("initialisation from images found no start".into()))
    })
}

/// Safe poses near `start` to seed from: joint vectors within [`SEED_REACH_RAD`] of it on
/// the proximal joints, each inside the limits and clear of the robot and the environment,
/// `start` itself first.
fn seed_candidates(checker: &SafetyChecker, start: &[f64], seed: u64) -> Vec<Vec<f64>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let moved = start.len().min(SEED_JOINTS);
    let mut out = vec![start.to_vec()];
    for _ in 0..SEED_SAMPLES {
        let mut q = start.to_vec();
        for v in q.iter_mut().take(moved) {
            *v += rng.random_range(-SEED_REACH_RAD..=SEED_REACH_RAD);
        }
        if checker.check_pose(&q).is_ok() {
            out.push(q);
        }
    }
    out
}

/// The link origins of `q` in the base frame: how far two poses are apart is how far the
/// links moved, which is what the camera sees change.
fn link_origins(checker: &SafetyChecker, q: &[f64]) -> Vec<nalgebra::Vector3<f64>> {
    checker
        .robot()
        .base_from_links(q)
        .iter()
        .map(|p| p.translation.vector)
        .collect()
}

/// The next seeding target: among `candidates` (link origins precomputed), the one farthest
/// from every view taken so far (`taken_links`) whose move from `from` passes every
/// safety check at `speed_rad_s`. Farthest first, because the change between views is the
/// evidence and nearby poses change little.
fn farthest_safe_move(
    checker: &SafetyChecker,
    candidates: &[(Vec<f64>, Vec<nalgebra::Vector3<f64>>)],
    taken_links: &[Vec<nalgebra::Vector3<f64>>],
    from: &[f64],
    speed_rad_s: f64,
) -> Option<(Vec<f64>, CheckedMove)> {
    let apart = |a: &[nalgebra::Vector3<f64>], b: &[nalgebra::Vector3<f64>]| {
        a.iter().zip(b).map(|(x, y)| (x - y).norm()).sum::<f64>() / a.len().max(1) as f64
    };
    let mut ranked: Vec<(f64, usize)> = candidates
        .iter()
        .enumerate()
        .map(|(i, (_, links))| {
            let nearest = taken_links
                .iter()
                .map(|t| apart(links, t))
                .fold(f64::INFINITY, f64::min);
            (nearest, i)
        })
        .filter(|(d, _)| *d > 1e-3)
        .collect();
    ranked.sort_by(|a, b| b.0.total_cmp(&a.0));
    ranked.iter().take(SEED_TRIES).find_map(|&(_, i)| {
        let q = &candidates[i].0;
        checker
            .check_move(from, q, speed_rad_s)
            .ok()
            .map(|mv| (q.clone(), mv))
    })
}

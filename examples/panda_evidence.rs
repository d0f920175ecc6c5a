//! Experiment behind the README's Panda note: how far the builtin segmenter's own evidence
//! (change and colour log-odds, no prior) goes on the ten photographs.
//!
//! `cargo run --release --example panda_evidence -- RUN_DIR joints|search`
//!
//! Both modes take the two-view pose that the provided masks give (`easyhec solve`'s
//! consistency check) as the reference and score a silhouette by its region score: the summed
//! evidence over the pixels it covers, divided by the view's summed positive evidence.
//! - `joints`: at the reference pose, each view's joints are chosen among the recorded joint
//!   vectors and interpolations towards them, then refined joint by joint, by the region score
//!   alone; prints the IoU of the result against the provided masks, and of the builtin masks
//!   segmented under those joints.
//! - `search`: looks for the camera pose itself by the region score (views scored by their
//!   positive part, so views with wrong joints cannot pull), from random poses around the run's
//!   guess and from the automatic initialisation's hemisphere grid, refined coarse to fine.
//! - `probe`: refines from the twelve grid poses nearest the reference and prints where each
//!   ends and its score (the score's peak lies 7.7° from the reference).
//! - `rank`: where the 40 grid poses nearest the reference rank among all of them at 1/16
//!   resolution, under four ways of summing the views' region scores.
//! - `chain POSE BANDS [VIEWS]`: from `POSE` (16 comma-separated row-major numbers), segments
//!   every frame under the render with each band in `BANDS` (pixels, comma-separated) in turn
//!   and solves; with `VIEWS` (comma-separated indices) only those views, else every view and
//!   the consistency check. Prints the error against the reference after each band. With a
//!   sixth argument `finish`, then refits every view's joints at the chained pose by the
//!   region score, segments under them (4, 8 and 16 px) and solves every view with the
//!   consistency check, printing the masks' IoU against the provided ones and the error.
//! - `pairs POSE BAND`: segments under `POSE`'s render with one band and solves every pair of
//!   views, best mean IoU first.
//! - `pairchain POSE BANDS`: for every pair of views, `chain` restricted to that pair (each
//!   band re-segments all frames under the pair's latest pose); ranks the pairs by their IoU
//!   on their own last masks, by the region score of their render and by the IoU on a
//!   re-segmentation with the first band.

use easyhec::camera::Intrinsics;
use easyhec::camera::LensWarp;
use easyhec::consensus::{find_consensus, ConsensusOptions};
use easyhec::geometry::{exp_se3, rotation_error_deg, translation_error_mm, Twist};
use easyhec::nalgebra::{Isometry3, Vector3};
use easyhec::render::{CpuRenderer, PosedRobot, SilhouetteRenderer};
use easyhec::run::{load_run, load_run_with, MaskSource};
use easyhec::segment::builtin::{evidence_over as region_score, segment_views_with_evidence};
use easyhec::segment::{BuiltinParams, ViewInput};
use easyhec::solve::{solve, SolveOptions, View};
use rand::{Rng, SeedableRng};
use rayon::prelude::*;
use std::path::Path;

/// Evidence summed over `factor` x `factor` blocks.
fn downsample(e: &[f32], w: usize, h: usize, factor: usize) -> Vec<f32> {
    let (lw, lh) = (w / factor, h / factor);
    let mut out = vec![0f32; lw * lh];
    for y in 0..lh * factor {
        for x in 0..lw * factor {
            out[(y / factor) * lw + x / factor] += e[y * w + x];
        }
    }
    out
}

/// One way of summing the views' region scores into a pose's score.
type ViewSum = fn(&[f64]) -> f64;

/// A pose from 16 comma-separated numbers, the 4x4 matrix row by row.
fn parse_pose(text: &str) -> Isometry3<f64> {
    let m: Vec<f64> = text.split(',').map(|x| x.trim().parse().unwrap()).collect();
    easyhec::nalgebra::try_convert(easyhec::nalgebra::Matrix4::from_row_slice(&m)).unwrap()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let dir = Path::new(&args[1]);
    let mode = args.get(2).map_or("joints", String::as_str);
    let run = load_run(dir).unwrap();
    let r = CpuRenderer;
    let opts = SolveOptions::default();
    let robots: Vec<PosedRobot> = run
        .views
        .iter()
        .map(|v| PosedRobot::new(&run.robot, &v.joints))
        .collect();
    let views: Vec<View> = run
        .views
        .iter()
        .zip(&robots)
        .map(|(v, robot)| View {
            robot: robot.clone(),
            observed: v.observed.clone(),
        })
        .collect();
    let guess = run.initial_guess.unwrap();
    let all = solve(&r, &run.camera, &views, &guess, &opts).unwrap();
    let consensus = find_consensus(
        &r,
        &run.camera,
        &views,
        &all,
        &opts,
        &ConsensusOptions::default(),
    )
    .unwrap()
    .unwrap();
    let pose = consensus.report.camera_from_base;
    println!(
        "reference: views {:?}; the guess is {:.2} deg / {:.1} mm from it",
        consensus.kept,
        rotation_error_deg(&guess, &pose),
        translation_error_mm(&guess, &pose)
    );
    let cam = run.camera.undistorted();
    let (w, h) = (cam.width as usize, cam.height as usize);
    let n = run.views.len();
    let images = load_run_with(dir, MaskSource::Image).unwrap();
    let frames: Vec<_> = images
        .views
        .iter()
        .map(|v| {
            easyhec::segment::read_frame(v.image.as_ref().unwrap(), cam.width, cam.height).unwrap()
        })
        .collect();
    let params = BuiltinParams::default();
    let inputs: Vec<ViewInput> = frames
        .iter()
        .map(|frame| ViewInput {
            frame,
            prior: None,
            band_px: 8.0,
        })
        .collect();
    let evidence = segment_views_with_evidence(&inputs, &params)
        .unwrap()
        .log_odds;
    let positive: Vec<f64> = evidence
        .iter()
        .map(|e| e.iter().map(|&x| f64::from(x.max(0.0))).sum())
        .collect();
    // Each view's joints refitted at `at` by the region score alone (the library's refit).
    let recorded: Vec<Vec<f64>> = run.views.iter().map(|v| v.joints.clone()).collect();
    let refit_joints = |at: &Isometry3<f64>, verbose: bool| -> Vec<PosedRobot> {
        let render = |q: &[f64]| {
            r.render(&PosedRobot::new(&run.robot, q), &cam, at, None)
                .mask
        };
        let mut fitted = Vec::new();
        for (k, (view, ev)) in run.views.iter().zip(&evidence).enumerate() {
            let best_q = easyhec::pipeline::segment_solve::refit_joints(
                &r,
                &run.camera,
                &run.robot,
                &recorded,
                k,
                ev,
                at,
            );
            if verbose {
                println!(
                    "view {k}: IoU against the provided mask with its recorded joints {:.3}, refitted {:.3}",
                    render(&view.joints).iou(&view.observed),
                    render(&best_q).iou(&view.observed)
                );
            }
            fitted.push(PosedRobot::new(&run.robot, &best_q));
        }
        fitted
    };
    // Builtin masks of every frame under the render of `fitted` at `at`, and their IoU against
    // the provided masks.
    let masks_under_fitted = |at: &Isometry3<f64>, fitted: &[PosedRobot], band_px: f32| {
        let priors = easyhec::pipeline::segment_solve::priors(&r, &run.camera, fitted, at);
        let inputs: Vec<ViewInput> = frames
            .iter()
            .zip(&priors)
            .map(|(frame, p)| ViewInput {
                frame,
                prior: Some(p),
                band_px,
            })
            .collect();
        let masks = segment_views_with_evidence(&inputs, &params).unwrap().masks;
        let ious: Vec<f64> = masks
            .iter()
            .zip(&run.views)
            .map(|(m, v)| m.iou(&v.observed))
            .collect();
        (masks, ious)
    };
    if mode == "joints" {
        let fitted = refit_joints(&pose, true);
        let priors = easyhec::pipeline::segment_solve::priors(&r, &run.camera, &fitted, &pose);
        for band_px in [4.0f32, 8.0] {
            let (_, ious) = masks_under_fitted(&pose, &fitted, band_px);
            let prior_ious: Vec<f64> = priors
                .iter()
                .zip(&run.views)
                .map(|(m, v)| m.iou(&v.observed))
                .collect();
            println!(
                "builtin masks under the refined joints, band {band_px} px: mean IoU {:.3} (min {:.3}); the priors themselves {:.3}",
                ious.iter().sum::<f64>() / n as f64,
                ious.iter().copied().fold(1.0, f64::min),
                prior_ious.iter().sum::<f64>() / n as f64
            );
        }
        return;
    }
    // Builtin masks of every frame under `p`'s render with one band, and the views they make.
    let segment_under =
        |p: &Isometry3<f64>, band_px: f32| -> (Vec<easyhec::mask::Mask>, Vec<View>) {
            let (masks, _) = masks_under_fitted(p, &robots, band_px);
            let views = masks
                .iter()
                .zip(&robots)
                .map(|(m, robot)| View {
                    robot: robot.clone(),
                    observed: run.camera.undistort_mask(m),
                })
                .collect();
            (masks, views)
        };
    if mode == "pairs" {
        let p = parse_pose(&args[3]);
        let band_px: f32 = args[4].parse().unwrap();
        let (_, bviews) = segment_under(&p, band_px);
        let pairs: Vec<(usize, usize)> = (0..n)
            .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
            .collect();
        let mut res: Vec<(f64, String)> = pairs
            .par_iter()
            .map(|&(i, j)| {
                let sub = vec![bviews[i].clone(), bviews[j].clone()];
                let rep = solve(&r, &run.camera, &sub, &p, &opts).unwrap();
                let q = rep.camera_from_base;
                let all: Vec<f64> = (0..n)
                    .map(|k| {
                        r.render(&robots[k], &cam, &q, None)
                            .mask
                            .iou(&bviews[k].observed)
                    })
                    .collect();
                (
                    rep.mean_iou(),
                    format!(
                        "pair ({i},{j}): mean IoU {:.3}; all views {:?}; {:.2} deg / {:.1} mm",
                        rep.mean_iou(),
                        all.iter()
                            .map(|x| (x * 100.0).round() / 100.0)
                            .collect::<Vec<_>>(),
                        rotation_error_deg(&q, &pose),
                        translation_error_mm(&q, &pose)
                    ),
                )
            })
            .collect();
        res.sort_by(|a, b| b.0.total_cmp(&a.0));
        for (_, line) in res {
            println!("{line}");
        }
        return;
    }
    if mode == "pairchain" {
        let start = parse_pose(&args[3]);
        let bands: Vec<f32> = args[4].split(',').map(|x| x.parse().unwrap()).collect();
        let pairs: Vec<(usize, usize)> = (0..n)
            .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
            .collect();
        let mut res: Vec<(f64, f64, f64, String)> = pairs
            .par_iter()
            .map(|&(i, j)| {
                let mut p = start;
                let mut iou = 0.0;
                for &band_px in &bands {
                    let (_, bviews) = segment_under(&p, band_px);
                    let sub = vec![bviews[i].clone(), bviews[j].clone()];
                    let rep = solve(&r, &run.camera, &sub, &p, &opts).unwrap();
                    p = rep.camera_from_base;
                    iou = rep.mean_iou();
                }
                // Prior-free: the evidence over the pair's render at the pose it settled on.
                let region: f64 = [i, j]
                    .iter()
                    .map(|&k| {
                        region_score(&r.render(&robots[k], &cam, &p, None).mask, &evidence[k])
                            / positive[k]
                    })
                    .sum::<f64>()
                    / 2.0;
                // The widest band again, under the settled pose.
                let (_, wide) = segment_under(&p, bands[0]);
                let wide_iou = [i, j]
                    .iter()
                    .map(|&k| r.render(&robots[k], &cam, &p, None).mask.iou(&wide[k].observed))
                    .sum::<f64>()
                    / 2.0;
                (
                    iou,
                    region,
                    wide_iou,
                    format!(
                        "pair ({i},{j}): settled IoU {iou:.3}, region {region:.3}, wide-band IoU {wide_iou:.3}; {:.2} deg / {:.1} mm",
                        rotation_error_deg(&p, &pose),
                        translation_error_mm(&p, &pose)
                    ),
                )
            })
            .collect();
        for (name, key) in [("settled IoU", 0usize), ("region", 1), ("wide-band IoU", 2)] {
            let k = |x: &(f64, f64, f64, String)| [x.0, x.1, x.2][key];
            res.sort_by(|a, b| k(b).total_cmp(&k(a)));
            println!("by {name}:");
            for x in res.iter().take(8) {
                println!("  {}", x.3);
            }
        }
        return;
    }
    if mode == "chain" {
        let mut p = parse_pose(&args[3]);
        let bands: Vec<f32> = args[4].split(',').map(|x| x.parse().unwrap()).collect();
        let only: Option<Vec<usize>> = args
            .get(5)
            .map(|a| a.split(',').map(|x| x.parse().unwrap()).collect());
        for band_px in bands {
            let (masks, bviews) = segment_under(&p, band_px);
            let ious: Vec<f64> = masks
                .iter()
                .zip(&run.views)
                .map(|(m, v)| m.iou(&v.observed))
                .collect();
            let (rep, kept) = match &only {
                Some(k) => {
                    let sub: Vec<View> = k.iter().map(|&i| bviews[i].clone()).collect();
                    (solve(&r, &run.camera, &sub, &p, &opts).unwrap(), k.clone())
                }
                None => {
                    let all = solve(&r, &run.camera, &bviews, &p, &opts).unwrap();
                    match find_consensus(
                        &r,
                        &run.camera,
                        &bviews,
                        &all,
                        &opts,
                        &ConsensusOptions::default(),
                    )
                    .unwrap()
                    {
                        Some(c) => (c.report, c.kept),
                        None => (all, (0..n).collect()),
                    }
                }
            };
            p = rep.camera_from_base;
            println!(
                "band {band_px}: mask IoU vs provided {:?}; solve kept {:?} mean IoU {:.3}; {:.2} deg / {:.1} mm from the reference",
                ious.iter().map(|x| (x * 100.0).round() / 100.0).collect::<Vec<_>>(),
                kept,
                rep.mean_iou(),
                rotation_error_deg(&p, &pose),
                translation_error_mm(&p, &pose)
            );
        }
        if args.get(6).map(String::as_str) == Some("finish") {
            // The masks: every view's joints refitted at the chained pose, segmented under them.
            let fitted = refit_joints(&p, false);
            for band_px in [4.0f32, 8.0, 16.0] {
                let (masks, ious) = masks_under_fitted(&p, &fitted, band_px);
                // The calibration: those masks with the recorded joints, every view, the
                // consistency check, from the chained pose.
                let fviews: Vec<View> = masks
                    .iter()
                    .zip(&robots)
                    .map(|(m, robot)| View {
                        robot: robot.clone(),
                        observed: run.camera.undistort_mask(m),
                    })
                    .collect();
                let all = solve(&r, &run.camera, &fviews, &p, &opts).unwrap();
                let (rep, kept) = match find_consensus(
                    &r,
                    &run.camera,
                    &fviews,
                    &all,
                    &opts,
                    &ConsensusOptions::default(),
                )
                .unwrap()
                {
                    Some(c) => (c.report, c.kept),
                    None => (all, (0..n).collect()),
                };
                let q = rep.camera_from_base;
                println!(
                    "finish, band {band_px}: masks under refitted joints mean IoU {:.3} (min {:.3}); solve kept {kept:?} mean IoU {:.3}; {:.2} deg / {:.1} mm from the reference",
                    ious.iter().sum::<f64>() / n as f64,
                    ious.iter().copied().fold(1.0, f64::min),
                    rep.mean_iou(),
                    rotation_error_deg(&q, &pose),
                    translation_error_mm(&q, &pose)
                );
            }
        }
        return;
    }
    // search: the camera pose by the region score, coarse to fine.
    let levels: Vec<(Intrinsics, Vec<Vec<f32>>, Vec<PosedRobot>)> = [16usize, 8, 4, 2]
        .iter()
        .map(|&f| {
            let low = cam.downsampled(f as u32);
            let ev: Vec<Vec<f32>> = evidence.iter().map(|e| downsample(e, w, h, f)).collect();
            let cell_m = 0.5 * f as f64 / cam.fx;
            (
                low,
                ev,
                robots.iter().map(|r| r.decimated(cell_m)).collect(),
            )
        })
        .collect();
    let robust = |p: &Isometry3<f64>, level: usize| -> f64 {
        (0..n)
            .map(|k| {
                let s = match levels.get(level) {
                    Some((low, ev, dec)) => {
                        region_score(&r.render(&dec[k], low, p, None).mask, &ev[k])
                    }
                    None => region_score(&r.render(&robots[k], &cam, p, None).mask, &evidence[k]),
                };
                (s / positive[k]).max(0.0)
            })
            .sum()
    };
    println!(
        "robust score (sum over views of max(0, region score)): {:.3} at the reference, {:.3} at the guess",
        robust(&pose, 9),
        robust(&guess, 9)
    );
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let around_guess: Vec<Isometry3<f64>> = (0..4000)
        .map(|_| {
            let mut xi = Twist::zeros();
            for d in 0..6 {
                let g: f64 = rng.sample(rand_distr::StandardNormal);
                xi[d] = g * if d < 3 { 0.2 } else { 20f64.to_radians() };
            }
            exp_se3(&xi) * guess
        })
        .collect();
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = -lo;
    for p in &robots[0].vertices_base {
        lo = lo.inf(&p.coords);
        hi = hi.sup(&p.coords);
    }
    let dense = easyhec::init::InitOptions {
        distances_m: (0..12).map(|i| 0.6 * 1.13f64.powi(i)).collect(),
        azimuth_step_deg: 7.5,
        elevations_deg: (0..10).map(|i| -10.0 + 10.0 * f64::from(i)).collect(),
        rolls_deg: (0..9).map(|i| -40.0 + 10.0 * f64::from(i)).collect(),
        ..Default::default()
    };
    let mut grid = Vec::new();
    for aim_u in [cam.cx - 160.0, cam.cx, cam.cx + 160.0] {
        grid.extend(easyhec::init::hypotheses(
            &((lo + hi) / 2.0),
            &cam,
            [aim_u, cam.cy],
            &dense,
        ));
    }
    let nearest = grid
        .iter()
        .map(|p| (rotation_error_deg(p, &pose), translation_error_mm(p, &pose)))
        .min_by(|a, b| (a.0 + a.1 / 10.0).total_cmp(&(b.0 + b.1 / 10.0)))
        .unwrap();
    println!(
        "{} grid hypotheses, the nearest {:.1} deg / {:.0} mm from the reference",
        grid.len(),
        nearest.0,
        nearest.1
    );
    let refine = |start: Isometry3<f64>, level: usize| -> (f64, Isometry3<f64>) {
        let mut p = start;
        let mut best = 0.0;
        for (level, m, deg) in [
            (level, 0.04, 4.0),
            (level, 0.02, 2.0),
            (1, 0.02, 2.0),
            (2, 0.01, 1.0),
            (3, 0.005, 0.5),
            (9, 0.002, 0.2),
            (9, 0.001, 0.1),
        ] {
            best = robust(&p, level);
            let mut improved = true;
            while improved {
                improved = false;
                for d in 0..6 {
                    for sign in [-1.0, 1.0] {
                        let mut xi = Twist::zeros();
                        xi[d] = sign * if d < 3 { m } else { f64::to_radians(deg) };
                        let cand = exp_se3(&xi) * p;
                        let v = robust(&cand, level);
                        if v > best + 1e-5 {
                            (best, p, improved) = (v, cand, true);
                        }
                    }
                }
            }
        }
        (best, p)
    };
    let per_view = |p: &Isometry3<f64>, level: usize| -> Vec<f64> {
        let (low, ev, dec) = &levels[level];
        (0..n)
            .map(|k| region_score(&r.render(&dec[k], low, p, None).mask, &ev[k]) / positive[k])
            .collect()
    };
    if mode == "rank" {
        let t0 = std::time::Instant::now();
        let raw: Vec<Vec<f64>> = grid.par_iter().map(|p| per_view(p, 0)).collect();
        println!(
            "scored {} at level 0 in {:.1} s",
            grid.len(),
            t0.elapsed().as_secs_f64()
        );
        let d = |p: &Isometry3<f64>| {
            rotation_error_deg(p, &pose) + translation_error_mm(p, &pose) / 10.0
        };
        let mut near: Vec<usize> = (0..grid.len()).collect();
        near.sort_by(|&a, &b| d(&grid[a]).total_cmp(&d(&grid[b])));
        let near: Vec<usize> = near.into_iter().take(40).collect();
        let scores: [(&str, ViewSum); 4] = [
            ("plain", |v| v.iter().sum()),
            ("robust", |v| v.iter().map(|x| x.max(0.0)).sum()),
            ("top3", |v| {
                let mut s = v.to_vec();
                s.sort_by(|a, b| b.total_cmp(a));
                s[..3].iter().sum()
            }),
            ("max", |v| v.iter().copied().fold(f64::MIN, f64::max)),
        ];
        for (name, f) in &scores {
            let sc: Vec<f64> = raw.iter().map(|v| f(v)).collect();
            let mut order: Vec<usize> = (0..grid.len()).collect();
            order.sort_by(|&a, &b| sc[b].total_cmp(&sc[a]));
            let mut rank = vec![0usize; grid.len()];
            for (r, &i) in order.iter().enumerate() {
                rank[i] = r;
            }
            let mut rs: Vec<usize> = near.iter().map(|&i| rank[i]).collect();
            rs.sort();
            println!("{name}: ranks of the 40 nearest grid poses {:?}", &rs[..10]);
        }
        return;
    }
    if mode == "probe" {
        let t0 = std::time::Instant::now();
        let scored: Vec<f64> = grid.par_iter().map(|p| robust(p, 0)).collect();
        println!(
            "scored {} at level 0 in {:.1} s",
            grid.len(),
            t0.elapsed().as_secs_f64()
        );
        let mut order: Vec<usize> = (0..grid.len()).collect();
        order.sort_by(|&a, &b| scored[b].total_cmp(&scored[a]));
        let mut rank = vec![0usize; grid.len()];
        for (r, &i) in order.iter().enumerate() {
            rank[i] = r;
        }
        let mut near: Vec<usize> = (0..grid.len()).collect();
        let d = |p: &Isometry3<f64>| {
            rotation_error_deg(p, &pose) + translation_error_mm(p, &pose) / 10.0
        };
        near.sort_by(|&a, &b| d(&grid[a]).total_cmp(&d(&grid[b])));
        for &i in near.iter().take(12) {
            let t = std::time::Instant::now();
            let (s, p) = refine(grid[i], 0);
            println!(
                "grid {:.1} deg / {:.0} mm off, level-0 score {:.3} rank {}; refined score {s:.3}, {:.2} deg / {:.1} mm off ({:.1} s)",
                rotation_error_deg(&grid[i], &pose),
                translation_error_mm(&grid[i], &pose),
                scored[i],
                rank[i],
                rotation_error_deg(&p, &pose),
                translation_error_mm(&p, &pose),
                t.elapsed().as_secs_f64()
            );
            if s > 0.9 {
                println!("pose {:?}", p.to_homogeneous().transpose().as_slice());
            }
        }
        return;
    }
    for (label, hypotheses, level) in [
        ("around the guess", around_guess, 2),
        ("hemisphere grid", grid, 0),
    ] {
        let mut scored: Vec<(f64, Isometry3<f64>)> = hypotheses
            .into_par_iter()
            .map(|p| (robust(&p, level), p))
            .collect();
        scored.sort_by(|a, b| b.0.total_cmp(&a.0));
        let mut starts: Vec<Isometry3<f64>> = Vec::new();
        for (_, p) in &scored {
            if starts.len() < 8
                && starts
                    .iter()
                    .all(|s| rotation_error_deg(s, p) > 5.0 || translation_error_mm(s, p) > 50.0)
            {
                starts.push(*p);
            }
        }
        for start in starts {
            let (best, p) = refine(start, level);
            println!(
                "{label}: refined to score {best:.3}, {:.2} deg / {:.1} mm from the reference",
                rotation_error_deg(&p, &pose),
                translation_error_mm(&p, &pose)
            );
        }
    }
}

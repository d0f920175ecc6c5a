//! Where the robot stands on its mount, masks can run fat round the base's foot (a plate of
//! the base's colour that no view uncovers) or thin (a flange the masks leave out), and a fit
//! that reads that outline pulls the camera along its axis. `mount_contact` leaves that
//! outline out, always or where the masks disagree with the render there (docs/method.md
//! §6).

mod common;

use easyhec::bench::seeded_scene;
use easyhec::config::NoiseModel;
use easyhec::geometry::camera_centre_error_mm;
use easyhec::render::{
    project_vertices, CpuRenderer, PosedRobot, SilhouetteRenderer, MOUNT_CONTACT_HEIGHT_M,
};
use easyhec::robot::RobotModel;
use easyhec::solve::{mount_contact_disagrees, solve, MountContact, SolveOptions, View};
use easyhec::synth::SynthOptions;

const Q: [f64; 6] = [0.3, -0.4, -0.6, 0.2, 0.5, -0.1];

/// The base-frame height of the lowest vertex of the xArm6's fixed base, and the base's
/// link index.
fn base_floor(robot: &RobotModel, posed: &PosedRobot) -> (u32, f64) {
    let base = robot.link_index("link_base").unwrap() as u32;
    let floor = (0..posed.vertices_base.len())
        .filter(|&i| posed.vertex_link[i] == base)
        .map(|i| posed.vertices_base[i].z)
        .fold(f64::INFINITY, f64::min);
    (base, floor)
}

/// Scenes with exact masks: what the tests paint on them is the only error.
fn noiseless() -> SynthOptions {
    SynthOptions {
        noise: NoiseModel::none(),
        ..Default::default()
    }
}

/// Of the rendered outline, only samples on the fixed base whose own point lies within the
/// contact height of its foot count as the mount; the base's outline above stays.
#[test]
fn only_the_outline_at_the_foot_of_the_fixed_base_counts_as_the_mount() {
    let robot = common::load_robot("xarm6");
    let synth = noiseless();
    let (scene, views, _) = seeded_scene(&robot, 1, 1, &synth).unwrap();
    let camera = scene.camera.undistorted();
    for posed in [views[0].robot.clone(), views[0].robot.decimated(0.005)] {
        let (base, floor) = base_floor(&robot, &posed);
        let mount = posed.mount().expect("the base stays put");
        let sil = CpuRenderer.render(&posed, &camera, &scene.camera_from_base, Some(1.0));
        let base_from_camera = scene.camera_from_base.inverse();
        let (mut at_foot, mut above) = (0, 0);
        for s in &sil.boundary {
            let z = (base_from_camera * s.point_camera).z;
            let on_base = posed.vertex_link[s.vertex as usize] == base;
            let held = mount.holds(s, &base_from_camera);
            assert_eq!(held, on_base && z < floor + MOUNT_CONTACT_HEIGHT_M, "{s:?}");
            at_foot += usize::from(held);
            above += usize::from(on_base && !held);
        }
        assert!(
            at_foot > 10 && above > 10,
            "{at_foot} at the foot, {above} above"
        );
    }
}

/// Without its links' joints nothing is known to stay put.
#[test]
fn a_robot_whose_links_are_unknown_has_no_mount() {
    let robot = common::load_robot("xarm6");
    let mut posed = PosedRobot::new(&robot, &Q);
    posed.fixed_links = std::sync::Arc::new(Vec::new());
    assert!(posed.mount().is_none());
}

/// A camera on a link sees every drawn link move, so nothing of the robot stays put for it,
/// not even a finger that only a mimic joint moves; from the base, the same robot has its
/// mount.
#[test]
fn a_camera_on_a_link_sees_no_mount() {
    for (name, link, q) in [
        ("xarm6", "link6", Q.to_vec()),
        (
            "panda",
            "panda_hand",
            vec![0.1, -0.3, 0.2, -2.0, 0.1, 1.8, 0.6, 0.02],
        ),
    ] {
        let robot = common::load_robot(name);
        let q = &q[..robot.actuated.len()];
        let seen = robot
            .seen_from_link(link, std::path::Path::new("cell.toml"), "camera.mount.link")
            .unwrap();
        assert!(PosedRobot::new(&robot, q).mount().is_some(), "{name}");
        let posed = PosedRobot::new(&seen, q);
        assert!(!posed.vertices_base.is_empty(), "{name}");
        assert!(posed.mount().is_none(), "{name} seen from {link}");
    }
}

/// Each view's mask with a plate around the base's foot: every pixel within `reach_px` of a
/// projected vertex of the base less than the contact height above its floor is marked
/// robot, as a segmenter that never saw the plate uncovered marks it.
fn with_plate(
    robot: &RobotModel,
    views: &[View],
    camera_from_base: &nalgebra::Isometry3<f64>,
    camera: &easyhec::camera::Intrinsics,
    reach_px: f64,
) -> Vec<View> {
    painted_at_foot(robot, views, camera_from_base, camera, reach_px, true)
}

/// Each view's mask with the pixels within `reach_px` of the foot's projected vertices set to
/// `robot` (true: a plate taken for the robot; false: a flange the masks leave out).
fn painted_at_foot(
    robot: &RobotModel,
    views: &[View],
    camera_from_base: &nalgebra::Isometry3<f64>,
    camera: &easyhec::camera::Intrinsics,
    reach_px: f64,
    robot_there: bool,
) -> Vec<View> {
    views
        .iter()
        .map(|v| {
            let (base, floor) = base_floor(robot, &v.robot);
            let (pixels, _) = project_vertices(&v.robot.vertices_base, camera, camera_from_base);
            let feet: Vec<[f64; 2]> = (0..pixels.len())
                .filter(|&i| {
                    v.robot.vertex_link[i] == base
                        && v.robot.vertices_base[i].z < floor + MOUNT_CONTACT_HEIGHT_M
                        && pixels[i][0].is_finite()
                })
                .map(|i| pixels[i])
                .collect();
            let mut observed = v.observed.clone();
            let (w, h) = (f64::from(observed.width), f64::from(observed.height));
            for p in &feet {
                let (x0, x1) = (
                    (p[0] - reach_px).ceil().max(0.0),
                    (p[0] + reach_px).min(w - 1.0),
                );
                let (y0, y1) = (
                    (p[1] - reach_px).ceil().max(0.0),
                    (p[1] + reach_px).min(h - 1.0),
                );
                let (mut y, mut x);
                y = y0;
                while y <= y1 {
                    x = x0;
                    while x <= x1 {
                        if (p[0] - x).hypot(p[1] - y) <= reach_px {
                            observed.set(x as u32, y as u32, robot_there);
                        }
                        x += 1.0;
                    }
                    y += 1.0;
                }
            }
            View {
                robot: v.robot.clone(),
                observed,
            }
        })
        .collect()
}

/// A plate the masks take for robot, 2 px round the base's foot (where the real xArm7's
/// builtin masks run fat), pulls a plain fit off; leaving the mount contact out keeps the fit
/// on the camera. Summed over four scenes, so that one scene's luck decides nothing
/// (measured: 2.1 mm reading the plate, 0.7 mm leaving the mount out).
#[test]
fn a_plate_taken_for_the_robot_moves_the_camera_unless_the_mount_is_left_out() {
    let robot = common::load_robot("xarm6");
    let synth = noiseless();
    let (mut read, mut left_out) = (0.0, 0.0);
    for seed in 1u64..=4 {
        let (scene, views, init) = seeded_scene(&robot, seed, 3, &synth).unwrap();
        let camera = scene.camera.undistorted();
        let plated = with_plate(&robot, &views, &scene.camera_from_base, &camera, 2.0);
        let error = |leave_out: bool| {
            let opts = SolveOptions {
                mount_contact: if leave_out {
                    MountContact::LeaveOut
                } else {
                    MountContact::Fit
                },
                ..SolveOptions::default()
            };
            let report = solve(&CpuRenderer, &scene.camera, &plated, &init, &opts).unwrap();
            camera_centre_error_mm(&report.camera_from_base, &scene.camera_from_base)
        };
        read += error(false);
        left_out += error(true);
    }
    assert!(
        left_out < 0.5 * read,
        "camera centres {read:.2} mm off in all reading the plate, {left_out:.2} mm leaving the mount out"
    );
}

/// `easyhec solve --mount-contact` reaches the fit: told to leave the mount out, the same run
/// solves to another pose; left to decide, it fits the masks the run gives; every pose lands
/// on the camera, and each result says whether the mount was left out.
#[test]
fn the_solve_flag_leaves_the_mount_out_of_the_fit() {
    use easyhec::run::ResultFile;
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    common::synth_run(&run, "xarm6", &["--views", "3", "--seed", "5"]);
    let text = std::fs::read_to_string(run.join("ground_truth.json")).unwrap();
    let doc: serde_json::Value = serde_json::from_str(&text).unwrap();
    let rows: [[f64; 4]; 4] = serde_json::from_value(doc["camera_from_base"].clone()).unwrap();
    let truth = easyhec::geometry::from_rows(&rows).unwrap();
    let mut poses = Vec::new();
    for (name, choice, left_out) in [
        ("fit.json", Some("fit"), false),
        ("left_out.json", Some("leave-out"), true),
        ("auto.json", None, false),
    ] {
        let out = dir.path().join(name);
        let mut args = vec!["--renderer", "cpu", "--out", out.to_str().unwrap()];
        if let Some(c) = choice {
            args.extend(["--mount-contact", c]);
        }
        let solved = common::solve_run(&run, &args);
        assert!(
            solved.status.success(),
            "{}",
            String::from_utf8_lossy(&solved.stderr)
        );
        let result = ResultFile::read(&out).unwrap();
        assert_eq!(result.mount_contact_left_out, left_out, "{name}");
        let written = std::fs::read_to_string(&out).unwrap();
        assert_eq!(
            written.contains("\"mount_contact_left_out\": true"),
            left_out,
            "{name}: {written}"
        );
        let pose = result.camera_from_base();
        let error = camera_centre_error_mm(&pose, &truth);
        assert!(error < 2.0, "{name}: camera centre {error:.2} mm off");
        poses.push(pose);
    }
    let apart = camera_centre_error_mm(&poses[0], &poses[1]);
    assert!(
        apart > 0.01,
        "leaving the mount out moved the camera centre {apart} mm"
    );
    let auto = camera_centre_error_mm(&poses[0], &poses[2]);
    assert!(
        auto < 1e-9,
        "deciding moved the camera centre {auto} mm from fitting"
    );
}

/// `auto` decides from the masks: exact ones agree with the render at the foot; a 4 px plate
/// taken for the robot, or the foot's outline left out of the masks as hand-made masks leave
/// out a flange, disagree. A solve left to decide then lands where one told to leave the mount
/// out does, and says so.
#[test]
fn auto_leaves_the_mount_out_where_the_masks_disagree_there() {
    let robot = common::load_robot("xarm6");
    let synth = noiseless();
    let (scene, views, init) = seeded_scene(&robot, 2, 4, &synth).unwrap();
    let camera = scene.camera.undistorted();
    let truth = scene.camera_from_base;
    let opts = SolveOptions::default();
    let disagrees = |v: &[View]| mount_contact_disagrees(&CpuRenderer, &camera, v, &truth, &opts);
    assert!(!disagrees(&views));
    let plated = painted_at_foot(&robot, &views, &truth, &camera, 4.0, true);
    assert!(disagrees(&plated));
    let thin = painted_at_foot(&robot, &views, &truth, &camera, 4.0, false);
    assert!(disagrees(&thin));
    let auto = solve(&CpuRenderer, &scene.camera, &plated, &init, &opts).unwrap();
    assert!(auto.mount_contact_left_out);
    let told = SolveOptions {
        mount_contact: MountContact::LeaveOut,
        ..SolveOptions::default()
    };
    let left_out = solve(&CpuRenderer, &scene.camera, &plated, &init, &told).unwrap();
    let apart = camera_centre_error_mm(&auto.camera_from_base, &left_out.camera_from_base);
    assert!(
        apart < 0.05,
        "auto lands {apart:.3} mm from leaving the mount out"
    );
    let clean = solve(&CpuRenderer, &scene.camera, &views, &init, &opts).unwrap();
    assert!(!clean.mount_contact_left_out);
}

/// Views that do not fit (here: rendered at other joints than their masks show) take no
/// part in the decision, so a plate seen only in them decides nothing.
#[test]
fn views_that_do_not_fit_take_no_part_in_the_decision() {
    let robot = common::load_robot("xarm6");
    let synth = noiseless();
    let (scene, views, _) = seeded_scene(&robot, 2, 4, &synth).unwrap();
    let camera = scene.camera.undistorted();
    let truth = scene.camera_from_base;
    let plated = painted_at_foot(&robot, &views, &truth, &camera, 4.0, true);
    let wrong: Vec<View> = plated
        .iter()
        .map(|v| View {
            robot: PosedRobot::new(&robot, &[0.9, 0.3, -1.2, 0.8, -0.4, 0.6]),
            observed: v.observed.clone(),
        })
        .collect();
    let opts = SolveOptions::default();
    assert!(!mount_contact_disagrees(
        &CpuRenderer,
        &camera,
        &wrong,
        &truth,
        &opts
    ));
}

/// The closed loop honours `[calibration] mount_contact` and records in its result that it
/// left the mount out, so a result says how it was fitted.
#[test]
fn the_loop_records_that_it_left_the_mount_out() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("cell.toml");
    let text = common::shipped_config_text("sim-xarm6.toml").replacen(
        "[calibration]",
        "[calibration]\nmount_contact = \"leave-out\"",
        1,
    );
    std::fs::write(&config, text).unwrap();
    let cell = easyhec::cell::Cell::open(&config).unwrap();
    let out = dir.path().join("run");
    common::run_loop(&cell, &out);
    let result = easyhec::run::ResultFile::read(&out.join("result.json")).unwrap();
    assert!(result.mount_contact_left_out);
}

/// Cuts the foot out of every mask of the synthetic run `run`, at its true pose, as hand-made
/// masks leave out a flange (the masks are rewritten in place).
fn cut_foot_out_of_masks(run: &std::path::Path, reach_px: f64) {
    let loaded = easyhec::run::load_run(run).unwrap();
    let text = std::fs::read_to_string(run.join("ground_truth.json")).unwrap();
    let doc: serde_json::Value = serde_json::from_str(&text).unwrap();
    let rows: [[f64; 4]; 4] = serde_json::from_value(doc["camera_from_base"].clone()).unwrap();
    let truth = easyhec::geometry::from_rows(&rows).unwrap();
    let views: Vec<View> = loaded
        .views
        .iter()
        .map(|v| View {
            robot: PosedRobot::new(&loaded.robot, &v.joints),
            observed: v.observed.clone(),
        })
        .collect();
    let camera = loaded.camera.undistorted();
    let cut = painted_at_foot(&loaded.robot, &views, &truth, &camera, reach_px, false);
    for (view, entry) in cut.iter().zip(&loaded.file.views) {
        let m = &view.observed;
        let pixels = m
            .data
            .iter()
            .map(|&v| if v != 0 { 255 } else { 0 })
            .collect();
        let image = image::GrayImage::from_raw(m.width, m.height, pixels).unwrap();
        image.save(run.join(entry.mask.as_ref().unwrap())).unwrap();
    }
}

/// Masks a run gives are fitted as they are, but `easyhec solve` says when they disagree
/// with the rendered robot at its foot, and names the setting that leaves it out; on masks
/// that agree there it says nothing.
#[test]
fn a_solve_of_given_masks_says_when_they_disagree_at_the_foot() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    common::synth_run(
        &run,
        "xarm6",
        &["--views", "4", "--seed", "2", "--no-noise"],
    );
    let out = dir.path().join("result.json");
    let says_it = || {
        let solved =
            common::solve_run(&run, &["--renderer", "cpu", "--out", out.to_str().unwrap()]);
        let said = String::from_utf8_lossy(&solved.stderr).into_owned();
        assert!(solved.status.success(), "{said}");
        let result = easyhec::run::ResultFile::read(&out).unwrap();
        assert!(!result.mount_contact_left_out, "given masks are fitted");
        said.contains(easyhec::pipeline::offline::MOUNT_CONTACT_DISAGREES)
    };
    assert!(!says_it(), "exact masks agree with the render at the foot");
    cut_foot_out_of_masks(&run, 4.0);
    assert!(says_it(), "masks without the foot disagree there");
}

/// Left out means left out of the whole fit: with the mount contact left out, a plate the
/// masks take for robot round the foot must not pull the posterior refinement's mask score
/// either. LM still feels a little of it (the plate reaches past the contact's height), so
/// the refined poses may move only about as far as LM's own do (measured over these three
/// scenes: 0.20 mm against LM's 0.26 mm; 0.46 mm when the refinement read the foot).
#[test]
fn a_left_out_mount_contact_pulls_the_refinement_no_more_than_lm() {
    let robot = common::load_robot("xarm6");
    let synth = noiseless();
    let refined = SolveOptions {
        mount_contact: MountContact::LeaveOut,
        ..SolveOptions::default()
    };
    let lm_only = SolveOptions {
        refine_samples: 0,
        ..refined.clone()
    };
    let (mut moved_refined, mut moved_lm) = (0.0, 0.0);
    for seed in 1u64..=3 {
        let (scene, views, init) = seeded_scene(&robot, seed, 3, &synth).unwrap();
        let camera = scene.camera.undistorted();
        let plated = with_plate(&robot, &views, &scene.camera_from_base, &camera, 4.0);
        let moved = |opts: &SolveOptions| {
            let clean = solve(&CpuRenderer, &scene.camera, &views, &init, opts).unwrap();
            let read = solve(&CpuRenderer, &scene.camera, &plated, &init, opts).unwrap();
            camera_centre_error_mm(&clean.camera_from_base, &read.camera_from_base)
        };
        moved_refined += moved(&refined);
        moved_lm += moved(&lm_only);
    }
    assert!(
        moved_refined < 1.3 * moved_lm,
        "the plate moved the refined camera centres {moved_refined:.3} mm in all, LM's {moved_lm:.3} mm"
    );
}

/// A segmenter that takes the plate for robot while its band round the render is wide, and
/// draws the exact masks once the band narrows: on the real xArm7 the builtin masks showed
/// the foot's disagreement in the wide-band rounds and hid part of it in the final
/// narrow-band one. It records the bands it was asked for.
struct PlateWhileWide {
    plated: Vec<easyhec::mask::Mask>,
    exact: Vec<easyhec::mask::Mask>,
    narrow_below_px: f32,
    bands_seen: std::sync::Mutex<Vec<Option<f32>>>,
}

impl easyhec::segment::Segmenter for PlateWhileWide {
    fn name(&self) -> &str {
        "plate-while-wide"
    }

    fn segment(
        &self,
        _frame: &easyhec_drivers::Frame,
    ) -> easyhec::error::Result<easyhec::mask::Mask> {
        Err(easyhec::error::Error::Solve(
            "segments whole runs only".into(),
        ))
    }

    fn segment_views(
        &self,
        views: &[easyhec::segment::ViewInput<'_>],
    ) -> easyhec::error::Result<Vec<easyhec::mask::Mask>> {
        let widest = views
            .iter()
            .map(|v| v.prior.map(|_| v.band_px))
            .max_by(|a, b| {
                a.unwrap_or(f32::INFINITY)
                    .total_cmp(&b.unwrap_or(f32::INFINITY))
            })
            .flatten();
        self.bands_seen.lock().unwrap().push(widest);
        let wide = widest.is_none_or(|b| b >= self.narrow_below_px);
        Ok(if wide {
            self.plated.clone()
        } else {
            self.exact.clone()
        })
    }

    fn uses_context(&self) -> bool {
        true
    }
}

/// Through the segment-and-solve rounds: once a round that fits has left the mount out, the
/// final narrow-band solve leaves it out too, though its own masks agree with the render at
/// the foot (decided afresh, they fit it).
#[test]
fn a_round_that_left_the_mount_out_binds_the_final_narrow_band_solve() {
    use easyhec::camera::LensWarp;
    use easyhec::pipeline::segment_solve::segment_and_solve;

    let robot = common::load_robot("xarm6");
    let (scene, views, init) = seeded_scene(&robot, 2, 4, &noiseless()).unwrap();
    let pinhole = scene.camera.undistorted();
    let truth = scene.camera_from_base;
    let plated = painted_at_foot(&robot, &views, &truth, &pinhole, 4.0, true);
    let distorted = |vs: &[View]| -> Vec<easyhec::mask::Mask> {
        vs.iter()
            .map(|v| scene.camera.distort_mask(&v.observed))
            .collect()
    };
    let segmenter = PlateWhileWide {
        plated: distorted(&plated),
        exact: distorted(&views),
        narrow_below_px: 7.5,
        bands_seen: std::sync::Mutex::new(Vec::new()),
    };
    let (w, h) = (scene.camera.width, scene.camera.height);
    let frames: Vec<easyhec_drivers::Frame> = (0..views.len())
        .map(|_| easyhec_drivers::Frame {
            width: w,
            height: h,
            rgb: vec![0; (w * h * 3) as usize],
            captured_at: std::time::SystemTime::now(),
            sequence: 0,
        })
        .collect();
    let refs: Vec<&easyhec_drivers::Frame> = frames.iter().collect();
    let robots: Vec<PosedRobot> = views.iter().map(|v| v.robot.clone()).collect();
    let opts = SolveOptions::default();
    let settled = segment_and_solve(
        &CpuRenderer,
        &scene.camera,
        &segmenter,
        &refs,
        &robots,
        &|_| Ok(init),
        Some((&init, 80.0)),
        8.0,
        4.0,
        &opts,
        4,
    )
    .unwrap();
    let bands = segmenter.bands_seen.lock().unwrap().clone();
    assert!(
        settled
            .masks
            .iter()
            .zip(&segmenter.exact)
            .all(|(a, b)| a.data == b.data),
        "the final round did not draw the exact masks (bands asked for: {bands:?})"
    );
    assert!(
        settled.report.mount_contact_left_out,
        "the final solve fitted the mount contact after a round had left it out (bands asked for: {bands:?})"
    );
    let exact_views: Vec<View> = settled
        .masks
        .iter()
        .zip(&robots)
        .map(|(m, r)| View {
            robot: r.clone(),
            observed: scene.camera.undistort_mask(m),
        })
        .collect();
    let afresh = solve(
        &CpuRenderer,
        &scene.camera,
        &exact_views,
        &settled.report.camera_from_base,
        &opts,
    )
    .unwrap();
    assert!(
        !afresh.mount_contact_left_out,
        "the final masks alone already disagree at the foot, so the test shows nothing"
    );
}

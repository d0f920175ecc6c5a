//! End-to-end: `easyhec synth` then `easyhec solve`, bad input.

mod common;

use std::path::Path;
use std::process::Command;

use easyhec::geometry::{from_rows, rotation_error_deg, translation_error_mm};
use easyhec::interop::ExportFormat;
use easyhec::run::GroundTruth;
use easyhec::run::ResultFile;

fn synth(out: &Path, extra: &[&str]) {
    let args: Vec<&str> = ["--views", "3", "--seed", "5"]
        .iter()
        .chain(extra)
        .copied()
        .collect();
    common::synth_run(out, "xarm6", &args);
}

fn solve(run: &Path, extra: &[&str]) -> std::process::Output {
    common::solve_run(run, extra)
}

fn assert_ok(out: &std::process::Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The run's result is within 0.15° / 1.5 mm of its ground truth.
fn assert_near_truth(run: &Path, context: &str) {
    let (rot, trans) = errors(run);
    assert!(
        rot < 0.15 && trans < 1.5,
        "{context}: error {rot:.4} deg {trans:.3} mm"
    );
}

/// The true `camera_from_base` of a synthetic run.
fn truth_of(run: &Path) -> nalgebra::Isometry3<f64> {
    let truth: GroundTruth =
        serde_json::from_str(&std::fs::read_to_string(run.join("ground_truth.json")).unwrap())
            .unwrap();
    from_rows(&truth.camera_from_base).unwrap()
}

fn errors(run: &Path) -> (f64, f64) {
    let result = ResultFile::read(&run.join("result.json")).unwrap();
    let t = truth_of(run);
    (
        rotation_error_deg(&result.camera_from_base(), &t),
        translation_error_mm(&result.camera_from_base(), &t),
    )
}

#[test]
fn synth_then_solve_recovers_the_camera() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    synth(&run, &[]);
    let out = solve(
        &run,
        &["--overlays", dir.path().join("ov").to_str().unwrap()],
    );
    assert_ok(&out);
    assert_near_truth(&run, "synthetic run");
    let result = ResultFile::read(&run.join("result.json")).unwrap();
    assert_eq!(result.views_used, vec![0, 1, 2]);
    assert!(
        result.per_view.iter().all(|v| v.iou > 0.95),
        "{:?}",
        result.per_view
    );
    let u = result.uncertainty.unwrap();
    assert!(
        u.rotation_deg.iter().all(|&s| s > 0.0 && s < 0.5)
            && u.translation_mm.iter().all(|&s| s > 0.0 && s < 5.0),
        "{u:?}"
    );
    // The centre bound and the covariance it comes from are written, and agree: the bound
    // exceeds the largest 1-sigma of the centre (its covariance has the same eigenvalues as
    // the translation block of the increment's).
    let bound = u.camera_centre_95_mm.expect("a centre bound");
    let c = u.covariance.expect("a covariance");
    let largest = (0..3).map(|k| c[k][k]).fold(0.0, f64::max).sqrt() * 1000.0;
    assert!(
        bound > largest && bound < 10.0 * largest,
        "bound {bound} mm, largest sigma {largest} mm"
    );
    for i in 0..3 {
        let png = image::open(dir.path().join(format!("ov/{i:03}.overlay.png")))
            .unwrap()
            .to_rgb8();
        assert_eq!((png.width(), png.height()), (640, 480));
        // Agreement colour dominates a converged overlay.
        let green = png
            .pixels()
            .filter(|p| p.0[1] > p.0[0] + 40 && p.0[1] > p.0[2] + 40)
            .count();
        assert!(green > 2000, "view {i}: only {green} agreeing pixels");
    }
}

/// The model-error floor is added to the reported covariance, per camera axis: each 1-sigma
/// of a solve with the floor is the root sum of squares of the floor and the solve's own. The
/// translation floor is on the camera centre (the increment's translation), so it adds to the
/// reported translation as is; a rotation floor would also move it through the lever arm.
#[test]
fn the_model_error_floor_adds_to_each_reported_axis() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    synth(&run, &[]);
    let uncertainty = |out: &str, extra: &[&str]| {
        let path = dir.path().join(out);
        let mut args = vec!["--out", path.to_str().unwrap()];
        args.extend_from_slice(extra);
        assert_ok(&solve(&run, &args));
        ResultFile::read(&path).unwrap().uncertainty.unwrap()
    };
    let own = uncertainty("own.json", &[]);
    let rotation = uncertainty("rotation.json", &["--model-floor-rotation-deg", "0.2"]);
    let translation = uncertainty("translation.json", &["--model-floor-translation-mm", "3"]);
    let pairs = own
        .rotation_deg
        .iter()
        .zip(rotation.rotation_deg)
        .map(|(a, b)| (*a, b, 0.2))
        .chain(
            own.translation_mm
                .iter()
                .zip(translation.translation_mm)
                .map(|(a, b)| (*a, b, 3.0)),
        );
    for (k, (without, with, floor)) in pairs.enumerate() {
        let expected = without.hypot(floor);
        assert!(
            (with - expected).abs() < 0.05 * expected,
            "axis {k}: {with} with the floor, {without} without, floor {floor}"
        );
    }
    let centre = |u: &easyhec::run::UncertaintyEntry| u.camera_centre_95_mm.unwrap();
    assert!(centre(&translation) > centre(&own) + 3.0);
}

#[test]
fn synth_is_deterministic() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    synth(&a, &[]);
    synth(&b, &[]);
    for f in [
        "run.json",
        "ground_truth.json",
        "views/000.mask.png",
        "views/002.mask.png",
    ] {
        assert_eq!(
            std::fs::read(a.join(f)).unwrap(),
            std::fs::read(b.join(f)).unwrap(),
            "{f} differs"
        );
    }
}

#[test]
fn distorted_run_solves_like_an_undistorted_one() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    synth(&run, &["--distortion=-0.25,0.08,0.001,-0.0008,-0.01"]);
    let out = solve(&run, &[]);
    assert_ok(&out);
    assert_near_truth(&run, "distorted run");
}

#[test]
fn explore_and_random_select_distinct_views_from_the_pool() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    common::synth_run(&run, "xarm6", &["--views", "8", "--seed", "9"]);
    for select in ["explore", "random"] {
        assert_ok(&solve(&run, &["--views", "3", "--select", select]));
        let result = ResultFile::read(&run.join("result.json")).unwrap();
        assert_eq!(result.views_used[0], 0, "{select} starts from view 0");
        let mut used = result.views_used.clone();
        used.sort_unstable();
        used.dedup();
        assert!(
            used.len() == result.views_used.len() && (2..=3).contains(&used.len()),
            "{select}: {:?}",
            result.views_used
        );
        assert!(!result.stop_reason.is_empty());
        assert_eq!(
            result.timings_s.contains_key("explore"),
            select == "explore"
        );
        assert_near_truth(&run, select);
    }
    // Random selection is seeded.
    let seeded_random = |out: &str| {
        let out = dir.path().join(out);
        let args = ["--views", "3", "--select", "random", "--seed", "4", "--out"];
        solve(&run, &[&args[..], &[out.to_str().unwrap()]].concat())
    };
    let a = seeded_random("a.json");
    let b = seeded_random("b.json");
    assert!(a.status.success() && b.status.success());
    let (ra, rb) = (
        ResultFile::read(&dir.path().join("a.json")).unwrap(),
        ResultFile::read(&dir.path().join("b.json")).unwrap(),
    );
    assert_eq!(ra.views_used, rb.views_used);
}

#[test]
fn no_initial_guess_is_found_automatically() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    synth(&run, &["--no-initial-guess"]);
    let run_json = std::fs::read_to_string(run.join("run.json")).unwrap();
    assert!(!run_json.contains("initial_guess"));
    let out = solve(&run, &[]);
    assert_ok(&out);
    assert!(String::from_utf8_lossy(&out.stderr).contains("automatic initialisation"));
    assert_near_truth(&run, "without a guess");
}

/// `--initial-guess FILE` starts a run that has no guess of its own from another file's
/// `camera_from_base` (here the truth moved about 3° and 5 cm), leaving run.json unchanged; the
/// solve lands on the truth without the automatic initialisation.
#[test]
fn the_initial_guess_can_come_from_a_file() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    synth(&run, &["--no-initial-guess"]);
    let run_json = std::fs::read_to_string(run.join("run.json")).unwrap();
    let off = easyhec::geometry::exp_se3(&easyhec::geometry::Twist::new(
        0.04,
        -0.03,
        0.02,
        1.5f64.to_radians(),
        (-2.0f64).to_radians(),
        2.0f64.to_radians(),
    ));
    let guess = off * truth_of(&run);
    let file = dir.path().join("guess.json");
    let rows = easyhec::geometry::to_rows(&guess);
    std::fs::write(
        &file,
        serde_json::json!({ "camera_from_base": rows }).to_string(),
    )
    .unwrap();
    let out = solve(&run, &["--initial-guess", file.to_str().unwrap()]);
    assert_ok(&out);
    assert!(!String::from_utf8_lossy(&out.stderr).contains("automatic initialisation"));
    assert_eq!(
        std::fs::read_to_string(run.join("run.json")).unwrap(),
        run_json
    );
    assert_near_truth(&run, "from --initial-guess");
}

#[test]
fn failed_automatic_initialisation_is_reported_not_returned() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    synth(&run, &["--no-initial-guess"]);
    // Masks of something that is not this robot: a filled disc in a corner.
    for i in 0..3 {
        let img = image::GrayImage::from_fn(640, 480, |u, v| {
            let (du, dv) = (f64::from(u) - 80.0, f64::from(v) - 80.0);
            image::Luma([if du * du + dv * dv < 900.0 { 255 } else { 0 }])
        });
        img.save(run.join(format!("views/{i:03}.mask.png")))
            .unwrap();
    }
    let out = solve(&run, &[]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success(),
        "a pose was returned for masks of a disc"
    );
    assert!(
        stderr.contains("automatic initialisation failed") && stderr.contains("initial_guess"),
        "{stderr}"
    );
    assert!(!run.join("result.json").exists());
}

/// Views whose joints were read at the wrong moment are left out, named, and the pose comes
/// from the views that agree; `--keep-all-views` keeps them (and still warns).
#[test]
fn views_whose_joints_do_not_match_their_images_are_left_out() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    common::synth_run(&run, "xarm6", &["--views", "5", "--seed", "5"]);
    let path = run.join("run.json");
    let mut doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    for (view, delta) in [(1usize, 0.35), (3, -0.3)] {
        let joints = doc["views"][view]["joints"].as_array_mut().unwrap();
        for j in [1usize, 2] {
            let v = joints[j].as_f64().unwrap() + delta;
            joints[j] = serde_json::json!(v);
        }
    }
    std::fs::write(&path, serde_json::to_string_pretty(&doc).unwrap()).unwrap();

    let out = solve(&run, &[]);
    assert_ok(&out);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("views 1 (IoU") && stderr.contains("3 (IoU") && stderr.contains("left out"),
        "{stderr}"
    );
    let result = ResultFile::read(&run.join("result.json")).unwrap();
    assert_eq!(result.views_used, vec![0, 2, 4]);
    assert!(result.stop_reason.contains("left out 2 inconsistent views"));
    assert_near_truth(&run, "consensus of the consistent views");

    // Kept, the two bad views pull the mean IoU under the poor-fit line: the solve fails and
    // the consensus result stays as it was.
    let before = std::fs::read(run.join("result.json")).unwrap();
    let out = solve(&run, &["--keep-all-views"]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("poor fit") && stderr.contains("--allow-poor-fit"),
        "{stderr}"
    );
    assert_eq!(std::fs::read(run.join("result.json")).unwrap(), before);

    let out = solve(&run, &["--keep-all-views", "--allow-poor-fit"]);
    assert_ok(&out);
    let result = ResultFile::read(&run.join("result.json")).unwrap();
    assert_eq!(result.views_used, vec![0, 1, 2, 3, 4]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("views [1, 3] fit poorly"), "{stderr}");
}

/// Every flag with fixed choices lists them in `--help`, and a wrong one is refused with them.
#[test]
fn help_lists_every_choice_flags_values() {
    let help = |args: &[&str]| {
        let out = Command::new(common::easyhec_bin())
            .args(args)
            .arg("--help")
            .output()
            .expect("easyhec runs");
        assert_ok(&out);
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let expected: &[(&[&str], &[&str])] = &[
        (
            &["solve"],
            &[
                "first", "explore", "random", "lm", "adam", "cpu", "wgpu", "auto", "builtin",
            ],
        ),
        (&["calibrate"], &["cpu", "wgpu", "auto"]),
        (
            &["bench", "loop"],
            &["explore", "random", "information", "variance"],
        ),
        (&["bench", "segment"], &["easy", "hard"]),
        (
            &["bench", "coverage"],
            &["standard", "segmenter", "blurred", "none"],
        ),
        (
            &["bench", "accuracy"],
            &["standard", "segmenter", "blurred", "none"],
        ),
    ];
    let formats: Vec<String> = ExportFormat::ALL.map(ExportFormat::name).into();
    let formats: Vec<&str> = formats.iter().map(String::as_str).collect();
    let export: &[&str] = &["export"];
    for (command, values) in expected.iter().chain([(export, formats.as_slice())].iter()) {
        let text = help(command);
        assert!(text.contains("ossible values"), "{command:?}: {text}");
        for v in *values {
            assert!(
                text.contains(&format!("- {v}:"))
                    || text.contains(&format!(" {v},"))
                    || text.contains(&format!(" {v}]")),
                "{command:?} --help does not list {v}:\n{text}"
            );
        }
    }
    let out = Command::new(common::easyhec_bin())
        .args(["export", "result.json", "--format", "yaml"])
        .output()
        .expect("easyhec runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(
        stderr.contains(&format!("allowed: {}", ExportFormat::names()))
            && stderr.contains("easy-handeye-ros1"),
        "{stderr}"
    );
}

/// `easyhec completions bash` is a script bash accepts that completes subcommands and flags;
/// `--version` names the features built in.
#[test]
fn completions_and_version() {
    let run = |args: &[&str]| {
        let out = Command::new(common::easyhec_bin())
            .args(args)
            .output()
            .expect("easyhec runs");
        assert_ok(&out);
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let script = run(&["completions", "bash"]);
    for word in [
        "solve",
        "calibrate",
        "--segmenter",
        "--ignore-masks",
        "easy-handeye",
    ] {
        assert!(script.contains(word), "the bash completion lacks {word}");
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("easyhec.bash");
    std::fs::write(&path, &script).unwrap();
    let syntax = Command::new("bash").arg("-n").arg(&path).output().unwrap();
    assert_ok(&syntax);
    for shell in ["zsh", "fish"] {
        assert!(run(&["completions", shell]).contains("solve"), "{shell}");
    }
    let version = run(&["--version"]);
    assert!(
        version.starts_with(&format!("easyhec {}", env!("CARGO_PKG_VERSION")))
            && version.contains("(features: ")
            && version.contains("sim"),
        "{version}"
    );
}

/// `easyhec solve` with the given log environment and flags: (success, stderr lines).
fn solve_logged(run: &Path, rust_log: Option<&str>, extra: &[&str]) -> (bool, Vec<String>) {
    let mut cmd = Command::new(common::easyhec_bin());
    cmd.arg("solve").arg(run).args(extra).env_remove("RUST_LOG");
    cmd.env_remove("EASYHEC_LOG_FORMAT");
    if let Some(spec) = rust_log {
        cmd.env("RUST_LOG", spec);
    }
    let out = cmd.output().expect("easyhec runs");
    let lines = String::from_utf8_lossy(&out.stderr)
        .lines()
        .map(str::to_string)
        .collect();
    (out.status.success(), lines)
}

#[test]
fn diagnostics_are_levelled_by_rust_log_and_the_flags() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    synth(&run, &[]);
    let is_debug = |l: &String| l.starts_with("debug: ");
    // Default: info lines only, as short as a plain program's output.
    let (ok, default) = solve_logged(&run, None, &[]);
    assert!(ok, "{default:?}");
    assert!(!default.is_empty() && default.len() <= 12, "{default:?}");
    assert!(!default.iter().any(is_debug), "{default:?}");
    // RUST_LOG=debug: the solver's per-level lines, marked as debug.
    let (ok, debug) = solve_logged(&run, Some("debug"), &[]);
    assert!(ok, "{debug:?}");
    let levels = debug
        .iter()
        .filter(|l| l.starts_with("debug: level "))
        .count();
    assert!(levels >= 3, "no per-level solver lines: {debug:?}");
    assert!(debug.len() > default.len(), "{debug:?}");
    // -v does the same without RUST_LOG; -q leaves warnings and errors only; a flag beats
    // RUST_LOG.
    let (_, verbose) = solve_logged(&run, None, &["-v"]);
    assert!(verbose.iter().any(is_debug), "{verbose:?}");
    let (ok, quiet) = solve_logged(&run, Some("debug"), &["--quiet"]);
    assert!(ok && quiet.is_empty(), "{quiet:?}");
    // JSON: every line is an object with a level and a target.
    let (ok, json) = solve_logged(&run, Some("easyhec=debug"), &["--log-format", "json"]);
    assert!(ok && !json.is_empty(), "{json:?}");
    for line in &json {
        let v: serde_json::Value =
            serde_json::from_str(line).unwrap_or_else(|e| panic!("not JSON ({e}): {line}"));
        assert!(v["level"].is_string() && v["target"].is_string(), "{line}");
    }
    assert!(json.iter().any(|l| l.contains("\"DEBUG\"")), "{json:?}");
    // A RUST_LOG that does not parse is one warning, and the default applies.
    let (ok, bad) = solve_logged(&run, Some("easyhec=loud"), &[]);
    assert!(ok, "{bad:?}");
    assert!(
        bad[0].starts_with("warning: RUST_LOG=") && bad.len() == default.len() + 1,
        "{bad:?}"
    );
}

/// `solve` shows a spinner on a terminal (a pseudo-terminal from util-linux `script`) and
/// nothing but plain lines when its output is piped.
#[test]
fn progress_shows_on_a_terminal_only() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    synth(&run, &[]);
    let (ok, piped) = solve_logged(&run, None, &[]);
    assert!(ok, "{piped:?}");
    assert!(
        piped
            .iter()
            .all(|l| !l.contains('\r') && !l.contains('\x1b')),
        "control characters in piped output: {piped:?}"
    );
    let line = format!(
        "{} solve {}",
        common::easyhec_bin().display(),
        run.display()
    );
    let tty = Command::new("script")
        .args(["-qfec", &line, "/dev/null"])
        .env_remove("RUST_LOG")
        .output();
    let Ok(tty) = tty else {
        eprintln!("SKIPPED: no `script` (util-linux) to make a pseudo-terminal");
        return;
    };
    let text = String::from_utf8_lossy(&tty.stdout);
    assert!(tty.status.success(), "{text}");
    assert!(
        text.contains("solve [") && text.contains("\x1b[2K"),
        "no spinner on a terminal: {text:?}"
    );
    // --quiet hides it there too.
    let quiet = Command::new("script")
        .args(["-qfec", &format!("{line} --quiet"), "/dev/null"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&quiet.stdout);
    assert!(!text.contains("solve ["), "{text:?}");
}

//! How the command line ends when its output or its run is cut short: a reader that closes
//! the pipe, a full or closed standard output, a signal during an import, and the values it
//! writes for other tools to read (YAML frame names, UTF-8 paths).

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// A result file for `export`, written by a quick synthetic solve.
fn result_file(dir: &Path) -> PathBuf {
    let run = dir.join("run");
    common::synth_run(
        &run,
        "xarm6",
        &[
            "--views", "2", "--width", "320", "--height", "240", "--focal", "300",
        ],
    );
    let out = common::solve_run(&run, &[]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    run.join("result.json")
}

fn export(result: &Path, extra: &[&str]) -> Command {
    let mut c = Command::new(common::easyhec_bin());
    c.args(["export"]).arg(result).args(extra);
    c
}

fn stderr_of(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn output_that_cannot_be_written_ends_in_one_line_or_quietly() {
    let dir = tempfile::tempdir().unwrap();
    let result = result_file(dir.path());
    let args = ["--format", "opencv"];

    // A reader that already closed the pipe: a quiet end, as Unix tools end, no panic.
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let out = export(&result, &args)
        .stdout(Stdio::from(writer))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(141), "{}", stderr_of(&out));
    assert!(stderr_of(&out).is_empty(), "{}", stderr_of(&out));

    // A full device: one error line and exit 1, never the panic's 101.
    let full = std::fs::File::create("/dev/full").unwrap();
    let out = export(&result, &args)
        .stdout(Stdio::from(full))
        .output()
        .unwrap();
    let err = stderr_of(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.starts_with("error: standard output") && err.lines().count() == 1,
        "{err}"
    );

    // Standard output closed (`>&-`): the result went nowhere, so it is no success.
    let line = format!(
        "exec {:?} export {:?} --format opencv >&-",
        common::easyhec_bin(),
        result
    );
    let out = Command::new("sh").args(["-c", &line]).output().unwrap();
    let err = stderr_of(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("standard output is closed"), "{err}");
}

#[test]
fn frame_names_yaml_would_read_as_other_types_are_quoted() {
    let dir = tempfile::tempdir().unwrap();
    let result = result_file(dir.path());
    for format in ["easy-handeye", "easy-handeye-ros1"] {
        let out = export(
            &result,
            &[
                "--format",
                format,
                "--frame-id",
                "on",
                "--child-frame-id",
                "null",
            ],
        )
        .output()
        .unwrap();
        assert!(out.status.success(), "{}", stderr_of(&out));
        let text = String::from_utf8(out.stdout).unwrap();
        assert!(text.contains("robot_base_frame: 'on'"), "{format}: {text}");
        assert!(
            text.contains("tracking_base_frame: 'null'"),
            "{format}: {text}"
        );
    }
    // An ordinary name stays plain.
    let out = export(
        &result,
        &["--format", "easy-handeye-ros1", "--frame-id", "world"],
    )
    .output()
    .unwrap();
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("robot_base_frame: world\n"), "{text}");
}

#[test]
fn a_path_that_is_not_utf8_is_refused_where_it_would_be_written() {
    use std::os::unix::ffi::OsStrExt;
    let dir = tempfile::tempdir().unwrap();
    let name = std::ffi::OsStr::from_bytes(b"robot-\xff.urdf");
    let urdf = dir.path().join(name);
    std::fs::copy(common::robot_urdf("xarm6"), &urdf).unwrap();
    let out = Command::new(common::easyhec_bin())
        .args(["synth", "--views", "1", "--robot"])
        .arg(&urdf)
        .arg("--out")
        .arg(dir.path().join("made"))
        .output()
        .unwrap();
    let err = stderr_of(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("not UTF-8") && err.contains("--urdf"), "{err}");
    assert!(!dir.path().join("made").exists(), "nothing written");
}

#[test]
fn synth_force_replaces_a_run_whole() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("made");
    let small = ["--width", "320", "--height", "240", "--focal", "300"];
    common::synth_run(&out, "xarm6", &[&["--views", "3"][..], &small].concat());
    std::fs::write(out.join("stale.txt"), "from before").unwrap();
    let again = Command::new(common::easyhec_bin())
        .args(["synth", "--views", "1"])
        .args(small)
        .arg("--robot")
        .arg(common::robot_urdf("xarm6"))
        .arg("--out")
        .arg(&out)
        .arg("--force")
        .output()
        .unwrap();
    assert!(again.status.success(), "{}", stderr_of(&again));
    assert!(!out.join("stale.txt").exists());
    assert!(
        !out.join("views/001.mask.png").exists(),
        "no mask of the old run left"
    );
    assert!(out.join("views/000.mask.png").is_file());
}

/// EasyHeC's offline layout with `n` views, large enough that the import takes a while.
fn big_import_source(src: &Path, n: usize) {
    let run = src.with_extension("run");
    common::synth_run(
        &run,
        "xarm6",
        &[
            "--views",
            &n.to_string(),
            "--width",
            "1280",
            "--height",
            "960",
            "--focal",
            "1100",
            "--images",
            "easy",
        ],
    );
    common::write_easyhec_source(&run, src, true);
}

#[test]
fn a_signal_during_an_import_leaves_no_staging_folder() {
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("src");
    big_import_source(&src, 48);
    let target = dir.path().join("out").join("imported");
    let mut child = Command::new(common::easyhec_bin())
        .args(["import", "easyhec"])
        .arg(&src)
        .arg("--out")
        .arg(&target)
        .arg("--urdf")
        .arg(common::robot_urdf("xarm6"))
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let parent = dir.path().join("out");
    let staging = || {
        std::fs::read_dir(&parent)
            .ok()
            .into_iter()
            .flatten()
            .flatten()
            .any(|e| {
                e.file_name()
                    .to_string_lossy()
                    .starts_with(".easyhec-import-")
            })
    };
    let started = Instant::now();
    while !staging() {
        assert!(
            child.try_wait().unwrap().is_none(),
            "the import ended before it staged"
        );
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "no staging folder appeared"
        );
        std::thread::sleep(Duration::from_millis(2));
    }
    // Straight away (a `kill` process would take longer than the import has left).
    // SAFETY: sends SIGTERM to our own child, which has not been waited for yet.
    let sent = unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) };
    assert_eq!(sent, 0);
    let ended = child.wait().unwrap();
    assert_eq!(ended.code(), Some(143), "{ended:?}");
    assert!(
        !staging(),
        "a staging folder was left in {}",
        parent.display()
    );
    // Nothing half-made: either no run, or (a signal that landed during the final rename,
    // which the handler waits for) the whole run.
    if target.exists() {
        let run: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(target.join("run.json")).unwrap())
                .unwrap();
        assert_eq!(run["views"].as_array().unwrap().len(), 48);
        assert!(target.join("views/047.mask.png").is_file());
    }
}

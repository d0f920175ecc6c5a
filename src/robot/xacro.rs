//! Robot descriptions written as xacro, as vendors ship them for ROS 2: expanded to URDF by
//! the `xacro` tool (PyPI `xacro`), run as a child process with the configured arguments.
//! Expanding in-process would mean a second, subtly different xacro; the tool is the
//! reference every ROS launch file uses.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::error::{Error, Result};
use crate::io::{read_text_input, MAX_TEXT_INPUT_BYTES};

/// A xacro expansion that takes longer is stuck (an include loop, a prompt).
const EXPAND_TIMEOUT: Duration = Duration::from_secs(60);

/// More arguments than any vendor description takes.
const MAX_ARGS: usize = 64;

/// Longest argument value, bytes.
const MAX_ARG_BYTES: usize = 4096;

/// The URDF text of a description: the file itself, or for `*.xacro` the `xacro` tool's
/// expansion with `args` as `name:=value`. `args` on a plain URDF is an error, not ignored.
pub(super) fn urdf_text(path: &Path, args: &BTreeMap<String, String>) -> Result<String> {
    let is_xacro = path.extension().and_then(|e| e.to_str()) == Some("xacro");
    if !is_xacro {
        if let Some(name) = args.keys().next() {
            return Err(Error::input(
                path,
                format!("robot.xacro_args.{name}"),
                "is set, but the description is not a .xacro file",
            ));
        }
        return read_text_input(path);
    }
    check_args(path, args)?;
    // Read first: the same size bound and the same one-line error for a missing file.
    read_text_input(path)?;
    expand(path, args)
}

/// Names are xacro identifiers; values are single lines within [`MAX_ARG_BYTES`].
fn check_args(path: &Path, args: &BTreeMap<String, String>) -> Result<()> {
    if args.len() > MAX_ARGS {
        return Err(Error::input(
            path,
            "robot.xacro_args",
            format!("has {} entries; allowed: at most {MAX_ARGS}", args.len()),
        ));
    }
    for (name, value) in args {
        let field = format!("robot.xacro_args.{name}");
        let identifier = name
            .chars()
            .next()
            .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
            && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
        if !identifier {
            return Err(Error::input(
                path,
                "robot.xacro_args",
                format!("has the name {name:?}; allowed: letters, digits and '_', not starting with a digit"),
            ));
        }
        if value.len() > MAX_ARG_BYTES || value.chars().any(|c| c.is_control()) {
            return Err(Error::input(
                path,
                field,
                format!("allowed: one line of at most {MAX_ARG_BYTES} bytes"),
            ));
        }
    }
    Ok(())
}

/// Runs `xacro PATH name:=value…`, bounded in time and output.
fn expand(path: &Path, args: &BTreeMap<String, String>) -> Result<String> {
    let mut child = Command::new("xacro")
        .arg(path)
        .args(args.iter().map(|(k, v)| format!("{k}:={v}")))
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| {
            Error::input(
                path,
                "robot.urdf",
                format!("is a xacro file, and the xacro tool could not start ({e}): install it with `python3 -m pip install xacro`"),
            )
        })?;
    let limit = MAX_TEXT_INPUT_BYTES;
    let mut stdout = child.stdout.take().expect("piped");
    let mut stderr = child.stderr.take().expect("piped");
    let out = std::thread::spawn(move || {
        let mut buf = Vec::new();
        let read = (&mut stdout).take(limit + 1).read_to_end(&mut buf);
        read.map(|_| buf)
    });
    let err = std::thread::spawn(move || {
        let mut buf = String::new();
        let _ = (&mut stderr).take(64 * 1024).read_to_string(&mut buf);
        buf
    });
    let started = Instant::now();
    let status = loop {
        match child.try_wait() {
            Ok(Some(status)) => break status,
            Ok(None) if started.elapsed() < EXPAND_TIMEOUT => {
                std::thread::sleep(Duration::from_millis(20))
            }
            Ok(None) | Err(_) => {
                let _ = child.kill();
                let _ = child.wait();
                return Err(Error::input(
                    path,
                    "robot.urdf",
                    format!("xacro did not finish within {} s", EXPAND_TIMEOUT.as_secs()),
                ));
            }
        }
    };
    let stdout = out.join().ok().and_then(|r| r.ok()).unwrap_or_default();
    let stderr = err.join().unwrap_or_default();
    if !status.success() {
        let reason = stderr
            .lines()
            .map(str::trim)
            .rfind(|l| !l.is_empty())
            .unwrap_or("no message");
        return Err(Error::input(
            path,
            "robot.urdf",
            format!("xacro failed ({status}): {reason}"),
        ));
    }
    if stdout.len() as u64 > limit {
        return Err(Error::input(
            path,
            "robot.urdf",
            format!("expands to more than {limit} bytes"),
        ));
    }
    String::from_utf8(stdout)
        .map_err(|_| Error::input(path, "robot.urdf", "xacro's expansion is not UTF-8"))
}

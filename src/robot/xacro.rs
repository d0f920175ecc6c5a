//! Robot descriptions written as xacro, as vendors ship them for ROS 2: expanded to URDF by
//! the `xacro` tool (PyPI `xacro`), run as a child process with the configured arguments.
//! Expanding in-process would mean a second, subtly different xacro; the tool is the
//! reference every ROS launch file uses.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use super::packages::{LazyPackages, PackageIndex};
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
pub(super) fn urdf_text(
    path: &Path,
    args: &BTreeMap<String, String>,
    packages: &LazyPackages<'_>,
) -> Result<String> {
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
    let resolver = write_resolver(path, packages.get())?;
    expand(path, args, resolver.path())
}

/// Our `ament_index_python` stand-in (`xacro_resolver/`), with the package table it answers
/// from, in a temporary folder that must outlive the xacro child.
fn write_resolver(path: &Path, packages: &PackageIndex) -> Result<tempfile::TempDir> {
    let io =
        |e: std::io::Error| Error::io(path, format!("cannot prepare xacro's package lookups: {e}"));
    let dir = tempfile::Builder::new()
        .prefix("easyhec-xacro-")
        .tempdir()
        .map_err(io)?;
    let module = dir.path().join("ament_index_python");
    std::fs::create_dir(&module).map_err(io)?;
    std::fs::write(
        module.join("__init__.py"),
        include_str!("xacro_resolver/__init__.py"),
    )
    .map_err(io)?;
    std::fs::write(
        module.join("packages.py"),
        include_str!("xacro_resolver/packages.py"),
    )
    .map_err(io)?;
    let table = serde_json::to_vec(&packages.to_json()).map_err(|e| io(e.into()))?;
    std::fs::write(module.join("packages.json"), table).map_err(io)?;
    Ok(dir)
}

/// `PYTHONPATH` with `first` ahead of what the environment already has.
fn python_path(first: &Path) -> std::ffi::OsString {
    let mut dirs = vec![first.to_path_buf()];
    if let Some(old) = std::env::var_os("PYTHONPATH") {
        dirs.extend(std::env::split_paths(&old));
    }
    std::env::join_paths(dirs).unwrap_or_else(|_| first.as_os_str().to_owned())
}

/// The cause of a failed expansion, from xacro's stderr: its `error:` line (xacro prints the
/// cause first, then where it happened: `when processing file: …`), else an XML parser's
/// line, else the last line that is not a location. Exception wrapping (`<class '…'>: `) and
/// a message xacro repeats are dropped.
fn xacro_reason(stderr: &str) -> String {
    const LOCATIONS: [&str; 7] = [
        "when ",
        "in file:",
        "included from:",
        "instantiated from:",
        "Check that:",
        "- ",
        "warning: ",
    ];
    let lines: Vec<&str> = stderr.lines().map(str::trim).collect();
    let line = lines
        .iter()
        .find_map(|l| l.strip_prefix("error: "))
        .or_else(|| {
            lines
                .iter()
                .copied()
                .find(|l| l.contains("XML parsing error:"))
        })
        .or_else(|| {
            lines
                .iter()
                .copied()
                .rfind(|l| !l.is_empty() && !LOCATIONS.iter().any(|p| l.starts_with(p)))
        })
        .unwrap_or("no message")
        .trim();
    let line = match (line.starts_with("<class '"), line.split_once("'>: ")) {
        (true, Some((_, rest))) => rest,
        _ => line,
    };
    let half = line.len() / 2;
    let repeated = line.len() % 2 == 1
        && line.is_char_boundary(half)
        && line[half..].starts_with(' ')
        && line[..half] == line[half + 1..];
    let line = if repeated { &line[..half] } else { line };
    line.trim_matches('"').to_string()
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

/// How much of xacro's stderr is kept: the end, where its error is.
const STDERR_TAIL_BYTES: usize = 64 * 1024;

/// Reads `pipe` to its end, so the child never blocks on a full pipe, keeping at most the
/// first `keep` bytes (output) or, with `tail`, the last ones (a log, whose end holds the
/// error). Returns them and the total byte count.
fn drain_keeping(mut pipe: impl Read, keep: usize, tail: bool) -> (Vec<u8>, usize) {
    let mut kept = Vec::new();
    let mut total = 0usize;
    let mut chunk = [0u8; 8192];
    while let Ok(n) = pipe.read(&mut chunk) {
        if n == 0 {
            break;
        }
        total += n;
        if tail {
            kept.extend_from_slice(&chunk[..n]);
            // Trimmed in halves, so each byte moves a bounded number of times.
            if kept.len() > 2 * keep {
                kept.drain(..kept.len() - keep);
            }
        } else if kept.len() < keep {
            let room = (keep - kept.len()).min(n);
            kept.extend_from_slice(&chunk[..room]);
        }
    }
    if kept.len() > keep {
        kept.drain(..kept.len() - keep);
    }
    (kept, total)
}

/// Runs `xacro PATH name:=value…`, bounded in time and output.
fn expand(path: &Path, args: &BTreeMap<String, String>, resolver: &Path) -> Result<String> {
    let mut child = Command::new("xacro")
        .arg(path)
        .env("PYTHONPATH", python_path(resolver))
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
    let limit = MAX_TEXT_INPUT_BYTES as usize;
    let stdout = child.stdout.take().expect("piped");
    let stderr = child.stderr.take().expect("piped");
    let out = std::thread::spawn(move || drain_keeping(stdout, limit, false));
    let err = std::thread::spawn(move || drain_keeping(stderr, STDERR_TAIL_BYTES, true));
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
    let (stdout, stdout_bytes) = out.join().unwrap_or_default();
    let (stderr, _) = err.join().unwrap_or_default();
    if stdout_bytes > limit {
        return Err(Error::input(
            path,
            "robot.urdf",
            format!("expands to more than {limit} bytes"),
        ));
    }
    if !status.success() {
        let reason = xacro_reason(&String::from_utf8_lossy(&stderr));
        return Err(Error::input(
            path,
            "robot.urdf",
            format!("xacro failed ({status}): {reason}"),
        ));
    }
    String::from_utf8(stdout)
        .map_err(|_| Error::input(path, "robot.urdf", "xacro's expansion is not UTF-8"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reason_is_xacros_cause_not_its_location() {
        let cases = [
            (
                "error: <class 'ament_index_python.packages.PackageNotFoundError'>: package 'x' not found; looked in y package 'x' not found; looked in y\nwhen processing file: a/cell.urdf.xacro\n",
                "package 'x' not found; looked in y",
            ),
            (
                "error: name 'prefx' is not defined \nwhen evaluating expression 'prefx'\nwhen instantiating macro: acme_arm (m.xacro)\nin file: cell.urdf.xacro\n",
                "name 'prefx' is not defined",
            ),
            (
                "warning: xacro:include: unknown attribute(s): bogus\nwhen processing file: w.xacro\nerror: Undefined parameters [limits_file]\nin file: w.xacro\n",
                "Undefined parameters [limits_file]",
            ),
            (
                "XML parsing error: mismatched tag: line 2, column 2\nwhen processing file: b.xacro\nCheck that:\n - Your XML is well-formed\n",
                "XML parsing error: mismatched tag: line 2, column 2",
            ),
            ("\n\n", "no message"),
        ];
        for (stderr, want) in cases {
            assert_eq!(xacro_reason(stderr), want, "{stderr}");
        }
    }

    #[test]
    fn draining_keeps_the_head_of_output_and_the_tail_of_a_log() {
        let data: Vec<u8> = (0..50_000u32).map(|i| (i % 251) as u8).collect();
        let (head, total) = drain_keeping(&data[..], 1000, false);
        assert_eq!((head.as_slice(), total), (&data[..1000], 50_000));
        let (tail, total) = drain_keeping(&data[..], 1000, true);
        assert_eq!((tail.as_slice(), total), (&data[49_000..], 50_000));
        let (all, _) = drain_keeping(&data[..10], 1000, true);
        assert_eq!(all, &data[..10]);
    }
}

//! Property checks of the fuzz targets for user-written inputs, `run_json` (a run's
//! `run.json`) and `cell_toml` (a cell config). For any bytes: no panic; every rejection is one
//! line; a run that parses survives a write-and-read round trip unchanged.
//!
//! Compiled into the fuzz targets and, through `#[path]`, into `tests/fuzz_inputs.rs`, which
//! replays `fuzz/seeds/<target>/` on stable Rust in the normal test run.

use std::path::Path;

/// The targets this file checks.
pub const TARGETS: &[&str] = &["run_json", "cell_toml"];

/// Dispatches to the target's check.
pub fn check(target: &str, data: &[u8]) {
    match target {
        "run_json" => run_json(data),
        "cell_toml" => cell_toml(data),
        other => panic!("unknown target {other}"),
    }
}

/// A rejection is one line that names the file.
fn one_line(e: &easyhec::error::Error, file: &str) {
    let text = e.to_string();
    assert!(!text.contains('\n'), "not one line: {text}");
    assert!(text.contains(file), "does not name {file}: {text}");
}

/// `run.json`: parse, round trip, then the content checks (paths against a folder that does
/// not exist, so nothing on this machine is read).
pub fn run_json(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = Path::new("fuzz-run/run.json");
    let file = match easyhec::run::RunFile::parse(text, path) {
        Ok(f) => f,
        Err(e) => return one_line(&e, "run.json"),
    };
    let written = serde_json::to_string(&file).expect("a parsed run serialises");
    let back = easyhec::run::RunFile::parse(&written, path).expect("a written run parses");
    assert_eq!(back, file, "round trip changed the run");
    if let Err(e) = file.check(path, Path::new("/nonexistent/easyhec-fuzz-run")) {
        one_line(&e, "run.json");
    }
}

/// A cell config: parse, then the one validation pass.
pub fn cell_toml(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = Path::new("fuzz-cell.toml");
    match easyhec::config::parse_config(text, path) {
        Ok(config) => {
            if let Err(e) = config.validate(path) {
                one_line(&e, "fuzz-cell.toml");
            }
        }
        Err(e) => one_line(&e, "fuzz-cell.toml"),
    }
}

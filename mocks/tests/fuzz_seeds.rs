//! Replays the fuzz seed corpora (`fuzz/seeds/<target>/`) and the inputs of crashes found and
//! fixed (`fuzz/regressions/<target>/`) through the fuzz targets' property checks, on stable
//! Rust as part of the normal test run; the checks are `fuzz/src/lib.rs`, compiled in here.

#[path = "../../fuzz/src/lib.rs"]
mod checks;

use std::path::{Path, PathBuf};

fn inputs(dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut files: Vec<PathBuf> = entries
        .map(|e| e.expect("readable folder entry").path())
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    files
}

#[test]
fn seeds_and_regressions_pass_the_fuzz_checks() {
    let fuzz = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz");
    let mut failures = Vec::new();
    for target in checks::TARGETS {
        let seeds = inputs(&fuzz.join("seeds").join(target));
        assert!(!seeds.is_empty(), "no seeds for fuzz target {target}");
        let regressions = inputs(&fuzz.join("regressions").join(target));
        for file in seeds.iter().chain(&regressions) {
            let data = std::fs::read(file).expect("readable input");
            if std::panic::catch_unwind(|| checks::check(target, &data)).is_err() {
                failures.push(file.display().to_string());
            }
        }
    }
    assert!(
        failures.is_empty(),
        "inputs failing their checks: {failures:?}"
    );
}

/// The checks do catch what they claim to: corrupted copies of a good packet either parse to
/// something that passes every property, or are refused, and never slip through as the
/// original; a stream cut differently yields the same frames.
#[test]
fn checks_run_on_edited_vectors() {
    let ping = [0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x03, 0x00, 0x01, 0x19, 0x4E];
    for i in 0..ping.len() {
        for bit in 0..8 {
            let mut v = ping.to_vec();
            v[i] ^= 1 << bit;
            checks::dynamixel(&v);
        }
    }
    let mut two = ping.to_vec();
    two.extend_from_slice(&[0x00, 0xFF, 0xFF, 0x01, 0x02, 0x01, 0xFB]);
    two.extend_from_slice(&ping);
    checks::dynamixel(&two);
    checks::feetech(&two);
    checks::xarm_reply(&two);
    checks::xarm_report(&two);
    checks::rtde(&two);
    checks::piper(&two);
}

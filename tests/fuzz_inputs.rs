//! Replays the seed corpora of the `run_json` and `cell_toml` fuzz targets
//! (`fuzz/seeds/<target>/`, plus every shipped config for `cell_toml`) and any recorded crash
//! inputs (`fuzz/regressions/<target>/`) through the targets' property checks, on stable Rust.

#[path = "../fuzz/src/inputs.rs"]
mod inputs;

use std::path::{Path, PathBuf};

fn files(dir: &Path, ext: Option<&str>) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut v: Vec<PathBuf> = entries
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_file() && ext.is_none_or(|x| p.extension().is_some_and(|e| e == x)))
        .collect();
    v.sort();
    v
}

#[test]
fn seeds_and_regressions_pass_the_input_fuzz_checks() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut failures = Vec::new();
    let mut count = 0;
    for target in inputs::TARGETS {
        let mut all = files(&root.join("fuzz/seeds").join(target), None);
        assert!(!all.is_empty(), "no seeds for {target}");
        all.extend(files(&root.join("fuzz/regressions").join(target), None));
        if *target == "cell_toml" {
            all.extend(files(&root.join("config"), Some("toml")));
        }
        for file in all {
            let data = std::fs::read(&file).unwrap();
            count += 1;
            if std::panic::catch_unwind(|| inputs::check(target, &data)).is_err() {
                failures.push(file.display().to_string());
            }
        }
    }
    println!("{count} inputs replayed");
    assert!(
        failures.is_empty(),
        "inputs failing their checks: {failures:?}"
    );
}

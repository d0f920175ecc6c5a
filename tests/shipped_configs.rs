//! Every shipped cell config parses to exactly what it parsed to when the fixture was made:
//! a change to a config table (a renamed key, a new default) cannot silently change what a
//! shipped file means. Regenerate after an intended change with
//! `UPDATE_SHIPPED_CONFIGS=1 cargo test --release --test shipped_configs` and review the diff.

mod common;

use std::collections::BTreeMap;

use easyhec::config::read_config;
use easyhec::config::SimCameraSettings;

/// Each config file's parse: its JSON form, or the one-line error it gives.
fn parsed() -> BTreeMap<String, serde_json::Value> {
    let mut out = BTreeMap::new();
    for entry in std::fs::read_dir(common::repo_root().join("config")).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        if !name.contains(".toml") {
            continue;
        }
        let value = match read_config(&path) {
            Ok(c) => serde_json::to_value(&c).unwrap(),
            Err(e) => serde_json::Value::String(format!("error: {e}")),
        };
        out.insert(name, value);
    }
    out
}

#[test]
fn every_shipped_config_parses_as_the_fixture_records() {
    let fixture = common::repo_root().join("tests/fixtures/shipped_configs.json");
    let now = parsed();
    if std::env::var_os("UPDATE_SHIPPED_CONFIGS").is_some() {
        let text = serde_json::to_string_pretty(&now).unwrap();
        std::fs::write(&fixture, text + "\n").unwrap();
    }
    let recorded: BTreeMap<String, serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(&fixture).unwrap()).unwrap();
    assert_eq!(
        now.keys().collect::<Vec<_>>(),
        recorded.keys().collect::<Vec<_>>(),
        "config files added or removed: regenerate the fixture"
    );
    for (name, value) in &now {
        assert!(!value.is_string(), "{name} no longer parses: {value}");
        assert_eq!(value, &recorded[name], "{name} parses differently");
    }
}

/// The templates a hardware user copies (`config/*.toml.example`) parse, and none of them
/// pairs a real camera with `sim-truth`, which only the simulator's frames carry.
#[test]
fn every_template_parses_and_segments_real_frames_with_a_real_segmenter() {
    use easyhec::config::{CameraConfig, SegmenterConfig};
    let mut seen = 0;
    for entry in std::fs::read_dir(common::repo_root().join("config")).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        if !name.ends_with(".toml.example") {
            continue;
        }
        seen += 1;
        let cfg = read_config(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
        for cam in cfg.camera.cameras() {
            let segmenter = cam.segmenter.as_ref().unwrap_or(&cfg.segmenter);
            let real_camera = !matches!(cam.config, CameraConfig::Sim(SimCameraSettings { .. }));
            assert!(
                !(real_camera && matches!(segmenter, SegmenterConfig::SimTruth { .. })),
                "{name}: camera '{}' is real and its segmenter is sim-truth",
                cam.name
            );
            assert!(
                real_camera,
                "{name}: a template for hardware films with the simulator"
            );
        }
    }
    assert!(seen >= 4, "only {seen} templates found");
}

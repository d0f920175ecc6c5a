//! Fuzz target `cell_toml`: see `fuzz/src/inputs.rs` for what it asserts.
#![no_main]

#[allow(dead_code)] // each target uses one of the checks
#[path = "../src/inputs.rs"]
mod inputs;

libfuzzer_sys::fuzz_target!(|data: &[u8]| inputs::cell_toml(data));

//! Fuzz target `run_json`: see `fuzz/src/inputs.rs` for what it asserts.
#![no_main]

#[path = "../src/inputs.rs"]
mod inputs;

libfuzzer_sys::fuzz_target!(|data: &[u8]| inputs::run_json(data));

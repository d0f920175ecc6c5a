//! Fuzz target `xarm_report`: see `easyhec_fuzz::xarm_report` for what it asserts.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| easyhec_fuzz::xarm_report(data));

//! Fuzz target `rtde`: see `easyhec_fuzz::rtde` for what it asserts.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| easyhec_fuzz::rtde(data));

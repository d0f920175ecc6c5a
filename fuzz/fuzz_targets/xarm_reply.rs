//! Fuzz target `xarm_reply`: see `easyhec_fuzz::xarm_reply` for what it asserts.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| easyhec_fuzz::xarm_reply(data));

//! Fuzz target `dynamixel`: see `easyhec_fuzz::dynamixel` for what it asserts.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| easyhec_fuzz::dynamixel(data));

//! Fuzz target `feetech`: see `easyhec_fuzz::feetech` for what it asserts.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| easyhec_fuzz::feetech(data));

//! Fuzz target `piper`: see `easyhec_fuzz::piper` for what it asserts.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| easyhec_fuzz::piper(data));

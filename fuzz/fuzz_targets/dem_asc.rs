//! Fuzz target: the dem decoder on `dem.asc` input (format picked by the file name).
//! Any panic, hang, or allocation beyond libFuzzer's limits is a finding; errors are fine.
#![no_main]

use libfuzzer_sys::fuzz_target;

const NAME: &str = "dem.asc";

fuzz_target!(|data: &[u8]| {
    let bytes = data;
    let _ = phenomena_engine::formats::dem::decode_dem(&bytes, Some(NAME), &phenomena_engine::formats::dem::DemOptions::default());
});

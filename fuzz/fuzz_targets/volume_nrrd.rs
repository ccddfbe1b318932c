//! Fuzz target: the volume decoder on `volume.nrrd` input (format picked by the file name and magic).
//! Any panic, hang, or allocation beyond libFuzzer's limits is a finding; errors are fine.
#![no_main]

use libfuzzer_sys::fuzz_target;

const NAME: &str = "volume.nrrd";

fuzz_target!(|data: &[u8]| {
    // Keep the format's magic so every input reaches this decoder.
    const MAGIC: &[u8] = b"NRRD000";
    let bytes: Vec<u8> = if data.starts_with(MAGIC) {
        data.to_vec()
    } else {
        [MAGIC, data].concat()
    };
    let _ = phenomena_engine::formats::volume::decode_volume(&bytes, Some(NAME), &phenomena_engine::formats::volume::VolumeOptions::default());
});

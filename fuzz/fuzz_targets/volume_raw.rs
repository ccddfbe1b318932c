//! Fuzz target: the volume decoder on `volume.raw` input (format picked by the file name).
//! Any panic, hang, or allocation beyond libFuzzer's limits is a finding; errors are fine.
#![no_main]

use libfuzzer_sys::fuzz_target;

const NAME: &str = "volume.raw";

fuzz_target!(|data: &[u8]| {
    let bytes = data;
    let _ = {
        // The first 3 bytes pick `dims` (1..=64 each) so the raw reader's size check is reached
        // with both matching and mismatching lengths.
        let dims = match bytes.get(..3) {
            Some(d) => [d[0] as usize % 64 + 1, d[1] as usize % 64 + 1, d[2] as usize % 64 + 1],
            None => return,
        };
        let opts = phenomena_engine::formats::volume::VolumeOptions {
            dims: Some(dims),
            ..Default::default()
        };
        phenomena_engine::formats::volume::decode_volume(&bytes[3..], Some(NAME), &opts)
    };
});

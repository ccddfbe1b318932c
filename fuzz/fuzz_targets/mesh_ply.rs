//! Fuzz target: the mesh decoder on `mesh.ply` input (format picked by the file name and magic).
//! Any panic, hang, or allocation beyond libFuzzer's limits is a finding; errors are fine.
#![no_main]

use libfuzzer_sys::fuzz_target;

const NAME: &str = "mesh.ply";

fuzz_target!(|data: &[u8]| {
    // Keep the format's magic so every input reaches this decoder.
    const MAGIC: &[u8] = b"ply\n";
    let bytes: Vec<u8> = if data.starts_with(MAGIC) {
        data.to_vec()
    } else {
        [MAGIC, data].concat()
    };
    let _ = phenomena_engine::formats::mesh::decode_mesh(&bytes, Some(NAME), &phenomena_engine::formats::mesh::MeshOptions::default());
});

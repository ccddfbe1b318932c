//! Fuzz target: the mesh decoder on `mesh.stl` input (format picked by the file name).
//! Any panic, hang, or allocation beyond libFuzzer's limits is a finding; errors are fine.
#![no_main]

use libfuzzer_sys::fuzz_target;

const NAME: &str = "mesh.stl";

fuzz_target!(|data: &[u8]| {
    let bytes = data;
    let _ = phenomena_engine::formats::mesh::decode_mesh(&bytes, Some(NAME), &phenomena_engine::formats::mesh::MeshOptions::default());
});

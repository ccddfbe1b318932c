//! Fuzz target: params JSON of every pipeline (the JSON a client sends as `params`), through the
//! same validation the server and the CLI use. Errors are fine; a panic is a finding.
#![no_main]

use libfuzzer_sys::fuzz_target;
use phenomena_engine::params::Limits;
use phenomena_engine::registry::{PipelineKind, PipelineParams};

fuzz_target!(|data: &[u8]| {
    let Ok(v) = serde_json::from_slice::<serde_json::Value>(data) else {
        return;
    };
    let limits = Limits::default();
    for kind in PipelineKind::ALL {
        if let Ok(p) = PipelineParams::parse(*kind, &v, &limits) {
            // The canonical form must parse back to the same parameters.
            let again = PipelineParams::parse(*kind, &p.canonical(), &limits);
            assert!(again.is_ok(), "canonical params of {kind:?} do not parse back: {again:?}");
        }
    }
});

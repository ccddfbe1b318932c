//! Fuzz target: a job request body as the server parses it (`phenomena::api::parse_submission`):
//! the bytes are a `multipart/form-data` body with boundary `fuzzboundary` (or, when they start
//! with `{`, a JSON body), then the params go through the pipelines' validation. Errors are fine;
//! a panic is a finding.
#![no_main]

use std::sync::OnceLock;

use axum::body::Body;
use axum::http::Request;
use libfuzzer_sys::fuzz_target;
use phenomena_engine::params::Limits;
use phenomena_engine::registry::{PipelineKind, PipelineParams};

fn runtime() -> &'static tokio::runtime::Runtime {
    static RT: OnceLock<tokio::runtime::Runtime> = OnceLock::new();
    RT.get_or_init(|| {
        tokio::runtime::Builder::new_current_thread()
            .build()
            .expect("a current-thread runtime")
    })
}

fuzz_target!(|data: &[u8]| {
    let ctype = if data.first() == Some(&b'{') {
        "application/json"
    } else {
        "multipart/form-data; boundary=fuzzboundary"
    };
    let Ok(req) = Request::builder()
        .method("POST")
        .uri("/v1/snow-terrain")
        .header("content-type", ctype)
        .body(Body::from(data.to_vec()))
    else {
        return;
    };
    let parsed = runtime().block_on(phenomena::api::parse_submission(req, "dem", 1 << 20));
    if let Ok((params, _input)) = parsed {
        let _ = PipelineParams::parse(PipelineKind::SnowTerrain, &params, &Limits::default());
    }
});

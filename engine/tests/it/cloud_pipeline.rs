//! The `cloud` and `cloud-edit` pipelines through the registry (`pipeline::decode`/`run`): the
//! world box the pipeline gives a volume, the ambient-field auxiliary input, and edit failures.

use phenomena_engine::cloud::{AmbientField, CloudState};
use phenomena_engine::geom::Volume;
use phenomena_engine::pipeline::{self, Job, Limits, Params, PipelineKind, RunFailure};
use phenomena_engine::NoControl;
use serde_json::json;

fn smoke_nrrd() -> Vec<u8> {
    std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../shared/data/volume/openvdb_smoke_density.nrrd"
    ))
    .unwrap()
}

fn decode(
    kind: PipelineKind,
    params: serde_json::Value,
    bytes: &[u8],
    aux: &[(String, Vec<u8>)],
) -> Job {
    let l = Limits::default();
    let p = Params::parse(kind, &params, &l).unwrap();
    pipeline::decode_with_aux(p, bytes, Some("v.nrrd"), aux, &l).unwrap()
}

fn volume(job: &Job) -> &Volume {
    match job {
        Job::Cloud { volume, .. } | Job::CloudEdit { volume, .. } => volume,
        _ => panic!("not a cloud job"),
    }
}

#[test]
fn the_world_box_is_specs_default_unless_given() {
    // The NRRD carries spacings (a 111×222×112-unit box); κ is per world unit, so the pipeline
    // uses SPEC §3's unit-cube default instead, and the user's `bounds` when given.
    let bytes = smoke_nrrd();
    let job = decode(PipelineKind::Cloud, json!({}), &bytes, &[]);
    let v = volume(&job);
    assert_eq!(v.dims, [111, 222, 112]);
    assert_eq!(v.bounds, Volume::default_bounds(v.dims));
    let job = decode(
        PipelineKind::Cloud,
        json!({"bounds": [[0, 0, 0], [2, 4, 2]]}),
        &bytes,
        &[],
    );
    assert_eq!(volume(&job).bounds, ([0.0; 3], [2.0, 4.0, 2.0]));
    let info = pipeline::describe(&job);
    assert_eq!(info["dims"], json!([111, 222, 112]));
}

/// A 16³ ball as `.npy`.
fn ball() -> Vec<u8> {
    let n = 16usize;
    let mut d = Vec::new();
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let p = [x, y, z].map(|c| (c as f32 + 0.5) / n as f32 - 0.5);
                let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                d.push((1.0 - r / 0.4).max(0.0));
            }
        }
    }
    use npyz::WriterBuilder;
    let mut out = Vec::new();
    let mut w = npyz::WriteOptions::new()
        .default_dtype()
        .shape(&[n as u64; 3])
        .writer(&mut out)
        .begin_nd()
        .unwrap();
    w.extend(d).unwrap();
    w.finish().unwrap();
    out
}

#[test]
fn the_ambient_field_input_changes_the_render_and_must_fit() {
    let bytes = ball();
    let params = json!({"width": 32, "height": 32, "kappa": 20});
    let l = Limits::default();
    let run = |aux: &[(String, Vec<u8>)]| {
        let p = Params::parse(PipelineKind::Cloud, &params, &l).unwrap();
        let job = pipeline::decode_with_aux(p, &bytes, Some("b.npy"), aux, &l).unwrap();
        pipeline::run(&job, &NoControl).unwrap()
    };
    let plain = run(&[]);
    let red = AmbientField::uniform(16 * 16 * 16, [3.0, 0.0, 0.0]).to_bytes();
    let tinted = run(&[(pipeline::AMBIENT_FIELD.to_string(), red)]);
    assert_ne!(
        plain[0].bytes, tinted[0].bytes,
        "the field must reach the renderer"
    );

    // A field for another grid is a clear input error, not a silent fallback.
    let wrong = AmbientField::uniform(8, [1.0; 3]).to_bytes();
    let p = Params::parse(PipelineKind::Cloud, &params, &l).unwrap();
    let aux = [(pipeline::AMBIENT_FIELD.to_string(), wrong)];
    assert!(pipeline::decode_with_aux(p, &bytes, Some("b.npy"), &aux, &l).is_err());
}

#[test]
fn an_edit_that_cannot_be_done_is_unprocessable_with_the_reason() {
    let base = serde_json::to_value(CloudState::default()).unwrap();
    let params = json!({
        "kind": "sun-direction",
        "base": base,
        "edit": {"width": 32, "height": 32, "from": [0, 0], "to": [16, 16]},
    });
    let job = decode(PipelineKind::CloudEdit, params.clone(), &ball(), &[]);
    match pipeline::run(&job, &NoControl) {
        Err(RunFailure::Unprocessable(m)) => assert!(m.contains("empty sky"), "{m}"),
        other => panic!("expected an unprocessable edit, got {other:?}"),
    }
    // Errors inside the edit name their field under `edit.`.
    let mut bad = params;
    bad["edit"]["from"] = json!([99, 0]);
    let e = Params::parse(PipelineKind::CloudEdit, &bad, &Limits::default()).unwrap_err();
    assert!(e.field.starts_with("edit.from"), "{e}");
    // The canonical form parses back to the same parameters.
    let p = Params::parse(
        PipelineKind::CloudEdit,
        &json!({"kind": "sun-color", "base": {}, "edit": {"strokes": [{"color": "#ffffff", "pixels": [[1, 1]]}]}}),
        &Limits::default(),
    )
    .unwrap();
    let again = Params::parse(PipelineKind::CloudEdit, &p.canonical(), &Limits::default()).unwrap();
    assert_eq!(again, p);
}

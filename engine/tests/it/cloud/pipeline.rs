//! The `cloud` and `cloud-edit` pipelines through the registry (`registry::decode`/`run`): the
//! world box the pipeline gives a volume, the ambient-field auxiliary input, and edit failures.

use phenomena_engine::cloud::{AmbientField, CloudState};
use phenomena_engine::geom::Volume;
use phenomena_engine::params::Limits;
use phenomena_engine::registry::{self, Job, PipelineKind, PipelineParams, RunFailure};
use phenomena_engine::{NoControl, Refusal};
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
    let p = PipelineParams::parse(kind, &params, &l).unwrap();
    registry::decode_parts(p, bytes, Some("v.nrrd"), aux, &l).unwrap()
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
    let info = registry::describe(&job);
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
        let p = PipelineParams::parse(PipelineKind::Cloud, &params, &l).unwrap();
        let job = registry::decode_parts(p, &bytes, Some("b.npy"), aux, &l).unwrap();
        registry::run(&job, &NoControl).unwrap()
    };
    let plain = run(&[]);
    let red = AmbientField::uniform(16 * 16 * 16, [3.0, 0.0, 0.0]).to_bytes();
    let tinted = run(&[(registry::AMBIENT_FIELD.to_string(), red)]);
    assert_ne!(
        plain[0].bytes, tinted[0].bytes,
        "the field must reach the renderer"
    );

    // A field for another grid is a clear input error, not a silent fallback.
    let wrong = AmbientField::uniform(8, [1.0; 3]).to_bytes();
    let p = PipelineParams::parse(PipelineKind::Cloud, &params, &l).unwrap();
    let aux = [(registry::AMBIENT_FIELD.to_string(), wrong)];
    assert!(registry::decode_parts(p, &bytes, Some("b.npy"), &aux, &l).is_err());
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
    match registry::run(&job, &NoControl) {
        Err(RunFailure::Refused {
            reason: Refusal::Unprocessable,
            detail: m,
        }) => assert!(m.contains("empty sky"), "{m}"),
        other => panic!("expected an unprocessable edit, got {other:?}"),
    }
    // Errors inside the edit name their field under `edit.`.
    let mut bad = params;
    bad["edit"]["from"] = json!([99, 0]);
    let e = PipelineParams::parse(PipelineKind::CloudEdit, &bad, &Limits::default()).unwrap_err();
    assert!(e.field.starts_with("edit.from"), "{e}");
    // The canonical form parses back to the same parameters.
    let p = PipelineParams::parse(
        PipelineKind::CloudEdit,
        &json!({"kind": "sun-color", "base": {}, "edit": {"strokes": [{"color": "#ffffff", "pixels": [[1, 1]]}]}}),
        &Limits::default(),
    )
    .unwrap();
    let again =
        PipelineParams::parse(PipelineKind::CloudEdit, &p.canonical(), &Limits::default()).unwrap();
    assert_eq!(again, p);
}

/// A sun-colour edit given the layers of the base version's render at its view (`layers.bin`)
/// reads them instead of decoding the volume and marching, and gives the same version byte for
/// byte; layers of another view are not used, and a corrupt blob is an input error.
#[test]
fn a_sun_color_edit_reads_the_render_layers_and_gives_the_same_version() {
    let bytes = ball();
    let l = Limits::default();
    let view =
        json!({"width": 40, "height": 30, "camera": {"azimuth_deg": 30, "elevation_deg": 10}});
    let base = json!({"kappa": 25, "background": "#203040"});
    let render = |view: &serde_json::Value| {
        let mut p = base.clone();
        p.as_object_mut()
            .unwrap()
            .extend(view.as_object().unwrap().clone());
        p["layers"] = json!(["linear"]);
        let job = decode(PipelineKind::Cloud, p, &bytes, &[]);
        let out = registry::run(&job, &NoControl).unwrap();
        let names: Vec<&str> = out.iter().map(|o| o.name.as_str()).collect();
        assert_eq!(names, ["render.png", "state.json", "layers.bin"]);
        let state: serde_json::Value = serde_json::from_slice(&out[1].bytes).unwrap();
        (state, out[2].bytes.clone())
    };
    // The edit's base is the render's state.json, as a scene's version gives it: with the
    // density floor the decoder chose (part of the layers' identity).
    let (rendered, blob) = render(&view);
    assert!(rendered["density_floor"].is_number(), "{rendered}");
    let base = rendered;
    let mut edit = view.clone();
    edit["strokes"] = json!([
        {"color": "#ff8040", "pixels": [[20, 15], [21, 15], [19, 16]]},
        {"color": "#ffffff", "pixels": [[22, 14]]}
    ]);
    let params = json!({"kind": "sun-color", "base": base, "edit": edit});
    let aux = |b: Vec<u8>| vec![(registry::LAYERS.to_string(), b)];
    let job = decode(
        PipelineKind::CloudEdit,
        params.clone(),
        &bytes,
        &aux(blob.clone()),
    );
    assert!(
        matches!(job, Job::CloudRecolor { .. }),
        "the layers must be used"
    );
    let cached = registry::run(&job, &NoControl).unwrap();
    let job = decode(PipelineKind::CloudEdit, params.clone(), &bytes, &[]);
    assert!(matches!(job, Job::CloudEdit { .. }));
    let marched = registry::run(&job, &NoControl).unwrap();
    let names: Vec<&str> = marched.iter().map(|o| o.name.as_str()).collect();
    assert_eq!(names, ["state.json", "render.png", "layers.bin"]);
    let named = |o: &[phenomena_engine::Output]| -> Vec<(String, Vec<u8>)> {
        o.iter()
            .map(|o| (o.name.clone(), o.bytes.clone()))
            .collect()
    };
    assert_eq!(named(&cached), named(&marched));
    assert_eq!(
        marched[2].bytes, blob,
        "the new version's layers are the base's"
    );
    let state: CloudState = serde_json::from_slice(&marched[0].bytes).unwrap();
    assert_ne!(state.sun_color, CloudState::default().sun_color);

    // Layers of another camera: marched instead, same result.
    let (_, other) = render(
        &json!({"width": 40, "height": 30, "camera": {"azimuth_deg": 31, "elevation_deg": 10}}),
    );
    let job = decode(PipelineKind::CloudEdit, params.clone(), &bytes, &aux(other));
    assert!(matches!(job, Job::CloudEdit { .. }));
    assert_eq!(
        named(&registry::run(&job, &NoControl).unwrap()),
        named(&marched)
    );

    // Layers of another density floor, or a base that leaves the floor open (the layers'
    // floor cannot be checked without the volume): marched.
    for floor in [json!(0.05), serde_json::Value::Null] {
        let mut other = params.clone();
        match &floor {
            serde_json::Value::Null => {
                let b = other["base"].as_object_mut().unwrap();
                b.remove("density_floor");
                b.remove("density_floor_auto");
            }
            f => other["base"]["density_floor"] = f.clone(),
        }
        let job = decode(PipelineKind::CloudEdit, other, &bytes, &aux(blob.clone()));
        assert!(matches!(job, Job::CloudEdit { .. }), "floor {floor}");
    }

    let p = PipelineParams::parse(PipelineKind::CloudEdit, &params, &l).unwrap();
    let corrupt = aux(blob[..blob.len() - 3].to_vec());
    assert!(registry::decode_parts(p, &bytes, Some("b.npy"), &corrupt, &l).is_err());
}

//! The whole `snow-cover` pipeline on real meshes: outputs, mass balance, validator-clean GLBs,
//! time-lapse frames, determinism.

use phenomena_engine::pipeline::{self, Job, Limits, Params, PipelineKind};
use phenomena_engine::{NoControl, Output};
use serde_json::{json, Value};

use crate::gltf_validator::validate_glb;
use crate::golden::assert_golden;

fn job(file: &str, params: Value) -> Job {
    let path = format!(
        "{}/../../shared/data/mesh/{file}",
        env!("CARGO_MANIFEST_DIR")
    );
    let l = Limits::default();
    let p = Params::parse(PipelineKind::SnowCover, &params, &l).unwrap();
    pipeline::decode(p, &std::fs::read(path).unwrap(), Some(file), &l).unwrap()
}

fn output<'a>(outs: &'a [Output], name: &str) -> &'a [u8] {
    &outs.iter().find(|o| o.name == name).unwrap().bytes
}

/// Small but real: the Inventor table (Z-up content in a GLB), 64² maps, 6 steps.
fn small() -> Value {
    json!({"up_axis": "z", "resolution": 64, "directions": 4, "steps": 6, "width": 160,
           "height": 120, "frames": 3})
}

#[test]
fn table_outputs_balance_and_validate() {
    let outs = pipeline::run(&job("inventor_table.glb", small()), &NoControl).unwrap();
    let names: Vec<&str> = outs.iter().map(|o| o.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "render.png",
            "snow.glb",
            "scene.glb",
            "displaced.glb",
            "timelapse.png",
            "report.json"
        ]
    );
    let report: Value = serde_json::from_slice(output(&outs, "report.json")).unwrap();
    let b = &report["mass_balance"];
    let fallen = b["fallen_units"].as_u64().unwrap();
    let resting: u64 = b["resting_units"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap())
        .sum();
    let lost = b["lost_units"].as_u64().unwrap();
    assert!(fallen > 0);
    assert_eq!(resting + lost, fallen, "mass is conserved exactly");
    assert!(
        b["resting_m3"].as_f64().unwrap() > 0.0,
        "snow rests on the table top"
    );
    for name in ["snow.glb", "scene.glb", "displaced.glb"] {
        let r = validate_glb(name, output(&outs, name));
        assert_eq!(
            r["issues"]["numErrors"],
            json!(0),
            "{name}: {}",
            r["issues"]
        );
    }
    // The time-lapse is an animated PNG with `frames` frames.
    let dec = png::Decoder::new(std::io::Cursor::new(output(&outs, "timelapse.png")));
    let reader = dec.read_info().unwrap();
    assert_eq!(reader.info().animation_control.unwrap().num_frames, 3);
}

#[test]
fn same_bytes_on_one_thread_and_two() {
    let j = job(
        "teapot_npm.obj",
        json!({"resolution": 48, "directions": 3, "steps": 4, "width": 96, "height": 64}),
    );
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| pipeline::run(&j, &NoControl).unwrap());
    let two = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap()
        .install(|| pipeline::run(&j, &NoControl).unwrap());
    for (a, b) in one.iter().zip(&two) {
        if a.name != "report.json" {
            assert!(
                a.bytes == b.bytes,
                "{} differs between thread counts",
                a.name
            );
        }
    }
}

fn decode_rgba(bytes: &[u8]) -> phenomena_engine::render::image::RgbaImage {
    let mut dec = png::Decoder::new(std::io::Cursor::new(bytes));
    dec.set_transformations(png::Transformations::EXPAND);
    let mut reader = dec.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    buf.truncate(info.buffer_size());
    phenomena_engine::render::image::RgbaImage {
        width: info.width,
        height: info.height,
        data: buf,
    }
}

/// Reference renders (STYLE habit 8) of two real meshes under snow, small maps and images so the
/// test stays fast: the Inventor table (Z-up content in a GLB) and the teapot (OBJ). Tolerance: 3
/// per channel (0–255), at most 0.5 % of the pixels beyond it (silhouette pixels can flip with
/// FMA contraction). `BLESS=1` regenerates `tests/golden/snow-cover/*.png`; a diff image goes to
/// `target/golden-diff/` on failure.
#[test]
fn golden_renders_of_real_meshes() {
    let cases = [
        (
            "inventor_table",
            "inventor_table.glb",
            json!({"up_axis": "z", "resolution": 64, "directions": 8, "steps": 6,
                   "width": 200, "height": 140}),
        ),
        (
            "teapot",
            "teapot_npm.obj",
            json!({"resolution": 64, "directions": 8, "steps": 6, "width": 200, "height": 140}),
        ),
    ];
    for (case, file, p) in cases {
        let outs = pipeline::run(&job(file, p), &NoControl).unwrap();
        assert_golden(
            "snow-cover",
            case,
            &decode_rgba(output(&outs, "render.png")),
            3,
            0.005,
        );
    }
}

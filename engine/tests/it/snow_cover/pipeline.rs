//! The whole `snow-cover` pipeline on real meshes: outputs, mass balance, validator-clean GLBs,
//! time-lapse frames, determinism.

use phenomena_engine::params::Limits;
use phenomena_engine::registry::{self, Job, PipelineKind, PipelineParams};
use phenomena_engine::{NoControl, Output};
use serde_json::{json, Value};

use crate::support::gltf_validator::validate_glb;
use crate::support::golden::assert_golden;

/// A job on `file`: a name in `../shared/data/mesh`, or a path under the repository root
/// (`tests/data/…`).
fn job(file: &str, params: Value) -> Job {
    let path = if file.starts_with("tests/") {
        format!("{}/../{file}", env!("CARGO_MANIFEST_DIR"))
    } else {
        format!(
            "{}/../../shared/data/mesh/{file}",
            env!("CARGO_MANIFEST_DIR")
        )
    };
    let l = Limits::default();
    let p = PipelineParams::parse(PipelineKind::SnowCover, &params, &l).unwrap();
    let name = file.rsplit('/').next().unwrap_or(file);
    registry::decode(p, &std::fs::read(path).unwrap(), Some(name), &l).unwrap()
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
    let outs = registry::run(&job("inventor_table.glb", small()), &NoControl).unwrap();
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
        .install(|| registry::run(&j, &NoControl).unwrap());
    let two = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap()
        .install(|| registry::run(&j, &NoControl).unwrap());
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
        let outs = registry::run(&job(file, p), &NoControl).unwrap();
        assert_golden(
            "snow-cover",
            case,
            &decode_rgba(output(&outs, "render.png")),
            3,
            0.005,
        );
    }
}

/// Issue 18: reference renders of three committed real models drawn with their own materials
/// (`tests/data/mesh`, provenance in its README), read as the CLI reads them (MTL and textures
/// from beside the file): the park bench (OBJ + MTL, wood `map_Kd` JPEG), assimp's spider (OBJ,
/// five materials, JPEG textures) and pymeshlab's airplane (PLY vertex colours). Small maps and
/// pictures so the test stays fast; default parameters otherwise (the default up axis, sun and
/// snowfall). Same tolerance as above.
#[test]
fn golden_renders_of_real_models_with_their_materials() {
    use crate::render::materials::read_with_sidecars;
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../tests/data/mesh");
    let cases = [
        ("bench_textured", "bench/bench.obj"),
        ("spider_textured", "spider/spider.obj"),
        ("airplane_vertex_colors", "colored_airplane.ply"),
    ];
    let l = Limits::default();
    for (case, file) in cases {
        let path = root.join(file);
        let params = json!({"resolution": 64, "directions": 8, "steps": 6,
                            "width": 200, "height": 140});
        let p = PipelineParams::parse(PipelineKind::SnowCover, &params, &l).unwrap();
        let (bytes, side) = read_with_sidecars(&path);
        assert!(
            file.ends_with(".ply") || !side.is_empty(),
            "{file}: sidecars read"
        );
        let name = path.file_name().unwrap().to_str().unwrap();
        let j = registry::decode_parts(p, &bytes, Some(name), &side, &l).unwrap();
        let outs = registry::run(&j, &NoControl).unwrap();
        assert_golden(
            "snow-cover",
            case,
            &decode_rgba(output(&outs, "render.png")),
            3,
            0.005,
        );
    }
}

/// The JSON chunk and the BIN chunk of a GLB.
fn glb_chunks(glb: &[u8]) -> (Value, &[u8]) {
    let len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let doc: Value = serde_json::from_slice(&glb[20..20 + len]).unwrap();
    let bin = &glb[20 + len + 8..];
    (doc, bin)
}

/// The bytes of bufferView `v`.
fn view<'a>(doc: &Value, bin: &'a [u8], v: u64) -> &'a [u8] {
    let bv = &doc["bufferViews"][v as usize];
    let off = bv["byteOffset"].as_u64().unwrap() as usize;
    &bin[off..off + bv["byteLength"].as_u64().unwrap() as usize]
}

/// The float accessor `a` as rows of its component count.
fn floats(doc: &Value, bin: &[u8], a: &Value) -> Vec<Vec<f32>> {
    let acc = &doc["accessors"][a.as_u64().unwrap() as usize];
    assert_eq!(acc["componentType"], json!(5126));
    let k = match acc["type"].as_str().unwrap() {
        "SCALAR" => 1,
        "VEC2" => 2,
        "VEC3" => 3,
        "VEC4" => 4,
        t => panic!("{t}"),
    };
    let bytes = view(doc, bin, acc["bufferView"].as_u64().unwrap());
    let all: Vec<f32> = bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    assert_eq!(all.len(), acc["count"].as_u64().unwrap() as usize * k);
    all.chunks(k).map(<[f32]>::to_vec).collect()
}

/// SPEC §2 step 6 in `displaced.glb`: the coverage is a per-vertex attribute equal to the
/// coverage recomputed from the file's own displaced surface and depths; the flake texture is the
/// generated one; the overlay's alpha is the coverage of its corners, its UVs finite; the flakes
/// show where the coverage is partial. (The validator runs in `table_outputs_balance_and_validate`.)
#[test]
fn displaced_glb_carries_coverage_and_flake_texture() {
    use phenomena_engine::formats::png_write::encode_rgba;
    use phenomena_engine::snow_cover::sparse::{
        flake_texture, vertex_coverage_with_probability, FLAKE_TEXTURE_SIZE,
    };
    let sparse_depth = 0.01;
    let mut p = small();
    p["seed"] = json!(5);
    p["sparse_depth"] = json!(sparse_depth);
    let outs = registry::run(&job("inventor_table.glb", p), &NoControl).unwrap();
    let (doc, bin) = glb_chunks(output(&outs, "displaced.glb"));
    let prims = doc["meshes"][0]["primitives"].as_array().unwrap();
    // The surface: one primitive per input part, all on the same vertices; then the snow layer
    // and the flakes.
    let n = prims.len();
    assert!(n >= 3, "surface parts + snow layer + flake overlay");
    let (surface, layer, over) = (&prims[..n - 2], &prims[n - 2], &prims[n - 1]["attributes"]);
    let base = &surface[0]["attributes"];
    assert!(surface.iter().all(|p| &p["attributes"] == base));
    let mut idx: Vec<u32> = Vec::new();
    for prim in surface {
        let idx_acc = &doc["accessors"][prim["indices"].as_u64().unwrap() as usize];
        idx.extend(
            view(&doc, bin, idx_acc["bufferView"].as_u64().unwrap())
                .chunks_exact(4)
                .map(|c| u32::from_le_bytes(c.try_into().unwrap())),
        );
    }

    let pos: Vec<[f32; 3]> = floats(&doc, bin, &base["POSITION"])
        .iter()
        .map(|v| [v[0], v[1], v[2]])
        .collect();
    let tris: Vec<[u32; 3]> = idx.chunks(3).map(|t| [t[0], t[1], t[2]]).collect();
    let cov: Vec<f32> = floats(&doc, bin, &base["_SNOW_COVERAGE"])
        .iter()
        .map(|v| v[0])
        .collect();
    let depth: Vec<f32> = floats(&doc, bin, &base["_SNOW_DEPTH"])
        .iter()
        .map(|v| v[0])
        .collect();
    let point_p: Vec<f32> = floats(&doc, bin, &base["_SNOW_POINT_PROBABILITY"])
        .iter()
        .map(|v| v[0])
        .collect();
    assert_eq!(cov.len(), pos.len(), "one coverage per vertex");
    assert_eq!(depth.len(), pos.len(), "one depth per vertex");
    assert_eq!(point_p.len(), pos.len(), "one point probability per vertex");
    assert!(point_p.iter().all(|p| (0.0..=1.0).contains(p)));
    assert_eq!(
        cov,
        vertex_coverage_with_probability(
            &pos,
            &tris,
            &depth,
            Some(&point_p),
            [0.0, -1.0, 0.0],
            sparse_depth
        ),
        "the attribute is the pipeline's coverage"
    );
    // Occlusion counts: some vertices are in shadow from some directions (under the top).
    assert!(point_p.iter().any(|&p| p < 0.5) && point_p.iter().any(|&p| p > 0.5));
    let partial = cov.iter().filter(|&&c| c > 0.0 && c < 1.0).count();
    assert!(partial > 0, "the table has partial coverage somewhere");
    assert!(cov.iter().all(|c| (0.0..=1.0).contains(c)));

    // The overlay: one triangle per surface triangle with coverage, its corners' alpha the
    // coverage, UVs finite, positions near (not on) the surface's.
    let kept: Vec<&[u32; 3]> = tris
        .iter()
        .filter(|t| t.iter().any(|&i| cov[i as usize] > 0.0))
        .collect();
    let colors = floats(&doc, bin, &over["COLOR_0"]);
    let uvs = floats(&doc, bin, &over["TEXCOORD_0"]);
    let opos = floats(&doc, bin, &over["POSITION"]);
    assert_eq!(colors.len(), kept.len() * 3);
    assert!(uvs.iter().flatten().all(|x| x.is_finite()));
    let (lo, hi) = (
        doc["accessors"][base["POSITION"].as_u64().unwrap() as usize]["min"].clone(),
        doc["accessors"][base["POSITION"].as_u64().unwrap() as usize]["max"].clone(),
    );
    let diag = (0..3)
        .map(|k| (hi[k].as_f64().unwrap() - lo[k].as_f64().unwrap()).powi(2))
        .sum::<f64>()
        .sqrt() as f32;
    for (k, t) in kept.iter().enumerate() {
        for (j, &i) in t.iter().enumerate() {
            assert_eq!(colors[3 * k + j][3], cov[i as usize]);
            assert_eq!(&colors[3 * k + j][..3], &[1.0, 1.0, 1.0]);
            let q = &opos[3 * k + j];
            let d = (0..3)
                .map(|c| (q[c] - pos[i as usize][c]).powi(2))
                .sum::<f32>()
                .sqrt();
            assert!(
                d > 0.0 && d <= 1.01e-3 * diag,
                "lift {d} of diagonal {diag}"
            );
            // UVs: the corner projected on two axes, in tiles of an eighth of the diagonal.
            let p = pos[i as usize].map(|x| x * 8.0 / diag);
            let uv = &uvs[3 * k + j];
            assert!(
                [(2, 1), (0, 2), (0, 1)].iter().any(|&(a, b)| {
                    (uv[0] - p[a]).abs() <= 1e-4 * (1.0 + p[a].abs())
                        && (uv[1] - p[b]).abs() <= 1e-4 * (1.0 + p[b].abs())
                }),
                "uv {uv:?} of corner {p:?} (tiles)"
            );
        }
    }
    // The snow layer: blended, its alpha the snow amount min(depth / sparse_depth, 1) of a
    // surface vertex with snow (one layer vertex per such vertex, lifted like the flakes).
    let lmat = &doc["materials"][layer["material"].as_u64().unwrap() as usize];
    assert_eq!(lmat["alphaMode"], json!("BLEND"));
    let lcol = floats(&doc, bin, &layer["attributes"]["COLOR_0"]);
    let mut want: Vec<f32> = depth
        .iter()
        .map(|&d| (d / sparse_depth).min(1.0))
        .filter(|&a| a > 0.0)
        .collect();
    let mut got: Vec<f32> = lcol.iter().map(|c| c[3]).filter(|&a| a > 0.0).collect();
    want.sort_by(f32::total_cmp);
    got.sort_by(f32::total_cmp);
    assert!(!got.is_empty(), "snow on the table top");
    assert_eq!(
        got, want,
        "the layer's alphas are the vertices' snow amounts"
    );

    let mat = &doc["materials"][prims[n - 1]["material"].as_u64().unwrap() as usize];
    assert_eq!(mat["alphaMode"], json!("BLEND"));
    let tex = mat["pbrMetallicRoughness"]["baseColorTexture"]["index"]
        .as_u64()
        .unwrap();
    assert_eq!(doc["samplers"][0]["wrapS"], json!(10497));
    assert_eq!(doc["samplers"][0]["wrapT"], json!(10497));
    let img = doc["textures"][tex as usize]["source"].as_u64().unwrap();
    let png = view(
        &doc,
        bin,
        doc["images"][img as usize]["bufferView"].as_u64().unwrap(),
    );
    let want = flake_texture(FLAKE_TEXTURE_SIZE, 5);
    let decoded = decode_rgba(png);
    assert_eq!(
        (decoded.width as usize, decoded.height as usize),
        (FLAKE_TEXTURE_SIZE, FLAKE_TEXTURE_SIZE)
    );
    assert_eq!(decoded.data, want, "the texture is the flake texture");
    let mut img = decoded;
    img.data = want;
    assert_eq!(png, encode_rgba(&img).as_slice(), "same PNG bytes");
}

/// Issue 18: `displaced.glb` carries the input's materials and textures as `scene.glb` does (a
/// glTF sample with an embedded PNG, subdivided by `max_edge_length` so that the texture
/// coordinates must be carried to the new vertices), and stays valid per the Khronos validator.
#[test]
fn displaced_glb_keeps_the_input_textures_and_validates() {
    use phenomena_engine::formats::mesh::{decode_mesh, MeshOptions};
    let file = "tests/data/mesh/box_textured.glb";
    let params = json!({"resolution": 64, "directions": 4, "steps": 4, "width": 160,
                        "height": 120, "max_edge_length": 0.3});
    let outs = registry::run(&job(file, params), &NoControl).unwrap();
    let path = format!("{}/../{file}", env!("CARGO_MANIFEST_DIR"));
    let input = decode_mesh(
        &std::fs::read(path).unwrap(),
        Some("box_textured.glb"),
        &MeshOptions::default(),
    )
    .unwrap();
    let png = &input.textures[0].encoded;
    for name in ["scene.glb", "displaced.glb"] {
        let glb = output(&outs, name);
        let r = validate_glb(name, glb);
        assert_eq!(
            r["issues"]["numErrors"],
            json!(0),
            "{name}: {}",
            r["issues"]
        );
        let (doc, bin) = glb_chunks(glb);
        // A primitive whose material has the input's texture, with one UV per vertex.
        let prims = doc["meshes"]
            .as_array()
            .unwrap()
            .iter()
            .flat_map(|m| m["primitives"].as_array().unwrap().iter());
        let textured: Vec<&Value> = prims
            .filter(|p| {
                let m = &doc["materials"][p["material"].as_u64().unwrap() as usize];
                let Some(t) = m["pbrMetallicRoughness"]["baseColorTexture"]["index"].as_u64()
                else {
                    return false;
                };
                let img = &doc["images"]
                    [doc["textures"][t as usize]["source"].as_u64().unwrap() as usize];
                view(&doc, bin, img["bufferView"].as_u64().unwrap()) == &png[..]
            })
            .collect();
        assert!(!textured.is_empty(), "{name}: the input's texture");
        for p in textured {
            let a = &p["attributes"];
            let count =
                |k: &str| doc["accessors"][a[k].as_u64().unwrap() as usize]["count"].clone();
            assert_eq!(count("TEXCOORD_0"), count("POSITION"), "{name}");
            if name == "displaced.glb" {
                // Subdivided: more vertices than the box's 24.
                assert!(count("POSITION").as_u64().unwrap() > 24, "{name}");
                assert!(a["_SNOW_DEPTH"].is_u64(), "{name}");
            }
        }
    }
}

/// With no `up_axis`, the decoder picks the convention each real mesh stands in (the Inventor
/// scenes are Z-up content in GLB, the Stanford scans Y-up in STL/PLY), and keeps the reader's
/// default where it already stands (the teapot, the house).
#[test]
fn default_up_axis_stands_the_real_meshes_up() {
    use phenomena_engine::formats::mesh::decode_upright;
    use phenomena_engine::geom::mesh::UpAxis;
    let l = Limits::default();
    let decode = |file: &str, up: Option<UpAxis>| {
        let path = format!(
            "{}/../../shared/data/mesh/{file}",
            env!("CARGO_MANIFEST_DIR")
        );
        decode_upright(&std::fs::read(path).unwrap(), Some(file), &[], up, &l)
            .unwrap()
            .positions
    };
    for (file, up) in [
        ("inventor_table.glb", UpAxis::Z),
        ("inventor_chesschairs.glb", UpAxis::Z),
        ("fzk_haus.glb", UpAxis::Y),
        ("armadillo.stl", UpAxis::Y),
        ("bunny00.ply", UpAxis::Y),
        ("teapot_npm.obj", UpAxis::Y),
    ] {
        assert!(
            decode(file, None) == decode(file, Some(up)),
            "{file}: default up axis should be {up:?}"
        );
    }
}

/// The real chess scene with no snowfall given: its 6 × 6 floor is wound facing down in the file
/// and is still where nearly all the snow lands (the peeling takes a downward face outside every
/// solid as a surface), and the default snowfall is 2.5 % of the scene's 3.6 m height.
#[test]
fn the_chess_scene_floor_wound_downward_takes_the_snowfall() {
    let p = json!({"resolution": 64, "directions": 4, "steps": 2, "width": 32, "height": 24});
    let outs = registry::run(&job("inventor_chesschairs.glb", p), &NoControl).unwrap();
    let report: Value = serde_json::from_slice(output(&outs, "report.json")).unwrap();
    let [lo, hi] = [0, 1].map(|k| report["input"]["bounds"][k].clone());
    let ext = |k: usize| hi[k].as_f64().unwrap() - lo[k].as_f64().unwrap();
    let total = report["snowfall"]["total_m"].as_f64().unwrap();
    assert!(
        (total - 0.025 * ext(1)).abs() < 1e-6,
        "{}",
        report["snowfall"]
    );
    assert_eq!(report["snowfall"]["scaled_to_scene"], json!(true));
    // Fallen volume = snowfall × the snow-possible area seen from above: about the floor's.
    let fallen = report["mass_balance"]["fallen_m3"].as_f64().unwrap();
    let floor = ext(0) * ext(2);
    assert!(
        fallen > 0.95 * total * floor && fallen <= 1.0001 * total * floor,
        "fallen {fallen} m³ for {total} m over {floor} m²"
    );
}

/// Relative luminance of an sRGB8 pixel (0–1, linear).
fn luminance(p: &[u8]) -> f32 {
    let lin = |v: u8| {
        let c = f32::from(v) / 255.0;
        if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        }
    };
    0.2126 * lin(p[0]) + 0.7152 * lin(p[1]) + 0.0722 * lin(p[2])
}

/// Issue 18, "snow that reads as snow" and "converges by default", on real meshes with the
/// default parameters (but a smaller picture): no unconverged step, the final repose residual
/// within the stabilization's tolerance, and the render with snow differs from the one with
/// `snowfall: 0` in at least 5 % of the model's pixels (a pixel is the model's where it differs
/// from the sky at the left end of its row by more than 2; changed = any channel by more than
/// 8), the changed pixels brighter on average.
#[test]
fn default_runs_converge_and_the_snow_shows() {
    default_run_checks(&[
        "inventor_table.glb",
        "fzk_haus.glb",
        "tests/data/mesh/bench/bench.obj",
    ]);
}

/// The same on curved closed surfaces, the teapot and the ant, which stopped at the cap (teapot 25
/// of 48 steps, residual ≈ 7 tan units; ant 48 of 48) while snow that ran onto a bare steep flank
/// waited a sweep per cell; the event-driven sweeps of `settle` settle every step.
#[test]
fn default_runs_on_curved_meshes_converge() {
    default_run_checks(&["teapot_npm.obj", "tests/data/mesh/pyvista_ant.ply"]);
}

fn default_run_checks(files: &[&str]) {
    for &file in files {
        let outs =
            registry::run(&job(file, json!({"width": 360, "height": 240})), &NoControl).unwrap();
        // snow.glb sized to the scene (issue 18: ≤ 4 MB for inputs under 50 k triangles).
        assert!(
            output(&outs, "snow.glb").len() <= 4_000_000,
            "{file}: snow.glb"
        );
        let report: Value = serde_json::from_slice(output(&outs, "report.json")).unwrap();
        // Every region simplified and closed (none fell back to full resolution), and the
        // triangle budget held: a fallback made the ant 103,538 triangles against 100,000.
        let sm = &report["snow_meshes"];
        eprintln!("{file}: {sm}");
        assert_eq!(sm["full_resolution_regions"], json!(0), "{file}: {sm}");
        if sm["within_budget"] == json!(true) {
            assert!(sm["triangles"].as_u64().unwrap() <= 100_000, "{file}: {sm}");
        }
        let st = &report["stabilization"];
        eprintln!("{file}: {st}");
        assert_eq!(st["unconverged_steps"], json!(0), "{file}: {st}");
        let residual = st["residual_tan"].as_f64().unwrap();
        let tolerance = st["tolerance_tan"].as_f64().unwrap();
        // One snow unit (1 µm) per cell of rounding on top of the tolerance.
        let cell = report["maps"]["cell_m"].as_f64().unwrap();
        assert!(
            residual <= tolerance + 1e-6 / cell + 1e-6,
            "{file}: residual {residual}"
        );
        let bare = registry::run(
            &job(file, json!({"width": 360, "height": 240, "snowfall": 0})),
            &NoControl,
        )
        .unwrap();
        let (a, b) = (
            decode_rgba(output(&outs, "render.png")),
            decode_rgba(output(&bare, "render.png")),
        );
        let w = a.width as usize;
        let (mut model, mut changed, mut brighter) = (0usize, 0usize, 0f64);
        for y in 0..a.height as usize {
            let sky = &b.data[y * w * 4..y * w * 4 + 4];
            for x in 0..w {
                let i = (y * w + x) * 4;
                let (pa, pb) = (&a.data[i..i + 4], &b.data[i..i + 4]);
                if (0..3).all(|k| pb[k].abs_diff(sky[k]) <= 2) {
                    continue;
                }
                model += 1;
                if (0..3).any(|k| pa[k].abs_diff(pb[k]) > 8) {
                    changed += 1;
                    brighter += f64::from(luminance(pa) - luminance(pb));
                }
            }
        }
        let share = changed as f64 / model.max(1) as f64;
        eprintln!(
            "{file}: {model} model pixels, {:.1} % changed, mean luminance change {:+.3}",
            100.0 * share,
            brighter / changed.max(1) as f64
        );
        assert!(model > 1000, "{file}: the model is in the picture");
        assert!(share >= 0.05, "{file}: {:.1} % changed", 100.0 * share);
        assert!(brighter > 0.0, "{file}: the snow is brighter");
    }
}

/// Issue 18's criteria on the held-out models (not committed; `/work/heldout/mesh`, provenance in
/// the README there), each run as the CLI runs it (sidecars read from beside the file) with no
/// parameters, and again with `snowfall: 0`; prints one line per model (triangles, steps capped,
/// residual, `snow.glb` size, share of the model's pixels changed by the snow and their mean
/// luminance change, input textures and images in `scene.glb`, the pipeline's own time) and
/// writes both renders to OUT for a look:
/// `cargo test --workspace snow_cover::pipeline::heldout_survey -- --ignored --nocapture`
/// (HELDOUT=dir, OUT=dir change the folders; default `/work/heldout/mesh`, `/tmp/snow_survey`).
#[test]
#[ignore]
fn heldout_survey() {
    use crate::render::materials::read_with_sidecars;
    use std::path::PathBuf;
    let dir = PathBuf::from(std::env::var("HELDOUT").unwrap_or("/work/heldout/mesh".into()));
    let out = PathBuf::from(std::env::var("OUT").unwrap_or("/tmp/snow_survey".into()));
    std::fs::create_dir_all(&out).unwrap();
    let mut files: Vec<PathBuf> = Vec::new();
    for e in std::fs::read_dir(&dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            for f in std::fs::read_dir(&p).unwrap() {
                let f = f.unwrap().path();
                if f.extension().is_some_and(|x| x == "obj" || x == "gltf") {
                    files.push(f);
                }
            }
        } else if p
            .extension()
            .is_some_and(|x| ["obj", "glb", "gltf", "stl", "ply"].contains(&x.to_str().unwrap()))
        {
            files.push(p);
        }
    }
    files.sort();
    let l = Limits::default();
    let run = |path: &PathBuf, params: Value| {
        let p = PipelineParams::parse(PipelineKind::SnowCover, &params, &l).unwrap();
        let (bytes, side) = read_with_sidecars(path);
        let name = path.file_name().unwrap().to_str().unwrap();
        let job = registry::decode_parts(p, &bytes, Some(name), &side, &l)?;
        Ok::<_, phenomena_engine::InputError>(registry::run(&job, &NoControl).unwrap())
    };
    println!("model | triangles | steps capped | residual | snow.glb | scene.glb | model px | changed | Δ luminance | textures in / images in scene.glb | pipeline ms (snowfall stage) | snow triangles (collapse pass, regions kept)");
    for path in files {
        let name = path.file_stem().unwrap().to_string_lossy().into_owned();
        let outs = match run(&path, json!({})) {
            Ok(o) => o,
            Err(e) => {
                println!("{name}: refused: {e}");
                continue;
            }
        };
        let bare = run(&path, json!({"snowfall": 0})).unwrap();
        let report: Value = serde_json::from_slice(output(&outs, "report.json")).unwrap();
        let (a, b) = (
            decode_rgba(output(&outs, "render.png")),
            decode_rgba(output(&bare, "render.png")),
        );
        let w = a.width as usize;
        let (mut model, mut changed, mut brighter) = (0usize, 0usize, 0f64);
        for y in 0..a.height as usize {
            let sky = &b.data[y * w * 4..y * w * 4 + 4];
            for x in 0..w {
                let i = (y * w + x) * 4;
                let (pa, pb) = (&a.data[i..i + 4], &b.data[i..i + 4]);
                if (0..3).all(|k| pb[k].abs_diff(sky[k]) <= 2) {
                    continue;
                }
                model += 1;
                if (0..3).any(|k| pa[k].abs_diff(pb[k]) > 8) {
                    changed += 1;
                    brighter += f64::from(luminance(pa) - luminance(pb));
                }
            }
        }
        let (scene, _) = glb_chunks(output(&outs, "scene.glb"));
        let images = scene["images"].as_array().map_or(0, Vec::len);
        let st = &report["stabilization"];
        println!(
            "{name} | {} | {} of {} | {:.4} | {:.2} MB | {:.2} MB | {model} | {:.1} % | {:+.3} | {} / {images} | {:.0} ({:.0}) | {} ({}, {})",
            report["input"]["triangles"],
            st["unconverged_steps"],
            st["steps"],
            st["residual_tan"].as_f64().unwrap(),
            output(&outs, "snow.glb").len() as f64 / 1e6,
            output(&outs, "scene.glb").len() as f64 / 1e6,
            100.0 * changed as f64 / model.max(1) as f64,
            brighter / changed.max(1) as f64,
            report["input"]["textures"].as_array().map_or(0, Vec::len),
            report["total_ms"].as_f64().unwrap(),
            report["timings"]
                .as_array()
                .unwrap()
                .iter()
                .find(|t| t["stage"] == "snowfall")
                .map_or(0.0, |t| t["ms"].as_f64().unwrap()),
            report["snow_meshes"]["triangles"],
            report["snow_meshes"]["collapsed"],
            report["snow_meshes"]["collapse_kept_regions"],
        );
        std::fs::write(out.join(format!("{name}.png")), output(&outs, "render.png")).unwrap();
        std::fs::write(
            out.join(format!("{name}_bare.png")),
            output(&bare, "render.png"),
        )
        .unwrap();
    }
}

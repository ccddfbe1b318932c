//! The `dust` pipeline end to end (SPEC §4): outputs, the shells' structure in the GLB, the
//! render's relation to the plain mesh render, determinism across thread counts, and a golden
//! render of a real mesh.

use std::path::PathBuf;

use phenomena_engine::dust::{self, DustParams};
use phenomena_engine::params::Limits;
use phenomena_engine::render::mesh::{render_meshes, MeshColors, MeshInstance, MeshLighting};
use phenomena_engine::NoControl;
use serde_json::{json, Value};

use crate::dust::model::box_on_floor;
use crate::support::gltf_validator::assert_valid;
use crate::support::golden::{assert_golden, decode_png};

fn data(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data")
        .join(rel)
}

fn run_file(file: &str, params: Value) -> Vec<phenomena_engine::Output> {
    let p = DustParams::from_json(&params, &Limits::default()).unwrap();
    let bytes = std::fs::read(data(file)).unwrap();
    let name = PathBuf::from(file);
    let mesh = dust::run::decode(
        &bytes,
        name.file_name().and_then(|n| n.to_str()),
        &[],
        &p,
        &Limits::default(),
    )
    .unwrap();
    dust::run(&mesh, &p, &NoControl).unwrap()
}

/// Renders a mesh with the pipeline for a look at the outputs:
/// `DUST_MESH=mesh/bunny00.ply DUST_PARAMS='{"width": 960}' DUST_OUT=/tmp/dust cargo test -p
/// phenomena-engine --test it dust::pipeline::preview -- --ignored --nocapture`.
#[test]
#[ignore]
fn preview() {
    let file = std::env::var("DUST_MESH").unwrap_or_else(|_| "mesh/bunny_npm.obj".into());
    let params: Value = std::env::var("DUST_PARAMS")
        .ok()
        .map(|s| serde_json::from_str(&s).unwrap())
        .unwrap_or_else(|| json!({}));
    let out = PathBuf::from(std::env::var("DUST_OUT").unwrap_or_else(|_| "/tmp/dust".into()));
    std::fs::create_dir_all(&out).unwrap();
    let t0 = std::time::Instant::now();
    let outs = run_file(&file, params);
    println!("{file}: {:.0} ms", t0.elapsed().as_secs_f64() * 1e3);
    for o in &outs {
        std::fs::write(out.join(&o.name), &o.bytes).unwrap();
        println!("{} {} bytes", o.name, o.bytes.len());
    }
    let report = outs.iter().find(|o| o.name == "report.json").unwrap();
    println!("{}", String::from_utf8_lossy(&report.bytes));
}

/// Small parameters: the whole pipeline in well under a second.
fn small(extra: Value) -> Value {
    let mut p = json!({
        "width": 160, "height": 120, "texture_size": 128, "fibers": 400, "shells": 8,
        "exposure_rays": 16,
    });
    for (k, v) in extra.as_object().unwrap() {
        p[k] = v.clone();
    }
    p
}

fn output<'a>(outs: &'a [phenomena_engine::Output], name: &str) -> &'a [u8] {
    &outs.iter().find(|o| o.name == name).unwrap().bytes
}

#[test]
fn outputs_are_complete_and_the_glb_is_valid() {
    let outs = run_file("mesh/teapot_npm.obj", small(json!({})));
    let names: Vec<&str> = outs.iter().map(|o| o.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "render.png",
            "fibers.png",
            "dust_amount.png",
            "dusty.glb",
            "report.json"
        ]
    );
    let render = decode_png(output(&outs, "render.png"));
    assert_eq!((render.width, render.height), (160, 120));
    let amount = decode_png(output(&outs, "dust_amount.png"));
    assert_eq!((amount.width, amount.height), (160, 120));
    // The preview of 8 textures of 128² in a 3 × 3 grid of 128² cells, 4-pixel gaps, opaque.
    let atlas = output(&outs, "fibers.png");
    let dec = png::Decoder::new(std::io::Cursor::new(atlas));
    let reader = dec.read_info().unwrap();
    let info = reader.info();
    assert_eq!((info.width, info.height), (3 * 132 - 4, 3 * 132 - 4));
    assert_eq!(info.color_type, png::ColorType::Rgba);

    let glb = output(&outs, "dusty.glb");
    assert_valid("dusty.glb", glb);
    let doc = glb_json(glb);
    let report: Value = serde_json::from_slice(output(&outs, "report.json")).unwrap();
    let nodes: Vec<&str> = doc["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| n["name"].as_str().unwrap())
        .collect();
    let shells: Vec<&&str> = nodes
        .iter()
        .filter(|n| n.starts_with("dust_shell_"))
        .collect();
    // Layer i has triangles where some vertex has D ≥ i/8; bottom first.
    let max_d = report["amount"]["max"].as_f64().unwrap();
    let layers = (max_d * 8.0 + 1e-6).floor() as usize;
    assert!(layers >= 6, "max D {max_d}");
    assert_eq!(shells.len(), layers, "{nodes:?}");
    assert_eq!(*shells[0], "dust_shell_001");
    assert_eq!(doc["images"].as_array().unwrap().len(), layers);
    for m in doc["materials"].as_array().unwrap() {
        if m["name"].as_str().unwrap().starts_with("dust_shell_") {
            assert_eq!(m["alphaMode"], "BLEND");
            assert!(m["pbrMetallicRoughness"]["baseColorTexture"].is_object());
        }
    }
    // Fewer triangles reach the upper layers.
    let tris = |name: &str| -> u64 {
        let i = nodes.iter().position(|n| *n == name).unwrap();
        let mesh = &doc["meshes"][doc["nodes"][i]["mesh"].as_u64().unwrap() as usize];
        let acc = mesh["primitives"][0]["indices"].as_u64().unwrap() as usize;
        doc["accessors"][acc]["count"].as_u64().unwrap() / 3
    };
    assert!(tris(&format!("dust_shell_{layers:03}")) < tris("dust_shell_001"));
    assert_eq!(report["fibers"]["per_shell"].as_array().unwrap().len(), 8);
    assert_eq!(report["surface"]["mapping"], "triplanar");
}

/// The JSON chunk of a GLB.
fn glb_json(glb: &[u8]) -> Value {
    assert_eq!(&glb[0..4], b"glTF");
    let len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    serde_json::from_slice(&glb[20..20 + len]).unwrap()
}

#[test]
fn same_seed_same_bytes_across_thread_counts() {
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| run_file("mesh/bunny_npm.obj", small(json!({"seed": 7}))))
    };
    let (one, three) = (run(1), run(3));
    for (a, b) in one.iter().zip(&three) {
        if a.name != "report.json" {
            assert!(
                a.bytes == b.bytes,
                "{} differs across thread counts",
                a.name
            );
        }
    }
    // Another seed changes the fibres and the bumps.
    let other = run_file("mesh/bunny_npm.obj", small(json!({"seed": 8})));
    assert_ne!(output(&one, "fibers.png"), output(&other, "fibers.png"));
    assert_ne!(output(&one, "render.png"), output(&other, "render.png"));
}

/// Camera looking at the box on the floor from the south-east, above.
fn box_params(k: f32) -> DustParams {
    DustParams::from_json(
        &json!({
            "width": 240, "height": 180, "stickiness": k, "texture_size": 128, "fibers": 600,
            "shells": 16, "exposure_rays": 32, "max_thickness": 0.08, "shadows": false,
            "camera": {"eye": [2.4, 2.2, 2.8], "target": [0.0, 0.3, 0.0], "fov_deg": 45},
        }),
        &Limits::default(),
    )
    .unwrap()
}

/// Pixel (x, y) of world point `p` for the camera of [`box_params`].
fn pixel_of(p: [f64; 3]) -> (u32, u32) {
    let params = box_params(1.0);
    let cam = params.view.camera.camera(None, 240.0 / 180.0);
    let ndc = cam.project_ndc(p, 240.0 / 180.0).unwrap();
    (
        ((ndc[0] + 1.0) * 0.5 * 240.0) as u32,
        ((1.0 - ndc[1]) * 0.5 * 180.0) as u32,
    )
}

#[test]
fn dust_is_drawn_where_d_is_and_nowhere_else() {
    let mesh = box_on_floor();
    let clean = dust::run(&mesh, &box_params(0.0), &NoControl).unwrap();
    let dusty = dust::run(&mesh, &box_params(1.0), &NoControl).unwrap();
    let (a, b) = (
        decode_png(output(&clean, "render.png")),
        decode_png(output(&dusty, "render.png")),
    );
    // Without dust (K = 0) no layer has a triangle: the render is the plain mesh render.
    let (mut m, mut normals) =
        phenomena_engine::dust::surface::crease_split(&mesh, [0.0, 1.0, 0.0]);
    phenomena_engine::dust::surface::refine(&mut m, &mut normals);
    let p = box_params(0.0);
    let cam = p.view.camera_for(&m, 240, 180);
    let plain = render_meshes(
        &[MeshInstance {
            positions: &m.positions,
            normals: Some(&normals),
            triangles: &m.triangles,
            colors: MeshColors::PerPart(&m.parts),
        }],
        &cam,
        &MeshLighting::for_view(&p.view, &m),
        240,
        180,
        &NoControl,
        (0.0, 1.0),
    )
    .unwrap();
    assert!(plain.data == a.data, "K = 0 differs from the plain render");
    let changed = |x: u32, y: u32| {
        let (pa, pb) = (a.pixel(x, y), b.pixel(x, y));
        pa.iter().zip(&pb).any(|(u, v)| u.abs_diff(*v) > 2)
    };
    // The box's top (D = K) and the open floor are dusty…
    for p in [
        [0.0, 1.0, 0.0],
        [0.2, 1.0, -0.2],
        [1.5, 0.0, -1.0],
        [1.2, 0.0, 0.0],
        [0.0, 0.0, 1.2],
        [-1.2, 0.0, 1.5],
    ] {
        let (x, y) = pixel_of(p);
        assert!(changed(x, y), "no dust at {p:?} (pixel {x}, {y})");
    }
    // …the vertical walls (N·U = 0) are not, away from the edges where the top's and the
    // floor's shells stand over them.
    for p in [[0.5, 0.5, 0.0], [0.0, 0.5, 0.5], [0.5, 0.4, 0.2]] {
        let (x, y) = pixel_of(p);
        assert!(!changed(x, y), "dust on a wall at {p:?} (pixel {x}, {y})");
    }
    let dusty_pixels = (0..180)
        .flat_map(|y| (0..240).map(move |x| (x, y)))
        .filter(|&(x, y)| changed(x, y))
        .count();
    assert!(dusty_pixels > 5000, "only {dusty_pixels} dusty pixels");
}

#[test]
fn golden_bunny() {
    let outs = run_file(
        "mesh/bunny_npm.obj",
        small(json!({"width": 240, "height": 180, "seed": 3})),
    );
    let img = decode_png(output(&outs, "render.png"));
    // Tolerance: 3/255 per channel, 0.5 % of pixels may differ more (silhouette pixels can flip
    // between CPUs with different FMA contraction, as for the other mesh goldens).
    assert_golden("dust", "bunny", &img, 3, 0.005);
}

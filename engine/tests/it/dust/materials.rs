//! Dust you can see on real models with their own materials (issue 18), with no dust parameters:
//! the default render differs from the same model without dust (`stickiness: 0`) on at least
//! 5 % of the model's pixels; the close-up (`close_up: true`) shows single fibres (its
//! high-frequency energy over the dusty pixels well above the same close-up without dust);
//! `fibers.png` is an opaque, visible preview of sensible size; `dusty.glb` keeps the input's
//! textures and validates; golden renders of three real models with their own materials.

use std::path::PathBuf;

use phenomena_engine::dust::{self, DustParams};
use phenomena_engine::params::Limits;
use phenomena_engine::render::image::RgbaImage;
use phenomena_engine::render::mesh::{render_meshes, MeshColors, MeshInstance, MeshLighting};
use phenomena_engine::{NoControl, Output};
use serde_json::{json, Value};

use crate::render::materials::{read_with_sidecars, test_data};
use crate::support::gltf_validator::assert_valid;
use crate::support::golden::{assert_golden, decode_png};

fn shared(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data")
        .join(rel)
}

fn output<'a>(outs: &'a [Output], name: &str) -> &'a [u8] {
    &outs.iter().find(|o| o.name == name).unwrap().bytes
}

/// Decodes `path` (with its sidecars) and runs the pipeline with `params`; also returns the mask
/// of the model's pixels in the render (the decoded mesh drawn from the same camera over a
/// transparent background).
fn run(path: &PathBuf, params: Value) -> (Vec<Output>, Vec<bool>) {
    let p = DustParams::from_json(&params, &Limits::default()).unwrap();
    let (bytes, side) = read_with_sidecars(path);
    let name = path.file_name().unwrap().to_str().unwrap();
    let mesh = dust::run::decode(&bytes, Some(name), &side, &p, &Limits::default()).unwrap();
    let outs = dust::run(&mesh, &p, &NoControl).unwrap();
    let (w, h) = (p.view.width, p.view.height);
    let camera = p.view.camera_for(&mesh, w, h);
    let light = MeshLighting {
        background: Some([0.0; 4]),
        shadows: false,
        samples: 1,
        ..MeshLighting::default()
    };
    let inst = MeshInstance {
        positions: &mesh.positions,
        normals: None,
        triangles: &mesh.triangles,
        colors: MeshColors::Uniform([0.5; 3]),
    };
    let img = render_meshes(&[inst], &camera, &light, w, h, &NoControl, (0.0, 1.0)).unwrap();
    let mask = img.data.chunks_exact(4).map(|p| p[3] > 0).collect();
    (outs, mask)
}

/// Share of `mask`'s pixels where `a` and `b` differ by at least `tol` in some channel.
fn differing_share(a: &RgbaImage, b: &RgbaImage, mask: &[bool], tol: u8) -> f64 {
    let (mut n, mut d) = (0usize, 0usize);
    for ((pa, pb), &m) in a.data.chunks(4).zip(b.data.chunks(4)).zip(mask) {
        if m {
            n += 1;
            if pa.iter().zip(pb).any(|(x, y)| x.abs_diff(*y) >= tol) {
                d += 1;
            }
        }
    }
    d as f64 / n.max(1) as f64
}

/// Mean absolute 4-neighbour Laplacian of the luminance over the pixels where `select` holds
/// (and whose neighbours are in the image): the image's high-frequency energy there.
fn laplacian_energy(img: &RgbaImage, select: &[bool]) -> f64 {
    let (w, h) = (img.width as usize, img.height as usize);
    let lum = |x: usize, y: usize| {
        let i = (y * w + x) * 4;
        0.2126 * f64::from(img.data[i])
            + 0.7152 * f64::from(img.data[i + 1])
            + 0.0722 * f64::from(img.data[i + 2])
    };
    let (mut sum, mut n) = (0.0, 0usize);
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            if select[y * w + x] {
                let l =
                    4.0 * lum(x, y) - lum(x - 1, y) - lum(x + 1, y) - lum(x, y - 1) - lum(x, y + 1);
                sum += l.abs();
                n += 1;
            }
        }
    }
    sum / n.max(1) as f64
}

/// The real models of the criteria: a textured GLB, two textured OBJ + MTL, a PLY with vertex
/// colours, and three of `shared/data` (grey: an OBJ scan, a GLB scene, the Stanford bunny PLY).
fn models() -> Vec<PathBuf> {
    vec![
        test_data("mesh/box_textured.glb"),
        test_data("mesh/spider/spider.obj"),
        test_data("mesh/bench/bench.obj"),
        test_data("mesh/colored_airplane.ply"),
        shared("mesh/bunny_npm.obj"),
        shared("mesh/inventor_table.glb"),
        shared("mesh/bunny00.ply"),
    ]
}

/// Image size of the criteria runs (the dust parameters are all defaults).
fn view() -> Value {
    json!({"width": 480, "height": 320})
}

#[test]
fn default_dust_changes_at_least_5_percent_of_the_model_and_the_close_up_shows_fibres() {
    for path in models() {
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let (dusty, mask) = run(&path, view());
        let mut clean_params = view();
        clean_params["stickiness"] = json!(0.0);
        let (clean, _) = run(&path, clean_params);
        let a = decode_png(output(&dusty, "render.png"));
        let b = decode_png(output(&clean, "render.png"));
        let model = mask.iter().filter(|&&m| m).count();
        assert!(model > 2000, "{name}: {model} model pixels");
        let share = differing_share(&a, &b, &mask, 8);
        println!(
            "{name}: default dust changes {:.1} % of {model} model pixels",
            share * 100.0
        );
        assert!(
            share >= 0.05,
            "{name}: dust changes only {:.2} %",
            share * 100.0
        );

        // Close-up: the fibres' high-frequency energy where the dust lies.
        let mut close = view();
        close["close_up"] = json!(true);
        let (near, _) = run(&path, close.clone());
        close["stickiness"] = json!(0.0);
        let (near_clean, _) = run(&path, close);
        let a = decode_png(output(&near, "render.png"));
        let b = decode_png(output(&near_clean, "render.png"));
        let all = vec![true; (a.width * a.height) as usize];
        let differs: Vec<bool> = a
            .data
            .chunks(4)
            .zip(b.data.chunks(4))
            .map(|(p, q)| p.iter().zip(q).any(|(x, y)| x.abs_diff(*y) >= 8))
            .collect();
        let dusty_share = differing_share(&a, &b, &all, 8);
        let (ea, eb) = (
            laplacian_energy(&a, &differs),
            laplacian_energy(&b, &differs),
        );
        println!(
            "{name}: close-up dust on {:.0} % of the image, high-frequency energy {ea:.2} vs \
             {eb:.2} without dust",
            dusty_share * 100.0
        );
        assert!(dusty_share >= 0.2, "{name}: close-up dust on {dusty_share}");
        assert!(ea >= 1.5 * eb + 1.0, "{name}: fibres {ea:.2} vs {eb:.2}");
    }
}

#[test]
fn fibers_png_is_an_opaque_visible_preview() {
    let (outs, _) = run(&test_data("mesh/box_textured.glb"), view());
    let img = decode_png(output(&outs, "fibers.png"));
    assert!(img.data.chunks(4).all(|p| p[3] == 255), "opaque");
    // 32 shells of 512²: 6 × 6 cells of 128² with 4-pixel gaps.
    assert_eq!((img.width, img.height), (6 * 132 - 4, 6 * 132 - 4));
    let bytes = output(&outs, "fibers.png").len();
    assert!(bytes < 3 << 19, "{bytes} bytes");
    // The first cell (the densest shell) shows fibres: a good share of its pixels is lighter
    // than the background.
    let lit = (0..128)
        .flat_map(|y| (0..128).map(move |x| (x, y)))
        .filter(|&(x, y)| {
            let i = ((y * img.width + x) * 4) as usize;
            img.data[i] > 38 + 40
        })
        .count();
    assert!(lit > 128 * 128 / 20, "{lit} fibre pixels in the first cell");
}

#[test]
fn dusty_glb_keeps_the_input_textures_and_validates() {
    let (outs, _) = run(
        &test_data("mesh/spider/spider.obj"),
        json!({"width": 160, "height": 120, "shells": 4, "texture_size": 64, "fibers": 200}),
    );
    let glb = output(&outs, "dusty.glb");
    assert_valid("dusty_spider.glb", glb);
    let len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let doc: Value = serde_json::from_slice(&glb[20..20 + len]).unwrap();
    let jpegs = doc["images"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|i| i["mimeType"] == "image/jpeg")
        .count();
    // The four textures the spider's parts use (its MTL names a fifth no part uses).
    assert_eq!(jpegs, 4);
    let report: Value = serde_json::from_slice(output(&outs, "report.json")).unwrap();
    assert_eq!(report["input"]["textures"].as_array().unwrap().len(), 4);
    // Every file the OBJ names was found (an up-axis note may stand there).
    let notes = report["input"]["notes"].as_array().unwrap();
    assert!(
        notes
            .iter()
            .all(|n| n.as_str().unwrap().starts_with("up axis")),
        "{notes:?}"
    );
}

#[test]
fn golden_real_models_with_their_materials() {
    for (case, path) in [
        ("box_textured", test_data("mesh/box_textured.glb")),
        ("bench", test_data("mesh/bench/bench.obj")),
        ("colored_airplane", test_data("mesh/colored_airplane.ply")),
    ] {
        let (outs, _) = run(&path, json!({"width": 320, "height": 240}));
        let img = decode_png(output(&outs, "render.png"));
        // Tolerance as for the other mesh goldens (silhouette pixels may flip between CPUs).
        assert_golden("dust", case, &img, 3, 0.005);
    }
}

/// The criteria on the held-out models (not committed; `/work/heldout/mesh`, README there), with
/// the renders written for a look:
/// `cargo test -p phenomena-engine --test it dust::materials::heldout_survey -- --ignored
/// --nocapture` (HELDOUT=dir, OUT=dir to change the folders).
#[test]
#[ignore]
fn heldout_survey() {
    let dir = PathBuf::from(std::env::var("HELDOUT").unwrap_or("/work/heldout/mesh".into()));
    let out = PathBuf::from(std::env::var("OUT").unwrap_or("/tmp/dust_survey".into()));
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
    for path in files {
        // The file name with its extension: a model shipped as both `x.glb` and `x/x.obj` (the
        // textured bunny) writes two sets of renders, not one set twice.
        let name = path
            .file_name()
            .unwrap()
            .to_string_lossy()
            .replace('.', "_");
        let t0 = std::time::Instant::now();
        let p = DustParams::from_json(&view(), &Limits::default()).unwrap();
        let (bytes, side) = read_with_sidecars(&path);
        let fname = path.file_name().unwrap().to_str().unwrap();
        if let Err(e) = dust::run::decode(&bytes, Some(fname), &side, &p, &Limits::default()) {
            println!("{name}: refused: {e}");
            continue;
        }
        let (dusty, mask) = run(&path, view());
        let mut clean_params = view();
        clean_params["stickiness"] = json!(0.0);
        let (clean, _) = run(&path, clean_params);
        let a = decode_png(output(&dusty, "render.png"));
        let b = decode_png(output(&clean, "render.png"));
        let share = differing_share(&a, &b, &mask, 8);
        let mut close = view();
        close["close_up"] = json!(true);
        let (near, _) = run(&path, close.clone());
        close["stickiness"] = json!(0.0);
        let (near_clean, _) = run(&path, close);
        let c = decode_png(output(&near, "render.png"));
        let d = decode_png(output(&near_clean, "render.png"));
        let differs: Vec<bool> = c
            .data
            .chunks(4)
            .zip(d.data.chunks(4))
            .map(|(p, q)| p.iter().zip(q).any(|(x, y)| x.abs_diff(*y) >= 8))
            .collect();
        let (ec, ed) = (
            laplacian_energy(&c, &differs),
            laplacian_energy(&d, &differs),
        );
        let report: Value = serde_json::from_slice(output(&dusty, "report.json")).unwrap();
        println!(
            "{name}: model {} px, dust changes {:.1} %; close-up dust {:.0} %, HF {ec:.2} vs \
             {ed:.2}; D mean {:.3}, dusty vertices {:.2}; notes {}; {:.1} s",
            mask.iter().filter(|&&m| m).count(),
            share * 100.0,
            100.0 * differs.iter().filter(|&&x| x).count() as f64 / differs.len() as f64,
            report["amount"]["mean"].as_f64().unwrap_or(f64::NAN),
            report["amount"]["dusty_vertex_fraction"]
                .as_f64()
                .unwrap_or(f64::NAN),
            report["input"]["notes"],
            t0.elapsed().as_secs_f64()
        );
        std::fs::write(
            out.join(format!("{name}_amount.png")),
            output(&dusty, "dust_amount.png"),
        )
        .unwrap();
        for (suffix, outs) in [
            ("", &dusty),
            ("_clean", &clean),
            ("_close", &near),
            ("_close_clean", &near_clean),
        ] {
            std::fs::write(
                out.join(format!("{name}{suffix}.png")),
                output(outs, "render.png"),
            )
            .unwrap();
        }
        std::fs::write(
            out.join(format!("{name}_fibers.png")),
            output(&dusty, "fibers.png"),
        )
        .unwrap();
    }
}

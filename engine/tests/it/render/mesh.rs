//! Outputs of the mesh pipelines: the general GLB writer (`formats::mesh_glb`), the mesh renderer
//! (`render::mesh`) and the animated PNG encoder.

use phenomena_engine::formats::mesh_glb::{mesh_glb, scene_nodes, GlbMaterial, GlbNode};
use phenomena_engine::formats::png_write::encode_rgba;
use phenomena_engine::geom::mesh::{Mesh, MeshPart};
use phenomena_engine::render::RgbaImage;
use serde_json::{json, Value};

use crate::support::gltf_validator::validate_glb;

/// The JSON chunk of a GLB.
fn glb_json(glb: &[u8]) -> Value {
    assert_eq!(&glb[0..4], b"glTF");
    assert_eq!(
        u32::from_le_bytes(glb[8..12].try_into().unwrap()) as usize,
        glb.len()
    );
    assert_eq!(glb.len() % 4, 0);
    let len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    assert_eq!(&glb[16..20], b"JSON");
    serde_json::from_slice(&glb[20..20 + len]).unwrap()
}

fn assert_valid(name: &str, glb: &[u8]) {
    let report = validate_glb(name, glb);
    let errors = report["issues"]["numErrors"].as_u64().unwrap();
    assert_eq!(
        errors,
        0,
        "{name}: {}",
        serde_json::to_string_pretty(&report["issues"]).unwrap()
    );
}

/// Positions, normals, UVs and triangles.
type Cube = (Vec<[f32; 3]>, Vec<[f32; 3]>, Vec<[f32; 2]>, Vec<[u32; 3]>);

/// A unit cube with per-face vertices: 24 positions, normals, UVs, 12 triangles (CCW outside).
fn cube() -> Cube {
    let (mut p, mut n, mut uv, mut t) = (vec![], vec![], vec![], vec![]);
    for axis in 0..3 {
        for s in [-1.0f32, 1.0] {
            let mut nn = [0.0; 3];
            nn[axis] = s;
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let base = p.len() as u32;
            for (a, b) in [(-1.0f32, -1.0f32), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                let mut q = [0.0f32; 3];
                q[axis] = 0.5 * s;
                q[u] = 0.5 * a;
                q[v] = 0.5 * b;
                p.push(q);
                n.push(nn);
                uv.push([(a + 1.0) * 0.5, (b + 1.0) * 0.5]);
            }
            // (u × v) = +axis, so (0,1,2) is CCW seen from +axis; flip for the − face.
            if s > 0.0 {
                t.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]]);
            } else {
                t.extend([[base, base + 2, base + 1], [base, base + 3, base + 2]]);
            }
        }
    }
    (p, n, uv, t)
}

#[test]
fn glb_textured_cube_is_valid() {
    let (p, n, uv, t) = cube();
    let mut tex = RgbaImage::new_filled(4, 4, [200, 40, 40, 128]);
    tex.set_pixel(1, 2, [0, 255, 0, 255]);
    let png = encode_rgba(&tex);
    let node = GlbNode {
        name: "cube",
        positions: &p,
        normals: Some(&n),
        uvs: Some(&uv),
        colors: None,
        triangles: &t,
        custom: &[],
        groups: &[],
        overlays: &[],
        material: GlbMaterial {
            name: "glass".into(),
            base_color: [1.0, 1.0, 1.0, 0.5],
            alpha_blend: true,
            double_sided: false,
            texture_png: Some(png.clone()),
            ..GlbMaterial::default()
        },
    };
    let glb = mesh_glb(&[node], Some(json!({"pipeline": "test"})));
    let doc = glb_json(&glb);
    assert_eq!(doc["asset"]["generator"], "phenomena");
    assert_eq!(doc["extras"]["pipeline"], "test");
    assert_eq!(doc["nodes"].as_array().unwrap().len(), 1);
    assert_eq!(doc["nodes"][0]["name"], "cube");
    let prim = &doc["meshes"][0]["primitives"][0];
    let attrs = prim["attributes"].as_object().unwrap();
    assert!(attrs.contains_key("NORMAL") && attrs.contains_key("TEXCOORD_0"));
    let pos = &doc["accessors"][prim["attributes"]["POSITION"].as_u64().unwrap() as usize];
    assert_eq!(pos["count"], 24);
    assert_eq!(pos["min"], json!([-0.5, -0.5, -0.5]));
    assert_eq!(pos["max"], json!([0.5, 0.5, 0.5]));
    assert_eq!(
        doc["accessors"][prim["indices"].as_u64().unwrap() as usize]["count"],
        36
    );
    let mat = &doc["materials"][0];
    assert_eq!(mat["name"], "glass");
    assert_eq!(mat["alphaMode"], "BLEND");
    assert_eq!(mat["pbrMetallicRoughness"]["baseColorTexture"]["index"], 0);
    assert_eq!(doc["samplers"][0]["wrapS"], 10497);
    assert_eq!(doc["images"][0]["mimeType"], "image/png");
    let view = &doc["bufferViews"][doc["images"][0]["bufferView"].as_u64().unwrap() as usize];
    assert_eq!(view["byteLength"], png.len());
    for v in doc["bufferViews"].as_array().unwrap() {
        assert_eq!(v["byteOffset"].as_u64().unwrap() % 4, 0);
    }
    assert_valid("cube.glb", &glb);
}

#[test]
fn glb_mesh_parts_become_colored_nodes() {
    // Three parts of one mesh (two quads and an empty part) sharing no vertices.
    let positions = vec![
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 0.0, 1.0],
        [0.0, 0.0, 1.0],
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
        [1.0, 2.0, 0.0],
        [0.0, 2.0, 0.0],
    ];
    let part = |name: &str, first: usize, count: usize, c: [f32; 4]| MeshPart {
        name: name.into(),
        first_triangle: first,
        triangle_count: count,
        base_color: c,
        texture: None,
    };
    let mesh = Mesh {
        positions,
        triangles: vec![[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7]],
        normals: None,
        uvs: Some((0..8).map(|i| [i as f32 * 0.1, 0.5]).collect()),
        parts: vec![
            part("floor", 0, 2, [0.5, 0.5, 0.5, 1.0]),
            part("nothing", 2, 0, [1.0, 0.0, 0.0, 1.0]),
            part("wall", 2, 2, [0.8, 0.2, 0.1, 1.0]),
        ],
        ..Mesh::default()
    };
    let parts = scene_nodes(&mesh);
    assert_eq!(parts.len(), 3);
    assert_eq!(parts[2].positions.len(), 4);
    assert_eq!(parts[2].triangles, vec![[0, 1, 2], [0, 2, 3]]);
    assert_eq!(parts[2].positions[0], [0.0, 1.0, 0.0]);
    assert_eq!(parts[2].uvs.as_ref().unwrap()[0], [0.4, 0.5]);
    let nodes: Vec<GlbNode> = parts.iter().map(|p| p.node()).collect();
    let glb = mesh_glb(&nodes, None);
    let doc = glb_json(&glb);
    let names: Vec<&str> = doc["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| n["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["floor", "wall"]);
    assert_eq!(doc["meshes"].as_array().unwrap().len(), 2);
    assert_eq!(doc["scenes"][0]["nodes"], json!([0, 1]));
    assert_eq!(
        doc["materials"][1]["pbrMetallicRoughness"]["baseColorFactor"],
        json!([0.8f32, 0.2f32, 0.1f32, 1.0f32])
    );
    assert_eq!(doc["materials"][1]["doubleSided"], true);
    assert_valid("parts.glb", &glb);

    // No non-empty node: still a valid file.
    let empty = mesh_glb(&nodes[..0], None);
    assert_eq!(glb_json(&empty)["scenes"][0], json!({}));
    assert_valid("empty.glb", &empty);
}

#[test]
fn glb_vertex_colors_are_valid() {
    let (p, n, _, t) = cube();
    let colors: Vec<[f32; 4]> = p
        .iter()
        .map(|q| [q[0] + 0.5, q[1] + 0.5, q[2] + 0.5, 1.0])
        .collect();
    // Unnormalised normals are renormalised.
    let n2: Vec<[f32; 3]> = n.iter().map(|v| v.map(|c| c * 3.0)).collect();
    let node = GlbNode {
        name: "snow",
        positions: &p,
        normals: Some(&n2),
        uvs: None,
        colors: Some(&colors),
        triangles: &t,
        custom: &[],
        groups: &[],
        overlays: &[],
        material: GlbMaterial::default(),
    };
    let glb = mesh_glb(&[node], None);
    let doc = glb_json(&glb);
    let prim = &doc["meshes"][0]["primitives"][0];
    let c = &doc["accessors"][prim["attributes"]["COLOR_0"].as_u64().unwrap() as usize];
    assert_eq!(
        (c["type"].as_str(), c["count"].as_u64()),
        (Some("VEC4"), Some(24))
    );
    assert_eq!(doc["materials"][0]["name"], "snow");
    assert_valid("colours.glb", &glb);
}

// ---- render::mesh ----

use phenomena_engine::geom::camera::Camera;
use phenomena_engine::geom::sun_direction;
use phenomena_engine::render::image::linear_to_srgb8;
use phenomena_engine::render::mesh::{
    frame_camera, render_meshes, MeshColors, MeshInstance, MeshLighting,
};
use phenomena_engine::NoControl;

/// A horizontal square of side `2·half` centred at (cx, y, cz), CCW seen from above.
fn quad(cx: f32, y: f32, cz: f32, half: f32) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    (
        vec![
            [cx - half, y, cz - half],
            [cx - half, y, cz + half],
            [cx + half, y, cz + half],
            [cx + half, y, cz - half],
        ],
        vec![[0, 1, 2], [0, 2, 3]],
    )
}

/// Pixel of world point `p` in a `w × h` image.
fn pixel_of(cam: &Camera, p: [f64; 3], w: u32, h: u32) -> (u32, u32) {
    let [x, y] = cam.project_ndc(p, f64::from(w) / f64::from(h)).unwrap();
    (
        ((x + 1.0) * 0.5 * f64::from(w)) as u32,
        ((1.0 - y) * 0.5 * f64::from(h)) as u32,
    )
}

fn plain_light() -> MeshLighting {
    MeshLighting {
        sun_dir: [0.0, 1.0, 0.0],
        sun_color: [0.7, 0.7, 0.7],
        ambient: 0.2,
        shadows: false,
        fog_density: 0.0,
        ..MeshLighting::default()
    }
}

#[test]
fn render_flat_quad_is_albedo_times_sun_plus_ambient() {
    let (p, t) = quad(0.0, 0.0, 0.0, 1.0);
    // Clockwise copy too: two-sided lighting must give the same colour.
    let flipped: Vec<[u32; 3]> = t.iter().map(|&[a, b, c]| [a, c, b]).collect();
    for tris in [&t, &flipped] {
        let inst = MeshInstance {
            positions: &p,
            normals: None,
            triangles: tris,
            colors: MeshColors::Uniform([0.5, 0.3, 0.1]),
        };
        let cam = Camera::orbit([0.0; 3], 30.0, 60.0, 4.0, 40.0);
        let img = render_meshes(
            &[inst],
            &cam,
            &plain_light(),
            64,
            48,
            &NoControl,
            (0.0, 1.0),
        )
        .unwrap();
        let px = img.pixel(32, 24);
        let want = [0.5f32, 0.3, 0.1].map(|a| linear_to_srgb8(a * 0.9));
        for k in 0..3 {
            assert!(
                (i32::from(px[k]) - i32::from(want[k])).abs() <= 1,
                "{px:?} vs {want:?}"
            );
        }
        assert_eq!(px[3], 255);
        // The corner is sky.
        assert_ne!(img.pixel(0, 0), px);
    }
}

/// A unit box on a 10 m plane, sun from the east (+X) 30° up.
fn box_scene() -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let (mut p, mut t) = quad(0.0, 0.0, 0.0, 5.0);
    let (bp, _, _, bt) = cube();
    let base = p.len() as u32;
    p.extend(bp.iter().map(|q| [q[0], q[1] + 0.5, q[2]]));
    t.extend(bt.iter().map(|tr| tr.map(|i| i + base)));
    (p, t)
}

#[test]
fn render_box_casts_shadow_away_from_the_sun() {
    let (p, t) = box_scene();
    let inst = MeshInstance {
        positions: &p,
        normals: None,
        triangles: &t,
        colors: MeshColors::Uniform([0.6; 3]),
    };
    let light = MeshLighting {
        sun_dir: sun_direction(90.0, 30.0),
        shadows: true,
        ..plain_light()
    };
    let (w, h) = (160, 120);
    let cam = Camera::orbit([0.0; 3], 0.0, 70.0, 12.0, 50.0);
    let img = render_meshes(&[inst], &cam, &light, w, h, &NoControl, (0.0, 1.0)).unwrap();
    let lum = |q: [f64; 3]| {
        let (x, y) = pixel_of(&cam, q, w, h);
        img.pixel(x, y)[0]
    };
    // Shadow: 1 m tall box at 30° → 1.73 m long, west of the box (x from −0.5 to −2.2).
    let shadowed = lum([-1.3, 0.0, 0.0]);
    let lit_east = lum([1.3, 0.0, 0.0]);
    let lit_north = lum([0.0, 0.0, -2.5]);
    assert!(shadowed + 40 < lit_east, "{shadowed} vs {lit_east}");
    assert!((i32::from(lit_east) - i32::from(lit_north)).abs() <= 1);
    // Without shadows the same spot is lit.
    let light2 = MeshLighting {
        shadows: false,
        ..light
    };
    let img2 = render_meshes(&[inst], &cam, &light2, w, h, &NoControl, (0.0, 1.0)).unwrap();
    let (x, y) = pixel_of(&cam, [-1.3, 0.0, 0.0], w, h);
    assert_eq!(img2.pixel(x, y)[0], lit_east);
}

#[test]
fn render_fog_pulls_far_surfaces_to_the_fog_color() {
    let (mut p, mut t) = quad(0.0, 0.0, -1.0, 0.5);
    let (p2, t2) = quad(0.0, 0.0, -30.0, 5.0);
    t.extend(t2.iter().map(|tr| tr.map(|i| i + 4)));
    p.extend(p2);
    let inst = MeshInstance {
        positions: &p,
        normals: None,
        triangles: &t,
        colors: MeshColors::Uniform([0.2, 0.2, 0.2]),
    };
    let light = MeshLighting {
        fog_density: 0.05,
        fog_color: [0.9, 0.9, 0.9],
        ..plain_light()
    };
    let cam = Camera {
        eye: [0.0, 1.5, 2.0],
        target: [0.0, 0.0, -10.0],
        up: [0.0, 1.0, 0.0],
        fov_deg: 60.0,
    };
    let (w, h) = (120, 90);
    let img = render_meshes(&[inst], &cam, &light, w, h, &NoControl, (0.0, 1.0)).unwrap();
    let at = |q: [f64; 3]| {
        let (x, y) = pixel_of(&cam, q, w, h);
        img.pixel(x, y)[0]
    };
    let fog = linear_to_srgb8(0.9);
    let (near, far) = (at([0.0, 0.0, -1.0]), at([0.0, 0.0, -30.0]));
    assert!(fog - far < fog - near, "near {near} far {far} fog {fog}");
    // The near one is close to the unfogged value: 0.2·0.9 at e^(−0.05·d), d its distance from
    // the eye less the distance from the eye to the scene's bounding box (fog counts from the
    // scene's near side).
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for q in &p {
        for k in 0..3 {
            lo[k] = lo[k].min(f64::from(q[k]));
            hi[k] = hi[k].max(f64::from(q[k]));
        }
    }
    let start = (0..3)
        .map(|k| {
            (lo[k] - cam.eye[k])
                .max(cam.eye[k] - hi[k])
                .max(0.0)
                .powi(2)
        })
        .sum::<f64>()
        .sqrt();
    let d = (1.5f64 * 1.5 + 3.0 * 3.0).sqrt() - start;
    let f = (-0.05 * d).exp() as f32;
    let want = linear_to_srgb8(0.18 * f + 0.9 * (1.0 - f));
    assert!(
        (i32::from(near) - i32::from(want)).abs() <= 2,
        "{near} vs {want}"
    );
}

#[test]
fn render_is_the_same_on_one_and_two_threads() {
    let (p, t) = box_scene();
    let colors: Vec<[f32; 3]> = p
        .iter()
        .map(|q| [0.3 + 0.05 * q[0], 0.5, 0.3 + 0.05 * q[2]])
        .collect();
    let inst = MeshInstance {
        positions: &p,
        normals: None,
        triangles: &t,
        colors: MeshColors::PerVertex(&colors),
    };
    let light = MeshLighting {
        fog_density: 0.01,
        ..MeshLighting::default()
    };
    let cam = frame_camera(([-5.0, 0.0, -5.0], [5.0, 1.0, 5.0]), 30.0, 35.0, 40.0, 1.5);
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| render_meshes(&[inst], &cam, &light, 150, 100, &NoControl, (0.0, 1.0)))
            .unwrap()
    };
    assert_eq!(run(1).data, run(2).data);
}

#[test]
fn render_fzk_haus() {
    use phenomena_engine::formats::mesh::{decode_mesh, MeshOptions};
    let path = format!(
        "{}/../../shared/data/mesh/fzk_haus.glb",
        env!("CARGO_MANIFEST_DIR")
    );
    let Ok(bytes) = std::fs::read(&path) else {
        eprintln!("skipped: {path} missing");
        return;
    };
    let mesh = decode_mesh(&bytes, Some("fzk_haus.glb"), &MeshOptions::default()).unwrap();
    let inst = MeshInstance {
        positions: &mesh.positions,
        normals: mesh.normals.as_deref(),
        triangles: &mesh.triangles,
        colors: MeshColors::PerPart(&mesh.parts),
    };
    let light = MeshLighting {
        fog_density: 0.005,
        ..MeshLighting::default()
    };
    let (w, h) = (640, 480);
    let cam = frame_camera(mesh.bounds().unwrap(), 200.0, 30.0, 40.0, 640.0 / 480.0);
    let t0 = std::time::Instant::now();
    let img = render_meshes(&[inst], &cam, &light, w, h, &NoControl, (0.0, 1.0)).unwrap();
    eprintln!(
        "fzk_haus: {} triangles, {:?}",
        mesh.triangles.len(),
        t0.elapsed()
    );
    let out = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/mesh_render");
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("fzk_haus.png"), encode_rgba(&img)).unwrap();
    // The house covers the middle of the frame.
    let sky = img.pixel(0, 0);
    assert_ne!(img.pixel(w / 2, h / 2), sky);
}

// ---- formats::png_write::encode_apng ----

#[test]
fn apng_decodes_as_animated_with_every_frame() {
    use phenomena_engine::formats::png_write::encode_apng;
    let frames: Vec<RgbaImage> = (0..5u8)
        .map(|k| {
            let mut f = RgbaImage::new_filled(7, 3, [k * 40, 10, 200 - k * 30, 255]);
            f.set_pixel(k as u32, 1, [255, 255, 255, 128]);
            f
        })
        .collect();
    let bytes = encode_apng(&frames, 250);
    let mut r = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .unwrap();
    let actl = r.info().animation_control.unwrap();
    assert_eq!((actl.num_frames, actl.num_plays), (5, 0));
    let mut buf = vec![0; r.output_buffer_size()];
    for f in &frames {
        let info = r.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (7, 3));
        let fc = r.info().frame_control.unwrap();
        assert_eq!((fc.delay_num, fc.delay_den), (250, 1000));
        assert_eq!(&buf[..info.buffer_size()], &f.data[..]);
    }
    assert!(r.next_frame(&mut buf).is_err());
}

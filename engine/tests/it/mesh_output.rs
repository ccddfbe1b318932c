//! Outputs of the mesh pipelines: the general GLB writer (`formats::mesh_glb`), the mesh renderer
//! (`render::mesh`) and the animated PNG encoder.

use phenomena_engine::formats::mesh_glb::{mesh_glb, scene_nodes, GlbMaterial, GlbNode};
use phenomena_engine::formats::png_write::encode_rgba;
use phenomena_engine::geom::mesh::{Mesh, MeshPart};
use phenomena_engine::render::RgbaImage;
use serde_json::{json, Value};

use crate::gltf_validator::validate_glb;

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

/// A unit cube with per-face vertices: 24 positions, normals, UVs, 12 triangles (CCW outside).
fn cube() -> (Vec<[f32; 3]>, Vec<[f32; 3]>, Vec<[f32; 2]>, Vec<[u32; 3]>) {
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
fn glb_mesh_parts_become_coloured_nodes() {
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
fn glb_vertex_colours_are_valid() {
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

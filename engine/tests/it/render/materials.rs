//! The input's materials (issue 18): glTF base colour textures, OBJ + MTL (`Kd`, `map_Kd`) as
//! sidecar files, PLY vertex colours — read, drawn by the mesh renderer, carried into the GLB
//! outputs (valid per the Khronos validator), and the graceful and the refused cases.
//!
//! Data: `tests/data/mesh/` (README.md there: Khronos BoxTextured, the assimp spider with its
//! MTL and JPEG textures, MeshLab's coloured airplane PLY).

use std::path::PathBuf;
use std::sync::Arc;

use phenomena_engine::formats::mesh::texture::{decode_image, ImageError};
use phenomena_engine::formats::mesh::{
    decode_mesh, decode_mesh_with, gather_sidecars, MeshOptions, Sidecars,
};
use phenomena_engine::formats::mesh_glb::{mesh_glb, scene_nodes, GlbNode};
use phenomena_engine::formats::png_write::encode_rgba;
use phenomena_engine::geom::camera::Camera;
use phenomena_engine::geom::mesh::{Mesh, MeshPart, Texture, TextureWrap};
use phenomena_engine::render::image::RgbaImage;
use phenomena_engine::render::mesh::{render_meshes, MeshColors, MeshInstance, MeshLighting};
use phenomena_engine::{InputError, NoControl};
use serde_json::Value;

use crate::support::gltf_validator::assert_valid;

pub(crate) fn test_data(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/data")
        .join(rel)
}

/// Reads a mesh with its sidecars from beside it, as the CLI does.
pub(crate) fn read_with_sidecars(path: &PathBuf) -> (Vec<u8>, Vec<(String, Vec<u8>)>) {
    let bytes = std::fs::read(path).unwrap();
    let dir = path.parent().unwrap().to_path_buf();
    let name = path.file_name().unwrap().to_str().unwrap();
    let side = gather_sidecars(&bytes, Some(name), &mut |rel| {
        std::fs::read(dir.join(rel)).ok()
    });
    (bytes, side)
}

fn glb_json(glb: &[u8]) -> Value {
    let len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    serde_json::from_slice(&glb[20..20 + len]).unwrap()
}

#[test]
fn glb_base_color_texture_is_decoded_with_its_uvs() {
    let bytes = std::fs::read(test_data("mesh/box_textured.glb")).unwrap();
    let mesh = decode_mesh(&bytes, Some("box_textured.glb"), &MeshOptions::default()).unwrap();
    assert_eq!(mesh.textures.len(), 1);
    let t = &mesh.textures[0];
    assert_eq!(t.mime, "image/png");
    assert_eq!(t.texels.len(), (t.width * t.height) as usize);
    assert!(t.width >= 64 && t.height >= 64, "{}×{}", t.width, t.height);
    assert!(mesh.uvs.is_some());
    assert!(mesh.parts.iter().all(|p| p.texture == Some(0)));
    assert!(mesh.has_textures());
    assert!(mesh.notes.is_empty(), "{:?}", mesh.notes);
    // The texture is not one flat colour (the Khronos logo on a pattern).
    let first = t.texels[0];
    let varied = t.texels.iter().filter(|&&c| c != first).count();
    assert!(varied > t.texels.len() / 10, "{varied} texels differ");
}

#[test]
fn texture_over_the_pixel_limit_is_refused_before_decoding() {
    let bytes = std::fs::read(test_data("mesh/box_textured.glb")).unwrap();
    let opts = MeshOptions {
        max_texture_pixels: 1000,
        ..MeshOptions::default()
    };
    let err = decode_mesh(&bytes, Some("box_textured.glb"), &opts).unwrap_err();
    assert!(
        matches!(
            err,
            InputError::TooLarge {
                what: "texture pixels",
                max: 1000,
                ..
            }
        ),
        "{err:?}"
    );
    // The limit comes from the header: a PNG whose header claims 60,000² but has no data.
    let mut png = b"\x89PNG\r\n\x1a\n\x00\x00\x00\x0dIHDR".to_vec();
    png.extend_from_slice(&60_000u32.to_be_bytes());
    png.extend_from_slice(&60_000u32.to_be_bytes());
    png.extend_from_slice(&[8, 6, 0, 0, 0]);
    let crc = crc32(&png[12..29]);
    png.extend_from_slice(&crc.to_be_bytes());
    let r = decode_image(
        Arc::from(png),
        "huge",
        [TextureWrap::Repeat; 2],
        8192 * 8192,
        4096,
    );
    assert!(matches!(r, Err(ImageError::TooLarge(_))), "{r:?}");
}

/// CRC-32 (PNG chunks).
fn crc32(bytes: &[u8]) -> u32 {
    let mut c = 0xFFFF_FFFFu32;
    for &b in bytes {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xEDB8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

#[test]
fn obj_takes_kd_and_map_kd_from_its_sidecars() {
    let path = test_data("mesh/spider/spider.obj");
    let (bytes, side) = read_with_sidecars(&path);
    let names: Vec<&str> = side.iter().map(|(n, _)| n.as_str()).collect();
    // The MTL and the five textures it names (written `.\name.jpg`).
    assert_eq!(names.len(), 6, "{names:?}");
    assert!(names.contains(&"spider.mtl") && names.contains(&"SpiderTex.jpg"));
    let mesh = decode_mesh_with(
        &bytes,
        Some("spider.obj"),
        &MeshOptions::default(),
        Sidecars(&side),
    )
    .unwrap();
    assert!(mesh.notes.is_empty(), "{:?}", mesh.notes);
    // Four of the five materials are used (`Brusttex` is not).
    assert_eq!(mesh.textures.len(), 4);
    assert!(mesh.textures.iter().all(|t| t.mime == "image/jpeg"));
    assert!(mesh.parts.iter().all(|p| p.texture.is_some()));
    // A resolved map_Kd replaces Kd: white base colour.
    assert!(mesh.parts.iter().all(|p| p.base_color == [1.0; 4]));
    // OBJ's v is flipped to glTF's convention.
    let raw_vt: Vec<f32> = String::from_utf8_lossy(&bytes)
        .lines()
        .filter_map(|l| l.strip_prefix("vt "))
        .map(|r| r.split_whitespace().nth(1).unwrap().parse().unwrap())
        .collect();
    let uvs = mesh.uvs.as_ref().unwrap();
    let min_v = uvs.iter().map(|u| u[1]).fold(f32::INFINITY, f32::min);
    let max_raw = raw_vt.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    assert!(
        (min_v - (1.0 - max_raw)).abs() < 1e-5,
        "{min_v} vs 1 − {max_raw}"
    );
}

#[test]
fn obj_without_its_mtl_is_grey_with_a_note_not_an_error() {
    let bytes = std::fs::read(test_data("mesh/spider/spider.obj")).unwrap();
    let mesh = decode_mesh(&bytes, Some("spider.obj"), &MeshOptions::default()).unwrap();
    assert!(mesh.textures.is_empty());
    assert!(mesh
        .parts
        .iter()
        .all(|p| p.base_color == [0.5, 0.5, 0.5, 1.0]));
    assert_eq!(mesh.notes.len(), 1, "{:?}", mesh.notes);
    assert!(mesh.notes[0].contains("spider.mtl"), "{}", mesh.notes[0]);
    // The MTL without its textures: Kd colours, one note per missing texture.
    let (_, side) = read_with_sidecars(&test_data("mesh/spider/spider.obj"));
    let only_mtl: Vec<(String, Vec<u8>)> = side
        .into_iter()
        .filter(|(n, _)| n.ends_with(".mtl"))
        .collect();
    let mesh = decode_mesh_with(
        &bytes,
        Some("spider.obj"),
        &MeshOptions::default(),
        Sidecars(&only_mtl),
    )
    .unwrap();
    assert!(mesh.textures.is_empty());
    assert_eq!(mesh.notes.len(), 4, "{:?}", mesh.notes);
    let skin = mesh
        .parts
        .iter()
        .find(|p| p.base_color[0] > 0.82 && p.base_color[0] < 0.83)
        .expect("a part with the Skin material's Kd 0.827");
    assert!((skin.base_color[1] - 0.792_157).abs() < 1e-5);
    // A texture that does not decode is a note too.
    let mut broken = only_mtl.clone();
    broken.push(("SpiderTex.jpg".into(), b"\xFF\xD8\xFFnot really".to_vec()));
    let mesh = decode_mesh_with(
        &bytes,
        Some("spider.obj"),
        &MeshOptions::default(),
        Sidecars(&broken),
    )
    .unwrap();
    assert!(mesh.notes.iter().any(|n| n.contains("SpiderTex.jpg")));
}

#[test]
fn ply_vertex_colors_are_kept_linear() {
    let bytes = std::fs::read(test_data("mesh/colored_airplane.ply")).unwrap();
    let mesh = decode_mesh(
        &bytes,
        Some("colored_airplane.ply"),
        &MeshOptions::default(),
    )
    .unwrap();
    let colors = mesh.colors.as_ref().expect("vertex colours");
    assert_eq!(colors.len(), mesh.positions.len());
    assert_eq!(mesh.parts[0].base_color, [1.0; 4]);
    // Several distinct colours, all within 0..1.
    let mut distinct: Vec<[u32; 3]> = colors
        .iter()
        .map(|c| [c[0], c[1], c[2]].map(f32::to_bits))
        .collect();
    distinct.sort_unstable();
    distinct.dedup();
    assert!(distinct.len() > 10, "{} colours", distinct.len());
    assert!(colors.iter().flatten().all(|v| (0.0..=1.0).contains(v)));
}

/// A unit quad on the ground (y = 0) with UVs (0,0)–(1,1), textured with `tex`.
fn textured_quad(tex: Texture) -> Mesh {
    Mesh {
        positions: vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 0.0, 1.0],
            [0.0, 0.0, 1.0],
        ],
        triangles: vec![[0, 2, 1], [0, 3, 2]],
        uvs: Some(vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]),
        textures: vec![Arc::new(tex)],
        parts: vec![MeshPart {
            name: "quad".into(),
            first_triangle: 0,
            triangle_count: 2,
            base_color: [1.0; 4],
            texture: Some(0),
        }],
        ..Mesh::default()
    }
}

/// A 2 × 2 texture: red left column, blue right column (u = 0 is the left).
fn red_blue() -> Texture {
    let texels = vec![
        [255, 0, 0, 255],
        [0, 0, 255, 255],
        [255, 0, 0, 255],
        [0, 0, 255, 255],
    ];
    let img = RgbaImage {
        width: 2,
        height: 2,
        data: texels.iter().flatten().copied().collect(),
    };
    Texture {
        name: "red_blue".into(),
        width: 2,
        height: 2,
        texels,
        encoded: Arc::from(encode_rgba(&img)),
        mime: "image/png",
        wrap: [TextureWrap::Clamp; 2],
    }
}

#[test]
fn renderer_draws_the_texture_through_the_uvs() {
    let mesh = textured_quad(red_blue());
    // Straight down on the quad, x to the right of the image (north up: −z at the top).
    let camera = Camera {
        eye: [0.5, 3.0, 0.5],
        target: [0.5, 0.0, 0.5],
        up: [0.0, 0.0, -1.0],
        fov_deg: 20.0,
    };
    let light = MeshLighting {
        shadows: false,
        samples: 1,
        ..MeshLighting::default()
    };
    let inst = MeshInstance {
        positions: &mesh.positions,
        normals: None,
        triangles: &mesh.triangles,
        colors: MeshColors::Materials(&mesh),
    };
    let img = render_meshes(&[inst], &camera, &light, 64, 64, &NoControl, (0.0, 1.0)).unwrap();
    let px = |x: u32, y: u32| {
        let i = ((y * 64 + x) * 4) as usize;
        [img.data[i], img.data[i + 1], img.data[i + 2]]
    };
    // The quad spans about ±0.5 m at 3 m with 20°: 0.5/(3·tan 10°) ≈ 94 % of the half-image.
    let left = px(14, 32);
    let right = px(50, 32);
    assert!(left[0] > 100 && left[2] < 40, "left {left:?}");
    assert!(right[2] > 100 && right[0] < 40, "right {right:?}");
    // The same quad without its texture is one colour.
    let plain = MeshInstance {
        colors: MeshColors::PerPart(&mesh.parts),
        ..inst
    };
    let img = render_meshes(&[plain], &camera, &light, 64, 64, &NoControl, (0.0, 1.0)).unwrap();
    let i = |x: u32| ((32 * 64 + x) * 4) as usize;
    assert_eq!(img.data[i(14)..i(14) + 3], img.data[i(50)..i(50) + 3]);
}

#[test]
fn scene_glb_embeds_the_input_textures_once_and_validates() {
    let path = test_data("mesh/spider/spider.obj");
    let (bytes, side) = read_with_sidecars(&path);
    let mesh = decode_mesh_with(
        &bytes,
        Some("spider.obj"),
        &MeshOptions::default(),
        Sidecars(&side),
    )
    .unwrap();
    let parts = scene_nodes(&mesh);
    let nodes: Vec<GlbNode> = parts.iter().map(|p| p.node()).collect();
    let glb = mesh_glb(&nodes, None);
    assert_valid("spider_scene.glb", &glb);
    let doc = glb_json(&glb);
    // Four textures for more parts: each image once, JPEG as read.
    let images = doc["images"].as_array().unwrap();
    assert_eq!(images.len(), 4);
    assert!(images.iter().all(|i| i["mimeType"] == "image/jpeg"));
    assert!(parts.len() > 4);
    let textured = doc["materials"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|m| m["pbrMetallicRoughness"]["baseColorTexture"].is_object())
        .count();
    assert_eq!(textured, parts.len());
    // The image bytes are the JPEG files as they were.
    let view = &doc["bufferViews"][images[0]["bufferView"].as_u64().unwrap() as usize];
    let len = view["byteLength"].as_u64().unwrap() as usize;
    assert!(side.iter().any(|(_, b)| b.len() == len));

    // PLY vertex colours travel as COLOR_0.
    let bytes = std::fs::read(test_data("mesh/colored_airplane.ply")).unwrap();
    let mesh = decode_mesh(
        &bytes,
        Some("colored_airplane.ply"),
        &MeshOptions::default(),
    )
    .unwrap();
    let parts = scene_nodes(&mesh);
    let nodes: Vec<GlbNode> = parts.iter().map(|p| p.node()).collect();
    let glb = mesh_glb(&nodes, None);
    assert_valid("airplane_scene.glb", &glb);
    let doc = glb_json(&glb);
    assert!(doc["meshes"][0]["primitives"][0]["attributes"]["COLOR_0"].is_u64());
}

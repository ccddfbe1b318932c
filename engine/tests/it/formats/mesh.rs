//! Mesh readers on the real meshes of `shared/data/mesh` (counts from its README), on files the
//! tests write themselves (ASCII STL, big-endian and ASCII PLY, a glTF/GLB with a node hierarchy,
//! strips and a mirror, OBJ with negative indices and quads), validation errors, and fuzz-style
//! robustness (truncation, flipped bytes, absurd counts → an error or a mesh, never a panic).

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may unwrap (STYLE habit 4)

use std::cell::Cell;
use std::sync::Once;
use std::time::{Duration, Instant};

use base64::Engine as _;
use phenomena_engine::formats::mesh::{decode_mesh, sniff_mesh, MeshFormat, MeshOptions, UpAxis};
use phenomena_engine::geom::mesh::Mesh;
use phenomena_engine::InputError;

macro_rules! mesh_path {
    ($name:literal) => {
        concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../shared/data/mesh/",
            $name
        )
    };
}

const REAL: [&str; 7] = [
    mesh_path!("inventor_table.glb"),
    mesh_path!("inventor_chesschairs.glb"),
    mesh_path!("fzk_haus.glb"),
    mesh_path!("bunny_npm.obj"),
    mesh_path!("teapot_npm.obj"),
    mesh_path!("bunny00.ply"),
    mesh_path!("armadillo.stl"),
];

fn name_of(path: &str) -> &str {
    path.rsplit('/').next().unwrap()
}

fn read_with(path: &str, opts: &MeshOptions) -> Mesh {
    let bytes = std::fs::read(path).unwrap();
    decode_mesh(&bytes, Some(name_of(path)), opts).unwrap()
}

fn read(path: &str) -> Mesh {
    read_with(path, &MeshOptions::default())
}

fn decode(bytes: &[u8], name: &str) -> Result<Mesh, InputError> {
    decode_mesh(bytes, Some(name), &MeshOptions::default())
}

fn extent(m: &Mesh) -> [f32; 3] {
    let (lo, hi) = m.bounds().unwrap();
    [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]]
}

fn close3(a: [f32; 3], b: [f32; 3], tol: f32) -> bool {
    (0..3).all(|k| (a[k] - b[k]).abs() <= tol)
}

/// Area of the triangles whose normal is dominated by each of +X −X +Y −Y +Z −Z.
fn area_by_axis(m: &Mesh, tris: std::ops::Range<usize>) -> [f64; 6] {
    let mut h = [0.0; 6];
    for t in tris {
        let n = m.face_normal(t);
        let a = f64::from((n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt()) / 2.0;
        let k = (0..3)
            .max_by(|&i, &j| n[i].abs().total_cmp(&n[j].abs()))
            .unwrap();
        h[2 * k + usize::from(n[k] < 0.0)] += a;
    }
    h
}

/// Structural checks every decoded mesh must pass.
fn check_invariants(m: &Mesh) {
    let n = m.positions.len();
    assert!(m.positions.iter().flatten().all(|c| c.is_finite()));
    assert!(m.triangles.iter().flatten().all(|&i| (i as usize) < n));
    let mut next = 0;
    for p in &m.parts {
        assert_eq!(p.first_triangle, next);
        next += p.triangle_count;
    }
    assert_eq!(next, m.triangles.len());
    if let Some(v) = &m.normals {
        assert_eq!(v.len(), n);
        assert!(v
            .iter()
            .all(|v| ((v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt() - 1.0).abs() < 1e-4));
    }
    if let Some(v) = &m.uvs {
        assert_eq!(v.len(), n);
    }
}

// ---------- real meshes ----------

#[test]
fn inventor_table_glb() {
    let m = read(REAL[0]);
    check_invariants(&m);
    assert_eq!((m.positions.len(), m.triangles.len()), (1936, 4960));
    assert_eq!(m.parts.len(), 2);
    assert!(m.uvs.is_some());
    // A round table 1.4 m across and 0.65 m high, in metres.
    let e = extent(&m);
    assert!(close3(e, [1.4, 1.4, 0.6538], 2e-3), "{e:?}");
}

/// The README's warning, measured: the Inventor models are Z-up inside a (Y-up) glTF. We keep
/// glTF's frame, so the table top (the part `material_1`, 1.5 m² of it facing one way) faces +Z,
/// and the legs hang toward −Z from it.
#[test]
fn inventor_table_is_z_up_content() {
    let m = read(REAL[0]);
    let top = m.parts.iter().find(|p| p.name == "material_1").unwrap();
    let h = area_by_axis(
        &m,
        top.first_triangle..top.first_triangle + top.triangle_count,
    );
    assert!(h[4] > 1.4 && h[4] > 10.0 * (h[2] + h[3]), "{h:?}");
    let (lo, hi) = m.bounds().unwrap();
    assert!(hi[2] < 0.01 && lo[2] < -0.6, "{lo:?} {hi:?}");
}

#[test]
fn inventor_chesschairs_glb() {
    let m = read(REAL[1]);
    check_invariants(&m);
    assert_eq!((m.positions.len(), m.triangles.len()), (11937, 19816));
    assert_eq!(m.parts.len(), 23);
    // The 6 m × 6 m floor is the lowest thing along Z and its 36 m² face −Z (wound downwards).
    let floor = m.parts.iter().find(|p| p.name == "material_23").unwrap();
    let h = area_by_axis(
        &m,
        floor.first_triangle..floor.first_triangle + floor.triangle_count,
    );
    assert!((h[5] - 36.0).abs() < 0.1, "{h:?}");
    let e = extent(&m);
    assert!(close3(e, [6.0, 6.0, 3.63], 0.05), "{e:?}");
}

#[test]
fn fzk_haus_glb() {
    let m = read(REAL[2]);
    check_invariants(&m);
    assert_eq!((m.positions.len(), m.triangles.len()), (20080, 35906));
    // 200 primitives in 59 meshes, instanced by 216 nodes into 294 (node, primitive) parts.
    assert_eq!(m.parts.len(), 294);
    let colors: std::collections::BTreeSet<String> = m
        .parts
        .iter()
        .map(|p| format!("{:?}", p.base_color))
        .collect();
    assert!(colors.len() > 3, "{colors:?}");
    // Y-up after the root node's −90° about X: the plot is 18 m × 16 m, the house ~7 m high.
    let (lo, hi) = m.bounds().unwrap();
    assert!(close3(lo, [-3.0, -1.0, -13.0], 1e-3), "{lo:?}");
    assert!(close3(hi, [15.0, 6.3177, 3.0], 1e-3), "{hi:?}");
}

#[test]
fn bunny_obj() {
    let m = read(REAL[3]);
    check_invariants(&m);
    // The README says 1,889 vertices; the file has 1,839 `v` lines, all used.
    assert_eq!((m.positions.len(), m.triangles.len()), (1839, 3674));
    assert_eq!(m.parts.len(), 1);
    let e = extent(&m);
    assert!(close3(e, [9.907, 9.658, 7.540], 1e-2), "{e:?}");
}

#[test]
fn teapot_obj() {
    let m = read(REAL[4]);
    check_invariants(&m);
    assert_eq!((m.positions.len(), m.triangles.len()), (792, 992));
    let e = extent(&m);
    assert!(close3(e, [32.14, 15.75, 20.0], 1e-2), "{e:?}");
}

#[test]
fn bunny_ply_up_axis() {
    let y_up = read_with(
        REAL[5],
        &MeshOptions {
            up_axis: Some(UpAxis::Y),
            ..MeshOptions::default()
        },
    );
    check_invariants(&y_up);
    assert_eq!((y_up.positions.len(), y_up.triangles.len()), (37706, 75408));
    // Default for PLY is Z-up: (x, y, z) → (x, z, −y).
    let z_up = read(REAL[5]);
    check_invariants(&z_up);
    assert_eq!(z_up.triangles, y_up.triangles);
    for (a, b) in y_up.positions.iter().zip(&z_up.positions) {
        assert_eq!(*b, [a[0], a[2], -a[1]]);
    }
    let e = extent(&y_up);
    assert!(close3(e, [0.998, 0.987, 0.773], 2e-3), "{e:?}");
}

#[test]
fn armadillo_stl() {
    let m = read(REAL[6]);
    check_invariants(&m);
    assert_eq!((m.positions.len(), m.triangles.len()), (26002, 52000));
    // The Stanford models are Y-up, so STL's Z-up default lays the Armadillo on its back:
    // (x, y, z) → (x, z, −y) swaps the extents of Y and Z.
    let e = extent(&m);
    assert!(close3(e, [127.02, 115.42, 151.31], 0.05), "{e:?}");
    let y_up = read_with(
        REAL[6],
        &MeshOptions {
            up_axis: Some(UpAxis::Y),
            ..MeshOptions::default()
        },
    );
    let e = extent(&y_up);
    assert!(close3(e, [127.02, 151.31, 115.42], 0.05), "{e:?}");
}

#[test]
fn sniffing() {
    for path in REAL {
        let bytes = std::fs::read(path).unwrap();
        let by_name = sniff_mesh(&bytes, Some(name_of(path))).unwrap();
        let by_content = sniff_mesh(&bytes, None).unwrap();
        assert_eq!(by_name, by_content, "{path}");
    }
    assert_eq!(sniff_mesh(b"solid x\nfacet", None), Some(MeshFormat::Stl));
    assert_eq!(
        sniff_mesh(b"{\"asset\":{\"version\":\"2.0\"}}", None),
        Some(MeshFormat::Gltf)
    );
    assert_eq!(
        sniff_mesh(b"# c\nv 0 0 0\nv 1 0 0\nf 1 2 3\n", None),
        Some(MeshFormat::Obj)
    );
    assert_eq!(sniff_mesh(b"hello world", None), None);
    assert!(matches!(
        decode(b"hello world", "x.bin"),
        Err(InputError::UnsupportedFormat(_))
    ));
}

// ---------- STL written here ----------

#[test]
fn ascii_stl_is_rotated_z_up_and_welded() {
    let text = "solid two\n\
        facet normal 0 0 1\n outer loop\n  vertex 0 0 0\n  vertex 1 0 0\n  vertex 0 1 0\n endloop\nendfacet\n\
        facet normal 0 0 1\n outer loop\n  vertex 1 0 0\n  vertex 1 1 0\n  vertex 0 1 -0\n endloop\nendfacet\n\
        endsolid two\n";
    let m = decode(text.as_bytes(), "two.stl").unwrap();
    check_invariants(&m);
    assert_eq!((m.positions.len(), m.triangles.len()), (4, 2));
    assert_eq!(m.parts[0].name, "two");
    // (x, y, z) → (x, z, −y): the +Z-facing square now faces +Y, with the winding kept.
    for t in 0..2 {
        let n = m.face_normal(t);
        assert!(n[1] > 0.0 && n[0] == 0.0 && n[2] == 0.0, "{n:?}");
    }
    assert!(m.positions.contains(&[1.0, 0.0, -1.0]));
    // Nameless "solid" and Y-up kept as is.
    let nameless = text.replace("solid two", "solid");
    let opts = MeshOptions {
        up_axis: Some(UpAxis::Y),
        ..MeshOptions::default()
    };
    let m = decode_mesh(nameless.as_bytes(), None, &opts).unwrap();
    assert!(m.positions.contains(&[1.0, 1.0, 0.0]));
}

fn binary_stl(tris: &[[[f32; 3]; 3]], header: &[u8]) -> Vec<u8> {
    let mut b = vec![0u8; 80];
    b[..header.len()].copy_from_slice(header);
    b.extend_from_slice(&(tris.len() as u32).to_le_bytes());
    for t in tris {
        b.extend_from_slice(&[0u8; 12]);
        for p in t {
            for c in p {
                b.extend_from_slice(&c.to_le_bytes());
            }
        }
        b.extend_from_slice(&[0, 0]);
    }
    b
}

#[test]
fn binary_stl_with_solid_header_and_nan() {
    let tri = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    // Many exporters start the binary header with "solid".
    let b = binary_stl(&[tri], b"solid exported by a CAD tool");
    assert_eq!(sniff_mesh(&b, None), Some(MeshFormat::Stl));
    let m = decode_mesh(&b, None, &MeshOptions::default()).unwrap();
    assert_eq!(m.triangles.len(), 1);
    let bad = binary_stl(
        &[
            tri,
            [[0.0, 0.0, 0.0], [1.0, f32::NAN, 0.0], [0.0, 1.0, 0.0]],
        ],
        b"",
    );
    match decode(&bad, "bad.stl") {
        Err(InputError::Corrupt { detail, .. }) => assert!(detail.contains("vertex 4"), "{detail}"),
        other => panic!("{other:?}"),
    }
    let mut short = binary_stl(&[tri, tri], b"");
    short.pop();
    assert!(matches!(
        decode(&short, "short.stl"),
        Err(InputError::Corrupt { .. })
    ));
}

// ---------- PLY written here ----------

fn ply_quad_header(format: &str) -> String {
    format!(
        "ply\nformat {format} 1.0\ncomment written by the test\nelement vertex 5\n\
         property float x\nproperty float y\nproperty double z\n\
         property float nx\nproperty float ny\nproperty float nz\n\
         property float s\nproperty float t\n\
         element face 2\nproperty list uchar int vertex_indices\n\
         element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n"
    )
}

const PLY_VERTS: [[f32; 8]; 5] = [
    [0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0],
    [2.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0],
    [2.0, 3.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0],
    [0.0, 3.0, 0.0, 0.0, 0.0, 2.0, 0.0, 1.0],
    [1.0, 1.0, 5.0, 0.0, 0.0, 1.0, 0.5, 0.5],
];

fn check_ply_quad(m: &Mesh) {
    check_invariants(m);
    // A quad (fanned into 2 triangles) and a triangle.
    assert_eq!((m.positions.len(), m.triangles.len()), (5, 3));
    assert_eq!(m.triangles[..2], [[0, 1, 2], [0, 2, 3]]);
    assert_eq!(m.triangles[2], [0, 1, 4]);
    // Z-up default: z = 5 becomes y = 5; normals rotate along and are normalised.
    assert_eq!(m.positions[4], [1.0, 5.0, -1.0]);
    assert_eq!(m.normals.as_ref().unwrap()[3], [0.0, 1.0, 0.0]);
    assert_eq!(m.uvs.as_ref().unwrap()[4], [0.5, 0.5]);
}

#[test]
fn big_endian_ply() {
    let mut b = ply_quad_header("binary_big_endian").into_bytes();
    for v in PLY_VERTS {
        for (k, c) in v.iter().enumerate() {
            if k == 2 {
                b.extend_from_slice(&f64::from(*c).to_be_bytes());
            } else {
                b.extend_from_slice(&c.to_be_bytes());
            }
        }
    }
    for face in [&[0i32, 1, 2, 3][..], &[0, 1, 4]] {
        b.push(face.len() as u8);
        for i in face {
            b.extend_from_slice(&i.to_be_bytes());
        }
    }
    b.extend_from_slice(&0i32.to_be_bytes());
    b.extend_from_slice(&1i32.to_be_bytes());
    check_ply_quad(&decode(&b, "quad.ply").unwrap());
    // Cut inside the faces: the header promises more than the payload holds.
    assert!(matches!(
        decode(&b[..b.len() - 12], "quad.ply"),
        Err(InputError::Corrupt { .. })
    ));
}

/// A header line with no keyword (Blender 2.4x's `Created by Blender3D 247 …`, as in assimp's
/// `Wuson.ply`) is read as a comment, in binary (the payload must start right after
/// `end_header`) and ASCII files, with a note; a malformed keyword line is still corrupt.
#[test]
fn ply_header_line_without_keyword_is_a_comment() {
    let mut b = ply_quad_header("binary_little_endian")
        .replace(
            "comment written by the test\n",
            "Created by Blender3D 247 - www.blender.org, source file: \n\n",
        )
        .into_bytes();
    for v in PLY_VERTS {
        for (k, c) in v.iter().enumerate() {
            if k == 2 {
                b.extend_from_slice(&f64::from(*c).to_le_bytes());
            } else {
                b.extend_from_slice(&c.to_le_bytes());
            }
        }
    }
    for face in [&[0i32, 1, 2, 3][..], &[0, 1, 4]] {
        b.push(face.len() as u8);
        for i in face {
            b.extend_from_slice(&i.to_le_bytes());
        }
    }
    b.extend_from_slice(&0i32.to_le_bytes());
    b.extend_from_slice(&1i32.to_le_bytes());
    let m = decode(&b, "quad.ply").unwrap();
    check_ply_quad(&m);
    assert!(
        m.notes
            .iter()
            .any(|n| n.contains("2 line(s) with no keyword")),
        "{:?}",
        m.notes
    );

    let mut s = ply_quad_header("ascii")
        .replace("\n", "\r\n")
        .replace("comment written by the test", "  exported by hand");
    for v in PLY_VERTS {
        let line: Vec<String> = v.iter().map(|c| c.to_string()).collect();
        s += &(line.join(" ") + "\n");
    }
    s += "4 0 1 2 3\n3 0 1 4\n0 1\n";
    check_ply_quad(&decode(s.as_bytes(), "quad.ply").unwrap());
    let malformed = s.replace("element face 2", "element face two");
    assert!(matches!(
        decode(malformed.as_bytes(), "quad.ply"),
        Err(InputError::Corrupt { .. })
    ));
    assert!(decode(b"not a ply\nend_header\n", "x.ply").is_err());
}

#[test]
fn ascii_ply_and_its_errors() {
    let mut s = ply_quad_header("ascii");
    for v in PLY_VERTS {
        let line: Vec<String> = v.iter().map(|c| c.to_string()).collect();
        s += &(line.join(" ") + "\n");
    }
    s += "4 0 1 2 3\n3 0 1 4\n0 1\n";
    check_ply_quad(&decode(s.as_bytes(), "quad.ply").unwrap());

    let out_of_range = s.replace("3 0 1 4\n", "3 0 1 7\n");
    assert!(matches!(
        decode(out_of_range.as_bytes(), "q.ply"),
        Err(InputError::Corrupt { .. })
    ));
    let negative = s.replace("3 0 1 4\n", "3 0 -1 4\n");
    assert!(matches!(
        decode(negative.as_bytes(), "q.ply"),
        Err(InputError::Corrupt { .. })
    ));
    // The double z overflows to +∞ (ply-rs's ASCII grammar has no "nan").
    let nan = s.replacen("0 0 0 0 0 1 0 0\n", "0 0 1e999 0 0 1 0 0\n", 1);
    match decode(nan.as_bytes(), "q.ply") {
        Err(InputError::Corrupt { detail, .. }) => assert!(detail.contains("vertex 0"), "{detail}"),
        other => panic!("{other:?}"),
    }
    let points = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n\
                  property float z\nelement face 0\nproperty list uchar int vertex_indices\n\
                  end_header\n0 0 0\n";
    assert!(matches!(
        decode(points.as_bytes(), "p.ply"),
        Err(InputError::Unusable(_))
    ));
}

// ---------- glTF / GLB written here ----------

/// Layout of the test buffer: triangle positions (36 B), its normals (36 B), strip positions
/// (48 B), strip indices (4 × u16).
fn gltf_bin() -> Vec<u8> {
    let mut b = Vec::new();
    let f =
        |b: &mut Vec<u8>, v: &[f32]| v.iter().for_each(|c| b.extend_from_slice(&c.to_le_bytes()));
    f(&mut b, &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]);
    f(&mut b, &[0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0]);
    f(
        &mut b,
        &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0],
    );
    for i in [0u16, 1, 2, 3] {
        b.extend_from_slice(&i.to_le_bytes());
    }
    assert_eq!(b.len(), 128);
    b
}

/// A scene: `root` (translate 10 along X) → `child` (rotate 90° about Y, scale 2) holding a
/// non-indexed triangle with normals and a coloured material; `mirror` (scale −1 along X)
/// holding an indexed triangle strip. `uri` = None for GLB.
fn gltf_json(uri: Option<&str>, position_count: u64) -> String {
    let buffer = match uri {
        Some(u) => format!("{{\"byteLength\":128,\"uri\":\"{u}\"}}"),
        None => "{\"byteLength\":128}".to_string(),
    };
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0,2]}}],
"nodes":[{{"name":"root","translation":[10,0,0],"children":[1]}},
 {{"name":"child","rotation":[0,0.70710678,0,0.70710678],"scale":[2,2,2],"mesh":0}},
 {{"name":"mirror","scale":[-1,1,1],"mesh":1}}],
"meshes":[{{"name":"tri","primitives":[{{"attributes":{{"POSITION":0,"NORMAL":1}},"material":0}}]}},
 {{"name":"strip","primitives":[{{"attributes":{{"POSITION":2}},"indices":3,"mode":5}}]}}],
"materials":[{{"pbrMetallicRoughness":{{"baseColorFactor":[0.2,0.4,0.6,1.0]}}}}],
"buffers":[{buffer}],
"bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":72}},{{"buffer":0,"byteOffset":72,"byteLength":48}},
 {{"buffer":0,"byteOffset":120,"byteLength":8}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":{position_count},"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
 {{"bufferView":0,"byteOffset":36,"componentType":5126,"count":3,"type":"VEC3"}},
 {{"bufferView":1,"componentType":5126,"count":4,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
 {{"bufferView":2,"componentType":5123,"count":4,"type":"SCALAR"}}]}}"#
    )
}

fn glb(json: &str, bin: &[u8]) -> Vec<u8> {
    let mut j = json.as_bytes().to_vec();
    while j.len() % 4 != 0 {
        j.push(b' ');
    }
    let mut b = Vec::new();
    b.extend_from_slice(b"glTF");
    b.extend_from_slice(&2u32.to_le_bytes());
    b.extend_from_slice(&((12 + 8 + j.len() + 8 + bin.len()) as u32).to_le_bytes());
    b.extend_from_slice(&(j.len() as u32).to_le_bytes());
    b.extend_from_slice(b"JSON");
    b.extend_from_slice(&j);
    b.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    b.extend_from_slice(b"BIN\0");
    b.extend_from_slice(bin);
    b
}

fn check_gltf_scene(m: &Mesh) {
    check_invariants(m);
    assert_eq!(m.parts.len(), 2);
    assert_eq!(m.parts[0].name, "child");
    assert_eq!(m.parts[0].base_color, [0.2, 0.4, 0.6, 1.0]);
    assert_eq!(m.parts[1].name, "mirror");
    assert_eq!(m.parts[1].base_color, [1.0, 1.0, 1.0, 1.0]);
    assert_eq!(m.triangles.len(), 3);
    // World = T(10,0,0) · R_y(90°) · S(2): p → (10 + 2 p_z, 2 p_y, −2 p_x).
    let [a, b, c] = m.corners(0);
    assert!(close3(a, [10.0, 0.0, 0.0], 1e-5), "{a:?}");
    assert!(close3(b, [10.0, 0.0, -2.0], 1e-5), "{b:?}");
    assert!(close3(c, [10.0, 2.0, 0.0], 1e-5), "{c:?}");
    // Normals are only kept when every primitive has them (the strip has none).
    assert!(m.normals.is_none());
    // The strip (0,1,2), (1,3,2) under a mirror: positions mirrored, winding flipped back so
    // both triangles still face +Z.
    for t in 1..3 {
        let n = m.face_normal(t);
        assert!(n[2] > 0.0, "triangle {t}: {n:?}");
    }
    assert!(m.positions.contains(&[-1.0, 1.0, 0.0]));
}

#[test]
fn glb_with_node_hierarchy() {
    let b = glb(&gltf_json(None, 3), &gltf_bin());
    assert_eq!(sniff_mesh(&b, None), Some(MeshFormat::Glb));
    check_gltf_scene(&decode(&b, "scene.glb").unwrap());
}

#[test]
fn gltf_with_data_uri_and_normals() {
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(gltf_bin())
    );
    let json = gltf_json(Some(&uri), 3);
    assert_eq!(sniff_mesh(json.as_bytes(), None), Some(MeshFormat::Gltf));
    check_gltf_scene(&decode(json.as_bytes(), "scene.gltf").unwrap());
    // Without the strip node, the triangle's normal (0,0,1) goes through R_y(90°) → (1,0,0).
    let only_tri = json.replace(r#""nodes":[0,2]"#, r#""nodes":[0]"#);
    let m = decode(only_tri.as_bytes(), "scene.gltf").unwrap();
    let n = m.normals.unwrap();
    assert!(n.iter().all(|v| close3(*v, [1.0, 0.0, 0.0], 1e-6)), "{n:?}");
}

#[test]
fn gltf_external_buffer_is_refused() {
    let json = gltf_json(Some("scene.bin"), 3);
    match decode(json.as_bytes(), "scene.gltf") {
        Err(InputError::Unusable(msg)) => assert!(msg.contains("scene.bin"), "{msg}"),
        other => panic!("{other:?}"),
    }
}

#[test]
fn gltf_node_cycle_and_short_buffer_are_corrupt() {
    let cyclic = gltf_json(None, 3).replace(
        r#""name":"mirror","scale""#,
        r#""name":"mirror","children":[2],"scale""#,
    );
    assert!(matches!(
        decode(&glb(&cyclic, &gltf_bin()), "c.glb"),
        Err(InputError::Corrupt { .. })
    ));
    let bin = gltf_bin();
    assert!(matches!(
        decode(&glb(&gltf_json(None, 3), &bin[..100]), "s.glb"),
        Err(InputError::Corrupt { .. })
    ));
}

// ---------- OBJ written here ----------

#[test]
fn obj_with_negative_indices_quads_and_groups() {
    let text = "# test\n\
        o floor\nv 0 0 0\nv 4 0 0\nv 4 0 4\nv 0 0 4\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
        f -4/-4 -1/-1 -2/-2 -3/-3\n\
        o box\nv 0 1 0\nv 1 1 0\nv 0 1 1\nf 5 7 6\nl 1 2\n";
    let m = decode(text.as_bytes(), "scene.obj").unwrap();
    check_invariants(&m);
    assert_eq!(m.parts.len(), 2);
    assert_eq!(
        (m.parts[0].name.as_str(), m.parts[0].triangle_count),
        ("floor", 2)
    );
    assert_eq!(
        (m.parts[1].name.as_str(), m.parts[1].triangle_count),
        ("box", 1)
    );
    assert_eq!(m.parts[0].base_color, [0.5, 0.5, 0.5, 1.0]);
    // The floor quad (1, 4, 3, 2) is wound to face +Y and stays so (OBJ default: Y up).
    for t in 0..3 {
        assert!(m.face_normal(t)[1] > 0.0, "{t}");
    }
    let (lo, hi) = m.bounds().unwrap();
    assert_eq!((lo, hi), ([0.0, 0.0, 0.0], [4.0, 1.0, 4.0]));
    // Not every part has texture coordinates, so none are kept.
    assert!(m.uvs.is_none());
    // Z up on request.
    let z = decode_mesh(
        text.as_bytes(),
        None,
        &MeshOptions {
            up_axis: Some(UpAxis::Z),
            ..MeshOptions::default()
        },
    )
    .unwrap();
    assert!(z.positions.contains(&[4.0, 4.0, -0.0]));
}

#[test]
fn obj_errors() {
    for (text, what) in [
        ("v 0 0 0\nv 1 0 0\nf 1 2 3\n", "forward index past the end"),
        (
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -4\n",
            "relative index before the start",
        ),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "index 0"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n", "not a number"),
        (
            "v 0 0 0\nv 1 0 inf\nv 0 1 0\nf 1 2 3\n",
            "infinite coordinate",
        ),
    ] {
        assert!(
            matches!(
                decode(text.as_bytes(), "e.obj"),
                Err(InputError::Corrupt { .. })
            ),
            "{what}"
        );
    }
    assert!(matches!(
        decode(b"v 0 0 0\nv 1 0 0\n", "e.obj"),
        Err(InputError::Unusable(_))
    ));
}

// ---------- limits ----------

#[test]
fn absurd_counts_are_too_large_quickly() {
    let start = Instant::now();
    let too_large = |r: Result<Mesh, InputError>| matches!(r, Err(InputError::TooLarge { .. }));
    // Binary STL claiming 4 billion triangles in 84 bytes.
    let mut stl = vec![0u8; 84];
    stl[80..84].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(too_large(decode(&stl, "x.stl")));
    // PLY headers.
    for el in ["vertex 4000000000", "face 4000000000"] {
        let (v, f) = if el.starts_with("vertex") {
            (el, "face 1")
        } else {
            ("vertex 3", el)
        };
        let ply = format!(
            "ply\nformat binary_little_endian 1.0\nelement {v}\nproperty float x\n\
             property float y\nproperty float z\nelement {f}\n\
             property list uchar int vertex_indices\nend_header\n"
        );
        assert!(too_large(decode(ply.as_bytes(), "x.ply")), "{el}");
    }
    // glTF accessor counts, before any buffer is read.
    let b = glb(&gltf_json(None, 1_000_000_000), &gltf_bin());
    assert!(too_large(decode(&b, "x.glb")));
    // Limits below the real files.
    let small = MeshOptions {
        max_triangles: 500,
        max_vertices: 500,
        ..MeshOptions::default()
    };
    for path in REAL {
        let bytes = std::fs::read(path).unwrap();
        let r = decode_mesh(&bytes, Some(name_of(path)), &small);
        assert!(too_large(r), "{path}");
    }
    let elapsed = start.elapsed();
    assert!(elapsed < Duration::from_secs(2), "{elapsed:?}");
}

// ---------- robustness ----------

thread_local! {
    static PANICKED: Cell<bool> = const { Cell::new(false) };
}

/// Record panics on this thread (decode_mesh catches them; we want to know they happened).
fn watch_panics() {
    static HOOK: Once = Once::new();
    HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            PANICKED.with(|p| p.set(true));
            previous(info);
        }));
    });
    PANICKED.with(|p| p.set(false));
}

fn no_panic_so_far() -> bool {
    !PANICKED.with(Cell::get)
}

/// xorshift64*: a fixed, dependency-free sequence.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
}

#[test]
fn truncated_files_are_errors_not_panics() {
    watch_panics();
    for path in REAL {
        let bytes = std::fs::read(path).unwrap();
        let name = name_of(path);
        let n = bytes.len();
        let mut cuts: Vec<usize> = (0..40).map(|i| n * i / 40).collect();
        cuts.extend([1, 4, 12, 20, 80, 83, 84, 85, 200, n - 1, n - 2, n - 50]);
        for cut in cuts {
            let r = decode_mesh(&bytes[..cut], Some(name), &MeshOptions::default());
            // Text formats cut at a line end can still be a valid (smaller) mesh.
            if let Ok(m) = &r {
                assert!(
                    name.ends_with(".obj") || name.ends_with(".ply"),
                    "{name} cut at {cut} decoded"
                );
                check_invariants(m);
            }
            assert!(no_panic_so_far(), "{name} cut at {cut} panicked");
        }
    }
}

#[test]
fn flipped_bytes_are_errors_or_meshes_never_panics() {
    watch_panics();
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    // MESH_FUZZ_TRIALS=2000 for a longer local run.
    let trials: usize = std::env::var("MESH_FUZZ_TRIALS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(24);
    let mut inputs: Vec<(String, Vec<u8>)> = REAL
        .iter()
        .map(|p| (name_of(p).to_string(), std::fs::read(p).unwrap()))
        .collect();
    // Small written files, where a flip lands in the structure more often.
    inputs.push(("s.glb".into(), glb(&gltf_json(None, 3), &gltf_bin())));
    let mut ply = ply_quad_header("binary_little_endian").into_bytes();
    ply.extend(PLY_VERTS.iter().flatten().enumerate().flat_map(|(k, c)| {
        if k % 8 == 2 {
            f64::from(*c).to_le_bytes().to_vec()
        } else {
            c.to_le_bytes().to_vec()
        }
    }));
    ply.extend([
        4, 0, 0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0, 3, 0, 0, 0, 3, 0, 0, 0, 0, 1, 0, 0, 0,
    ]);
    ply.extend([4, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0]);
    inputs.push(("s.ply".into(), ply));
    inputs.push((
        "s.obj".into(),
        b"o a\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\nf 1/1/1 2/1/1 3/1/1 4/1/1\nf -1 -2 -3\n"
            .to_vec(),
    ));
    for (name, bytes) in &inputs {
        for trial in 0..trials {
            let mut b = bytes.clone();
            // Half the trials hit the first 512 bytes (headers, JSON), half anywhere.
            for _ in 0..1 + rng.next() % 8 {
                let span = if trial % 2 == 0 {
                    b.len().min(512)
                } else {
                    b.len()
                };
                let i = (rng.next() % span as u64) as usize;
                b[i] ^= 1 << (rng.next() % 8);
            }
            if let Ok(m) = decode_mesh(&b, Some(name), &MeshOptions::default()) {
                check_invariants(&m);
            }
            assert!(no_panic_so_far(), "{name} trial {trial} panicked");
        }
    }
}

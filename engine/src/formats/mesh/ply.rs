//! Stanford PLY through `ply-rs-bw` 3.x (the maintained fork of `ply-rs`, free of the
//! `linked-hash-map` soundness bug CVE-2020-25573, with capped pre-allocation): ASCII and binary
//! little/big endian.
//!
//! - Element `vertex`: `x y z` (any scalar type, required), `nx ny nz` (normals), texture
//!   coordinates as `u v`, `s t` or `texture_u texture_v` (flipped to glTF's v = 1 − v), colours as `red green blue [alpha]`
//!   (also `r g b a`, `diffuse_red …`; integers over their type's range — 255 for uchar — floats
//!   as 0–1; read as sRGB, as scanners and MeshLab write them, and kept linear in
//!   [`crate::geom::Mesh::colors`], the part's base colour then white). Other properties are
//!   ignored.
//! - Element `face`: the list `vertex_indices` (or `vertex_index`); polygons are fanned
//!   (n − 2 triangles), faces with fewer than 3 corners are skipped, negative indices are
//!   `Corrupt`. Other elements (`edge`, `material`, …) are read and dropped.
//! - Limits: the header is parsed first; the `vertex` and `face` counts are checked against the
//!   limits (a face is at least one triangle), the other elements against their sum, and for
//!   binary files the smallest possible payload for those counts against the bytes present —
//!   all before any element is read. The fanned triangle total is checked again before the index
//!   buffer is allocated. One part, grey (white under vertex colours); default up axis Z.
//! - Lenient header: a header line that starts with no PLY keyword (`format`, `element`,
//!   `property`, `comment`, `obj_info`, `end_header`) is read as a comment, as Assimp, MeshLab and
//!   trimesh read it (Blender 2.4x wrote a bare `Created by Blender3D 247 …` line; assimp's
//!   `Wuson.ply` has one); a note in the report says so. A line that starts with a keyword and is
//!   malformed is still `Corrupt`.

use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{ElementDef, Encoding, Property, PropertyAccess, PropertyType, ScalarType};

use super::{check_counts, srgb_to_linear, Builder, MeshOptions, PartData, GREY};
use crate::error::InputError;
use crate::geom::mesh::Mesh;

const FORMAT: &str = "PLY";

fn corrupt(detail: impl Into<String>) -> InputError {
    InputError::Corrupt {
        format: FORMAT,
        detail: detail.into(),
    }
}

fn scalar(p: &Property) -> Option<f64> {
    Some(match *p {
        Property::Char(v) => f64::from(v),
        Property::UChar(v) => f64::from(v),
        Property::Short(v) => f64::from(v),
        Property::UShort(v) => f64::from(v),
        Property::Int(v) => f64::from(v),
        Property::UInt(v) => f64::from(v),
        Property::Float(v) => f64::from(v),
        Property::Double(v) => v,
        _ => return None,
    })
}

#[derive(Default)]
struct Vertex {
    p: [f64; 3],
    n: [f32; 3],
    uv: [f32; 2],
    /// sRGB 0..1 (alpha linear).
    c: [f32; 4],
}

/// A colour channel 0..1 from a property of any scalar type.
fn channel(p: &Property) -> Option<f32> {
    Some(match *p {
        Property::UChar(v) => f32::from(v) / 255.0,
        Property::Char(v) => f32::from(v.max(0)) / 127.0,
        Property::UShort(v) => f32::from(v) / 65535.0,
        Property::Short(v) => f32::from(v.max(0)) / 32767.0,
        Property::UInt(v) => (f64::from(v) / f64::from(u32::MAX)) as f32,
        Property::Int(v) => (f64::from(v.max(0)) / f64::from(i32::MAX)) as f32,
        Property::Float(v) => v,
        Property::Double(v) => v as f32,
        _ => return None,
    })
}

const COLOR_NAMES: [[&str; 3]; 3] = [
    ["red", "green", "blue"],
    ["r", "g", "b"],
    ["diffuse_red", "diffuse_green", "diffuse_blue"],
];

impl PropertyAccess for Vertex {
    fn new() -> Self {
        Self {
            c: [1.0; 4],
            ..Self::default()
        }
    }
    fn set_property(&mut self, name: &str, property: Property) {
        let k = match name {
            "red" | "r" | "diffuse_red" => Some(0),
            "green" | "g" | "diffuse_green" => Some(1),
            "blue" | "b" | "diffuse_blue" => Some(2),
            "alpha" | "a" | "diffuse_alpha" => Some(3),
            _ => None,
        };
        if let Some(k) = k {
            if let Some(c) = channel(&property).filter(|c| c.is_finite()) {
                self.c[k] = c.clamp(0.0, 1.0);
            }
            return;
        }
        let Some(v) = scalar(&property) else {
            return;
        };
        match name {
            "x" => self.p[0] = v,
            "y" => self.p[1] = v,
            "z" => self.p[2] = v,
            "nx" => self.n[0] = v as f32,
            "ny" => self.n[1] = v as f32,
            "nz" => self.n[2] = v as f32,
            "u" | "s" | "texture_u" => self.uv[0] = v as f32,
            "v" | "t" | "texture_v" => self.uv[1] = v as f32,
            _ => {}
        }
    }
}

/// Corner indices of one face; `None` entries were negative.
#[derive(Default)]
struct Face {
    corners: Vec<Option<u32>>,
}

impl PropertyAccess for Face {
    fn new() -> Self {
        Self::default()
    }
    fn set_property(&mut self, name: &str, property: Property) {
        if name != "vertex_indices" && name != "vertex_index" {
            return;
        }
        let u = |v: i64| u32::try_from(v).ok();
        self.corners = match property {
            Property::ListChar(v) => v.into_iter().map(|i| u(i64::from(i))).collect(),
            Property::ListUChar(v) => v.into_iter().map(|i| Some(u32::from(i))).collect(),
            Property::ListShort(v) => v.into_iter().map(|i| u(i64::from(i))).collect(),
            Property::ListUShort(v) => v.into_iter().map(|i| Some(u32::from(i))).collect(),
            Property::ListInt(v) => v.into_iter().map(|i| u(i64::from(i))).collect(),
            Property::ListUInt(v) => v.into_iter().map(Some).collect(),
            _ => Vec::new(),
        };
    }
}

/// Elements we do not use.
struct Skip;

impl PropertyAccess for Skip {
    fn new() -> Self {
        Skip
    }
}

fn scalar_size(t: &ScalarType) -> u64 {
    match t {
        ScalarType::Char | ScalarType::UChar => 1,
        ScalarType::Short | ScalarType::UShort => 2,
        ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
        ScalarType::Double => 8,
    }
}

/// The fewest bytes one binary element can take (lists of length 0).
fn min_binary_size(e: &ElementDef) -> u64 {
    e.properties
        .values()
        .map(|p| match &p.data_type {
            PropertyType::Scalar(t) => scalar_size(t),
            PropertyType::List(count, _) => scalar_size(count),
        })
        .sum()
}

/// The header's keywords: a line starting with anything else is read as a comment.
const KEYWORDS: [&[u8]; 7] = [
    b"ply",
    b"format",
    b"element",
    b"property",
    b"comment",
    b"obj_info",
    b"end_header",
];

/// The header (up to and including its `end_header` line) with every line that starts with no
/// keyword turned into a `comment` line, the offset where the payload starts and how many lines
/// were turned; `None` when no line needs it (or the header never ends: the parser then says
/// what is wrong). Allocates a copy of the header only.
fn lenient_header(bytes: &[u8]) -> Option<(Vec<u8>, usize, usize)> {
    let mut out = Vec::new();
    let (mut start, mut turned) = (0usize, 0usize);
    while start < bytes.len() {
        let end = bytes[start..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(bytes.len(), |i| start + i + 1);
        let line = &bytes[start..end];
        let first = line
            .split(|b| b.is_ascii_whitespace())
            .find(|w| !w.is_empty())
            .unwrap_or(b"");
        if start == 0 && first != b"ply" {
            // Not a PLY file: the parser says so.
            return None;
        }
        if KEYWORDS.contains(&first) {
            out.extend_from_slice(line);
        } else {
            // The line's own text becomes the comment's (its terminator kept).
            out.extend_from_slice(b"comment ");
            // Leading blanks dropped, the line's terminator kept (an empty line stays a line).
            let text = line
                .iter()
                .position(|&b| b != b' ' && b != b'\t')
                .map_or(&line[line.len()..], |i| &line[i..]);
            out.extend_from_slice(text);
            turned += 1;
        }
        start = end;
        if first == b"end_header" {
            return (turned > 0).then_some((out, end, turned));
        }
    }
    None
}

pub(super) fn decode(bytes: &[u8], opts: &MeshOptions) -> Result<Mesh, InputError> {
    let lenient = lenient_header(bytes);
    let (header_bytes, mut reader): (&[u8], &[u8]) = match &lenient {
        Some((h, end, _)) => (h, &bytes[*end..]),
        None => (bytes, bytes),
    };
    let header = if lenient.is_some() {
        Parser::<Skip>::new().read_header(&mut { header_bytes })
    } else {
        Parser::<Skip>::new().read_header(&mut reader)
    }
    .map_err(|e| corrupt(format!("header: {e}")))?;

    let count = |name: &str| header.elements.get(name).map_or(0, |e| e.count as u64);
    let (n_vertices, n_faces) = (count("vertex"), count("face"));
    check_counts(n_vertices, n_faces, opts)?;
    let others: u64 = header
        .elements
        .values()
        .filter(|e| e.name != "vertex" && e.name != "face")
        .map(|e| e.count as u64)
        .sum();
    let max_others = opts.max_vertices.saturating_add(opts.max_triangles);
    if others > max_others {
        return Err(InputError::TooLarge {
            what: "PLY elements other than vertex and face",
            actual: others,
            max: max_others,
        });
    }
    let vertex_def = header
        .elements
        .get("vertex")
        .ok_or_else(|| InputError::Unusable("the PLY file has no vertex element".to_string()))?;
    for axis in ["x", "y", "z"] {
        if !vertex_def.properties.contains_key(axis) {
            return Err(InputError::Unusable(format!(
                "the PLY vertex element has no '{axis}' property"
            )));
        }
    }
    if header.encoding != Encoding::Ascii {
        let needed: u64 = header
            .elements
            .values()
            .map(|e| (e.count as u64).saturating_mul(min_binary_size(e)))
            .fold(0u64, u64::saturating_add);
        if needed > reader.len() as u64 {
            return Err(corrupt(format!(
                "the header's elements need at least {needed} bytes, the payload has {}",
                reader.len()
            )));
        }
    }
    let has = |names: &[&str]| names.iter().all(|n| vertex_def.properties.contains_key(*n));
    let has_normals = has(&["nx", "ny", "nz"]);
    let has_uvs = has(&["u", "v"]) || has(&["s", "t"]) || has(&["texture_u", "texture_v"]);
    let has_colors = COLOR_NAMES.iter().any(|names| has(names));

    let mut vertices: Vec<Vertex> = Vec::new();
    let mut faces: Vec<Face> = Vec::new();
    for (name, def) in &header.elements {
        let what = |e: std::io::Error| corrupt(format!("element '{name}': {e}"));
        match name.as_str() {
            "vertex" => {
                vertices = Parser::<Vertex>::new()
                    .read_payload_for_element(&mut reader, def, &header)
                    .map_err(what)?;
            }
            "face" => {
                faces = Parser::<Face>::new()
                    .read_payload_for_element(&mut reader, def, &header)
                    .map_err(what)?;
            }
            _ => {
                Parser::<Skip>::new()
                    .read_payload_for_element(&mut reader, def, &header)
                    .map_err(what)?;
            }
        }
    }

    let mut n_triangles = 0u64;
    for f in &faces {
        n_triangles += f.corners.len().saturating_sub(2) as u64;
    }
    check_counts(vertices.len() as u64, n_triangles, opts)?;
    let mut triangles = Vec::with_capacity(n_triangles as usize);
    for (i, f) in faces.iter().enumerate() {
        if f.corners.len() < 3 {
            continue;
        }
        let mut c = Vec::with_capacity(f.corners.len());
        for k in &f.corners {
            c.push(k.ok_or_else(|| corrupt(format!("face {i} has a negative vertex index")))?);
        }
        for k in 1..c.len() - 1 {
            triangles.push([c[0], c[k], c[k + 1]]);
        }
    }
    drop(faces);

    let positions = vertices
        .iter()
        .map(|v| v.p.map(|c| c as f32))
        .collect::<Vec<_>>();
    let normals = has_normals.then(|| vertices.iter().map(|v| v.n).collect());
    // PLY's texture coordinates have v up (MeshLab, VTK); glTF's convention is v down.
    let uvs = has_uvs.then(|| vertices.iter().map(|v| [v.uv[0], 1.0 - v.uv[1]]).collect());
    let colors = has_colors.then(|| {
        vertices
            .iter()
            .map(|v| {
                [
                    srgb_to_linear(v.c[0]),
                    srgb_to_linear(v.c[1]),
                    srgb_to_linear(v.c[2]),
                    v.c[3],
                ]
            })
            .collect()
    });
    drop(vertices);
    let mut builder = Builder::new();
    if let Some((_, _, turned)) = lenient {
        builder.note(format!(
            "the PLY header has {turned} line(s) with no keyword (e.g. an exporter's name); read \
             as comments"
        ));
    }
    builder.push_part(
        PartData {
            name: "ply".to_string(),
            base_color: if has_colors { [1.0; 4] } else { GREY },
            texture: None,
            positions,
            normals,
            uvs,
            colors,
            triangles,
        },
        FORMAT,
    )?;
    Ok(builder.build())
}

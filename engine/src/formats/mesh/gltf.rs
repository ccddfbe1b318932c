//! glTF 2.0 (`.gltf` with `data:` buffers) and GLB (with its BIN chunk) through the `gltf` crate
//! (1.4, without its `import` feature: we resolve buffers ourselves and never decode images).
//!
//! - **Scene.** The default scene (else the first; else every root node) is walked from its
//!   roots, composing node transforms parent → child (matrix or TRS, in f64). Every node that
//!   holds a mesh contributes each of its primitives as one part named after the node (else the
//!   mesh, else `part<i>`), with `/<p>` appended for the p-th primitive when a mesh has several.
//!   A node reached twice (a cycle, or a child of two parents) is `Corrupt`: glTF requires the
//!   node hierarchy to be a forest, and this also bounds the walk.
//! - **Primitives.** `TRIANGLES`, `TRIANGLE_STRIP` and `TRIANGLE_FAN` (converted to triangles
//!   with the spec's winding), indexed or not. `POINTS` and `LINES*` primitives are skipped: they
//!   have no surface to hold snow or dust. A node whose world matrix has a negative determinant
//!   (a mirror) gets its triangles' winding flipped, as the spec requires.
//! - **Attributes.** Positions by the world matrix, normals by its inverse transpose (then
//!   normalised in [`super::finish`]); UVs (`TEXCOORD_0`, any component type, as f32) and
//!   normals are kept only when every primitive has them. Base colour: the material's
//!   `baseColorFactor` (linear RGBA; the default material is white); textures are ignored.
//! - **Files.** Only self-contained files are read: buffers in the GLB BIN chunk or in base64
//!   `data:` URIs. A buffer with an external URI is [`InputError::Unusable`] (only one file is
//!   uploaded). Images are never decoded.
//! - **Limits.** Vertex and triangle counts are summed from the accessor counts in the JSON
//!   (once per instancing node) and checked before any buffer is decoded or any vertex read; a
//!   buffer shorter than its declared `byteLength` and an accessor outside its buffer are
//!   `Corrupt`.
//! - The frame is glTF's: Y up, metres. [`super::MeshOptions::up_axis`] does not apply.

use ::gltf::buffer::Source;
use ::gltf::mesh::Mode;
use ::gltf::{Document, Node, Primitive, Semantic};
use base64::Engine as _;

use super::{check_counts, Builder, MeshFormat, MeshOptions, PartData};
use crate::error::InputError;
use crate::geom::mesh::Mesh;

/// Column-major 4 × 4 matrix (`m[col][row]`), as glTF stores them.
type M4 = [[f64; 4]; 4];

const IDENTITY: M4 = [
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
    [0.0, 0.0, 0.0, 1.0],
];

fn mul(a: &M4, b: &M4) -> M4 {
    let mut r = [[0.0; 4]; 4];
    for (c, col) in r.iter_mut().enumerate() {
        for (row, v) in col.iter_mut().enumerate() {
            *v = (0..4).map(|k| a[k][row] * b[c][k]).sum();
        }
    }
    r
}

/// The upper 3 × 3 block's determinant and its inverse transpose (zero when singular).
fn normal_matrix(m: &M4) -> (f64, [[f64; 3]; 3]) {
    let a = |r: usize, c: usize| m[c][r];
    // Cofactors C[r][c]; inverse transpose = C / det.
    let cof = |r: usize, c: usize| {
        let (r1, r2) = ((r + 1) % 3, (r + 2) % 3);
        let (c1, c2) = ((c + 1) % 3, (c + 2) % 3);
        a(r1, c1) * a(r2, c2) - a(r1, c2) * a(r2, c1)
    };
    let det = a(0, 0) * cof(0, 0) + a(0, 1) * cof(0, 1) + a(0, 2) * cof(0, 2);
    let inv = if det != 0.0 { 1.0 / det } else { 0.0 };
    let mut n = [[0.0; 3]; 3];
    for (r, row) in n.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = cof(r, c) * inv;
        }
    }
    (det, n)
}

fn to_m4(m: [[f32; 4]; 4]) -> M4 {
    m.map(|c| c.map(f64::from))
}

fn transform_point(m: &M4, p: [f32; 3]) -> [f32; 3] {
    let p = p.map(f64::from);
    let mut r = [0.0f64; 3];
    for (row, v) in r.iter_mut().enumerate() {
        *v = m[0][row] * p[0] + m[1][row] * p[1] + m[2][row] * p[2] + m[3][row];
    }
    r.map(|v| v as f32)
}

fn transform_normal(n3: &[[f64; 3]; 3], v: [f32; 3]) -> [f32; 3] {
    let v = v.map(f64::from);
    let mut r = [0.0f64; 3];
    for (row, o) in r.iter_mut().enumerate() {
        *o = n3[row][0] * v[0] + n3[row][1] * v[1] + n3[row][2] * v[2];
    }
    r.map(|v| v as f32)
}

pub(super) fn decode(
    bytes: &[u8],
    format: MeshFormat,
    opts: &MeshOptions,
) -> Result<Mesh, InputError> {
    let name = format.name();
    let corrupt = |detail: String| InputError::Corrupt {
        format: name,
        detail,
    };
    let (json, blob) = if bytes.starts_with(b"glTF") {
        let glb = ::gltf::Glb::from_slice(bytes).map_err(|e| corrupt(e.to_string()))?;
        (glb.json, glb.bin)
    } else {
        (std::borrow::Cow::Borrowed(bytes), None)
    };
    let root = ::gltf::json::Root::from_slice(&json).map_err(|e| corrupt(e.to_string()))?;
    drop(json);
    precheck(&root).map_err(corrupt)?;
    let document = ::gltf::Document::from_json(root).map_err(|e| corrupt(e.to_string()))?;
    let doc = &document;

    let instances = walk_scene(doc).map_err(corrupt)?;
    let (mut vertices, mut triangles) = (0u64, 0u64);
    for (node, _) in &instances {
        for prim in node.mesh().into_iter().flat_map(|m| m.primitives()) {
            let v = prim
                .get(&Semantic::Positions)
                .map_or(0, |a| a.count() as u64);
            let corners = prim.indices().map_or(v, |a| a.count() as u64);
            vertices = vertices.saturating_add(v);
            triangles = triangles.saturating_add(triangle_count(prim.mode(), corners));
        }
    }
    check_counts(vertices, triangles, opts)?;

    let buffers = resolve_buffers(doc, blob.as_deref(), name)?;
    let mut builder = Builder::new();
    let mut part_index = 0usize;
    for (node, world) in &instances {
        let Some(mesh) = node.mesh() else { continue };
        let several = mesh.primitives().len() > 1;
        for (p, prim) in mesh.primitives().enumerate() {
            if triangle_count(prim.mode(), 1 << 20) == 0 {
                continue; // points and lines
            }
            let base = node
                .name()
                .or(mesh.name())
                .map_or_else(|| format!("part{part_index}"), str::to_string);
            let part_name = if several { format!("{base}/{p}") } else { base };
            part_index += 1;
            let part = read_primitive(&prim, world, &buffers, part_name).map_err(corrupt)?;
            builder.push_part(part, name)?;
        }
    }
    Ok(builder.build())
}

/// What `gltf-json` 1.4's validator indexes without checking: a primitive's `POSITION`
/// accessor (it panics on an index out of range, found by the byte-flip test).
fn precheck(root: &::gltf::json::Root) -> Result<(), String> {
    let n = root.accessors.len();
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            for (semantic, accessor) in &prim.attributes {
                if accessor.value() >= n {
                    return Err(format!(
                        "mesh {m} primitive {p}: attribute {semantic:?} refers to accessor {}, \
                         but there are {n}",
                        accessor.value()
                    ));
                }
            }
        }
    }
    Ok(())
}

/// Triangles made from `corners` indices in `mode` (0 for points and lines).
fn triangle_count(mode: Mode, corners: u64) -> u64 {
    match mode {
        Mode::Triangles => corners / 3,
        Mode::TriangleStrip | Mode::TriangleFan => corners.saturating_sub(2),
        Mode::Points | Mode::Lines | Mode::LineLoop | Mode::LineStrip => 0,
    }
}

/// Every node of the scene with its world matrix, parents before children.
fn walk_scene(doc: &Document) -> Result<Vec<(Node<'_>, M4)>, String> {
    let roots: Vec<Node> = match doc.default_scene().or_else(|| doc.scenes().next()) {
        Some(scene) => scene.nodes().collect(),
        None => {
            let mut has_parent = vec![false; doc.nodes().len()];
            for n in doc.nodes() {
                for c in n.children() {
                    has_parent[c.index()] = true;
                }
            }
            doc.nodes().filter(|n| !has_parent[n.index()]).collect()
        }
    };
    let mut seen = vec![false; doc.nodes().len()];
    let mut out = Vec::new();
    let mut stack: Vec<(Node, M4)> = roots.into_iter().rev().map(|n| (n, IDENTITY)).collect();
    while let Some((node, parent)) = stack.pop() {
        if std::mem::replace(&mut seen[node.index()], true) {
            return Err(format!(
                "node {} is reached twice; a glTF node hierarchy must be a set of trees",
                node.index()
            ));
        }
        let world = mul(&parent, &to_m4(node.transform().matrix()));
        let children: Vec<Node> = node.children().collect();
        for c in children.into_iter().rev() {
            stack.push((c, world));
        }
        out.push((node, world));
    }
    Ok(out)
}

/// The bytes of every buffer: the GLB BIN chunk or a base64 `data:` URI.
fn resolve_buffers<'a>(
    doc: &Document,
    blob: Option<&'a [u8]>,
    format: &'static str,
) -> Result<Vec<std::borrow::Cow<'a, [u8]>>, InputError> {
    let corrupt = |detail: String| InputError::Corrupt { format, detail };
    let mut out = Vec::with_capacity(doc.buffers().len());
    for b in doc.buffers() {
        let data: std::borrow::Cow<[u8]> = match b.source() {
            Source::Bin => std::borrow::Cow::Borrowed(blob.ok_or_else(|| {
                corrupt(format!(
                    "buffer {} refers to the GLB BIN chunk, which is missing",
                    b.index()
                ))
            })?),
            Source::Uri(uri) => {
                let Some(rest) = uri.strip_prefix("data:") else {
                    return Err(InputError::Unusable(format!(
                        "buffer {} refers to the external file '{}'; only self-contained files \
                         can be uploaded (a GLB, or a .gltf with embedded data: URIs)",
                        b.index(),
                        uri.chars().take(200).collect::<String>()
                    )));
                };
                let Some((_, payload)) = rest.split_once(";base64,") else {
                    return Err(corrupt(format!(
                        "buffer {}: only base64 data: URIs are supported",
                        b.index()
                    )));
                };
                // Decoded size ≤ 3/4 of the text, which the upload limit already bounds.
                let bytes = base64::engine::general_purpose::STANDARD
                    .decode(payload.trim_end())
                    .map_err(|e| corrupt(format!("buffer {}: bad base64: {e}", b.index())))?;
                std::borrow::Cow::Owned(bytes)
            }
        };
        if data.len() < b.length() {
            return Err(corrupt(format!(
                "buffer {} declares {} bytes but holds {}",
                b.index(),
                b.length(),
                data.len()
            )));
        }
        out.push(data);
    }
    Ok(out)
}

/// One primitive in world space, as a part with local indices.
fn read_primitive(
    prim: &Primitive<'_>,
    world: &M4,
    buffers: &[std::borrow::Cow<'_, [u8]>],
    name: String,
) -> Result<PartData, String> {
    let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d[..]));
    let positions: Vec<[f32; 3]> = reader
        .read_positions()
        .ok_or_else(|| format!("{name}: POSITION is missing or lies outside its buffer"))?
        .map(|p| transform_point(world, p))
        .collect();
    let n = positions.len();
    let (det, nm) = normal_matrix(world);
    let normals = reader
        .read_normals()
        .map(|it| it.map(|v| transform_normal(&nm, v)).collect::<Vec<_>>())
        .filter(|v| v.len() == n);
    let uvs = reader
        .read_tex_coords(0)
        .map(|t| t.into_f32().collect::<Vec<_>>())
        .filter(|v| v.len() == n);
    let corners: Vec<u32> = match prim.indices() {
        Some(_) => reader
            .read_indices()
            .ok_or_else(|| format!("{name}: the index accessor lies outside its buffer"))?
            .into_u32()
            .collect(),
        None => (0..u32::try_from(n).map_err(|_| format!("{name}: too many vertices"))?).collect(),
    };
    if let Some(&bad) = corners.iter().find(|&&i| i as usize >= n) {
        return Err(format!(
            "{name}: index {bad} is out of range ({n} vertices)"
        ));
    }
    let mut triangles: Vec<[u32; 3]> = match prim.mode() {
        Mode::Triangles => corners
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect(),
        // Spec §3.7.2.1: strip triangle i = (i, i + 1 + i%2, i + 2 − i%2); fan = (i + 1, i + 2, 0).
        Mode::TriangleStrip => (0..corners.len().saturating_sub(2))
            .map(|i| {
                let odd = i % 2;
                [corners[i], corners[i + 1 + odd], corners[i + 2 - odd]]
            })
            .collect(),
        Mode::TriangleFan => (0..corners.len().saturating_sub(2))
            .map(|i| [corners[i + 1], corners[i + 2], corners[0]])
            .collect(),
        Mode::Points | Mode::Lines | Mode::LineLoop | Mode::LineStrip => Vec::new(),
    };
    if det < 0.0 {
        for t in &mut triangles {
            t.swap(1, 2);
        }
    }
    let material = prim.material();
    Ok(PartData {
        name,
        base_color: material.pbr_metallic_roughness().base_color_factor(),
        positions,
        normals,
        uvs,
        triangles,
    })
}

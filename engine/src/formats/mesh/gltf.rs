//! glTF 2.0 (`.gltf` with `data:` buffers) and GLB (with its BIN chunk) through the `gltf` crate
//! (1.4, without its `import` feature: we resolve buffers and images ourselves, so the limits
//! hold before anything is decoded).
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
//!   `baseColorFactor` (linear RGBA; the default material is white) times `COLOR_0` (kept as
//!   [`crate::geom::Mesh::colors`]) times its `baseColorTexture` (PNG or JPEG, through the
//!   texture's `texCoord` set and sampler wrap modes; [`super::texture`]). Each texture is decoded
//!   once however many parts use it. Not applied: `KHR_texture_transform` and other texture
//!   extensions (noted in [`crate::geom::Mesh::notes`]); an image that is not PNG/JPEG or does not
//!   decode leaves the base colour, with a note; an image over the pixel limit is `TooLarge`.
//! - **Files.** Buffers and images in the GLB BIN chunk, in base64 `data:` URIs, or in the
//!   [`super::Sidecars`] by URI (the CLI reads them from beside a `.gltf`). A buffer found nowhere
//!   is [`InputError::Unusable`] (an HTTP upload is one file: send a GLB); a missing image is a
//!   note.
//! - **Limits.** Vertex and triangle counts are summed from the accessor counts in the JSON
//!   (once per instancing node) and checked before any buffer is decoded or any vertex read; a
//!   buffer shorter than its declared `byteLength` and an accessor outside its buffer are
//!   `Corrupt`.
//! - The frame is glTF's: Y up, metres. [`super::MeshOptions::up_axis`] does not apply.

use std::collections::HashMap;
use std::sync::Arc;

use ::gltf::buffer::Source;
use ::gltf::mesh::Mode;
use ::gltf::texture::WrappingMode;
use ::gltf::{Document, Node, Primitive, Semantic};
use base64::Engine as _;

use super::texture::{decode_image, store_side, ImageError};
use super::{check_counts, Builder, MeshFormat, MeshOptions, PartData, Sidecars};
use crate::error::InputError;
use crate::geom::mesh::{Mesh, Texture, TextureWrap};

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

/// The non-`data:` buffer and image URIs of a `.gltf` (for [`super::gather_sidecars`]).
pub(super) fn external_uris(bytes: &[u8]) -> Vec<String> {
    let Ok(v) = serde_json::from_slice::<serde_json::Value>(bytes) else {
        return Vec::new();
    };
    ["buffers", "images"]
        .iter()
        .filter_map(|k| v.get(*k)?.as_array())
        .flatten()
        .filter_map(|b| b.get("uri")?.as_str())
        .filter(|u| !u.starts_with("data:"))
        .map(str::to_string)
        .collect()
}

/// The bytes of a `data:` URI (base64 only).
fn data_uri(uri: &str) -> Option<Result<Vec<u8>, String>> {
    let rest = uri.strip_prefix("data:")?;
    let Some((_, payload)) = rest.split_once(";base64,") else {
        return Some(Err("only base64 data: URIs are supported".to_string()));
    };
    // Decoded size ≤ 3/4 of the text, which the upload limit already bounds.
    Some(
        base64::engine::general_purpose::STANDARD
            .decode(payload.trim_end())
            .map_err(|e| format!("bad base64: {e}")),
    )
}

fn wrap(mode: WrappingMode) -> TextureWrap {
    match mode {
        WrappingMode::Repeat => TextureWrap::Repeat,
        WrappingMode::ClampToEdge => TextureWrap::Clamp,
        WrappingMode::MirroredRepeat => TextureWrap::Mirror,
    }
}

/// Our decoded textures and the map from glTF texture index to ours.
type DecodedTextures = (Vec<Arc<Texture>>, HashMap<usize, usize>);

/// Decodes the base-colour textures the instanced primitives use; returns our textures and the
/// map from glTF texture index to ours. Missing or undecodable images become notes.
fn base_color_textures(
    doc: &Document,
    instances: &[(Node<'_>, M4)],
    buffers: &[std::borrow::Cow<'_, [u8]>],
    sidecars: Sidecars<'_>,
    opts: &MeshOptions,
    builder: &mut Builder,
) -> Result<DecodedTextures, InputError> {
    let mut used: Vec<usize> = Vec::new();
    for (node, _) in instances {
        for prim in node.mesh().into_iter().flat_map(|m| m.primitives()) {
            let pbr = prim.material().pbr_metallic_roughness();
            if let Some(info) = pbr.base_color_texture() {
                let t = info.texture().index();
                if !used.contains(&t) {
                    used.push(t);
                }
            }
        }
    }
    let side = store_side(used.len());
    let mut textures = Vec::new();
    let mut map = HashMap::new();
    for t in used {
        let Some(tex) = doc.textures().nth(t) else {
            continue;
        };
        let image = tex.source();
        let name = image
            .name()
            .map(str::to_string)
            .unwrap_or_else(|| format!("image {}", image.index()));
        let bytes: Result<Vec<u8>, String> = match image.source() {
            ::gltf::image::Source::View { view, .. } => {
                let (o, l) = (view.offset(), view.length());
                buffers
                    .get(view.buffer().index())
                    .and_then(|b| b.get(o..o.checked_add(l)?))
                    .map(<[u8]>::to_vec)
                    .ok_or_else(|| format!("the bufferView of {name} lies outside its buffer"))
            }
            ::gltf::image::Source::Uri { uri, .. } => match data_uri(uri) {
                Some(r) => r.map_err(|e| format!("{name}: {e}")),
                None => sidecars.get(uri).map(<[u8]>::to_vec).ok_or_else(|| {
                    format!(
                        "image '{}' is an external file that was not given (an upload is one \
                         file: send a GLB)",
                        uri.chars().take(200).collect::<String>()
                    )
                }),
            },
        };
        let sampler = tex.sampler();
        let decoded = bytes.map_err(ImageError::Unsupported).and_then(|b| {
            decode_image(
                Arc::from(b),
                &name,
                [wrap(sampler.wrap_s()), wrap(sampler.wrap_t())],
                opts.max_texture_pixels,
                side,
            )
        });
        match decoded {
            Ok(texture) => {
                map.insert(t, textures.len());
                textures.push(Arc::new(texture));
            }
            Err(ImageError::TooLarge(e)) => return Err(e),
            Err(e) => builder.note(format!("{e}; its parts keep their base colour")),
        }
    }
    Ok((textures, map))
}

pub(super) fn decode(
    bytes: &[u8],
    format: MeshFormat,
    opts: &MeshOptions,
    sidecars: Sidecars<'_>,
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
    let texture_extensions: Vec<String> = root
        .extensions_used
        .iter()
        .filter(|e| e.starts_with("KHR_texture") || e.starts_with("EXT_texture"))
        .cloned()
        .collect();
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

    let buffers = resolve_buffers(doc, blob.as_deref(), name, sidecars)?;
    let mut builder = Builder::new();
    let (textures, texture_map) =
        base_color_textures(doc, &instances, &buffers, sidecars, opts, &mut builder)?;
    if !texture_extensions.is_empty() && !textures.is_empty() {
        builder.note(format!(
            "texture extensions {texture_extensions:?} are not applied"
        ));
    }
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
            let part =
                read_primitive(&prim, world, &buffers, part_name, &texture_map).map_err(corrupt)?;
            builder.push_part(part, name)?;
        }
    }
    Ok(builder.build_with(textures))
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
    sidecars: Sidecars<'a>,
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
            Source::Uri(uri) => match data_uri(uri) {
                Some(r) => std::borrow::Cow::Owned(
                    r.map_err(|e| corrupt(format!("buffer {}: {e}", b.index())))?,
                ),
                None => std::borrow::Cow::Borrowed(sidecars.get(uri).ok_or_else(|| {
                    InputError::Unusable(format!(
                        "buffer {} refers to the external file '{}', which was not given; an \
                         upload is one file (a GLB, or a .gltf with embedded data: URIs); the \
                         CLI reads such files from beside the .gltf",
                        b.index(),
                        uri.chars().take(200).collect::<String>()
                    ))
                })?),
            },
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
    texture_map: &HashMap<usize, usize>,
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
    let material = prim.material();
    let pbr = material.pbr_metallic_roughness();
    let info = pbr.base_color_texture();
    let texture = info
        .as_ref()
        .and_then(|i| texture_map.get(&i.texture().index()).copied());
    // The UV set the texture names (set 0 without a texture: the dust's fibre mapping uses it).
    let set = match (&info, texture) {
        (Some(i), Some(_)) => i.tex_coord(),
        _ => 0,
    };
    let uvs = reader
        .read_tex_coords(set)
        .map(|t| t.into_f32().collect::<Vec<_>>())
        .filter(|v| v.len() == n);
    let colors = reader
        .read_colors(0)
        .map(|c| c.into_rgba_f32().collect::<Vec<_>>())
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
    Ok(PartData {
        name,
        base_color: pbr.base_color_factor(),
        texture,
        positions,
        normals,
        uvs,
        colors,
        triangles,
    })
}

//! Binary glTF 2.0 (GLB) export for the mesh pipelines: the snow meshes and the scene with snow
//! (SPEC §2 "Output shape": `snow.glb`, `scene.glb`, `displaced.glb`) and the dusty mesh (SPEC §4
//! "Outputs": `dusty.glb`).
//!
//! **Structure.** One glTF node per [`GlbNode`], each with its own mesh of one triangle primitive
//! (one per material group when the node has [`GlbNode::groups`], sharing one set of vertex
//! accessors; then one more per [`GlbNode::overlays`] entry) and its own material per primitive,
//! all children of scene 0 in input order. Nodes with no triangles or no
//! positions are skipped (the validator rejects empty accessors), so node `i` of the file is the
//! `i`-th *non-empty* input node. No node transforms: positions are already in world space,
//! metres, Y up (glTF's frame; see [`crate::geom::mesh`]).
//!
//! **Layout.** Per node, in this order: POSITION (float VEC3, with min/max), NORMAL (float VEC3,
//! renormalised to unit length; a zero normal becomes +Y), TEXCOORD_0 (float VEC2), COLOR_0
//! (float VEC4, linear RGBA clamped to 0..1 per the glTF spec), the application-specific
//! attributes (`_NAME`, float SCALAR) in the node's order, indices (u32), then the node's
//! PNG texture if any (an `image/png` bufferView, sampler with REPEAT wrap and linear filters) or
//! its input texture (the image file as read, PNG or JPEG, once per file; a sampler with its wrap
//! modes and mipmapped minification).
//! Every bufferView starts on a 4-byte boundary. The container (chunk padding) is
//! [`super::glb::glb_container`]'s. `asset.generator` is `"phenomena"`; `extras` goes on the root
//! object.
//!
//! **Cost.** One pass over each node's arrays; allocates the binary buffer (12 B per position,
//! 12 per normal, 8 per UV, 16 per colour, 12 per triangle, plus textures) and the output.
//! Panics on caller bugs: attribute arrays of another length than `positions`, or an index
//! `≥ positions.len()`.

use std::sync::Arc;

use serde_json::{json, Value};

use super::glb::glb_container;
use crate::geom::mesh::{Mesh, Texture, TextureWrap};

const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;
const REPEAT: u32 = 10497;
const CLAMP_TO_EDGE: u32 = 33071;
const MIRRORED_REPEAT: u32 = 33648;
const LINEAR: u32 = 9729;
const LINEAR_MIPMAP_LINEAR: u32 = 9987;

fn gl_wrap(w: TextureWrap) -> u32 {
    match w {
        TextureWrap::Repeat => REPEAT,
        TextureWrap::Clamp => CLAMP_TO_EDGE,
        TextureWrap::Mirror => MIRRORED_REPEAT,
    }
}

/// One node of the output: a mesh in world space with one material.
#[derive(Debug, Clone)]
pub struct GlbNode<'a> {
    /// Node, mesh and (unless the material names itself) material name.
    pub name: &'a str,
    /// Vertex positions, metres, Y up. Must be finite.
    pub positions: &'a [[f32; 3]],
    /// Per-vertex normals (renormalised on export), same length as `positions`.
    pub normals: Option<&'a [[f32; 3]]>,
    /// Per-vertex texture coordinates (glTF convention: v down from the image's top).
    pub uvs: Option<&'a [[f32; 2]]>,
    /// Per-vertex colours, linear RGBA 0..1 (exported as `COLOR_0`, multiplied by the base colour
    /// in viewers).
    pub colors: Option<&'a [[f32; 4]]>,
    /// Triangles, counter-clockwise seen from outside, indices into `positions`.
    pub triangles: &'a [[u32; 3]],
    pub material: GlbMaterial,
    /// Application-specific per-vertex scalars (glTF 2.0 §3.7.2.1: semantics starting with `_`),
    /// exported as float SCALAR attributes, each as long as `positions`. Panics on a name without
    /// the leading `_` (a caller bug).
    pub custom: &'a [(&'a str, &'a [f32])],
    /// Material groups: when not empty, the node's triangles are drawn as one primitive per
    /// group (its range of `triangles`, in order), all sharing the node's vertex attributes
    /// (one set of accessors), each with its own material; `material` is then unused. For a
    /// surface whose parts have different materials but share vertices (the displaced scene of
    /// `displaced.glb`). Empty ranges are skipped; ranges past the end are clipped.
    pub groups: &'a [GlbGroup],
    /// Further primitives of this node's mesh, after its own, each drawn with its own arrays and
    /// material (e.g. blended decal layers); their `name`, `groups` and own `overlays` are
    /// ignored, their `custom` attributes are written. Empty ones are skipped.
    pub overlays: &'a [GlbNode<'a>],
}

/// One material group of a [`GlbNode`]: a range of its triangles and their material.
#[derive(Debug, Clone, PartialEq)]
pub struct GlbGroup {
    /// Triangle indices (into [`GlbNode::triangles`]) of this group.
    pub triangles: std::ops::Range<usize>,
    pub material: GlbMaterial,
}

/// A metallic-roughness material.
#[derive(Debug, Clone, PartialEq)]
pub struct GlbMaterial {
    /// Material name. Empty = the node's name.
    pub name: String,
    /// Base colour factor, linear RGBA 0..1. Default: opaque white.
    pub base_color: [f32; 4],
    /// Roughness 0..1. Default: 1 (matte).
    pub roughness: f32,
    /// Metalness 0..1. Default: 0.
    pub metallic: f32,
    /// `alphaMode: BLEND` (else OPAQUE). Default: false.
    pub alpha_blend: bool,
    /// `doubleSided`. Default: false.
    pub double_sided: bool,
    /// A PNG embedded as the base colour texture (sRGB, per glTF), sampled with REPEAT wrap
    /// through `TEXCOORD_0`. Ignored when the node has no UVs. Default: none.
    pub texture_png: Option<Vec<u8>>,
    /// An input texture ([`Texture::encoded`], PNG or JPEG) as the base colour texture, with its
    /// wrap modes; embedded once per file however many nodes use it (same `Arc`). Used when
    /// `texture_png` is none and the node has UVs. Default: none.
    pub texture: Option<Arc<Texture>>,
}

impl Default for GlbMaterial {
    fn default() -> Self {
        Self {
            name: String::new(),
            base_color: [1.0; 4],
            roughness: 1.0,
            metallic: 0.0,
            alpha_blend: false,
            double_sided: false,
            texture_png: None,
            texture: None,
        }
    }
}

/// Encode `nodes` as a GLB (see the module doc). `extras` (any JSON) is stored as the root
/// object's `extras`. With no non-empty node the result is a valid GLB with an empty scene.
pub fn mesh_glb(nodes: &[GlbNode], extras: Option<Value>) -> Vec<u8> {
    let mut b = Builder::default();
    let mut gl_nodes: Vec<Value> = Vec::new();
    let mut meshes: Vec<Value> = Vec::new();

    for node in nodes {
        let mut primitives = b.primitives(node, node.groups);
        if primitives.is_empty() {
            continue;
        }
        for o in node.overlays {
            primitives.extend(b.primitives(o, &[]));
        }
        meshes.push(json!({ "name": node.name, "primitives": primitives }));
        gl_nodes.push(json!({ "name": node.name, "mesh": meshes.len() - 1 }));
    }

    let mut doc = json!({
        "asset": { "version": "2.0", "generator": "phenomena" },
        "scene": 0,
        // An empty `nodes` array is an error for the validator: an empty scene has none.
        "scenes": [{}],
    });
    if !gl_nodes.is_empty() {
        doc["scenes"][0]["nodes"] = json!((0..gl_nodes.len()).collect::<Vec<_>>());
        doc["nodes"] = json!(gl_nodes);
        doc["meshes"] = json!(meshes);
        doc["materials"] = json!(b.materials);
        doc["accessors"] = json!(b.accessors);
        doc["bufferViews"] = json!(b.views);
        doc["buffers"] = json!([{ "byteLength": b.bin.len() }]);
    }
    if !b.textures.is_empty() {
        // Sampler 0 serves the generated textures; input textures add one per wrap pair.
        let mut samplers = vec![
            json!({"magFilter": LINEAR, "minFilter": LINEAR, "wrapS": REPEAT, "wrapT": REPEAT}),
        ];
        samplers.extend(b.samplers.iter().map(|w| {
            json!({
                "magFilter": LINEAR, "minFilter": LINEAR_MIPMAP_LINEAR,
                "wrapS": gl_wrap(w[0]), "wrapT": gl_wrap(w[1])
            })
        }));
        doc["samplers"] = json!(samplers);
        doc["images"] = json!(b.images);
        doc["textures"] = json!(b.textures);
    }
    if let Some(e) = extras {
        doc["extras"] = e;
    }
    glb_container(&doc, &b.bin)
}

/// The growing binary buffer and the JSON arrays that index it.
#[derive(Default)]
struct Builder {
    bin: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
    materials: Vec<Value>,
    images: Vec<Value>,
    textures: Vec<Value>,
    /// Wrap pairs of the input textures' samplers (sampler i + 1).
    samplers: Vec<[TextureWrap; 2]>,
    /// Input textures already embedded: (the `Arc`'s address, texture index).
    embedded: Vec<(usize, usize)>,
}

impl Builder {
    /// Append bytes as a new bufferView (4-byte aligned); returns its index.
    fn view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        while self.bin.len() % 4 != 0 {
            self.bin.push(0);
        }
        let off = self.bin.len();
        self.bin.extend_from_slice(bytes);
        let mut v = json!({ "buffer": 0, "byteOffset": off, "byteLength": bytes.len() });
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        self.views.push(v);
        self.views.len() - 1
    }

    /// A float vertex attribute (`ty` VEC2/VEC3/VEC4/SCALAR) in its own view; returns the
    /// accessor's index.
    fn attribute(&mut self, bytes: &[u8], count: usize, ty: &str) -> usize {
        let v = self.view(bytes, Some(ARRAY_BUFFER));
        accessor(&mut self.accessors, v, count, ty, FLOAT)
    }

    /// The node's arrays, materials and textures as triangle primitives (JSON): one, or one
    /// per non-empty group of `groups` sharing the vertex accessors. None for a node with no
    /// positions or no triangles (skipped: the validator rejects empty accessors).
    fn primitives(&mut self, node: &GlbNode, groups: &[GlbGroup]) -> Vec<Value> {
        let n = node.positions.len();
        let nt = node.triangles.len();
        let ranges: Vec<(std::ops::Range<usize>, &GlbMaterial)> = if groups.is_empty() {
            vec![(0..nt, &node.material)]
        } else {
            groups
                .iter()
                .map(|g| {
                    (
                        g.triangles.start.min(nt)..g.triangles.end.min(nt),
                        &g.material,
                    )
                })
                .collect()
        }
        .into_iter()
        .filter(|(r, _)| !r.is_empty())
        .collect();
        if n == 0 || ranges.is_empty() {
            return Vec::new();
        }
        for (what, len) in [
            ("normals", node.normals.map(<[_]>::len)),
            ("uvs", node.uvs.map(<[_]>::len)),
            ("colors", node.colors.map(<[_]>::len)),
        ]
        .into_iter()
        .chain(node.custom.iter().map(|(k, v)| (*k, Some(v.len()))))
        {
            if let Some(len) = len {
                assert_eq!(len, n, "{}: {what} must match positions", node.name);
            }
        }
        let mut attributes = serde_json::Map::new();

        // POSITION with bounds.
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for p in node.positions {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        let a = self.attribute(&flat_bytes(node.positions), n, "VEC3");
        self.accessors[a]["min"] = json!(lo);
        self.accessors[a]["max"] = json!(hi);
        attributes.insert("POSITION".into(), json!(a));

        if let Some(normals) = node.normals {
            let unit: Vec<[f32; 3]> = normals.iter().map(|&v| unit_normal(v)).collect();
            let a = self.attribute(&flat_bytes(&unit), n, "VEC3");
            attributes.insert("NORMAL".into(), json!(a));
        }
        if let Some(uvs) = node.uvs {
            let a = self.attribute(&flat_bytes(uvs), n, "VEC2");
            attributes.insert("TEXCOORD_0".into(), json!(a));
        }
        if let Some(colors) = node.colors {
            let c: Vec<[f32; 4]> = colors
                .iter()
                .map(|c| c.map(|v| if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) }))
                .collect();
            let a = self.attribute(&flat_bytes(&c), n, "VEC4");
            attributes.insert("COLOR_0".into(), json!(a));
        }
        for (semantic, values) in node.custom {
            assert!(
                semantic.starts_with('_'),
                "{}: custom attribute {semantic} must start with '_'",
                node.name
            );
            let bytes: Vec<u8> = values.iter().flat_map(|x| x.to_le_bytes()).collect();
            let a = self.attribute(&bytes, n, "SCALAR");
            attributes.insert((*semantic).into(), json!(a));
        }
        let attributes = Value::Object(attributes);
        let has_uvs = node.uvs.is_some();
        ranges
            .into_iter()
            .map(|(range, m)| {
                let indices = self.indices(node.name, n, &node.triangles[range]);
                let material = self.material(m, node.name, has_uvs);
                json!({
                    "attributes": attributes.clone(), "indices": indices,
                    "material": material, "mode": 4
                })
            })
            .collect()
    }

    /// Triangle indices (u32) as an accessor; returns its index. Panics on an index `≥ n`.
    fn indices(&mut self, name: &str, n: usize, triangles: &[[u32; 3]]) -> usize {
        let idx: Vec<u8> = triangles
            .iter()
            .flat_map(|t| {
                for &i in t {
                    assert!((i as usize) < n, "{name}: index {i} out of range");
                }
                *t
            })
            .flat_map(u32::to_le_bytes)
            .collect();
        let v = self.view(&idx, Some(ELEMENT_ARRAY_BUFFER));
        accessor(
            &mut self.accessors,
            v,
            triangles.len() * 3,
            "SCALAR",
            UNSIGNED_INT,
        )
    }

    /// A material (and its texture, when the primitive has UVs); returns its index.
    fn material(&mut self, m: &GlbMaterial, node_name: &str, has_uvs: bool) -> usize {
        let mut pbr = json!({
            "baseColorFactor": m.base_color.map(|v| if v.is_nan() { 1.0 } else { v.clamp(0.0, 1.0) }),
            "metallicFactor": m.metallic.clamp(0.0, 1.0),
            "roughnessFactor": m.roughness.clamp(0.0, 1.0),
        });
        if let (Some(png), true) = (&m.texture_png, has_uvs) {
            let v = self.view(png, None);
            self.images
                .push(json!({ "bufferView": v, "mimeType": "image/png" }));
            self.textures
                .push(json!({ "sampler": 0, "source": self.images.len() - 1 }));
            pbr["baseColorTexture"] = json!({ "index": self.textures.len() - 1, "texCoord": 0 });
        } else if let (Some(tex), true) = (&m.texture, has_uvs) {
            let key = Arc::as_ptr(tex) as usize;
            let index = match self.embedded.iter().find(|(k, _)| *k == key) {
                Some(&(_, i)) => i,
                None => {
                    let v = self.view(&tex.encoded, None);
                    self.images
                        .push(json!({ "bufferView": v, "mimeType": tex.mime }));
                    let sampler = match self.samplers.iter().position(|w| *w == tex.wrap) {
                        Some(k) => k + 1,
                        None => {
                            self.samplers.push(tex.wrap);
                            self.samplers.len()
                        }
                    };
                    self.textures
                        .push(json!({ "sampler": sampler, "source": self.images.len() - 1 }));
                    self.embedded.push((key, self.textures.len() - 1));
                    self.textures.len() - 1
                }
            };
            pbr["baseColorTexture"] = json!({ "index": index, "texCoord": 0 });
        }
        let name = if m.name.is_empty() {
            node_name
        } else {
            &m.name
        };
        let mut mat = json!({ "name": name, "pbrMetallicRoughness": pbr });
        if m.alpha_blend {
            mat["alphaMode"] = json!("BLEND");
        }
        if m.double_sided {
            mat["doubleSided"] = json!(true);
        }
        self.materials.push(mat);
        self.materials.len() - 1
    }
}

/// One part of an input [`Mesh`] as a self-contained node: only the vertices its triangles use,
/// renumbered in first-use order. See [`scene_nodes`].
#[derive(Debug, Clone, PartialEq)]
pub struct PartNode {
    /// The part's name.
    pub name: String,
    pub positions: Vec<[f32; 3]>,
    pub normals: Option<Vec<[f32; 3]>>,
    pub uvs: Option<Vec<[f32; 2]>>,
    pub triangles: Vec<[u32; 3]>,
    /// The part's base colour, linear RGBA.
    pub base_color: [f32; 4],
    /// Per-vertex colours (linear RGBA) when the mesh has them.
    pub colors: Option<Vec<[f32; 4]>>,
    /// The part's base-colour texture, when it has one and the mesh has UVs.
    pub texture: Option<Arc<Texture>>,
}

impl PartNode {
    /// A [`GlbNode`] borrowing this part, with a matte, double-sided material of the part's base
    /// colour and texture (alpha blended when its alpha is below 1) and its vertex colours as
    /// `COLOR_0`. Input windings are not trusted, hence double-sided.
    pub fn node(&self) -> GlbNode<'_> {
        GlbNode {
            name: &self.name,
            positions: &self.positions,
            normals: self.normals.as_deref(),
            uvs: self.uvs.as_deref(),
            colors: self.colors.as_deref(),
            triangles: &self.triangles,
            custom: &[],
            groups: &[],
            overlays: &[],
            material: GlbMaterial {
                name: self.name.clone(),
                base_color: self.base_color,
                alpha_blend: self.base_color[3] < 1.0,
                double_sided: true,
                texture: self.texture.clone(),
                ..GlbMaterial::default()
            },
        }
    }
}

/// Split `mesh` into one [`PartNode`] per [`crate::geom::mesh::MeshPart`] (in part order), each
/// keeping the normals, UVs, vertex colours and texture the mesh has. Parts with no triangles come out empty (and
/// [`mesh_glb`] skips them). Triangles outside every part (none for a well-formed mesh) are
/// dropped. Allocates about the mesh's size.
pub fn scene_nodes(mesh: &Mesh) -> Vec<PartNode> {
    let mut remap = vec![u32::MAX; mesh.positions.len()];
    mesh.parts
        .iter()
        .map(|part| {
            let end = (part.first_triangle + part.triangle_count).min(mesh.triangles.len());
            let start = part.first_triangle.min(end);
            let mut used: Vec<u32> = Vec::new();
            let triangles: Vec<[u32; 3]> = mesh.triangles[start..end]
                .iter()
                .map(|t| {
                    t.map(|i| {
                        let r = &mut remap[i as usize];
                        if *r == u32::MAX {
                            *r = used.len() as u32;
                            used.push(i);
                        }
                        *r
                    })
                })
                .collect();
            for &i in &used {
                remap[i as usize] = u32::MAX;
            }
            let pick = |i: &u32| mesh.positions[*i as usize];
            PartNode {
                name: part.name.clone(),
                positions: used.iter().map(pick).collect(),
                normals: mesh
                    .normals
                    .as_ref()
                    .map(|n| used.iter().map(|&i| n[i as usize]).collect()),
                uvs: mesh
                    .uvs
                    .as_ref()
                    .map(|u| used.iter().map(|&i| u[i as usize]).collect()),
                triangles,
                base_color: part.base_color,
                colors: mesh
                    .colors
                    .as_ref()
                    .map(|c| used.iter().map(|&i| c[i as usize]).collect()),
                texture: part
                    .texture
                    .filter(|_| mesh.uvs.is_some())
                    .and_then(|k| mesh.textures.get(k).cloned()),
            }
        })
        .collect()
}

/// Append an accessor; returns its index.
fn accessor(acc: &mut Vec<Value>, view: usize, count: usize, ty: &str, ct: u32) -> usize {
    acc.push(json!({ "bufferView": view, "componentType": ct, "count": count, "type": ty }));
    acc.len() - 1
}

fn unit_normal(v: [f32; 3]) -> [f32; 3] {
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if l > 1e-20 && l.is_finite() {
        v.map(|c| c / l)
    } else {
        [0.0, 1.0, 0.0]
    }
}

fn flat_bytes<const N: usize>(v: &[[f32; N]]) -> Vec<u8> {
    v.iter()
        .flat_map(|a| a.iter().flat_map(|x| x.to_le_bytes()))
        .collect()
}

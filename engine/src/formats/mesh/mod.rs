//! Mesh readers: glTF 2.0 / GLB, Wavefront OBJ, STL (binary and ASCII) and PLY (ASCII, binary
//! little and big endian) (SPEC §2 and §4, *Input*), all flattened into one [`Mesh`] in world
//! space: metres as in the file, Y up, counter-clockwise triangles.
//!
//! - **Frame.** glTF is Y-up by its spec and is never rotated ([`MeshOptions::up_axis`] is
//!   ignored for it). OBJ defaults to Y-up (no change), STL and PLY to Z-up, which is turned into
//!   Y-up by the proper rotation of −90° about X: `(x, y, z) → (x, z, −y)` (determinant +1, so
//!   the winding and the handedness are kept). Normals get the same rotation.
//! - **Limits.** Every reader checks the declared vertex and triangle counts against
//!   [`MeshOptions::max_vertices`] / [`MeshOptions::max_triangles`] *before* allocating the mesh:
//!   binary STL from its header count (which must match the file size exactly), PLY from its
//!   header's element counts, glTF from the accessor counts in the JSON before any buffer is
//!   decoded, OBJ from a counting pass over the text. Polygons are fanned, so a PLY face or an
//!   OBJ `f` line with n corners counts n − 2 triangles; the caps also hold while parsing.
//! - **Validation, the same for all formats** ([`finish`]): non-finite positions are
//!   [`InputError::Corrupt`] naming the vertex; finite positions beyond ±10⁹ m
//!   ([`crate::geom::sanity::MAX_COORDINATE`]) are [`InputError::Unusable`]; indices out of
//!   range are `Corrupt`; a mesh without triangles is [`InputError::Unusable`]. Normals are
//!   normalised; if any is non-finite or zero the whole normal set is dropped (consumers compute
//!   their own). Non-finite UVs drop the UV set. Degenerate (zero-area) triangles are *kept*: they are harmless for rasterising
//!   and ray casting, and dropping them would shift part ranges for no gain.
//! - **Safety net.** The third-party parsers (`gltf`, `tobj`, `stl_io`, `ply-rs-bw`) run inside
//!   [`std::panic::catch_unwind`]; a panic on hostile bytes becomes `Corrupt`.
//!
//! Cost: one pass over the file (two for OBJ, on all threads for its common subset), plus the
//! mesh itself; glTF additionally holds the decoded `data:` buffers while reading.
//!
//! - **Materials** (`crate::geom::mesh`, *Materials*): glTF base colour factors, `COLOR_0` and
//!   base-colour textures; OBJ `Kd`/`d`/`map_Kd` from its MTL; PLY vertex colours. Textures are
//!   PNG or JPEG ([`texture`]), refused over [`MeshOptions::max_texture_pixels`] from their header
//!   and stored within a shared budget. **Sidecar files** (an OBJ's MTL and textures, a `.gltf`'s
//!   external buffers and images) come as [`Sidecars`], by the relative path the file names:
//!   the CLI reads them from beside the input ([`gather_sidecars`]); the HTTP API takes one file,
//!   so an upload that needs them keeps its defaults — a GLB embeds everything and is the way to
//!   send a textured model. A missing or undecodable MTL or texture is never an error: the part
//!   keeps grey (OBJ without MTL) or its base colour, and [`Mesh::notes`] says what was missing
//!   (the pipelines put the notes in `report.json`). A `.gltf` buffer that is missing is still
//!   [`InputError::Unusable`]: without it there is no geometry.
//!
//! Rejected designs: a zip upload for OBJ + MTL + textures (one more container to bound and
//! fuzz, while GLB already carries everything), welding vertices across parts.

mod gltf;
mod obj;
mod obj_fast;
mod ply;
mod stl;
pub mod texture;
mod upright;

pub use upright::{decode_upright, other_up_reason, shape_decides, support_share};

use crate::error::InputError;
use crate::geom::mesh::{Mesh, MeshPart, Texture};

pub use crate::geom::mesh::UpAxis;

/// Options for [`decode_mesh`].
#[derive(Debug, Clone)]
pub struct MeshOptions {
    /// Refuse meshes with more triangles than this, before allocating them
    /// ([`InputError::TooLarge`]). Polygons count as their fan triangulation. Default: 4,000,000
    /// (≈ 48 MB of indices), far above the paper's scenes (≤ 13k triangles) while bounding a job.
    pub max_triangles: u64,
    /// Refuse meshes with more vertices than this, before allocating them. glTF counts a mesh
    /// once per node that instances it. Default: 4,000,000 (≈ 48 MB of positions).
    pub max_vertices: u64,
    /// Up axis for OBJ/STL/PLY (glTF is always Y-up by its spec). `None` = the format's
    /// default: Z for STL and PLY, Y for OBJ. Default: `None`.
    pub up_axis: Option<UpAxis>,
    /// Refuse base-colour textures with more pixels than this, from the image header before
    /// decoding ([`InputError::TooLarge`]). Default: 8192² (≈ 67 M pixels).
    pub max_texture_pixels: u64,
}

impl Default for MeshOptions {
    fn default() -> Self {
        Self {
            max_triangles: 4_000_000,
            max_vertices: 4_000_000,
            up_axis: None,
            max_texture_pixels: 8192 * 8192,
        }
    }
}

/// The files a mesh refers to by relative path (OBJ `mtllib` and `map_Kd`, glTF buffer and image
/// URIs), as (path as written in the referring file, bytes). The CLI reads them from beside the
/// input ([`gather_sidecars`]); the HTTP API uploads one file, so there they are empty and the
/// readers fall back to defaults with a note (see the module doc, *Materials*).
#[derive(Debug, Clone, Copy, Default)]
pub struct Sidecars<'a>(pub &'a [(String, Vec<u8>)]);

impl<'a> Sidecars<'a> {
    /// The bytes of the file `name` refers to (compared after [`normalize_ref`]).
    pub fn get(&self, name: &str) -> Option<&'a [u8]> {
        let want = normalize_ref(name);
        self.0
            .iter()
            .find(|(k, _)| normalize_ref(k) == want)
            .map(|(_, v)| &v[..])
    }
}

/// A relative reference as the readers compare them: `%XX` escapes decoded (glTF URIs),
/// backslashes as slashes (Windows exporters), a leading `./` dropped.
pub fn normalize_ref(name: &str) -> String {
    let mut out = Vec::with_capacity(name.len());
    let b = name.trim().as_bytes();
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' && i + 2 < b.len() {
            let hex = std::str::from_utf8(&b[i + 1..i + 3]).unwrap_or("");
            if let Ok(v) = u8::from_str_radix(hex, 16) {
                out.push(v);
                i += 3;
                continue;
            }
        }
        out.push(if b[i] == b'\\' { b'/' } else { b[i] });
        i += 1;
    }
    let s = String::from_utf8_lossy(&out).into_owned();
    s.strip_prefix("./").map(str::to_string).unwrap_or(s)
}

/// The relative files `bytes` (a mesh named `filename`) refers to, read with `read` (given the
/// normalised reference; `None` = not there): for OBJ its `mtllib` files and the `map_Kd`
/// textures those name, for a `.gltf` its non-`data:` buffer and image URIs. At most 64 files;
/// others formats have none. For the CLI, which reads them from beside the input file.
pub fn gather_sidecars(
    bytes: &[u8],
    filename: Option<&str>,
    read: &mut dyn FnMut(&str) -> Option<Vec<u8>>,
) -> Vec<(String, Vec<u8>)> {
    let mut names: Vec<String> = Vec::new();
    match sniff_mesh(bytes, filename) {
        Some(MeshFormat::Obj) => names.extend(obj::material_libraries(bytes)),
        Some(MeshFormat::Gltf) => names.extend(gltf::external_uris(bytes)),
        _ => return Vec::new(),
    }
    let mut out: Vec<(String, Vec<u8>)> = Vec::new();
    let mut i = 0;
    while i < names.len() && out.len() < 64 {
        let name = normalize_ref(&names[i]);
        i += 1;
        if out.iter().any(|(k, _)| *k == name) {
            continue;
        }
        let Some(data) = read(&name) else { continue };
        if name.to_ascii_lowercase().ends_with(".mtl") {
            names.extend(obj::mtl_textures(&data));
        }
        out.push((name, data));
    }
    out
}

/// The mesh formats we read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshFormat {
    /// glTF 2.0 JSON (`.gltf`) with embedded `data:` buffers.
    Gltf,
    /// Binary glTF (`.glb`) with its BIN chunk.
    Glb,
    /// Wavefront OBJ (without its MTL file).
    Obj,
    /// STL, binary or ASCII.
    Stl,
    /// Stanford PLY, ASCII or binary (either endianness).
    Ply,
}

impl MeshFormat {
    /// Short name used in error messages.
    pub fn name(self) -> &'static str {
        match self {
            MeshFormat::Gltf => "glTF",
            MeshFormat::Glb => "GLB",
            MeshFormat::Obj => "OBJ",
            MeshFormat::Stl => "STL",
            MeshFormat::Ply => "PLY",
        }
    }
}

/// The format detected from magic bytes, the file name and the text, without decoding.
///
/// Order: GLB magic `glTF`; PLY magic `ply` + newline; a binary STL whose header triangle count
/// gives exactly the file size (unless the text starts with `solid` and ends with `endsolid`);
/// then the file extension (`.gltf`, `.glb`, `.obj`, `.stl`, `.ply`); then text sniffing: a JSON
/// object with an `"asset"` key is glTF, text starting with `solid` is ASCII STL, and text whose
/// first meaningful lines are OBJ statements (`v`, `vn`, `vt`, `f`, `o`, `g`, `mtllib`, …) is OBJ.
pub fn sniff_mesh(bytes: &[u8], filename: Option<&str>) -> Option<MeshFormat> {
    if bytes.starts_with(b"glTF") {
        return Some(MeshFormat::Glb);
    }
    if bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r\n") {
        return Some(MeshFormat::Ply);
    }
    if stl::is_binary(bytes) {
        return Some(MeshFormat::Stl);
    }
    let ext = filename
        .and_then(|n| n.rsplit('.').next().filter(|_| n.contains('.')))
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("gltf") => return Some(MeshFormat::Gltf),
        Some("glb") => return Some(MeshFormat::Glb),
        Some("obj") => return Some(MeshFormat::Obj),
        Some("stl") => return Some(MeshFormat::Stl),
        Some("ply") => return Some(MeshFormat::Ply),
        _ => {}
    }
    let head = &bytes[..bytes.len().min(4096)];
    let text = trim_ascii_start(head.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(head));
    if text.starts_with(b"{") && contains(head, b"\"asset\"") {
        return Some(MeshFormat::Gltf);
    }
    if text.starts_with(b"solid") {
        return Some(MeshFormat::Stl);
    }
    if obj::looks_like_obj(head) {
        return Some(MeshFormat::Obj);
    }
    None
}

/// Decode a mesh of any supported format (see [`sniff_mesh`]) into world space, metres, Y up.
///
/// Errors: [`InputError::UnsupportedFormat`] when no format matches, [`InputError::Corrupt`]
/// for truncated or inconsistent bytes, non-finite positions or indices out of range,
/// [`InputError::TooLarge`] when the declared counts exceed `opts` (checked before the mesh is
/// allocated), [`InputError::Unusable`] for a mesh without triangles or a glTF that needs files
/// other than the upload.
///
/// Allocates the mesh (plus, for glTF, the decoded `data:` buffers; for STL, a vertex-welding
/// hash map).
pub fn decode_mesh(
    bytes: &[u8],
    filename: Option<&str>,
    opts: &MeshOptions,
) -> Result<Mesh, InputError> {
    decode_mesh_with(bytes, filename, opts, Sidecars::default())
}

/// An OBJ through the `tobj` path alone (no parallel reader): the reference the `mesh_decode`
/// example times [`decode_mesh`] against. Test and benchmark builds only.
#[cfg(feature = "testkit")]
#[doc(hidden)]
pub fn decode_obj_tobj(bytes: &[u8], opts: &MeshOptions) -> Result<Mesh, InputError> {
    let decoded = obj::decode_with(bytes, opts, Sidecars::default(), false)?;
    finish(decoded, "OBJ", opts)
}

/// [`decode_mesh`] with the files the mesh refers to ([`Sidecars`]): OBJ material libraries and
/// their textures, external glTF buffers and images.
pub fn decode_mesh_with(
    bytes: &[u8],
    filename: Option<&str>,
    opts: &MeshOptions,
    sidecars: Sidecars<'_>,
) -> Result<Mesh, InputError> {
    let format = sniff_mesh(bytes, filename).ok_or_else(|| {
        InputError::UnsupportedFormat(
            "not a mesh format we read (glTF/GLB, OBJ, STL, PLY)".to_string(),
        )
    })?;
    let decoded = std::panic::catch_unwind(|| match format {
        MeshFormat::Gltf | MeshFormat::Glb => gltf::decode(bytes, format, opts, sidecars),
        MeshFormat::Obj => obj::decode(bytes, opts, sidecars),
        MeshFormat::Stl => stl::decode(bytes, opts),
        MeshFormat::Ply => ply::decode(bytes, opts),
    })
    .unwrap_or_else(|_| {
        Err(InputError::Corrupt {
            format: format.name(),
            detail: "the decoder panicked on malformed data".to_string(),
        })
    })?;
    let mut mesh = finish(decoded, format.name(), opts)?;
    let up = match format {
        MeshFormat::Gltf | MeshFormat::Glb => UpAxis::Y,
        MeshFormat::Obj => opts.up_axis.unwrap_or(UpAxis::Y),
        MeshFormat::Stl | MeshFormat::Ply => opts.up_axis.unwrap_or(UpAxis::Z),
    };
    if up == UpAxis::Z {
        z_up_to_y_up(&mut mesh);
    }
    Ok(mesh)
}

/// Rotate a Z-up mesh to Y-up: (x, y, z) → (x, z, −y), −90° about X (a proper rotation).
fn z_up_to_y_up(mesh: &mut Mesh) {
    let rot = |p: &mut [f32; 3]| *p = [p[0], p[2], -p[1]];
    mesh.positions.iter_mut().for_each(rot);
    if let Some(n) = &mut mesh.normals {
        n.iter_mut().for_each(rot);
    }
}

/// Refuse counts over the limits (used before allocating).
pub(crate) fn check_counts(
    vertices: u64,
    triangles: u64,
    opts: &MeshOptions,
) -> Result<(), InputError> {
    if vertices > opts.max_vertices {
        return Err(InputError::TooLarge {
            what: "mesh vertices",
            actual: vertices,
            max: opts.max_vertices,
        });
    }
    if triangles > opts.max_triangles {
        return Err(InputError::TooLarge {
            what: "mesh triangles",
            actual: triangles,
            max: opts.max_triangles,
        });
    }
    Ok(())
}

/// Collects parts of a mesh; indices passed to [`Builder::push_part`] are local to the part.
///
/// Attribute sets across parts: normals are kept only when every part has them (consumers
/// compute their own otherwise). UVs are kept when every part has them, or when a part with a
/// texture has them (the others get (0, 0): they have no texture to look up). Vertex colours are
/// kept when any part has them (the others get white, which leaves their base colour as it is).
pub(crate) struct Builder {
    mesh: Mesh,
    normals: Vec<[f32; 3]>,
    uvs: Vec<[f32; 2]>,
    colors: Vec<[f32; 4]>,
    all_normals: bool,
    all_uvs: bool,
    textured_uvs: bool,
    any_colors: bool,
}

/// One part's data, indices local to `positions`.
pub(crate) struct PartData {
    pub name: String,
    pub base_color: [f32; 4],
    /// Index into the textures given to [`Builder::build`].
    pub texture: Option<usize>,
    pub positions: Vec<[f32; 3]>,
    pub normals: Option<Vec<[f32; 3]>>,
    pub uvs: Option<Vec<[f32; 2]>>,
    /// Linear RGBA per vertex.
    pub colors: Option<Vec<[f32; 4]>>,
    pub triangles: Vec<[u32; 3]>,
}

/// Linear from an sRGB value 0..1 (clamped).
pub(crate) fn srgb_to_linear(v: f32) -> f32 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.040_45 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// Neutral grey (linear) for formats without material colours.
pub(crate) const GREY: [f32; 4] = [0.5, 0.5, 0.5, 1.0];

impl Builder {
    pub fn new() -> Self {
        Self {
            mesh: Mesh::default(),
            normals: Vec::new(),
            uvs: Vec::new(),
            colors: Vec::new(),
            all_normals: true,
            all_uvs: true,
            textured_uvs: false,
            any_colors: false,
        }
    }

    pub fn vertex_count(&self) -> usize {
        self.mesh.positions.len()
    }

    /// Adds a note for the report (see [`Mesh::notes`]).
    pub fn note(&mut self, note: String) {
        if !self.mesh.notes.contains(&note) {
            self.mesh.notes.push(note);
        }
    }

    /// Append a part; its indices are checked against its own vertex count. A part without
    /// triangles (points, lines, an empty object) is skipped.
    pub fn push_part(&mut self, part: PartData, format: &'static str) -> Result<(), InputError> {
        if part.triangles.is_empty() {
            return Ok(());
        }
        let n = part.positions.len();
        let base = u32::try_from(self.mesh.positions.len()).map_err(|_| InputError::TooLarge {
            what: "mesh vertices",
            actual: self.mesh.positions.len() as u64,
            max: u64::from(u32::MAX),
        })?;
        if base as usize + n > u32::MAX as usize {
            return Err(InputError::TooLarge {
                what: "mesh vertices",
                actual: (base as usize + n) as u64,
                max: u64::from(u32::MAX),
            });
        }
        let first_triangle = self.mesh.triangles.len();
        for (t, tri) in part.triangles.iter().enumerate() {
            if let Some(&bad) = tri.iter().find(|&&i| i as usize >= n) {
                return Err(InputError::Corrupt {
                    format,
                    detail: format!(
                        "triangle {t} of part '{}' uses vertex {bad}, but the part has {n} \
                         vertices",
                        part.name
                    ),
                });
            }
            self.mesh
                .triangles
                .push([tri[0] + base, tri[1] + base, tri[2] + base]);
        }
        match part.normals {
            Some(v) if v.len() == n && self.all_normals => self.normals.extend(v),
            _ => {
                self.all_normals = false;
                self.normals = Vec::new();
            }
        }
        let before = base as usize;
        match part.uvs.filter(|v| v.len() == n) {
            Some(v) => {
                self.textured_uvs |= part.texture.is_some();
                self.uvs.resize(before, [0.0; 2]);
                self.uvs.extend(v);
            }
            None => {
                self.all_uvs = false;
                self.uvs.resize(before + n, [0.0; 2]);
            }
        }
        match part.colors.filter(|v| v.len() == n) {
            Some(v) => {
                self.any_colors = true;
                self.colors.resize(before, [1.0; 4]);
                self.colors.extend(v);
            }
            None => self.colors.resize(before + n, [1.0; 4]),
        }
        self.mesh.positions.extend(part.positions);
        self.mesh.parts.push(MeshPart {
            name: part.name,
            first_triangle,
            triangle_count: part.triangles.len(),
            base_color: part.base_color,
            texture: part.texture,
        });
        Ok(())
    }

    /// The mesh, with `textures` (the parts' texture indices refer to them).
    pub fn build_with(mut self, textures: Vec<std::sync::Arc<Texture>>) -> Mesh {
        let has_vertices = !self.mesh.positions.is_empty();
        if self.all_normals && has_vertices {
            self.mesh.normals = Some(self.normals);
        }
        if (self.all_uvs || self.textured_uvs) && has_vertices {
            self.mesh.uvs = Some(self.uvs);
        }
        if self.any_colors && has_vertices {
            self.mesh.colors = Some(self.colors);
        }
        // A part whose texture is missing keeps its base colour.
        for p in &mut self.mesh.parts {
            if p.texture.is_some_and(|t| t >= textures.len()) {
                p.texture = None;
            }
        }
        self.mesh.textures = textures;
        self.mesh
    }

    pub fn build(self) -> Mesh {
        self.build_with(Vec::new())
    }
}

/// The checks every format goes through (see the module doc).
fn finish(mut mesh: Mesh, format: &'static str, opts: &MeshOptions) -> Result<Mesh, InputError> {
    check_counts(
        mesh.positions.len() as u64,
        mesh.triangles.len() as u64,
        opts,
    )?;
    if let Some(i) = mesh
        .positions
        .iter()
        .position(|p| !p.iter().all(|c| c.is_finite()))
    {
        return Err(InputError::Corrupt {
            format,
            detail: format!(
                "vertex {i} has a non-finite position {:?}",
                mesh.positions[i]
            ),
        });
    }
    // Finite but absurd (|x| > 10⁹ m): squares and products overflow f32 in the pipelines.
    if let Some((_, detail)) = crate::geom::sanity::first_bad_position(&mesh.positions) {
        return Err(InputError::Unusable(format!("the {format} mesh: {detail}")));
    }
    let n = mesh.positions.len();
    if let Some(t) = mesh
        .triangles
        .iter()
        .position(|tri| tri.iter().any(|&i| i as usize >= n))
    {
        return Err(InputError::Corrupt {
            format,
            detail: format!(
                "triangle {t} refers to vertex {:?}, but there are {n} vertices",
                mesh.triangles[t]
            ),
        });
    }
    if mesh.triangles.is_empty() {
        return Err(InputError::Unusable(format!(
            "the {format} file holds no triangles"
        )));
    }
    if mesh.normals.as_ref().is_some_and(|v| v.len() != n) {
        mesh.normals = None;
    }
    if let Some(normals) = &mut mesh.normals {
        let mut ok = true;
        for v in normals.iter_mut() {
            let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if !(len.is_finite() && len > 0.0) {
                ok = false;
                break;
            }
            *v = [v[0] / len, v[1] / len, v[2] / len];
        }
        if !ok {
            mesh.normals = None;
        }
    }
    if mesh
        .uvs
        .as_ref()
        .is_some_and(|v| v.len() != n || v.iter().flatten().any(|c| !c.is_finite()))
    {
        mesh.uvs = None;
    }
    if mesh
        .colors
        .as_ref()
        .is_some_and(|v| v.len() != n || v.iter().flatten().any(|c| !c.is_finite()))
    {
        mesh.colors = None;
    }
    if let Some(colors) = &mut mesh.colors {
        for c in colors.iter_mut() {
            *c = c.map(|v| v.clamp(0.0, 1.0));
        }
    }
    // Parts must tile the triangles; readers build them that way, but keep the promise.
    let mut next = 0;
    for p in &mesh.parts {
        if p.first_triangle != next {
            return Err(InputError::Corrupt {
                format,
                detail: "internal: parts do not tile the triangles".to_string(),
            });
        }
        next += p.triangle_count;
    }
    if next != mesh.triangles.len() {
        return Err(InputError::Corrupt {
            format,
            detail: "internal: parts do not cover the triangles".to_string(),
        });
    }
    Ok(mesh)
}

fn trim_ascii_start(b: &[u8]) -> &[u8] {
    let i = b
        .iter()
        .position(|c| !c.is_ascii_whitespace())
        .unwrap_or(b.len());
    &b[i..]
}

fn contains(hay: &[u8], needle: &[u8]) -> bool {
    hay.windows(needle.len()).any(|w| w == needle)
}

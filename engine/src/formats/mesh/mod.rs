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
//!   [`InputError::Corrupt`] naming the vertex; indices out of range are `Corrupt`; a mesh
//!   without triangles is [`InputError::Unusable`]. Normals are normalised; if any is non-finite
//!   or zero the whole normal set is dropped (consumers compute their own). Non-finite UVs drop
//!   the UV set. Degenerate (zero-area) triangles are *kept*: they are harmless for rasterising
//!   and ray casting, and dropping them would shift part ranges for no gain.
//! - **Safety net.** The third-party parsers (`gltf`, `tobj`, `stl_io`, `ply-rs-bw`) run inside
//!   [`std::panic::catch_unwind`]; a panic on hostile bytes becomes `Corrupt`.
//!
//! Cost: one pass over the file (two for OBJ), plus the mesh itself; glTF additionally holds the
//! decoded `data:` buffers while reading.
//!
//! Rejected designs: resolving external glTF/OBJ-MTL files (only one file is uploaded; a missing
//! sidecar is reported, or, for MTL, replaced by grey), decoding glTF images (not needed for the
//! base colour, and an easy way to blow the memory budget), welding vertices across parts.

mod gltf;
mod obj;
mod ply;
mod stl;

use crate::error::InputError;
use crate::geom::mesh::{Mesh, MeshPart};

/// Which file axis points up, for formats without a fixed convention (OBJ, STL, PLY).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UpAxis {
    /// +Y is up (glTF, most OBJ exporters): no change.
    Y,
    /// +Z is up (CAD, 3-D printing, scanners): rotated by (x, y, z) → (x, z, −y).
    Z,
}

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
}

impl Default for MeshOptions {
    fn default() -> Self {
        Self {
            max_triangles: 4_000_000,
            max_vertices: 4_000_000,
            up_axis: None,
        }
    }
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
    let format = sniff_mesh(bytes, filename).ok_or_else(|| {
        InputError::UnsupportedFormat(
            "not a mesh format we read (glTF/GLB, OBJ, STL, PLY)".to_string(),
        )
    })?;
    let decoded = std::panic::catch_unwind(|| match format {
        MeshFormat::Gltf | MeshFormat::Glb => gltf::decode(bytes, format, opts),
        MeshFormat::Obj => obj::decode(bytes, opts),
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
pub(crate) struct Builder {
    mesh: Mesh,
    normals: Vec<[f32; 3]>,
    uvs: Vec<[f32; 2]>,
    all_normals: bool,
    all_uvs: bool,
}

/// One part's data, indices local to `positions`.
pub(crate) struct PartData {
    pub name: String,
    pub base_color: [f32; 4],
    pub positions: Vec<[f32; 3]>,
    pub normals: Option<Vec<[f32; 3]>>,
    pub uvs: Option<Vec<[f32; 2]>>,
    pub triangles: Vec<[u32; 3]>,
}

/// Neutral grey (linear) for formats without material colours.
pub(crate) const GREY: [f32; 4] = [0.5, 0.5, 0.5, 1.0];

impl Builder {
    pub fn new() -> Self {
        Self {
            mesh: Mesh::default(),
            normals: Vec::new(),
            uvs: Vec::new(),
            all_normals: true,
            all_uvs: true,
        }
    }

    pub fn vertex_count(&self) -> usize {
        self.mesh.positions.len()
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
        match part.uvs {
            Some(v) if v.len() == n && self.all_uvs => self.uvs.extend(v),
            _ => {
                self.all_uvs = false;
                self.uvs = Vec::new();
            }
        }
        self.mesh.positions.extend(part.positions);
        self.mesh.parts.push(MeshPart {
            name: part.name,
            first_triangle,
            triangle_count: part.triangles.len(),
            base_color: part.base_color,
        });
        Ok(())
    }

    pub fn build(mut self) -> Mesh {
        if self.all_normals && !self.mesh.positions.is_empty() {
            self.mesh.normals = Some(self.normals);
        }
        if self.all_uvs && !self.mesh.positions.is_empty() {
            self.mesh.uvs = Some(self.uvs);
        }
        self.mesh
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

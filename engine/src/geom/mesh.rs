//! Triangle meshes as the mesh pipelines see them: one flattened scene in world space.
//!
//! Frame: Y up, metres (glTF's frame). Readers apply node transforms and the `up_axis` conversion
//! so every consumer sees the same frame. Triangles are counter-clockwise seen from outside
//! (glTF's convention); readers keep the file's winding.

//! **Materials.** A part has a base colour (linear RGBA) and optionally a base-colour texture
//! ([`MeshPart::texture`], an index into [`Mesh::textures`]) looked up through [`Mesh::uvs`];
//! the mesh may carry per-vertex colours ([`Mesh::colors`], PLY). The albedo of a surface point
//! is glTF's: base colour × vertex colour × texture (sRGB texels decoded to linear).

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use super::vec::Vec3;

/// Which file axis points up, for formats without a fixed convention (OBJ, STL, PLY); the mesh
/// pipelines' `up_axis` parameter (`"y"`, `"z"`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum UpAxis {
    /// +Y is up (glTF, most OBJ exporters): no change.
    Y,
    /// +Z is up (CAD, 3-D printing, scanners): rotated by (x, y, z) → (x, z, −y).
    Z,
}

/// How a texture repeats outside [0, 1] (glTF sampler `wrapS`/`wrapT`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TextureWrap {
    /// Tiles (glTF's default).
    #[default]
    Repeat,
    /// Edge texels extend.
    Clamp,
    /// Tiles, every other tile mirrored.
    Mirror,
}

/// A base-colour texture decoded for rendering, with the encoded image kept for export.
#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    /// Where it came from (glTF image name or URI, the `map_Kd` path), for reports.
    pub name: String,
    /// Stored size in texels (the decoded image, box-filtered down when over the reader's
    /// storage budget; see [`crate::formats::mesh`]).
    pub width: u32,
    pub height: u32,
    /// sRGB RGBA, 8 bits, row-major, top row first (texture coordinate v = 0).
    pub texels: Vec<[u8; 4]>,
    /// The image file as read (PNG or JPEG), embedded unchanged in the GLB outputs.
    pub encoded: Arc<[u8]>,
    /// `image/png` or `image/jpeg`.
    pub mime: &'static str,
    /// Wrap along u and v.
    pub wrap: [TextureWrap; 2],
}

/// A contiguous run of triangles that came from one mesh/primitive/object of the input, with its
/// material colour, so outputs can keep the input's parts apart.
#[derive(Debug, Clone, PartialEq)]
pub struct MeshPart {
    /// Name from the file (node/mesh/object name), or `part<i>`.
    pub name: String,
    /// First triangle index of this part in [`Mesh::triangles`].
    pub first_triangle: usize,
    /// Number of triangles.
    pub triangle_count: usize,
    /// Base colour, linear RGBA (glTF `baseColorFactor`, OBJ `Kd`, PLY/STL: a neutral grey).
    pub base_color: [f32; 4],
    /// Base-colour texture (index into [`Mesh::textures`]), multiplied with `base_color`; used
    /// only where the mesh has [`Mesh::uvs`]. Default: none.
    pub texture: Option<usize>,
}

/// An indexed triangle mesh in world space.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Mesh {
    /// Vertex positions, metres, Y up. All finite (readers reject NaN/∞).
    pub positions: Vec<[f32; 3]>,
    /// Vertex indices, three per triangle, all `< positions.len()`.
    pub triangles: Vec<[u32; 3]>,
    /// Per-vertex unit normals when the file has them (same length as `positions`).
    pub normals: Option<Vec<[f32; 3]>>,
    /// Per-vertex texture coordinates when the file has them, glTF's convention (v = 0 at the
    /// image's top row; OBJ's v is flipped on reading).
    pub uvs: Option<Vec<[f32; 2]>>,
    /// Per-vertex colours, linear RGBA 0..1, when the file has them (PLY `red green blue`, OBJ
    /// `v x y z r g b`, glTF `COLOR_0`); they multiply the part's base colour.
    pub colors: Option<Vec<[f32; 4]>>,
    /// The base-colour textures the parts refer to (shared, so copies of the mesh are cheap).
    pub textures: Vec<Arc<Texture>>,
    /// The input's parts in order; their triangle ranges tile `triangles`.
    pub parts: Vec<MeshPart>,
    /// What the reader could not use and replaced by a default (a material library or texture
    /// that was not uploaded, an unsupported image format): for the pipeline's report.
    pub notes: Vec<String>,
}

/// Axis-aligned bounds (min, max) of `points`; `None` when there are none.
pub fn bounds_of(points: &[[f32; 3]]) -> Option<([f32; 3], [f32; 3])> {
    let mut it = points.iter();
    let first = *it.next()?;
    let (mut lo, mut hi) = (first, first);
    for p in it {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    Some((lo, hi))
}

impl Mesh {
    /// Whether any part has a texture the mesh's UVs can look up.
    pub fn has_textures(&self) -> bool {
        self.uvs.is_some() && self.parts.iter().any(|p| p.texture.is_some())
    }

    /// Axis-aligned bounds (min, max); `None` for an empty mesh.
    pub fn bounds(&self) -> Option<([f32; 3], [f32; 3])> {
        bounds_of(&self.positions)
    }

    /// The three corners of triangle `t`.
    #[inline]
    pub fn corners(&self, t: usize) -> [[f32; 3]; 3] {
        let [a, b, c] = self.triangles[t];
        [
            self.positions[a as usize],
            self.positions[b as usize],
            self.positions[c as usize],
        ]
    }

    /// Unnormalised face normal (cross product of two edges; length = 2 × area).
    #[inline]
    pub fn face_normal(&self, t: usize) -> [f32; 3] {
        let [a, b, c] = self.corners(t).map(Vec3::from);
        (b - a).cross(c - a).to_array()
    }
}

//! Triangle meshes as the mesh pipelines see them: one flattened scene in world space.
//!
//! Frame: Y up, metres (glTF's frame). Readers apply node transforms and the `up_axis` conversion
//! so every consumer sees the same frame. Triangles are counter-clockwise seen from outside
//! (glTF's convention); readers keep the file's winding.

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
    /// Per-vertex texture coordinates when the file has them.
    pub uvs: Option<Vec<[f32; 2]>>,
    /// The input's parts in order; their triangle ranges tile `triangles`.
    pub parts: Vec<MeshPart>,
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
        let [a, b, c] = self.corners(t);
        let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ]
    }
}

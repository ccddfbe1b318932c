//! Geometry: height fields (DEMs) and their georeferencing; triangle meshes; density volumes.

pub mod heightfield;
pub mod mesh;
pub mod sanity;
pub mod volume;

pub use heightfield::{Dem, GeoRef};
pub use mesh::{Mesh, MeshPart};
pub use volume::Volume;

/// `v` scaled to unit length; the zero vector when `v` is zero or not finite (degenerate
/// normals stay harmless instead of turning into NaNs).
pub fn unit(v: [f32; 3]) -> [f32; 3] {
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if l > 0.0 && l.is_finite() {
        v.map(|c| c / l)
    } else {
        [0.0; 3]
    }
}

/// Box (tri-planar) projection of triangle `(a, b, c)`: the axis its face normal is most aligned
/// with (0 = X, 1 = Y, 2 = Z; ties go to the lower index, so the choice is deterministic) and the
/// two coordinates that project onto that axis plane, as `(u, v)`: X → (Z, Y), Y → (X, Z),
/// Z → (X, Y). Shared by the dust export's UVs and the snow cover's flake overlay.
pub fn box_projection(a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> (usize, [usize; 2]) {
    let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
    let n = [
        (u[1] * v[2] - u[2] * v[1]).abs(),
        (u[2] * v[0] - u[0] * v[2]).abs(),
        (u[0] * v[1] - u[1] * v[0]).abs(),
    ];
    if n[0] >= n[1] && n[0] >= n[2] {
        (0, [2, 1])
    } else if n[1] >= n[2] {
        (1, [0, 2])
    } else {
        (2, [0, 1])
    }
}

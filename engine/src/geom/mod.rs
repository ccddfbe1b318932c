//! Geometry: height fields (DEMs) and their georeferencing; triangle meshes; density volumes.

pub mod heightfield;
pub mod mesh;
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

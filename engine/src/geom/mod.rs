//! Geometry: height fields (DEMs) and their georeferencing; triangle meshes.

pub mod heightfield;
pub mod mesh;

pub use heightfield::{Dem, GeoRef};
pub use mesh::{Mesh, MeshPart};

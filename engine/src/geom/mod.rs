//! Geometry: height fields (DEMs) and their georeferencing; triangle meshes; density volumes.

pub mod heightfield;
pub mod mesh;
pub mod volume;

pub use heightfield::{Dem, GeoRef};
pub use mesh::{Mesh, MeshPart};
pub use volume::Volume;

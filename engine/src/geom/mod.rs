//! Geometry, the engine's ground floor above the error types: height fields (DEMs) and their
//! georeferencing, triangle meshes and their subdivision, density volumes, glam-based vector
//! maths, the sun's direction, the perspective camera and a ray-casting BVH that holds on any
//! mesh ([`bvh`]). Imports nothing of the engine but [`crate::error`].

pub mod bvh;
pub mod camera;
pub mod heightfield;
pub mod mercator;
pub mod mesh;
pub mod sanity;
pub mod subdivide;
pub mod vec;
pub mod volume;

pub use heightfield::{Dem, GeoRef};
pub use mesh::{Mesh, MeshPart};
pub use vec::{box_projection, sun_direction, unit};
pub use volume::Volume;

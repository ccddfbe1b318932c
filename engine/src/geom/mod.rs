//! Geometry, the engine's ground floor above the error types: height fields (DEMs) and their
//! georeferencing, triangle meshes and their subdivision, density volumes, glam-based vector
//! maths, the sun's direction and the perspective camera. Imports nothing of the engine but
//! [`crate::error`].

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

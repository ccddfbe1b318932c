//! Parameters, the floor under the formats and the renderers: what every pipeline's parameters
//! are made of (SPEC §5). The configured [`Limits`], the wire helpers ([`deserialize_params`],
//! [`range`], [`image_size`]), the typed [`Color`], the camera ([`camera`]) and the
//! view block the mesh pipelines share ([`mesh_view`]). Imports only `geom` and the error types.

pub mod camera;
pub mod color;
pub mod mesh_view;
mod wire;

pub use camera::{camera_spec, CameraSpec, OrbitDefaults, WireCamera};
pub use color::Color;
pub use mesh_view::{MeshView, MeshViewDefaults, WireMeshView};
pub use wire::{deserialize_params, image_size, range, unit_vector, Limits};

//! Input decoders and output encoders. Each reader refuses bad bytes with an [`crate::InputError`]
//! before any large allocation.

pub mod dem;
pub mod geotiff_write;
pub mod glb;
pub mod mesh;
pub mod mesh_glb;
pub(crate) mod npy_header;
pub mod ortho;
pub mod png_write;
pub mod volume;

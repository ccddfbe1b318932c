//! The readers and writers: DEMs, meshes, volumes.

mod cog;
mod dem;
mod mesh;
mod volume;

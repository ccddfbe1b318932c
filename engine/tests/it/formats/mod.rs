//! The readers and writers: DEMs, meshes, volumes.

mod dem;
mod mesh;
mod volume;

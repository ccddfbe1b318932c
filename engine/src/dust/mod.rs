//! Dust with fibre structure (SPEC §4; paper "Real Time Rendering of Dust Considered Fiber
//! Structure", `shared/papers/dust-fiber-shells.txt`).
//!
//! One module per step of the paper:
//! - [`amount`]: where dust lies and how much (§2.1, after Hsu & Wong 1995): D = K·max(0, N·U)^s·E(P).
//! - [`noise`]: the seeded, tileable Perlin fBm that modulates start points, brightness and bumps.
//! - [`params`]: the wire and validated parameters (SPEC §4, §5).
//! - [`shells`]: how thick it lies — layer heights and which texels each layer draws (§2.2).
//! - [`fibers`]: the fibre textures drawn as the trails of moving points (§2.3).
//!
//! And the pieces that turn them into pictures and files:
//! - [`surface`]: the mesh with crease-split vertex normals, which D and the shells use.
//! - [`mapping`]: how the textures lie on the mesh (its UVs rescaled, or tri-planar / box UVs).
//! - [`texture`]: the shell textures as 8-bit mip pyramids for sampling.
//! - [`render`]: the shells as lit, semi-transparent layers over the base mesh (§2.2, §3).
//! - [`export`]: `fibers.png` (atlas) and `dusty.glb` (base + shell meshes).
//! - [`run`]: the pipeline, mesh to outputs.

pub mod amount;
pub mod export;
pub mod fibers;
pub mod mapping;
pub mod noise;
pub mod params;
pub mod render;
pub mod run;
pub mod shells;
pub mod surface;
pub mod texture;

pub use params::DustParams;
pub use run::run;

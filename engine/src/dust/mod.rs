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
//! Not here yet (issue 6): the renderer, the glTF export, and the pipeline glue.

pub mod amount;
pub mod fibers;
pub mod noise;
pub mod params;
pub mod shells;

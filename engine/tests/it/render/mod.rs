//! The renderers: the height-field ray caster and rasteriser, the mesh renderer and its materials.

pub mod materials;
mod mesh;
mod terrain;

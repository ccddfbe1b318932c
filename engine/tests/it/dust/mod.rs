//! Dust (SPEC §4): the model, the input's materials, the pipeline's outputs.

mod bvh;
mod materials;
pub mod model;
mod pipeline;

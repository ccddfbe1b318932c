//! Snow cover (SPEC §2): the model, the pipeline, the snow shape outputs.

mod model;
mod pipeline;
mod shape;

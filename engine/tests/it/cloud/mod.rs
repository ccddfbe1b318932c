//! Clouds (SPEC §3): the renderer, the three edits, multiple scattering, the registry's cloud jobs and real volumes.

mod edit;
mod multiple;
mod pipeline;
mod render;
mod wild;

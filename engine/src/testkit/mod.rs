//! Fixtures for the tests and the benchmarks (behind the `testkit` feature; not part of the
//! library a service build links): scenes and volumes built in code, so the tests and the
//! benchmarks measure the same inputs.
//!
//! - [`snow_scenes`]: the snow-cover scenes (a bumpy grid with boxes, a table on a waved floor).
//! - [`dems`]: DEMs built from real ones (a mirrored tiling to any size).
//! - [`cloud_volumes`]: a procedural cumulus and the ambient edit's standard painted regions.

pub mod cloud_volumes;
pub mod dems;
pub mod snow_scenes;

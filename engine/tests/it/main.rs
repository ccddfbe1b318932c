//! Engine integration tests, one module per area.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may unwrap (STYLE habit 4)

mod cloud;
mod cloud_edit;
mod cloud_multiple;
mod cloud_pipeline;
mod cloud_wild;
mod descriptor;
mod dust;
mod dust_materials;
mod dust_pipeline;
mod formats;
mod gltf_validator;
mod golden;
mod materials;
mod mesh_formats;
mod mesh_output;
mod render;
mod snow_cover;
mod snow_cover_pipeline;
mod snow_shape;
mod snow_terrain;
mod snow_terrain_winter;
mod terrain_view;
mod volume_formats;

//! Engine integration tests, grouped by pipeline (and the shared floors: formats, render).

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may unwrap (STYLE habit 4)

mod cloud;
mod dust;
mod formats;
mod render;
mod snow_cover;
mod snow_terrain;
mod support;

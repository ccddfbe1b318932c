//! Engine integration tests, one module per area.

mod descriptor;
mod formats;
mod golden;
mod render;
mod snow_terrain;

//! Engine integration tests, one module per area.

mod descriptor;
mod formats;
mod render;

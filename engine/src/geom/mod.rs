//! Geometry: height fields (DEMs) and their georeferencing.

pub mod heightfield;

pub use heightfield::{Dem, GeoRef};

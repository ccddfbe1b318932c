//! snow_cover tests

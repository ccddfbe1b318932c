//! Pipeline registry.

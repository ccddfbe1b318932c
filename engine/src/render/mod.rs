//! Rendering shared by the pipelines.

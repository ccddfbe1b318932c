//! mesh_formats tests

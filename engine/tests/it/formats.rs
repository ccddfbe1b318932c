//! formats tests

//! Mesh readers (in progress).

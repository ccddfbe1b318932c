//! Shared by the tests: golden images and the Khronos glTF validator.

pub mod gltf_validator;
pub mod golden;

//! Snow on terrain (SPEC §1): Nakatani, Fujishiro and Ohno's surface descriptor.

pub mod descriptor;
